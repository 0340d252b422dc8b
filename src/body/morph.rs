//! MakeHuman macro morph targets (PyPI `makehuman` 1.3.2, `makehuman/data/targets.npz`, CC0) and the macro
//! modifier weights that blend them (gender, age, muscle, weight, height, proportions, ethnicity).
//!
//! Each target is a sparse displacement: `targets/<group>/<name>.index.npy` (u16 vertex indices into the full
//! base mesh) and `.vector.npy` (i16, shape (n, 3)). The i16 values are fixed point with
//! [`TARGET_SCALE`] decimetres per unit, MakeHuman's own loader scale (`/1000`); the test
//! `baby_target_scale_is_plausible` checks it against body height.

use std::collections::HashMap;
use std::io::Read;
use std::path::Path;

use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::BodyError;
use crate::io::npy::{NpyArray, NpyData};

/// Decimetres per i16 unit in `targets.npz`.
pub const TARGET_SCALE: f32 = 1.0 / 1000.0;

/// One sparse morph target.
#[derive(Clone, Debug, PartialEq)]
pub struct Target {
    /// Vertex indices into the full base mesh.
    pub indices: Vec<u16>,
    /// Displacements in fixed point (multiply by [`TARGET_SCALE`] for decimetres).
    pub deltas: Vec<[i16; 3]>,
}

/// The macro targets (`targets/macrodetails/...`), keyed by their path below `targets/macrodetails/` without
/// extension, e.g. `universal-female-young-averagemuscle-averageweight` or `height/male-old-...-maxheight`.
#[derive(Clone, Debug, Default)]
pub struct MorphLibrary {
    /// Targets by name.
    pub targets: HashMap<String, Target>,
}

impl MorphLibrary {
    /// Reads the macro targets from MakeHuman's `targets.npz`.
    pub fn load(npz: &Path) -> Result<Self, BodyError> {
        let err = |m: String| BodyError::Asset { what: npz.display().to_string(), message: m };
        let file = std::fs::File::open(npz)
            .map_err(|e| err(format!("{e}; install it with `bash scripts/setup.d/synth.sh` (PyPI makehuman 1.3.2)")))?;
        let mut zip = zip::ZipArchive::new(std::io::BufReader::new(file)).map_err(|e| err(e.to_string()))?;
        type Halves = (Option<Vec<u16>>, Option<Vec<[i16; 3]>>);
        let mut raw: HashMap<String, Halves> = HashMap::new();
        for i in 0..zip.len() {
            let mut entry = zip.by_index(i).map_err(|e| err(e.to_string()))?;
            let name = entry.name().to_string();
            let Some(rest) = name.strip_prefix("targets/macrodetails/") else { continue };
            let (stem, kind) = if let Some(s) = rest.strip_suffix(".index.npy") {
                (s, 0)
            } else if let Some(s) = rest.strip_suffix(".vector.npy") {
                (s, 1)
            } else {
                continue;
            };
            let mut bytes = Vec::with_capacity(entry.size() as usize);
            entry.read_to_end(&mut bytes).map_err(|e| err(format!("{name}: {e}")))?;
            let arr = NpyArray::from_bytes(&bytes).map_err(|e| err(format!("{name}: {e}")))?;
            let slot = raw.entry(stem.to_string()).or_default();
            match (kind, arr.data) {
                (0, NpyData::U16(v)) => slot.0 = Some(v),
                (1, NpyData::I16(v)) if arr.shape.len() == 2 && arr.shape[1] == 3 => {
                    slot.1 = Some(v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
                }
                _ => return Err(err(format!("{name}: unexpected dtype or shape {:?}", arr.shape))),
            }
        }
        let mut targets = HashMap::new();
        for (stem, (idx, vec)) in raw {
            let (Some(indices), Some(deltas)) = (idx, vec) else {
                return Err(err(format!("target {stem} lacks its index or vector array")));
            };
            if indices.len() != deltas.len() {
                return Err(err(format!("target {stem}: {} indices but {} vectors", indices.len(), deltas.len())));
            }
            if indices.iter().any(|&i| i as usize >= super::base::FULL_VERTEX_COUNT) {
                return Err(err(format!("target {stem} indexes past the base mesh")));
            }
            targets.insert(stem, Target { indices, deltas });
        }
        if targets.is_empty() {
            return Err(err("no targets/macrodetails/ arrays found".into()));
        }
        Ok(Self { targets })
    }

    /// Adds `weight` times the named target to `positions` (decimetres). Unknown names are an error.
    pub fn apply(&self, name: &str, weight: f32, positions: &mut [Vec3]) -> Result<(), BodyError> {
        let t = self.targets.get(name).ok_or_else(|| BodyError::Asset {
            what: "targets.npz".into(),
            message: format!("macro target {name:?} is missing"),
        })?;
        let s = weight * TARGET_SCALE;
        for (&i, d) in t.indices.iter().zip(&t.deltas) {
            if let Some(p) = positions.get_mut(i as usize) {
                *p += s * Vec3::new(d[0] as f32, d[1] as f32, d[2] as f32);
            }
        }
        Ok(())
    }

    /// Applies every macro target with the weights of `m` (see [`MacroParams::target_weights`]). Targets absent
    /// from the library that MakeHuman does not ship either (proportions for babies) are skipped.
    pub fn apply_macros(&self, m: &MacroParams, positions: &mut [Vec3]) -> Result<(), BodyError> {
        for (name, w) in m.target_weights() {
            if w.abs() < 1e-6 {
                continue;
            }
            if name.starts_with("proportions/") && !self.targets.contains_key(&name) {
                continue;
            }
            self.apply(&name, w, positions)?;
        }
        Ok(())
    }
}

/// MakeHuman macro modifier values, each in `[0, 1]` (MakeHuman's slider scale; 0.5 is neutral).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MacroParams {
    /// 0 female, 1 male.
    pub gender: f32,
    /// 0 = 1 year, 0.1875 = 11 years, 0.5 = 25 years, 1 = 90 years.
    pub age: f32,
    /// Muscle tone: 0 min, 0.5 average, 1 max.
    pub muscle: f32,
    /// Body mass: 0 min, 0.5 average, 1 max.
    pub weight: f32,
    /// Height: 0 min, 0.5 neutral, 1 max.
    pub height: f32,
    /// Body proportions: 0 uncommon, 0.5 neutral, 1 ideal.
    pub proportions: f32,
    /// Ethnic blend weights (African, Asian, Caucasian), normalised to sum 1.
    pub ethnicity: [f32; 3],
}

