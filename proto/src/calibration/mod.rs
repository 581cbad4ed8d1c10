//! The δ → R_d calibration table (paper §3.3.2) and its evaluation.
//!
//! The viewer bends its render mesh inside a disc of radius R_d around the contact. R_d grows
//! with the indentation depth δ; the paper measures it by FEM (the radius beyond which the surface
//! is depressed by less than 0.5 mm), samples δ every 0.5 mm up to 10 mm, and fits a line below
//! about 7 mm and a quadratic beyond. A table is a JSON file (format `softhaptic-calibration`,
//! version 1, see proto/WIRE.md) written by the offline calibration tool, or built here from the
//! analytical elastic half-space when no FEM table exists ([`CalibrationTable::half_space`]),
//! or from the same profile with its far field cut by a rigid base at the object's thickness
//! ([`CalibrationTable::half_space_on_base`]).
//!
//! The fit is what the server evaluates at 50 Hz ([`CalibrationTable::deformed_radius_m`]); the
//! rows are kept so that a reader can see what the fit was made from.
//!
//! - this file: the table, its file format and its validation;
//! - `fit`: the paper's piecewise least-squares fit R_d(δ) ([`CalibrationFit`]);
//! - `half_space`: the analytical surface profiles (half-space, and half-space on a rigid
//!   base) and the tables built from them.

use serde::{Deserialize, Serialize};

mod fit;
mod half_space;

pub use fit::CalibrationFit;
pub use half_space::{
    BASE_IMAGE_DEPTH_FACTOR, half_space_deformed_radius_m, half_space_depression_m,
    half_space_on_base_deformed_radius_m, half_space_on_base_depression_m,
};

use crate::deformation::SurfaceFamily;
use crate::material::Material;
use crate::tool::ToolShape;

/// The `format` string every table carries.
pub const CALIBRATION_FORMAT: &str = "softhaptic-calibration";
/// The table layout version this code reads and writes.
pub const CALIBRATION_VERSION: u32 = 1;
/// The paper's depression threshold that defines R_d: 0.5 mm.
pub const PAPER_THRESHOLD_M: f64 = 0.5e-3;
/// The paper's breakpoint between the linear and the quadratic fit: 7 mm.
pub const PAPER_BREAKPOINT_M: f64 = 7e-3;

/// Why a table was refused. Each variant names the field (with the row index where there is one)
/// and the offending value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibrationError {
    #[error("format must be \"{CALIBRATION_FORMAT}\", got {0:?}")]
    Format(String),
    #[error("version must be {CALIBRATION_VERSION}, got {0}")]
    Version(u32),
    #[error("tool: {0}")]
    Tool(#[from] crate::tool::ToolError),
    #[error("threshold_m must be finite and > 0, got {0}")]
    Threshold(f64),
    #[error("thickness_m must be finite and > 0, got {0}")]
    Thickness(f64),
    #[error("block_m[{index}] must be finite and > 0, got {value}")]
    Block { index: usize, value: f64 },
    #[error("rows must not be empty")]
    NoRows,
    #[error("rows[{index}].depth_m must be finite and > 0, got {value}")]
    RowDepth { index: usize, value: f64 },
    #[error(
        "rows[{index}].depth_m = {value} is not greater than rows[{previous}].depth_m = {previous_value}: rows must be in increasing depth",
        previous = index - 1
    )]
    RowsNotIncreasing {
        index: usize,
        value: f64,
        previous_value: f64,
    },
    #[error("rows[{index}].deformed_radius_m must be finite and >= 0, got {value}")]
    RowRadius { index: usize, value: f64 },
    #[error("fit.breakpoint_m must be finite and > 0, got {0}")]
    Breakpoint(f64),
    #[error(
        "the linear fit needs at least 2 rows shallower than fit.breakpoint_m = {breakpoint_m}, found {found}"
    )]
    TooFewLinearRows { breakpoint_m: f64, found: usize },
    #[error("fit.{field}[{index}] must be finite, got {value}")]
    Coefficient {
        field: &'static str,
        index: usize,
        value: f64,
    },
    #[error(
        "fit.quadratic does not meet fit.linear at fit.breakpoint_m = {breakpoint_m}: {quadratic_m} m vs {linear_m} m"
    )]
    Discontinuous {
        breakpoint_m: f64,
        linear_m: f64,
        quadratic_m: f64,
    },
}

