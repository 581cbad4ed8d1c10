//! Scripted sessions: the simulated PHANTOM pressed by its simulated hand through a fixed script,
//! stepped tick by tick with no thread and no wall clock, and recorded exactly as a live session
//! is (`softhaptic record-script`). The same script and build always write the same bytes,
//! which is what the recordings under `tests/sessions/` are.

use std::path::Path;

use softhaptic_device::device::{DeviceError, HapticDevice};
use softhaptic_device::metrics::{MetricsAccumulator, TickInput};
use softhaptic_device::replay::device_record;
use softhaptic_device::sim::{HandScript, SimFault, SimParams, SimulatedPhantom};
use softhaptic_proto::record::{BuildRecord, RecordingStats, SceneRecord};
use softhaptic_proto::wire::{ContactFrame, ServerMessage};

use super::SessionError;
use super::check::haptic_world;
use super::writer::SessionWriter;
use crate::scene::{Scene, SceneError};
use crate::stream::{EncodedFrame, metrics_message};

/// The built-in scene files the scripts use (the repository's `scenes/`).
const DEFAULT_SCENE_TOML: &str = include_str!("../../../scenes/default.toml");
const CONE_SCENE_TOML: &str = include_str!("../../../scenes/cone.toml");

/// Haptic ticks per contact frame: 1 kHz loop, 50 Hz frames.
const TICKS_PER_FRAME: u64 = 20;
/// Ticks between two `metrics` messages: once a second, as a live session streams them.
const TICKS_PER_METRICS: u64 = 1000;

/// The scripted sessions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ScriptName {
    /// The 10 mm sphere pressed into the liver, held, released (no slide).
    SpherePress,
    /// The 45° cone pressed into the liver, held, released.
    ConePress,
    /// The sphere pressed, then slid 10 mm along the surface, then released.
    Slide,
    /// The sphere pressed and held; the device disconnects for 200 ms in the middle of the hold.
    FaultMidPress,
    /// The slide again, by a loose hand (50 N/m) aiming 6 mm to the side of it, guided at full
    /// gain along the path the `slide` script's tool takes (`run --guide`).
    GuidedSlide,
}

impl ScriptName {
    /// Every script, in the order `record-script` writes them.
    pub const ALL: [ScriptName; 5] = [
        ScriptName::SpherePress,
        ScriptName::ConePress,
        ScriptName::Slide,
        ScriptName::FaultMidPress,
        ScriptName::GuidedSlide,
    ];

    fn scene_toml(self) -> &'static str {
        match self {
            ScriptName::ConePress => CONE_SCENE_TOML,
            _ => DEFAULT_SCENE_TOML,
        }
    }

    /// The script's name on the command line, and its file name under tests/sessions/.
    pub fn label(self) -> &'static str {
        match self {
            ScriptName::SpherePress => "sphere-press",
            ScriptName::ConePress => "cone-press",
            ScriptName::Slide => "slide",
            ScriptName::FaultMidPress => "fault-mid-press",
            ScriptName::GuidedSlide => "guided-slide",
        }
    }
}