impl Default for MacroParams {
    fn default() -> Self {
        Self {
            gender: 0.5,
            age: 0.5,
            muscle: 0.5,
            weight: 0.5,
            height: 0.5,
            proportions: 0.5,
            ethnicity: [1.0 / 3.0; 3],
        }
    }
}

/// Piecewise-linear weights of a three-valued macro (`min`, `average`, `max`) at slider value `v`.
pub fn three_way(v: f32) -> [f32; 3] {
    let v = v.clamp(0.0, 1.0);
    let lo = (1.0 - 2.0 * v).max(0.0);
    let hi = (2.0 * v - 1.0).max(0.0);
    [lo, 1.0 - lo - hi, hi]
}

/// MakeHuman's age weights (baby, child, young, old) at slider value `a` (ages 1, 11, 25, 90 at 0, 0.1875,
/// 0.5, 1).
pub fn age_weights(a: f32) -> [f32; 4] {
    let a = a.clamp(0.0, 1.0);
    if a < 0.5 {
        let baby = (1.0 - a / 0.1875).max(0.0);
        let young = ((a - 0.1875) / (0.5 - 0.1875)).max(0.0);
        let child = (a / 0.1875).min(1.0) - young;
        [baby, child, young, 0.0]
    } else {
        let old = 2.0 * a - 1.0;
        [0.0, 0.0, 1.0 - old, old]
    }
}

impl MacroParams {
    /// Clamps every value into `[0, 1]` and normalises the ethnic weights (uniform if they sum to 0 or NaN).
    pub fn sanitized(mut self) -> Self {
        for v in [
            &mut self.gender,
            &mut self.age,
            &mut self.muscle,
            &mut self.weight,
            &mut self.height,
            &mut self.proportions,
        ] {
            *v = if v.is_finite() { v.clamp(0.0, 1.0) } else { 0.5 };
        }
        let e = self.ethnicity.map(|x| if x.is_finite() { x.max(0.0) } else { 0.0 });
        let s: f32 = e.iter().sum();
        self.ethnicity = if s > 1e-6 { e.map(|x| x / s) } else { [1.0 / 3.0; 3] };
        self
    }

