//! `paper`: the seed paper's deformation profile (§3.3), a quadratic Bézier flank around the
//! tool's imprint, as proto/WIRE.md ("Deformation profile", `paper`) defines it.

use serde::{Deserialize, Serialize};

use crate::tool::ToolShape;

use super::{sanitise, tool_height_m};

/// The cross-section of one contact, precomputed once per frame and then evaluated per vertex.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DeformationProfile {
    tool: ToolShape,
    /// Sanitised indentation δ.
    depth_m: f64,
    /// Effective contact radius: a clamped to the tool's lateral extent.
    contact_radius_eff_m: f64,
    /// Depression at the contact edge (P0's height).
    edge_depression_m: f64,
    /// P1's radius, in [a_eff, R_d_eff].
    control_radius_m: f64,
    /// Effective deformed radius: at least a_eff + z0, so the Bézier region is never inverted.
    deformed_radius_eff_m: f64,
}

impl DeformationProfile {
    /// Builds the profile from the tool, depth δ, contact radius a (from the contact law) and
    /// deformed radius R_d (from the calibration table), following proto/WIRE.md steps 1–4.
    ///
    /// A tool that fails [`ToolShape::validate`] deforms nothing (depth treated as 0), so no
    /// input can produce NaN.
    pub fn new(
        tool: &ToolShape,
        depth_m: f64,
        contact_radius_m: f64,
        deformed_radius_m: f64,
    ) -> Self {
        let valid_tool = tool.validate().is_ok();
        let depth_m = if valid_tool { sanitise(depth_m) } else { 0.0 };
        let a = sanitise(contact_radius_m);
        let rd = sanitise(deformed_radius_m);
        if depth_m == 0.0 {
            return Self {
                tool: *tool,
                depth_m: 0.0,
                contact_radius_eff_m: 0.0,
                edge_depression_m: 0.0,
                control_radius_m: 0.0,
                deformed_radius_eff_m: 0.0,
            };
        }
        let a_eff = a.min(tool.radius_m());
        let z0 = (depth_m - tool_height_m(tool, a_eff)).max(0.0);
        let rd_eff = rd.max(a_eff + z0);
        // Tool slope at the contact edge.
        let slope = match *tool {
            ToolShape::Sphere { radius_m } => {
                let under = radius_m * radius_m - a_eff * a_eff;
                if under > 0.0 {
                    a_eff / under.sqrt()
                } else {
                    f64::INFINITY
                }
            }
            ToolShape::Cone { half_angle_rad, .. } => 1.0 / half_angle_rad.tan(),
        };
        let r1 = if slope == f64::INFINITY || z0 == 0.0 {
            a_eff
        } else if slope == 0.0 {
            rd_eff
        } else {
            a_eff + z0 / slope
        };
        let r1 = r1.clamp(a_eff, rd_eff);
        Self {
            tool: *tool,
            depth_m,
            contact_radius_eff_m: a_eff,
            edge_depression_m: z0,
            control_radius_m: if r1.is_finite() { r1 } else { a_eff },
            deformed_radius_eff_m: rd_eff,
        }
    }

    /// The depression z(r) ≥ 0 at radial distance `r_m` from the contact axis (proto/WIRE.md,
    /// "Deformation profile", step 5).
    pub fn depression_m(&self, r_m: f64) -> f64 {
        let r = sanitise(r_m);
        let a = self.contact_radius_eff_m;
        let rd = self.deformed_radius_eff_m;
        if self.depth_m == 0.0 || r >= rd {
            return 0.0;
        }
        if r < a {
            return (self.depth_m - tool_height_m(&self.tool, r)).max(0.0);
        }
        // Invert the Bézier's radial coordinate r(t) = (1−t)² a + 2t(1−t) r1 + t² R_d for t.
        let r1 = self.control_radius_m;
        let qa = a - 2.0 * r1 + rd;
        let qb = 2.0 * (r1 - a);
        let qc = a - r;
        let root = (qb * qb - 4.0 * qa * qc).max(0.0).sqrt();
        let t = if qb + root > 0.0 {
            -2.0 * qc / (qb + root)
        } else {
            (r - a) / (rd - a)
        };
        let t = t.clamp(0.0, 1.0);
        (1.0 - t) * (1.0 - t) * self.edge_depression_m
    }

