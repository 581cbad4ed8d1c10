//! Linear-elastic material constants.

use serde::{Deserialize, Serialize};

/// Why a material was refused. Each variant names the field and the offending value.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum MaterialError {
    #[error("youngs_modulus_pa must be finite and > 0, got {0}")]
    YoungsModulus(f64),
    #[error("poisson_ratio must be finite and in [0, 0.5), got {0}")]
    PoissonRatio(f64),
}

/// An isotropic linear-elastic material.
///
/// The fields are private so that every `Material` in the program has passed [`Material::new`]:
/// E > 0 and 0 ≤ ν < 0.5 (ν = 0.5 makes the bulk modulus infinite). Deserialisation goes through
/// the same check.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RawMaterial", into = "RawMaterial")]
pub struct Material {
    youngs_modulus_pa: f64,
    poisson_ratio: f64,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMaterial {
    youngs_modulus_pa: f64,
    poisson_ratio: f64,
}

impl TryFrom<RawMaterial> for Material {
    type Error = MaterialError;
    fn try_from(raw: RawMaterial) -> Result<Self, Self::Error> {
        Material::new(raw.youngs_modulus_pa, raw.poisson_ratio)
    }
}

impl From<Material> for RawMaterial {
    fn from(m: Material) -> Self {
        RawMaterial {
            youngs_modulus_pa: m.youngs_modulus_pa,
            poisson_ratio: m.poisson_ratio,
        }
    }
}

impl Material {
    /// Soft tissue as the paper's experiments model it: E = 50 kPa, ν = 0.33.
    pub const PAPER_SOFT: Material = Material {
        youngs_modulus_pa: 50e3,
        poisson_ratio: 0.33,
    };
    /// The paper's stiffer calibration material: E = 1.5 MPa, ν = 0.33.
    pub const PAPER_STIFF: Material = Material {
        youngs_modulus_pa: 1.5e6,
        poisson_ratio: 0.33,
    };

    /// Validates and builds a material.
    pub fn new(youngs_modulus_pa: f64, poisson_ratio: f64) -> Result<Self, MaterialError> {
        if !(youngs_modulus_pa.is_finite() && youngs_modulus_pa > 0.0) {
            return Err(MaterialError::YoungsModulus(youngs_modulus_pa));
        }
        if !(poisson_ratio.is_finite() && (0.0..0.5).contains(&poisson_ratio)) {
            return Err(MaterialError::PoissonRatio(poisson_ratio));
        }
        Ok(Self {
            youngs_modulus_pa,
            poisson_ratio,
        })
    }

    /// Young's modulus E in pascals.
    pub fn youngs_modulus_pa(&self) -> f64 {
        self.youngs_modulus_pa
    }

    /// Poisson's ratio ν (dimensionless).
    pub fn poisson_ratio(&self) -> f64 {
        self.poisson_ratio
    }

    /// Shear modulus G = E / (2(1+ν)).
    pub fn shear_modulus_pa(&self) -> f64 {
        self.youngs_modulus_pa / (2.0 * (1.0 + self.poisson_ratio))
    }

    /// Plane-strain modulus E* = E / (1 − ν²), the constant of every half-space contact law.
    pub fn plane_strain_modulus_pa(&self) -> f64 {
        self.youngs_modulus_pa / (1.0 - self.poisson_ratio * self.poisson_ratio)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn reference_moduli_match_physics_reference() {
        let m = Material::PAPER_SOFT;
        assert!((m.plane_strain_modulus_pa() - 56_110.0).abs() < 1.0);
        assert!((m.shear_modulus_pa() - 18_797.0).abs() < 1.0);
    }

    #[test]
    fn invalid_values_are_refused_with_field_and_value() {
        let e = Material::new(-5.0, 0.3).unwrap_err();
        assert_eq!(e, MaterialError::YoungsModulus(-5.0));
        assert!(e.to_string().contains("youngs_modulus_pa") && e.to_string().contains("-5"));
        assert!(Material::new(f64::NAN, 0.3).is_err());
        assert!(
            Material::new(1e3, 0.5)
                .unwrap_err()
                .to_string()
                .contains("poisson_ratio")
        );
        assert!(Material::new(1e3, -0.1).is_err());
        assert!(Material::new(1.0, 0.0).is_ok());
        assert!(Material::new(1e9, 0.4999).is_ok());
    }

    #[test]
    fn deserialisation_validates() {
        let ok: Material =
            serde_json::from_str(r#"{"youngs_modulus_pa":50000,"poisson_ratio":0.33}"#).unwrap();
        assert_eq!(ok, Material::PAPER_SOFT);
        let bad =
            serde_json::from_str::<Material>(r#"{"youngs_modulus_pa":0,"poisson_ratio":0.3}"#)
                .unwrap_err();
        assert!(bad.to_string().contains("youngs_modulus_pa"));
    }
}
