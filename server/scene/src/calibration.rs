//! The scene's calibration: the R_d table the viewers bend the surface with, and the measured
//! limits of the contact models (the module docs of [`super`] say where each is looked up).

use std::path::{Path, PathBuf};

use softhaptic_proto::calibration::PAPER_THRESHOLD_M;
use softhaptic_proto::{CalibrationError, CalibrationTable, Material, ModelLimitsFile, ToolShape};

use super::file::SceneFile;
use super::{FileBase, ModelSource, SceneError};
use crate::files::{self, FileKind, ReadError};
use crate::toml_file::TomlFileError;

/// The limits file a scene uses when it names none, relative to the scene file.
pub const DEFAULT_LIMITS_FILE: &str = "calibration/model_limits.json";

/// The calibration tables built into the binary, by the name the built-in scene gives them
/// (relative to the repository's `scenes/`).
const EMBEDDED_TABLES: [(&str, &str); 4] = [
    (
        "calibration/sphere10_50kpa.json",
        include_str!("../../../scenes/calibration/sphere10_50kpa.json"),
    ),
    (
        "calibration/sphere10_1500kpa.json",
        include_str!("../../../scenes/calibration/sphere10_1500kpa.json"),
    ),
    (
        "calibration/cone10_45_50kpa.json",
        include_str!("../../../scenes/calibration/cone10_45_50kpa.json"),
    ),
    (
        "calibration/cone10_45_1500kpa.json",
        include_str!("../../../scenes/calibration/cone10_45_1500kpa.json"),
    ),
];

/// Reads the limits file: the one `named` in the scene (which must exist), or the default one
/// (whose absence means the paper's limits, logged). `None` when there is no file.
pub(super) fn load_limits(
    named: Option<&Path>,
    files: FileBase<'_>,
    scene: &Path,
) -> Result<Option<ModelLimitsFile>, SceneError> {
    let full = files.resolve(named.unwrap_or(Path::new(DEFAULT_LIMITS_FILE)));
    let error = |reason: String| SceneError::Limits {
        path: scene.to_owned(),
        file: full.clone(),
        reason,
    };
    let text = match files::read_text(&full, FileKind::Table) {
        Ok(text) => text,
        Err(ReadError::Io(e)) if named.is_none() && e.kind() == std::io::ErrorKind::NotFound => {
            tracing::info!(
                scene = %scene.display(),
                file = %full.display(),
                "no model limits file: the validity flags use the paper's limits (4.3 mm; 22° sphere, 9° cone)"
            );
            return Ok(None);
        }
        Err(e) => return Err(error(e.to_string())),
    };
    let limits: ModelLimitsFile = serde_json::from_str(&text).map_err(|e| error(e.to_string()))?;
    validate_limits(&limits).map_err(error)?;
    Ok(Some(limits))
}

/// Checks what serde cannot: the version, and that every limit is a usable positive number.
/// Public so the fuzz targets (`tests/src/fuzz.rs`) run the same check the loader does.
pub fn validate_limits(file: &ModelLimitsFile) -> Result<(), String> {
    if file.version != ModelLimitsFile::VERSION {
        return Err(format!(
            "version: this build reads version {}, got {}",
            ModelLimitsFile::VERSION,
            file.version
        ));
    }
    if !(file.threshold_percent.is_finite() && file.threshold_percent > 0.0) {
        return Err(format!(
            "threshold_percent: must be finite and > 0, got {}",
            file.threshold_percent
        ));
    }
    for (i, limit) in file.limits.iter().enumerate() {
        if !(limit.valid_depth_m.is_finite() && limit.valid_depth_m > 0.0) {
            return Err(format!(
                "limits[{i}].valid_depth_m: must be finite and > 0, got {}",
                limit.valid_depth_m
            ));
        }
        if let Some(angle) = limit.valid_inclination_rad
            && !(angle.is_finite() && angle > 0.0 && angle <= std::f64::consts::FRAC_PI_2)
        {
            return Err(format!(
                "limits[{i}].valid_inclination_rad: must be in (0, π/2], got {angle}"
            ));
        }
    }
    Ok(())
}

