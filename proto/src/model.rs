//! Which contact model a scene object uses, and how far each model has been measured to hold.
//!
//! The paper's laws (Hertz for a sphere, Sneddon for a cone) assume a flat elastic half-space
//! pressed perpendicularly by a paraboloid, in small strain. A [`ModelSpec`] switches on the
//! corrections of docs/physics.md ("Corrections that go past the paper") one by one, so a scene
//! pays only for what its objects need (`docs/design.md`, invariant 7). The runtime evaluates them
//! in `softhaptic_device::model`; the offline calibration measures each against the FEM and writes
//! a [`ModelLimitsFile`] of the depths where each combination stays within 7 % of it, which a scene
//! turns into the [`ValidityLimits`] its flags use (the paper's where nothing was measured).

use serde::{Deserialize, Serialize};

use crate::ToolShape;

/// Why a model description was refused; names the field and the value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ModelError {
    #[error("thickness.thickness_m must be finite and > 0, got {0}")]
    Thickness(f64),
    #[error("exact_sphere applies to a sphere tool only; this tool is a cone")]
    ExactSphereOnCone,
    #[error(
        "thickness.bonded = false has no published law for a cone (only the bonded layer of \
         Garcia & Garcia 2018); set bonded = true or remove the thickness correction"
    )]
    UnbondedCone,
}

/// A layer of finite thickness resting on a rigid base (Dimitriadis et al. 2002 for a sphere,
/// Garcia & Garcia 2018 for a cone; bonded, times a residual fitted to the project's FEM at the
/// material's ν).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LayerSpec {
    /// Thickness h of the elastic layer above the rigid base, metres.
    pub thickness_m: f64,
    /// True when the layer is glued to the base (no slip); false when it slides on it.
    pub bonded: bool,
}

/// The contact model of one scene object: the paper's law of its tool, and the corrections that
/// apply. Every field defaults to off, which is the paper's law exactly.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelSpec {
    /// Sneddon's exact sphere instead of Hertz's paraboloid (sphere tools only).
    pub exact_sphere: bool,
    /// The object's local curvature at the contact, taken from the haptic mesh (effective radius
    /// for a sphere, the derived law for a cone).
    pub curvature: bool,
    /// The object is a layer of this thickness on a rigid base.
    pub thickness: Option<LayerSpec>,
    /// Large-strain (neo-Hookean) stiffening, fitted to the project's own neo-Hookean FEM.
    pub hyperelastic: bool,
    /// The force along the contact normal when the tool axis is inclined to it.
    pub inclination: bool,
}

impl ModelSpec {
    /// The paper's law with no correction.
    pub const PAPER: ModelSpec = ModelSpec {
        exact_sphere: false,
        curvature: false,
        thickness: None,
        hyperelastic: false,
        inclination: false,
    };

    /// Checks the fields against the tool they will be used with.
    pub fn validate(&self, tool: &ToolShape) -> Result<(), ModelError> {
        if let Some(layer) = self.thickness {
            if !(layer.thickness_m.is_finite() && layer.thickness_m > 0.0) {
                return Err(ModelError::Thickness(layer.thickness_m));
            }
            if matches!(tool, ToolShape::Cone { .. }) && !layer.bonded {
                return Err(ModelError::UnbondedCone);
            }
        }
        if self.exact_sphere && matches!(tool, ToolShape::Cone { .. }) {
            return Err(ModelError::ExactSphereOnCone);
        }
        Ok(())
    }

    /// True when no correction is on.
    pub fn is_paper(&self) -> bool {
        *self == ModelSpec::PAPER
    }

