//! The replay check: do the recorded device readings, fed through this build's haptic world, give
//! the recorded forces bit for bit? (docs/design.md, invariant 5.)
//!
//! The world is rebuilt from the scene file stored in the recording, the readings are played by a
//! [`ReplayDevice`] (recorded errors included) through [`HapticWorld::step`] with no thread and no
//! clock, and every commanded force is compared with the recorded one by its f64 bits. Scene
//! overrides ([`CheckOverrides`]) exist so that a test can show that a deliberate change is caught
//! and reported at its first tick.

use std::fmt;
use std::path::PathBuf;

use glam::DVec3;
use softhaptic_device::replay::ReplayDevice;
use softhaptic_device::world::HapticWorld;

use super::reader::Recording;
use crate::scene::{Scene, SceneError};

/// Changes to the recorded scene before the replay (a check with any of them is expected to fail
/// when the change matters).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CheckOverrides {
    /// Replaces the scene's damping along the normal, N·s/m.
    pub damping_n_s_per_m: Option<f64>,
}

/// Why a check could not run (as opposed to running and finding a difference).
#[derive(Debug, thiserror::Error)]
pub enum CheckError {
    #[error("{path}: the recorded scene does not load: {source}")]
    Scene {
        path: PathBuf,
        #[source]
        source: Box<SceneError>,
    },
    #[error("{path}: --damping must be finite and >= 0, got {value}")]
    Override { path: PathBuf, value: f64 },
    #[error("{path}: the recording has no device ticks to check")]
    Empty { path: PathBuf },
    #[error(
        "{path}: the recording starts at tick {first} instead of 0: the world's state before it is unknown"
    )]
    StartsLate { path: PathBuf, first: u64 },
}

/// The first tick whose replayed force differs from the recorded one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceDifference {
    pub tick: u64,
    pub time_ns: u64,
    pub recorded_n: [f64; 3],
    pub replayed_n: [f64; 3],
}

impl ForceDifference {
    /// replayed − recorded.
    pub fn difference_n(&self) -> DVec3 {
        DVec3::from_array(self.replayed_n) - DVec3::from_array(self.recorded_n)
    }
}

/// The outcome of a check.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckReport {
    pub path: PathBuf,
    /// Ticks replayed and compared.
    pub ticks_compared: u64,
    /// The first tick that differs, if any.
    pub first_difference: Option<ForceDifference>,
    /// Ticks whose force differs, in all.
    pub differing_ticks: u64,
    /// Where the recording has a gap (ticks the recorder dropped, or a damaged part of the file
    /// the reader skipped): the last tick before it, the first after, and whether the gap lies
    /// in a damaged part. The check stops there, because the world's state past a missing
    /// reading cannot be reproduced.
    pub stopped_at_gap: Option<(u64, u64, bool)>,
    /// Every replayed force, in tick order (for determinism tests).
    pub replayed_n: Vec<[f64; 3]>,
    /// The trainee's metrics of the replayed ticks, computed by the replaying world as the live
    /// loop computed them.
    pub metrics: softhaptic_device::metrics::TraineeMetrics,
    /// When the recording holds the live loop's final metrics and every tick was replayed:
    /// whether the replay's are the same (`None` when there is nothing to compare).
    pub metrics_difference: Option<MetricsDifference>,
    /// Whether the replay's metrics were held against recorded ones at all.
    pub metrics_compared: bool,
}

/// The replay's trainee metrics differ from those the live loop recorded at the session's end.
#[derive(Debug, Clone, PartialEq)]
pub struct MetricsDifference {
    pub recorded: softhaptic_proto::wire::MetricsMessage,
    pub replayed: softhaptic_proto::wire::MetricsMessage,
}

impl CheckReport {
    /// True when every compared force is identical, the trainee's metrics are the recorded
    /// ones (when recorded), and nothing was left unchecked.
    pub fn passed(&self) -> bool {
        self.first_difference.is_none()
            && self.stopped_at_gap.is_none()
            && self.metrics_difference.is_none()
    }
}

impl fmt::Display for CheckReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let path = self.path.display();
        match &self.first_difference {
            None => write!(
                f,
                "{path}: {} ticks replayed, every force identical bit for bit{}",
                self.ticks_compared,
                if self.metrics_compared && self.metrics_difference.is_none() {
                    "; the trainee's metrics are the ones recorded"
                } else {
                    ""
                }
            )?,
            Some(d) => {
                let diff = d.difference_n();
                write!(
                    f,
                    "{path}: forces differ at tick {} (device time {:.3} s), first of {} differing ticks out of {}:\n  \
                     recorded force_n = {:?}\n  replayed force_n = {:?}\n  difference       = {:?} (|Δ| = {:e} N)",
                    d.tick,
                    d.time_ns as f64 * 1e-9,
                    self.differing_ticks,
                    self.ticks_compared,
                    d.recorded_n,
                    d.replayed_n,
                    diff.to_array(),
                    diff.length(),
                )?;
            }
        }
        if let Some(d) = &self.metrics_difference {
            let json = |m| serde_json::to_string(m).unwrap_or_default();
            write!(
                f,
                "\n{path}: the trainee's metrics differ from those recorded at the session's end:\n  \
                 recorded {}\n  replayed {}",
                json(&d.recorded),
                json(&d.replayed)
            )?;
        }
        if let Some((after, next, damaged)) = self.stopped_at_gap {
            let cause = if damaged {
                "the ticks between were in a damaged part of the file"
            } else {
                "ticks dropped by the recorder"
            };
            write!(
                f,
                "\n{path}: stopped after tick {after}: the next recorded tick is {next} ({cause}), so the rest cannot be checked"
            )?;
        }
        Ok(())
    }
}

