//! Closed-form contact laws of a rigid tool tip on an elastic half-space (paper §3.1).
//!
//! Every function takes the depth δ in metres and is defined for any input: a negative or NaN
//! depth is treated as no contact (zero), so a bad sample can never produce a force.

use softhaptic_proto::{Material, ToolShape};

/// Depth clamped to a valid indentation: NaN and negatives become 0, +∞ stays +∞ (callers cap).
#[inline]
fn clean_depth(depth_m: f64) -> f64 {
    if depth_m > 0.0 { depth_m } else { 0.0 }
}

/// Hertz force of a sphere of radius `radius_m` (paper eq. 4):
/// F = 8G√R / (3(1−ν)) δ^{3/2} = (4/3) E* √R δ^{3/2}.
#[inline]
pub fn hertz_force_n(material: &Material, radius_m: f64, depth_m: f64) -> f64 {
    let d = clean_depth(depth_m);
    4.0 / 3.0 * material.plane_strain_modulus_pa() * radius_m.sqrt() * d * d.sqrt()
}

/// Hertz stiffness dF/dδ = 2 E* √(Rδ).
#[inline]
pub fn hertz_stiffness_n_per_m(material: &Material, radius_m: f64, depth_m: f64) -> f64 {
    2.0 * material.plane_strain_modulus_pa() * (radius_m * clean_depth(depth_m)).sqrt()
}

/// Sneddon force of a cone with half-angle α between axis and flank:
/// F = (2/π) E* tan(α) δ². Equal to the paper's eq. (5) when its angle is measured from the
/// surface, i.e. identical at 45°.
#[inline]
pub fn sneddon_cone_force_n(material: &Material, half_angle_rad: f64, depth_m: f64) -> f64 {
    let d = clean_depth(depth_m);
    2.0 / std::f64::consts::PI * material.plane_strain_modulus_pa() * half_angle_rad.tan() * d * d
}

/// Cone stiffness dF/dδ = (4/π) E* tan(α) δ.
#[inline]
pub fn sneddon_cone_stiffness_n_per_m(
    material: &Material,
    half_angle_rad: f64,
    depth_m: f64,
) -> f64 {
    4.0 / std::f64::consts::PI
        * material.plane_strain_modulus_pa()
        * half_angle_rad.tan()
        * clean_depth(depth_m)
}

/// Contact force for any tool shape (the paper's F = Φ(φ, δ, E, ν), eq. 1).
#[inline]
pub fn contact_force_n(tool: &ToolShape, material: &Material, depth_m: f64) -> f64 {
    match *tool {
        ToolShape::Sphere { radius_m } => hertz_force_n(material, radius_m, depth_m),
        ToolShape::Cone { half_angle_rad, .. } => {
            sneddon_cone_force_n(material, half_angle_rad, depth_m)
        }
    }
}

/// Contact stiffness dF/dδ for any tool shape.
#[inline]
pub fn contact_stiffness_n_per_m(tool: &ToolShape, material: &Material, depth_m: f64) -> f64 {
    match *tool {
        ToolShape::Sphere { radius_m } => hertz_stiffness_n_per_m(material, radius_m, depth_m),
        ToolShape::Cone { half_angle_rad, .. } => {
            sneddon_cone_stiffness_n_per_m(material, half_angle_rad, depth_m)
        }
    }
}

/// Radius a of the contact circle: √(Rδ) for a sphere, 2δ tan(α)/π for a cone.
#[inline]
pub fn contact_radius_m(tool: &ToolShape, depth_m: f64) -> f64 {
    let d = clean_depth(depth_m);
    match *tool {
        ToolShape::Sphere { radius_m } => (radius_m * d).sqrt(),
        ToolShape::Cone { half_angle_rad, .. } => {
            2.0 * d * half_angle_rad.tan() / std::f64::consts::PI
        }
    }
}