    /// The corrections that are on, by their scene-file names, in a fixed order.
    pub fn corrections(&self) -> Vec<&'static str> {
        let mut names = Vec::new();
        if self.exact_sphere {
            names.push("exact_sphere");
        }
        if self.curvature {
            names.push("curvature");
        }
        match self.thickness {
            Some(LayerSpec { bonded: true, .. }) => names.push("thickness_bonded"),
            Some(LayerSpec { bonded: false, .. }) => names.push("thickness_unbonded"),
            None => {}
        }
        if self.hyperelastic {
            names.push("hyperelastic");
        }
        if self.inclination {
            names.push("inclination");
        }
        names
    }

    /// A human-readable name, e.g. "Hertz + exact sphere + bonded layer 30 mm + neo-Hookean fit".
    pub fn label(&self, tool: &ToolShape) -> String {
        let mut label = String::from(match tool {
            ToolShape::Sphere { .. } => "Hertz",
            ToolShape::Cone { .. } => "Sneddon cone",
        });
        if self.exact_sphere {
            label.push_str(" + exact sphere");
        }
        if self.curvature {
            label.push_str(" + curvature");
        }
        if let Some(layer) = self.thickness {
            let kind = if layer.bonded { "bonded" } else { "sliding" };
            label.push_str(&format!(
                " + {kind} layer {:.0} mm",
                layer.thickness_m * 1e3
            ));
        }
        if self.hyperelastic {
            label.push_str(" + neo-Hookean fit");
        }
        if self.inclination {
            label.push_str(" + inclination");
        }
        label
    }
}

/// Which tool a measured limit belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ToolKind {
    Sphere,
    Cone,
}

impl ToolKind {
    pub fn of(tool: &ToolShape) -> Self {
        match tool {
            ToolShape::Sphere { .. } => ToolKind::Sphere,
            ToolShape::Cone { .. } => ToolKind::Cone,
        }
    }
}

/// How far one model was measured to stay within the threshold of the neo-Hookean FEM.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeasuredLimit {
    pub tool: ToolKind,
    pub model: ModelSpec,
    /// Depth up to which the model stays within the threshold: the first crossing, or the deepest
    /// depth measured when it never crosses (`crossed` false).
    pub valid_depth_m: f64,
    /// Whether the error crossed the threshold within the measured depths.
    pub crossed: bool,
    /// Largest angle between tool axis and contact normal within the threshold, when measured.
    pub valid_inclination_rad: Option<f64>,
    /// The experiment the figure comes from (tool size, block, FEM law and mesh).
    pub reference: String,
    /// Poisson's ratio of the material the limit was measured on; absent for the paper's
    /// [`PAPER_POISSON_RATIO`] (the files written before limits were measured over ν).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub poisson_ratio: Option<f64>,
}

/// Poisson's ratio of the paper's experiments, and of a measured limit that names none.
pub const PAPER_POISSON_RATIO: f64 = 0.33;

impl MeasuredLimit {
    /// Poisson's ratio the limit was measured at.
    pub fn measured_poisson_ratio(&self) -> f64 {
        self.poisson_ratio.unwrap_or(PAPER_POISSON_RATIO)
    }
}

/// The file `softhaptic-calibrate all` writes (`scenes/calibration/model_limits.json`; a single
/// study writes its own into `--out`) and scenes load to set the validity flags of their active
/// model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelLimitsFile {
    /// Format version; 1.
    pub version: u32,
    /// The error threshold the limits are measured at, percent of the largest reference force
    /// (the paper's eq. 9 uses 7).
    pub threshold_percent: f64,
    pub limits: Vec<MeasuredLimit>,
}

impl ModelLimitsFile {
    pub const VERSION: u32 = 1;

    /// The measured limit of exactly this tool kind and model at the paper's ν, if it was
    /// measured.
    pub fn lookup(&self, tool: &ToolShape, spec: &ModelSpec) -> Option<&MeasuredLimit> {
        self.lookup_at(tool, spec, PAPER_POISSON_RATIO)
    }

    /// The measured limit of exactly this tool kind and model at Poisson's ratio
    /// `poisson_ratio` (within 1e-6), if it was measured there.
    pub fn lookup_at(
        &self,
        tool: &ToolShape,
        spec: &ModelSpec,
        poisson_ratio: f64,
    ) -> Option<&MeasuredLimit> {
        self.measured(tool, spec)
            .find(|l| (l.measured_poisson_ratio() - poisson_ratio).abs() < 1e-6)
    }

