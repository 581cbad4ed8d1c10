//! The contact radius of Sneddon's exact sphere, the `contact_radius_m` a contact streams when its
//! model uses the exact sphere (proto/WIRE.md, `contact`), and so the radius of the `paper`
//! profile's contact edge.
//!
//! Hertz's a = √(Rδ) is the paraboloid's radius: at δ = R it equals R, so the paper's Bézier
//! loses its flank (the drawn surface hugs the whole hemisphere), while a sphere's real contact
//! is then 0.83 R wide. The exact sphere's δ = (a/2) ln((R+a)/(R−a)) keeps a < R at any depth.
//!
//! The viewer (web/src/deformation.js, `exactSphereContactRadius`) computes the same number by
//! the same steps; the shared vectors (`proto/vectors/deformation.json`) hold the two together.

/// Newton steps from the starting guess: 4 reach the last bits over every δ/R below
/// [`SATURATED_DEPTH_OVER_RADIUS`]; 6 leave a margin and cost nothing next to a frame.
const NEWTON_STEPS: usize = 6;

/// From δ/R = 20 on, tanh of the root is 1 to the last bit: a = R exactly.
const SATURATED_DEPTH_OVER_RADIUS: f64 = 20.0;

/// The contact radius a of a rigid sphere of radius `radius_m` pressed `depth_m` into an elastic
/// half-space, Sneddon's exact solution (not Hertz's paraboloid): the root a ∈ [0, R) of
/// δ = (a/2) ln((R+a)/(R−a)). For a sphere on a curved object pass the effective radius
/// 1/(1/R + κ), as the force does.
///
/// Solved for t = atanh(a/R), where the law reads t tanh t = δ/R: smooth and increasing in t, so
/// a few Newton steps from t₀ = √s √(1 + s/3) (s = δ/R; t ≈ √s (1 + s/6) when s is small) reach
/// the root without the singularity of the logarithm at a = R. a ≈ √(Rδ) as δ → 0, a → R as
/// δ → ∞ (a = 0.834 R at δ = R). A non-finite or non-positive depth or radius gives 0; an
/// infinite depth on a valid radius gives R.
pub fn exact_sphere_contact_radius_m(radius_m: f64, depth_m: f64) -> f64 {
    if !(radius_m.is_finite() && radius_m > 0.0) || depth_m.is_nan() || depth_m <= 0.0 {
        return 0.0;
    }
    let s = depth_m / radius_m;
    if s >= SATURATED_DEPTH_OVER_RADIUS {
        return radius_m;
    }
    let mut t = s.sqrt() * (1.0 + s / 3.0).sqrt();
    for _ in 0..NEWTON_STEPS {
        let tanh_t = t.tanh();
        // The slope tanh t + t sech² t is > 0 for t > 0, and t stays > 0 from t₀ > 0.
        let slope = tanh_t + t * (1.0 - tanh_t * tanh_t);
        t -= (t * tanh_t - s) / slope;
    }
    radius_m * t.tanh()
}

#[cfg(test)]
mod tests {
    use super::*;

    const MM: f64 = 1e-3;

    /// δ from a, the law itself (ln((R+a)/(R−a)) as ln(1 + 2a/(R−a)), accurate for a ≪ R).
    fn depth_of(radius_m: f64, a_m: f64) -> f64 {
        0.5 * a_m * (2.0 * a_m / (radius_m - a_m)).ln_1p()
    }

    #[test]
    fn the_radius_solves_the_exact_sphere_law_from_tiny_to_deep_presses() {
        let r = 10.0 * MM;
        for k in -60..=26 {
            // δ/R from 1e-12 to 19.95, a quarter decade apart below 1, then linear.
            let s = if k <= 0 {
                10f64.powf(k as f64 / 5.0)
            } else {
                0.75 * k as f64
            };
            let d = s * r;
            let a = exact_sphere_contact_radius_m(r, d);
            assert!(
                a > 0.0 && a < r || (a == r && s > 18.0),
                "δ/R = {s}: a = {a}"
            );
            // Near a = R the law amplifies a's last bit; checked where it does not (δ ≤ 3.8 R).
            if a < 0.999 * r {
                let back = depth_of(r, a);
                assert!((back - d).abs() <= 1e-12 * d, "δ/R = {s}: {back} vs {d}");
            }
        }
    }

    #[test]
    fn it_is_hertz_when_shallow_and_narrower_than_hertz_when_deep() {
        let r = 10.0 * MM;
        let d = 1e-6 * r;
        let hertz = (r * d).sqrt();
        assert!((exact_sphere_contact_radius_m(r, d) / hertz - 1.0).abs() < 1e-6);
        // At δ = R: x atanh x = 1, x = 0.8336 (Hertz: 1).
        let a = exact_sphere_contact_radius_m(r, r);
        assert!((a / r - 0.833_556_559_6).abs() < 1e-9, "{a}");
        // Increasing with depth, and below Hertz's radius at every depth.
        let mut last = 0.0;
        for k in 1..=200 {
            let d = 0.1 * MM * k as f64;
            let a = exact_sphere_contact_radius_m(r, d);
            assert!(a > last && a < (r * d).sqrt(), "δ = {d}: {a}");
            last = a;
        }
    }

    #[test]
    fn degenerate_inputs_give_zero_or_the_radius() {
        let r = 10.0 * MM;
        for d in [0.0, -MM, f64::NAN, f64::NEG_INFINITY] {
            assert_eq!(exact_sphere_contact_radius_m(r, d), 0.0, "δ = {d}");
        }
        for bad_r in [0.0, -r, f64::NAN, f64::INFINITY] {
            assert_eq!(exact_sphere_contact_radius_m(bad_r, MM), 0.0, "R = {bad_r}");
        }
        assert_eq!(exact_sphere_contact_radius_m(r, f64::INFINITY), r);
        assert_eq!(exact_sphere_contact_radius_m(r, 1e300), r);
        assert_eq!(exact_sphere_contact_radius_m(r, 20.0 * r), r);
        // Subnormal depth: still finite, positive and below R.
        let a = exact_sphere_contact_radius_m(r, 5e-324);
        assert!(a > 0.0 && a < r);
    }
}
