//! Haptic guidance from a recording, end to end without a wall clock: the shipped slide
//! recording guides a trainee whose hand aims 6 mm to the side of the expert's path; the
//! trainee's session is recorded, read back and checked bit for bit like any other.
//!
//! The trainee's hand yields (a loose 50 N/m grip, as a trainee letting the device lead): at
//! full gain the tool is pulled most of the way to the path, at none it stays where the hand
//! aims. Every tick the commanded force stays within the device's peak, the guide's own force
//! within its cap, and neither jumps.

use std::path::{Path, PathBuf};

use glam::DVec3;
use softhaptic_device::guide::GuidePath;
use softhaptic_device::sim::{SimParams, SimulatedPhantom};
use softhaptic_proto::{ContactFlags, GuideGain, GuideParams};
use softhaptic_server::scene::Scene;
use softhaptic_server::session::check::{CheckOverrides, check};
use softhaptic_server::session::guide::{GuideLoadError, guide_from_file};
use softhaptic_server::session::reader::Recording;
use softhaptic_server::session::script::record_device;

const OFFSET_M: f64 = 0.006;

fn expert() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("sessions/slide.mcap")
}

fn default_scene() -> (Scene, &'static str) {
    let text = include_str!("../../scenes/default.toml");
    let scene = Scene::from_toml(text, Path::new("default.toml"), None).expect("default scene");
    (scene, text)
}

/// What one guided session did.
#[derive(Debug)]
struct Tracking {
    /// Mean and largest distance of the tip from the expert's path over the slide, m.
    mean_error_m: f64,
    max_error_m: f64,
    /// Largest commanded force, and largest guiding force, N.
    peak_force_n: f64,
    peak_guide_n: f64,
    /// Largest change of the guiding force from one tick to the next, N.
    largest_guide_step_n: f64,
    /// Ticks on which the passivity observer added damping.
    passivity_ticks: usize,
    /// Ticks whose replayed force differed from the recorded one.
    differing_ticks: u64,
    /// The deviation from the expert after time alignment, as `info` prints it.
    deviation: softhaptic_device::deviation::Deviation,
}

/// The trainee's session at `gain`, recorded into `dir` and read back.
fn guided_session(dir: &Path, gain: f64) -> Tracking {
    let (mut scene, text) = default_scene();
    let guide = guide_from_file(
        &expert(),
        &scene,
        GuideParams::default(),
        GuideGain::Fixed { gain },
    )
    .expect("the slide recording guides the default scene");
    let path = GuidePath::from_recorded(&guide).expect("its path");
    scene.set_guide(guide).expect("settings in range");
    // The expert's slide, aimed 6 mm to its side (across the slide, along the surface).
    let mut script = scene.hand_script();
    script.repeat = false;
    let across = script
        .surface_normal
        .cross(script.slide_direction)
        .normalize();
    script.surface_point_m += across * OFFSET_M;
    let params = SimParams {
        limits: scene.device_limits,
        hand_stiffness_n_per_m: 50.0,
        ..SimParams::default()
    };
    let (slide_from_s, slide_to_s) = {
        let (_, hold_end_s) = script.hold_window_s();
        (hold_end_s, hold_end_s + script.slide_s)
    };
    let out = dir.join(format!("guided-{gain}.mcap"));
    let _ = std::fs::remove_file(&out);
    record_device(
        &scene,
        text,
        SimulatedPhantom::with_params(script, params),
        "guided",
        &out,
    )
    .expect("recorded");

    let recording = Recording::open(&out).expect("read back");
    assert!(
        recording.scene.guide.is_some(),
        "the recording keeps the guide"
    );
    let mut errors = Vec::new();
    let mut tracking = Tracking {
        mean_error_m: 0.0,
        max_error_m: 0.0,
        peak_force_n: 0.0,
        peak_guide_n: 0.0,
        largest_guide_step_n: 0.0,
        passivity_ticks: 0,
        differing_ticks: 0,
        deviation: softhaptic_device::deviation::Deviation {
            mean_path_m: 0.0,
            max_path_m: 0.0,
            mean_force_n: 0.0,
            pairs: 0,
        },
    };
    let mut previous_guide = DVec3::ZERO;
    for r in &recording.device {
        let g = r
            .guide
            .expect("every tick of a guided session says its guidance");
        let t_s = r.time_ns as f64 * 1e-9;
        tracking.peak_force_n = tracking
            .peak_force_n
            .max(DVec3::from_array(r.force_n).length());
        tracking.peak_guide_n = tracking.peak_guide_n.max(g.force_n.length());
        tracking.largest_guide_step_n = tracking
            .largest_guide_step_n
            .max(g.force_n.distance(previous_guide));
        previous_guide = g.force_n;
        if r.flags & ContactFlags::PASSIVITY_DAMPING.bits() != 0 {
            tracking.passivity_ticks += 1;
        }
        if (slide_from_s..slide_to_s).contains(&t_s)
            && let Some(s) = &r.sample
        {
            let tip = DVec3::from_array(s.tip_position_m);
            let (_, d) = path.closest_in(tip, 0.0, path.length_m());
            errors.push(d);
        }
    }
    assert!(!errors.is_empty(), "the slide is in the recording");
    tracking.mean_error_m = errors.iter().sum::<f64>() / errors.len() as f64;
    tracking.max_error_m = errors.iter().copied().fold(0.0, f64::max);
    let report = check(&recording, CheckOverrides::default()).expect("checked");
    tracking.differing_ticks = report.differing_ticks;
    let summary = softhaptic_server::session::guide::summary(&recording).expect("guided");
    tracking.deviation = summary.deviation.expect("captured at some point");
    tracking
}

