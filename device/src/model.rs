//! The runtime contact model: the paper's law of the tool times the corrections a scene turns on
//! (docs/physics.md, "Corrections that go past the paper").
//!
//! Long because its last 450 lines are the tests that pin each correction to its closed form; the
//! model itself is about 680 lines: five corrections, each with how it is kept safe at the extremes.
//!
//! Each correction is a pure factor or a change of the effective geometry, cheap enough for the
//! 1 kHz loop (a few tens of nanoseconds each, no iteration, no allocation). A [`ForceModel`] is
//! built once per scene object from a [`ModelSpec`]; the corrections that are off cost nothing
//! but a branch. With every correction off it is the paper's law bit for bit (the force goes
//! through [`crate::law`] unchanged).
//!
//! Every correction is made safe at the extremes rather than trusted there: each published
//! series is used inside the range it was derived for and continued beyond it by its tangent
//! (continuous, monotone), and inputs from the mesh (curvature, inclination) are clamped, so the
//! force stays finite, non-negative, continuous and non-decreasing in depth for any input.

use softhaptic_proto::{LayerSpec, Material, ModelError, ModelSpec, ToolShape};
use std::f64::consts::{FRAC_PI_2, PI};

use crate::law;

/// What the model needs to know about the object where the tool touches it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalGeometry {
    /// Curvature 1/R0 of the object's surface at the contact, 1/m: positive where it is convex
    /// (a ball), negative where concave, zero on a plane.
    pub curvature_1_per_m: f64,
    /// Angle between the tool's axis and the contact normal, radians (0 = perpendicular).
    pub inclination_rad: f64,
}

impl LocalGeometry {
    /// A flat object pressed perpendicularly: the paper's configuration.
    pub const FLAT: LocalGeometry = LocalGeometry {
        curvature_1_per_m: 0.0,
        inclination_rad: 0.0,
    };
}

/// Large-strain (neo-Hookean) correction, fitted to the project's neo-Hookean FEM.
///
/// The factor multiplies the runtime's closed-form linear-elastic force after the other
/// corrections, so it is fitted against that closed form of the same geometry, not against the
/// linear FEM: F_nH ≈ F_closed · (1 + c1 x + c2 x²) with x = δ/R for a sphere (F_closed =
/// Sneddon's exact sphere on the bonded layer, with the layer's FEM residual of [`layer_fit`]),
/// and F_nH ≈ F_closed · c for a cone (Sneddon's cone on the bonded layer; a cone's indentation
/// has no length scale), least squares on the force. With the layer's residual the closed form is
/// within about 1% of the small-deformation FEM, so the factor is the large-strain stiffening
/// alone, not the layer law's error as well.
/// Data: the §4.3 experiment, sphere R = 6 mm and 45° cone on a 100 × 100 × 30 mm block,
/// E = 50 kPa, ν = 0.33, finest mesh (1.5 mm cells, 22 491 / 13 005 unknowns), δ = 0.5 … 6 mm.
/// The fit gives c1 = 0.1082, c2 = −0.0736 (x ≤ 1) and c = 1.0452: without it the closed form is
/// up to 3.4% (sphere) and 4.6% (cone) off the neo-Hookean FEM (eq. 9), with it 0.15% and 0.46%
/// (1.2% and 0.9% out of sample, on the 10 mm tools and the 50 mm block). Against the linear FEM the same data would
/// give F_nH/F_lin up to 1.31 at δ = R (c1 = −0.171, c2 = 0.472; cone 1.20), but that ratio is
/// mostly the linear FEM's own softening below the closed form at large strain (−23% at δ = R),
/// so it must not multiply the closed form. Lin et al.'s incompressible formula (docs/physics.md)
/// would give 1.27 at δ = R. Refit and compare with
/// `cargo run --release -p softhaptic-calibration --bin softhaptic-calibrate -- speed-accuracy`
/// (calibration report, "Hyperelastic fit"), which prints the refit beside these constants.
pub mod hyperelastic_fit {
    /// c1 of the sphere's factor 1 + c1 x + c2 x², x = δ/R.
    pub const SPHERE_C1: f64 = 0.1082;
    /// c2 of the sphere's factor.
    pub const SPHERE_C2: f64 = -0.0736;
    /// Deepest δ/R of the fit; beyond it the factor continues along its tangent (held if the
    /// tangent falls).
    pub const SPHERE_X_MAX: f64 = 1.0;
    /// The cone's constant factor.
    pub const CONE_RATIO: f64 = 1.0452;

    /// Poisson's ratios the factor was fitted at (`softhaptic-calibrate poisson`, the same fit
    /// against the closed form of each ν: the layer's factor depends on ν), increasing; the
    /// ν = 0.33 entry is the constants above. Full-mode fits (calibration report, "Nearly
    /// incompressible tissue").
    pub const POISSON_RATIOS: [f64; 5] = [0.30, 0.33, 0.40, 0.45, 0.49];
    /// c1 at each of [`POISSON_RATIOS`].
    pub const SPHERE_C1_BY_POISSON: [f64; 5] = [0.1457, SPHERE_C1, 0.0179, -0.0536, -0.1067];
    /// c2 at each of [`POISSON_RATIOS`].
    pub const SPHERE_C2_BY_POISSON: [f64; 5] = [-0.0887, SPHERE_C2, -0.0393, -0.0102, 0.0099];
    /// The cone's factor at each of [`POISSON_RATIOS`].
    pub const CONE_RATIO_BY_POISSON: [f64; 5] = [1.0656, CONE_RATIO, 0.9950, 0.9575, 0.9250];

    /// The factor's constants at one Poisson's ratio.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub struct Constants {
        pub sphere_c1: f64,
        pub sphere_c2: f64,
        pub cone_ratio: f64,
    }

    /// The ν = 0.33 constants.
    pub const PAPER: Constants = Constants {
        sphere_c1: SPHERE_C1,
        sphere_c2: SPHERE_C2,
        cone_ratio: CONE_RATIO,
    };

    /// The constants at `poisson_ratio`: the fitted ones at a fitted ν (exactly), linearly
    /// interpolated between the two fitted ν around it, and the nearest fit's outside the
    /// fitted range (a NaN ratio, which a material cannot have, gives the ν = 0.33 fit).
    pub fn at(poisson_ratio: f64) -> Constants {
        let entry = |i: usize| Constants {
            sphere_c1: SPHERE_C1_BY_POISSON[i],
            sphere_c2: SPHERE_C2_BY_POISSON[i],
            cone_ratio: CONE_RATIO_BY_POISSON[i],
        };
        let (i, j, t) = super::poisson_bracket(&POISSON_RATIOS, poisson_ratio);
        let (a, b) = (entry(i), entry(j));
        let lerp = |x: f64, y: f64| x + t * (y - x);
        Constants {
            sphere_c1: lerp(a.sphere_c1, b.sphere_c1),
            sphere_c2: lerp(a.sphere_c2, b.sphere_c2),
            cone_ratio: lerp(a.cone_ratio, b.cone_ratio),
        }
    }
}