/// The scene's R_d table: the one its recording ran with; the half-space (cut by the rigid base
/// under a layer); or the file it names (for a built-in scene, the copy built into the binary).
pub(super) fn calibration_table(
    file: &SceneFile,
    tool: ToolShape,
    material: Material,
    files: FileBase<'_>,
    model_source: ModelSource<'_>,
    path: &Path,
) -> Result<CalibrationTable, SceneError> {
    let field =
        |field: &str, reason: String| SceneError::from(TomlFileError::field(path, field, reason));
    let table = if let ModelSource::Recorded(record) = model_source {
        // The table the session ran with, as its viewers were sent it.
        record.message.calibration.clone()
    } else if file.calibration.table == "half_space" {
        // An object that is a layer on a rigid base gets the half-space profile with the far
        // field the base removes, which is much closer to an FEM table of that layer than the
        // plain half-space (CalibrationTable::half_space_on_base); the model is the one the
        // session runs with, from the file or the recording.
        let layer = match model_source {
            ModelSource::File => file.object.model.thickness,
            ModelSource::Recorded(record) => record.message.contact_model.spec.thickness,
        };
        match layer {
            Some(layer) => CalibrationTable::half_space_on_base(
                tool,
                material,
                PAPER_THRESHOLD_M,
                layer.thickness_m,
            )
            .map_err(|e| match e {
                CalibrationError::Thickness(_) => {
                    field("object.model.thickness.thickness_m", e.to_string())
                }
                _ => field("calibration.table", e.to_string()),
            })?,
            None => CalibrationTable::half_space(tool, material, PAPER_THRESHOLD_M)
                .map_err(|e| field("calibration.table", e.to_string()))?,
        }
    } else {
        let table_path = PathBuf::from(&file.calibration.table);
        let (full, text) = match files {
            FileBase::Dir(_) => {
                let full = files.resolve(&table_path);
                let text = files::read_text(&full, FileKind::Table).map_err(|e| {
                    SceneError::Calibration {
                        path: path.to_owned(),
                        table: full.clone(),
                        reason: e.to_string(),
                    }
                })?;
                (full, text)
            }
            FileBase::BuiltIn => {
                let name = file.calibration.table.as_str();
                let found = EMBEDDED_TABLES.iter().find(|(n, _)| *n == name);
                let Some((_, text)) = found else {
                    let names: Vec<&str> = EMBEDDED_TABLES.iter().map(|(n, _)| *n).collect();
                    return Err(field(
                        "calibration.table",
                        format!(
                            "a built-in scene can name only the tables built into the binary ({}), got {name:?}",
                            names.join(", ")
                        ),
                    ));
                };
                (
                    PathBuf::from(format!("<built-in {name}>")),
                    (*text).to_owned(),
                )
            }
        };
        let calibration_error = |reason: String| SceneError::Calibration {
            path: path.to_owned(),
            table: full.clone(),
            reason,
        };
        let table: CalibrationTable =
            serde_json::from_str(&text).map_err(|e| calibration_error(e.to_string()))?;
        if table.tool() != &tool {
            return Err(calibration_error(format!(
                "was made for tool {:?}, the scene's tool is {:?}",
                table.tool(),
                tool
            )));
        }
        check_poisson_ratio(&table, material, &file.calibration.table, files, path)?;
        table
    };
    Ok(table)
}

/// How far the scene's Poisson ratio may sit from its table's: the tables are written at
/// ν = 0.30, 0.33, 0.40, 0.45, 0.49, and R_d moves by several percent between neighbours, so
/// anything beyond rounding means the scene names a table made for another material.
pub const POISSON_TOLERANCE: f64 = 0.005;

