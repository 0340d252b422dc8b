//! User scans (`--scan FILE`): textured glTF/GLB, OBJ+MTL or PLY (THuman2.0, 2K2K, game characters,
//! photogrammetry), turned upright and toward the source camera, and normalised into the body cube like the
//! reference (height 1.8, xz centred on the minimal enclosing circle); a character too wide for the cube at that
//! height (T-pose, wings, a wide stance) is scaled down to fit, with one warning.
//!
//! Orientation ([`ScanOrientation`]): the up axis (`y` or `z`) and the direction the person faces (`+z`, `-z`,
//! `+x`, `-x`) are taken from the options, or detected ([`detect_orientation`]) and logged with the flags that
//! override them.

use std::path::Path;
use std::str::FromStr;

use glam::{Quat, Vec3};

use super::normalize::{self, Normalization};
use super::SynthError;
use crate::io::mesh_io::{read_mesh, TexturedMesh};

/// Largest coordinate magnitude accepted before normalisation (beyond it f32 precision is gone and the file is
/// almost certainly corrupt or in the wrong units).
pub const MAX_ABS_COORDINATE: f32 = 1e6;

/// Radius (xz, body-cube units) a scan is fitted into when it is too wide at height 1.8: a little margin inside
/// the cube so no vertex sits on its side.
pub const FIT_RADIUS: f32 = 0.98;

/// Widest scan accepted, as its xz radius at height 1.8: beyond it (a person 2.5 times wider than half their
/// height) the mesh almost certainly holds a floor or other objects, and shrinking it would leave a speck.
pub const MAX_RADIUS_AT_BODY_HEIGHT: f32 = 2.5;

/// The file's up axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpAxis {
    /// +Y up (glTF, most OBJ).
    Y,
    /// +Z up (Blender, 3ds Max, many photogrammetry exports): the file's -Y becomes +z (the front in Blender).
    Z,
}

/// The direction the person faces (in the file's coordinates once Y is up).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Facing {
    /// Toward +z (the source camera; glTF's convention for characters).
    PlusZ,
    /// Toward -z.
    MinusZ,
    /// Toward +x.
    PlusX,
    /// Toward -x.
    MinusX,
}

/// An `--up` or `--facing` value that names no axis ([`UpAxis`], [`Facing`]).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{what} {given:?}: use {expected}")]
pub struct BadAxis {
    /// `up axis` or `facing`.
    pub what: &'static str,
    /// The value given (lower case).
    pub given: String,
    /// The accepted values.
    pub expected: &'static str,
}

impl FromStr for UpAxis {
    type Err = BadAxis;
    fn from_str(s: &str) -> Result<Self, BadAxis> {
        match s.to_ascii_lowercase().as_str() {
            "y" | "+y" => Ok(Self::Y),
            "z" | "+z" => Ok(Self::Z),
            other => Err(BadAxis { what: "up axis", given: other.to_string(), expected: "y or z" }),
        }
    }
}

impl FromStr for Facing {
    type Err = BadAxis;
    fn from_str(s: &str) -> Result<Self, BadAxis> {
        match s.to_ascii_lowercase().as_str() {
            "+z" | "z" => Ok(Self::PlusZ),
            "-z" => Ok(Self::MinusZ),
            "+x" | "x" => Ok(Self::PlusX),
            "-x" => Ok(Self::MinusX),
            other => Err(BadAxis { what: "facing", given: other.to_string(), expected: "+z, -z, +x or -x" }),
        }
    }
}

impl std::fmt::Display for UpAxis {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Y => "y",
            Self::Z => "z",
        })
    }
}

impl std::fmt::Display for Facing {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::PlusZ => "+z",
            Self::MinusZ => "-z",
            Self::PlusX => "+x",
            Self::MinusX => "-x",
        })
    }
}

impl UpAxis {
    /// The rotation that makes this axis +Y.
    pub fn to_y_up(self) -> Quat {
        match self {
            Self::Y => Quat::IDENTITY,
            // (x, y, z) -> (x, z, -y).
            Self::Z => Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2),
        }
    }
}