    /// Every limit of this tool kind and model, whatever its ν.
    fn measured(&self, tool: &ToolShape, spec: &ModelSpec) -> impl Iterator<Item = &MeasuredLimit> {
        let kind = ToolKind::of(tool);
        let spec = *spec;
        self.limits
            .iter()
            .filter(move |l| l.tool == kind && l.model == spec)
    }

    /// The limit of this tool kind and model at `poisson_ratio`: the one measured there, or,
    /// between two measured ν, the depth and inclination interpolated linearly in ν between the
    /// nearest measured on either side (its `reference` names both); `None` outside the measured
    /// range.
    pub fn limit_at(
        &self,
        tool: &ToolShape,
        spec: &ModelSpec,
        poisson_ratio: f64,
    ) -> Option<MeasuredLimit> {
        if let Some(exact) = self.lookup_at(tool, spec, poisson_ratio) {
            return Some(exact.clone());
        }
        let nu = poisson_ratio;
        let below = self
            .measured(tool, spec)
            .filter(|l| l.measured_poisson_ratio() < nu)
            .max_by(|a, b| {
                a.measured_poisson_ratio()
                    .total_cmp(&b.measured_poisson_ratio())
            })?;
        let above = self
            .measured(tool, spec)
            .filter(|l| l.measured_poisson_ratio() > nu)
            .min_by(|a, b| {
                a.measured_poisson_ratio()
                    .total_cmp(&b.measured_poisson_ratio())
            })?;
        let (nu0, nu1) = (
            below.measured_poisson_ratio(),
            above.measured_poisson_ratio(),
        );
        let t = (nu - nu0) / (nu1 - nu0);
        let lerp = |a: f64, b: f64| a + t * (b - a);
        Some(MeasuredLimit {
            tool: below.tool,
            model: below.model,
            valid_depth_m: lerp(below.valid_depth_m, above.valid_depth_m),
            crossed: below.crossed || above.crossed,
            valid_inclination_rad: match (below.valid_inclination_rad, above.valid_inclination_rad)
            {
                (Some(a), Some(b)) => Some(lerp(a, b)),
                (a, b) => a.or(b),
            },
            reference: format!(
                "interpolated in ν between {} (ν = {nu0:.2}) and {} (ν = {nu1:.2})",
                below.reference, above.reference
            ),
            poisson_ratio: Some(nu),
        })
    }
}

/// The paper's validity depth for both tips: within 7 % of the linear FEM up to 4.3 mm (§4.3).
pub const PAPER_VALID_DEPTH_M: f64 = 4.3e-3;

/// The paper's validity inclination: 22° for the sphere (eq. 7), 9° for the cone (§3.2).
pub fn paper_valid_inclination_rad(tool: &ToolShape) -> f64 {
    let degrees: f64 = match tool {
        ToolShape::Sphere { .. } => 22.0,
        ToolShape::Cone { .. } => 9.0,
    };
    degrees.to_radians()
}

/// The validity limits a model runs with, and where they come from: the measured limit of
/// exactly this tool kind and model when a limits file has one, the paper's otherwise.
#[derive(Debug, Clone, PartialEq)]
pub struct ValidityLimits {
    /// Depth beyond which the contact frame is flagged `beyond_valid_depth`.
    pub valid_depth_m: f64,
    /// Angle between tool axis and contact normal beyond which it is flagged
    /// `beyond_valid_inclination`.
    pub valid_inclination_rad: f64,
    /// The measured limit's `reference`, or [`ValidityLimits::PAPER_SOURCE`].
    pub source: String,
}

impl ValidityLimits {
    /// The source of the paper's limits.
    pub const PAPER_SOURCE: &'static str = "paper";

    /// The paper's limits for `tool`.
    pub fn paper(tool: &ToolShape) -> Self {
        Self {
            valid_depth_m: PAPER_VALID_DEPTH_M,
            valid_inclination_rad: paper_valid_inclination_rad(tool),
            source: Self::PAPER_SOURCE.to_owned(),
        }
    }