/// Where a table's rows come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CalibrationSource {
    /// The analytical elastic half-space (Johnson for the sphere, Sneddon for the cone): no
    /// finite block, so R_d is larger than on the paper's block with a fixed bottom.
    HalfSpace,
    /// The same analytical profile on a layer of finite thickness bonded to a rigid base
    /// ([`CalibrationTable::half_space_on_base`]): the base cuts the far field, so R_d is close
    /// to an FEM table of the same thickness.
    HalfSpaceOnBase,
    /// Linear-elastic (small-strain) FEM of the paper's block.
    FemLinear,
    /// Compressible neo-Hookean (large-strain) FEM of the paper's block.
    FemNeoHookean,
}

impl CalibrationSource {
    /// The snake_case name used in the JSON and in logs.
    pub fn as_str(&self) -> &'static str {
        match self {
            CalibrationSource::HalfSpace => "half_space",
            CalibrationSource::HalfSpaceOnBase => "half_space_on_base",
            CalibrationSource::FemLinear => "fem_linear",
            CalibrationSource::FemNeoHookean => "fem_neo_hookean",
        }
    }
}

/// One measured sample: at indentation `depth_m`, the surface is depressed by more than the
/// table's threshold out to `deformed_radius_m` from the contact axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationRow {
    pub depth_m: f64,
    pub deformed_radius_m: f64,
}
/// A δ → R_d table with its provenance (proto/WIRE.md, "Calibration table file / object").
///
/// Every `CalibrationTable` in the program has been validated: deserialising one runs the same
/// checks as [`CalibrationTable::new`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RawCalibrationTable", into = "RawCalibrationTable")]
pub struct CalibrationTable {
    source: CalibrationSource,
    description: String,
    tool: ToolShape,
    material: Material,
    threshold_m: f64,
    block_m: Option<[f64; 3]>,
    rows: Vec<CalibrationRow>,
    fit: CalibrationFit,
    /// The FEM surface the `fem` render profile draws, when the calibration measured it.
    surface: Option<SurfaceFamily>,
}

/// The JSON layout, checked by `TryFrom` on the way in.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCalibrationTable {
    format: String,
    version: u32,
    source: CalibrationSource,
    description: String,
    tool: ToolShape,
    material: Material,
    threshold_m: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    block_m: Option<[f64; 3]>,
    rows: Vec<CalibrationRow>,
    fit: CalibrationFit,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    surface: Option<SurfaceFamily>,
}

impl TryFrom<RawCalibrationTable> for CalibrationTable {
    type Error = CalibrationError;
    fn try_from(raw: RawCalibrationTable) -> Result<Self, Self::Error> {
        if raw.format != CALIBRATION_FORMAT {
            return Err(CalibrationError::Format(raw.format));
        }
        if raw.version != CALIBRATION_VERSION {
            return Err(CalibrationError::Version(raw.version));
        }
        let table = CalibrationTable {
            source: raw.source,
            description: raw.description,
            tool: raw.tool,
            material: raw.material,
            threshold_m: raw.threshold_m,
            block_m: raw.block_m,
            rows: raw.rows,
            fit: raw.fit,
            surface: raw.surface,
        };
        table.validate()?;
        Ok(table)
    }
}

impl From<CalibrationTable> for RawCalibrationTable {
    fn from(t: CalibrationTable) -> Self {
        RawCalibrationTable {
            format: CALIBRATION_FORMAT.to_owned(),
            version: CALIBRATION_VERSION,
            source: t.source,
            description: t.description,
            tool: t.tool,
            material: t.material,
            threshold_m: t.threshold_m,
            block_m: t.block_m,
            rows: t.rows,
            fit: t.fit,
            surface: t.surface,
        }
    }
}

/// Checks rows: non-empty, depth finite > 0 and strictly increasing, radius finite ≥ 0.
pub fn validate_rows(rows: &[CalibrationRow]) -> Result<(), CalibrationError> {
    if rows.is_empty() {
        return Err(CalibrationError::NoRows);
    }
    for (index, row) in rows.iter().enumerate() {
        if !(row.depth_m.is_finite() && row.depth_m > 0.0) {
            return Err(CalibrationError::RowDepth {
                index,
                value: row.depth_m,
            });
        }
        if !(row.deformed_radius_m.is_finite() && row.deformed_radius_m >= 0.0) {
            return Err(CalibrationError::RowRadius {
                index,
                value: row.deformed_radius_m,
            });
        }
        if index > 0 && row.depth_m <= rows[index - 1].depth_m {
            return Err(CalibrationError::RowsNotIncreasing {
                index,
                value: row.depth_m,
                previous_value: rows[index - 1].depth_m,
            });
        }
    }
    Ok(())
}

