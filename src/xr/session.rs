//! The OpenXR session: instance and system, the Vulkan device the runtime asks for, one swapchain per eye, the
//! session state machine, controller actions and the frame loop (wait, begin, locate views, upload, end).
//!
//! The person is rendered on the GPU by a separate thread ([`super::pacing`], [`super::eyes`]); the frame loop
//! copies the newest finished eye images into the swapchains on the GPU ([`EyeUploader`]) and never waits for a
//! render. The renderer and the OpenXR session share one Vulkan queue when the device has only one (lavapipe):
//! every use of it is serialised by [`crate::gpu::Context::lock_queue_at`], and the time the frame loop spends waiting for
//! that lock is measured and reported. Every way a session can end — the frame budget, the runtime asking
//! to exit, session loss, instance loss, the runtime process going away — ends the loop cleanly with an
//! [`EndReason`]; only setup failures are errors.

use std::fmt;
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::{Quat, Vec2, Vec3};
use openxr as xr;
use xr::sys::Handle as _;

use super::check::{blend_mode_name, extension_names};
use super::device::{create_device, renderer_shares_queue, SESSION_QUEUE};
use super::diag::{ValidationLog, XrMessenger};
use super::eyes::{CpuEyes, GpuEyes, NeuralEyeStats, SceneFeed};
use super::pacing::{EyeRenderer, EyeView, PacingStats, RenderMailbox, RenderRequest, RenderedEyes};
use super::placement::{Controls, Placement, DEFAULT_DISTANCE};
use super::swapchain::{format_name, EyeSwapchain, EyeUploader, SwapchainFormat};
use super::{load_entry, XrContext, XrError};
use crate::buffer::RgbaImage;
use crate::capture::stats::{DurationHistogram, StageSummary};
use crate::compose::Mode;
use crate::geometry::camera::{Camera, Fov};
use crate::gpu::{self, backend::Backend};
use crate::io::environment::Environment;
use crate::window::mirror::{Mirror, MirrorEventLoop, DEVICE_EXTENSIONS};

const VIEW_TYPE: xr::ViewConfigurationType = xr::ViewConfigurationType::PRIMARY_STEREO;

/// Writes the person the session shows as a file (the export action: a controller button, the mirror window's `E`
/// key, or [`SessionConfig::export_at_frames`]). The app layer implements it (glTF through
/// [`crate::pipeline::export`]); the session calls it on a thread of its own, one export at a time, so the display
/// loop never waits for it.
pub trait PersonExporter: Send + Sync {
    /// Writes the person shown now; `frame` is the number of frames that have shown the person so far (it names
    /// the file). Returns the file written, or why nothing was written.
    fn export(&self, frame: u64) -> Result<std::path::PathBuf, ExportFailure>;
}

/// Why an export of the person wrote nothing.
#[derive(Debug, thiserror::Error)]
pub enum ExportFailure {
    /// No person has been shown yet (a live source before its first frame).
    #[error("no person has been reconstructed yet: wait for the first frame")]
    NothingShown,
    /// Writing the file failed.
    #[error("{}: {source}", .path.display())]
    Write {
        /// The file that was to be written.
        path: std::path::PathBuf,
        /// Why.
        #[source]
        source: crate::pipeline::export::ExportError,
    },
}

/// The exporter a session calls (see [`PersonExporter`]).
#[derive(Clone)]
pub struct ExportHook(pub Arc<dyn PersonExporter>);

impl fmt::Debug for ExportHook {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("ExportHook")
    }
}

/// How the session is run.
#[derive(Clone, Debug)]
pub struct SessionConfig {
    /// VR or AR.
    pub mode: Mode,
    /// Request exit after this many frames showing the person (`None`: run until the runtime ends the session).
    pub max_person_frames: Option<u64>,
    /// Request exit after this much time in the session loop (a safety net for unattended runs).
    pub max_duration: Option<Duration>,
    /// Largest eye image side in pixels; the runtime's recommended size is scaled down to fit (a software Vulkan
    /// device cannot fill full headset resolution at display rate).
    pub eye_max_side: u32,
    /// Read every fresh eye image back from the swapchain and keep the last pair (tests).
    pub capture: bool,
    /// Show the eye images side by side in a desktop window while the session runs (skipped with a warning when
    /// there is no display).
    pub mirror: bool,
    /// What the export action does (`None`: the action only logs that exporting is off).
    pub export: Option<ExportHook>,
    /// Also export when this many frames have shown the person (scripted captures, tests without a controller).
    pub export_at_frames: Vec<u64>,
    /// Which engine renders the eyes ([`Backend::resolve`] on the session's device: the CPU reference on a software
    /// rasteriser under `Auto`).
    pub backend: Backend,
}

impl Default for SessionConfig {
    fn default() -> Self {
        Self {
            mode: Mode::Vr,
            max_person_frames: None,
            max_duration: None,
            eye_max_side: 512,
            capture: false,
            mirror: false,
            export: None,
            export_at_frames: Vec::new(),
            backend: Backend::Auto,
        }
    }
}

/// The environment blend mode chosen for a mode, and how AR is achieved.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BlendChoice {
    /// The blend mode submitted with every frame.
    pub blend: xr::EnvironmentBlendMode,
    /// Submit an XR_FB_passthrough layer under the person.
    pub passthrough_fb: bool,
    /// A notice for the user when the requested mode cannot be honoured fully.
    pub notice: Option<String>,
}

/// Picks the blend mode: VR wants OPAQUE; AR wants ALPHA_BLEND, then ADDITIVE, then XR_FB_passthrough over
/// OPAQUE, and finally plain OPAQUE with a notice (the person over black). `offered` is in the runtime's order of
/// preference; an empty list is treated as OPAQUE (every runtime must support some mode).
pub fn choose_blend(mode: Mode, offered: &[xr::EnvironmentBlendMode], fb_passthrough: bool) -> BlendChoice {
    use xr::EnvironmentBlendMode as B;
    let has = |m: B| offered.contains(&m);
    let first = offered.first().copied().unwrap_or(B::OPAQUE);
    match mode {
        Mode::Vr if has(B::OPAQUE) || offered.is_empty() => {
            BlendChoice { blend: B::OPAQUE, passthrough_fb: false, notice: None }
        }
        Mode::Vr => BlendChoice {
            blend: first,
            passthrough_fb: false,
            notice: Some(format!(
                "the runtime offers no OPAQUE blend mode: VR is shown with {}",
                blend_mode_name(first)
            )),
        },
        Mode::Ar if has(B::ALPHA_BLEND) => BlendChoice { blend: B::ALPHA_BLEND, passthrough_fb: false, notice: None },
        Mode::Ar if has(B::ADDITIVE) => BlendChoice { blend: B::ADDITIVE, passthrough_fb: false, notice: None },
        Mode::Ar if fb_passthrough => BlendChoice {
            blend: if has(B::OPAQUE) || offered.is_empty() { B::OPAQUE } else { first },
            passthrough_fb: true,
            notice: None,
        },
        Mode::Ar => BlendChoice {
            blend: if has(B::OPAQUE) || offered.is_empty() { B::OPAQUE } else { first },
            passthrough_fb: false,
            notice: Some(
                "AR: the runtime offers neither a see-through blend mode (ALPHA_BLEND, ADDITIVE) nor \
                 XR_FB_passthrough, so the person is shown over black (OPAQUE)"
                    .into(),
            ),
        },
    }
}

/// What the application must do after a session state change.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StateCommand {
    /// Nothing.
    None,
    /// Call `xrBeginSession` (READY).
    Begin,
    /// Call `xrEndSession` (STOPPING).
    End,
    /// Leave the loop and destroy the session (EXITING or LOSS_PENDING).
    Exit,
}