/// Where `poisson_ratio` falls in the increasing `ratios` of a table of fits: entries `i` and
/// `j` and the weight `t` of `j`, for `a + t (b − a)`. At a fitted ν, and outside the fitted
/// range (the nearest entry), `t` is exactly zero, so the entry comes back bit for bit; a NaN
/// ratio, which a material cannot have, gives the paper's ν = 0.33 entry.
fn poisson_bracket(ratios: &[f64], poisson_ratio: f64) -> (usize, usize, f64) {
    let last = ratios.len().saturating_sub(1);
    if poisson_ratio.is_nan() {
        let paper = ratios.iter().position(|&nu| nu == 0.33).unwrap_or(last / 2);
        return (paper, paper, 0.0);
    }
    if last == 0 || poisson_ratio <= ratios[0] {
        return (0, 0, 0.0);
    }
    if poisson_ratio >= ratios[last] {
        return (last, last, 0.0);
    }
    let i = (0..last)
        .rfind(|&i| ratios[i] <= poisson_ratio)
        .unwrap_or(0);
    let t = (poisson_ratio - ratios[i]) / (ratios[i + 1] - ratios[i]);
    (i, i + 1, t)
}

/// Bonded-layer correction refitted to the project's small-deformation FEM, over ν.
///
/// The published series (Dimitriadis et al. 2002 for a sphere, Garcia & Garcia 2018 for a cone)
/// solve a paraboloid, or a cone at ν = 0.5, on an infinite layer; against the small-deformation
/// FEM of the 6 mm tools on 100 × 100 mm blocks 12, 20 and 30 mm thick they over-predict by up to
/// 6.5–7.9% (sphere) and 4.4–12% (cone; its series does not depend on ν) over ν = 0.30 … 0.49. The runtime multiplies the published series by a residual
/// 1 + k1 χ + k2 χ s, s = δ/R for a sphere (its series takes Hertz's contact radius, too large
/// as δ approaches R) and s = χ for a cone (no length scale), fitted at each ν by least squares
/// on the factor FEM / Sneddon's half-space (δ = 2 … 6 mm, χ to 0.5; `softhaptic-calibrate
/// poisson`, calibration report, "Nearly incompressible tissue", which scores it out of sample
/// on a 15 mm block). Full-mode fits: within 1.0–1.1% of the FEM in sample and 0.3–0.4% on the
/// 15 mm layer (sphere), 1.8–4.2% and 1.7–4.1% (cone, worst at ν = 0.49). The unbonded sphere
/// keeps the published series: the FEM clamps the block's base.
pub mod layer_fit {
    /// Poisson's ratios the residual was fitted at, increasing.
    pub const POISSON_RATIOS: [f64; 5] = super::hyperelastic_fit::POISSON_RATIOS;
    /// [k1, k2] of the sphere's residual 1 + k1 χ + k2 χ δ/R on Dimitriadis' bonded series at
    /// each ν.
    pub const SPHERE_BONDED_BY_POISSON: [[f64; 2]; 5] = [
        [0.0503, -0.1865],
        [0.0531, -0.1926],
        [0.0605, -0.2123],
        [0.0729, -0.2356],
        [0.1118, -0.2758],
    ];
    /// [k1, k2] of the cone's residual 1 + k1 χ + k2 χ² on Garcia & Garcia's series at each ν.
    pub const CONE_BY_POISSON: [[f64; 2]; 5] = [
        [-0.1381, -0.2151],
        [-0.1218, -0.2102],
        [-0.0693, -0.1920],
        [-0.0049, -0.1877],
        [0.1293, -0.2883],
    ];

    /// The residuals [k1, k2] at one Poisson's ratio.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub struct Residual {
        pub sphere_bonded: [f64; 2],
        pub cone: [f64; 2],
    }

    /// The residuals at `poisson_ratio`, interpolated in ν as [`super::hyperelastic_fit::at`].
    pub fn at(poisson_ratio: f64) -> Residual {
        let (i, j, t) = super::poisson_bracket(&POISSON_RATIOS, poisson_ratio);
        let lerp = |a: [f64; 2], b: [f64; 2]| [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])];
        Residual {
            sphere_bonded: lerp(SPHERE_BONDED_BY_POISSON[i], SPHERE_BONDED_BY_POISSON[j]),
            cone: lerp(CONE_BY_POISSON[i], CONE_BY_POISSON[j]),
        }
    }
}

/// Which bonded-layer law [`layer_factor`] evaluates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LayerLaw {
    /// The published series alone (what the FEM refit starts from).
    Published,
    /// The published series times the FEM residual at the material's ν: what the runtime uses.
    Runtime,
}

/// The layer factor of `tool` on a flat layer at depth `depth_m` (χ = √(Rδ)/h for a sphere,
/// δ tan α / h for a cone), as the runtime applies it with `law` = [`LayerLaw::Runtime`].
pub fn layer_factor(
    tool: &ToolShape,
    poisson_ratio: f64,
    layer: LayerSpec,
    depth_m: f64,
    law: LayerLaw,
) -> f64 {
    let residual = match law {
        LayerLaw::Published => layer_fit::Residual {
            sphere_bonded: [0.0; 2],
            cone: [0.0; 2],
        },
        LayerLaw::Runtime => layer_fit::at(poisson_ratio),
    };
    let depth_m = depth_m.max(0.0);
    match *tool {
        ToolShape::Sphere { radius_m } => LayerSeries::sphere(poisson_ratio, layer, &residual)
            .factor(
                (radius_m * depth_m).sqrt() / layer.thickness_m,
                depth_m / radius_m,
            ),
        ToolShape::Cone { half_angle_rad, .. } => LayerSeries::cone(layer, &residual)
            .factor(depth_m * half_angle_rad.tan() / layer.thickness_m, 0.0),
    }
}

/// Dimitriadis' series is derived for small χ = a/h; beyond this it is continued by its tangent
/// (its quartic term would otherwise turn the force down for very thin layers).
const LAYER_CHI_MAX: f64 = 0.5;
/// The exact-sphere series is in x = δ/R; past δ = R the sphere is buried to its equator and the
/// shape factor is held at its value there.
const EXACT_SPHERE_X_MAX: f64 = 1.0;
/// A concave surface may not conform more than this to a sphere: R0 ≥ 2R keeps R* ≤ 2R.
const CONCAVE_LIMIT_TIMES_TOOL_RADIUS: f64 = 2.0;
/// Curvature above this (a radius of 1 µm) is a mesh artefact, not an object.
const MAX_CURVATURE_1_PER_M: f64 = 1e6;
/// A cone's flank must stay this far (radians) from lying flat on the surface.
const CONE_FLANK_MARGIN_RAD: f64 = 5.0 * PI / 180.0;

