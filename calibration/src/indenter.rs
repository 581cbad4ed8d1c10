//! Rigid indenters: where they are and how far a point is from their surface.

use serde::Serialize;
use softhaptic_proto::ToolShape;

/// The surface of a rigid indenter tip.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "shape", rename_all = "snake_case")]
pub enum IndenterShape {
    /// A sphere of radius R (the real tool).
    Sphere { radius_m: f64 },
    /// Hertz's paraboloid h(r) = r²/(2R): the shape for which the Hertz law is exact on a
    /// half-space, used to verify the solver without the sphere's own deviation from Hertz.
    Paraboloid { radius_m: f64 },
    /// An infinite cone with half-angle α between axis and flank (the tool's base radius is never
    /// reached in the experiments: the cone of the paper is 10 mm tall and indents ≤ 10 mm).
    Cone { half_angle_rad: f64 },
}

impl From<&ToolShape> for IndenterShape {
    fn from(tool: &ToolShape) -> Self {
        match *tool {
            ToolShape::Sphere { radius_m } => IndenterShape::Sphere { radius_m },
            ToolShape::Cone { half_angle_rad, .. } => IndenterShape::Cone { half_angle_rad },
        }
    }
}

/// An indenter placed in the FEM frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Indenter {
    pub shape: IndenterShape,
    /// The tip's proximal point (sphere bottom, cone apex), metres.
    pub tip_m: [f64; 3],
    /// Unit vector along the tool axis from the tip toward the hand.
    pub axis: [f64; 3],
}