/// The session lifecycle: IDLE -> READY -> SYNCHRONIZED -> VISIBLE -> FOCUSED and back down through STOPPING to
/// IDLE, then EXITING (or LOSS_PENDING from any state).
#[derive(Clone, Debug, Default)]
pub struct SessionStateMachine {
    /// Current state (UNKNOWN before the first event).
    pub state: xr::SessionState,
    /// Between `xrBeginSession` and `xrEndSession`: the frame loop runs.
    pub running: bool,
    /// Every state entered, in order.
    pub history: Vec<xr::SessionState>,
}

impl SessionStateMachine {
    /// Records a state change and says what to do.
    pub fn on_state(&mut self, state: xr::SessionState) -> StateCommand {
        self.state = state;
        self.history.push(state);
        match state {
            xr::SessionState::READY => {
                self.running = true;
                StateCommand::Begin
            }
            xr::SessionState::STOPPING => {
                self.running = false;
                StateCommand::End
            }
            xr::SessionState::EXITING | xr::SessionState::LOSS_PENDING => StateCommand::Exit,
            _ => StateCommand::None,
        }
    }

    /// Controller input is read only while focused; it pauses (reads as zero) otherwise.
    pub fn input_enabled(&self) -> bool {
        self.state == xr::SessionState::FOCUSED
    }

    /// The person is worth rendering only while the session is visible.
    pub fn visible(&self) -> bool {
        matches!(self.state, xr::SessionState::VISIBLE | xr::SessionState::FOCUSED)
    }

    /// Was this state ever entered?
    pub fn reached(&self, state: xr::SessionState) -> bool {
        self.history.contains(&state)
    }
}

/// Why the session ended.
#[derive(Clone, Debug, PartialEq)]
pub enum EndReason {
    /// The frame budget was reached; the runtime confirmed the exit.
    FrameLimit,
    /// The time budget was reached; the runtime confirmed the exit.
    TimeLimit,
    /// The runtime asked the application to exit (EXITING without a request).
    RuntimeExit,
    /// The session was lost (LOSS_PENDING), e.g. the headset was unplugged.
    SessionLoss,
    /// The runtime announced instance loss (XrEventDataInstanceLossPending).
    InstanceLoss,
    /// An OpenXR or Vulkan call failed mid-session (the runtime went away).
    RuntimeGone(String),
    /// The person renderer failed.
    RenderFailed(String),
}

impl fmt::Display for EndReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            EndReason::FrameLimit => write!(f, "frame budget reached"),
            EndReason::TimeLimit => write!(f, "time budget reached"),
            EndReason::RuntimeExit => write!(f, "the runtime ended the session"),
            EndReason::SessionLoss => write!(f, "the session was lost (headset gone?)"),
            EndReason::InstanceLoss => write!(f, "the OpenXR runtime announced instance loss"),
            EndReason::RuntimeGone(e) => write!(f, "the OpenXR runtime went away ({e})"),
            EndReason::RenderFailed(e) => write!(f, "rendering failed: {e}"),
        }
    }
}

/// One eye image read back from the swapchain, with the cameras it was rendered for.
#[derive(Clone, Debug)]
pub struct EyeCapture {
    /// Eye index.
    pub eye: usize,
    /// Decoded image (linear premultiplied RGBA).
    pub image: RgbaImage,
    /// The eye camera in body-cube coordinates.
    pub body_camera: Camera,
    /// The eye pose in the reference space.
    pub view: EyeView,
    /// The placement the image was rendered with.
    pub placement: Placement,
}

/// What happened in a session.
#[derive(Clone, Debug)]
pub struct SessionReport {
    /// Runtime name and version.
    pub runtime: String,
    /// System (headset) name.
    pub system: String,
    /// Vulkan device name.
    pub vulkan_device: String,
    /// Blend mode used and how AR was done.
    pub blend: BlendChoice,
    /// "STAGE" or "LOCAL".
    pub reference_space: String,
    /// Swapchain format name.
    pub swapchain_format: String,
    /// Eye image size.
    pub eye_size: (u32, u32),
    /// Every session state entered, in order.
    pub states: Vec<xr::SessionState>,
    /// Time from session creation to FOCUSED.
    pub time_to_focused: Option<Duration>,
    /// Frames submitted (`xrEndFrame` calls).
    pub frames_submitted: u64,
    /// Pacing of the person layer.
    pub pacing: PacingStats,
    /// Median per-eye render time (ms; the CPU eyes draw a pair at once: its wall time divided between the eyes).
    pub eye_render_ms: Option<f64>,
    /// Number of eye renders.
    pub eye_renders: usize,
    /// Median time of each stage of an eye render on the CPU reference (empty for the Vulkan passes, whose stage
    /// times the GPU benchmark reads from timestamps).
    pub eye_stages: Vec<StageSummary>,
    /// Times new content (a new input frame) was uploaded to the renderer.
    pub scene_uploads: u64,
    /// Messages about the input (a live source that ended, a corrupt frame); the session went on.
    pub source_messages: Vec<String>,
    /// The renderer submits to the OpenXR session's queue (the device has one queue).
    pub renderer_shares_queue: bool,
    /// Where the eyes were rendered and how they reached the swapchains.
    pub render_path: String,
    /// Which renderer drew the person: "geometric (GPU)" or the neural renderer's summary (eye images, decoder
    /// runs and times, reuses, fallbacks).
    pub person_renderer: String,
    /// What the neural renderer did for the eyes (all zero with the geometric renderer).
    pub neural: NeuralEyeStats,
    /// Time the frame loop waited for the shared queue per frame (ms): median and maximum.
    pub queue_wait_ms: (Option<f64>, f64),
    /// Time between consecutive submitted frames: the display loop's frame times (fixed memory).
    pub frame_intervals: DurationHistogram,
    /// Submitted frames per second while running.
    pub display_fps: f64,
    /// How the session ended.
    pub end: EndReason,
    /// OpenXR validation warnings/errors (XR_EXT_debug_utils; the core validation layer reports here).
    pub xr_messages: Vec<String>,
    /// Their count.
    pub xr_message_count: usize,
    /// Vulkan validation warnings/errors (VK_EXT_debug_utils).
    pub vk_messages: Vec<String>,
    /// Their count.
    pub vk_message_count: usize,
    /// The last fresh eye images read back from the swapchain (with `capture`).
    pub captures: Vec<EyeCapture>,
    /// The final placement of the person.
    pub placement: Option<Placement>,
    /// Images shown in the desktop mirror window (0 without a mirror).
    pub mirror_presented: u64,
    /// Files written by the export action, in order.
    pub exports: Vec<std::path::PathBuf>,
    /// Export requests that wrote nothing, each with the reason (a failure, or an export still being written).
    pub export_failures: Vec<String>,
}

impl SessionReport {
    /// Did the session reach a state?
    pub fn reached(&self, state: xr::SessionState) -> bool {
        self.states.contains(&state)
    }
}

