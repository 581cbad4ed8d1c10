//! Scene files on disk: the shipped scenes load, invalid ones are refused before anything starts
//! with the file, the field and the reason.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::path::{Path, PathBuf};

use softhaptic_proto::calibration::PAPER_THRESHOLD_M;
use softhaptic_proto::deformation::RenderProfile;
use softhaptic_proto::{CalibrationSource, CalibrationTable, Material, ToolShape};
use softhaptic_server::scene::{Scene, SceneError};
use softhaptic_tests::repo_scenes;

/// A fresh directory for one test's files.
fn scratch(name: &str) -> PathBuf {
    softhaptic_tests::scratch_dir(&format!("scene-{name}"))
}

const GOOD: &str = r#"
[object]
name = "liver"
builtin = "liver"

[material]
youngs_modulus_pa = 50000.0
poisson_ratio = 0.33

[tool]
shape = "sphere"
radius_m = 0.01

[calibration]
table = "half_space"
"#;

/// Writes `text` as `scene.toml` in `dir` and loads it.
fn load(dir: &Path, text: &str) -> Result<Scene, SceneError> {
    softhaptic_tests::load_scene_text(dir, text)
}

fn refused(dir: &Path, text: &str, expected: &[&str]) {
    softhaptic_tests::assert_scene_refused(dir, text, expected)
}

#[test]
fn a_scene_path_that_is_not_a_regular_file_is_refused_at_once() {
    // /dev/zero would grow the process without end; a directory or a FIFO would fail late or
    // block the start.
    let e = Scene::load(Path::new("/dev/zero")).unwrap_err().to_string();
    assert_eq!(e, "/dev/zero: is a character device, not a regular file");
    let dir = scratch("not-regular");
    let e = Scene::load(&dir).unwrap_err().to_string();
    assert!(e.ends_with("is a directory, not a regular file"), "{e}");
    // A mesh named by a scene goes through the same check.
    refused(
        &dir,
        &GOOD.replace(
            "builtin = \"liver\"",
            "haptic_mesh = \"/dev/zero\"\nposition_m = [0.0, 0.01, 0.0]",
        ),
        &["object.haptic_mesh", "/dev/zero", "character device"],
    );
    // The OS's reason once, not twice.
    let e = Scene::load(&dir.join("missing.toml"))
        .unwrap_err()
        .to_string();
    assert_eq!(e.matches("No such file or directory").count(), 1, "{e}");
}

#[test]
fn shipped_scenes_load() {
    let default = Scene::load(&repo_scenes().join("default.toml")).unwrap();
    assert_eq!(default.tool, ToolShape::sphere(0.01).unwrap());
    assert_eq!(default.material, Material::PAPER_SOFT);
    let cone = Scene::load(&repo_scenes().join("cone.toml")).unwrap();
    assert!(matches!(cone.tool, ToolShape::Cone { .. }));
    assert!(matches!(cone.calibration.tool(), ToolShape::Cone { .. }));
    assert_eq!(cone.calibration.source(), CalibrationSource::FemNeoHookean);
    assert_eq!(
        default.calibration.source(),
        CalibrationSource::FemNeoHookean
    );
}

#[test]
fn the_nearly_incompressible_scene_runs_on_limits_measured_at_its_poisson_ratio() {
    let scene = Scene::load(&repo_scenes().join("incompressible.toml")).unwrap();
    assert_eq!(scene.material.poisson_ratio(), 0.49);
    assert_eq!(scene.calibration.material().poisson_ratio(), 0.49);
    // The neo-Hookean sphere's entry measured at ν = 0.49 (4.29 mm), not the paper's 6 mm nor
    // the ν = 0.33 entry's.
    let source = &scene.validity.source;
    assert!(source.contains("ν = 0.49"), "{source}");
    assert!(
        (scene.validity.valid_depth_m - 4.29e-3).abs() < 0.01e-3,
        "{} m from {source}",
        scene.validity.valid_depth_m
    );
    // Its R_d table is the ν = 0.49 FEM's: at 6 mm the nearly incompressible block's surface
    // sinks less far out than at ν = 0.33.
    let paper_nu = Scene::load(&repo_scenes().join("default.toml")).unwrap();
    assert!(
        scene.calibration.deformed_radius_m(6e-3) < paper_nu.calibration.deformed_radius_m(6e-3)
    );
    // The viewers draw that FEM's own surface, tabulated at ν = 0.49, like the default scene
    // draws the ν = 0.33 one: less sunk at 20 mm from the axis at 6 mm.
    assert_eq!(scene.render_profile, RenderProfile::Fem);
    let sphere = scene.tool;
    let sunk = |s: &Scene| {
        s.calibration
            .surface()
            .expect("the table carries its FEM surface")
            .at_depth(&sphere, 6e-3)
            .depression_m(20e-3)
    };
    assert!(sunk(&scene) > 0.0 && sunk(&scene) < sunk(&paper_nu));
}