/// Depth δ* at which the law's stiffness reaches `max_stiffness_n_per_m` (docs/physics.md,
/// "Haptic stability"): K²/(4E*²R) for a sphere, πK/(4E* tanα) for a cone.
#[inline]
pub fn depth_at_stiffness_m(
    tool: &ToolShape,
    material: &Material,
    max_stiffness_n_per_m: f64,
) -> f64 {
    let e_star = material.plane_strain_modulus_pa();
    let k = max_stiffness_n_per_m.max(0.0);
    match *tool {
        ToolShape::Sphere { radius_m } => k * k / (4.0 * e_star * e_star * radius_m),
        ToolShape::Cone { half_angle_rad, .. } => {
            std::f64::consts::PI * k / (4.0 * e_star * half_angle_rad.tan())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::f64::consts::FRAC_PI_4;

    const MM: f64 = 1e-3;

    /// docs/physics.md, "Reference values": E = 50 kPa, ν = 0.33, sphere R = 6 mm, cone 45°.
    const REFERENCE: [(f64, f64, f64, f64, f64); 6] = [
        // δ mm, Hertz F, Hertz dF/dδ, cone F, cone dF/dδ
        (1.0, 0.1833, 275.0, 0.0357, 71.0),
        (2.0, 0.5183, 389.0, 0.1429, 143.0),
        (3.0, 0.9522, 476.0, 0.3215, 214.0),
        (4.0, 1.4660, 550.0, 0.5715, 286.0),
        (5.0, 2.0489, 615.0, 0.8930, 357.0),
        (6.0, 2.6933, 673.0, 1.2860, 429.0),
    ];

    #[test]
    fn laws_match_physics_reference_table() {
        let m = Material::PAPER_SOFT;
        let sphere = ToolShape::sphere(6.0 * MM).unwrap();
        let cone = ToolShape::cone(FRAC_PI_4, 6.0 * MM).unwrap();
        for (d_mm, hf, hk, cf, ck) in REFERENCE {
            let d = d_mm * MM;
            assert!(
                (contact_force_n(&sphere, &m, d) - hf).abs() < 5e-4,
                "Hertz F at {d_mm} mm"
            );
            assert!(
                (contact_stiffness_n_per_m(&sphere, &m, d) - hk).abs() < 1.0,
                "Hertz k at {d_mm} mm"
            );
            assert!(
                (contact_force_n(&cone, &m, d) - cf).abs() < 5e-4,
                "cone F at {d_mm} mm"
            );
            assert!(
                (contact_stiffness_n_per_m(&cone, &m, d) - ck).abs() < 1.0,
                "cone k at {d_mm} mm"
            );
        }
    }

    #[test]
    fn paper_hertz_form_equals_plane_strain_form() {
        // Eq. (4) as printed: 8 G √R / (3(1−ν)) δ^{3/2}.
        let m = Material::new(1.5e6, 0.4999).unwrap();
        let (r, d) = (0.01_f64, 0.003_f64);
        let g = m.shear_modulus_pa();
        let paper = 8.0 * g * r.sqrt() / (3.0 * (1.0 - m.poisson_ratio())) * d.powf(1.5);
        assert!((hertz_force_n(&m, r, d) / paper - 1.0).abs() < 1e-12);
    }

    #[test]
    fn thirty_degree_cone_uses_axis_to_flank_convention() {
        // Sneddon's parametrisation by the contact radius a, with α the half-angle between axis
        // and flank (cone profile z = r·cot α): δ = (π/2) a cot α, F = (π/2) E* a² cot α.
        // Eliminating a must give our closed form and our contact radius at a non-45° angle.
        let m = Material::PAPER_SOFT;
        let alpha = 30f64.to_radians();
        let cone = ToolShape::cone(alpha, 0.01).unwrap();
        let e_star = m.plane_strain_modulus_pa();
        let a = 1.5 * MM;
        let depth = std::f64::consts::FRAC_PI_2 * a / alpha.tan();
        let force = std::f64::consts::FRAC_PI_2 * e_star * a * a / alpha.tan();
        assert!((contact_force_n(&cone, &m, depth) / force - 1.0).abs() < 1e-12);
        assert!((contact_radius_m(&cone, depth) / a - 1.0).abs() < 1e-12);
        // The paper's other convention measures the angle β from the surface (β = 60° here);
        // mixing the two up would change the force by tan²(30°) = 1/3.
        let beta = 60f64.to_radians();
        let with_beta = 2.0 / std::f64::consts::PI * e_star / beta.tan() * depth * depth;
        assert!((contact_force_n(&cone, &m, depth) / with_beta - 1.0).abs() < 1e-12);
        let mixed_up = 2.0 / std::f64::consts::PI * e_star * beta.tan() * depth * depth;
        assert!((contact_force_n(&cone, &m, depth) / mixed_up - 1.0 / 3.0).abs() < 1e-9);
    }

    #[test]
    fn stiffness_cap_depth_reaches_the_cap() {
        let m = Material::PAPER_STIFF;
        for tool in [
            ToolShape::sphere(0.005).unwrap(),
            ToolShape::cone(0.4, 0.005).unwrap(),
        ] {
            let d_star = depth_at_stiffness_m(&tool, &m, 1000.0);
            assert!((contact_stiffness_n_per_m(&tool, &m, d_star) - 1000.0).abs() < 1e-6);
        }
    }

    #[test]
    fn extremes_give_zero_or_finite() {
        let sphere = ToolShape::sphere(0.01).unwrap();
        let m = Material::new(1.0, 0.0).unwrap();
        for d in [0.0, -1.0, f64::NAN, f64::NEG_INFINITY, 1e-12] {
            let f = contact_force_n(&sphere, &m, d);
            assert!(f.is_finite() && f >= 0.0);
        }
        assert_eq!(contact_force_n(&sphere, &m, f64::NAN), 0.0);
        let stiff = Material::new(1e9, 0.4999).unwrap();
        assert!(contact_force_n(&sphere, &stiff, 0.02).is_finite());
    }

    proptest! {
        #[test]
        fn force_is_finite_nonnegative_and_monotone(
            e in 1.0f64..1e9, nu in 0.0f64..0.4999, r in 1e-4f64..0.05,
            alpha in 0.05f64..1.5, d1 in 0.0f64..0.05, d2 in 0.0f64..0.05,
        ) {
            let m = Material::new(e, nu).unwrap();
            for tool in [ToolShape::sphere(r).unwrap(), ToolShape::cone(alpha, r).unwrap()] {
                let (lo, hi) = if d1 <= d2 { (d1, d2) } else { (d2, d1) };
                let (f_lo, f_hi) = (contact_force_n(&tool, &m, lo), contact_force_n(&tool, &m, hi));
                prop_assert!(f_lo.is_finite() && f_hi.is_finite());
                prop_assert!(f_lo >= 0.0 && f_hi >= f_lo);
                // Continuity: the mean-value bound with the stiffness at the deeper end.
                let k_hi = contact_stiffness_n_per_m(&tool, &m, hi);
                prop_assert!(f_hi - f_lo <= k_hi * (hi - lo) * (1.0 + 1e-9) + 1e-300);
            }
        }
    }
}