impl fmt::Display for SessionReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "runtime: {}; system: {}; Vulkan device: {}", self.runtime, self.system, self.vulkan_device)?;
        writeln!(
            f,
            "blend mode: {}{}; reference space: {}; eye images {}x{} {}",
            blend_mode_name(self.blend.blend),
            if self.blend.passthrough_fb { " + XR_FB_passthrough" } else { "" },
            self.reference_space,
            self.eye_size.0,
            self.eye_size.1,
            self.swapchain_format
        )?;
        if let Some(n) = &self.blend.notice {
            writeln!(f, "notice: {n}")?;
        }
        let states: Vec<String> = self.states.iter().map(|s| format!("{s:?}")).collect();
        writeln!(f, "session states: {}", states.join(" -> "))?;
        writeln!(
            f,
            "frames submitted: {} ({:.1} per second), with the person: {}, fresh renders: {:.0}%",
            self.frames_submitted,
            self.display_fps,
            self.pacing.person_frames,
            100.0 * self.pacing.fresh_share()
        )?;
        match self.pacing.median_latency_ms() {
            Some(ms) => writeln!(f, "motion-to-photon latency of the person layer (median): {ms:.1} ms")?,
            None => writeln!(f, "motion-to-photon latency: not measured (runtime lacks XR_KHR_convert_timespec_time)")?,
        }
        if let Some(ms) = self.eye_render_ms {
            writeln!(f, "per-eye render time (median of {}): {ms:.1} ms", self.eye_renders)?;
        }
        if !self.eye_stages.is_empty() {
            let parts: Vec<String> =
                self.eye_stages.iter().map(|s| format!("{} {:.1}", s.name, s.median_ms())).collect();
            writeln!(f, "eye stages (median ms): {}", parts.join(", "))?;
        }
        writeln!(f, "eyes rendered on {}", self.render_path)?;
        writeln!(f, "person renderer: {}", self.person_renderer)?;
        if let Some(ms) = self.queue_wait_ms.0 {
            writeln!(
                f,
                "frame loop wait for the session queue lock per frame: median {ms:.2} ms, max {:.1} ms",
                self.queue_wait_ms.1
            )?;
        }
        let h = &self.frame_intervals;
        if h.count() > 0 {
            writeln!(f, "frame interval (ms) over {} intervals: {}", h.count(), h.summary())?;
        }
        if self.scene_uploads > 1 {
            writeln!(f, "input frames uploaded to the GPU: {}", self.scene_uploads)?;
        }
        for m in &self.source_messages {
            writeln!(f, "input: {m}")?;
        }
        if self.mirror_presented > 0 {
            writeln!(f, "desktop mirror: {} images shown", self.mirror_presented)?;
        }
        for p in &self.exports {
            writeln!(f, "exported the person: {}", p.display())?;
        }
        for e in &self.export_failures {
            writeln!(f, "export: {e}")?;
        }
        writeln!(f, "validation messages: OpenXR {}, Vulkan {}", self.xr_message_count, self.vk_message_count)?;
        write!(f, "session ended: {}", self.end)
    }
}

/// Controller actions: move, turn/scale, recentre, export.
struct Controllers {
    set: xr::ActionSet,
    move_xz: xr::Action<xr::Vector2f>,
    turn_scale: xr::Action<xr::Vector2f>,
    recentre: xr::Action<bool>,
    export: xr::Action<bool>,
}

/// Which action a binding drives.
#[derive(Clone, Copy)]
enum Act {
    Move,
    TurnScale,
    Recentre,
    Export,
}

/// Bindings for common controllers (profile, [(input path, action)]): the left thumbstick moves the person, the
/// right one turns (x) and scales (y) it, right A (select on the simple controller's right hand) recentres it, and
/// right B (select on its left hand) writes it as glTF.
const BINDINGS: [(&str, &[(&str, Act)]); 3] = [
    (
        "/interaction_profiles/khr/simple_controller",
        &[("/user/hand/right/input/select/click", Act::Recentre), ("/user/hand/left/input/select/click", Act::Export)],
    ),
    (
        "/interaction_profiles/oculus/touch_controller",
        &[
            ("/user/hand/left/input/thumbstick", Act::Move),
            ("/user/hand/right/input/thumbstick", Act::TurnScale),
            ("/user/hand/right/input/a/click", Act::Recentre),
            ("/user/hand/right/input/b/click", Act::Export),
        ],
    ),
    (
        "/interaction_profiles/valve/index_controller",
        &[
            ("/user/hand/left/input/thumbstick", Act::Move),
            ("/user/hand/right/input/thumbstick", Act::TurnScale),
            ("/user/hand/right/input/a/click", Act::Recentre),
            ("/user/hand/right/input/b/click", Act::Export),
        ],
    ),
];

impl Controllers {
    fn new(instance: &xr::Instance) -> Result<Self, XrError> {
        let set = instance.create_action_set("r2human", "r2human person placement", 0).xr("xrCreateActionSet")?;
        let move_xz = set.create_action::<xr::Vector2f>("move", "Move the person", &[]).xr("xrCreateAction")?;
        let turn_scale =
            set.create_action::<xr::Vector2f>("turn_scale", "Turn and scale the person", &[]).xr("xrCreateAction")?;
        let recentre = set.create_action::<bool>("recentre", "Recentre the person", &[]).xr("xrCreateAction")?;
        let export = set.create_action::<bool>("export", "Write the person as glTF", &[]).xr("xrCreateAction")?;
        let c = Self { set, move_xz, turn_scale, recentre, export };
        // A profile the runtime does not know is skipped with a log line.
        for (profile, bindings) in BINDINGS {
            let result = (|| -> Result<(), xr::sys::Result> {
                let mut list = Vec::new();
                for &(path, act) in bindings {
                    let p = instance.string_to_path(path)?;
                    list.push(match act {
                        Act::Move => xr::Binding::new(&c.move_xz, p),
                        Act::TurnScale => xr::Binding::new(&c.turn_scale, p),
                        Act::Recentre => xr::Binding::new(&c.recentre, p),
                        Act::Export => xr::Binding::new(&c.export, p),
                    });
                }
                instance.suggest_interaction_profile_bindings(instance.string_to_path(profile)?, &list)
            })();
            if let Err(e) = result {
                tracing::info!("controller profile {profile} not used: {e}");
            }
        }
        Ok(c)
    }

    /// Reads the controls (call only while focused, after `xrSyncActions`): the placement controls, and whether
    /// the export button went down since the last sync.
    fn read(&self, session: &xr::Session<xr::Vulkan>) -> (Controls, bool) {
        let v2 = |a: &xr::Action<xr::Vector2f>| {
            a.state(session, xr::Path::NULL)
                .ok()
                .filter(|s| s.is_active)
                .map(|s| Vec2::new(s.current_state.x, s.current_state.y))
                .unwrap_or(Vec2::ZERO)
        };
        let pressed = |a: &xr::Action<bool>| {
            a.state(session, xr::Path::NULL)
                .ok()
                .is_some_and(|s| s.is_active && s.current_state && s.changed_since_last_sync)
        };
        let ts = v2(&self.turn_scale);
        let controls =
            Controls { move_xz: v2(&self.move_xz), turn: -ts.x, scale: ts.y, recentre: pressed(&self.recentre) };
        (controls, pressed(&self.export))
    }
}

fn to_view(v: &xr::View) -> EyeView {
    let p = v.pose.position;
    let o = v.pose.orientation;
    EyeView {
        position: Vec3::new(p.x, p.y, p.z),
        orientation: Quat::from_xyzw(o.x, o.y, o.z, o.w).normalize(),
        fov: Fov {
            angle_left: v.fov.angle_left,
            angle_right: v.fov.angle_right,
            angle_up: v.fov.angle_up,
            angle_down: v.fov.angle_down,
        },
    }
}

fn to_posef(v: &EyeView) -> xr::Posef {
    xr::Posef {
        orientation: xr::Quaternionf { x: v.orientation.x, y: v.orientation.y, z: v.orientation.z, w: v.orientation.w },
        position: xr::Vector3f { x: v.position.x, y: v.position.y, z: v.position.z },
    }
}

fn to_fovf(f: &Fov) -> xr::Fovf {
    xr::Fovf { angle_left: f.angle_left, angle_right: f.angle_right, angle_up: f.angle_up, angle_down: f.angle_down }
}