/// The second term k2 χ s of the FEM residual 1 + k1 χ + k2 χ s ([`layer_fit`]).
#[derive(Debug, Clone, Copy, PartialEq)]
enum ResidualShape {
    /// s = χ. A cone's indentation has no length scale: its factor is a function of χ alone.
    ChiSquared,
    /// s = δ/R, held at 1 past δ = R. The sphere's series takes Hertz's a = √(Rδ), which
    /// over-states the exact sphere's contact radius more the deeper it goes: at the same χ the
    /// FEM's factor falls with depth.
    ChiTimesDepthOverRadius,
}

/// A layer-thickness polynomial 1 + c1 χ + c2 χ² + c3 χ³ + c4 χ⁴ (the published series) times
/// the FEM residual.
#[derive(Debug, Clone, Copy, PartialEq)]
struct LayerSeries {
    c: [f64; 4],
    /// [k1, k2] of the residual; zero leaves the published series bit for bit.
    k: [f64; 2],
    shape: ResidualShape,
    thickness_m: f64,
    /// The series' value and slope at χ_max, for the tangent continuation.
    series_at_max: f64,
    series_slope_at_max: f64,
}

impl LayerSeries {
    fn new(c: [f64; 4], k: [f64; 2], shape: ResidualShape, thickness_m: f64) -> Self {
        let [c1, c2, c3, c4] = c;
        let x = LAYER_CHI_MAX;
        LayerSeries {
            c,
            k,
            shape,
            thickness_m,
            series_at_max: 1.0 + x * (c1 + x * (c2 + x * (c3 + x * c4))),
            series_slope_at_max: c1 + x * (2.0 * c2 + x * (3.0 * c3 + x * 4.0 * c4)),
        }
    }

    #[inline]
    fn series(&self, chi: f64) -> f64 {
        let [c1, c2, c3, c4] = self.c;
        1.0 + chi * (c1 + chi * (c2 + chi * (c3 + chi * c4)))
    }

    /// The factor at `chi`; `depth_over_radius` is the sphere's δ/R (a cone ignores it).
    #[inline]
    fn factor(&self, chi: f64, depth_over_radius: f64) -> f64 {
        let [k1, k2] = self.k;
        let x = depth_over_radius.min(1.0);
        let s = |chi: f64| match self.shape {
            ResidualShape::ChiSquared => chi,
            ResidualShape::ChiTimesDepthOverRadius => x,
        };
        if chi <= LAYER_CHI_MAX {
            return self.series(chi) * (1.0 + chi * (k1 + k2 * s(chi)));
        }
        // Past χ_max, the tangent in χ of (series × residual): (P R)' = P' R + P R', held if
        // it falls. With no residual (k = 0) this is the series' own tangent bit for bit.
        let m = LAYER_CHI_MAX;
        let residual = 1.0 + m * (k1 + k2 * s(m));
        let residual_slope = match self.shape {
            ResidualShape::ChiSquared => k1 + 2.0 * k2 * m,
            ResidualShape::ChiTimesDepthOverRadius => k1 + k2 * x,
        };
        let slope =
            (self.series_slope_at_max * residual + self.series_at_max * residual_slope).max(0.0);
        self.series_at_max * residual + slope * (chi - m)
    }

    /// Dimitriadis et al. (2002), sphere on a layer, χ = √(Rδ)/h; on a bonded layer, times the
    /// residual of `residual`.
    fn sphere(poisson_ratio: f64, layer: LayerSpec, residual: &layer_fit::Residual) -> Self {
        let nu = poisson_ratio;
        let (a0, b0) = if layer.bonded {
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
        let c = [
            -2.0 * a0 / PI,
            4.0 * a0 * a0 / pi2,
            -8.0 / (pi2 * PI) * (a0 * a0 * a0 + 4.0 * pi2 * b0 / 15.0),
            16.0 * a0 / (pi2 * pi2) * (a0 * a0 * a0 + 3.0 * pi2 * b0 / 5.0),
        ];
        let k = if layer.bonded {
            residual.sphere_bonded
        } else {
            [0.0; 2]
        };
        LayerSeries::new(
            c,
            k,
            ResidualShape::ChiTimesDepthOverRadius,
            layer.thickness_m,
        )
    }

    /// Garcia & Garcia (2018), cone on a bonded layer, x = δ tan α / h (derived at ν = 0.5),
    /// times the residual of `residual`.
    fn cone(layer: LayerSpec, residual: &layer_fit::Residual) -> Self {
        LayerSeries::new(
            [0.721, 0.650, 0.491, 0.225],
            residual.cone,
            ResidualShape::ChiSquared,
            layer.thickness_m,
        )
    }
}

/// The contact force of one tool on one object, with the corrections its scene asked for.
#[derive(Debug, Clone, PartialEq)]
pub struct ForceModel {
    tool: ToolShape,
    material: Material,
    spec: ModelSpec,
    e_star_pa: f64,
    layer: Option<LayerSeries>,
    /// The hyperelastic factor's constants at the material's ν.
    hyper: hyperelastic_fit::Constants,
    /// Value and slope of the hyperelastic ratio at its fit limit (sphere).
    hyper_at_max: f64,
    hyper_slope_at_max: f64,
}

impl ForceModel {
    /// Builds the model; refuses combinations that have no law (see [`ModelSpec::validate`]).
    pub fn new(tool: ToolShape, material: Material, spec: ModelSpec) -> Result<Self, ModelError> {
        spec.validate(&tool)?;
        let residual = layer_fit::at(material.poisson_ratio());
        let layer = spec.thickness.map(|layer| match tool {
            ToolShape::Sphere { .. } => {
                LayerSeries::sphere(material.poisson_ratio(), layer, &residual)
            }
            ToolShape::Cone { .. } => LayerSeries::cone(layer, &residual),
        });
        let hyper = hyperelastic_fit::at(material.poisson_ratio());
        let x = hyperelastic_fit::SPHERE_X_MAX;
        let hyper_at_max = 1.0 + hyper.sphere_c1 * x + hyper.sphere_c2 * x * x;
        let hyper_slope_at_max = (hyper.sphere_c1 + 2.0 * hyper.sphere_c2 * x).max(0.0);
        Ok(Self {
            tool,
            material,
            spec,
            e_star_pa: material.plane_strain_modulus_pa(),
            layer,
            hyper,
            hyper_at_max,
            hyper_slope_at_max,
        })
    }

    /// The paper's law for `tool` on `material`, no correction.
    pub fn paper(tool: ToolShape, material: Material) -> Self {
        match Self::new(tool, material, ModelSpec::PAPER) {
            Ok(model) => model,
            // The paper's spec has no field that can be refused.
            Err(_) => unreachable!("ModelSpec::PAPER is valid for every tool"),
        }
    }

    pub fn tool(&self) -> &ToolShape {
        &self.tool
    }