#[test]
fn invalid_values_name_the_field_and_value() {
    let dir = scratch("values");
    load(&dir, GOOD).expect("the reference text is valid");
    refused(
        &dir,
        &GOOD.replace("50000.0", "-5.0"),
        // The value's own line and column, not the table's header.
        &[
            "youngs_modulus_pa",
            "-5",
            "line 7, column 21",
            "7 | youngs_modulus_pa = -5.0",
        ],
    );
    refused(
        &dir,
        &GOOD.replace("0.33", "0.5"),
        &["poisson_ratio", "0.5", "line 8, column 17"],
    );
    refused(
        &dir,
        &GOOD.replace("radius_m = 0.01", "radius_m = -0.01"),
        &["radius_m", "-0.01", "line 12, column 12"],
    );
    refused(
        &dir,
        &GOOD.replace(
            "shape = \"sphere\"\nradius_m = 0.01",
            "shape = \"cone\"\nhalf_angle_rad = 2.0\nradius_m = 0.01",
        ),
        &["half_angle_rad", "2", "line 12, column 18"],
    );
    refused(
        &dir,
        &GOOD.replace("shape = \"sphere\"", "shape = \"cone\""),
        &["a cone needs half_angle_rad", "line 11"],
    );
    refused(
        &dir,
        &GOOD.replace("radius_m = 0.01", "radius = 0.01"),
        &["unknown field", "radius"],
    );
    refused(
        &dir,
        &GOOD.replace("[object]", "[object]\norientation = [0.0, 0.0, 0.0, 0.0]"),
        &["object.orientation"],
    );
    refused(
        &dir,
        &format!("{GOOD}\n[device]\npress_depth_m = 0.5\n"),
        &["device.press_depth_m", "0.5"],
    );
    refused(
        &dir,
        &format!("{GOOD}\n[haptics]\ncollision = \"telepathy\"\n"),
        &["collision", "telepathy"],
    );
    refused(&dir, "[object\nname=", &["line 1"]);
}

#[test]
fn meshes_with_nan_vertices_are_refused_with_file_and_index() {
    let dir = scratch("obj");
    std::fs::write(
        dir.join("tetra.obj"),
        "v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nv 0 0 0.05\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("broken.obj"),
        "v 0 0 0\nv 0.05 0 0\nv nan 0.05 0\nv 0 0 0.05\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
    )
    .unwrap();
    let with_mesh = |file: &str| {
        GOOD.replace(
            "builtin = \"liver\"",
            &format!("haptic_mesh = \"{file}\"\nposition_m = [0.0, 0.01, 0.0]"),
        )
    };
    let scene = load(&dir, &with_mesh("tetra.obj")).expect("the tetrahedron loads");
    assert_eq!(scene.haptic_mesh.positions_m().len(), 4);
    assert_eq!(scene.render_surface.positions_m.len(), 4);
    // The press site is the vertex highest in the world: (0, 0.05, 0).
    assert_eq!(
        scene.press_site_in_object.0,
        glam::DVec3::new(0.0, 0.05, 0.0)
    );

    refused(
        &dir,
        &with_mesh("broken.obj"),
        &["object.haptic_mesh", "broken.obj", "vertex 2", "not finite"],
    );
    // Finite coordinates that no haptic mesh has: refused at load, not a panic in the collision.
    std::fs::write(
        dir.join("huge.obj"),
        "v 0 0 0\nv 1e39 0 0\nv 0 1e39 0\nv 0 0 1e39\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
    )
    .unwrap();
    refused(
        &dir,
        &with_mesh("huge.obj"),
        &["object.haptic_mesh", "huge.obj", "vertex 1", "±100 m"],
    );
    refused(
        &dir,
        &with_mesh("missing.obj"),
        &["object.haptic_mesh", "missing.obj"],
    );
    refused(
        &dir,
        &GOOD.replace("builtin = \"liver\"", ""),
        &["object", "builtin"],
    );
}

#[test]
fn calibration_tables_are_validated() {
    let dir = scratch("calibration");
    let tool = ToolShape::sphere(0.01).unwrap();
    let table =
        CalibrationTable::half_space(tool, Material::PAPER_SOFT, PAPER_THRESHOLD_M).unwrap();
    let mut json = serde_json::to_value(&table).unwrap();
    std::fs::write(dir.join("good.json"), json.to_string()).unwrap();
    let with_table = |file: &str| GOOD.replace("\"half_space\"", &format!("\"{file}\""));
    let scene = load(&dir, &with_table("good.json")).expect("a valid table file loads");
    assert_eq!(scene.calibration, table);

    json["rows"][3]["depth_m"] = 0.0001.into();
    std::fs::write(dir.join("unordered.json"), json.to_string()).unwrap();
    refused(
        &dir,
        &with_table("unordered.json"),
        &["calibration.table", "unordered.json", "rows[3].depth_m"],
    );
    refused(
        &dir,
        &with_table("absent.json"),
        &["calibration.table", "absent.json"],
    );

    let cone = ToolShape::cone(0.785, 0.01).unwrap();
    let other =
        CalibrationTable::half_space(cone, Material::PAPER_SOFT, PAPER_THRESHOLD_M).unwrap();
    std::fs::write(
        dir.join("cone.json"),
        serde_json::to_string(&other).unwrap(),
    )
    .unwrap();
    refused(
        &dir,
        &with_table("cone.json"),
        &["cone.json", "was made for tool"],
    );
}
