//! End to end: `softhaptic-calibrate --quick all` into a temporary directory; every output must
//! exist and parse, the tables must load through the shared calibration type, and the report
//! must carry each experiment beside the paper's figure.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::process::Command;

use softhaptic_proto::CalibrationTable;

#[test]
fn quick_all_writes_parsable_report_tables_csv_and_svg() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("report");
    let status = Command::new(env!("CARGO_BIN_EXE_softhaptic-calibrate"))
        .args(["--quick", "--out"])
        .arg(&out)
        .arg("all")
        .env("RUST_LOG", "warn")
        .status()
        .unwrap();
    assert!(
        status.success(),
        "softhaptic-calibrate exited with {status}"
    );

    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    for section in [
        "## R_d calibration",
        "## Force accuracy",
        "## Curvature",
        "## Inclination",
        "## Speed against accuracy",
        "4.3 mm",
        "3.3 mm",
        "5.66 N",
        "22°",
    ] {
        assert!(report.contains(section), "report lacks {section:?}");
    }

    for name in [
        "sphere10_50kpa",
        "sphere10_1500kpa",
        "cone10_45_50kpa",
        "cone10_45_1500kpa",
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

    let mut csv_count = 0;
    let mut svg_count = 0;
    for entry in std::fs::read_dir(&out).unwrap() {
        let path = entry.unwrap().path();
        let text = std::fs::read_to_string(&path).unwrap_or_default();
        match path.extension().and_then(|e| e.to_str()) {
            Some("csv") => {
                csv_count += 1;
                let mut lines = text.lines();
                let header = lines.next().unwrap();
                let columns = header.split(',').count();
                let mut rows = 0;
                for line in lines {
                    rows += 1;
                    if path.file_name().unwrap() == "speed_accuracy.csv" {
                        continue; // First column is the quoted model name.
                    }
                    let cells: Vec<f64> =
                        line.split(',').map(|c| c.parse::<f64>().unwrap()).collect();
                    assert_eq!(cells.len(), columns, "{}", path.display());
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
                    text.contains("<polyline") || text.contains("<path"),
                    "{} has no curve",
                    path.display()
                );
            }
            _ => {}
        }
    }
    assert!(csv_count >= 8, "{csv_count} CSV files");
    assert!(svg_count >= 9, "{svg_count} SVG files");
}
