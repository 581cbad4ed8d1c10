//! `softhaptic-calibrate --quick inclination` refreshes the angles of an existing limits file and
//! nothing else: every entry keeps its model and depth limit, the cone models with the
//! inclination correction take the angle the tilted FEM gives with it, and the entries measured
//! at another ν take their paper's-ν twin's.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

mod common;

use softhaptic_proto::ModelLimitsFile;
use softhaptic_proto::model::ToolKind;

#[test]
fn the_inclination_command_refreshes_the_angles_of_the_limits_file_only() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("report");
    // Quick runs read and write the limits file under `<out>/tables`.
    let tables = out.join("tables");
    std::fs::create_dir_all(&tables).unwrap();
    let shipped = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../scenes/calibration/model_limits.json");
    let mut before: ModelLimitsFile =
        serde_json::from_str(&std::fs::read_to_string(&shipped).unwrap()).unwrap();
    // A stale angle on every entry, so that each one the command refreshes is seen to change.
    for l in &mut before.limits {
        l.valid_inclination_rad = Some(0.123);
        let base = l
            .reference
            .split("; inclination")
            .next()
            .unwrap()
            .to_owned();
        l.reference = match l.poisson_ratio {
            None => format!("{base}; inclination (stale): 7.0°"),
            Some(_) => format!("{base}; inclination as measured at ν = 0.33: 7.0° (stale)"),
        };
    }
    std::fs::write(
        tables.join("model_limits.json"),
        serde_json::to_string_pretty(&before).unwrap(),
    )
    .unwrap();

    common::run_quick(&out, "inclination");

    let after: ModelLimitsFile =
        serde_json::from_str(&std::fs::read_to_string(tables.join("model_limits.json")).unwrap())
            .unwrap();
    assert_eq!(after.limits.len(), before.limits.len());
    for (b, a) in before.limits.iter().zip(&after.limits) {
        assert_eq!(
            (a.tool, a.model, a.poisson_ratio),
            (b.tool, b.model, b.poisson_ratio)
        );
        assert_eq!(a.valid_depth_m.to_bits(), b.valid_depth_m.to_bits());
        assert_eq!(a.crossed, b.crossed);
        let angle = a.valid_inclination_rad.unwrap();
        assert!(angle != 0.123 && angle > 0.0, "{a:?}");
        assert!(!a.reference.contains("stale"), "{}", a.reference);
        if a.poisson_ratio.is_some() {
            let twin = after
                .limits
                .iter()
                .find(|o| o.poisson_ratio.is_none() && o.tool == a.tool && o.model == a.model);
            if let Some(twin) = twin {
                assert_eq!(twin.valid_inclination_rad, a.valid_inclination_rad);
                assert!(
                    a.reference.contains(
                        "inclination as measured at ν = 0.33, copied: not measured at this ν"
                    ),
                    "{}",
                    a.reference
                );
            }
        } else {
            assert!(a.reference.contains("; inclination ("), "{}", a.reference);
        }
        // The cone with the inclination correction is measured against the corrected force.
        if a.tool == ToolKind::Cone && a.model.inclination && a.poisson_ratio.is_none() {
            assert!(a.reference.contains("with the inclination correction"));
        }
    }
}
