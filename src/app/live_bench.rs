//! `r2human bench-live`: a clip played through the live pipeline exactly as `view` plays it (paced at the clip's
//! frame rate, frames dropped when the pipeline is busy, the frame path, the encoder on the worker), without a
//! window; with `views`, each completed frame is also drawn once from a fixed view on the calling thread, as a
//! display would. The report says what a user sees: completed person frames per second, dropped frames, frames without a person,
//! arrival -> completion latency (p50, p95) and the per-stage medians.

use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use anyhow::Context;

use super::live::{video_source, EncodeProcessor, LiveOptions, LivePipeline, LiveStats};
use super::neural::{load_interactive, NeuralSetup};
use crate::capture::stats::median;
use crate::capture::SegmentMethod;
use crate::geometry::Camera;
use crate::pipeline::warp::OcclusionFill;
use crate::pipeline::{auto_frame_options, PrepareOptions, ViewRenderer};

/// What `bench-live` plays and how.
#[derive(Clone, Debug)]
pub struct LiveBenchOptions {
    /// A video file or a folder of frames.
    pub video: PathBuf,
    /// Frame rate of a folder of frames (a video file plays at its own).
    pub fps: f32,
    /// How frames are segmented.
    pub segment: SegmentMethod,
    /// Which renderer draws the views (and whether the worker runs the encoder).
    pub neural: NeuralSetup,
    /// Stop after this long (the whole clip when `None`).
    pub seconds: Option<f64>,
    /// Side of the view drawn from each completed frame, in pixels.
    pub view_size: usize,
    /// Yaw of that view in degrees.
    pub yaw: f32,
    /// Draw one view of every completed frame (else the pipeline alone is measured).
    pub views: bool,
    /// Source resolution (512 like the reference).
    pub resolution: usize,
    /// Keep the person model across the frames ([`crate::pipeline::PrepareOptions::person_model`]).
    pub person_model: bool,
}

impl Default for LiveBenchOptions {
    fn default() -> Self {
        Self {
            video: PathBuf::new(),
            fps: 30.0,
            segment: SegmentMethod::Auto,
            neural: NeuralSetup::default(),
            seconds: None,
            view_size: 512,
            yaw: 30.0,
            views: false,
            resolution: crate::geometry::SOURCE_RESOLUTION,
            person_model: false,
        }
    }
}

/// What `bench-live` measured.
#[derive(Clone, Debug)]
pub struct LiveBenchReport {
    /// The source's description.
    pub source: String,
    /// "neural" or "geometric": what drew the views.
    pub renderer: &'static str,
    /// From the pipeline's start to the end of the clip (or `seconds`).
    pub wall: Duration,
    /// The pipeline's counters, latency quantiles and stage medians.
    pub stats: LiveStats,
    /// Encoder runs on the worker.
    pub encodes: u64,
    /// Views drawn (one per completed frame the loop saw).
    pub views: u64,
    /// Median time of one view.
    pub view_median: Duration,
}

impl LiveBenchReport {
    /// Completed person frames per second over the whole run.
    pub fn completed_per_second(&self) -> f64 {
        self.stats.completed as f64 / self.wall.as_secs_f64().max(1e-9)
    }
}

impl std::fmt::Display for LiveBenchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = &self.stats;
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        writeln!(f, "bench-live: {} ({} renderer), {:.1} s", self.source, self.renderer, self.wall.as_secs_f64())?;
        writeln!(
            f,
            "frames: {} read, {} completed ({:.1} per second), {} dropped, {} without a person, {} errors",
            s.read,
            s.completed,
            self.completed_per_second(),
            s.dropped,
            s.no_person,
            s.errors
        )?;
        writeln!(
            f,
            "latency (arrival -> completion): p50 {:.0} ms, p95 {:.0} ms",
            ms(s.latency_p50),
            ms(s.latency_p95)
        )?;
        writeln!(
            f,
            "views: {} drawn, median {:.1} ms; encoder runs {}",
            self.views,
            ms(self.view_median),
            self.encodes
        )?;
        // A stage that did not run once per completed frame (kept between frames, or run on frames then dropped)
        // says how often it ran.
        let stages: Vec<String> = s
            .stages
            .iter()
            .map(|st| match st.total == s.completed {
                true => format!("{} {:.1}", st.name, st.median_ms()),
                false => format!("{} {:.1} (x{})", st.name, st.median_ms(), st.total),
            })
            .collect();
        write!(f, "stage medians (ms; (xN): ran N times): {}", stages.join(", "))
    }
}

/// Plays `opts.video` through the live pipeline and measures it (see the module docs).
pub fn bench_live(opts: &LiveBenchOptions) -> anyhow::Result<LiveBenchReport> {
    if !(64..=1024).contains(&opts.resolution) {
        anyhow::bail!("--resolution {} is out of range: use 64 to 1024 (512 is the reference's)", opts.resolution);
    }
    if !(16..=4096).contains(&opts.view_size) {
        anyhow::bail!("--view-size {} is out of range: use 16 to 4096 pixels", opts.view_size);
    }
    if !(opts.fps.is_finite() && opts.fps > 0.0 && opts.fps <= 1000.0) {
        anyhow::bail!("--fps {} is out of range: use a rate above 0 and up to 1000", opts.fps);
    }
    let limit = match opts.seconds.map(Duration::try_from_secs_f64) {
        Some(Ok(d)) if !d.is_zero() => Some(d),
        Some(_) => anyhow::bail!("--seconds: give a positive number of seconds"),
        None => None,
    };
    let neural = load_interactive(&opts.neural, true)?;
    let prepare = PrepareOptions {
        person_model: opts.person_model,
        ..auto_frame_options(opts.neural.models.as_deref(), opts.resolution, &opts.neural.options)?
    };
    let worker = neural.second_instance().context("loading the neural models for the live worker")?;
    let processor = EncodeProcessor::new(prepare, worker);
    let encodes = processor.encode_counter();
    let options = LiveOptions { segment: opts.segment.clone(), ..LiveOptions::default() };
    let start = Instant::now();
    let pipeline = LivePipeline::start(video_source(&opts.video, opts.fps), processor, options)?;
    let source = pipeline.describe().to_string();
    let mut reader = pipeline.reader();
    let camera = Camera::orbit(opts.yaw, 0.0, opts.view_size, opts.view_size);
    let (mut last, mut view_times) = (0u64, Vec::new());
    let renderer_name = if neural.renderer.is_some() { "neural" } else { "geometric" };
    while !pipeline.is_finished() && limit.is_none_or(|l| start.elapsed() < l) {
        let Some(done) = reader.get().filter(|d| opts.views && d.sequence != last).cloned() else {
            std::thread::sleep(Duration::from_millis(1));
            continue;
        };
        last = done.sequence;
        let t = Instant::now();
        let frame = &done.output;
        let mut view = match (&neural.renderer, &frame.neural) {
            (Some(decoder), Some(encoded)) => ViewRenderer::with_neural(
                &frame.input,
                OcclusionFill::default(),
                false,
                std::sync::Arc::clone(decoder),
                encoded.clone(),
            ),
            _ => ViewRenderer::new(&frame.input, OcclusionFill::default(), false),
        };
        view.render_person(&camera).with_context(|| format!("drawing frame {}", done.frame_index))?;
        view_times.push(t.elapsed());
    }
    let wall = start.elapsed();
    let stats = pipeline.stop();
    Ok(LiveBenchReport {
        source,
        renderer: renderer_name,
        wall,
        stats,
        encodes: encodes.load(Ordering::Relaxed),
        views: view_times.len() as u64,
        view_median: median(&view_times),
    })
}
