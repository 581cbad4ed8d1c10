//! What recording costs the haptic loop: `softhaptic recording-overhead`.
//!
//! Runs the real 1 kHz loop thread (the built-in scene: liver, sphere, simulated PHANTOM pressing
//! over and over) twice for the same time, once without a tick sink and once with the session
//! recorder draining its ring to a file, and reports the loop's period-error percentiles side by
//! side, with the recording's size per minute. A measurement, not a test: numbers depend on the
//! machine and its load.

use std::fmt;
use std::path::Path;
use std::time::Duration;

use softhaptic_device::haptic_loop::{HapticLoop, LoopConfig};
use softhaptic_device::sim::{SimParams, SimulatedPhantom};
use softhaptic_device::stats::LoopStats;
use softhaptic_proto::record::{BuildRecord, SESSION_FORMAT_VERSION, SceneRecord};
use softhaptic_proto::wire::PROTOCOL_VERSION;

use super::check::haptic_world;
use super::writer::Recorder;
use super::writer::TICK_RING_CAPACITY;
use crate::routes::SERVER_NAME;
use crate::scene::Scene;

/// One run's figures.
#[derive(Debug, Clone, Copy)]
pub struct RunFigures {
    pub stats: LoopStats,
    /// Recording size and ticks written (none for the run without recording).
    pub file_bytes: Option<u64>,
    pub ticks_recorded: u64,
    pub ticks_dropped: u64,
}

/// Both runs.
#[derive(Debug, Clone, Copy)]
pub struct OverheadReport {
    pub seconds: f64,
    pub realtime_granted: bool,
    pub without: RunFigures,
    pub with: RunFigures,
}

fn run_once(
    scene: &Scene,
    seconds: f64,
    realtime: bool,
    record_to: Option<&Path>,
) -> anyhow::Result<(RunFigures, bool)> {
    let script = scene.hand_script();
    let params = SimParams {
        limits: scene.device_limits,
        ..SimParams::default()
    };
    let device = SimulatedPhantom::with_params(script, params);
    let (sink, recorder) = match record_to {
        Some(path) => {
            let build = BuildRecord {
                session_format_version: SESSION_FORMAT_VERSION,
                protocol_version: PROTOCOL_VERSION,
                writer: SERVER_NAME.into(),
                git_commit: super::git_commit(),
                session_id: "recording-overhead".into(),
                started_unix_ns: super::unix_now_ns(),
            };
            let scene_record = SceneRecord {
                message: scene.message(),
                scene_toml: include_str!("../../../scenes/default.toml").into(),
                scene_file: None,
                period_ns: params.period_ns,
                meshes: scene.recorded_meshes(),
                inclusions: scene.recorded_inclusions(),
                guide: scene.recorded_guide(),
            };
            let (producer, consumer) = rtrb::RingBuffer::new(TICK_RING_CAPACITY);
            let recorder = Recorder::start(path, &build, &scene_record, consumer)?;
            (Some(producer), Some(recorder))
        }
        None => (None, None),
    };
    let haptic = HapticLoop::spawn(
        Box::new(device),
        haptic_world(scene),
        LoopConfig {
            period_ns: params.period_ns,
            realtime,
            tick_sink: sink,
            ..LoopConfig::default()
        },
    )?;
    let granted = haptic.realtime().granted();
    // The measurement runs on the main thread with no async runtime: nothing else waits for it.
    #[allow(clippy::disallowed_methods)]
    std::thread::sleep(Duration::from_secs_f64(seconds));
    let stats = haptic.stop();
    let (file_bytes, ticks_recorded, ticks_dropped) = match (recorder, record_to) {
        (Some(r), Some(path)) => {
            let rec = r.finish()?;
            let len = std::fs::metadata(path)?.len();
            (Some(len), rec.ticks_recorded, rec.ticks_dropped)
        }
        _ => (None, 0, 0),
    };
    Ok((
        RunFigures {
            stats,
            file_bytes,
            ticks_recorded,
            ticks_dropped,
        },
        granted,
    ))
}

/// Runs the loop without, then with recording, `seconds` each; the recording goes to `dir`.
pub fn measure(seconds: f64, realtime: bool, dir: &Path) -> anyhow::Result<OverheadReport> {
    if !(seconds.is_finite() && seconds > 0.0) {
        anyhow::bail!("--seconds must be a positive number, got {seconds}");
    }
    let scene = Scene::builtin_default()?;
    std::fs::create_dir_all(dir)?;
    let path = dir.join(format!("recording-overhead-{}.mcap", std::process::id()));
    let _ = std::fs::remove_file(&path);
    let (without, granted) = run_once(&scene, seconds, realtime, None)?;
    let (with, _) = run_once(&scene, seconds, realtime, Some(&path))?;
    Ok(OverheadReport {
        seconds,
        realtime_granted: granted,
        without,
        with,
    })
}

impl fmt::Display for OverheadReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let us = |ns: u64| ns as f64 * 1e-3;
        writeln!(
            f,
            "haptic loop, {} s per run, real-time scheduling {}",
            self.seconds,
            if self.realtime_granted {
                "granted"
            } else {
                "not granted"
            }
        )?;
        writeln!(
            f,
            "{:<18} {:>8} {:>10} {:>10} {:>10} {:>10} {:>9} {:>11}",
            "run", "ticks", "p50 µs", "p99 µs", "p99.9 µs", "max µs", "overruns", "compute p99"
        )?;
        for (name, r) in [
            ("without recording", &self.without),
            ("with recording", &self.with),
        ] {
            let s = &r.stats;
            writeln!(
                f,
                "{:<18} {:>8} {:>10.1} {:>10.1} {:>10.1} {:>10.1} {:>9} {:>9.1} µs",
                name,
                s.ticks,
                us(s.period_error_p50_ns),
                us(s.period_error_p99_ns),
                us(s.period_error_p999_ns),
                us(s.period_error_max_ns),
                s.overruns,
                us(s.compute_p99_ns),
            )?;
        }
        if let Some(bytes) = self.with.file_bytes {
            let minutes = self.with.ticks_recorded as f64 / 60_000.0;
            writeln!(
                f,
                "recording: {} ticks written, {} dropped, {} bytes = {:.2} MB per minute of session",
                self.with.ticks_recorded,
                self.with.ticks_dropped,
                bytes,
                if minutes > 0.0 {
                    bytes as f64 / minutes / 1e6
                } else {
                    0.0
                }
            )?;
        }
        Ok(())
    }
}
