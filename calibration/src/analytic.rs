//! Closed-form references the FEM is checked against and the runtime models are ranked with
//! (physics.md, "Corrections that go past the paper"). The paper's own laws (Hertz, Sneddon)
//! live in `softhaptic_device::law` and are used from there.

use softhaptic_proto::Material;
use std::f64::consts::PI;

/// Sneddon's exact sphere (not the paraboloid): δ = (a/2) ln((R+a)/(R−a)),
/// F = (E*/2) [(a² + R²) ln((R+a)/(R−a)) − 2aR]. Valid for a < R, i.e. any depth: δ → ∞ as
/// a → R. The contact radius is found by bisection on a ∈ (0, R).
pub fn exact_sphere_force_n(material: &Material, radius_m: f64, depth_m: f64) -> f64 {
    // NaN and non-positive depths both mean no contact.
    if depth_m.is_nan() || depth_m <= 0.0 {
        return 0.0;
    }
    let r = radius_m;
    let depth_of = |a: f64| 0.5 * a * ((r + a) / (r - a)).ln();
    let (mut lo, mut hi) = (0.0, r * (1.0 - 1e-15));
    // 64 halvings of [0, R] reach the last bit of a double.
    for _ in 0..64 {
        let mid = 0.5 * (lo + hi);
        if depth_of(mid) < depth_m {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let a = 0.5 * (lo + hi);
    0.5 * material.plane_strain_modulus_pa()
        * ((a * a + r * r) * ((r + a) / (r - a)).ln() - 2.0 * a * r)
}

/// Dimitriadis et al. (2002) finite-thickness factor for a sphere on a layer of thickness
/// `thickness_m` bonded to a rigid base (`bonded`) or sliding on it, χ = √(Rδ)/h.
pub fn thickness_factor_sphere(
    poisson_ratio: f64,
    radius_m: f64,
    depth_m: f64,
    thickness_m: f64,
    bonded: bool,
) -> f64 {
    let nu = poisson_ratio;
    let chi = (radius_m * depth_m.max(0.0)).sqrt() / thickness_m;
    let (a0, b0) = if bonded {
        (
            -(1.2876 - 1.4678 * nu + 1.3442 * nu * nu) / (1.0 - nu),
            (0.6387 - 1.0277 * nu + 1.5164 * nu * nu) / (1.0 - nu),
        )
    } else {
        (
            -0.347 * (3.0 - 2.0 * nu) / (1.0 - nu),
            0.056 * (5.0 - 2.0 * nu) / (1.0 - nu),
        )
    };
    let pi2 = PI * PI;
    1.0 - 2.0 * a0 / PI * chi + 4.0 * a0 * a0 / pi2 * chi.powi(2)
        - 8.0 / PI.powi(3) * (a0.powi(3) + 4.0 * pi2 * b0 / 15.0) * chi.powi(3)
        + 16.0 * a0 / PI.powi(4) * (a0.powi(3) + 3.0 * pi2 * b0 / 5.0) * chi.powi(4)
}

/// Garcia & Garcia (2018) bonded finite-thickness factor for a cone (derived for ν = 0.5),
/// x = δ tan α / h.
pub fn thickness_factor_cone(half_angle_rad: f64, depth_m: f64, thickness_m: f64) -> f64 {
    let x = depth_m.max(0.0) * half_angle_rad.tan() / thickness_m;
    1.0 + 0.721 * x + 0.650 * x * x + 0.491 * x.powi(3) + 0.225 * x.powi(4)
}

/// Hertz for a sphere of radius R on a convex sphere of radius R0: 1/R* = 1/R + 1/R0.
pub fn hertz_on_sphere_force_n(
    material: &Material,
    radius_m: f64,
    object_radius_m: f64,
    depth_m: f64,
) -> f64 {
    let r_eff = radius_m * object_radius_m / (radius_m + object_radius_m);
    softhaptic_device::law::hertz_force_n(material, r_eff, depth_m)
}

/// Cone on a convex sphere of radius R0 (a ≪ R0): δ = (π/2) a cot α + a²/R0,
/// F = E* [(π/2) a² cot α + (4/3) a³/R0].
pub fn cone_on_sphere_force_n(
    material: &Material,
    half_angle_rad: f64,
    object_radius_m: f64,
    depth_m: f64,
) -> f64 {
    // NaN and non-positive depths both mean no contact.
    if depth_m.is_nan() || depth_m <= 0.0 {
        return 0.0;
    }
    let cot = 1.0 / half_angle_rad.tan();
    let r0 = object_radius_m;
    // Positive root of a²/R0 + (π/2) cot α a − δ = 0.
    let b = 0.5 * PI * cot;
    let a = (-b + (b * b + 4.0 * depth_m / r0).sqrt()) * r0 / 2.0;
    material.plane_strain_modulus_pa() * (0.5 * PI * a * a * cot + 4.0 / 3.0 * a.powi(3) / r0)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    /// physics.md reference column "exact sphere, Sneddon" (R = 6 mm, E = 50 kPa, ν = 0.33).
    #[test]
    fn exact_sphere_matches_reference_table() {
        let m = Material::PAPER_SOFT;
        for (d_mm, f) in [(1.0, 0.1802), (2.0, 0.5010), (4.0, 1.3679), (6.0, 2.4233)] {
            let got = exact_sphere_force_n(&m, 0.006, d_mm * 1e-3);
            assert!((got - f).abs() < 5e-4, "{d_mm} mm: {got}");
        }
    }

    #[test]
    fn bonded_thickness_factor_matches_reference_range() {
        // physics.md: ν = 0.33, h = 30 mm, R = 6 mm → 1.079 … 1.215 for δ = 1 … 6 mm.
        let lo = thickness_factor_sphere(0.33, 0.006, 0.001, 0.03, true);
        let hi = thickness_factor_sphere(0.33, 0.006, 0.006, 0.03, true);
        assert!((lo - 1.079).abs() < 2e-3, "{lo}");
        assert!((hi - 1.215).abs() < 2e-3, "{hi}");
    }

    #[test]
    fn curvature_ratio_matches_reference() {
        let m = Material::PAPER_SOFT;
        for (r0, ratio) in [(0.03, 0.866), (0.05, 0.913), (0.1, 0.953)] {
            let flat = softhaptic_device::law::hertz_force_n(&m, 0.01, 0.002);
            let curved = hertz_on_sphere_force_n(&m, 0.01, r0, 0.002);
            assert!((curved / flat - ratio).abs() < 1e-3);
        }
        // The cone law tends to Sneddon's on a flat surface.
        let flat = softhaptic_device::law::sneddon_cone_force_n(&m, 0.7, 0.002);
        let huge = cone_on_sphere_force_n(&m, 0.7, 1e6, 0.002);
        assert!((huge / flat - 1.0).abs() < 1e-6);
    }
}
