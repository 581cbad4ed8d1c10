//! Rigid tool tips.
//!
//! The tool frame has its origin at the tip's proximal point (the first point that touches a
//! surface: the bottom of the sphere, the apex of the cone) and its `+y` axis running from the
//! tip up the shaft toward the hand. An unrotated tool therefore points straight down onto a
//! horizontal surface of the y-up world.

use serde::{Deserialize, Serialize};

/// Why a tool description was refused; names the field and the value.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum ToolError {
    #[error("radius_m must be finite and > 0, got {0}")]
    Radius(f64),
    #[error("half_angle_rad must be finite and in (0, π/2), got {0}")]
    HalfAngle(f64),
}

/// The shape of the tool tip.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "shape", rename_all = "snake_case", deny_unknown_fields)]
pub enum ToolShape {
    /// A sphere of radius `radius_m` (Hertz contact).
    Sphere { radius_m: f64 },
    /// A cone (Sneddon contact). `half_angle_rad` is the angle between the cone's axis and its
    /// flank (so a sharp needle has a small half-angle); `radius_m` is the radius of the cone's
    /// base, where it joins the shaft, so the conical part is `radius_m / tan(half_angle_rad)` long.
    ///
    /// The paper's eq. (5) measures its α between the flank and the surface instead; the two agree
    /// at 45° only (docs/physics.md).
    Cone { half_angle_rad: f64, radius_m: f64 },
}

impl ToolShape {
    /// A sphere of radius `radius_m`, validated.
    pub fn sphere(radius_m: f64) -> Result<Self, ToolError> {
        let s = ToolShape::Sphere { radius_m };
        s.validate()?;
        Ok(s)
    }

    /// A cone with the given half-angle (axis to flank) and base radius, validated.
    pub fn cone(half_angle_rad: f64, radius_m: f64) -> Result<Self, ToolError> {
        let c = ToolShape::Cone {
            half_angle_rad,
            radius_m,
        };
        c.validate()?;
        Ok(c)
    }

    /// Checks the fields; deserialised tools must be validated before use.
    pub fn validate(&self) -> Result<(), ToolError> {
        let radius_m = self.radius_m();
        if !(radius_m.is_finite() && radius_m > 0.0) {
            return Err(ToolError::Radius(radius_m));
        }
        if let ToolShape::Cone { half_angle_rad, .. } = *self
            && !(half_angle_rad.is_finite()
                && half_angle_rad > 0.0
                && half_angle_rad < std::f64::consts::FRAC_PI_2)
        {
            return Err(ToolError::HalfAngle(half_angle_rad));
        }
        Ok(())
    }

    /// The tip's lateral radius: the sphere's radius, or the cone's base radius.
    pub fn radius_m(&self) -> f64 {
        match *self {
            ToolShape::Sphere { radius_m } | ToolShape::Cone { radius_m, .. } => radius_m,
        }
    }

    /// Length of the tip along its axis: the sphere's radius (the lower hemisphere), or the cone's
    /// height from apex to base.
    pub fn tip_length_m(&self) -> f64 {
        match *self {
            ToolShape::Sphere { radius_m } => radius_m,
            ToolShape::Cone {
                half_angle_rad,
                radius_m,
            } => radius_m / half_angle_rad.tan(),
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn invalid_tools_are_refused() {
        assert_eq!(ToolShape::sphere(0.0), Err(ToolError::Radius(0.0)));
        assert!(ToolShape::cone(std::f64::consts::FRAC_PI_2, 0.01).is_err());
        assert!(ToolShape::cone(0.0, 0.01).is_err());
        assert!(ToolShape::cone(f64::NAN, 0.01).is_err());
        assert!(ToolShape::cone(0.5, 0.01).is_ok());
    }

    #[test]
    fn json_names_the_convention() {
        let c = ToolShape::cone(std::f64::consts::FRAC_PI_4, 0.01).unwrap();
        let s = serde_json::to_string(&c).unwrap();
        assert!(s.contains("\"shape\":\"cone\"") && s.contains("half_angle_rad"));
        assert_eq!(serde_json::from_str::<ToolShape>(&s).unwrap(), c);
    }

    #[test]
    fn cone_tip_length_follows_half_angle() {
        let c = ToolShape::cone(std::f64::consts::FRAC_PI_4, 0.01).unwrap();
        assert!((c.tip_length_m() - 0.01).abs() < 1e-12);
    }
}
