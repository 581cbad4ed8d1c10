//! Closed-form references that are not runtime models: what the FEM and the runtime's own
//! corrections are checked against (docs/physics.md, "Corrections that go past the paper").
//!
//! The paper's laws (Hertz, Sneddon's cone) live in `softhaptic_device::law` and every runtime
//! correction in `softhaptic_device::model`; the calibration evaluates those, never a copy.

use softhaptic_proto::Material;

/// Sneddon's exact sphere (not the paraboloid): δ = (a/2) ln((R+a)/(R−a)),
/// F = (E*/2) [(a² + R²) ln((R+a)/(R−a)) − 2aR]. Valid for a < R, i.e. any depth: δ → ∞ as
/// a → R. The contact radius is found by bisection on a ∈ (0, R).
///
/// The runtime's exact-sphere correction is a series of this law in δ/R; this closed form is
/// the reference it is checked against, and the cost a haptic loop would pay without the series.
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

/// Lin, Shreiber, Dimitriadis & Horkay (2009, Biomech. Model. Mechanobiol. 8:345): a sphere on
/// an incompressible neo-Hookean half-space, F = (20/9) E* a² (λ⁻² − λ), λ = 1 − 0.2 a/R, with
/// Hertz's contact radius a = √(Rδ). It tends to Hertz as a/R → 0. The literature's
/// hyperelastic correction, shown beside the project's fit (docs/physics.md says why it is not
/// used: it was derived for ν = 0.5).
pub fn lin_neo_hookean_sphere_force_n(material: &Material, radius_m: f64, depth_m: f64) -> f64 {
    if depth_m.is_nan() || depth_m <= 0.0 {
        return 0.0;
    }
    let a = (radius_m * depth_m).sqrt();
    let lambda = 1.0 - 0.2 * a / radius_m;
    20.0 / 9.0 * material.plane_strain_modulus_pa() * a * a * (lambda.powi(-2) - lambda)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    /// docs/physics.md reference column "exact sphere, Sneddon" (R = 6 mm, E = 50 kPa, ν = 0.33).
    #[test]
    fn exact_sphere_matches_reference_table() {
        let m = Material::PAPER_SOFT;
        for (d_mm, f) in [(1.0, 0.1802), (2.0, 0.5010), (4.0, 1.3679), (6.0, 2.4233)] {
            let got = exact_sphere_force_n(&m, 0.006, d_mm * 1e-3);
            assert!((got - f).abs() < 5e-4, "{d_mm} mm: {got}");
        }
    }

    /// docs/physics.md: Lin et al.'s law exceeds Hertz by 7% already at δ ≈ 0.6 mm (R = 6 mm), and
    /// it tends to Hertz at small depth.
    #[test]
    fn lin_et_al_departs_from_hertz_by_seven_percent_near_0_6_mm() {
        let m = Material::PAPER_SOFT;
        let ratio = |d: f64| {
            lin_neo_hookean_sphere_force_n(&m, 0.006, d)
                / softhaptic_device::law::hertz_force_n(&m, 0.006, d)
        };
        assert!((ratio(1e-9) - 1.0).abs() < 1e-3);
        assert!(
            ratio(0.55e-3) < 1.07 && ratio(0.65e-3) > 1.07,
            "{}",
            ratio(0.6e-3)
        );
        assert_eq!(lin_neo_hookean_sphere_force_n(&m, 0.006, -1.0), 0.0);
    }
}