/// The haptic world a scene describes (the same construction as the live server's).
pub fn haptic_world(scene: &Scene) -> HapticWorld {
    scene.haptic_world()
}

/// Loads the scene a recording was made with, from the recording alone
/// ([`Scene::from_recording`]): the scene text it stores, the contact model, validity limits and
/// calibration table of its `scene` message (a recording made before the message named its
/// model reads as the paper's law, which is what those servers ran), and the meshes it kept.
pub fn recorded_scene(recording: &Recording) -> Result<Scene, CheckError> {
    let s = &recording.scene;
    // Names the scene in errors only: nothing is read from where the scene file was.
    let label = PathBuf::from(match &s.scene_file {
        Some(file) => format!("{file} (as recorded in {})", recording.path.display()),
        None => format!("<scene of {}>", recording.path.display()),
    });
    let mut scene = Scene::from_recording(s, &label).map_err(|e| CheckError::Scene {
        path: recording.path.clone(),
        source: Box::new(e),
    })?;
    // The limits the session ran with: a real device's are the tighter of its own and the
    // preset's, known only once it was open, and the `scene` message recorded them.
    let d = &s.message.device;
    scene.device_limits.peak_force_n = d.peak_force_n;
    scene.device_limits.continuous_force_n = d.continuous_force_n;
    scene.device_limits.max_stiffness_n_per_m = d.max_stiffness_n_per_m;
    scene.device_limits.damping_n_s_per_m = d.damping_n_s_per_m;
    scene.device_limits.workspace_radius_m = d.workspace_radius_m;
    scene.device_label = Some(d.name.clone());
    scene.device_renders_force = d.force_feedback;
    Ok(scene)
}

/// Replays `recording` and compares every force.
pub fn check(recording: &Recording, overrides: CheckOverrides) -> Result<CheckReport, CheckError> {
    let path = recording.path.clone();
    let mut scene = recorded_scene(recording)?;
    if let Some(d) = overrides.damping_n_s_per_m {
        if !(d.is_finite() && d >= 0.0) {
            return Err(CheckError::Override { path, value: d });
        }
        scene.force.damping_n_s_per_m = d;
    }
    let records = &recording.device;
    let Some(first) = records.first() else {
        return Err(CheckError::Empty { path });
    };
    if first.tick != 0 {
        return Err(CheckError::StartsLate {
            path,
            first: first.tick,
        });
    }
    // Only the run of consecutive ticks from 0 can be reproduced.
    let contiguous = records
        .windows(2)
        .position(|w| w[1].tick != w[0].tick + 1)
        .map(|i| i + 1)
        .unwrap_or(records.len());
    let stopped_at_gap = (contiguous < records.len()).then(|| {
        let (before, after) = (&records[contiguous - 1], &records[contiguous]);
        // A span the reader skipped as damaged that lies between the two ticks (or, without its
        // times, anywhere: the reader could not tell when it was).
        let damaged = recording.lost.iter().any(|span| match span.time_ns {
            Some((from, to)) => from <= after.time_ns && to >= before.time_ns,
            None => true,
        });
        (before.tick, after.tick, damaged)
    });
    let records = &records[..contiguous];

    let mut world = haptic_world(&scene);
    let mut device = ReplayDevice::from_records(scene.device_limits, records);
    let mut replayed_n = Vec::with_capacity(records.len());
    let mut first_difference = None;
    let mut differing_ticks = 0;
    for rec in records {
        // The same tick as the loop's, refusals of the recorded device included.
        let state = world.tick(&mut device).state;
        let replayed = state.force_n.to_array();
        replayed_n.push(replayed);
        let same = replayed
            .iter()
            .zip(rec.force_n.iter())
            .all(|(a, b)| a.to_bits() == b.to_bits());
        if !same {
            differing_ticks += 1;
            if first_difference.is_none() {
                first_difference = Some(ForceDifference {
                    tick: rec.tick,
                    time_ns: rec.time_ns,
                    recorded_n: rec.force_n,
                    replayed_n: replayed,
                });
            }
        }
    }
    let metrics = world.metrics();
    // The live loop's final metrics cover every tick it ran: comparable when the replay ran
    // them all too (no gap, and the recording was not cut short of its last ticks).
    let comparable = recording
        .final_metrics()
        .filter(|recorded| stopped_at_gap.is_none() && recorded.ticks == metrics.ticks);
    let metrics_compared = comparable.is_some();
    let metrics_difference = comparable.and_then(|recorded| {
        let replayed = crate::stream::metrics_message(&metrics, true);
        (!same_metrics(recorded, &replayed)).then(|| MetricsDifference {
            recorded: recorded.clone(),
            replayed,
        })
    });
    Ok(CheckReport {
        path,
        ticks_compared: records.len() as u64,
        first_difference,
        differing_ticks,
        stopped_at_gap,
        replayed_n,
        metrics,
        metrics_difference,
        metrics_compared,
    })
}

/// Equal metrics messages, comparing floating-point values by their bits (a recorded NaN is
/// the same as a replayed NaN; the file keeps every bit of a finite value).
pub fn same_metrics(
    a: &softhaptic_proto::wire::MetricsMessage,
    b: &softhaptic_proto::wire::MetricsMessage,
) -> bool {
    let floats = |m: &softhaptic_proto::wire::MetricsMessage| {
        [
            m.peak_force_n,
            m.peak_force_time_s,
            m.safe_force_n,
            m.time_above_safe_s,
            m.time_in_contact_s,
            m.path_length_in_contact_m,
            m.mean_squared_jerk_m2_s6,
        ]
        .map(f64::to_bits)
    };
    floats(a) == floats(b)
        && (a.pushes, a.device_fault_ticks, a.ticks, a.is_final)
            == (b.pushes, b.device_fault_ticks, b.ticks, b.is_final)
        && a.flags_raised == b.flags_raised
}
