//! `softhaptic info` and `softhaptic export`: what a recording holds, and its channels as CSV.
//!
//! # Layout
//! - this file: the trainee's metrics of a recording, computed from its ticks as the live loop
//!   computed them, which both commands report.
//! - `info.rs`: [`Info`], the summary `info` prints (counts, lost ticks, fault gaps, flags,
//!   metrics, marks, how the file ended).
//! - `export.rs`: [`export`], the channels as CSV and the metrics and marks as JSON.

mod export;
mod info;

pub use export::{Exported, export};
pub use info::{FaultSpan, Info};

use softhaptic_device::metrics::{MetricsAccumulator, TickInput, TraineeMetrics};

use super::reader::Recording;

/// The part of a recorded scene's TOML the safe force is read from, typed as the scene's own
/// schema types it (`scene::file::HapticsSection`): a number, whole (`1`) or not (`1.5`).
/// Everything else in the text is ignored here; the scene loader checks it.
#[derive(serde::Deserialize)]
struct SafeForceOnly {
    #[serde(default)]
    haptics: SafeForceHaptics,
}

#[derive(serde::Deserialize, Default)]
struct SafeForceHaptics {
    safe_force_n: Option<f64>,
}

/// The safe force a recording's scene set (`[haptics] safe_force_n`, read as the scene loader
/// reads it); the one the live loop's `metrics` messages carry when the recorded text does not
/// parse; else the default (what a scene without one runs with).
pub fn recorded_safe_force_n(r: &Recording) -> f64 {
    let usable = |f: &f64| f.is_finite() && *f > 0.0;
    match toml::from_str::<SafeForceOnly>(&r.scene.scene_toml) {
        Ok(scene) => scene.haptics.safe_force_n,
        Err(_) => r.metrics.first().map(|m| m.safe_force_n),
    }
    .filter(usable)
    .unwrap_or(softhaptic_device::world::DEFAULT_SAFE_FORCE_N)
}

/// The trainee's metrics of a recording, from its ticks in order: the live server's, exactly.
pub fn recording_metrics(r: &Recording) -> TraineeMetrics {
    let mut acc = MetricsAccumulator::new(recorded_safe_force_n(r));
    for d in &r.device {
        acc.update(&TickInput::from_record(d));
    }
    acc.metrics()
}