impl Facing {
    /// The rotation about +Y that turns this direction into +z.
    pub fn to_plus_z(self) -> Quat {
        use std::f32::consts::{FRAC_PI_2, PI};
        match self {
            Self::PlusZ => Quat::IDENTITY,
            Self::MinusZ => Quat::from_rotation_y(PI),
            Self::PlusX => Quat::from_rotation_y(-FRAC_PI_2),
            Self::MinusX => Quat::from_rotation_y(FRAC_PI_2),
        }
    }

    fn of_axis(x_axis: bool, positive: bool) -> Self {
        match (x_axis, positive) {
            (true, true) => Self::PlusX,
            (true, false) => Self::MinusX,
            (false, true) => Self::PlusZ,
            (false, false) => Self::MinusZ,
        }
    }
}

/// How to turn a scan upright and toward the camera; `None` fields are detected.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ScanOrientation {
    /// `--up`; `None`: detected.
    pub up: Option<UpAxis>,
    /// `--facing`; `None`: detected.
    pub facing: Option<Facing>,
}

/// A scan in the body cube.
#[derive(Clone, Debug)]
pub struct Scan {
    /// The normalised textured mesh.
    pub mesh: TexturedMesh,
    /// The transform applied after the rotation (file units to body cube).
    pub normalization: Normalization,
    /// The orientation used (given or detected).
    pub up: UpAxis,
    /// The facing used (given or detected).
    pub facing: Facing,
    /// Whether the scan was scaled below height 1.8 to fit the body cube.
    pub fitted: bool,
}

/// Reads and normalises a scan with detected orientation ([`load_scan_with`]).
pub fn load_scan(path: &Path) -> Result<Scan, SynthError> {
    load_scan_with(path, &ScanOrientation::default())
}

/// Reads a scan, turns it upright and toward +z (given or detected orientation, logged), and normalises it.
/// Errors (each naming the file): unreadable/corrupt/truncated files, missing textures, empty meshes, NaN
/// vertices, absurd coordinates, and meshes far wider than a person (a floor plane or a second object).
pub fn load_scan_with(path: &Path, orientation: &ScanOrientation) -> Result<Scan, SynthError> {
    let mut m = read_mesh(path)?;
    orient_and_normalize(path, &mut m, orientation)
}

/// Rotates (see [`load_scan_with`]) and normalises a mesh in place; `path` labels errors and log lines.
pub fn orient_and_normalize(
    path: &Path,
    m: &mut TexturedMesh,
    orientation: &ScanOrientation,
) -> Result<Scan, SynthError> {
    let err = |message: String| SynthError::Scan { path: path.to_path_buf(), message };
    check_coordinates(path, m)?;
    let detected = detect_orientation(&used_points(m));
    let up = orientation.up.unwrap_or(detected.up);
    rotate(m, up.to_y_up());
    let facing = match orientation.facing {
        Some(f) => f,
        // Detect the facing on the upright mesh (with the up axis actually used).
        None if up == detected.up => detected.facing,
        None => detect_orientation(&used_points(m)).facing,
    };
    rotate(m, facing.to_plus_z());
    if orientation.up.is_none() || orientation.facing.is_none() {
        tracing::info!(
            "{}: {} up {} ({}), facing {} ({}); override with --up y|z and --facing +z|-z|+x|-x",
            path.display(),
            if orientation.up.is_none() { "detected" } else { "given" },
            up,
            detected.up_reason,
            facing,
            if orientation.facing.is_none() { detected.facing_reason.as_str() } else { "given" },
        );
    }
    let height = height_of(m);
    let normalization = normalize_scan(path, m)?;
    let fitted = normalization.scale * height < normalize::BODY_HEIGHT * 0.999;
    if !m.mesh.positions.iter().all(|p| p.is_finite()) {
        return Err(err("normalisation produced non-finite vertices".into()));
    }
    Ok(Scan { mesh: m.clone(), normalization, up, facing, fitted })
}

/// The y extent of the vertices triangles use.
fn height_of(m: &TexturedMesh) -> f32 {
    let (lo, hi) = used_points(m).iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), p| (a.min(p.y), b.max(p.y)));
    hi - lo
}

