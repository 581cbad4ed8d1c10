//! Stiffer inclusions inside the object (palpation): where each one is, and the FEM table of
//! how much it stiffens the contact.
//!
//! An [`Inclusion`] is a sphere in the object's frame with its modulus as a multiple of the
//! tissue's. The [`InclusionTable`] is what the calibration's FEM measured: the force with the
//! inclusion over the force of the homogeneous block at the same indentation (the *force
//! ratio*), on a grid of five axes — the tool's indentation δ, the lateral offset of the
//! tool's contact point from the inclusion's centre, the centre's depth below the surface, the
//! inclusion's radius and its stiffness ratio. The runtime multiplies its own contact model by
//! the interpolated ratio (`softhaptic_device::inclusion`), so a scene keeps its model and its
//! corrections and the FEM supplies only what the homogeneous model cannot know. A ratio, not a
//! force, is tabulated because the FEM's own discretisation error is common to the two runs and
//! cancels in it.
//!
//! Every `InclusionTable` in the program has been validated: deserialising one runs the same
//! checks as [`InclusionTable::new`]. The positions are what a trainee must find: they reach a
//! viewer only in the `inclusions` message ([`crate::wire::InclusionsMessage`]), which the server
//! sends by role.

use serde::{Deserialize, Serialize};

use crate::{Material, ToolShape};

/// Format name of the JSON file.
pub const INCLUSION_TABLE_FORMAT: &str = "softhaptic-inclusion-table";

/// Stiffness ratios a scene may give an inclusion (tumours run from about 1.5 to 10 times the
/// tissue around them).
pub const STIFFNESS_RATIO_RANGE: std::ops::RangeInclusive<f64> = 1.5..=10.0;

/// One spherical inclusion, resolved: its centre in the object's frame, its radius and its
/// modulus over the tissue's.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Inclusion {
    pub centre_in_object_m: [f64; 3],
    pub radius_m: f64,
    pub stiffness_ratio: f64,
    /// Depth of the centre below the surface point it was placed under, along that point's
    /// normal (what the scene asked for; kept so a recording says it).
    pub centre_depth_m: f64,
}

/// Why an inclusion table was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum InclusionTableError {
    #[error("format {0:?}: expected {INCLUSION_TABLE_FORMAT:?}")]
    Format(String),
    #[error("axis {axis}: {reason}")]
    Axis { axis: &'static str, reason: String },
    #[error("force_ratio: {0}")]
    Values(String),
}

/// The FEM's force ratio on a regular grid (module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RawInclusionTable", into = "RawInclusionTable")]
pub struct InclusionTable {
    raw: RawInclusionTable,
}

/// The JSON layout, checked by `TryFrom` on the way in.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawInclusionTable {
    format: String,
    description: String,
    tool: ToolShape,
    material: Material,
    /// The FEM block's size, x, y, z.
    block_m: [f64; 3],
    /// Tool indentation δ.
    depths_m: Vec<f64>,
    /// Lateral offset of the tool's contact point from the inclusion's centre.
    offsets_m: Vec<f64>,
    /// Depth of the inclusion's centre below the undeformed surface.
    centre_depths_m: Vec<f64>,
    radii_m: Vec<f64>,
    stiffness_ratios: Vec<f64>,
    /// F_with / F_homogeneous, row-major over (ratio, radius, centre depth, offset, depth): the
    /// depth varies fastest.
    force_ratio: Vec<f64>,
}

impl TryFrom<RawInclusionTable> for InclusionTable {
    type Error = InclusionTableError;
    fn try_from(raw: RawInclusionTable) -> Result<Self, Self::Error> {
        if raw.format != INCLUSION_TABLE_FORMAT {
            return Err(InclusionTableError::Format(raw.format));
        }
        let axes: [(&'static str, &Vec<f64>, f64); 5] = [
            ("depths_m", &raw.depths_m, 0.0),
            ("offsets_m", &raw.offsets_m, 0.0),
            ("centre_depths_m", &raw.centre_depths_m, 0.0),
            ("radii_m", &raw.radii_m, 0.0),
            ("stiffness_ratios", &raw.stiffness_ratios, 1.0),
        ];
        let mut count = 1usize;
        for (axis, values, floor) in axes {
            let reason = if values.is_empty() {
                Some("is empty".to_owned())
            } else if let Some(v) = values.iter().find(|v| !(v.is_finite() && **v >= floor)) {
                Some(format!("{v} is not finite and at least {floor}"))
            } else if values.windows(2).any(|w| w[1] <= w[0]) {
                Some("is not strictly increasing".to_owned())
            } else {
                None
            };
            if let Some(reason) = reason {
                return Err(InclusionTableError::Axis { axis, reason });
            }
            count *= values.len();
        }
        if raw.force_ratio.len() != count {
            return Err(InclusionTableError::Values(format!(
                "{} values for a grid of {count}",
                raw.force_ratio.len()
            )));
        }
        if let Some(v) = raw
            .force_ratio
            .iter()
            .find(|v| !(v.is_finite() && **v > 0.0))
        {
            return Err(InclusionTableError::Values(format!(
                "{v} is not a finite positive ratio"
            )));
        }
        Ok(InclusionTable { raw })
    }
}

impl From<InclusionTable> for RawInclusionTable {
    fn from(t: InclusionTable) -> Self {
        t.raw
    }
}

impl InclusionTable {
    /// A table from its axes and values (row-major, depth fastest), checked.
    #[allow(clippy::too_many_arguments)] // the five axes are the table
    pub fn new(
        description: String,
        tool: ToolShape,
        material: Material,
        block_m: [f64; 3],
        depths_m: Vec<f64>,
        offsets_m: Vec<f64>,
        centre_depths_m: Vec<f64>,
        radii_m: Vec<f64>,
        stiffness_ratios: Vec<f64>,
        force_ratio: Vec<f64>,
    ) -> Result<Self, InclusionTableError> {
        Self::try_from(RawInclusionTable {
            format: INCLUSION_TABLE_FORMAT.to_owned(),
            description,
            tool,
            material,
            block_m,
            depths_m,
            offsets_m,
            centre_depths_m,
            radii_m,
            stiffness_ratios,
            force_ratio,
        })
    }