impl CalibrationTable {
    /// Builds a table from measured rows, fitting R_d(δ) with the given breakpoint.
    #[allow(clippy::too_many_arguments)] // Each argument is one field of the file format.
    pub fn new(
        source: CalibrationSource,
        description: impl Into<String>,
        tool: ToolShape,
        material: Material,
        threshold_m: f64,
        block_m: Option<[f64; 3]>,
        rows: Vec<CalibrationRow>,
        breakpoint_m: f64,
    ) -> Result<Self, CalibrationError> {
        validate_rows(&rows)?;
        let fit = Self::fit(&rows, breakpoint_m)?;
        let table = CalibrationTable {
            source,
            description: description.into(),
            tool,
            material,
            threshold_m,
            block_m,
            rows,
            fit,
            surface: None,
        };
        table.validate()?;
        Ok(table)
    }

    /// The paper's fit of `rows`: linear below `breakpoint_m`, quadratic beyond, continuous at
    /// the breakpoint. See [`CalibrationFit::from_rows`].
    pub fn fit(
        rows: &[CalibrationRow],
        breakpoint_m: f64,
    ) -> Result<CalibrationFit, CalibrationError> {
        validate_rows(rows)?;
        CalibrationFit::from_rows(rows, breakpoint_m)
    }

    fn validate(&self) -> Result<(), CalibrationError> {
        self.tool.validate()?;
        if !(self.threshold_m.is_finite() && self.threshold_m > 0.0) {
            return Err(CalibrationError::Threshold(self.threshold_m));
        }
        if let Some(block) = self.block_m
            && let Some((index, &value)) = block
                .iter()
                .enumerate()
                .find(|(_, v)| !(v.is_finite() && **v > 0.0))
        {
            return Err(CalibrationError::Block { index, value });
        }
        validate_rows(&self.rows)?;
        self.fit.validate()
    }

    /// R_d for indentation `depth_m` from the fit, ≥ 0; 0 for no (or a non-finite) depth.
    pub fn deformed_radius_m(&self, depth_m: f64) -> f64 {
        self.fit.evaluate_m(depth_m)
    }

    pub fn source(&self) -> CalibrationSource {
        self.source
    }

    pub fn description(&self) -> &str {
        &self.description
    }

    pub fn tool(&self) -> &ToolShape {
        &self.tool
    }

    pub fn material(&self) -> &Material {
        &self.material
    }

    pub fn threshold_m(&self) -> f64 {
        self.threshold_m
    }

    pub fn block_m(&self) -> Option<[f64; 3]> {
        self.block_m
    }

    pub fn rows(&self) -> &[CalibrationRow] {
        &self.rows
    }

    pub fn fit_coefficients(&self) -> &CalibrationFit {
        &self.fit
    }

    /// The tabulated FEM surface the `fem` render profile draws (proto/WIRE.md, "Deformation
    /// profile"), when the calibration wrote one.
    pub fn surface(&self) -> Option<&SurfaceFamily> {
        self.surface.as_ref()
    }