    /// The limits of `spec` with `tool` on a material of the paper's ν: measured when `file`
    /// has them, the paper's otherwise. A measured limit without an inclination keeps the
    /// paper's inclination, and says so.
    pub fn of(file: Option<&ModelLimitsFile>, tool: &ToolShape, spec: &ModelSpec) -> Self {
        Self::at_poisson_ratio(file, tool, spec, PAPER_POISSON_RATIO)
    }

    /// The limits of `spec` with `tool` on a material of Poisson's ratio `poisson_ratio`:
    /// measured (or interpolated between two measured ν, see [`ModelLimitsFile::limit_at`])
    /// when `file` has them, the paper's otherwise.
    pub fn at_poisson_ratio(
        file: Option<&ModelLimitsFile>,
        tool: &ToolShape,
        spec: &ModelSpec,
        poisson_ratio: f64,
    ) -> Self {
        let Some(measured) = file.and_then(|f| f.limit_at(tool, spec, poisson_ratio)) else {
            return Self::paper(tool);
        };
        match measured.valid_inclination_rad {
            Some(valid_inclination_rad) => Self {
                valid_depth_m: measured.valid_depth_m,
                valid_inclination_rad,
                source: measured.reference.clone(),
            },
            None => Self {
                valid_depth_m: measured.valid_depth_m,
                valid_inclination_rad: paper_valid_inclination_rad(tool),
                source: format!("{} (inclination: paper)", measured.reference),
            },
        }
    }