/// Scales a recommended eye size down so its larger side is at most `max_side` (never up, never below 16).
pub fn eye_size(recommended: (u32, u32), max_side: u32) -> (u32, u32) {
    let (w, h) = (recommended.0.max(1), recommended.1.max(1));
    let max_side = max_side.max(16);
    let s = (max_side as f64 / w.max(h) as f64).min(1.0);
    (((w as f64 * s).round() as u32).max(16).min(w.max(16)), ((h as f64 * s).round() as u32).max(16).min(h.max(16)))
}

/// The head pose from the eye views: mean eye position, first eye's orientation.
fn head_pose(views: &[EyeView]) -> (Vec3, Quat) {
    let n = views.len().max(1) as f32;
    let pos = views.iter().fold(Vec3::ZERO, |a, v| a + v.position) / n;
    (pos, views.first().map(|v| v.orientation).unwrap_or(Quat::IDENTITY))
}

/// Runs one OpenXR session showing the person of `feed` (a still photo or a live source; each new scene is
/// uploaded to the GPU once) in the eyes, over `environment` in VR, until the frame/time budget, the runtime ending
/// the session, or the runtime going away. Errors only for setup failures (no runtime, no headset, no Vulkan, VR
/// without a panorama); everything after the session starts ends with an [`EndReason`] in the report.
pub fn run_session(
    config: &SessionConfig,
    feed: Box<dyn SceneFeed>,
    environment: Option<Environment>,
) -> Result<SessionReport, XrError> {
    if config.mode == Mode::Vr && environment.is_none() {
        return Err(XrError::Render("VR needs a panorama to show around the person".into()));
    }
    let entry = load_entry()?;
    let available = entry.enumerate_extensions().xr("xrEnumerateInstanceExtensionProperties")?;
    if !available.khr_vulkan_enable2 {
        return Err(XrError::MissingExtension("XR_KHR_vulkan_enable2"));
    }
    let mut exts = xr::ExtensionSet::default();
    exts.khr_vulkan_enable2 = true;
    exts.khr_convert_timespec_time = available.khr_convert_timespec_time;
    exts.ext_debug_utils = available.ext_debug_utils;
    exts.fb_passthrough = config.mode == Mode::Ar && available.fb_passthrough;
    tracing::debug!("enabling OpenXR extensions: {:?}", extension_names(&exts));
    let instance = entry
        .create_instance(
            &xr::ApplicationInfo {
                application_name: "r2human",
                application_version: 1,
                engine_name: "r2human",
                engine_version: 1,
                api_version: xr::Version::new(1, 0, 0),
            },
            &exts,
            &[],
            &(),
        )
        .xr("xrCreateInstance")?;
    let xr_log = Arc::new(ValidationLog::default());
    let _messenger = XrMessenger::new(&instance, xr_log.clone());
    let props = instance.properties().xr("xrGetInstanceProperties")?;
    let runtime = format!("{} {}", props.runtime_name, props.runtime_version);
    let system = instance.system(xr::FormFactor::HEAD_MOUNTED_DISPLAY).xr("xrGetSystem")?;
    let system_name = instance.system_properties(system).xr("xrGetSystemProperties")?.system_name;
    let modes = instance.enumerate_environment_blend_modes(system, VIEW_TYPE).xr("xrEnumerateEnvironmentBlendModes")?;
    let blend = choose_blend(config.mode, &modes, instance.exts().fb_passthrough.is_some());
    if let Some(n) = &blend.notice {
        tracing::warn!("{n}");
    }
    let config_views =
        instance.enumerate_view_configuration_views(system, VIEW_TYPE).xr("xrEnumerateViewConfigurationViews")?;
    if config_views.is_empty() {
        return Err(XrError::Unsupported("the headset reports no stereo views".into()));
    }
    let dims: Vec<(u32, u32)> = config_views
        .iter()
        .map(|v| eye_size((v.recommended_image_rect_width, v.recommended_image_rect_height), config.eye_max_side))
        .collect();
    let mut mirror_loop = None;
    let mut mirror_instance_exts = Vec::new();
    let mut mirror_device_exts = Vec::new();
    if config.mirror {
        let opened = MirrorEventLoop::new(dims[0].0 * dims.len() as u32, dims[0].1)
            .and_then(|l| l.required_instance_extensions().map(|e| (l, e)));
        match opened {
            Ok((l, exts)) => {
                mirror_loop = Some(l);
                mirror_instance_exts = exts;
                mirror_device_exts = DEVICE_EXTENSIONS.to_vec();
            }
            Err(e) => tracing::warn!("desktop mirror disabled: {e}"),
        }
    }
    let vk = create_device(&instance, system, &mirror_instance_exts, &mirror_device_exts)?;
    tracing::info!("OpenXR runtime {runtime}, system {system_name}, Vulkan device {}", vk.device_name());

    // SAFETY: the Vulkan handles come from this runtime through XR_KHR_vulkan_enable2 and outlive the session
    // (the session and everything holding it are locals declared after `vk`, so they are dropped first).
    let (session, mut frame_wait, mut frame_stream) = unsafe {
        use ash::vk::Handle;
        instance.create_session::<xr::Vulkan>(
            system,
            &xr::vulkan::SessionCreateInfo {
                instance: vk.instance().handle().as_raw() as _,
                physical_device: vk.physical_device().as_raw() as _,
                device: vk.device().handle().as_raw() as _,
                queue_family_index: vk.queue_family(),
                queue_index: SESSION_QUEUE as u32,
            },
        )
    }
    .xr("xrCreateSession")?;
    let session_created = Instant::now();
    let spaces = session.enumerate_reference_spaces().xr("xrEnumerateReferenceSpaces")?;
    let (space_type, space_name) = if spaces.contains(&xr::ReferenceSpaceType::STAGE) {
        (xr::ReferenceSpaceType::STAGE, "STAGE")
    } else {
        (xr::ReferenceSpaceType::LOCAL, "LOCAL")
    };
    let space = session.create_reference_space(space_type, xr::Posef::IDENTITY).xr("xrCreateReferenceSpace")?;
    let controllers = Controllers::new(&instance)?;
    session.attach_action_sets(&[&controllers.set]).xr("xrAttachSessionActionSets")?;

    let formats = session.enumerate_swapchain_formats().xr("xrEnumerateSwapchainFormats")?;
    let blittable = |f| vk.format_supports(f, ash::vk::FormatFeatureFlags::BLIT_DST);
    let format = SwapchainFormat::choose_where(&formats, blittable).ok_or_else(|| {
        let names: Vec<String> = formats.iter().map(|&f| format_name(f)).collect();
        XrError::Unsupported(format!(
            "no 8-bit RGBA swapchain format the device can blit to among {}",
            names.join(", ")
        ))
    })?;
    // Declared after `vk`, so dropped (swapchains, float images, readback buffers) before the device.
    let mut eyes: Vec<EyeSwapchain> = Vec::new();
    for &(w, h) in &dims {
        eyes.push(EyeSwapchain::new(&vk, &session, format, w, h, config.capture)?);
    }
    let eye_dims = (eyes[0].width, eyes[0].height);
    let sizes: Vec<(usize, usize)> = eyes.iter().map(|e| (e.width as usize, e.height as usize)).collect();
    let engine = config.backend.resolve(vk.is_software());
    if engine == Backend::Cpu && config.backend == Backend::Auto {
        crate::gpu::backend::log_software_device(vk.device_name());
    }
    // On a one-queue device the Vulkan renderer gets its own device, so the runtime's per-frame work on the session
    // queue never waits behind an eye render (see `super::eyes`). The CPU eyes need none.
    let render_ctx = if engine == Backend::Vulkan && renderer_shares_queue(&vk) {
        let validation = std::env::var("VK_INSTANCE_LAYERS").is_ok_and(|l| l.contains("KHRONOS_validation"));
        match crate::gpu::Context::new(&crate::gpu::ContextOptions { validation: Some(validation), display: None }) {
            Ok(c) => Arc::new(c),
            Err(e) => {
                tracing::warn!("no separate render device ({e}); the eyes share the session's queue");
                vk.clone()
            }
        }
    } else {
        vk.clone()
    };
    let render_path = if engine == Backend::Cpu {
        "the CPU reference (staged through host memory)".to_string()
    } else if Arc::ptr_eq(&render_ctx, &vk) {
        if renderer_shares_queue(&vk) {
            "the session's queue (copied on the GPU)".to_string()
        } else {
            "a second queue of the session's device (copied on the GPU)".to_string()
        }
    } else {
        format!("its own device on {} (staged through host memory)", render_ctx.device_name())
    };
    let mut renderer = match engine {
        Backend::Cpu => {
            Eyes::Cpu(CpuEyes::new(vk.clone(), &sizes, config.mode, environment, feed).map_err(XrError::RenderSetup)?)
        }
        _ => Eyes::Gpu(
            GpuEyes::new(vk.clone(), render_ctx.clone(), &sizes, config.mode, environment, feed)
                .map_err(XrError::RenderSetup)?,
        ),
    };
    let mut uploader = EyeUploader::new(&vk)?;
    let passthrough = if blend.passthrough_fb {
        let p =
            session.create_passthrough(xr::PassthroughFlagsFB::IS_RUNNING_AT_CREATION).xr("xrCreatePassthroughFB")?;
        let layer = session
            .create_passthrough_layer(
                &p,
                xr::PassthroughFlagsFB::IS_RUNNING_AT_CREATION,
                xr::PassthroughLayerPurposeFB::RECONSTRUCTION,
            )
            .xr("xrCreatePassthroughLayerFB")?;
        Some((p, layer))
    } else {
        None
    };

    let mailbox = RenderMailbox::new();
    let mut loop_state = LoopState {
        sm: SessionStateMachine::default(),
        pacing: PacingStats::default(),
        frames_submitted: 0,
        first_frame: None,
        last_frame: None,
        time_to_focused: None,
        placement: None,
        captures: Vec::new(),
        capture_of: None,
        queue_waits: DurationHistogram::default(),
        frame_intervals: DurationHistogram::default(),
        mirror_loop,
        mirror: None,
        mirror_presented: 0,
        exports: Exports::default(),
    };
    let end = std::thread::scope(|scope| {
        let m = mailbox.clone();
        let renderer = renderer.as_dyn();
        let render_thread =
            std::thread::Builder::new().name("r2human-xr-render".into()).spawn_scoped(scope, move || {
                // The eyes' parallel stages run on a pool of their own: in the global pool they would queue behind
                // the live worker's (segmentation, geometry) and an eye would wait for a whole frame's work.
                match eye_pool() {
                    Some(pool) => pool.install(|| m.run_render_loop(renderer)),
                    None => m.run_render_loop(renderer),
                }
            });
        if let Err(e) = render_thread {
            return EndReason::RenderFailed(format!("cannot start the render thread: {e}"));
        }
        let ctx = FrameContext {
            config,
            instance: &instance,
            session: &session,
            space: &space,
            stage_has_floor: space_type == xr::ReferenceSpaceType::STAGE,
            controllers: &controllers,
            vk: &vk,
            blend: &blend,
            passthrough_layer: passthrough.as_ref().map(|(_, l)| l),
            mailbox: &mailbox,
            session_created,
        };
        let end = frame_loop(&ctx, &mut frame_wait, &mut frame_stream, &mut eyes, &mut uploader, &mut loop_state);
        mailbox.shutdown();
        end
    });
    // An export still being written finishes (its file is part of what the session did).
    loop_state.exports.collect(true);
    // The render thread has ended; collect a capture still in flight.
    if uploader.wait().is_ok() {
        collect_captures(&mut uploader, &eyes, &mut loop_state);
    }
    if loop_state.sm.running {
        // The loop left while the session was still running (runtime gone or render failure): best effort.
        let _q = vk.lock_queue_at(SESSION_QUEUE);
        let _ = session.end();
    }
    if let Some(m) = loop_state.mirror.take() {
        loop_state.mirror_presented = m.presented;
        m.destroy();
    }
    // The device finishes all uploads before the swapchains go away.
    let _ = vk.wait_idle();
    drop(uploader);
    let neural = renderer.neural_stats().clone();
    let eye_stages = renderer.stages();
    let person_renderer = neural.summary().unwrap_or_else(|| match engine {
        Backend::Cpu => "geometric (CPU reference)".to_string(),
        _ => "geometric (GPU passes)".to_string(),
    });
    drop(renderer);
    drop(eyes);
    drop(passthrough);
    drop((controllers, space, frame_wait, frame_stream, session));
    let eye_times = mailbox.eye_times();
    let (render_messages, render_message_count) = if Arc::ptr_eq(&render_ctx, &vk) {
        (Vec::new(), 0)
    } else {
        // The loader's notice that VK_INSTANCE_LAYERS switched the layer on (it is how tests enable validation) is
        // not a finding; the render device's messenger sees it because it exists from instance creation on.
        let findings: Vec<String> = render_ctx
            .validation()
            .messages()
            .into_iter()
            .filter(|m| !(m.starts_with("env var '") && m.contains("defined and adding layers")))
            .collect();
        let notices = render_ctx.validation().messages().len() - findings.len();
        let count = render_ctx.validation().count() as usize;
        (findings, count.saturating_sub(notices))
    };
    drop(render_ctx);
    let display_fps = match (loop_state.first_frame, loop_state.last_frame) {
        (Some(a), Some(b)) if b > a && loop_state.frames_submitted > 1 => {
            (loop_state.frames_submitted - 1) as f64 / (b - a).as_secs_f64()
        }
        _ => 0.0,
    };
    let report = SessionReport {
        runtime,
        system: system_name,
        vulkan_device: vk.device_name().to_string(),
        blend,
        reference_space: space_name.into(),
        swapchain_format: format_name(format.vk.as_raw() as u32),
        eye_size: eye_dims,
        states: loop_state.sm.history.clone(),
        time_to_focused: loop_state.time_to_focused,
        frames_submitted: loop_state.frames_submitted,
        pacing: loop_state.pacing,
        eye_render_ms: (eye_times.count() > 0).then(|| eye_times.median().as_secs_f64() * 1e3),
        eye_renders: eye_times.count() as usize,
        eye_stages,
        scene_uploads: mailbox.uploads(),
        source_messages: mailbox.messages(),
        renderer_shares_queue: renderer_shares_queue(&vk),
        queue_wait_ms: (
            (loop_state.queue_waits.count() > 0).then(|| loop_state.queue_waits.median().as_secs_f64() * 1e3),
            loop_state.queue_waits.max().as_secs_f64() * 1e3,
        ),
        frame_intervals: loop_state.frame_intervals.clone(),
        display_fps,
        end,
        xr_messages: xr_log.messages(),
        xr_message_count: xr_log.count() as usize,
        vk_messages: vk.validation().messages().into_iter().chain(render_messages).collect(),
        vk_message_count: vk.validation().count() as usize + render_message_count,
        render_path,
        person_renderer,
        neural,
        captures: loop_state.captures,
        placement: loop_state.placement,
        mirror_presented: loop_state.mirror_presented,
        exports: loop_state.exports.written,
        export_failures: loop_state.exports.failures,
    };
    drop(vk);
    Ok(report)
}

