//! End to end: `softhaptic-calibrate --quick all` into a temporary directory; every output must
//! exist and parse, the tables and the model limits must load through the shared types, the
//! report must carry each experiment beside the paper's figure, and the runtime's hyperelastic
//! constants must agree with the fit the pipeline makes.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::collections::HashSet;
use std::path::Path;
mod common;

use softhaptic_calibration::experiments::force::HyperelasticConstants;
use softhaptic_proto::model::ToolKind;
use softhaptic_proto::{CalibrationTable, ModelLimitsFile, ModelSpec, ToolShape, ValidityLimits};

/// The runtime's fitted factor may differ from the quick pipeline's refit by this much, relative,
/// anywhere in the fitted range. The quick meshes (3 mm cells against the full 1.5 mm) move the
/// fitted factor by about 1%; the factor itself departs from 1 by about 3%, so constants left
/// unfitted (factor 1) or fitted to the wrong reference (the linear FEM: up to +29%) fail.
const FACTOR_TOLERANCE: f64 = 0.02;

fn run_quick_all(out: &Path) {
    common::run_quick(out, "all");
}

#[test]
fn quick_all_writes_parsable_report_tables_limits_csv_and_svg() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("report");
    run_quick_all(&out);

    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    for section in [
        "## R_d calibration",
        "## The drawn surface against the FEM surface",
        "paper's Bézier",
        "Johnson (half-space)",
        "Sneddon (half-space)",
        "## Force accuracy",
        "## Curvature",
        "## Inclination",
        "## Corrections beyond the paper",
        "### Hyperelastic fit",
        "### Speed against accuracy",
        "### Curved objects",
        "### Measured validity limits",
        "4.3 mm",
        "3.3 mm",
        "5.66 N",
        "22°",
        "Lin et al.",
        "(best combined)",
        "## Nearly incompressible tissue",
        "Small-deformation linear FEM against Sneddon",
        "Neo-Hookean FEM against Sneddon at small depths",
        "the bonded layer",
        "FEM, cells a/2 (N)",
        "| tool | model | ν | valid depth |",
        "fem, row held out: max error (mm)",
        "`sphere10_50kpa_nu49.json`",
        "`cone10_45_50kpa_nu30.json`",
    ] {
        assert!(report.contains(section), "report lacks {section:?}");
    }

    for name in [
        "sphere10_50kpa",
        "sphere10_1500kpa",
        "cone10_45_50kpa",
        "cone10_45_1500kpa",
        "sphere10_50kpa_nu30",
        "sphere10_50kpa_nu49",
        "cone10_45_50kpa_nu45",
    ] {
        let text =
            std::fs::read_to_string(out.join("tables").join(format!("{name}.json"))).unwrap();
        let table: CalibrationTable = serde_json::from_str(&text).unwrap();
        assert!(
            table.rows().len() >= 5,
            "{name}: {} rows",
            table.rows().len()
        );
        // R_d grows with depth on the block.
        let first = table.rows().first().unwrap().deformed_radius_m;
        let last = table.rows().last().unwrap().deformed_radius_m;
        assert!(last > first && last > 0.005, "{name}: R_d {first} → {last}");
    }

    // The runtime rows of the speed-accuracy table: (tool, model name).
    let table = std::fs::read_to_string(out.join("speed_accuracy.csv")).unwrap();
    let mut lines = table.lines();
    let columns = lines.next().unwrap().split(',').count();
    let mut runtime_rows = Vec::new();
    for line in lines {
        let cells: Vec<&str> = line.split(',').collect();
        assert_eq!(cells.len(), columns, "speed_accuracy.csv: {line}");
        // tool, model, kind, then numbers.
        for c in &cells[3..] {
            let v: f64 = c.parse().unwrap();
            assert!(v.is_finite(), "speed_accuracy.csv: {line}");
        }
        if cells[2] == "runtime" {
            runtime_rows.push((cells[0].to_owned(), cells[1].to_owned()));
        }
    }
    assert!(runtime_rows.len() >= 11, "{runtime_rows:?}");

    // The limits file parses with the shared type and covers every runtime model of the table.
    let text = std::fs::read_to_string(out.join("tables").join("model_limits.json")).unwrap();
    let limits: ModelLimitsFile = serde_json::from_str(&text).unwrap();
    assert_eq!(limits.version, ModelLimitsFile::VERSION);
    assert_eq!(limits.threshold_percent, 7.0);
    let sphere = ToolShape::Sphere { radius_m: 0.006 };
    let cone = ToolShape::Cone {
        half_angle_rad: std::f64::consts::FRAC_PI_4,
        radius_m: 0.006,
    };
    let mut listed = HashSet::new();
    for l in &limits.limits {
        let (tool, tool_name) = match l.tool {
            ToolKind::Sphere => (sphere, "sphere6"),
            ToolKind::Cone => (cone, "cone6_45"),
        };
        if l.poisson_ratio.is_some() {
            // Measured over ν by the Poisson sweep; checked below. The tilted runs are at
            // ν = 0.33 only, and an inclination limit carried to another ν says so.
            if l.valid_inclination_rad.is_some() {
                assert!(
                    l.reference.contains("measured at ν = 0.33, copied"),
                    "{}",
                    l.reference
                );
            }
            assert!(
                !limits.limits.iter().any(|o| o.tool == l.tool
                    && o.model == l.model
                    && o.poisson_ratio == l.poisson_ratio
                    && !std::ptr::eq(o, l)),
                "duplicate limit for {tool_name} {} at {:?}",
                l.model.label(&tool),
                l.poisson_ratio
            );
        } else {
            assert!(
                listed.insert((tool_name, l.model.label(&tool))),
                "duplicate limit for {tool_name} {}",
                l.model.label(&tool)
            );
        }
        assert!(
            l.valid_depth_m.is_finite() && l.valid_depth_m > 0.0 && l.valid_depth_m <= 0.0101,
            "{l:?}"
        );
        if let Some(a) = l.valid_inclination_rad {
            assert!(a > 0.0 && a <= std::f64::consts::FRAC_PI_2, "{l:?}");
        }
        assert!(!l.reference.is_empty());
    }
    for (tool, model) in &runtime_rows {
        assert!(
            listed.contains(&(tool.as_str(), model.clone())),
            "no limit for {tool} {model}"
        );
    }
    // The scenes' models are covered: the default scene's sphere and the cone scene's cone.
    for (tool, spec) in [
        (
            sphere,
            ModelSpec {
                exact_sphere: true,
                curvature: true,
                hyperelastic: true,
                ..ModelSpec::PAPER
            },
        ),
        (
            cone,
            ModelSpec {
                curvature: true,
                inclination: true,
                ..ModelSpec::PAPER
            },
        ),
    ] {
        let got = limits.lookup(&tool, &spec).unwrap();
        assert!(got.valid_inclination_rad.is_some(), "{got:?}");
    }
    // A scene at ν = 0.49 runs with limits measured at ν = 0.49, and one between two measured
    // ν with limits interpolated between them.
    let best = ModelSpec {
        exact_sphere: true,
        thickness: Some(softhaptic_proto::LayerSpec {
            thickness_m: 0.03,
            bonded: true,
        }),
        hyperelastic: true,
        ..ModelSpec::PAPER
    };
    let at_049 = limits.lookup_at(&sphere, &best, 0.49).unwrap();
    assert_eq!(at_049.poisson_ratio, Some(0.49));
    let between = ValidityLimits::at_poisson_ratio(Some(&limits), &sphere, &best, 0.47);
    assert!(
        between.source.starts_with("interpolated in ν"),
        "{between:?}"
    );

    // Every CSV parses (the speed-accuracy table's text columns apart) and every SVG has a curve.
    let mut csv_count = 0;
    let mut svg_count = 0;
    for entry in std::fs::read_dir(&out).unwrap() {
        let path = entry.unwrap().path();
        let text = std::fs::read_to_string(&path).unwrap_or_default();
        match path.extension().and_then(|e| e.to_str()) {
            Some("csv") => {
                csv_count += 1;
                if path.file_name().unwrap() == "speed_accuracy.csv" {
                    continue;
                }
                let mut lines = text.lines();
                let header: Vec<&str> = lines.next().unwrap().split(',').collect();
                let columns = header.len();
                // Named columns: the surface comparison's law and region of the worst error.
                let named = |h: &str| h == "law" || h.ends_with("_region");
                let mut rows = 0;
                for line in lines {
                    rows += 1;
                    let raw: Vec<&str> = line.split(',').collect();
                    assert_eq!(raw.len(), columns, "{}", path.display());
                    let mut cells = Vec::new();
                    for (h, c) in header.iter().zip(&raw) {
                        if named(h) {
                            assert!(
                                !c.is_empty()
                                    && c.chars().all(|ch| ch.is_ascii_lowercase() || ch == '_'),
                                "{}: {h} = {c:?}",
                                path.display()
                            );
                        } else {
                            cells.push(c.parse::<f64>().unwrap());
                        }
                    }
                    assert!(
                        cells.iter().all(|v| v.is_finite()),
                        "{}: {line}",
                        path.display()
                    );
                }
                assert!(rows > 0, "{} is empty", path.display());
            }
            Some("svg") => {
                svg_count += 1;
                assert!(
                    text.starts_with("<svg") && text.trim_end().ends_with("</svg>"),
                    "{}",
                    path.display()
                );
                assert!(
                    text.contains("<polyline")
                        || text.contains("<path")
                        || text.contains("<circle"),
                    "{} has no curve",
                    path.display()
                );
            }
            _ => {}
        }
    }
    assert!(csv_count >= 16, "{csv_count} CSV files");
    assert!(svg_count >= 21, "{svg_count} SVG files");

    // The runtime's hyperelastic constants against the pipeline's own refit.
    let text = std::fs::read_to_string(out.join("hyperelastic_fit.json")).unwrap();
    let fit: serde_json::Value = serde_json::from_str(&text).unwrap();
    let refit = HyperelasticConstants {
        sphere_c1: fit["refit"]["sphere_c1"].as_f64().unwrap(),
        sphere_c2: fit["refit"]["sphere_c2"].as_f64().unwrap(),
        sphere_x_max: fit["refit"]["sphere_x_max"].as_f64().unwrap(),
        cone_ratio: fit["refit"]["cone_ratio"].as_f64().unwrap(),
    };
    let in_use = HyperelasticConstants::IN_USE;
    assert!(
        (refit.sphere_x_max - in_use.sphere_x_max).abs() < 1e-9,
        "SPHERE_X_MAX {} vs the deepest fitted δ/R {}",
        in_use.sphere_x_max,
        refit.sphere_x_max
    );
    for i in 0..=20 {
        let x = in_use.sphere_x_max * i as f64 / 20.0;
        let rel = refit.sphere_ratio(x) / in_use.sphere_ratio(x) - 1.0;
        assert!(
            rel.abs() < FACTOR_TOLERANCE,
            "sphere factor at x = {x}: refit {} vs in use {}",
            refit.sphere_ratio(x),
            in_use.sphere_ratio(x)
        );
    }
    let rel = refit.cone_ratio / in_use.cone_ratio - 1.0;
    assert!(
        rel.abs() < FACTOR_TOLERANCE,
        "cone ratio: refit {} vs in use {}",
        refit.cone_ratio,
        in_use.cone_ratio
    );
}