    /// The table with `surface` as its tabulated FEM surface (a [`SurfaceFamily`] is valid by
    /// construction, so this cannot fail).
    pub fn with_surface(mut self, surface: SurfaceFamily) -> Self {
        self.surface = Some(surface);
        self
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    const MM: f64 = 1e-3;

    pub(super) fn sphere10() -> CalibrationTable {
        CalibrationTable::half_space(
            ToolShape::sphere(10.0 * MM).unwrap(),
            Material::PAPER_SOFT,
            PAPER_THRESHOLD_M,
        )
        .unwrap()
    }

    #[test]
    fn a_table_carries_its_surface_and_reads_without_one() {
        use crate::deformation::{SurfaceFamily, SurfaceRow};
        let family =
            SurfaceFamily::new(0.5, MM, vec![SurfaceRow::new(MM, vec![MM, 0.5 * MM, 0.0])])
                .unwrap();
        let plain = sphere10();
        assert!(plain.surface().is_none());
        assert!(!serde_json::to_string(&plain).unwrap().contains("surface"));
        let table = plain.clone().with_surface(family.clone());
        let text = serde_json::to_string(&table).unwrap();
        let back: CalibrationTable = serde_json::from_str(&text).unwrap();
        assert_eq!(back.surface(), Some(&family));
        assert_eq!(back, table);
        // A table whose surface is malformed is refused, naming the field.
        let bad = text.replace(
            "\"depression_m\":[0.001,0.0005,0.0]",
            "\"depression_m\":[0.001,0.0005]",
        );
        assert_ne!(bad, text);
        let err = serde_json::from_str::<CalibrationTable>(&bad)
            .unwrap_err()
            .to_string();
        assert!(err.contains("must end at 0"), "{err}");
    }

    #[test]
    fn evaluation_is_clamped_and_safe() {
        let table = sphere10();
        for d in [0.0, -1.0, f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert_eq!(table.deformed_radius_m(d), 0.0);
        }
        let fit = CalibrationFit {
            breakpoint_m: 0.007,
            linear: [-0.01, 1.0],
            quadratic: [-0.003, 0.0, 0.0],
        };
        assert_eq!(fit.evaluate_m(0.001), 0.0);
    }

    #[test]
    fn json_round_trip_has_the_wire_layout() {
        let table = sphere10();
        let json = serde_json::to_value(&table).unwrap();
        assert_eq!(json["format"], "softhaptic-calibration");
        assert_eq!(json["version"], 1);
        assert_eq!(json["source"], "half_space");
        assert_eq!(json["tool"]["shape"], "sphere");
        assert_eq!(json["threshold_m"], 0.0005);
        assert!(json.get("block_m").is_none());
        assert_eq!(json["rows"].as_array().unwrap().len(), 20);
        assert_eq!(json["fit"]["quadratic"].as_array().unwrap().len(), 3);
        let back: CalibrationTable = serde_json::from_value(json).unwrap();
        assert_eq!(back, table);
    }

    fn table_json_with(edit: impl FnOnce(&mut serde_json::Value)) -> String {
        let mut json = serde_json::to_value(sphere10()).unwrap();
        edit(&mut json);
        json.to_string()
    }

    #[test]
    fn invalid_tables_are_refused_with_field_and_value() {
        type Edit = Box<dyn FnOnce(&mut serde_json::Value)>;
        let cases: Vec<(Edit, &str)> = vec![
            (
                Box::new(|j| j["rows"][3]["depth_m"] = 0.001.into()),
                "rows[3].depth_m = 0.001 is not greater than rows[2].depth_m = 0.0015",
            ),
            (
                Box::new(|j| j["rows"][5]["deformed_radius_m"] = (-0.02).into()),
                "rows[5].deformed_radius_m must be finite and >= 0, got -0.02",
            ),
            (
                Box::new(|j| j["threshold_m"] = 0.0.into()),
                "threshold_m must be finite and > 0, got 0",
            ),
            (
                Box::new(|j| j["format"] = "other".into()),
                "format must be \"softhaptic-calibration\"",
            ),
            (
                Box::new(|j| j["version"] = 2.into()),
                "version must be 1, got 2",
            ),
            (
                Box::new(|j| j["rows"] = serde_json::json!([])),
                "rows must not be empty",
            ),
            (
                Box::new(|j| j["block_m"] = serde_json::json!([0.1, -0.1, 0.05])),
                "block_m[1] must be finite and > 0, got -0.1",
            ),
            (
                Box::new(|j| j["fit"]["quadratic"][0] = 5.0.into()),
                "fit.quadratic does not meet fit.linear",
            ),
            (
                Box::new(|j| j["tool"]["radius_m"] = (-0.01).into()),
                "radius_m must be finite and > 0, got -0.01",
            ),
            (
                Box::new(|j| j["material"]["poisson_ratio"] = 0.7.into()),
                "poisson_ratio",
            ),
            (
                Box::new(|j| j["source"] = "guess".into()),
                "unknown variant `guess`",
            ),
        ];
        for (edit, expected) in cases {
            let text = table_json_with(edit);
            let err = serde_json::from_str::<CalibrationTable>(&text).unwrap_err();
            assert!(
                err.to_string().contains(expected),
                "expected {expected:?} in {err}"
            );
        }
    }
}