/// Why a scripted recording failed.
#[derive(Debug, thiserror::Error)]
pub enum ScriptError {
    #[error("built-in scene of script {script}: {source}")]
    Scene {
        script: &'static str,
        #[source]
        source: Box<SceneError>,
    },
    #[error(transparent)]
    Session(#[from] SessionError),
    #[error("could not encode a contact frame: {0}")]
    Encode(#[from] serde_json::Error),
    #[error("the guided script's guide: {0}")]
    Guide(String),
}

/// The hand's script for `name` at the scene's press site.
fn hand_script(name: ScriptName, scene: &Scene) -> HandScript {
    // The live demonstration's press, once.
    let mut script = scene.hand_script();
    script.repeat = false;
    if !matches!(name, ScriptName::Slide | ScriptName::GuidedSlide) {
        script.slide_distance_m = 0.0;
        script.slide_s = 0.0;
    }
    script
}

/// Runs script `name` and records it to `out` (which must not exist). Returns the recorder's
/// final accounting.
pub fn record_script(name: ScriptName, out: &Path) -> Result<RecordingStats, ScriptError> {
    let label = format!("<built-in scene of script {}>", name.label());
    let scene = Scene::from_toml(name.scene_toml(), Path::new(&label), None).map_err(|e| {
        ScriptError::Scene {
            script: name.label(),
            source: Box::new(e),
        }
    })?;
    let script = hand_script(name, &scene);
    if name == ScriptName::GuidedSlide {
        return record_guided_slide(scene, name.scene_toml(), script, out);
    }
    record_hand(
        &scene,
        name.scene_toml(),
        script,
        &format!("script-{}", name.label()),
        out,
        |device| {
            if name == ScriptName::FaultMidPress {
                let (hold_start_s, hold_end_s) = script.hold_window_s();
                let middle_ns = ((hold_start_s + hold_end_s) * 0.5 * 1e9) as u64;
                device.schedule_fault(
                    middle_ns - 100_000_000,
                    middle_ns + 100_000_000,
                    SimFault::Error(DeviceError::Disconnected),
                );
            }
        },
    )
}

/// How far to the side of the expert's slide the guided trainee's hand aims.
pub const GUIDED_OFFSET_M: f64 = 0.006;
/// The guided trainee's grip: loose, letting the device lead.
pub const GUIDED_GRIP_N_PER_M: f64 = 50.0;

/// The `guided-slide` script: the expert's path is the tool's own path in the `slide` script,
/// simulated here tick by tick (the same ticks `slide.mcap` holds), resampled as `run --guide`
/// resamples a recording; the trainee's hand aims [`GUIDED_OFFSET_M`] across the slide with a
/// [`GUIDED_GRIP_N_PER_M`] grip.
fn record_guided_slide(
    mut scene: Scene,
    scene_toml: &str,
    script: HandScript,
    out: &Path,
) -> Result<RecordingStats, ScriptError> {
    let params = SimParams {
        limits: scene.device_limits,
        ..SimParams::default()
    };
    let mut expert = SimulatedPhantom::with_params(script, params);
    let mut world = haptic_world(&scene);
    let ticks = ((script.duration_s() + 0.5) * 1e9) as u64 / params.period_ns.max(1);
    let mut samples = Vec::with_capacity(ticks as usize);
    for _ in 0..ticks {
        let read = expert.read();
        let state = world.step(read);
        let _ = expert.command_force(state.force_n);
        if let Ok(s) = read {
            let depth_m = if state.in_contact { state.depth_m } else { 0.0 };
            samples.push((s.tip_in_world.position_m, depth_m, state.force_n.length()));
        }
    }
    let path = softhaptic_device::guide::GuidePath::resample_with_forces(
        samples,
        crate::guide::GUIDE_SPACING_M,
    )
    .map_err(|e| ScriptError::Guide(e.to_string()))?;
    scene
        .set_guide(softhaptic_proto::guide::RecordedGuide {
            source: "slide.mcap".into(),
            source_scene: Some("default.toml".into()),
            points_m: path.points_m().iter().map(|p| p.to_array()).collect(),
            depths_m: path.depths_m().to_vec(),
            forces_n: Some(path.forces_n().to_vec()),
            spacing_m: path.spacing_m(),
            params: softhaptic_proto::GuideParams::default(),
            gain: softhaptic_proto::GuideGain::Fixed { gain: 1.0 },
        })
        .map_err(ScriptError::Guide)?;
    let mut trainee = script;
    let across = trainee
        .surface_normal
        .cross(trainee.slide_direction)
        .normalize_or_zero();
    trainee.surface_point_m += across * GUIDED_OFFSET_M;
    let device = SimulatedPhantom::with_params(
        trainee,
        SimParams {
            hand_stiffness_n_per_m: GUIDED_GRIP_N_PER_M,
            ..params
        },
    );
    record_device(&scene, scene_toml, device, "script-guided-slide", out)
}

/// Records the simulated PHANTOM moved by `script` in `scene` (whose text is `scene_toml`) to
/// `out` (which must not exist), tick by tick without a wall clock, as a live session records;
/// `prepare` may schedule the device's faults first. Tests record the scripted attempts of an
/// exercise through it.
pub fn record_hand(
    scene: &Scene,
    scene_toml: &str,
    script: HandScript,
    session_id: &str,
    out: &Path,
    prepare: impl FnOnce(&mut SimulatedPhantom),
) -> Result<RecordingStats, ScriptError> {
    let params = SimParams {
        limits: scene.device_limits,
        ..SimParams::default()
    };
    let mut device = SimulatedPhantom::with_params(script, params);
    prepare(&mut device);
    record_device(scene, scene_toml, device, session_id, out)
}

/// [`record_hand`] with a simulated device already made (another grip, faults scheduled): its
/// script, and half a second after it, recorded to `out` (which must not exist).
pub fn record_device(
    scene: &Scene,
    scene_toml: &str,
    mut device: SimulatedPhantom,
    session_id: &str,
    out: &Path,
) -> Result<RecordingStats, ScriptError> {
    let params = *device.params();
    let script = *device.script();
    let mut world = haptic_world(scene);

    let build = BuildRecord {
        session_format_version: softhaptic_proto::record::SESSION_FORMAT_VERSION,
        protocol_version: softhaptic_proto::wire::PROTOCOL_VERSION,
        writer: crate::routes::SERVER_NAME.into(),
        git_commit: super::git_commit(),
        session_id: session_id.to_owned(),
        // No wall clock in a scripted session: the same script and build write the same bytes,
        // so a regenerated recording only changes when the forces do.
        started_unix_ns: 0,
    };
    let scene_record = SceneRecord {
        message: scene.message(),
        scene_toml: scene_toml.to_owned(),
        scene_file: None,
        period_ns: params.period_ns,
        meshes: scene.recorded_meshes(),
        inclusions: scene.recorded_inclusions(),
        guide: scene.recorded_guide(),
    };
    let mut writer = SessionWriter::create(out, &build, &scene_record)?;

    // Half a second of rest after the script ends, so the release is complete in the file.
    let duration_ns = ((script.duration_s() + 0.5) * 1e9) as u64;
    let ticks = duration_ns / params.period_ns.max(1);
    let mut seq = 0;
    // The trainee's metrics from every tick, recorded once a second and at the end as a live
    // session records them, so that `info`, `export` and `check` read them from this file too.
    let mut metrics = MetricsAccumulator::new(scene.safe_force_n);
    for k in 0..ticks {
        let read = device.read();
        let state = world.step(read);
        // The simulated device accepts every command; a refusal would only mean zero force.
        let _ = device.command_force(state.force_n);
        let record = device_record(&read, &state);
        metrics.update(&TickInput::from_record(&record));
        writer.write_device(&record)?;
        if (k + 1).is_multiple_of(TICKS_PER_METRICS) {
            let message = ServerMessage::Metrics(metrics_message(&metrics.metrics(), false));
            writer.write_metrics(&message.encode()?)?;
        }
        if k.is_multiple_of(TICKS_PER_FRAME) {
            let deformed_radius_m = if state.in_contact {
                scene.calibration.deformed_radius_m(state.depth_m)
            } else {
                0.0
            };
            let frame = ContactFrame::from_state(&state, seq, deformed_radius_m, 0);
            let text = EncodedFrame::new(&frame)?.text_for(0);
            writer.write_contact(state.time_ns, text.as_str())?;
            seq += 1;
        }
    }
    let message = ServerMessage::Metrics(metrics_message(&metrics.metrics(), true));
    writer.write_metrics(&message.encode()?)?;
    Ok(writer.finish()?)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use crate::reader::Recording;
    use crate::tools::Info;

    #[test]
    fn a_scripted_recording_holds_the_trainees_metrics_once_a_second_and_at_the_end() {
        let dir = std::env::temp_dir().join(format!("softhaptic-script-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("cone-press.mcap");
        let _ = std::fs::remove_file(&path);
        record_script(ScriptName::ConePress, &path).unwrap();
        let r = Recording::open(&path).unwrap();
        let seconds = r.device.len() as u64 / TICKS_PER_METRICS;
        assert!(seconds >= 2, "{} ticks", r.device.len());
        // One a second, then the final one.
        assert_eq!(r.metrics.len() as u64, seconds + 1);
        assert!(r.metrics[..r.metrics.len() - 1].iter().all(|m| !m.is_final));
        let info = Info::of(&r);
        let (recorded, same) = info.recorded_metrics.clone().unwrap();
        assert!(
            recorded.is_final && same,
            "{recorded:?} vs {:?}",
            info.metrics
        );
        assert_eq!(recorded.ticks, r.device.len() as u64);
        // The press is in it: contact time and a peak force above zero.
        assert!(recorded.time_in_contact_s > 0.5 && recorded.peak_force_n > 0.1);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