struct FrameContext<'a> {
    config: &'a SessionConfig,
    instance: &'a xr::Instance,
    session: &'a xr::Session<xr::Vulkan>,
    space: &'a xr::Space,
    stage_has_floor: bool,
    controllers: &'a Controllers,
    vk: &'a Arc<gpu::Context>,
    blend: &'a BlendChoice,
    passthrough_layer: Option<&'a xr::PassthroughLayerFB>,
    mailbox: &'a RenderMailbox,
    session_created: Instant,
}

struct LoopState {
    sm: SessionStateMachine,
    pacing: PacingStats,
    frames_submitted: u64,
    first_frame: Option<Instant>,
    last_frame: Option<Instant>,
    time_to_focused: Option<Duration>,
    placement: Option<Placement>,
    captures: Vec<EyeCapture>,
    /// The frame whose eye images are being read back (capture), with its request.
    capture_of: Option<std::sync::Arc<RenderedEyes>>,
    /// Per frame: time spent waiting for the shared queue lock.
    queue_waits: DurationHistogram,
    /// Time between consecutive submitted frames (the display loop's frame times).
    frame_intervals: DurationHistogram,
    mirror_loop: Option<MirrorEventLoop>,
    mirror: Option<Mirror>,
    mirror_presented: u64,
    exports: Exports,
}

