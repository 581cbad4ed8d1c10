//! The contact model of a scene's object: the `[object.model]` table and the limits file are
//! validated with the file, the field and the value; the server builds only the model of the
//! scene's tool; the `scene` message tells viewers which model runs; the validity flags of a
//! closed-loop run use the measured limits of that model; and recordings, with or without the
//! model in their `scene` message, replay with the model they ran.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::path::{Path, PathBuf};
use std::time::Duration;

use softhaptic_device::device::HapticDevice;
use softhaptic_device::sim::{SimParams, SimulatedPhantom};
use softhaptic_proto::model::{MeasuredLimit, ToolKind};
use softhaptic_proto::wire::ServerMessage;
use softhaptic_proto::{ContactFlags, ModelLimitsFile, ModelSpec, ToolShape};
use softhaptic_server::app;
use softhaptic_server::scene::{Scene, SceneError};
use softhaptic_tests::repo_scenes;
use softhaptic_tests::{Viewer, start_default, test_options};

const WAIT: Duration = Duration::from_secs(10);

/// A fresh directory for one test's files.
fn scratch(name: &str) -> PathBuf {
    softhaptic_tests::scratch_dir(&format!("model-{name}"))
}

/// A sphere scene with a model table (`{model}` is replaced by its fields).
const SPHERE: &str = r#"
[object]
name = "liver"
builtin = "liver"

[object.model]
{model}

[material]
youngs_modulus_pa = 50000.0
poisson_ratio = 0.33

[tool]
shape = "sphere"
radius_m = 0.01

[calibration]
table = "half_space"
"#;

fn sphere_scene(model: &str) -> String {
    SPHERE.replace("{model}", model)
}

fn cone_scene(model: &str) -> String {
    sphere_scene(model).replace(
        "shape = \"sphere\"\nradius_m = 0.01",
        "shape = \"cone\"\nhalf_angle_rad = 0.7853981633974483\nradius_m = 0.01",
    )
}

fn combined() -> ModelSpec {
    ModelSpec {
        exact_sphere: true,
        curvature: true,
        hyperelastic: true,
        ..ModelSpec::PAPER
    }
}

const COMBINED_TOML: &str = "exact_sphere = true\ncurvature = true\nhyperelastic = true";

/// Writes `text` as `scene.toml` in `dir` and loads it.
fn load(dir: &Path, text: &str) -> Result<Scene, SceneError> {
    softhaptic_tests::load_scene_text(dir, text)
}

fn refused(dir: &Path, text: &str, expected: &[&str]) {
    softhaptic_tests::assert_scene_refused(dir, text, expected)
}

fn limits_file(valid_depth_m: f64, spec: ModelSpec, inclination: Option<f64>) -> String {
    serde_json::to_string_pretty(&ModelLimitsFile {
        version: 1,
        threshold_percent: 7.0,
        limits: vec![MeasuredLimit {
            tool: ToolKind::Sphere,
            model: spec,
            valid_depth_m,
            crossed: true,
            valid_inclination_rad: inclination,
            reference: "test block, neo-Hookean FEM".into(),
            poisson_ratio: None,
        }],
    })
    .unwrap()
}