    /// The sanitised indentation δ.
    pub fn depth_m(&self) -> f64 {
        self.depth_m
    }

    /// a_eff: the contact radius clamped to the tool's lateral extent.
    pub fn contact_radius_eff_m(&self) -> f64 {
        self.contact_radius_eff_m
    }

    /// z0: the depression at the contact edge.
    pub fn edge_depression_m(&self) -> f64 {
        self.edge_depression_m
    }

    /// r1: the radius of the middle control point P1.
    pub fn control_radius_m(&self) -> f64 {
        self.control_radius_m
    }

    /// R_d_eff: no vertex at or beyond this radius moves.
    pub fn deformed_radius_eff_m(&self) -> f64 {
        self.deformed_radius_eff_m
    }
}

/// One-shot form of [`DeformationProfile::depression_m`].
pub fn depression_m(
    tool: &ToolShape,
    depth_m: f64,
    contact_radius_m: f64,
    deformed_radius_m: f64,
    r_m: f64,
) -> f64 {
    DeformationProfile::new(tool, depth_m, contact_radius_m, deformed_radius_m).depression_m(r_m)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use crate::deformation::test_tools::*;
    use proptest::prelude::*;

    #[test]
    fn centre_is_pressed_by_the_full_depth() {
        for d in [1e-9, 0.5 * MM, 3.0 * MM, 9.0 * MM] {
            let z = depression_m(&sphere(), d, sphere_a(d), 30.0 * MM, 0.0);
            assert!((z - d).abs() < 1e-15, "sphere δ = {d}");
            let z = depression_m(&cone(), d, cone_a(d), 30.0 * MM, 0.0);
            assert!((z - d).abs() < 1e-15, "cone δ = {d}");
        }
    }

    #[test]
    fn inside_the_contact_follows_the_tool_surface() {
        let d = 4.0 * MM;
        let a = sphere_a(d);
        for k in 0..20 {
            let r = a * k as f64 / 20.0;
            let expected = d - (10.0 * MM - ((10.0 * MM).powi(2) - r * r).sqrt());
            let z = depression_m(&sphere(), d, a, 30.0 * MM, r);
            assert!((z - expected).abs() < 1e-15);
        }
        let a = cone_a(d);
        for k in 0..20 {
            let r = a * k as f64 / 20.0;
            let z = depression_m(&cone(), d, a, 30.0 * MM, r);
            assert!((z - (d - r)).abs() < 1e-15);
        }
    }

    #[test]
    fn zero_at_and_beyond_the_deformed_radius() {
        let d = 4.0 * MM;
        let p = DeformationProfile::new(&sphere(), d, sphere_a(d), 30.0 * MM);
        assert_eq!(p.deformed_radius_eff_m(), 30.0 * MM);
        for r in [30.0 * MM, 30.0001 * MM, 1.0] {
            assert_eq!(p.depression_m(r), 0.0);
        }
        assert!(p.depression_m(29.9 * MM) > 0.0);
    }

    #[test]
    fn bezier_region_matches_the_control_points() {
        // Sphere δ = 4 mm, R = 10 mm: a = √40 mm, z0 = δ − (R − √(R² − a²)).
        let d = 4.0 * MM;
        let a = sphere_a(d);
        let p = DeformationProfile::new(&sphere(), d, a, 30.0 * MM);
        let r_tool = 10.0 * MM;
        let z0 = d - (r_tool - (r_tool * r_tool - a * a).sqrt());
        assert!((p.edge_depression_m() - z0).abs() < 1e-15);
        let slope = a / (r_tool * r_tool - a * a).sqrt();
        assert!((p.control_radius_m() - (a + z0 / slope)).abs() < 1e-15);
        // Points on the curve: r(t), z(t) for sample t.
        let (r1, rd) = (p.control_radius_m(), 30.0 * MM);
        for k in 0..=10 {
            let t = k as f64 / 10.0;
            let r = (1.0 - t).powi(2) * a + 2.0 * t * (1.0 - t) * r1 + t * t * rd;
            let z = (1.0 - t).powi(2) * z0;
            assert!((p.depression_m(r) - z).abs() < 1e-12, "t = {t}");
        }
        // The curve leaves P0 along the tool's tangent: the one-sided slope at a matches.
        let h = 1e-9;
        let slope_out = (p.depression_m(a) - p.depression_m(a + h)) / h;
        assert!((slope_out / slope - 1.0).abs() < 1e-3);
    }

    #[test]
    fn deformed_radius_inside_the_contact_is_lifted() {
        // R_d ≤ a: R_d_eff = a_eff + z0, still continuous and zero beyond.
        let d = 4.0 * MM;
        let a = sphere_a(d);
        let p = DeformationProfile::new(&sphere(), d, a, 0.1 * a);
        assert!((p.deformed_radius_eff_m() - (a + p.edge_depression_m())).abs() < 1e-15);
        // The steepest slope here is 1 (z0 over r1 − a_eff, P1 clamped to R_d_eff).
        let step = p.deformed_radius_eff_m() * 1.1 / 1000.0;
        let mut prev = p.depression_m(0.0);
        for k in 1..=1000 {
            let r = step * k as f64;
            let z = p.depression_m(r);
            assert!(z <= prev + 1e-15, "monotone at r = {r}");
            assert!(prev - z <= 1.01 * step, "jump at r = {r}");
            prev = z;
        }
        assert_eq!(p.depression_m(p.deformed_radius_eff_m()), 0.0);
    }

    #[test]
    fn contact_wider_than_the_tool_is_clamped() {
        // Sphere: a ≥ R → a_eff = R, vertical tangent, r1 = a_eff.
        let d = 15.0 * MM;
        let p = DeformationProfile::new(&sphere(), d, sphere_a(d), 60.0 * MM);
        assert_eq!(p.contact_radius_eff_m(), 10.0 * MM);
        assert!((p.edge_depression_m() - 5.0 * MM).abs() < 1e-15);
        assert_eq!(p.control_radius_m(), 10.0 * MM);
        // Cone: a beyond the base radius is clamped to it.
        let d = 30.0 * MM;
        let p = DeformationProfile::new(&cone(), d, cone_a(d), 60.0 * MM);
        assert_eq!(p.contact_radius_eff_m(), 10.0 * MM);
        assert!((p.edge_depression_m() - 20.0 * MM).abs() < 1e-15);
    }

    #[test]
    fn degenerate_inputs_give_no_deformation() {
        for (d, a, rd, r) in [
            (0.0, 0.001, 0.02, 0.0),
            (-1.0, 0.001, 0.02, 0.0),
            (f64::NAN, 0.001, 0.02, 0.0),
            (f64::INFINITY, 0.001, 0.02, 0.0),
        ] {
            assert_eq!(depression_m(&sphere(), d, a, rd, r), 0.0);
        }
        // NaN radius behaves as r = 0.
        let d = 2.0 * MM;
        assert_eq!(
            depression_m(&sphere(), d, sphere_a(d), 0.02, f64::NAN),
            depression_m(&sphere(), d, sphere_a(d), 0.02, 0.0)
        );
        // Zero contact radius: tiny contact, horizontal slope, r1 = R_d.
        let p = DeformationProfile::new(&sphere(), d, 0.0, 0.02);
        assert_eq!(p.control_radius_m(), 0.02);
        assert_eq!(p.depression_m(0.0), d);
        // An invalid tool deforms nothing.
        let bad = ToolShape::Sphere { radius_m: -1.0 };
        assert_eq!(depression_m(&bad, d, 0.001, 0.02, 0.0), 0.0);
    }

    /// Largest jump of z over a fine sweep of r, to check continuity in r.
    fn max_jump(p: &DeformationProfile, r_max: f64, n: usize) -> f64 {
        let mut prev = p.depression_m(0.0);
        let mut worst: f64 = 0.0;
        for k in 1..=n {
            let z = p.depression_m(r_max * k as f64 / n as f64);
            worst = worst.max((z - prev).abs());
            prev = z;
        }
        worst
    }

    proptest! {
        #[test]
        fn never_nan_and_bounded_for_any_input(
            d in prop_oneof![Just(f64::NAN), Just(f64::INFINITY), Just(-1.0), Just(0.0), -0.1f64..0.1],
            a in prop_oneof![Just(f64::NAN), Just(f64::INFINITY), Just(0.0), -0.1f64..0.1],
            rd in prop_oneof![Just(f64::NAN), Just(f64::INFINITY), Just(0.0), -0.1f64..0.5],
            r in prop_oneof![Just(f64::NAN), Just(f64::INFINITY), Just(0.0), -0.1f64..0.5],
            radius in prop_oneof![Just(f64::NAN), Just(0.0), 1e-4f64..0.05],
            alpha in prop_oneof![Just(f64::NAN), Just(0.0), Just(std::f64::consts::FRAC_PI_2), 0.01f64..1.56],
        ) {
            for tool in [ToolShape::Sphere { radius_m: radius }, ToolShape::Cone { half_angle_rad: alpha, radius_m: radius }] {
                let z = depression_m(&tool, d, a, rd, r);
                prop_assert!(z.is_finite());
                prop_assert!(z >= 0.0);
                let bound = if d.is_finite() && d > 0.0 { d } else { 0.0 };
                prop_assert!(z <= bound);
            }
        }

        #[test]
        fn continuous_in_r(
            d_mm in 0.01f64..15.0, rd_mm in 0.0f64..100.0, r_tool_mm in 1.0f64..20.0,
            alpha in 0.1f64..1.4, cone in any::<bool>(),
        ) {
            let d = d_mm * MM;
            let tool = if cone {
                ToolShape::cone(alpha, r_tool_mm * MM).unwrap()
            } else {
                ToolShape::sphere(r_tool_mm * MM).unwrap()
            };
            let a = crate_contact_radius(&tool, d);
            let p = DeformationProfile::new(&tool, d, a, rd_mm * MM);
            // With 20 000 samples, no step exceeds what the steepest slope allows: the slope is
            // bounded by the tool's slope at the contact edge and by the Bézier's end tangents.
            let r_max = p.deformed_radius_eff_m() * 1.2;
            let n = 20_000;
            let dr = r_max / n as f64;
            let slope_bound = p.edge_depression_m() / (p.control_radius_m() - p.contact_radius_eff_m()).max(1e-300);
            let tool_slope = match tool {
                ToolShape::Sphere { radius_m } => {
                    let a = p.contact_radius_eff_m();
                    let u = radius_m * radius_m - a * a;
                    if u > 0.0 { a / u.sqrt() } else { f64::INFINITY }
                }
                ToolShape::Cone { half_angle_rad, .. } => 1.0 / half_angle_rad.tan(),
            };
            let jump = max_jump(&p, r_max, n);
            // A vertical wall (infinite slope) is allowed only where the contact saturates the
            // tool; there z0 drops to 0 over the tool's own rim, still continuous in the limit.
            if tool_slope.is_finite() && slope_bound.is_finite() {
                let allowed = (2.0 * slope_bound.max(tool_slope)) * dr * 1.01 + 1e-12;
                prop_assert!(jump <= allowed, "jump {} > {}", jump, allowed);
            }
        }

        #[test]
        fn continuous_in_depth(
            d_mm in 0.0f64..15.0, r_mm in 0.0f64..60.0, cone in any::<bool>(),
        ) {
            let tool = if cone { self::cone() } else { sphere() };
            // R_d continuous in δ, as a calibration table's fit is.
            let rd = |d: f64| 0.003 + 5.0 * d;
            let z = |d: f64| depression_m(&tool, d, crate_contact_radius(&tool, d), rd(d), r_mm * MM);
            let d = d_mm * MM;
            let h = 1e-10;
            prop_assert!((z(d + h) - z(d)).abs() < 1e-5, "{} vs {}", z(d), z(d + h));
        }

        #[test]
        fn monotone_in_r(d_mm in 0.01f64..12.0, rd_mm in 0.0f64..90.0, cone in any::<bool>()) {
            let tool = if cone { self::cone() } else { sphere() };
            let d = d_mm * MM;
            let p = DeformationProfile::new(&tool, d, crate_contact_radius(&tool, d), rd_mm * MM);
            let mut prev = p.depression_m(0.0);
            for k in 1..=500 {
                let z = p.depression_m(p.deformed_radius_eff_m() * k as f64 / 450.0);
                prop_assert!(z <= prev + 1e-15);
                prev = z;
            }
        }
    }
}