/// Refuses a table made at another Poisson ratio than the scene's: the drawn depression would be
/// that of another material while nothing says so. The error names the table the calibration
/// writes for the scene's ν (`<tool>_<E>_nu<100ν>.json`, the paper's 0.33 without the suffix)
/// when there is one.
fn check_poisson_ratio(
    table: &CalibrationTable,
    material: Material,
    table_name: &str,
    files: FileBase<'_>,
    path: &Path,
) -> Result<(), SceneError> {
    let scene_nu = material.poisson_ratio();
    let table_nu = table.material().poisson_ratio();
    if (scene_nu - table_nu).abs() <= POISSON_TOLERANCE {
        return Ok(());
    }
    let suggestion = match table_for_poisson(table_name, scene_nu) {
        Some(name) if table_exists(&name, files) => format!("use table = {name:?}"),
        Some(name) => format!(
            "there is no {name:?}: write one with `softhaptic-calibrate poisson` at that ν, or use \
             table = \"half_space\""
        ),
        None => "use a table made at the scene's ν, or table = \"half_space\"".to_owned(),
    };
    Err(TomlFileError::field(
        path,
        "material.poisson_ratio",
        format!(
            "{scene_nu} differs from the ν = {table_nu} of calibration.table {table_name:?} (more \
             than {POISSON_TOLERANCE}): {suggestion}"
        ),
    )
    .into())
}

/// The name the calibration gives the table of `table_name`'s tool and stiffness at
/// `poisson_ratio` (`calibration/sphere10_50kpa_nu49.json`), `None` when `table_name` does not
/// follow that pattern or ν is not a whole hundredth.
fn table_for_poisson(table_name: &str, poisson_ratio: f64) -> Option<String> {
    let stem = table_name.strip_suffix(".json")?;
    let base = match stem.rsplit_once("_nu") {
        Some((base, digits))
            if !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit()) =>
        {
            base
        }
        _ => stem,
    };
    let hundredths = (poisson_ratio * 100.0).round();
    if (poisson_ratio * 100.0 - hundredths).abs() > 1e-6 {
        return None;
    }
    if hundredths as i64 == 33 {
        Some(format!("{base}.json"))
    } else {
        Some(format!("{base}_nu{}.json", hundredths as i64))
    }
}