    pub fn description(&self) -> &str {
        &self.raw.description
    }
    pub fn tool(&self) -> &ToolShape {
        &self.raw.tool
    }
    pub fn material(&self) -> &Material {
        &self.raw.material
    }
    pub fn block_m(&self) -> [f64; 3] {
        self.raw.block_m
    }
    pub fn depths_m(&self) -> &[f64] {
        &self.raw.depths_m
    }
    pub fn offsets_m(&self) -> &[f64] {
        &self.raw.offsets_m
    }
    pub fn centre_depths_m(&self) -> &[f64] {
        &self.raw.centre_depths_m
    }
    pub fn radii_m(&self) -> &[f64] {
        &self.raw.radii_m
    }
    pub fn stiffness_ratios(&self) -> &[f64] {
        &self.raw.stiffness_ratios
    }
    /// The values, row-major over (ratio, radius, centre depth, offset, depth).
    pub fn force_ratio(&self) -> &[f64] {
        &self.raw.force_ratio
    }

    /// The value at grid indices (ratio, radius, centre depth, offset, depth).
    pub fn at(
        &self,
        ratio: usize,
        radius: usize,
        centre: usize,
        offset: usize,
        depth: usize,
    ) -> f64 {
        let r = &self.raw;
        let i = (((ratio * r.radii_m.len() + radius) * r.centre_depths_m.len() + centre)
            * r.offsets_m.len()
            + offset)
            * r.depths_m.len()
            + depth;
        r.force_ratio[i]
    }

    /// Why `inclusion` lies outside what the table measured (its radius or its ratio), or `None`
    /// when the table covers it. Depth and offset are clamped at run time instead: they change
    /// as the tool moves.
    pub fn refuses(&self, radius_m: f64, stiffness_ratio: f64) -> Option<String> {
        let within = |axis: &[f64], v: f64| {
            let (lo, hi) = (axis[0], axis[axis.len() - 1]);
            // A one-value axis covers its value only (to a part in 10⁹: a scene writes it in
            // decimal as the table does).
            v >= lo * (1.0 - 1e-9) && v <= hi * (1.0 + 1e-9)
        };
        if !within(self.radii_m(), radius_m) {
            return Some(format!(
                "radius {radius_m} m is outside the table's radii {:?} m",
                self.radii_m()
            ));
        }
        if !within(self.stiffness_ratios(), stiffness_ratio) {
            return Some(format!(
                "stiffness ratio {stiffness_ratio} is outside the table's ratios {:?}",
                self.stiffness_ratios()
            ));
        }
        None
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    fn table(values: Vec<f64>) -> Result<InclusionTable, InclusionTableError> {
        InclusionTable::new(
            "test".into(),
            ToolShape::sphere(0.01).unwrap(),
            Material::PAPER_SOFT,
            [0.08, 0.08, 0.04],
            vec![0.001, 0.002],
            vec![0.0, 0.005, 0.01],
            vec![0.01],
            vec![0.005],
            vec![2.0, 4.0],
            values,
        )
    }

    #[test]
    fn a_table_round_trips_and_indexes_depth_fastest() {
        let values: Vec<f64> = (0..12).map(|i| 1.0 + i as f64 * 0.1).collect();
        let t = table(values).unwrap();
        assert_eq!(t.at(0, 0, 0, 0, 1), 1.1);
        assert_eq!(t.at(0, 0, 0, 2, 0), 1.4);
        assert_eq!(t.at(1, 0, 0, 0, 0), 1.6);
        let json = serde_json::to_string(&t).unwrap();
        let back: InclusionTable = serde_json::from_str(&json).unwrap();
        assert_eq!(back, t);
        assert!(t.refuses(0.005, 3.0).is_none());
        assert!(t.refuses(0.006, 3.0).unwrap().contains("radius 0.006"));
        assert!(t.refuses(0.005, 5.0).unwrap().contains("ratio 5"));
    }

    #[test]
    fn a_bad_table_is_refused_naming_what_is_wrong() {
        let err = table(vec![1.0; 11]).unwrap_err().to_string();
        assert!(err.contains("11 values for a grid of 12"), "{err}");
        let mut v = vec![1.0; 12];
        v[3] = f64::NAN;
        assert!(table(v).unwrap_err().to_string().contains("NaN"));
        let mut raw = serde_json::to_value(table(vec![1.0; 12]).unwrap()).unwrap();
        raw["offsets_m"] = serde_json::json!([0.0, 0.01, 0.005]);
        let err = serde_json::from_value::<InclusionTable>(raw)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("offsets_m") && err.contains("increasing"),
            "{err}"
        );
    }
}