/// The export action's state: one export at a time, on a thread of its own.
#[derive(Default)]
struct Exports {
    running: Option<std::thread::JoinHandle<Result<std::path::PathBuf, ExportFailure>>>,
    written: Vec<std::path::PathBuf>,
    failures: Vec<String>,
    /// The person-frame count [`SessionConfig::export_at_frames`] was last checked at.
    checked_frame: u64,
}

impl Exports {
    /// Starts an export of the person shown after `frame` person frames, asked for `by` (for the log); refused
    /// (and recorded) while the previous one is still being written or when the session has no exporter.
    fn request(&mut self, config: &SessionConfig, frame: u64, by: &str) {
        self.collect(false);
        let refused = match (&config.export, &self.running) {
            (None, _) => Some(format!("{by} at frame {frame}: exporting is off in this session")),
            (Some(_), Some(_)) => {
                Some(format!("{by} at frame {frame}: the previous export is still being written; press again later"))
            }
            (Some(_), None) => None,
        };
        if let Some(why) = refused {
            tracing::warn!("{why}");
            self.failures.push(why);
            return;
        }
        let Some(hook) = config.export.as_ref().map(|h| Arc::clone(&h.0)) else { return };
        tracing::info!("{by}: exporting the person shown at frame {frame}");
        match std::thread::Builder::new().name("r2human-xr-export".into()).spawn(move || hook.export(frame)) {
            Ok(h) => self.running = Some(h),
            Err(e) => self.failures.push(format!("{by}: cannot start the export thread: {e}")),
        }
    }

    /// Exports when the person-frame count reaches one of [`SessionConfig::export_at_frames`] (once per count).
    fn at_frame(&mut self, config: &SessionConfig, person_frames: u64) {
        if person_frames != self.checked_frame {
            self.checked_frame = person_frames;
            if config.export_at_frames.contains(&person_frames) {
                self.request(config, person_frames, "--export-at-frame");
            }
        }
    }

    /// Records a finished export; with `wait`, waits for one still being written.
    fn collect(&mut self, wait: bool) {
        if !self.running.as_ref().is_some_and(|h| wait || h.is_finished()) {
            return;
        }
        let Some(handle) = self.running.take() else { return };
        match handle.join() {
            Ok(Ok(path)) => {
                tracing::info!("exported the person: {}", path.display());
                self.written.push(path);
            }
            Ok(Err(e)) => {
                tracing::warn!("export failed: {e}");
                self.failures.push(e.to_string());
            }
            Err(_) => self.failures.push("the export thread panicked".into()),
        }
    }
}

/// How long to wait for the runtime to confirm an exit request before giving up on it.
const EXIT_GRACE: Duration = Duration::from_secs(10);

/// Turns finished read-backs into [`EyeCapture`]s (never blocks).
fn collect_captures(uploader: &mut EyeUploader, eyes: &[EyeSwapchain], st: &mut LoopState) {
    let Some(images) = uploader.take_captures(eyes) else { return };
    let Some(frame) = st.capture_of.take() else { return };
    for (i, image) in images.into_iter().enumerate() {
        let cap = EyeCapture {
            eye: i,
            image,
            body_camera: frame.cameras[i],
            view: frame.request.views[i],
            placement: frame.request.placement,
        };
        if let Some(slot) = st.captures.iter_mut().find(|c| c.eye == i) {
            *slot = cap;
        } else {
            st.captures.push(cap);
        }
    }
}

/// Runs `f` holding the session queue lock, adding the time spent waiting for the lock to `waited`.
fn with_queue<T>(vk: &gpu::Context, waited: &mut Duration, f: impl FnOnce() -> T) -> T {
    let _q = vk.lock_queue_timed(SESSION_QUEUE, waited);
    f()
}