fn table_exists(name: &str, files: FileBase<'_>) -> bool {
    match files {
        FileBase::Dir(_) => files.resolve(Path::new(name)).is_file(),
        FileBase::BuiltIn => EMBEDDED_TABLES.iter().any(|(n, _)| *n == name),
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use softhaptic_proto::wire::ContactModelInfo;
    use softhaptic_proto::{ModelSpec, ValidityLimits};

    use super::super::Scene;
    use super::super::tests::recording_of;
    use super::*;

    #[test]
    fn a_half_space_table_on_a_layer_is_cut_by_its_base() {
        let text = include_str!("../../../scenes/default.toml").replace(
            "table = \"calibration/sphere10_50kpa.json\"",
            "table = \"half_space\"",
        );
        let with_layer = |thickness: &str| {
            text.replace(
                "hyperelastic = true\n",
                &format!("hyperelastic = true\nthickness = {{ thickness_m = {thickness}, bonded = true }}\n"),
            )
        };
        let tool = ToolShape::sphere(0.01).unwrap();
        // No thickness: the plain half-space.
        let plain = Scene::from_toml(&text, Path::new("<test>"), None).unwrap();
        assert_eq!(
            plain.calibration,
            CalibrationTable::half_space(tool, Material::PAPER_SOFT, PAPER_THRESHOLD_M).unwrap()
        );
        // A 50 mm layer: the base-corrected table of that thickness, which says so.
        let layer = Scene::from_toml(&with_layer("0.05"), Path::new("<test>"), None).unwrap();
        assert_eq!(
            layer.calibration.source(),
            softhaptic_proto::CalibrationSource::HalfSpaceOnBase
        );
        assert!(
            layer
                .calibration
                .description()
                .contains("rigid base 50.0 mm")
        );
        assert_eq!(
            layer.calibration,
            CalibrationTable::half_space_on_base(
                tool,
                Material::PAPER_SOFT,
                PAPER_THRESHOLD_M,
                0.05
            )
            .unwrap()
        );
        assert!(
            layer.calibration.deformed_radius_m(0.006)
                < 0.6 * plain.calibration.deformed_radius_m(0.006)
        );
        // A bad thickness is refused with its field and value.
        let err = Scene::from_toml(&with_layer("-0.02"), Path::new("<test>"), None)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("object.model.thickness.thickness_m") && err.contains("-0.02"),
            "{err}"
        );
        // A replay takes the layer from the recorded model, not from the scene text.
        let recorded = ContactModelInfo::new(
            &tool,
            &ModelSpec {
                thickness: Some(softhaptic_proto::LayerSpec {
                    thickness_m: 0.03,
                    bonded: true,
                }),
                ..ModelSpec::PAPER
            },
            &ValidityLimits::paper(&tool),
        );
        // The table the session ran with is the recording's: a replay never recomputes or
        // reads it.
        let table = CalibrationTable::half_space_on_base(
            tool,
            Material::PAPER_SOFT,
            PAPER_THRESHOLD_M,
            0.03,
        )
        .unwrap();
        let mut record = recording_of(&text, recorded);
        record.message.calibration = table.clone();
        let replay = Scene::from_recording(&record, Path::new("<test>")).unwrap();
        assert_eq!(replay.calibration, table);
    }

    #[test]
    fn a_table_made_at_another_poisson_ratio_is_refused_with_the_one_to_use() {
        let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
        // The ν = 0.49 scene with its own table loads.
        let scene_path = scenes.join("incompressible.toml");
        let text = crate::files::read_text(&scene_path, crate::files::FileKind::Scene).unwrap();
        Scene::from_toml(&text, &scene_path, Some(&scenes)).unwrap();
        // At ν = 0.45 it names the ν = 0.49 table: refused, naming the scene, the field, both
        // values and the ν = 0.45 table that exists beside it.
        let at_045 = text.replace("poisson_ratio = 0.49", "poisson_ratio = 0.45");
        assert_ne!(at_045, text, "the scene's ν line moved");
        let err = Scene::from_toml(&at_045, &scene_path, Some(&scenes))
            .unwrap_err()
            .to_string();
        for part in [
            "incompressible.toml",
            "material.poisson_ratio",
            "0.45",
            "0.49",
            "calibration/sphere10_50kpa_nu49.json",
            "use table = \"calibration/sphere10_50kpa_nu45.json\"",
        ] {
            assert!(err.contains(part), "{part:?} missing from: {err}");
        }
        // Within the tolerance (a ν written with more digits) it loads.
        let near = text.replace("poisson_ratio = 0.49", "poisson_ratio = 0.4925");
        Scene::from_toml(&near, &scene_path, Some(&scenes)).unwrap();
        // The paper's ν asks for the table without a suffix.
        assert_eq!(
            table_for_poisson("calibration/cone10_45_50kpa_nu45.json", 0.33).as_deref(),
            Some("calibration/cone10_45_50kpa.json")
        );
        assert_eq!(
            table_for_poisson("calibration/cone10_45_50kpa.json", 0.4),
            Some("calibration/cone10_45_50kpa_nu40.json".to_owned())
        );
        assert_eq!(table_for_poisson("mine.json", 0.437), None);
        // The built-in scene at ν = 0.45: no such table inside the binary, and the error says
        // how to get one.
        let built_in = include_str!("../../../scenes/default.toml")
            .replace("poisson_ratio = 0.33", "poisson_ratio = 0.45");
        let err = Scene::from_toml(&built_in, Path::new("<test>"), None)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("material.poisson_ratio")
                && err.contains("there is no \"calibration/sphere10_50kpa_nu45.json\""),
            "{err}"
        );
    }

    #[test]
    fn the_built_in_scene_names_only_embedded_tables() {
        let text = include_str!("../../../scenes/default.toml").replace(
            "calibration/sphere10_50kpa.json",
            "calibration/elsewhere.json",
        );
        let err = Scene::from_toml(&text, Path::new("<test>"), None)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("calibration.table")
                && err.contains("elsewhere.json")
                && err.contains("sphere10_50kpa.json"),
            "{err}"
        );
        // Every embedded table parses.
        for (name, text) in EMBEDDED_TABLES {
            serde_json::from_str::<CalibrationTable>(text)
                .unwrap_or_else(|e| panic!("{name}: {e}"));
        }
    }
}