/// Signed distance of a point from the indenter and the unit normal of the indenter surface
/// there (pointing out of the indenter). Negative distance = penetration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gap {
    pub distance_m: f64,
    pub normal: [f64; 3],
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn scaled(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

impl Indenter {
    /// A tool pressing straight down (−z) onto the surface z = 0 with its tip at depth `depth_m`.
    pub fn vertical(shape: IndenterShape, depth_m: f64) -> Self {
        Indenter {
            shape,
            tip_m: [0.0, 0.0, -depth_m],
            axis: [0.0, 0.0, 1.0],
        }
    }

    /// Gap of point `x` (current position) from the indenter surface.
    pub fn gap(&self, x: [f64; 3]) -> Gap {
        let e = self.axis;
        let d = sub(x, self.tip_m);
        let h = dot(d, e);
        let radial = sub(d, scaled(e, h));
        let rho = norm(radial);
        // Radial unit vector; on the axis any perpendicular direction serves (its weight in the
        // normal is then zero for the sphere and paraboloid; for the cone apex the symmetry
        // planes of the model fix the lateral components anyway).
        let rho_hat = if rho > 1e-15 {
            scaled(radial, 1.0 / rho)
        } else {
            any_perpendicular(e)
        };
        match self.shape {
            IndenterShape::Sphere { radius_m } => {
                let c = [
                    self.tip_m[0] + radius_m * e[0],
                    self.tip_m[1] + radius_m * e[1],
                    self.tip_m[2] + radius_m * e[2],
                ];
                let dc = sub(x, c);
                let len = norm(dc);
                if len > 1e-15 {
                    Gap {
                        distance_m: len - radius_m,
                        normal: scaled(dc, 1.0 / len),
                    }
                } else {
                    Gap {
                        distance_m: -radius_m,
                        normal: scaled(e, -1.0),
                    }
                }
            }
            IndenterShape::Paraboloid { radius_m } => {
                // Level set φ = r²/(2R) − h (negative inside), distance ≈ φ/|∇φ|.
                let phi = rho * rho / (2.0 * radius_m) - h;
                let grad = [
                    rho_hat[0] * rho / radius_m - e[0],
                    rho_hat[1] * rho / radius_m - e[1],
                    rho_hat[2] * rho / radius_m - e[2],
                ];
                let gl = norm(grad);
                Gap {
                    distance_m: phi / gl,
                    normal: scaled(grad, 1.0 / gl),
                }
            }
            IndenterShape::Cone { half_angle_rad } => {
                let (s, c) = half_angle_rad.sin_cos();
                // In the (ρ, h) half-plane the flank is the ray along (sin α, cos α); its
                // outward normal is (cos α, −sin α).
                let along = rho * s + h * c;
                if rho <= 1e-12 && h > 0.0 {
                    // On the axis inside the cone the flank normal is undefined (every radial
                    // direction serves): push straight back along the axis to the apex.
                    Gap {
                        distance_m: -h,
                        normal: scaled(e, -1.0),
                    }
                } else if along >= 0.0 {
                    Gap {
                        distance_m: rho * c - h * s,
                        normal: [
                            rho_hat[0] * c - e[0] * s,
                            rho_hat[1] * c - e[1] * s,
                            rho_hat[2] * c - e[2] * s,
                        ],
                    }
                } else {
                    let len = norm(d);
                    Gap {
                        distance_m: len,
                        normal: if len > 1e-15 {
                            scaled(d, 1.0 / len)
                        } else {
                            scaled(e, -1.0)
                        },
                    }
                }
            }
        }
    }
}

impl Indenter {
    /// Gap of a point of the reference configuration measured along the tool's axis, as the
    /// small-deformation contact problem measures it: the indenter occupies h ≥ f(ρ) (h the
    /// height above the tip along the axis, ρ the distance from the axis, f the tool's profile:
    /// R − √(R² − ρ²), ρ cot α, ρ²/(2R)), and the gap is f(ρ) − h, negative inside. Its normal is
    /// −axis: a displacement u changes the linearised gap by −u·axis, whatever its lateral part.
    ///
    /// Beyond the sphere's silhouette (ρ ≥ R) the axial line misses the tool; the Euclidean gap,
    /// positive there, stands in (such points are never in contact).
    pub fn axial_gap(&self, x: [f64; 3]) -> Gap {
        let e = self.axis;
        let d = sub(x, self.tip_m);
        let h = dot(d, e);
        let rho = norm(sub(d, scaled(e, h)));
        let profile_m = match self.shape {
            IndenterShape::Sphere { radius_m } => {
                if rho >= radius_m {
                    return Gap {
                        distance_m: self.gap(x).distance_m,
                        normal: scaled(e, -1.0),
                    };
                }
                radius_m - (radius_m * radius_m - rho * rho).sqrt()
            }
            IndenterShape::Paraboloid { radius_m } => rho * rho / (2.0 * radius_m),
            IndenterShape::Cone { half_angle_rad } => rho / half_angle_rad.tan(),
        };
        Gap {
            distance_m: profile_m - h,
            normal: scaled(e, -1.0),
        }
    }
}

impl Indenter {
    /// Gap of a point of the reference configuration measured along the body's surface normal,
    /// +z in the FEM frame (the direction the tool's lowest point approaches along), as the
    /// small-deformation contact problem measures it for a tilted tool: the height of the tool's
    /// lower surface above the point's vertical line, minus the point's height. Its normal is
    /// −z, so the reaction is normal to the undeformed surface, as in the textbook half-space
    /// problem of an inclined punch. For a tool pressing straight down this is [`Self::axial_gap`]
    /// (same arithmetic, bit for bit).
    ///
    /// Where the vertical line misses the tool (beyond a sphere's silhouette, or a cone tilted
    /// past its half-angle) the Euclidean gap, positive there, stands in.
    pub fn surface_normal_gap(&self, x: [f64; 3]) -> Gap {
        const DOWN: [f64; 3] = [0.0, 0.0, -1.0];
        if self.axis == [0.0, 0.0, 1.0] {
            return self.axial_gap(x);
        }
        let miss = || Gap {
            distance_m: self.gap(x).distance_m.max(0.0),
            normal: DOWN,
        };
        let lower_m = match self.shape {
            IndenterShape::Sphere { radius_m } | IndenterShape::Paraboloid { radius_m } => {
                // The paraboloid is a verification shape that is never tilted; its sphere of
                // curvature stands in.
                let c = [
                    self.tip_m[0] + radius_m * self.axis[0],
                    self.tip_m[1] + radius_m * self.axis[1],
                    self.tip_m[2] + radius_m * self.axis[2],
                ];
                let s2 = (x[0] - c[0]).powi(2) + (x[1] - c[1]).powi(2);
                if s2 >= radius_m * radius_m {
                    return miss();
                }
                c[2] - (radius_m * radius_m - s2).sqrt()
            }
            IndenterShape::Cone { half_angle_rad } => {
                // Points p = (x, y, z) of the cone's flank satisfy (d·e)² = cos²α |d|², d = p − tip,
                // on the nappe d·e ≥ 0: a quadratic in t = z − tip_z. The vertical line enters the
                // solid cone at its lower root on that nappe.
                let e = self.axis;
                let (dx, dy) = (x[0] - self.tip_m[0], x[1] - self.tip_m[1]);
                let p = dx * e[0] + dy * e[1];
                let q = e[2];
                let c2 = half_angle_rad.cos().powi(2);
                let a = q * q - c2;
                let b = 2.0 * p * q;
                let k = p * p - c2 * (dx * dx + dy * dy);
                let disc = b * b - 4.0 * a * k;
                if a <= 0.0 || disc < 0.0 {
                    return miss();
                }
                let root = disc.sqrt();
                let mut roots = [(-b - root) / (2.0 * a), (-b + root) / (2.0 * a)];
                roots.sort_by(f64::total_cmp);
                match roots.iter().find(|&&t| p + q * t >= 0.0) {
                    Some(&t) => self.tip_m[2] + t,
                    None => return miss(),
                }
            }
        };
        Gap {
            distance_m: lower_m - x[2],
            normal: DOWN,
        }
    }
}

impl Indenter {
    /// Derivative of the surface normal with respect to the point, dn/dx (3×3, symmetric): the
    /// indenter's curvature, which enters the Newton tangent of a node sliding on it (without
    /// it the normal is only updated between iterations and Newton converges linearly).
    pub fn normal_derivative(&self, x: [f64; 3]) -> [[f64; 3]; 3] {
        let e = self.axis;
        let d = sub(x, self.tip_m);
        let h = dot(d, e);
        let radial = sub(d, scaled(e, h));
        let rho = norm(radial);
        let outer = |a: [f64; 3], s: f64| -> [[f64; 3]; 3] {
            std::array::from_fn(|i| std::array::from_fn(|j| a[i] * a[j] * s))
        };
        let projector = |n: [f64; 3], s: f64| -> [[f64; 3]; 3] {
            std::array::from_fn(|i| {
                std::array::from_fn(|j| s * (if i == j { 1.0 } else { 0.0 } - n[i] * n[j]))
            })
        };
        match self.shape {
            IndenterShape::Sphere { radius_m } | IndenterShape::Paraboloid { radius_m } => {
                let g = self.gap(x);
                let dist = (g.distance_m + radius_m).max(1e-12);
                projector(g.normal, 1.0 / dist)
            }
            IndenterShape::Cone { half_angle_rad } => {
                let (s, c) = half_angle_rad.sin_cos();
                if rho <= 1e-12 || rho * s + h * c < 0.0 {
                    return [[0.0; 3]; 3];
                }
                // n = ρ̂ cos α − e sin α, dρ̂/dx = (I − e eᵀ − ρ̂ ρ̂ᵀ)/ρ: only the hoop direction.
                let rho_hat = scaled(radial, 1.0 / rho);
                let hoop_e = outer(e, 1.0);
                let hoop_r = outer(rho_hat, 1.0);
                std::array::from_fn(|i| {
                    std::array::from_fn(|j| {
                        let id = if i == j { 1.0 } else { 0.0 };
                        c * (id - hoop_e[i][j] - hoop_r[i][j]) / rho
                    })
                })
            }
        }
    }
}

fn any_perpendicular(e: [f64; 3]) -> [f64; 3] {
    let t = if e[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let p = sub(t, scaled(e, dot(t, e)));
    scaled(p, 1.0 / norm(p))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn sphere_gap_is_distance_to_surface() {
        let ind = Indenter::vertical(IndenterShape::Sphere { radius_m: 0.01 }, 0.002);
        // A point on the surface plane right under the tip is 2 mm inside.
        let g = ind.gap([0.0, 0.0, 0.0]);
        assert!((g.distance_m + 0.002).abs() < 1e-15);
        assert!((g.normal[2] + 1.0).abs() < 1e-15);
        let g = ind.gap([0.02, 0.0, 0.0]);
        let expect = ((0.02f64).powi(2) + 0.008f64.powi(2)).sqrt() - 0.01;
        assert!((g.distance_m - expect).abs() < 1e-15);
    }

    #[test]
    fn cone_gap_on_flank_and_apex() {
        let alpha = std::f64::consts::FRAC_PI_4;
        let ind = Indenter::vertical(
            IndenterShape::Cone {
                half_angle_rad: alpha,
            },
            0.003,
        );
        // Surface point at r = 3 mm lies on the 45° flank exactly.
        let g = ind.gap([0.003, 0.0, 0.0]);
        assert!(g.distance_m.abs() < 1e-15);
        // Below the apex the distance is to the apex.
        let g = ind.gap([0.0, 0.0, -0.004]);
        assert!((g.distance_m - 0.001).abs() < 1e-15);
        // On the axis above the apex: back to the apex along the axis, no lateral push.
        let g = ind.gap([0.0, 0.0, 0.0]);
        assert!((g.distance_m + 0.003).abs() < 1e-15);
        assert_eq!(g.normal, [0.0, 0.0, -1.0]);
        // Just off the axis: the flank distance h sin α.
        let g = ind.gap([1e-9, 0.0, 0.0]);
        assert!((g.distance_m + 0.003 * alpha.sin()).abs() < 1e-9);
    }

    #[test]
    fn axial_gap_is_vertical_distance_to_profile() {
        let alpha = std::f64::consts::FRAC_PI_4;
        let cone = Indenter::vertical(
            IndenterShape::Cone {
                half_angle_rad: alpha,
            },
            0.003,
        );
        // 3 mm deep on the axis; at r = 1 mm the 45° flank is 1 mm above the apex, so 2 mm.
        let g = cone.axial_gap([0.0, 0.0, 0.0]);
        assert!((g.distance_m + 0.003).abs() < 1e-15);
        assert_eq!(g.normal, [0.0, 0.0, -1.0]);
        let g = cone.axial_gap([0.001, 0.0, 0.0]);
        assert!((g.distance_m + 0.002).abs() < 1e-15);
        let sphere = Indenter::vertical(IndenterShape::Sphere { radius_m: 0.01 }, 0.002);
        let r: f64 = 0.006;
        let g = sphere.axial_gap([r, 0.0, 0.0]);
        let expect = 0.01 - (0.01f64.powi(2) - r * r).sqrt() - 0.002;
        assert!((g.distance_m - expect).abs() < 1e-15);
        // Outside the silhouette: no contact.
        assert!(sphere.axial_gap([0.011, 0.0, 0.0]).distance_m > 0.0);
    }

    #[test]
    fn surface_normal_gap_is_the_axial_gap_when_upright_and_vertical_when_tilted() {
        let alpha = std::f64::consts::FRAC_PI_4;
        let cone = Indenter::vertical(
            IndenterShape::Cone {
                half_angle_rad: alpha,
            },
            0.003,
        );
        for x in [[0.0, 0.0, 0.0], [0.001, 0.0005, -0.0002]] {
            assert_eq!(cone.surface_normal_gap(x), cone.axial_gap(x));
        }
        // A cone tilted by θ toward +x, apex at the origin: in the x–z plane its flanks are the
        // generators at α + θ from the vertical on the +x side and α − θ on the −x side.
        let theta: f64 = 0.3;
        let tilted = Indenter {
            shape: IndenterShape::Cone {
                half_angle_rad: alpha,
            },
            tip_m: [0.0, 0.0, 0.0],
            axis: [theta.sin(), 0.0, theta.cos()],
        };
        let r = 0.002;
        let g = tilted.surface_normal_gap([r, 0.0, 0.0]);
        assert_eq!(g.normal, [0.0, 0.0, -1.0]);
        let expect = r / (alpha + theta).tan();
        assert!(
            (g.distance_m - expect).abs() < 1e-12,
            "{} {expect}",
            g.distance_m
        );
        let g = tilted.surface_normal_gap([-r, 0.0, 0.0]);
        let expect = r / (alpha - theta).tan();
        assert!(
            (g.distance_m - expect).abs() < 1e-12,
            "{} {expect}",
            g.distance_m
        );
        // A tilted sphere is the same sphere: its lower surface, measured vertically.
        let sphere = Indenter {
            shape: IndenterShape::Sphere { radius_m: 0.01 },
            tip_m: [-0.01 * theta.sin(), 0.0, 0.01 - 0.01 * theta.cos()],
            axis: [theta.sin(), 0.0, theta.cos()],
        };
        let g = sphere.surface_normal_gap([0.006, 0.0, 0.0]);
        let expect = 0.01 - (0.01f64.powi(2) - 0.006f64.powi(2)).sqrt();
        assert!((g.distance_m - expect).abs() < 1e-12);
        assert!(sphere.surface_normal_gap([0.011, 0.0, 0.0]).distance_m > 0.0);
    }

    #[test]
    fn paraboloid_matches_sphere_near_axis() {
        let s = Indenter::vertical(IndenterShape::Sphere { radius_m: 0.01 }, 0.001);
        let p = Indenter::vertical(IndenterShape::Paraboloid { radius_m: 0.01 }, 0.001);
        let x = [0.0005, 0.0, 0.0];
        assert!((s.gap(x).distance_m - p.gap(x).distance_m).abs() < 1e-6);
    }
}