fn used_points(m: &TexturedMesh) -> Vec<Vec3> {
    let mut used = vec![false; m.mesh.positions.len()];
    for t in &m.mesh.triangles {
        for &i in t {
            if let Some(u) = used.get_mut(i as usize) {
                *u = true;
            }
        }
    }
    m.mesh.positions.iter().zip(&used).filter(|(_, &u)| u).map(|(p, _)| *p).collect()
}

fn check_coordinates(path: &Path, m: &TexturedMesh) -> Result<(), SynthError> {
    if let Some(p) = used_points(m).iter().find(|p| !p.is_finite() || p.abs().max_element() > MAX_ABS_COORDINATE) {
        return Err(SynthError::Scan {
            path: path.to_path_buf(),
            message: format!(
                "vertex {p} is far outside any plausible unit box (|coordinate| > {MAX_ABS_COORDINATE:e})"
            ),
        });
    }
    Ok(())
}

fn rotate(m: &mut TexturedMesh, q: Quat) {
    if q == Quat::IDENTITY {
        return;
    }
    for p in &mut m.mesh.positions {
        *p = q * *p;
    }
}

/// What [`detect_orientation`] found, with the evidence for the log.
#[derive(Clone, Debug, PartialEq)]
pub struct DetectedOrientation {
    /// The up axis.
    pub up: UpAxis,
    /// Why.
    pub up_reason: String,
    /// The facing (of the points once `up` is made +Y).
    pub facing: Facing,
    /// Why.
    pub facing_reason: String,
}

/// The height band (fractions of the height above the lowest vertex) where [`detect_orientation`] first reads the
/// facing axis: the pelvis, between the crotch and the waist of an adult.
pub const PELVIS_BAND: (f32, f32) = (0.45, 0.55);

/// How much wider than deep (5-95 % range of the vertices) the [`PELVIS_BAND`] must be for
/// [`detect_orientation`] to take its facing axis from it.
pub const PELVIS_RATIO: f32 = 1.15;