    /// True when both limits are the paper's.
    pub fn is_paper(&self) -> bool {
        self.source == Self::PAPER_SOURCE
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_paper_law() {
        let spec: ModelSpec = serde_json::from_str("{}").unwrap();
        assert!(spec.is_paper());
        assert!(spec.corrections().is_empty());
        assert_eq!(spec.label(&ToolShape::Sphere { radius_m: 0.006 }), "Hertz");
    }

    #[test]
    fn invalid_combinations_name_the_field() {
        let cone = ToolShape::Cone {
            half_angle_rad: 0.7,
            radius_m: 0.01,
        };
        let sphere = ToolShape::Sphere { radius_m: 0.006 };
        let mut spec = ModelSpec {
            thickness: Some(LayerSpec {
                thickness_m: -1.0,
                bonded: true,
            }),
            ..ModelSpec::PAPER
        };
        let err = spec.validate(&sphere).unwrap_err().to_string();
        assert!(err.contains("thickness_m") && err.contains("-1"), "{err}");
        spec.thickness = Some(LayerSpec {
            thickness_m: 0.03,
            bonded: false,
        });
        assert!(spec.validate(&sphere).is_ok());
        assert_eq!(spec.validate(&cone), Err(ModelError::UnbondedCone));
        let exact = ModelSpec {
            exact_sphere: true,
            ..ModelSpec::PAPER
        };
        assert_eq!(exact.validate(&cone), Err(ModelError::ExactSphereOnCone));
        assert!(serde_json::from_str::<ModelSpec>(r#"{"exact":true}"#).is_err());
    }

    #[test]
    fn lookup_matches_tool_and_model_exactly() {
        let best = ModelSpec {
            exact_sphere: true,
            hyperelastic: true,
            ..ModelSpec::PAPER
        };
        let file = ModelLimitsFile {
            version: 1,
            threshold_percent: 7.0,
            limits: vec![MeasuredLimit {
                tool: ToolKind::Sphere,
                model: best,
                valid_depth_m: 0.006,
                crossed: false,
                valid_inclination_rad: None,
                reference: "test".into(),
                poisson_ratio: None,
            }],
        };
        let text = serde_json::to_string(&file).unwrap();
        let back: ModelLimitsFile = serde_json::from_str(&text).unwrap();
        let sphere = ToolShape::Sphere { radius_m: 0.006 };
        assert!(back.lookup(&sphere, &best).is_some());
        assert!(back.lookup(&sphere, &ModelSpec::PAPER).is_none());
        let cone = ToolShape::Cone {
            half_angle_rad: 0.7,
            radius_m: 0.01,
        };
        assert!(back.lookup(&cone, &best).is_none());
    }

    #[test]
    fn limits_between_two_measured_poisson_ratios_are_interpolated_and_outside_are_the_papers() {
        let sphere = ToolShape::Sphere { radius_m: 0.006 };
        let at = |nu: Option<f64>, depth: f64| MeasuredLimit {
            tool: ToolKind::Sphere,
            model: ModelSpec::PAPER,
            valid_depth_m: depth,
            crossed: true,
            valid_inclination_rad: Some(0.4),
            reference: format!("block at {nu:?}"),
            poisson_ratio: nu,
        };
        let file = ModelLimitsFile {
            version: 1,
            threshold_percent: 7.0,
            limits: vec![
                at(None, 0.004),
                at(Some(0.49), 0.002),
                at(Some(0.40), 0.003),
            ],
        };
        // At the paper's ν the entry without a ν, exactly as before.
        let paper = ValidityLimits::of(Some(&file), &sphere, &ModelSpec::PAPER);
        assert_eq!(paper.valid_depth_m, 0.004);
        assert_eq!(paper.source, "block at None");
        let measured =
            ValidityLimits::at_poisson_ratio(Some(&file), &sphere, &ModelSpec::PAPER, 0.49);
        assert_eq!(measured.valid_depth_m, 0.002);
        let between =
            ValidityLimits::at_poisson_ratio(Some(&file), &sphere, &ModelSpec::PAPER, 0.445);
        assert!((between.valid_depth_m - 0.0025).abs() < 1e-12);
        assert!(
            between
                .source
                .starts_with("interpolated in ν between block at Some(0.4)")
        );
        let outside =
            ValidityLimits::at_poisson_ratio(Some(&file), &sphere, &ModelSpec::PAPER, 0.2);
        assert!(outside.is_paper());
    }

    #[test]
    fn validity_limits_are_measured_when_present_else_the_papers() {
        let sphere = ToolShape::Sphere { radius_m: 0.01 };
        let cone = ToolShape::Cone {
            half_angle_rad: 0.7,
            radius_m: 0.01,
        };
        let curved = ModelSpec {
            curvature: true,
            ..ModelSpec::PAPER
        };
        let measured = |valid_inclination_rad| MeasuredLimit {
            tool: ToolKind::Sphere,
            model: curved,
            valid_depth_m: 0.0055,
            crossed: true,
            valid_inclination_rad,
            reference: "sphere 10 mm on a 50 mm ball, neo-Hookean FEM".into(),
            poisson_ratio: None,
        };
        let mut file = ModelLimitsFile {
            version: 1,
            threshold_percent: 7.0,
            limits: vec![measured(Some(0.3))],
        };
        let got = ValidityLimits::of(Some(&file), &sphere, &curved);
        assert_eq!(got.valid_depth_m, 0.0055);
        assert_eq!(got.valid_inclination_rad, 0.3);
        assert_eq!(got.source, "sphere 10 mm on a 50 mm ball, neo-Hookean FEM");
        assert!(!got.is_paper());
        // Without a measured inclination, the paper's, and the source says so.
        file.limits = vec![measured(None)];
        let got = ValidityLimits::of(Some(&file), &sphere, &curved);
        assert_eq!(got.valid_inclination_rad, 22f64.to_radians());
        assert!(
            got.source.ends_with("(inclination: paper)"),
            "{}",
            got.source
        );
        // Another model, another tool, or no file: the paper's limits.
        for (tool, spec, f) in [
            (sphere, ModelSpec::PAPER, Some(&file)),
            (cone, curved, Some(&file)),
            (sphere, curved, None),
        ] {
            let got = ValidityLimits::of(f, &tool, &spec);
            assert!(got.is_paper());
            assert_eq!(got.valid_depth_m, 4.3e-3);
            assert_eq!(
                got.valid_inclination_rad,
                paper_valid_inclination_rad(&tool)
            );
        }
        assert_eq!(paper_valid_inclination_rad(&cone), 9f64.to_radians());
    }
}