#[test]
fn a_yielding_hand_is_pulled_to_the_experts_path_and_drifts_without_the_pull() {
    let dir = softhaptic_tests::scratch_dir("guidance");
    let peak_n = softhaptic_device::device::DeviceLimits::PHANTOM_DESKTOP.peak_force_n;
    let cap_n = GuideParams::default().max_force_n;
    let mut mean_errors = Vec::new();
    let mut passivity_ticks = Vec::new();
    let mut aligned = Vec::new();
    for gain in [0.0, 0.25, 0.5, 1.0] {
        let t = guided_session(&dir, gain);
        println!(
            "gain {gain:4}: tracking error over the slide mean {:.2} mm, max {:.2} mm; \
             after time alignment path {:.2} mm, force {:.3} N; \
             peak force {:.2} N, guide {:.2} N, largest guide step {:.4} N; \
             passivity ticks {}",
            t.mean_error_m * 1e3,
            t.max_error_m * 1e3,
            t.deviation.mean_path_m * 1e3,
            t.deviation.mean_force_n,
            t.peak_force_n,
            t.peak_guide_n,
            t.largest_guide_step_n,
            t.passivity_ticks
        );
        assert_eq!(t.differing_ticks, 0, "the check replays the guided forces");
        assert!(t.peak_force_n <= peak_n + 1e-9, "{t:?}");
        assert!(t.peak_guide_n <= cap_n + 1e-9, "{t:?}");
        // A 0.2 s ramp and a damped spring: no step the hand would feel as a jolt. What steps
        // remain (up to 0.08 N at full gain) are the damping of the encoders' velocity noise.
        assert!(t.largest_guide_step_n < 0.1, "{t:?}");
        // The pull books its own energy and stays passive: it adds no work for the contact's
        // controller to damp (the unguided press has its own few ticks).
        passivity_ticks.push(t.passivity_ticks);
        mean_errors.push(t.mean_error_m);
        aligned.push(t.deviation.mean_path_m);
    }
    let (free, full) = (mean_errors[0], mean_errors[3]);
    // Unguided the tool stays where the hand aims (the contact's own pull aside)...
    assert!(free > 0.8 * OFFSET_M, "unguided {free}");
    // ...guided at full gain, a 150 N/m pull against a 50 N/m grip leaves about a quarter.
    assert!(full < 0.4 * OFFSET_M, "guided {full}");
    assert!(
        passivity_ticks.iter().all(|&n| n <= passivity_ticks[0]),
        "passivity ticks by gain: {passivity_ticks:?}"
    );
    // More gain, closer: over the slide, and over the whole guided stretch aligned in time.
    assert!(
        mean_errors.windows(2).all(|w| w[1] < w[0]),
        "{mean_errors:?}"
    );
    assert!(aligned.windows(2).all(|w| w[1] < w[0]), "{aligned:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_recording_of_another_tool_or_object_is_refused_naming_the_field() {
    let cone_text = include_str!("../../scenes/cone.toml");
    let cone = Scene::from_toml(cone_text, Path::new("cone.toml"), None).expect("cone scene");
    let err = guide_from_file(
        &expert(),
        &cone,
        GuideParams::default(),
        GuideGain::default(),
    )
    .expect_err("a sphere's recording cannot guide a cone");
    assert!(matches!(err, GuideLoadError::OtherScene { .. }), "{err}");
    let text = err.to_string();
    assert!(
        text.contains("tool.shape") && text.contains("cone"),
        "{text}"
    );

    let (scene, default_text) = default_scene();
    let moved = default_text.replacen(
        "position_m = [0.0, 0.0, 0.0]",
        "position_m = [0.0, 0.01, 0.0]",
        1,
    );
    let moved = Scene::from_toml(&moved, Path::new("moved.toml"), None).expect("moved scene");
    let text = guide_from_file(
        &expert(),
        &moved,
        GuideParams::default(),
        GuideGain::default(),
    )
    .expect_err("the object moved")
    .to_string();
    assert!(text.contains("object.position_m"), "{text}");

    // Settings out of range are refused naming the field.
    let text = guide_from_file(
        &expert(),
        &scene,
        GuideParams {
            max_force_n: -1.0,
            ..GuideParams::default()
        },
        GuideGain::default(),
    )
    .expect_err("a negative cap")
    .to_string();
    assert!(text.contains("params.max_force_n"), "{text}");
}