/// Detects a standing person's up axis and facing from their vertices (file coordinates).
///
/// - Up: the axis (Y or Z) along which the vertices spread most is the height (10-90 % percentile range: legs,
///   torso and head spread along it, a body is far less deep) when one spread is over 1.3 times the other.
///   Otherwise the other axis is a T-pose's arm span (detailed hands can hold many vertices): the height is the
///   axis whose vertex histogram is less mirror-symmetric (a body is left-right symmetric, head and feet differ).
/// - Facing axis: a person is wider across the body than deep, so they face along the narrower of x and z. Read
///   first at the pelvis ([`PELVIS_BAND`], 5-95 % percentile range of the vertices, when one width is at least
///   [`PELVIS_RATIO`] times the other): arms do not reach it, except hands hanging at the sides, which widen it
///   the right way. Otherwise at shoulder height (55-80 % of the height, arms included; when one is at least 1.2
///   times the other), else +z is kept. The shoulders alone are misled by arms held forward: on the ten
///   characters of `scripts/scan-check.sh`, written facing +z and facing +x, the shoulder rule found the axis of
///   3 of the 10 and the pelvis rule 9 (kyonshi, holding her sleeves forward at the waist, is the exception).
/// - Facing sign: toes point forward: the centroid of the lowest 3 % of the vertices (the feet) lies ahead of
///   the shins' (8-20 % of the height) by at least 1 % of the height; without that evidence (no feet, e.g. a bust)
///   the positive direction is kept.
pub fn detect_orientation(points: &[Vec3]) -> DetectedOrientation {
    // 10-90 % range of the coordinates: the arms of a T-pose are few vertices far out, the height is spread by
    // legs, torso and head, so this tells height from arm span where the extents do not.
    let spread = |axis: usize| {
        let mut v: Vec<f32> = points.iter().map(|p| p[axis]).filter(|v| v.is_finite()).collect();
        if v.is_empty() {
            return 0.0;
        }
        v.sort_by(f32::total_cmp);
        v[v.len() * 9 / 10] - v[v.len() / 10]
    };
    // Mirror asymmetry of the vertex histogram along an axis: about 0 across a body (left-right symmetric),
    // large along its height (feet and head differ).
    let asymmetry = |axis: usize| {
        const BINS: usize = 32;
        let (lo, hi) = points
            .iter()
            .map(|p| p[axis])
            .filter(|v| v.is_finite())
            .fold((f32::MAX, f32::MIN), |(a, b), v| (a.min(v), b.max(v)));
        if hi <= lo {
            return 0.0;
        }
        let mut h = [0usize; BINS];
        for v in points.iter().map(|p| p[axis]).filter(|v| v.is_finite()) {
            h[(((v - lo) / (hi - lo)) * BINS as f32).clamp(0.0, BINS as f32 - 1.0) as usize] += 1;
        }
        let total: usize = h.iter().sum();
        let diff: usize = (0..BINS / 2).map(|i| h[i].abs_diff(h[BINS - 1 - i])).sum();
        diff as f32 / total.max(1) as f32
    };
    let (sy, sz) = (spread(1), spread(2));
    let (up, up_reason) = if sz > 1.3 * sy {
        (UpAxis::Z, format!("the 10-90 % spread along z {sz:.3} is {:.1}x that along y", sz / sy.max(1e-12)))
    } else if sy > 1.3 * sz {
        (UpAxis::Y, format!("the 10-90 % spread along y {sy:.3} is {:.1}x that along z", sy / sz.max(1e-12)))
    } else {
        // Similar spreads: one of them is a T-pose's arm span, which is mirror-symmetric; the height is not.
        let (ay, az) = (asymmetry(1), asymmetry(2));
        let why = format!("similar spreads (y {sy:.3}, z {sz:.3}); mirror asymmetry y {ay:.2}, z {az:.2}");
        (if az > ay { UpAxis::Z } else { UpAxis::Y }, why)
    };
    let q = up.to_y_up();
    let up_pts: Vec<Vec3> = points.iter().map(|p| q * *p).collect();
    let (ymin, ymax) = up_pts.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), p| (a.min(p.y), b.max(p.y)));
    let h = ymax - ymin;
    let band = |from: f32, to: f32| up_pts.iter().filter(move |p| p.y >= ymin + from * h && p.y <= ymin + to * h);
    // 5-95 % range of one coordinate of the pelvis band's vertices.
    let pelvis_width = |axis: usize| {
        let mut v: Vec<f32> = band(PELVIS_BAND.0, PELVIS_BAND.1).map(|p| p[axis]).filter(|v| v.is_finite()).collect();
        if v.len() < 2 {
            return None;
        }
        v.sort_by(f32::total_cmp);
        Some(v[(v.len() - 1) * 19 / 20] - v[(v.len() - 1) / 20])
    };
    let (slo, shi) = band(0.55, 0.80)
        .fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(a, b), p| (a.min(*p), b.max(*p)));
    let (wx, wz) = (shi.x - slo.x, shi.z - slo.z);
    let pelvis = match (pelvis_width(0), pelvis_width(2)) {
        (Some(px), Some(pz)) if h > 0.0 && pz > PELVIS_RATIO * px => {
            Some((true, format!("pelvis {pz:.3} across z, {px:.3} along x")))
        }
        (Some(px), Some(pz)) if h > 0.0 && px > PELVIS_RATIO * pz => {
            Some((false, format!("pelvis {px:.3} across x, {pz:.3} along z")))
        }
        _ => None,
    };
    let (x_axis, axis_reason) = if let Some(found) = pelvis {
        found
    } else if !(h > 0.0 && wx.is_finite() && wz.is_finite()) {
        (false, "no shoulder band".to_string())
    } else if wz > 1.2 * wx {
        (true, format!("shoulders {wz:.3} across z, {wx:.3} along x"))
    } else if wx > 1.2 * wz {
        (false, format!("shoulders {wx:.3} across x, {wz:.3} along z"))
    } else {
        (false, format!("shoulders {wx:.3} x, {wz:.3} z: ambiguous, kept +z"))
    };
    let centroid = |it: &mut dyn Iterator<Item = &Vec3>| {
        let (s, n) = it.fold((Vec3::ZERO, 0usize), |(s, n), p| (s + *p, n + 1));
        (n > 0).then(|| s / n as f32)
    };
    let feet = centroid(&mut band(0.0, 0.03));
    let shins = centroid(&mut band(0.08, 0.20));
    let (positive, sign_reason) = match (feet, shins) {
        (Some(f), Some(s)) => {
            let d = if x_axis { f.x - s.x } else { f.z - s.z };
            if d.abs() >= 0.01 * h {
                (d > 0.0, format!("feet {:.1} % of the height ahead of the shins", 100.0 * d.abs() / h))
            } else {
                (true, "no clear toes, kept the positive direction".to_string())
            }
        }
        _ => (true, "no feet, kept the positive direction".to_string()),
    };
    DetectedOrientation {
        up,
        up_reason,
        facing: Facing::of_axis(x_axis, positive),
        facing_reason: format!("{axis_reason}; {sign_reason}"),
    }
}

