//! The XR session with a live source that stalls, disappears, changes resolution and comes back (issue 16; the
//! long version is `scripts/soak.sh --xr-only --faults`): the session keeps running through one whole fault cycle
//! of `synthetic:…+faults` and shows the person again after each fault, with OpenXR and Vulkan validation on.
//!
//! `cargo test --test xr_faults` runs `xr_faulty_live_source_in_monado_root`, which (as root) builds or reuses the
//! Monado root and re-runs this binary's ignored test inside it (see `tests/xr.rs`; skipped with the reason
//! printed when not root or when the root cannot be built). Kept apart from `tests/xr.rs` so the two suites
//! change independently.

mod xr_root;

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use r2human::app::live::video_source;
use r2human::app::neural::{load_interactive, NeuralSetup};
use r2human::app::xr_session::LiveFeed;
use r2human::capture::SegmentMethod;
use r2human::compose::Mode;
use r2human::io::environment::Environment;
use r2human::pipeline::{PrepareOptions, RendererChoice, Scene};
use r2human::xr::session::EndReason;
use r2human::xr::{run_session, SceneFeed, SessionConfig};
use xr_root::{assert_validation_layers_present, prepare_root, run_inside};

#[test]
fn xr_faulty_live_source_in_monado_root() {
    if std::env::var("R2HUMAN_XR_IN_ROOT").is_ok() {
        return; // already inside: the ignored test is the suite
    }
    if let Err(why) = prepare_root() {
        println!("SKIPPED xr_faulty_live_source_in_monado_root: {why}");
        return;
    }
    let (ok, text) =
        run_inside(&[], &["--ignored", "--exact", "xr_session_survives_a_faulty_live_source", "--nocapture"]);
    println!("{text}");
    assert!(ok, "the XR fault test inside the Monado root failed (output above)");
}

/// A feed that passes the product's [`LiveFeed`] through and notes when each new scene arrived.
struct Timed {
    feed: LiveFeed,
    start: Instant,
    arrivals: Arc<Mutex<Vec<f64>>>,
}

impl SceneFeed for Timed {
    fn poll(&mut self) -> Option<Arc<Scene>> {
        let scene = self.feed.poll()?;
        self.arrivals.lock().unwrap().push(self.start.elapsed().as_secs_f64());
        Some(scene)
    }

    fn take_messages(&mut self) -> Vec<String> {
        self.feed.take_messages()
    }
}

#[test]
#[ignore = "needs a running OpenXR runtime; run via xr_faulty_live_source_in_monado_root"]
fn xr_session_survives_a_faulty_live_source() {
    assert_validation_layers_present();
    let neural =
        load_interactive(&NeuralSetup { choice: RendererChoice::Geometric, ..Default::default() }, true).unwrap();
    // 3 s normal, 2 s stalled, 2 s normal, 2 s gone, 3 s at 80x60, then 160x120 again (capture::synthetic).
    let source = video_source(std::path::Path::new("synthetic:160x120@15+faults"), 15.0);
    let feed = LiveFeed::start(source, SegmentMethod::Alpha, PrepareOptions::default(), &neural).unwrap();
    let arrivals = Arc::new(Mutex::new(Vec::new()));
    let timed = Timed { feed, start: Instant::now(), arrivals: Arc::clone(&arrivals) };
    let config = SessionConfig {
        mode: Mode::Vr,
        max_person_frames: None,
        // One fault cycle, the return to full size, and the session's start-up.
        max_duration: Some(Duration::from_secs(16)),
        eye_max_side: 96,
        ..SessionConfig::default()
    };
    let report = run_session(&config, Box::new(timed), Some(Environment::default_embedded())).unwrap();
    println!("{report}\nsource messages: {:#?}", report.source_messages);
    // Not dropped: the session ran to its time budget, with no validation message.
    assert_eq!(report.end, EndReason::TimeLimit, "{report}");
    assert_eq!(report.xr_message_count, 0, "OpenXR validation: {:#?}", report.xr_messages);
    assert_eq!(report.vk_message_count, 0, "Vulkan validation: {:#?}", report.vk_messages);
    // The display loop never waited for the source (the stall and the outage last 2 s each).
    let longest = report.frame_intervals.max();
    assert!(longest < Duration::from_millis(1500), "the XR frame loop stalled for {longest:?}");
    // Every fault was seen and reported: the outage, then both resolution changes.
    let said = |what: &str| report.source_messages.iter().any(|m| m.contains(what));
    assert!(said("gone"), "the outage was not reported: {:#?}", report.source_messages);
    assert!(said("from 160x120 to 80x60"), "{:#?}", report.source_messages);
    assert!(said("from 80x60 to 160x120"), "{:#?}", report.source_messages);
    // New people kept arriving after each fault: the stall and the outage are pauses of over 1.5 s between new
    // scenes (one long pause when the worker is too slow to finish a frame between them); the last resolution
    // change above is a full-size person after the outage and the resize (the source is back at 12 s).
    let arrivals = arrivals.lock().unwrap().clone();
    println!("new scenes at (s after the source started): {arrivals:.2?}");
    let pauses = arrivals.windows(2).filter(|w| w[1] - w[0] > 1.5).count();
    assert!(pauses >= 1, "no pause for the stall or the outage, arrivals at {arrivals:?}");
    assert_eq!(report.scene_uploads as usize, arrivals.len(), "every new scene was uploaded");
}