    pub fn material(&self) -> &Material {
        &self.material
    }

    pub fn spec(&self) -> &ModelSpec {
        &self.spec
    }

    /// True when the force depends on the local geometry (curvature or inclination is on).
    pub fn uses_geometry(&self) -> bool {
        self.spec.curvature
            || (self.spec.inclination && matches!(self.tool, ToolShape::Cone { .. }))
    }

    /// Curvature clamped to what the laws can take: finite, not sharper than 1 µm, and a concave
    /// surface no tighter than twice the tool radius (a sphere) or none at all (a cone).
    #[inline]
    fn clamp_curvature(&self, curvature_1_per_m: f64) -> f64 {
        if !self.spec.curvature || !curvature_1_per_m.is_finite() {
            return 0.0;
        }
        // The cone's law is derived for a convex ball; on a concave surface it uses the plane's.
        let concave_limit = match self.tool {
            ToolShape::Sphere { radius_m } => -1.0 / (CONCAVE_LIMIT_TIMES_TOOL_RADIUS * radius_m),
            ToolShape::Cone { .. } => 0.0,
        };
        curvature_1_per_m.clamp(concave_limit, MAX_CURVATURE_1_PER_M)
    }

    /// The force magnitude along the contact normal at depth `depth_m` (≥ 0; NaN and negative
    /// depths give zero).
    #[inline]
    pub fn force_n(&self, depth_m: f64, geometry: &LocalGeometry) -> f64 {
        if self.spec.is_paper() {
            return law::contact_force_n(&self.tool, &self.material, depth_m);
        }
        let depth_m = if depth_m > 0.0 { depth_m } else { 0.0 };
        let force = match self.tool {
            ToolShape::Sphere { radius_m } => self.sphere_force_n(radius_m, depth_m, geometry),
            ToolShape::Cone { half_angle_rad, .. } => {
                self.cone_force_n(half_angle_rad, depth_m, geometry)
            }
        };
        // The factors are positive by construction; this guards the last bit (and ∞ · 0).
        if force.is_finite() {
            force.max(0.0)
        } else if depth_m > 0.0 {
            f64::MAX
        } else {
            0.0
        }
    }

    #[inline]
    fn sphere_force_n(&self, radius_m: f64, depth_m: f64, geometry: &LocalGeometry) -> f64 {
        // Curvature: Hertz with the effective radius 1/R* = 1/R + 1/R0 (Johnson ch. 4).
        let kappa = self.clamp_curvature(geometry.curvature_1_per_m);
        let r_eff = 1.0 / (1.0 / radius_m + kappa);
        let mut force = law::hertz_force_n(&self.material, r_eff, depth_m);
        if self.spec.exact_sphere {
            force *= exact_sphere_factor(depth_m / radius_m);
        }
        if let Some(layer) = &self.layer {
            force *= layer.factor(
                (r_eff * depth_m).sqrt() / layer.thickness_m,
                depth_m / radius_m,
            );
        }
        if self.spec.hyperelastic {
            force *= self.hyperelastic_sphere_factor(depth_m / radius_m);
        }
        // A sphere is symmetric about every axis through its centre: with δ measured along the
        // contact normal (crate::collision) its force does not depend on the tool's inclination.
        force
    }

    #[inline]
    fn cone_force_n(&self, half_angle_rad: f64, depth_m: f64, geometry: &LocalGeometry) -> f64 {
        let mut tan_alpha = half_angle_rad.tan();
        if self.spec.inclination {
            tan_alpha *= inclined_cone_factor(half_angle_rad, geometry.inclination_rad);
        }
        let kappa = self.clamp_curvature(geometry.curvature_1_per_m);
        let mut force = if kappa == 0.0 {
            2.0 / PI * self.e_star_pa * tan_alpha * depth_m * depth_m
        } else {
            // Cone on a sphere of radius R0 = 1/κ: δ = p a + κ a², F = E*(p a² + (4/3) κ a³),
            // p = (π/2) cot α. a is the positive root, in the form that stays accurate as κ → 0;
            // κ ≥ 0 here (clamp_curvature).
            let p = FRAC_PI_2 / tan_alpha;
            let a = 2.0 * depth_m / (p + (p * p + 4.0 * kappa * depth_m).sqrt());
            self.e_star_pa * a * a * (p + 4.0 / 3.0 * kappa * a)
        };
        if let Some(layer) = &self.layer {
            force *= layer.factor(depth_m * tan_alpha / layer.thickness_m, 0.0);
        }
        if self.spec.hyperelastic {
            force *= self.hyper.cone_ratio;
        }
        force
    }

    #[inline]
    fn hyperelastic_sphere_factor(&self, x: f64) -> f64 {
        if x <= hyperelastic_fit::SPHERE_X_MAX {
            1.0 + x * (self.hyper.sphere_c1 + x * self.hyper.sphere_c2)
        } else {
            self.hyper_at_max + self.hyper_slope_at_max * (x - hyperelastic_fit::SPHERE_X_MAX)
        }
    }

    /// dF/dδ at `depth_m`. Exact for the paper's law; otherwise a central difference with a step
    /// small against δ (the corrections are smooth), one-sided at δ = 0.
    pub fn stiffness_n_per_m(&self, depth_m: f64, geometry: &LocalGeometry) -> f64 {
        if self.spec.is_paper() {
            return law::contact_stiffness_n_per_m(&self.tool, &self.material, depth_m);
        }
        let d = if depth_m > 0.0 { depth_m } else { 0.0 };
        let h = (d * 1e-4).max(1e-12);
        let lo = (d - h).max(0.0);
        let hi = d + h;
        ((self.force_n(hi, geometry) - self.force_n(lo, geometry)) / (hi - lo)).max(0.0)
    }

    /// Radius a of the contact circle, the one a contact streams and the `paper` profile draws
    /// with; it never enters the force. The paper's law's (Hertz's √(Rδ), Sneddon's 2δ tanα/π,
    /// [`law::contact_radius_m`] bit for bit) unless the model bends it: on a curved object the
    /// effective radius R* = 1/(1/R + κ) (for a cone, the root of its law), and under the exact
    /// sphere the exact sphere's root of δ = (a/2) ln((R*+a)/(R*−a))
    /// ([`softhaptic_proto::deformation::exact_sphere_contact_radius_m`]), which stays inside
    /// the tool at every depth where Hertz's reaches R at δ = R.
    pub fn contact_radius_m(&self, depth_m: f64, geometry: &LocalGeometry) -> f64 {
        let exact_sphere = self.spec.exact_sphere && matches!(self.tool, ToolShape::Sphere { .. });
        if !self.spec.curvature && !exact_sphere {
            return law::contact_radius_m(&self.tool, depth_m);
        }
        let d = if depth_m > 0.0 { depth_m } else { 0.0 };
        let kappa = self.clamp_curvature(geometry.curvature_1_per_m);
        match self.tool {
            ToolShape::Sphere { radius_m } if exact_sphere => {
                softhaptic_proto::deformation::exact_sphere_contact_radius_m(
                    1.0 / (1.0 / radius_m + kappa),
                    d,
                )
            }
            ToolShape::Sphere { radius_m } => ((d / (1.0 / radius_m + kappa)).max(0.0)).sqrt(),
            ToolShape::Cone { half_angle_rad, .. } => {
                let p = FRAC_PI_2 / half_angle_rad.tan();
                2.0 * d / (p + (p * p + 4.0 * kappa * d).sqrt())
            }
        }
    }