#[test]
fn every_bad_model_field_is_refused_with_file_field_and_value() {
    let dir = scratch("fields");
    let good = load(&dir, &sphere_scene(COMBINED_TOML)).expect("the reference text is valid");
    assert_eq!(*good.contact_model.spec(), combined());
    refused(
        &dir,
        &sphere_scene("curvatur = true"),
        &["unknown field", "curvatur", "line"],
    );
    refused(
        &dir,
        &sphere_scene("exact_sphere = \"yes\""),
        &["exact_sphere", "yes", "line"],
    );
    refused(
        &dir,
        &sphere_scene("hyperelastic = 1"),
        &["hyperelastic", "line"],
    );
    refused(
        &dir,
        &sphere_scene("thickness = { thickness_m = -0.01, bonded = true }"),
        &["object.model.thickness.thickness_m", "-0.01"],
    );
    refused(
        &dir,
        &sphere_scene("thickness = { thickness_m = nan, bonded = true }"),
        &["object.model.thickness.thickness_m", "NaN"],
    );
    refused(
        &dir,
        &sphere_scene("thickness = { thickness_m = 0.03 }"),
        &["bonded", "line"],
    );
    refused(
        &dir,
        &sphere_scene("thickness = { thickness_m = 0.03, bonded = true, glued = 1 }"),
        &["unknown field", "glued"],
    );
    refused(
        &dir,
        &cone_scene("exact_sphere = true"),
        &["object.model.exact_sphere", "cone"],
    );
    refused(
        &dir,
        &cone_scene("thickness = { thickness_m = 0.03, bonded = false }"),
        &["object.model.thickness.bonded", "bonded = false"],
    );
    // A layer on a sphere, bonded or not, and a bonded layer under a cone are laws.
    load(
        &dir,
        &sphere_scene("thickness = { thickness_m = 0.03, bonded = false }"),
    )
    .unwrap();
    load(
        &dir,
        &cone_scene("thickness = { thickness_m = 0.03, bonded = true }"),
    )
    .unwrap();
}

#[test]
fn the_limits_file_is_validated_and_its_default_may_be_missing() {
    let dir = scratch("limits");
    // No limits named and no default file next to the scene: the paper's limits.
    let scene = load(&dir, &sphere_scene(COMBINED_TOML)).unwrap();
    assert!(scene.validity.is_paper());
    assert_eq!(scene.force.valid_depth_m, 4.3e-3);
    assert_eq!(scene.force.valid_inclination_rad, 22f64.to_radians());
    assert_eq!(scene.contact_model_info().limits_source, "paper");

    // The default file next to the scene is read when present.
    std::fs::create_dir_all(dir.join("calibration")).unwrap();
    std::fs::write(
        dir.join("calibration/model_limits.json"),
        limits_file(0.0062, combined(), Some(0.3)),
    )
    .unwrap();
    let scene = load(&dir, &sphere_scene(COMBINED_TOML)).unwrap();
    assert_eq!(scene.force.valid_depth_m, 0.0062);
    assert_eq!(scene.force.valid_inclination_rad, 0.3);
    assert_eq!(scene.validity.source, "test block, neo-Hookean FEM");
    // A model the file does not list keeps the paper's limits.
    let paper = load(&dir, &sphere_scene("")).unwrap();
    assert!(paper.validity.is_paper());

    let with_limits = |file: &str| {
        sphere_scene(COMBINED_TOML).replace(
            "table = \"half_space\"",
            &format!("table = \"half_space\"\nlimits = \"{file}\""),
        )
    };
    refused(
        &dir,
        &with_limits("absent.json"),
        &["calibration.limits", "absent.json"],
    );
    std::fs::write(dir.join("broken.json"), "{\"version\": 1, \"limits\": [").unwrap();
    refused(
        &dir,
        &with_limits("broken.json"),
        &["calibration.limits", "broken.json", "line"],
    );
    std::fs::write(
        dir.join("negative.json"),
        limits_file(-1.0, combined(), None),
    )
    .unwrap();
    refused(
        &dir,
        &with_limits("negative.json"),
        &["negative.json", "limits[0].valid_depth_m", "-1"],
    );
    std::fs::write(
        dir.join("steep.json"),
        limits_file(0.004, combined(), Some(2.0)),
    )
    .unwrap();
    refused(
        &dir,
        &with_limits("steep.json"),
        &["steep.json", "limits[0].valid_inclination_rad", "2"],
    );
    let newer = limits_file(0.004, combined(), None).replace("\"version\": 1", "\"version\": 2");
    std::fs::write(dir.join("newer.json"), newer).unwrap();
    refused(
        &dir,
        &with_limits("newer.json"),
        &["newer.json", "version", "2"],
    );
    // A named file that exists is used.
    std::fs::write(dir.join("mine.json"), limits_file(0.0031, combined(), None)).unwrap();
    let scene = load(&dir, &with_limits("mine.json")).unwrap();
    assert_eq!(scene.force.valid_depth_m, 0.0031);
    assert_eq!(scene.force.valid_inclination_rad, 22f64.to_radians());
    assert!(scene.validity.source.contains("(inclination: paper)"));
}