fn frame_loop(
    ctx: &FrameContext<'_>,
    frame_wait: &mut xr::FrameWaiter,
    frame_stream: &mut xr::FrameStream<xr::Vulkan>,
    eyes: &mut [EyeSwapchain],
    uploader: &mut EyeUploader,
    st: &mut LoopState,
) -> EndReason {
    let mut events = xr::EventDataBuffer::new();
    let mut exit_requested: Option<(Instant, EndReason)> = None;
    let mut last_uploaded: Option<u64> = None;
    let mut shown: Option<std::sync::Arc<super::pacing::RenderedEyes>> = None;
    let mut request_seq = 0u64;
    let mut last_frame_time: Option<Instant> = None;
    let started = Instant::now();
    let can_time = ctx.instance.exts().khr_convert_timespec_time.is_some();
    let request_exit = |why: EndReason, exit_requested: &mut Option<(Instant, EndReason)>| {
        if exit_requested.is_none() {
            tracing::info!("requesting session exit: {why}");
            if let Err(e) = ctx.session.request_exit() {
                if e != xr::sys::Result::ERROR_SESSION_NOT_RUNNING {
                    tracing::warn!("xrRequestExitSession failed: {e}");
                }
            }
            *exit_requested = Some((Instant::now(), why));
        }
    };
    loop {
        // 1. Events: state changes, instance loss.
        loop {
            let event = match ctx.instance.poll_event(&mut events) {
                Ok(Some(e)) => e,
                Ok(None) => break,
                Err(e) => return EndReason::RuntimeGone(format!("xrPollEvent: {e}")),
            };
            match event {
                xr::Event::SessionStateChanged(e) => {
                    tracing::info!("session state {:?}", e.state());
                    if e.state() == xr::SessionState::FOCUSED && st.time_to_focused.is_none() {
                        st.time_to_focused = Some(ctx.session_created.elapsed());
                    }
                    match st.sm.on_state(e.state()) {
                        StateCommand::Begin => {
                            if let Err(e) = ctx.session.begin(VIEW_TYPE) {
                                st.sm.running = false;
                                return EndReason::RuntimeGone(format!("xrBeginSession: {e}"));
                            }
                        }
                        StateCommand::End => {
                            let ended = {
                                let _q = ctx.vk.lock_queue_at(SESSION_QUEUE);
                                ctx.session.end()
                            };
                            if let Err(e) = ended {
                                return EndReason::RuntimeGone(format!("xrEndSession: {e}"));
                            }
                        }
                        StateCommand::Exit => {
                            return if e.state() == xr::SessionState::LOSS_PENDING {
                                EndReason::SessionLoss
                            } else {
                                exit_requested.take().map(|(_, why)| why).unwrap_or(EndReason::RuntimeExit)
                            };
                        }
                        StateCommand::None => {}
                    }
                }
                xr::Event::InstanceLossPending(_) => return EndReason::InstanceLoss,
                xr::Event::EventsLost(e) => tracing::warn!("{} OpenXR events lost", e.lost_event_count()),
                _ => {}
            }
        }
        if let Some((since, why)) = &exit_requested {
            // A session that never began has nothing to wind down: leave at once.
            if !st.sm.reached(xr::SessionState::READY) {
                return why.clone();
            }
            if since.elapsed() > EXIT_GRACE {
                tracing::warn!("the runtime did not confirm the exit request within {EXIT_GRACE:?}");
                return why.clone();
            }
        }
        if let Some(e) = ctx.mailbox.error() {
            request_exit(EndReason::RenderFailed(e), &mut exit_requested);
        }
        if ctx.config.max_duration.is_some_and(|d| started.elapsed() > d) {
            request_exit(EndReason::TimeLimit, &mut exit_requested);
        }
        st.exports.collect(false);
        if let Some(m) = &mut st.mirror {
            if m.take_export_key() {
                st.exports.request(ctx.config, st.pacing.person_frames, "the mirror window's E key");
            }
            if !m.pump() {
                tracing::info!("mirror window closed; the session goes on");
                if let Some(m) = st.mirror.take() {
                    st.mirror_presented = m.presented;
                    m.destroy();
                }
            }
        }
        if !st.sm.running {
            std::thread::sleep(Duration::from_millis(5));
            continue;
        }

        collect_captures(uploader, eyes, st);

        // 2. One frame.
        let mut waited = Duration::ZERO;
        let step = (|| -> Result<(), XrError> {
            let fs = frame_wait.wait().xr("xrWaitFrame")?;
            with_queue(ctx.vk, &mut waited, || frame_stream.begin()).xr("xrBeginFrame")?;
            let now = Instant::now();
            let dt = last_frame_time.map(|t| (now - t).as_secs_f32()).unwrap_or(0.0);
            last_frame_time = Some(now);
            let (flags, raw_views) =
                ctx.session.locate_views(VIEW_TYPE, fs.predicted_display_time, ctx.space).xr("xrLocateViews")?;
            let sampled_at = if can_time { ctx.instance.now().ok().map(|t| t.as_nanos()) } else { None };
            let tracked = flags.contains(xr::ViewStateFlags::ORIENTATION_VALID | xr::ViewStateFlags::POSITION_VALID)
                && raw_views.len() == eyes.len();
            let views: Vec<EyeView> = raw_views.iter().map(to_view).collect();
            if tracked {
                let (head_pos, head_rot) = head_pose(&views);
                let floor = Placement::floor_height(ctx.stage_has_floor, head_pos.y);
                let placement = *st
                    .placement
                    .get_or_insert_with(|| Placement::in_front_of(head_pos, head_rot, floor, DEFAULT_DISTANCE));
                // Input pauses while the session is not focused (xrSyncActions would fail anyway).
                let (controls, export_pressed) = if st.sm.input_enabled() {
                    ctx.session.sync_actions(&[(&ctx.controllers.set).into()]).xr("xrSyncActions")?;
                    ctx.controllers.read(ctx.session)
                } else {
                    (Controls::default(), false)
                };
                if export_pressed {
                    st.exports.request(ctx.config, st.pacing.person_frames, "the controller's export button");
                }
                if controls.is_active() {
                    st.placement = Some(placement.apply(&controls, head_pos, head_rot, floor, dt));
                }
                if fs.should_render && st.sm.visible() {
                    request_seq += 1;
                    ctx.mailbox.request(RenderRequest {
                        seq: request_seq,
                        views: views.clone(),
                        placement: st.placement.unwrap_or(placement),
                        sizes: eyes.iter().map(|e| (e.width as usize, e.height as usize)).collect(),
                        sampled_at,
                    });
                }
            }
            // Copy the newest finished eye images into the swapchains if they are new (GPU to GPU); otherwise
            // re-submit the last ones (the compositor reprojects them from the poses they were rendered for).
            let mut fresh = false;
            if fs.should_render {
                if let Some(frame) = ctx.mailbox.take_newer(last_uploaded) {
                    let capture = ctx.config.capture && st.capture_of.is_none();
                    uploader.upload(ctx.vk, eyes, &frame.outputs, capture, &mut waited)?;
                    // The copy is waited for here (the next upload would wait for it anyway), so the render
                    // thread reuses the buffers on this report and never touches the fence this loop reuses.
                    uploader.wait()?;
                    ctx.mailbox.copied(frame.request.seq);
                    if capture {
                        st.capture_of = Some(frame.clone());
                    }
                    // The mirror window opens with the first image, so it maps above the runtime's own
                    // window when both share a display.
                    if let Some(l) = st.mirror_loop.take() {
                        match Mirror::new(l, ctx.vk) {
                            Ok(m) => st.mirror = Some(m),
                            Err(e) => tracing::warn!("desktop mirror disabled: {e}"),
                        }
                    }
                    if let Some(m) = &mut st.mirror {
                        let images: Vec<_> = eyes.iter().map(|e| &e.linear).collect();
                        if let Err(e) = m.present(&images) {
                            tracing::warn!("desktop mirror stopped: {e}");
                            if let Some(m) = st.mirror.take() {
                                st.mirror_presented = m.presented;
                                m.destroy();
                            }
                        }
                    }
                    last_uploaded = Some(frame.request.seq);
                    shown = Some(frame);
                    fresh = true;
                }
            }
            let person = shown.as_ref().filter(|_| fs.should_render && eyes.iter().all(|e| e.has_content()));
            match person {
                Some(frame) => {
                    let proj_views: Vec<xr::CompositionLayerProjectionView<'_, xr::Vulkan>> = eyes
                        .iter()
                        .zip(&frame.request.views)
                        .map(|(eye, v)| {
                            xr::CompositionLayerProjectionView::new().pose(to_posef(v)).fov(to_fovf(&v.fov)).sub_image(
                                xr::SwapchainSubImage::new().swapchain(&eye.handle).image_array_index(0).image_rect(
                                    xr::Rect2Di {
                                        offset: xr::Offset2Di { x: 0, y: 0 },
                                        extent: xr::Extent2Di { width: eye.width as i32, height: eye.height as i32 },
                                    },
                                ),
                            )
                        })
                        .collect();
                    let flags = if ctx.config.mode == Mode::Ar {
                        // Premultiplied alpha (no UNPREMULTIPLIED_ALPHA flag): what the pipeline produces.
                        xr::CompositionLayerFlags::BLEND_TEXTURE_SOURCE_ALPHA
                    } else {
                        xr::CompositionLayerFlags::EMPTY
                    };
                    let projection =
                        xr::CompositionLayerProjection::new().layer_flags(flags).space(ctx.space).views(&proj_views);
                    match ctx.passthrough_layer {
                        Some(layer) => {
                            // The crate has no public builder for this layer: build the raw struct (XR_FB_passthrough
                            // ignores `space`) and pass it by its base header, as the crate's own layers are passed.
                            let raw = xr::sys::CompositionLayerPassthroughFB {
                                ty: xr::sys::CompositionLayerPassthroughFB::TYPE,
                                next: std::ptr::null(),
                                flags: xr::CompositionLayerFlags::BLEND_TEXTURE_SOURCE_ALPHA,
                                space: xr::sys::Space::NULL,
                                layer_handle: layer.as_raw(),
                            };
                            // SAFETY: CompositionLayerBase is a transparent wrapper of the base header every layer
                            // struct starts with; `raw` outlives the xrEndFrame call.
                            let pt: &xr::CompositionLayerBase<'_, xr::Vulkan> =
                                unsafe { &*(&raw as *const xr::sys::CompositionLayerPassthroughFB).cast() };
                            with_queue(ctx.vk, &mut waited, || {
                                frame_stream.end(fs.predicted_display_time, ctx.blend.blend, &[pt, &projection])
                            })
                            .xr("xrEndFrame")?;
                        }
                        None => {
                            with_queue(ctx.vk, &mut waited, || {
                                frame_stream.end(fs.predicted_display_time, ctx.blend.blend, &[&projection])
                            })
                            .xr("xrEndFrame")?;
                        }
                    }
                    st.pacing.record(fresh, fs.predicted_display_time.as_nanos(), frame.request.sampled_at);
                }
                None => {
                    with_queue(ctx.vk, &mut waited, || {
                        frame_stream.end(fs.predicted_display_time, ctx.blend.blend, &[])
                    })
                    .xr("xrEndFrame")?;
                }
            }
            st.frames_submitted += 1;
            st.queue_waits.record(waited);
            if let Some(last) = st.last_frame {
                st.frame_intervals.record(now.saturating_duration_since(last));
            }
            st.first_frame.get_or_insert(now);
            st.last_frame = Some(now);
            Ok(())
        })();
        if let Err(e) = step {
            return EndReason::RuntimeGone(e.to_string());
        }
        st.exports.at_frame(ctx.config, st.pacing.person_frames);
        if ctx.config.max_person_frames.is_some_and(|n| st.pacing.person_frames >= n) {
            request_exit(EndReason::FrameLimit, &mut exit_requested);
        }
    }
}

