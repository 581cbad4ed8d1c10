//! The deformation profiles the viewer draws, exactly as proto/WIRE.md ("Deformation profile")
//! defines them. A scene chooses one ([`RenderProfile`]).
//!
//! `paper`, the paper's profile (§3.3), [`DeformationProfile`]: around the contact axis (the line
//! through the contact point along the outward normal), a render vertex at radial distance r is
//! moved along −n by the depression z(r):
//! - r < a: on the tool surface (the paper's region Π);
//! - a ≤ r < R_d: on the quadratic Bézier cross-section P0 = (a, z0), P1 = (r1, 0), P2 = (R_d, 0),
//!   where P1 is where the tool's tangent at P0 meets the undeformed surface (region Ū);
//! - r ≥ R_d: unchanged.
//!
//! `fem`, the FEM's own top surface, [`SurfaceFamily`]: the calibration tabulates the depression
//! of its block's surface against the radius at each depth of the table, and the viewer
//! interpolates between the two nearest depths after scaling each row to the depth drawn the
//! way the elastic contact itself scales (depression ∝ δ, radius ∝ the contact radius). The
//! paper's Bézier is too shallow everywhere outside the contact and drops the tail beyond R_d
//! (calibration report, "The drawn surface against the FEM surface"); this profile follows the
//! FEM surface at every depth it was calibrated for.
//!
//! The viewer draws the `fem` profile on its render mesh from a [`SurfaceTable`], the profile
//! sampled once per frame, within 2 µm of it.
//!
//! The `paper` profile's contact radius a is the one the contact streams: the contact law's
//! (Hertz's √(Rδ), Sneddon's 2δ tanα/π, bent by the object's curvature when the model is), or
//! Sneddon's exact sphere's ([`exact_sphere_contact_radius_m`]) when the model uses the exact
//! sphere, which stays inside the tool at every depth where Hertz's reaches R at δ = R.
//!
//! The viewer (web/src) implements the same functions in JavaScript; the shared vectors in
//! `proto/vectors/deformation.json` and `proto/vectors/surface_profile.json`, written from this
//! code, keep the two identical. Every degenerate input (zero depth, R_d inside the contact, a
//! contact wider than the tool, a vertical or horizontal tool tangent, NaN) has a defined,
//! continuous answer.

use serde::{Deserialize, Serialize};

use crate::tool::ToolShape;

mod exact_sphere;
mod fem;
mod paper;
mod vectors;

pub use exact_sphere::exact_sphere_contact_radius_m;
pub use fem::{
    SURFACE_TABLE_INTERVALS, SurfaceFamily, SurfaceFamilyError, SurfaceProfile, SurfaceRow,
    SurfaceTable,
};
pub use paper::{DeformationProfile, depression_m};
pub use vectors::{
    DeformationVector, SurfaceProfileVector, SurfaceProfileVectors, deformation_vectors,
    surface_profile_vectors,
};

/// Non-finite or negative inputs count as zero (proto/WIRE.md, "Deformation profile", step 1).
#[inline]
fn sanitise(x: f64) -> f64 {
    if x.is_finite() && x > 0.0 { x } else { 0.0 }
}

/// The tool's profile height above its tip at radius r: the sphere's cap R − √(R² − r²) (r ≤ R),
/// the cone's flank r cot α.
#[inline]
fn tool_height_m(tool: &ToolShape, r_m: f64) -> f64 {
    match *tool {
        ToolShape::Sphere { radius_m } => {
            let r = r_m.min(radius_m);
            radius_m - (radius_m * radius_m - r * r).max(0.0).sqrt()
        }
        ToolShape::Cone { half_angle_rad, .. } => r_m / half_angle_rad.tan(),
    }
}

/// Which cross-section the viewer draws: a scene's `[render] profile`, carried to the viewer by
/// the `scene` message's `render_profile` (proto/WIRE.md). The profile changes only what is
/// drawn, never the force.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RenderProfile {
    /// The paper's Bézier (§3.3), [`DeformationProfile`]. The default for a message or a
    /// recording that does not name one: every viewer before the choice existed drew it.
    #[default]
    Paper,
    /// The FEM's top surface as the calibration tabulated it ([`SurfaceFamily`], carried in the
    /// scene's calibration table).
    Fem,
}

impl RenderProfile {
    /// The name a scene file and the wire use.
    pub fn as_str(self) -> &'static str {
        match self {
            RenderProfile::Paper => "paper",
            RenderProfile::Fem => "fem",
        }
    }
}

/// What the tests of every profile share: the tools of the report and their contact radii.
#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
pub(crate) mod test_tools {
    use crate::tool::ToolShape;

    pub(crate) const MM: f64 = 1e-3;

    pub(crate) fn sphere() -> ToolShape {
        ToolShape::sphere(10.0 * MM).unwrap()
    }

    pub(crate) fn cone() -> ToolShape {
        ToolShape::cone(std::f64::consts::FRAC_PI_4, 10.0 * MM).unwrap()
    }

    pub(crate) fn sphere_a(d: f64) -> f64 {
        (10.0 * MM * d).sqrt()
    }

    pub(crate) fn cone_a(d: f64) -> f64 {
        2.0 * d / std::f64::consts::PI
    }

    /// The contact law's radius (duplicated from `softhaptic-device::law` only for these tests,
    /// since proto cannot depend on the device crate): √(Rδ) sphere, 2δ tanα/π cone.
    pub(crate) fn crate_contact_radius(tool: &ToolShape, d: f64) -> f64 {
        match *tool {
            ToolShape::Sphere { radius_m } => (radius_m * d).sqrt(),
            ToolShape::Cone { half_angle_rad, .. } => {
                2.0 * d * half_angle_rad.tan() / std::f64::consts::PI
            }
        }
    }
}