#[test]
fn a_scene_with_the_cone_tool_builds_no_sphere_model() {
    let scene = Scene::load(&repo_scenes().join("cone.toml")).unwrap();
    assert!(matches!(scene.tool, ToolShape::Cone { .. }));
    assert!(matches!(scene.contact_model.tool(), ToolShape::Cone { .. }));
    let world = scene.haptic_world();
    assert!(matches!(world.model().tool(), ToolShape::Cone { .. }));
    // The cone scene's model uses the curvature, so its world measures it...
    assert!(world.collider().has_curvature());
    let message = scene.message();
    assert_eq!(message.model.name, "sneddon_cone");
    assert_eq!(
        message.contact_model.label,
        "Sneddon cone + curvature + inclination"
    );
    // ...and a cone scene without curvature does not.
    let dir = scratch("cone");
    let plain = load(&dir, &cone_scene("inclination = true")).unwrap();
    assert!(!plain.haptic_world().collider().has_curvature());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_scene_message_names_the_active_model() {
    let server = start_default(test_options()).await;
    let mut viewer = Viewer::connect(server.local_addr()).await;
    let ServerMessage::Hello(_) = viewer.expect_message(WAIT).await else {
        panic!("first message is hello")
    };
    let ServerMessage::Scene(scene) = viewer.expect_message(WAIT).await else {
        panic!("second message is scene")
    };
    let model = &scene.contact_model;
    assert_eq!(
        model.label,
        "Hertz + exact sphere + curvature + neo-Hookean fit"
    );
    assert_eq!(
        model.corrections,
        vec!["exact_sphere", "curvature", "hyperelastic"]
    );
    assert_eq!(model.spec, combined());
    assert_eq!(model.valid_depth_m, scene.model.valid_depth_m);
    assert_eq!(
        model.valid_inclination_rad,
        scene.model.valid_inclination_rad
    );
    assert!(!model.limits_source.is_empty());
    assert_eq!(&scene.contact_model, &server.scene_message().contact_model);
    server.shutdown().await;

    // A scene with a measured limit: the message carries it and its source.
    let dir = scratch("ws");
    std::fs::write(
        dir.join("limits.json"),
        limits_file(0.0051, combined(), None),
    )
    .unwrap();
    let text = sphere_scene(COMBINED_TOML).replace(
        "table = \"half_space\"",
        "table = \"half_space\"\nlimits = \"limits.json\"",
    );
    let loaded = load(&dir, &text).unwrap();
    let server = app::start(loaded, test_options()).await.unwrap();
    let mut viewer = Viewer::connect(server.local_addr()).await;
    viewer.expect_message(WAIT).await;
    let ServerMessage::Scene(scene) = viewer.expect_message(WAIT).await else {
        panic!("second message is scene")
    };
    assert_eq!(scene.contact_model.valid_depth_m, 0.0051);
    assert_eq!(scene.model.valid_depth_m, 0.0051);
    assert_eq!(
        scene.contact_model.limits_source,
        "test block, neo-Hookean FEM (inclination: paper)"
    );
    server.shutdown().await;
}

/// Presses the scene's object with the simulated hand (aiming 8 mm deep) tick by tick, as a
/// scripted recording does; returns (depth, flags) of every tick in contact.
fn press(scene: &Scene) -> Vec<(f64, ContactFlags)> {
    let mut script = scene.hand_script();
    script.repeat = false;
    let params = SimParams {
        limits: scene.device_limits,
        ..SimParams::default()
    };
    let mut device = SimulatedPhantom::with_params(script, params);
    let mut world = scene.haptic_world();
    let ticks = (script.duration_s() * 1e3) as usize;
    let mut contacts = Vec::new();
    for _ in 0..ticks {
        let state = world.step(device.read());
        let _ = device.command_force(state.force_n);
        if state.in_contact {
            contacts.push((state.depth_m, state.flags));
        }
    }
    contacts
}

#[test]
fn the_flags_use_the_measured_limit_of_the_active_model_in_a_closed_loop_run() {
    let dir = scratch("closed-loop");
    let valid_depth_m = 0.001;
    std::fs::write(
        dir.join("limits.json"),
        limits_file(valid_depth_m, combined(), None),
    )
    .unwrap();
    let text = sphere_scene(COMBINED_TOML).replace(
        "table = \"half_space\"",
        "table = \"half_space\"\nlimits = \"limits.json\"",
    );
    let measured = load(&dir, &text).unwrap();
    let contacts = press(&measured);
    let deepest = contacts.iter().map(|c| c.0).fold(0.0, f64::max);
    assert!(deepest > 0.002, "the press goes past 1 mm: {deepest}");
    let flagged = |(depth, flags): &(f64, ContactFlags)| {
        flags.contains(ContactFlags::BEYOND_VALID_DEPTH) == (*depth > valid_depth_m)
    };
    assert!(
        contacts.iter().all(flagged),
        "beyond_valid_depth is set exactly past 1 mm"
    );
    assert!(
        contacts
            .iter()
            .any(|c| c.1.contains(ContactFlags::BEYOND_VALID_DEPTH))
    );
    assert!(
        contacts
            .iter()
            .any(|c| c.0 > 0.0 && !c.1.contains(ContactFlags::BEYOND_VALID_DEPTH))
    );

    // The same press with the paper's limits (no file): flagged only past 4.3 mm.
    let paper = load(&scratch("closed-loop-paper"), &sphere_scene(COMBINED_TOML)).unwrap();
    let contacts = press(&paper);
    assert!(contacts.iter().all(|(depth, flags)| {
        flags.contains(ContactFlags::BEYOND_VALID_DEPTH) == (*depth > 4.3e-3)
    }));
    assert!(
        contacts
            .iter()
            .any(|(d, f)| *d > 0.002 && !f.contains(ContactFlags::BEYOND_VALID_DEPTH))
    );
}

#[test]
fn a_recording_from_before_the_model_field_reads_as_the_papers_law() {
    // A cone press recorded by a server whose `scene` message did not name its model (kept
    // under tests/sessions/legacy/, not regenerated). Its scene text has no model table, but
    // the replay takes the model from the message: absent, that is the paper's law with the
    // paper's limits, which is what that server ran.
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("sessions")
        .join("legacy")
        .join("cone-press-before-contact-model.mcap");
    let recording = softhaptic_server::session::reader::Recording::open(&path).unwrap();
    let message = &recording.scene.message;
    assert!(matches!(message.tool, ToolShape::Cone { .. }));
    assert_eq!(
        message.contact_model,
        softhaptic_proto::wire::ContactModelInfo::paper(&message.tool)
    );
    let scene = softhaptic_server::session::check::recorded_scene(&recording).unwrap();
    assert!(scene.contact_model.spec().is_paper());
    assert!(matches!(scene.contact_model.tool(), ToolShape::Cone { .. }));
    assert_eq!(scene.force.valid_depth_m, 4.3e-3);
    assert_eq!(scene.force.valid_inclination_rad, 9f64.to_radians());
    // The check runs over every tick (whether the forces still match depends on everything
    // else that changed since, which the regenerated recordings pin).
    let report = softhaptic_server::session::check::check(&recording, Default::default()).unwrap();
    assert_eq!(report.ticks_compared, recording.device.len() as u64);
}

#[test]
fn a_recording_with_the_model_field_replays_its_model_bit_for_bit() {
    // The regenerated cone press names its model (curvature + inclination); the replay
    // rebuilds exactly that model, and every force matches.
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("sessions")
        .join("cone-press.mcap");
    let recording = softhaptic_server::session::reader::Recording::open(&path).unwrap();
    let recorded = &recording.scene.message.contact_model;
    assert_eq!(
        recorded.spec,
        ModelSpec {
            curvature: true,
            inclination: true,
            ..ModelSpec::PAPER
        }
    );
    let scene = softhaptic_server::session::check::recorded_scene(&recording).unwrap();
    assert_eq!(scene.contact_model.spec(), &recorded.spec);
    assert_eq!(&scene.contact_model_info(), recorded);
    let report = softhaptic_server::session::check::check(&recording, Default::default()).unwrap();
    assert!(report.passed(), "{report}");
}