/// Normalises an upright mesh in place: height 1.8 and xz centred like the reference, then z centred on the
/// occupied volume ([`normalize::centre_depth`]); a mesh wider than the body
/// cube at that height is scaled down until its xz radius is [`FIT_RADIUS`], with one warning. `path` labels
/// errors.
pub fn normalize_scan(path: &Path, m: &mut TexturedMesh) -> Result<Normalization, SynthError> {
    let err = |message: String| SynthError::Scan { path: path.to_path_buf(), message };
    check_coordinates(path, m)?;
    let pts = used_points(m);
    let mut n = normalize::compute(&pts).ok_or_else(|| err("the mesh has no height (all vertices at one y)".into()))?;
    if n.xz_radius > MAX_RADIUS_AT_BODY_HEIGHT {
        return Err(err(format!(
            "after scaling to height {} the mesh is {:.2} wide (xz radius {:.2} > {MAX_RADIUS_AT_BODY_HEIGHT}): far \
             wider than a person; remove floors or other objects, and check the up axis (--up y|z)",
            normalize::BODY_HEIGHT,
            2.0 * n.xz_radius,
            n.xz_radius
        )));
    }
    if n.xz_radius > 1.0 {
        let shrink = FIT_RADIUS / n.xz_radius;
        tracing::warn!(
            "{}: at height {} the mesh is {:.2} wide (a T-pose or wide character), more than the body cube holds: \
             scaled to height {:.2} to fit",
            path.display(),
            normalize::BODY_HEIGHT,
            2.0 * n.xz_radius,
            normalize::BODY_HEIGHT * shrink
        );
        n.scale *= shrink;
        n.xz_radius = FIT_RADIUS;
    }
    for p in &mut m.mesh.positions {
        *p = n.apply(*p);
    }
    let n = n.shifted_in_depth(normalize::centre_depth(&mut m.mesh));
    m.mesh.compute_normals();
    Ok(n)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stick person (feet forward along `front`) as points: legs, feet, torso, arms out (T-pose) or down.
    fn person(front: Vec3, t_pose: bool) -> Vec<Vec3> {
        let side = Vec3::Y.cross(front).normalize();
        let mut p = Vec::new();
        for i in 0..=100 {
            let y = i as f32 / 100.0 * 1.75;
            // Torso and legs: 0.35 wide across, 0.2 deep.
            for k in 0..8 {
                let a = k as f32 / 8.0 * std::f32::consts::TAU;
                p.push(Vec3::Y * y + side * (0.17 * a.cos()) + front * (0.1 * a.sin()));
            }
        }
        // Feet: 0.25 long, pointing forward.
        for i in 0..=20 {
            for s in [-0.1f32, 0.1] {
                p.push(side * s + front * (i as f32 / 20.0 * 0.25 - 0.05) + Vec3::Y * 0.02);
            }
        }
        // Arms, densely meshed (detailed hands): as many vertices as the torso.
        for i in 0..=400 {
            let t = i as f32 / 400.0 * 0.75;
            for s in [-1.0f32, 1.0] {
                p.push(if t_pose {
                    Vec3::Y * 1.4 + side * s * (0.17 + t)
                } else {
                    Vec3::Y * (1.4 - t) + side * s * 0.22
                });
            }
        }
        p
    }

    #[test]
    fn orientation_is_detected_for_every_up_and_facing() {
        let mut by_symmetry = 0;
        for t_pose in [false, true] {
            for (front, want) in [
                (Vec3::Z, Facing::PlusZ),
                (-Vec3::Z, Facing::MinusZ),
                (Vec3::X, Facing::PlusX),
                (-Vec3::X, Facing::MinusX),
            ] {
                let pts = person(front, t_pose);
                let d = detect_orientation(&pts);
                assert_eq!((d.up, d.facing), (UpAxis::Y, want), "{front} t-pose {t_pose}: {d:?}");
                // The same person in a Z-up file: (x, y, z) -> (x, -z, y) is Y-up's inverse.
                let z_up: Vec<Vec3> = pts.iter().map(|p| UpAxis::Z.to_y_up().inverse() * *p).collect();
                let d = detect_orientation(&z_up);
                assert_eq!((d.up, d.facing), (UpAxis::Z, want), "z-up {front} t-pose {t_pose}: {d:?}");
                by_symmetry += d.up_reason.contains("mirror") as usize;
                // Turning by the detected facing puts the front at +z.
                let turned = want.to_plus_z() * front;
                assert!((turned - Vec3::Z).length() < 1e-5, "{front} -> {turned}");
            }
        }
        // The T-pose facing along x in a Z-up file has similar spreads along y (arms) and z (height).
        assert!(by_symmetry >= 1);
    }

    #[test]
    fn arms_held_forward_do_not_turn_the_detected_facing() {
        // Arms bent forward at the chest, as game characters hold a weapon and people hold a phone: at shoulder
        // height the person is now deeper than wide (the old shoulder rule alone turned such a person by 90°), the
        // pelvis below is not.
        for (front, want) in [(Vec3::Z, Facing::PlusZ), (Vec3::X, Facing::PlusX), (-Vec3::X, Facing::MinusX)] {
            let side = Vec3::Y.cross(front).normalize();
            let mut pts = person(front, false);
            for i in 0..=400 {
                let t = i as f32 / 400.0 * 0.6;
                for s in [-1.0f32, 1.0] {
                    pts.push(Vec3::Y * 1.2 + side * s * 0.1 + front * t);
                }
            }
            let (lo, hi) = pts
                .iter()
                .filter(|p| p.y >= 0.55 * 1.75 && p.y <= 0.8 * 1.75)
                .fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(a, b), p| (a.min(*p), b.max(*p)));
            let (across, deep) = ((hi - lo).dot(side).abs(), (hi - lo).dot(front).abs());
            assert!(deep > 1.2 * across, "the stand-in must mislead the shoulders: {across} across, {deep} deep");
            let d = detect_orientation(&pts);
            assert_eq!(d.facing, want, "{front}: {d:?}");
            assert!(d.facing_reason.starts_with("pelvis"), "{}", d.facing_reason);
        }
    }

    #[test]
    fn options_parse_and_rotations_are_exact() {
        assert_eq!("Z".parse::<UpAxis>(), Ok(UpAxis::Z));
        assert_eq!("-x".parse::<Facing>(), Ok(Facing::MinusX));
        assert!("w".parse::<UpAxis>().is_err() && "up".parse::<Facing>().is_err());
        assert_eq!("W".parse::<UpAxis>().unwrap_err().to_string(), "up axis \"w\": use y or z");
        assert_eq!("up".parse::<Facing>().unwrap_err().to_string(), "facing \"up\": use +z, -z, +x or -x");
        // Z up: +Z becomes +Y and Blender's front (-Y) becomes +z.
        assert!((UpAxis::Z.to_y_up() * Vec3::Z - Vec3::Y).length() < 1e-6);
        assert!((UpAxis::Z.to_y_up() * -Vec3::Y - Vec3::Z).length() < 1e-6);
        for f in [Facing::PlusZ, Facing::MinusZ, Facing::PlusX, Facing::MinusX] {
            assert_eq!(f.to_string().parse::<Facing>(), Ok(f));
            assert!((f.to_plus_z() * Vec3::Y - Vec3::Y).length() < 1e-6, "rotations keep up");
        }
    }
}