    /// The depth δ* at which the model's stiffness first reaches `max_stiffness_n_per_m`, for the
    /// stiffness cap (docs/physics.md, "Haptic stability"). Closed form for the paper's law;
    /// otherwise bisection on the (monotone) stiffness, 48 halvings of [0, 1 m].
    pub fn depth_at_stiffness_m(
        &self,
        max_stiffness_n_per_m: f64,
        geometry: &LocalGeometry,
    ) -> f64 {
        if self.spec.is_paper() {
            return law::depth_at_stiffness_m(&self.tool, &self.material, max_stiffness_n_per_m);
        }
        let k = max_stiffness_n_per_m.max(0.0);
        let (mut lo, mut hi) = (0.0_f64, 1.0_f64);
        if self.stiffness_n_per_m(hi, geometry) < k {
            return hi;
        }
        for _ in 0..48 {
            let mid = 0.5 * (lo + hi);
            if self.stiffness_n_per_m(mid, geometry) < k {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        lo
    }

    /// Elastic energy ∫₀^δ F dδ' stored at `depth_m` (the renderer credits it to the passivity
    /// observer). Closed form for the paper's law; otherwise composite Simpson on 32 panels,
    /// after a change of variable
    /// that makes the integrand smooth.
    pub fn energy_j(&self, depth_m: f64, geometry: &LocalGeometry) -> f64 {
        let d = if depth_m > 0.0 { depth_m } else { 0.0 };
        if self.spec.is_paper() {
            let f = law::contact_force_n(&self.tool, &self.material, d);
            return match self.tool {
                ToolShape::Sphere { .. } => f * d / 2.5,
                ToolShape::Cone { .. } => f * d / 3.0,
            };
        }
        // δ' = δ t² turns the δ^{3/2} and δ² laws into smooth polynomials in t, which Simpson
        // integrates almost exactly: ∫₀^δ F dδ' = ∫₀^1 F(δ t²) 2δ t dt.
        const PANELS: usize = 32;
        let h = 1.0 / PANELS as f64;
        let integrand = |t: f64| self.force_n(d * t * t, geometry) * 2.0 * d * t;
        let mut sum = integrand(0.0) + integrand(1.0);
        for i in 1..PANELS {
            let w = if i % 2 == 1 { 4.0 } else { 2.0 };
            sum += w * integrand(i as f64 * h);
        }
        sum * h / 3.0
    }
}

/// Sneddon's exact sphere over Hertz's paraboloid, as the series of docs/physics.md in x = δ/R:
/// 1 − x/10 − x²/840 + 11x³/15120 + 1357x⁴/6652800 (within 1e-4 of the exact closed form up to
/// x = 1), held constant beyond x = 1.
#[inline]
pub fn exact_sphere_factor(depth_over_radius: f64) -> f64 {
    let x = depth_over_radius.clamp(0.0, EXACT_SPHERE_X_MAX);
    1.0 + x * (-0.1 + x * (-1.0 / 840.0 + x * (11.0 / 15120.0 + x * (1357.0 / 6_652_800.0))))
}

/// The exponent β of the inclined-cone correction k(θ)^β ([`inclined_cone_factor`]), fitted
/// by `softhaptic-calibrate inclination` (full mode) to the 45° cone of base radius 10 mm tilted
/// into the 100 × 100 × 50 mm block, against the linear FEM with contact on the deformed surface
/// (the formulation whose force turns with the contact, which the limits file measures): least
/// squares on ln(|F(θ)| / |F(0)|) at depths ≥ 3 mm and θ = 10°, 20°, worst error 0.98%; out of
/// sample at 5°, 15°, 25°, 1.87%. The equal-area cone alone (β = 1) falls 7% short of the FEM
/// from 17°; with β the magnitude stays within 7% to 25°, the largest tilt measured.
pub const INCLINED_CONE_EXPONENT: f64 = 1.373;

/// tan α_eff / tan α of the cone of the same cross-section area as a cone whose axis is tilted
/// by θ from the contact normal: the geometric part of the inclined-cone correction.
///
/// The tilted cone cuts the plane at depth δ in an ellipse with semi-axes
/// δ sinα cosα / (cos²θ − sin²α) and δ sinα / √(cos²θ − sin²α); the equivalent axisymmetric cone
/// has the same cross-section area, tan α_eff = √(sin²α cosα / (cos²θ − sin²α)^{3/2}). θ is
/// clamped so the flank stays 5° from lying on the surface.
#[inline]
pub fn equal_area_cone_factor(half_angle_rad: f64, inclination_rad: f64) -> f64 {
    let theta_max = (FRAC_PI_2 - half_angle_rad - CONE_FLANK_MARGIN_RAD).max(0.0);
    let theta = if inclination_rad.is_finite() {
        inclination_rad.abs().min(theta_max)
    } else {
        0.0
    };
    if theta == 0.0 {
        return 1.0;
    }
    let (sin_a, cos_a) = half_angle_rad.sin_cos();
    let cos_t = theta.cos();
    let gap = cos_t * cos_t - sin_a * sin_a;
    let tan_eff = (sin_a * sin_a * cos_a / (gap * gap.sqrt())).sqrt();
    tan_eff / half_angle_rad.tan()
}

/// The inclined-cone correction: the factor on the cone's law when its axis is tilted by θ
/// from the contact normal, k(θ)^β with k the equal-area cone ([`equal_area_cone_factor`]) and
/// β = [`INCLINED_CONE_EXPONENT`] fitted to the FEM. Exactly 1 for a perpendicular tool, so a
/// press along the normal renders the paper's law bit for bit.
#[inline]
pub fn inclined_cone_factor(half_angle_rad: f64, inclination_rad: f64) -> f64 {
    let k = equal_area_cone_factor(half_angle_rad, inclination_rad);
    if k == 1.0 {
        return 1.0;
    }
    k.powf(INCLINED_CONE_EXPONENT)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::f64::consts::FRAC_PI_4;

    const MM: f64 = 1e-3;

    fn sphere6() -> ToolShape {
        ToolShape::Sphere { radius_m: 6.0 * MM }
    }
    fn cone45() -> ToolShape {
        ToolShape::Cone {
            half_angle_rad: FRAC_PI_4,
            radius_m: 10.0 * MM,
        }
    }
    fn all_on(layer_mm: f64, bonded: bool) -> ModelSpec {
        ModelSpec {
            exact_sphere: true,
            curvature: true,
            thickness: Some(LayerSpec {
                thickness_m: layer_mm * MM,
                bonded,
            }),
            hyperelastic: true,
            inclination: true,
        }
    }

    /// Sneddon's closed form, solved for a by bisection (the reference of docs/physics.md's table).
    fn exact_sphere_closed_form(m: &Material, r: f64, depth: f64) -> f64 {
        let depth_of = |a: f64| 0.5 * a * ((r + a) / (r - a)).ln();
        let (mut lo, mut hi) = (0.0, r * (1.0 - 1e-15));
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            if depth_of(mid) < depth {
                lo = mid
            } else {
                hi = mid
            }
        }
        let a = 0.5 * (lo + hi);
        0.5 * m.plane_strain_modulus_pa()
            * ((a * a + r * r) * ((r + a) / (r - a)).ln() - 2.0 * a * r)
    }

    #[test]
    fn hyperelastic_constants_are_the_fits_at_fitted_poisson_ratios_and_interpolate_between() {
        use hyperelastic_fit::*;
        assert_eq!(at(0.33), PAPER);
        assert_eq!(PAPER.sphere_c1, SPHERE_C1);
        for (i, &nu) in POISSON_RATIOS.iter().enumerate() {
            let c = at(nu);
            assert_eq!(c.sphere_c1, SPHERE_C1_BY_POISSON[i]);
            assert_eq!(c.sphere_c2, SPHERE_C2_BY_POISSON[i]);
            assert_eq!(c.cone_ratio, CONE_RATIO_BY_POISSON[i]);
        }
        for w in POISSON_RATIOS.windows(2) {
            let (i, mid) = (
                POISSON_RATIOS.iter().position(|&n| n == w[0]).unwrap(),
                0.5 * (w[0] + w[1]),
            );
            let half = 0.5 * (CONE_RATIO_BY_POISSON[i] + CONE_RATIO_BY_POISSON[i + 1]);
            assert!((at(mid).cone_ratio - half).abs() < 1e-12);
        }
        let last = POISSON_RATIOS.len() - 1;
        assert_eq!(at(0.0), at(POISSON_RATIOS[0]));
        assert_eq!(at(0.4999), at(POISSON_RATIOS[last]));
        assert_eq!(at(f64::NAN), PAPER);
        // The model built at the stiffest fitted ν uses that fit.
        let m = Material::new(50e3, 0.4999).unwrap();
        let spec = ModelSpec {
            hyperelastic: true,
            ..ModelSpec::PAPER
        };
        let cone = ForceModel::new(cone45(), m, spec).unwrap();
        let plain = ForceModel::paper(cone45(), m);
        let ratio =
            cone.force_n(0.004, &LocalGeometry::FLAT) / plain.force_n(0.004, &LocalGeometry::FLAT);
        assert!(
            (ratio - CONE_RATIO_BY_POISSON[last]).abs() < 1e-12,
            "{ratio}"
        );
    }

    #[test]
    fn paper_spec_is_the_paper_law_bit_for_bit() {
        for tool in [sphere6(), cone45()] {
            let model = ForceModel::paper(tool, Material::PAPER_SOFT);
            for i in 0..100 {
                let d = i as f64 * 0.1 * MM;
                assert_eq!(
                    model.force_n(d, &LocalGeometry::FLAT).to_bits(),
                    law::contact_force_n(&tool, &Material::PAPER_SOFT, d).to_bits()
                );
            }
        }
    }

    #[test]
    fn exact_sphere_matches_the_reference_table() {
        // docs/physics.md, "Reference values", column "exact sphere, Sneddon".
        let table = [
            (1.0, 0.1802),
            (2.0, 0.5010),
            (3.0, 0.9044),
            (4.0, 1.3679),
            (5.0, 1.8775),
            (6.0, 2.4233),
        ];
        let spec = ModelSpec {
            exact_sphere: true,
            ..ModelSpec::PAPER
        };
        let model = ForceModel::new(sphere6(), Material::PAPER_SOFT, spec).unwrap();
        for (d_mm, f) in table {
            let got = model.force_n(d_mm * MM, &LocalGeometry::FLAT);
            assert!((got - f).abs() < 5e-4, "δ = {d_mm} mm: {got} vs {f}");
            let closed = exact_sphere_closed_form(&Material::PAPER_SOFT, 6.0 * MM, d_mm * MM);
            assert!(
                (got / closed - 1.0).abs() < 1e-4,
                "series vs closed form at {d_mm} mm"
            );
        }
    }

    #[test]
    fn published_bonded_layer_matches_physics_md() {
        // "At ν = 0.33, h = 30 mm, R = 6 mm the bonded factor runs 1.079 … 1.215 for δ = 1 … 6 mm."
        let layer = LayerSpec {
            thickness_m: 30.0 * MM,
            bonded: true,
        };
        let published = |d| layer_factor(&sphere6(), 0.33, layer, d, LayerLaw::Published);
        let f1 = published(1.0 * MM);
        let f6 = published(6.0 * MM);
        assert!((f1 - 1.079).abs() < 2e-3, "{f1}");
        assert!((f6 - 1.215).abs() < 2e-3, "{f6}");
    }

    #[test]
    fn bonded_layer_is_the_published_series_times_the_residual_fitted_at_the_materials_poisson_ratio()
     {
        use layer_fit::*;
        let thin = LayerSpec {
            thickness_m: 12.0 * MM,
            bonded: true,
        };
        for (i, &nu) in POISSON_RATIOS.iter().enumerate() {
            let residual = at(nu);
            assert_eq!(residual.sphere_bonded, SPHERE_BONDED_BY_POISSON[i]);
            assert_eq!(residual.cone, CONE_BY_POISSON[i]);
            let material = Material::new(50e3, nu).unwrap();
            let spec = ModelSpec {
                thickness: Some(thin),
                ..ModelSpec::PAPER
            };
            for (tool, [k1, k2]) in [
                (sphere6(), residual.sphere_bonded),
                (cone45(), residual.cone),
            ] {
                let layered = ForceModel::new(tool, material, spec).unwrap();
                let plain = ForceModel::paper(tool, material);
                for d_mm in [1.0, 3.0, 6.0] {
                    let d = d_mm * MM;
                    // χ = √(Rδ)/h and s = δ/R for the 6 mm sphere; χ = s = δ tan 45° / h for
                    // the cone.
                    let (chi, s) = match tool {
                        ToolShape::Sphere { .. } => {
                            ((6.0 * MM * d).sqrt() / thin.thickness_m, d / (6.0 * MM))
                        }
                        ToolShape::Cone { .. } => (d / thin.thickness_m, d / thin.thickness_m),
                    };
                    let published = layer_factor(&tool, nu, thin, d, LayerLaw::Published);
                    let runtime = layer_factor(&tool, nu, thin, d, LayerLaw::Runtime);
                    let expected = published * (1.0 + chi * (k1 + k2 * s));
                    assert!((runtime / expected - 1.0).abs() < 1e-12, "ν {nu} δ {d_mm}");
                    let ratio = layered.force_n(d, &LocalGeometry::FLAT)
                        / plain.force_n(d, &LocalGeometry::FLAT);
                    assert!((ratio / runtime - 1.0).abs() < 1e-12, "ν {nu} δ {d_mm}");
                }
            }
        }
        // Between fitted ratios the residual is interpolated; outside, the nearest fit's.
        let mid = 0.5 * (POISSON_RATIOS[3] + POISSON_RATIOS[4]);
        let half = 0.5 * (CONE_BY_POISSON[3][0] + CONE_BY_POISSON[4][0]);
        assert!((at(mid).cone[0] - half).abs() < 1e-12);
        assert_eq!(at(0.4999), at(POISSON_RATIOS[4]));
        assert_eq!(at(0.1), at(POISSON_RATIOS[0]));
        // The unbonded sphere keeps the published series: the FEM has no sliding base.
        let unbonded = LayerSpec {
            bonded: false,
            ..thin
        };
        for law in [LayerLaw::Published, LayerLaw::Runtime] {
            assert_eq!(
                layer_factor(&sphere6(), 0.49, unbonded, 4.0 * MM, law),
                layer_factor(&sphere6(), 0.49, unbonded, 4.0 * MM, LayerLaw::Published)
            );
        }
    }

    #[test]
    fn curvature_ratios_match_physics_md() {
        // F/F_flat = √(R0/(R+R0)) for R = 10 mm on R0 = 30, 50, 100 mm: 0.866, 0.913, 0.953.
        let tool = ToolShape::Sphere {
            radius_m: 10.0 * MM,
        };
        let spec = ModelSpec {
            curvature: true,
            ..ModelSpec::PAPER
        };
        let model = ForceModel::new(tool, Material::PAPER_SOFT, spec).unwrap();
        for (r0_mm, ratio) in [(30.0, 0.866), (50.0, 0.913), (100.0, 0.953)] {
            let g = LocalGeometry {
                curvature_1_per_m: 1.0 / (r0_mm * MM),
                inclination_rad: 0.0,
            };
            let got = model.force_n(3.0 * MM, &g) / model.force_n(3.0 * MM, &LocalGeometry::FLAT);
            assert!((got - ratio).abs() < 1e-3, "R0 = {r0_mm}: {got}");
        }
    }

    #[test]
    fn cone_on_a_sharp_ball_tends_to_hertz_of_the_ball() {
        // As R0 → 0 the cone's flank is flat against a tiny ball: F → (4/3) E* √R0 δ^{3/2}.
        let spec = ModelSpec {
            curvature: true,
            ..ModelSpec::PAPER
        };
        let model = ForceModel::new(cone45(), Material::PAPER_SOFT, spec).unwrap();
        let r0 = 1e-6;
        let g = LocalGeometry {
            curvature_1_per_m: 1.0 / r0,
            inclination_rad: 0.0,
        };
        let d = 1.0 * MM;
        let hertz = law::hertz_force_n(&Material::PAPER_SOFT, r0, d);
        let got = model.force_n(d, &g);
        assert!((got / hertz - 1.0).abs() < 0.05, "{got} vs {hertz}");
    }

    #[test]
    fn inclined_cone_is_the_paper_law_when_perpendicular_and_stiffens_when_tilted() {
        assert!((inclined_cone_factor(FRAC_PI_4, 0.0) - 1.0).abs() < 1e-12);
        assert!((inclined_cone_factor(0.3, 0.0) - 1.0).abs() < 1e-12);
        let mut last = 1.0;
        for deg in 1..=60 {
            let f = inclined_cone_factor(FRAC_PI_4, (deg as f64).to_radians());
            assert!(f.is_finite() && f >= last, "{deg}°: {f}");
            last = f;
        }
        // Past the flank margin the factor is held, not singular.
        assert_eq!(
            inclined_cone_factor(FRAC_PI_4, 1.5),
            inclined_cone_factor(FRAC_PI_4, 1.2)
        );
        assert_eq!(inclined_cone_factor(FRAC_PI_4, f64::NAN), 1.0);
        // The fitted correction is the equal-area cone raised to the fitted exponent, and
        // stiffer than it once tilted (the equal-area cone alone under-predicts the FEM).
        for deg in [5.0, 10.0, 20.0, 30.0f64] {
            let theta = deg.to_radians();
            let k = equal_area_cone_factor(FRAC_PI_4, theta);
            let fitted = inclined_cone_factor(FRAC_PI_4, theta);
            assert!((fitted - k.powf(INCLINED_CONE_EXPONENT)).abs() < 1e-15);
            assert!(fitted > k && k > 1.0, "{deg}°: {fitted} vs {k}");
        }
    }

    #[test]
    fn layer_series_reduces_to_the_paper_law_for_thick_layers() {
        for bonded in [true, false] {
            let spec = ModelSpec {
                thickness: Some(LayerSpec {
                    thickness_m: 1e3,
                    bonded,
                }),
                ..ModelSpec::PAPER
            };
            let model = ForceModel::new(sphere6(), Material::PAPER_SOFT, spec).unwrap();
            let f = model.force_n(3.0 * MM, &LocalGeometry::FLAT);
            let hertz = law::hertz_force_n(&Material::PAPER_SOFT, 6.0 * MM, 3.0 * MM);
            assert!((f / hertz - 1.0).abs() < 1e-4);
        }
    }

    #[test]
    fn stiffness_and_energy_agree_with_the_force() {
        let model = ForceModel::new(sphere6(), Material::PAPER_SOFT, all_on(30.0, true)).unwrap();
        let g = LocalGeometry {
            curvature_1_per_m: 1.0 / 0.05,
            inclination_rad: 0.2,
        };
        let d = 3.0 * MM;
        let h = 1e-7;
        let numeric = (model.force_n(d + h, &g) - model.force_n(d - h, &g)) / (2.0 * h);
        assert!((model.stiffness_n_per_m(d, &g) / numeric - 1.0).abs() < 1e-4);
        // Energy: trapezoid on a fine grid.
        let n = 20_000;
        let trap: f64 = (0..n)
            .map(|i| {
                let (a, b) = (d * i as f64 / n as f64, d * (i + 1) as f64 / n as f64);
                0.5 * (model.force_n(a, &g) + model.force_n(b, &g)) * (b - a)
            })
            .sum();
        let energy = model.energy_j(d, &g);
        assert!((energy / trap - 1.0).abs() < 1e-5, "{energy} vs {trap}");
        // δ* is where the stiffness reaches K.
        let k = 1000.0;
        let star = model.depth_at_stiffness_m(k, &g);
        assert!((model.stiffness_n_per_m(star, &g) / k - 1.0).abs() < 1e-3);
    }

    fn any_spec() -> impl Strategy<Value = ModelSpec> {
        (
            any::<bool>(),
            any::<bool>(),
            prop_oneof![Just(None), (1e-4f64..1.0, any::<bool>()).prop_map(Some)],
            any::<bool>(),
            any::<bool>(),
        )
            .prop_map(
                |(exact_sphere, curvature, layer, hyperelastic, inclination)| ModelSpec {
                    exact_sphere,
                    curvature,
                    thickness: layer.map(|(thickness_m, bonded)| LayerSpec {
                        thickness_m,
                        bonded,
                    }),
                    hyperelastic,
                    inclination,
                },
            )
    }

    fn any_tool() -> impl Strategy<Value = ToolShape> {
        prop_oneof![
            (1e-4f64..0.05).prop_map(|radius_m| ToolShape::Sphere { radius_m }),
            (0.05f64..1.5, 1e-3f64..0.05).prop_map(|(half_angle_rad, radius_m)| ToolShape::Cone {
                half_angle_rad,
                radius_m
            }),
        ]
    }

    #[test]
    fn the_contact_radius_is_the_exact_spheres_under_the_exact_sphere_and_the_laws_otherwise() {
        let m = Material::PAPER_SOFT;
        let curved = LocalGeometry {
            curvature_1_per_m: 1.0 / (30.0 * MM),
            ..LocalGeometry::FLAT
        };
        let exact = ModelSpec {
            exact_sphere: true,
            ..ModelSpec::PAPER
        };
        let both = ModelSpec {
            curvature: true,
            ..exact
        };
        let paper = ForceModel::paper(sphere6(), m);
        let exact_model = ForceModel::new(sphere6(), m, exact).unwrap();
        let both_model = ForceModel::new(sphere6(), m, both).unwrap();
        for d_mm in [0.5, 3.0, 6.0, 9.0] {
            let d = d_mm * MM;
            // Without a correction that bends it: the paper's law, bit for bit.
            assert_eq!(
                paper.contact_radius_m(d, &curved).to_bits(),
                law::contact_radius_m(&sphere6(), d).to_bits()
            );
            let cone = ForceModel::new(cone45(), m, ModelSpec::PAPER).unwrap();
            assert_eq!(
                cone.contact_radius_m(d, &curved).to_bits(),
                law::contact_radius_m(&cone45(), d).to_bits()
            );
            // Under the exact sphere: its root, inside Hertz's and inside the tool even at δ ≥ R.
            let a = exact_model.contact_radius_m(d, &curved);
            let expected =
                softhaptic_proto::deformation::exact_sphere_contact_radius_m(6.0 * MM, d);
            assert_eq!(a, expected);
            assert!(a < law::contact_radius_m(&sphere6(), d) && a < 6.0 * MM);
            // With the curvature too: the exact sphere of the effective radius 1/(1/R + κ).
            let r_eff = 1.0 / (1.0 / (6.0 * MM) + 1.0 / (30.0 * MM));
            let a = both_model.contact_radius_m(d, &curved);
            let expected = softhaptic_proto::deformation::exact_sphere_contact_radius_m(r_eff, d);
            assert_eq!(a, expected);
        }
        assert_eq!(exact_model.contact_radius_m(f64::NAN, &curved), 0.0);
        assert_eq!(exact_model.contact_radius_m(-MM, &curved), 0.0);
    }

    proptest! {
        /// docs/design.md invariant 4 for every combination of corrections: finite, non-negative,
        /// zero at zero depth, non-decreasing and continuous in depth, for any geometry input.
        #[test]
        fn every_model_is_safe_at_the_extremes(
            tool in any_tool(),
            spec in any_spec(),
            e in 1.0f64..1e9,
            nu in prop_oneof![Just(0.0), Just(0.4999), 0.0f64..0.4999],
            depth in prop_oneof![Just(0.0), Just(1e-12), 0.0f64..0.2],
            curvature in prop_oneof![Just(0.0), Just(f64::NAN), Just(f64::INFINITY), Just(-1e9), -1e3f64..1e7],
            inclination in prop_oneof![Just(0.0), Just(f64::NAN), -3.2f64..3.2],
        ) {
            let material = Material::new(e, nu).unwrap();
            let Ok(model) = ForceModel::new(tool, material, spec) else {
                // Refused combinations (a cone with the exact sphere or an unbonded layer).
                return Ok(());
            };
            let g = LocalGeometry { curvature_1_per_m: curvature, inclination_rad: inclination };
            let f = model.force_n(depth, &g);
            prop_assert!(f.is_finite() && f >= 0.0, "F({depth}) = {f}");
            prop_assert_eq!(model.force_n(0.0, &g), 0.0);
            prop_assert_eq!(model.force_n(-1.0, &g), 0.0);
            prop_assert_eq!(model.force_n(f64::NAN, &g), 0.0);
            let f_next = model.force_n(depth * (1.0 + 1e-6) + 1e-15, &g);
            prop_assert!(f_next >= f * (1.0 - 1e-12), "not monotone at {depth}: {f} → {f_next}");
            // Continuity: a relative step of 1e-6 in depth moves the force by at most 1e-5 of its
            // value (every law here grows like a power of δ of exponent below 10); at δ = 0 the
            // force leaves zero smoothly.
            if depth > 1e-9 {
                prop_assert!(f_next - f <= 1e-5 * f_next, "jump at {depth}: {f} → {f_next}");
            } else {
                prop_assert!(f_next < 1e-6, "F({}) = {f_next}", depth + 1e-15);
            }
            let k = model.stiffness_n_per_m(depth, &g);
            prop_assert!(k.is_finite() && k >= 0.0);
            let energy = model.energy_j(depth, &g);
            prop_assert!(energy.is_finite() && energy >= 0.0);
        }

        /// Each correction reduces to the paper's law in the paper's own limit: flat, thick,
        /// perpendicular, small depth.
        #[test]
        fn corrections_vanish_in_the_papers_limit(tool in any_tool(), spec in any_spec(), nu in 0.0f64..0.4999) {
            let material = Material::new(50e3, nu).unwrap();
            let mut spec = spec;
            spec.hyperelastic = false; // a fitted material law, not a geometric limit
            if let Some(layer) = spec.thickness.as_mut() { layer.thickness_m = 1e4; }
            let Ok(model) = ForceModel::new(tool, material, spec) else { return Ok(()); };
            let paper = ForceModel::paper(tool, material);
            let d = tool.radius_m() * 1e-4;
            let ratio = model.force_n(d, &LocalGeometry::FLAT) / paper.force_n(d, &LocalGeometry::FLAT);
            prop_assert!((ratio - 1.0).abs() < 1e-3, "ratio {ratio}");
        }
    }
}