/// A thread pool for the render thread's parallel work, one thread per core; `None` (the global pool is used,
/// with a debug message) when the system refuses the threads.
fn eye_pool() -> Option<rayon::ThreadPool> {
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
    match rayon::ThreadPoolBuilder::new().num_threads(threads).thread_name(|i| format!("r2human-eyes-{i}")).build() {
        Ok(pool) => Some(pool),
        Err(e) => {
            tracing::debug!("no thread pool of its own for the eyes ({e}); they share the global one");
            None
        }
    }
}

/// The eye renderer a session runs: the Vulkan passes or the CPU reference ([`SessionConfig::backend`]).
enum Eyes {
    Gpu(GpuEyes),
    Cpu(CpuEyes),
}

impl Eyes {
    fn as_dyn(&mut self) -> &mut dyn EyeRenderer {
        match self {
            Eyes::Gpu(e) => e,
            Eyes::Cpu(e) => e,
        }
    }

    fn neural_stats(&self) -> &NeuralEyeStats {
        match self {
            Eyes::Gpu(e) => &e.neural_stats,
            Eyes::Cpu(e) => &e.views.neural_stats,
        }
    }

    /// The CPU eyes' stage medians (none for the Vulkan passes).
    fn stages(&self) -> Vec<StageSummary> {
        match self {
            Eyes::Gpu(_) => Vec::new(),
            Eyes::Cpu(e) => e.views.stages.summary(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use xr::EnvironmentBlendMode as B;
    use xr::SessionState as S;

    #[test]
    fn blend_choice_follows_the_preference_order() {
        let c = choose_blend(Mode::Ar, &[B::OPAQUE, B::ADDITIVE, B::ALPHA_BLEND], true);
        assert_eq!((c.blend, c.passthrough_fb, c.notice.is_none()), (B::ALPHA_BLEND, false, true));
        let c = choose_blend(Mode::Ar, &[B::OPAQUE, B::ADDITIVE], true);
        assert_eq!((c.blend, c.passthrough_fb), (B::ADDITIVE, false));
        let c = choose_blend(Mode::Ar, &[B::OPAQUE], true);
        assert_eq!((c.blend, c.passthrough_fb, c.notice.is_none()), (B::OPAQUE, true, true));
        // Monado's simulated HMD: OPAQUE only, no passthrough -> OPAQUE with a notice.
        let c = choose_blend(Mode::Ar, &[B::OPAQUE], false);
        assert_eq!((c.blend, c.passthrough_fb), (B::OPAQUE, false));
        assert!(c.notice.unwrap().contains("over black"));
        let c = choose_blend(Mode::Vr, &[B::ADDITIVE, B::OPAQUE], false);
        assert_eq!((c.blend, c.notice), (B::OPAQUE, None));
        let c = choose_blend(Mode::Vr, &[B::ADDITIVE], false);
        assert_eq!(c.blend, B::ADDITIVE);
        assert!(c.notice.is_some());
        assert_eq!(choose_blend(Mode::Vr, &[], false).blend, B::OPAQUE);
    }

    #[test]
    fn state_machine_begins_ends_and_exits() {
        let mut sm = SessionStateMachine::default();
        assert_eq!(sm.on_state(S::IDLE), StateCommand::None);
        assert!(!sm.running);
        assert_eq!(sm.on_state(S::READY), StateCommand::Begin);
        assert!(sm.running);
        assert_eq!(sm.on_state(S::SYNCHRONIZED), StateCommand::None);
        assert!(!sm.visible() && !sm.input_enabled());
        sm.on_state(S::VISIBLE);
        assert!(sm.visible() && !sm.input_enabled());
        sm.on_state(S::FOCUSED);
        assert!(sm.visible() && sm.input_enabled());
        // Focus loss (e.g. a system menu) pauses input but keeps rendering.
        sm.on_state(S::VISIBLE);
        assert!(sm.visible() && !sm.input_enabled());
        assert_eq!(sm.on_state(S::STOPPING), StateCommand::End);
        assert!(!sm.running);
        assert_eq!(sm.on_state(S::IDLE), StateCommand::None);
        assert_eq!(sm.on_state(S::EXITING), StateCommand::Exit);
        assert!(sm.reached(S::FOCUSED) && !sm.reached(S::LOSS_PENDING));
        let expected =
            [S::IDLE, S::READY, S::SYNCHRONIZED, S::VISIBLE, S::FOCUSED, S::VISIBLE, S::STOPPING, S::IDLE, S::EXITING];
        assert_eq!(sm.history, expected);
        let mut lost = SessionStateMachine::default();
        lost.on_state(S::READY);
        assert_eq!(lost.on_state(S::LOSS_PENDING), StateCommand::Exit);
    }

    #[test]
    fn eye_size_scales_down_only() {
        assert_eq!(eye_size((1440, 1600), 512), (461, 512));
        assert_eq!(eye_size((300, 200), 512), (300, 200));
        assert_eq!(eye_size((0, 0), 0), (16, 16));
        assert_eq!(eye_size((4000, 10), 100), (100, 16));
    }

    #[test]
    fn pose_conversions_round_trip() {
        let v = EyeView {
            position: Vec3::new(0.1, 1.6, -0.2),
            orientation: Quat::from_rotation_y(0.3),
            fov: Fov { angle_left: -0.8, angle_right: 0.7, angle_up: 0.75, angle_down: -0.85 },
        };
        let back = to_view(&xr::View { pose: to_posef(&v), fov: to_fovf(&v.fov) });
        assert!((back.position - v.position).length() < 1e-7);
        assert!(back.orientation.angle_between(v.orientation) < 1e-4);
        assert_eq!(back.fov, v.fov);
        let (p, q) = head_pose(&[v, EyeView { position: Vec3::new(0.3, 1.6, -0.2), ..v }]);
        assert!((p - Vec3::new(0.2, 1.6, -0.2)).length() < 1e-6 && q == v.orientation);
    }
}