    /// The macro targets and their weights, exactly as MakeHuman's macro modifiers combine them:
    /// `<race>-<gender>-<age>` (race x gender x age), `universal-<gender>-<age>-<muscle>-<weight>`
    /// (gender x age x muscle x weight), `height/...-<min|max>height` and `proportions/...-<ideal|uncommon>
    /// proportions` (the universal weight times the height or proportion weight).
    pub fn target_weights(&self) -> Vec<(String, f32)> {
        let m = self.sanitized();
        let genders = [("female", 1.0 - m.gender), ("male", m.gender)];
        let aw = age_weights(m.age);
        let ages = [("baby", aw[0]), ("child", aw[1]), ("young", aw[2]), ("old", aw[3])];
        let mw = three_way(m.muscle);
        let muscles = [("minmuscle", mw[0]), ("averagemuscle", mw[1]), ("maxmuscle", mw[2])];
        let ww = three_way(m.weight);
        let weights = [("minweight", ww[0]), ("averageweight", ww[1]), ("maxweight", ww[2])];
        let hw = three_way(m.height);
        let heights = [("minheight", hw[0]), ("maxheight", hw[2])];
        let pw = three_way(m.proportions);
        let props = [("uncommonproportions", pw[0]), ("idealproportions", pw[2])];
        let races = [("african", m.ethnicity[0]), ("asian", m.ethnicity[1]), ("caucasian", m.ethnicity[2])];
        let mut out = Vec::new();
        for (g, gw) in genders {
            for (a, agw) in ages {
                for (r, rw) in races {
                    out.push((format!("{r}-{g}-{a}"), rw * gw * agw));
                }
                for (mu, muw) in muscles {
                    for (we, wew) in weights {
                        let base = gw * agw * muw * wew;
                        out.push((format!("universal-{g}-{a}-{mu}-{we}"), base));
                        for (h, hw) in heights {
                            out.push((format!("height/{g}-{a}-{mu}-{we}-{h}"), base * hw));
                        }
                        for (p, pw) in props {
                            out.push((format!("proportions/{g}-{a}-{mu}-{we}-{p}"), base * pw));
                        }
                    }
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn macro_weights_partition_unity() {
        for v in [0.0f32, 0.1, 0.5, 0.77, 1.0] {
            let t = three_way(v);
            assert!((t.iter().sum::<f32>() - 1.0).abs() < 1e-6 && t.iter().all(|&x| x >= 0.0));
        }
        assert_eq!(three_way(0.5), [0.0, 1.0, 0.0]);
        assert_eq!(three_way(0.0), [1.0, 0.0, 0.0]);
        assert_eq!(three_way(0.75), [0.0, 0.5, 0.5]);
        for a in [0.0f32, 0.1, 0.1875, 0.3, 0.5, 0.6, 1.0] {
            let w = age_weights(a);
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-5, "{a}: {w:?}");
            assert!(w.iter().all(|&x| x >= -1e-6));
        }
        assert_eq!(age_weights(0.1875), [0.0, 1.0, 0.0, 0.0]);
        assert_eq!(age_weights(0.5), [0.0, 0.0, 1.0, 0.0]);
        assert_eq!(age_weights(1.0), [0.0, 0.0, 0.0, 1.0]);
    }

    #[test]
    fn target_weights_sum_like_makehuman() {
        let m = MacroParams {
            gender: 0.3,
            age: 0.7,
            muscle: 0.2,
            weight: 0.9,
            height: 0.8,
            proportions: 0.1,
            ethnicity: [1.0, 2.0, 1.0],
        };
        let w = m.target_weights();
        let sum = |pre: &str| w.iter().filter(|(n, _)| n.starts_with(pre)).map(|(_, x)| x).sum::<f32>();
        // The ethnic and the universal families each blend to 1; height and proportions to their own weight.
        assert!((sum("universal-") - 1.0).abs() < 1e-5);
        let race: f32 = w
            .iter()
            .filter(|(n, _)| n.starts_with("african") || n.starts_with("asian") || n.starts_with("caucasian"))
            .map(|(_, x)| x)
            .sum();
        assert!((race - 1.0).abs() < 1e-5);
        assert!((sum("height/") - three_way(0.8)[2]).abs() < 1e-5);
        assert!((sum("proportions/") - three_way(0.1)[0]).abs() < 1e-5);
        let asian: f32 = w.iter().filter(|(n, _)| n.starts_with("asian")).map(|(_, x)| x).sum();
        assert!((asian - 0.5).abs() < 1e-5);
    }

    #[test]
    fn zero_weight_morph_is_identity() {
        let mut lib = MorphLibrary::default();
        lib.targets.insert("t".into(), Target { indices: vec![0, 2], deltas: vec![[1000, -2000, 500], [7, 7, 7]] });
        let mut p = vec![Vec3::ONE; 3];
        lib.apply("t", 0.0, &mut p).unwrap();
        assert_eq!(p, vec![Vec3::ONE; 3]);
        lib.apply("t", 0.5, &mut p).unwrap();
        assert!((p[0] - Vec3::new(1.5, 0.0, 1.25)).abs().max_element() < 1e-6);
        assert_eq!(p[1], Vec3::ONE);
        assert!(lib.apply("missing", 1.0, &mut p).is_err());
    }
}
