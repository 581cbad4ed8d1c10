//! The surface the viewer draws, held against the FEM's top surface.
//!
//! The viewer can deform its mesh with the paper's profile (proto's [`DeformationProfile`]: the
//! tool's shape inside the contact radius a, a quadratic Bézier from a to R_d, nothing beyond),
//! with a as the contact streams it ([`drawn_contact_radius_m`]) and R_d from the calibration
//! table. The R_d runs already
//! hold the FEM's top surface at every depth, so this module measures the drawn depression
//! against the FEM's at the same undeformed radius, and does the same for the analytical
//! alternatives: the elastic half-space's surface (Johnson's for the sphere, Sneddon's for the
//! cone) and that surface with its far field cut by the rigid base
//! ([`half_space_on_base_depression_m`]).
//!
//! The errors are read at the FEM's profile nodes (where the FEM's answer is known without
//! interpolation), from the axis to the block's side face; the RMS integrates the squared error
//! over that line with the trapezoidal rule, so the graded mesh does not weight the contact zone
//! more than the far field.
//!
//! It also tabulates the FEM surface for the `fem` render profile ([`surface_family`]: the
//! neo-Hookean run's surface at each table depth, resampled on a uniform radius grid, carried in
//! the calibration tables) and scores that profile the same way, twice: as written (at a table
//! depth it is the FEM row itself, so what remains is the resampling), and with the row of the
//! depth being scored left out, so the profile there is interpolated from the rows beside it:
//! the error a depth between the table's rows sees, at twice the rows' spacing.

use serde::Serialize;
use softhaptic_device::law;
use softhaptic_device::model::{ForceModel, LocalGeometry};
use softhaptic_proto::calibration::{half_space_depression_m, half_space_on_base_depression_m};
use softhaptic_proto::deformation::{
    DeformationProfile, SurfaceFamily, SurfaceFamilyError, SurfaceRow,
};
use softhaptic_proto::{Material, ModelSpec, ToolShape};

use super::IndentationRun;
use crate::element::LawKind;
use crate::solver::SurfacePoint;

/// A surface profile the viewer could draw.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DrawnProfile {
    /// The paper's profile as the viewer draws it (proto's reference implementation), with the
    /// contact radius the contact streams ([`drawn_contact_radius_m`]).
    Paper,
    /// The elastic half-space's surface: Johnson's Hertz profile (sphere), Sneddon's (cone).
    HalfSpace,
    /// The half-space's surface with its far field removed by the rigid base.
    HalfSpaceOnBase,
    /// The `fem` render profile: the neo-Hookean run's surface as the table carries it.
    Fem,
    /// The `fem` profile without the row of the depth drawn: interpolated from its neighbours.
    FemHeldOut,
}

impl DrawnProfile {
    /// Every profile the comparison scores, the drawn one first.
    pub const ALL: [DrawnProfile; 5] = [
        DrawnProfile::Paper,
        DrawnProfile::HalfSpace,
        DrawnProfile::HalfSpaceOnBase,
        DrawnProfile::Fem,
        DrawnProfile::FemHeldOut,
    ];

    /// Short name for files and tables.
    pub fn name(self) -> &'static str {
        match self {
            DrawnProfile::Paper => "paper",
            DrawnProfile::HalfSpace => "half_space",
            DrawnProfile::HalfSpaceOnBase => "half_space_on_base",
            DrawnProfile::Fem => "fem",
            DrawnProfile::FemHeldOut => "fem_held_out",
        }
    }

    /// Name for the report, with the source of the formula for `tool`.
    pub fn title(self, tool: &ToolShape) -> &'static str {
        match (self, tool) {
            (DrawnProfile::Paper, _) => "paper's Bézier",
            (DrawnProfile::HalfSpace, ToolShape::Sphere { .. }) => "Johnson (half-space)",
            (DrawnProfile::HalfSpace, ToolShape::Cone { .. }) => "Sneddon (half-space)",
            (DrawnProfile::HalfSpaceOnBase, _) => "half-space on base",
            (DrawnProfile::Fem, _) => "fem (tabulated FEM)",
            (DrawnProfile::FemHeldOut, _) => "fem, row held out",
        }
    }
}

/// Every drawn profile of one contact, ready to evaluate at any radius.
#[derive(Debug, Clone)]
pub struct DrawnSurface {
    tool: ToolShape,
    depth_m: f64,
    thickness_m: f64,
    bezier: DeformationProfile,
    /// The `fem` profile's family; without one the `fem` profiles are NaN.
    fem: Option<SurfaceFamily>,
    /// The same without the row at `depth_m`.
    fem_held_out: Option<SurfaceFamily>,
}

impl DrawnSurface {
    /// The profiles of `tool` pressed `depth_m` into a layer `thickness_m` thick, the paper's
    /// drawn with the streamed contact radius ([`drawn_contact_radius_m`]) and the table's
    /// `deformed_radius_m`.
    pub fn new(tool: &ToolShape, depth_m: f64, deformed_radius_m: f64, thickness_m: f64) -> Self {
        DrawnSurface {
            tool: *tool,
            depth_m,
            thickness_m,
            bezier: DeformationProfile::new(
                tool,
                depth_m,
                drawn_contact_radius_m(tool, depth_m),
                deformed_radius_m,
            ),
            fem: None,
            fem_held_out: None,
        }
    }

    /// The same with the `fem` profiles tabulated from `run` (the run the tables are written
    /// from), once whole and once without its row at this depth.
    pub fn with_fem_from(mut self, run: Option<&IndentationRun>) -> Self {
        if let Some(run) = run {
            self.fem = surface_family_without(&self.tool, run, None).ok();
            self.fem_held_out = surface_family_without(&self.tool, run, Some(self.depth_m)).ok();
        }
        self
    }

    /// The profiles a study's report draws at `depth_m`: the paper's with `deformed_radius_m`,
    /// the `fem` ones from the study's neo-Hookean run.
    pub fn of_study(study: &super::RdStudy, depth_m: f64, deformed_radius_m: f64) -> Self {
        DrawnSurface::new(
            &study.tool,
            depth_m,
            deformed_radius_m,
            super::RD_BLOCK_M[2],
        )
        .with_fem_from(fem_source(&study.runs))
    }

    /// Outward radial displacement of `profile` at undeformed radius `r_m`: only the `fem`
    /// profiles move the surface sideways; the others move it along −n alone.
    pub fn radial_displacement_m(&self, profile: DrawnProfile, r_m: f64) -> f64 {
        let family = match profile {
            DrawnProfile::Fem => &self.fem,
            DrawnProfile::FemHeldOut => &self.fem_held_out,
            _ => return 0.0,
        };
        family.as_ref().map_or(f64::NAN, |f| {
            f.at_depth(&self.tool, self.depth_m)
                .radial_displacement_m(r_m)
        })
    }

    /// Depression of `profile` at radius `r_m` from the contact axis.
    pub fn depression_m(&self, profile: DrawnProfile, r_m: f64) -> f64 {
        match profile {
            DrawnProfile::Paper => self.bezier.depression_m(r_m),
            DrawnProfile::HalfSpace => half_space_depression_m(&self.tool, self.depth_m, r_m),
            DrawnProfile::HalfSpaceOnBase => {
                half_space_on_base_depression_m(&self.tool, self.depth_m, r_m, self.thickness_m)
            }
            DrawnProfile::Fem => self.fem.as_ref().map_or(f64::NAN, |f| {
                f.at_depth(&self.tool, self.depth_m).depression_m(r_m)
            }),
            DrawnProfile::FemHeldOut => self.fem_held_out.as_ref().map_or(f64::NAN, |f| {
                f.at_depth(&self.tool, self.depth_m).depression_m(r_m)
            }),
        }
    }
}

/// The contact radius a contact on the flat calibration block streams, which the paper's profile
/// draws with: the runtime's own ([`ForceModel::contact_radius_m`]) under the model of the
/// scenes that use this tool. The sphere's scenes use the exact sphere, so its a is the root of
/// δ = (a/2) ln((R+a)/(R−a)) (0.83 R at δ = R, where Hertz's √(Rδ) reaches R and the Bézier's
/// flank would vanish); their other corrections (curvature, none on a flat block; the
/// hyperelastic factor) change the force, not a. The cone's is Sneddon's 2δ tanα/π. Falls back
/// to the paper's law if the model were refused.
pub fn drawn_contact_radius_m(tool: &ToolShape, depth_m: f64) -> f64 {
    let spec = ModelSpec {
        exact_sphere: matches!(tool, ToolShape::Sphere { .. }),
        ..ModelSpec::PAPER
    };
    match ForceModel::new(*tool, Material::PAPER_SOFT, spec) {
        Ok(model) => model.contact_radius_m(depth_m, &LocalGeometry::FLAT),
        Err(_) => law::contact_radius_m(tool, depth_m),
    }
}

/// Radius spacing of the tabulated surface: 0.5 mm, under half the FEM's finest node spacing
/// (1.25 mm on the calibration block), so resampling changes the surface by a few µm.
pub const SURFACE_STEP_M: f64 = 0.5e-3;
/// Where a row's depression falls below this for good, the row ends (ramped down, see
/// [`SURFACE_RAMP_SLOPE`]): 0.05 mm, a tenth of the paper's R_d threshold and a fifth of the
/// profile's error budget; the last few hundredths of a millimetre of the far tail would move
/// most of a large mesh every frame for a depression no one can see.
pub const SURFACE_FLOOR_M: f64 = 5e-5;
/// Where a row ends (below the floor, or at the block's side, beyond which the surface is not
/// known), it ramps linearly to 0 at this slope, 1 in 100 (the drawn normal tilts by 0.6°), so
/// the drawn surface meets the unmoved one without a step or a ring in its shading.
pub const SURFACE_RAMP_SLOPE: f64 = 0.01;

/// How the contact radius grows with depth, the `fem` profile's radius exponent: √(Rδ) for a
/// sphere, 2δ tanα/π for a cone.
pub fn radius_exponent(tool: &ToolShape) -> f64 {
    match tool {
        ToolShape::Sphere { .. } => 0.5,
        ToolShape::Cone { .. } => 1.0,
    }
}

/// The run the `fem` profile is tabulated from: the neo-Hookean one, which writes the tables.
pub fn fem_source(runs: &[IndentationRun]) -> Option<&IndentationRun> {
    runs.iter().find(|r| r.law == LawKind::NeoHookean)
}

/// The `fem` render profile's family from `run`: its top surface at every depth, resampled every
/// [`SURFACE_STEP_M`] from the axis to the block's side ([`surface_row`]).
pub fn surface_family(
    tool: &ToolShape,
    run: &IndentationRun,
) -> Result<SurfaceFamily, SurfaceFamilyError> {
    surface_family_without(tool, run, None)
}

/// [`surface_family`] without the row at `skip_depth_m`.
fn surface_family_without(
    tool: &ToolShape,
    run: &IndentationRun,
    skip_depth_m: Option<f64>,
) -> Result<SurfaceFamily, SurfaceFamilyError> {
    let rows = run
        .depths_m
        .iter()
        .zip(&run.surfaces)
        .filter(|(d, _)| skip_depth_m.is_none_or(|skip| (**d - skip).abs() > 1e-9))
        .map(|(&depth_m, surface)| surface_row(depth_m, surface))
        .collect();
    SurfaceFamily::new(radius_exponent(tool), SURFACE_STEP_M, rows)
}

/// One row of the `fem` profile: the FEM's depression (linear between its nodes, ≥ 0) and its
/// radial displacement (0 on the axis) every [`SURFACE_STEP_M`] out to the last node, rounded
/// to 10 nm (the file stays short; the FEM is not that precise), ended after the last sample
/// whose depression is at or above [`SURFACE_FLOOR_M`] (or at the block's side) by a ramp of
/// both to 0 over the samples that take the depression to 0 at [`SURFACE_RAMP_SLOPE`].
pub fn surface_row(depth_m: f64, surface: &[SurfacePoint]) -> SurfaceRow {
    let last_m = surface.last().map_or(0.0, |p| p.radius_m);
    let samples = (last_m / SURFACE_STEP_M).floor() as usize;
    let round = |z: f64| (z * 1e8).round() / 1e8;
    let sample = |k: usize, field: fn(&SurfacePoint) -> f64| {
        let x = surface_value_at(surface, k as f64 * SURFACE_STEP_M, field);
        if x.is_finite() { round(x) } else { 0.0 }
    };
    let mut depression_m: Vec<f64> = (0..=samples)
        .map(|k| sample(k, |p| p.depression_m).max(0.0))
        .collect();
    // The axis does not move sideways (by symmetry; the FEM's axis nodes are held on it).
    let mut radial_m: Vec<f64> = (0..=samples)
        .map(|k| {
            if k == 0 {
                0.0
            } else {
                sample(k, |p| p.radial_displacement_m)
            }
        })
        .collect();
    let kept = depression_m
        .iter()
        .rposition(|&z| z >= SURFACE_FLOOR_M)
        .map_or(0, |k| k + 1);
    depression_m.truncate(kept);
    radial_m.truncate(kept);
    if let (Some(&end_m), Some(&end_u_m)) = (depression_m.last(), radial_m.last()) {
        let ramp = (end_m / (SURFACE_RAMP_SLOPE * SURFACE_STEP_M))
            .ceil()
            .max(1.0) as usize;
        let fade = |k: usize| 1.0 - k as f64 / ramp as f64;
        depression_m.extend((1..ramp).map(|k| round(end_m * fade(k))));
        radial_m.extend((1..ramp).map(|k| round(end_u_m * fade(k))));
    }
    depression_m.push(0.0);
    radial_m.push(0.0);
    if depression_m.len() < 2 {
        depression_m.insert(0, 0.0);
        radial_m.insert(0, 0.0);
    }
    SurfaceRow {
        depth_m,
        depression_m,
        radial_displacement_m: radial_m,
    }
}

/// Where along the surface a radius lies, relative to the drawn contact radius a and R_d.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SurfaceRegion {
    /// r < a: under the tool.
    Contact,
    /// a ≤ r < R_d: the Bézier's flank.
    Flank,
    /// r ≥ R_d: where the paper's profile draws nothing.
    Tail,
}

impl SurfaceRegion {
    fn of(r_m: f64, contact_radius_m: f64, deformed_radius_m: f64) -> Self {
        if r_m < contact_radius_m {
            SurfaceRegion::Contact
        } else if r_m < deformed_radius_m {
            SurfaceRegion::Flank
        } else {
            SurfaceRegion::Tail
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            SurfaceRegion::Contact => "contact",
            SurfaceRegion::Flank => "flank",
            SurfaceRegion::Tail => "tail",
        }
    }
}

/// One drawn profile against the FEM surface at one depth. Errors are drawn − FEM: negative
/// where the drawn surface is too shallow.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ProfileError {
    pub profile: DrawnProfile,
    /// The error of largest magnitude over the profile nodes, signed.
    pub worst_error_m: f64,
    /// Undeformed radius of that node.
    pub worst_error_radius_m: f64,
    pub worst_error_region: SurfaceRegion,
    /// The error of largest magnitude at r ≥ a, signed. Inside the contact the profiles that
    /// move the surface along −n alone follow the tool, so there their error is the FEM node's
    /// sideways slide under the tool (or the mesh's resolution of it), the same for each of
    /// them; outside it the profiles differ. (The `fem` profiles slide their points as the FEM's
    /// did.)
    pub worst_error_outside_contact_m: f64,
    /// Root mean square of the error along the line from the axis to the block's side.
    pub rms_error_m: f64,
    /// The profile's depression at r = 2a.
    pub depression_at_twice_contact_m: f64,
    /// The profile's depression at r = R_d / 2.
    pub depression_at_half_deformed_m: f64,
    /// How far the profile moves the surface point at undeformed r = a towards the axis (0 for
    /// the profiles drawn along −n alone).
    pub inward_motion_at_contact_edge_m: f64,
}

impl ProfileError {
    /// Magnitude of the worst error.
    pub fn max_error_m(&self) -> f64 {
        self.worst_error_m.abs()
    }
}

/// Every drawn profile against one FEM run's surface at one depth.
#[derive(Debug, Clone, Serialize)]
pub struct SurfaceComparison {
    pub law: LawKind,
    pub depth_m: f64,
    /// The contact radius as the contact streams it and the paper's profile draws it
    /// ([`drawn_contact_radius_m`]).
    pub contact_radius_m: f64,
    /// R_d the viewer draws with (the calibration table's fit at this depth).
    pub deformed_radius_m: f64,
    /// R_d measured on this run's own surface.
    pub fem_deformed_radius_m: f64,
    pub fem_depression_at_twice_contact_m: f64,
    pub fem_depression_at_half_deformed_m: f64,
    /// How far the FEM surface at the drawn contact edge (undeformed r = a) moved towards the
    /// axis; the drawn vertices do not move sideways at all.
    pub fem_inward_motion_at_contact_edge_m: f64,
    /// One entry per profile of [`DrawnProfile::ALL`], in that order.
    pub profiles: Vec<ProfileError>,
}

impl SurfaceComparison {
    /// The entry of `profile`.
    pub fn error(&self, profile: DrawnProfile) -> Option<&ProfileError> {
        self.profiles.iter().find(|p| p.profile == profile)
    }
}

/// A field of the FEM surface at radius `r_m`, linearly interpolated between the profile nodes
/// (held at the end values outside them); NaN for an empty surface.
pub fn surface_value_at(
    surface: &[SurfacePoint],
    r_m: f64,
    field: fn(&SurfacePoint) -> f64,
) -> f64 {
    let (Some(first), Some(last)) = (surface.first(), surface.last()) else {
        return f64::NAN;
    };
    if r_m <= first.radius_m {
        return field(first);
    }
    if r_m >= last.radius_m {
        return field(last);
    }
    let k = surface.partition_point(|p| p.radius_m <= r_m);
    let (p0, p1) = (&surface[k - 1], &surface[k]);
    let span = p1.radius_m - p0.radius_m;
    if span <= 0.0 {
        return field(p0);
    }
    let t = (r_m - p0.radius_m) / span;
    field(p0) + t * (field(p1) - field(p0))
}

/// Compares every drawn profile with the FEM's `surface` of a run with `law` at `depth_m`, the
/// paper's drawn with `deformed_radius_m`, on a block `thickness_m` deep, the `fem` ones
/// tabulated from `fem_source`.
pub fn compare_surface(
    tool: &ToolShape,
    law: LawKind,
    depth_m: f64,
    deformed_radius_m: f64,
    thickness_m: f64,
    surface: &[SurfacePoint],
    fem_source: Option<&IndentationRun>,
) -> SurfaceComparison {
    let drawn =
        DrawnSurface::new(tool, depth_m, deformed_radius_m, thickness_m).with_fem_from(fem_source);
    let a = drawn_contact_radius_m(tool, depth_m);
    let depression = |p: &SurfacePoint| p.depression_m;
    let profile: Vec<(f64, f64)> = surface
        .iter()
        .map(|p| (p.radius_m, p.depression_m))
        .collect();
    let profiles = DrawnProfile::ALL
        .iter()
        .map(|&kind| {
            let errors: Vec<(f64, f64)> = surface
                .iter()
                .map(|p| {
                    (
                        p.radius_m,
                        drawn.depression_m(kind, p.radius_m) - p.depression_m,
                    )
                })
                .collect();
            let worst = |from_m: f64| {
                errors
                    .iter()
                    .copied()
                    .filter(|&(r, _)| r >= from_m)
                    .max_by(|x, y| x.1.abs().total_cmp(&y.1.abs()))
                    .unwrap_or((f64::NAN, f64::NAN))
            };
            let (worst_error_radius_m, worst_error_m) = worst(0.0);
            ProfileError {
                profile: kind,
                worst_error_m,
                worst_error_radius_m,
                worst_error_region: SurfaceRegion::of(worst_error_radius_m, a, deformed_radius_m),
                worst_error_outside_contact_m: worst(a).1,
                rms_error_m: rms_along(&errors),
                depression_at_twice_contact_m: drawn.depression_m(kind, 2.0 * a),
                depression_at_half_deformed_m: drawn.depression_m(kind, 0.5 * deformed_radius_m),
                inward_motion_at_contact_edge_m: -drawn.radial_displacement_m(kind, a),
            }
        })
        .collect();
    SurfaceComparison {
        law,
        depth_m,
        contact_radius_m: a,
        deformed_radius_m,
        fem_deformed_radius_m: crate::solver::deformed_radius_m(&profile, super::RD_THRESHOLD_M),
        fem_depression_at_twice_contact_m: surface_value_at(surface, 2.0 * a, depression),
        fem_depression_at_half_deformed_m: surface_value_at(
            surface,
            0.5 * deformed_radius_m,
            depression,
        ),
        fem_inward_motion_at_contact_edge_m: -surface_value_at(surface, a, |p| {
            p.radial_displacement_m
        }),
        profiles,
    }
}

/// The `fem` profile's goal: within 0.25 mm (max) of the neo-Hookean FEM's surface, the FEM the
/// scenes' tables are tabulated from, at every depth to δ = R.
pub const FEM_PROFILE_GOAL_M: f64 = 0.25e-3;

/// The largest |error| of `profile` against the FEM of `law` over `comparisons` (every depth
/// they hold), with its depth: `(depth_m, max_error_m)`; `None` without such a comparison.
pub fn worst_error(
    comparisons: &[SurfaceComparison],
    law: LawKind,
    profile: DrawnProfile,
) -> Option<(f64, f64)> {
    comparisons
        .iter()
        .filter(|c| c.law == law)
        .filter_map(|c| Some((c.depth_m, c.error(profile)?.max_error_m())))
        .max_by(|x, y| x.1.total_cmp(&y.1))
}

/// How far apart two FEM surfaces of the same block are: the largest |depression of `a` −
/// depression of `b`| at `a`'s profile nodes (`b` interpolated there); NaN if either is empty.
pub fn surface_difference_m(a: &[SurfacePoint], b: &[SurfacePoint]) -> f64 {
    if a.is_empty() || b.is_empty() {
        return f64::NAN;
    }
    a.iter()
        .map(|p| (p.depression_m - surface_value_at(b, p.radius_m, |q| q.depression_m)).abs())
        .fold(0.0, f64::max)
}

/// √(∫ e² dr / L) over the sampled line (r, e), trapezoidal; the single value for one sample.
fn rms_along(errors: &[(f64, f64)]) -> f64 {
    match errors {
        [] => f64::NAN,
        [(_, e)] => e.abs(),
        _ => {
            let mut integral = 0.0;
            for w in errors.windows(2) {
                let ((r0, e0), (r1, e1)) = (w[0], w[1]);
                integral += 0.5 * (e0 * e0 + e1 * e1) * (r1 - r0);
            }
            let length = errors[errors.len() - 1].0 - errors[0].0;
            if length > 0.0 {
                (integral / length).sqrt()
            } else {
                errors.iter().map(|(_, e)| e.abs()).fold(0.0, f64::max)
            }
        }
    }
}

/// The comparisons of every run at each of its depths up to δ = R (the tool's radius: the
/// paper's sphere is then buried to its equator), the
/// paper's profile drawn with `deformed_radius_m(δ)`, the `fem` ones tabulated from the
/// neo-Hookean run among `runs`.
pub fn compare_runs(
    tool: &ToolShape,
    runs: &[IndentationRun],
    thickness_m: f64,
    deformed_radius_m: impl Fn(f64) -> f64,
) -> Vec<SurfaceComparison> {
    let source = fem_source(runs);
    let mut out = Vec::new();
    for run in runs {
        for (&depth_m, surface) in run.depths_m.iter().zip(&run.surfaces) {
            if depth_m > tool.radius_m() * (1.0 + 1e-9) {
                continue;
            }
            out.push(compare_surface(
                tool,
                run.law,
                depth_m,
                deformed_radius_m(depth_m),
                thickness_m,
                surface,
                source,
            ));
        }
    }
    out
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    const MM: f64 = 1e-3;

    fn point(radius_m: f64, depression_m: f64) -> SurfacePoint {
        SurfacePoint {
            radius_m,
            depression_m,
            radial_displacement_m: -0.1 * depression_m,
        }
    }

    #[test]
    fn interpolation_is_linear_between_nodes_and_held_outside() {
        let s = [point(0.0, 2.0), point(1.0, 1.0), point(3.0, 0.0)];
        let z = |p: &SurfacePoint| p.depression_m;
        assert_eq!(surface_value_at(&s, -1.0, z), 2.0);
        assert_eq!(surface_value_at(&s, 0.5, z), 1.5);
        assert_eq!(surface_value_at(&s, 1.0, z), 1.0);
        assert_eq!(surface_value_at(&s, 2.0, z), 0.5);
        assert_eq!(surface_value_at(&s, 9.0, z), 0.0);
        assert!(surface_value_at(&[], 1.0, z).is_nan());
    }

    #[test]
    fn rms_weights_by_length_not_by_node_count() {
        // Dense nodes near the axis with a large error do not dominate a long quiet tail.
        let e = [(0.0, 1.0), (0.01, 1.0), (0.02, 0.0), (1.0, 0.0)];
        let rms = rms_along(&e);
        let expected = ((0.01 + 0.5 * 0.01) / 1.0_f64).sqrt();
        assert!((rms - expected).abs() < 1e-12, "{rms} vs {expected}");
    }

    #[test]
    fn a_row_ends_where_the_surface_settles_or_ramps_down_past_the_block() {
        // Settles inside the block: the FEM row up to the last sample above the floor, then a
        // ramp to 0 no steeper than the ramp slope.
        let settled: Vec<SurfacePoint> = (0..=100)
            .map(|k| point(k as f64 * MM, (2.0 * MM - 0.1 * MM * k as f64).max(0.0)))
            .collect();
        let row = surface_row(2.0 * MM, &settled);
        assert_eq!(row.depression_m[0], 2.0 * MM);
        assert_eq!(row.depression_m[2], 1.9 * MM); // r = 1 mm, on a node
        assert_eq!(*row.depression_m.last().unwrap(), 0.0);
        // The FEM row falls to 0.05 mm at r = 19.5 mm (sample 39): kept, then the ramp.
        assert!((row.depression_m[39] - SURFACE_FLOOR_M).abs() < 1e-9);
        let ramp = &row.depression_m[39..];
        for w in ramp.windows(2) {
            assert!(w[1] < w[0]);
            assert!(w[0] - w[1] <= SURFACE_RAMP_SLOPE * SURFACE_STEP_M * (1.0 + 1e-6));
        }
        assert_eq!(ramp.len(), 11, "{ramp:?}");
        // The sideways motion beside it: the FEM's on the samples (−0.1 z here), 0 on the axis
        // (where the FEM's −0.2 mm would tear the surface), faded with the ramp, 0 at the end.
        let u = &row.radial_displacement_m;
        assert_eq!(u.len(), row.depression_m.len());
        assert_eq!(u[0], 0.0);
        assert!((u[2] + 0.19 * MM).abs() < 1e-12, "{}", u[2]);
        assert_eq!(*u.last().unwrap(), 0.0);
        for (w, z) in u[39..].windows(2).zip(ramp) {
            assert!(w[1] > w[0] && (w[0] + 0.1 * z).abs() < 1e-8);
        }
        // Still sunk at the block's side (50 mm): a ramp to 0 beyond it.
        let sunk: Vec<SurfacePoint> = (0..=50)
            .map(|k| point(k as f64 * MM, 5.0 * MM / (1.0 + k as f64)))
            .collect();
        let row = surface_row(5.0 * MM, &sunk);
        let at_side = (50.0 * MM / SURFACE_STEP_M) as usize;
        assert!((row.depression_m[at_side] - 5.0 * MM / 51.0).abs() < 1e-8);
        assert!(row.depression_m.len() > at_side + 3);
        for w in row.depression_m[at_side..].windows(2) {
            assert!(w[1] < w[0]);
            assert!(w[0] - w[1] <= SURFACE_RAMP_SLOPE * SURFACE_STEP_M * (1.0 + 1e-6));
        }
        // As a family it draws the FEM's surface at the row's depth (under a slender cone, whose
        // own surface, the lower bound of the drawn one, lies below this one's everywhere).
        let f = SurfaceFamily::new(0.5, SURFACE_STEP_M, vec![row]).unwrap();
        let p = f.at_depth(&ToolShape::cone(0.1, 0.01).unwrap(), 5.0 * MM);
        for q in &sunk {
            assert!((p.depression_m(q.radius_m) - q.depression_m).abs() < 1e-8);
        }
    }

    #[test]
    fn a_surface_equal_to_the_half_space_scores_zero_for_it() {
        let tool = ToolShape::Sphere { radius_m: 0.01 };
        let d = 4.0 * MM;
        let surface: Vec<SurfacePoint> = (0..=100)
            .map(|k| {
                let r = 0.5 * MM * k as f64;
                point(r, half_space_depression_m(&tool, d, r))
            })
            .collect();
        let c = compare_surface(
            &tool,
            LawKind::NeoHookean,
            d,
            15.0 * MM,
            0.05,
            &surface,
            None,
        );
        let hs = c.error(DrawnProfile::HalfSpace).unwrap();
        assert!(hs.max_error_m() < 1e-15 && hs.rms_error_m < 1e-15);
        assert!(hs.worst_error_outside_contact_m.abs() < 1e-15);
        // The Bézier ends at R_d where Johnson's surface is still sunk, and lies below it on the
        // flank: too shallow there.
        let paper = c.error(DrawnProfile::Paper).unwrap();
        assert!(paper.worst_error_m < -0.1 * MM, "{paper:?}");
        assert_ne!(paper.worst_error_region, SurfaceRegion::Contact);
        assert_eq!(paper.worst_error_outside_contact_m, paper.worst_error_m);
        // The drawn contact edge is the exact sphere's, inside Hertz's √(Rδ), where Johnson's
        // surface is δ/2 deep; at the drawn edge it is deeper.
        let hertz_a = (0.01 * d).sqrt();
        assert!(c.contact_radius_m < 0.97 * hertz_a && c.contact_radius_m > 0.9 * hertz_a);
        let at_hertz_a = surface_value_at(&surface, hertz_a, |p| p.depression_m);
        assert!((at_hertz_a - 0.5 * d).abs() < 0.02 * MM);
        let at_a = surface_value_at(&surface, c.contact_radius_m, |p| p.depression_m);
        assert!(at_a > 0.5 * d + 0.05 * MM);
        assert!((c.fem_inward_motion_at_contact_edge_m - 0.1 * at_a).abs() < 1e-6);
    }

    #[test]
    fn the_paper_profile_is_drawn_with_the_streamed_contact_radius() {
        let sphere = ToolShape::Sphere { radius_m: 0.01 };
        let cone = ToolShape::Cone {
            half_angle_rad: std::f64::consts::FRAC_PI_4,
            radius_m: 0.01,
        };
        for d in [0.5 * MM, 4.0 * MM, 10.0 * MM] {
            let a = drawn_contact_radius_m(&sphere, d);
            let exact = softhaptic_proto::deformation::exact_sphere_contact_radius_m(0.01, d);
            assert_eq!(a, exact);
            assert_eq!(
                drawn_contact_radius_m(&cone, d),
                law::contact_radius_m(&cone, d)
            );
        }
        // At δ = R the sphere's contact is 0.83 R: the Bézier keeps a flank beyond the tool's
        // radius (with Hertz's a = R it is flat there).
        let p = DrawnSurface::new(&sphere, 10.0 * MM, 31.0 * MM, 0.05);
        let beyond = p.depression_m(DrawnProfile::Paper, 12.0 * MM);
        assert!(beyond > 0.5 * MM && beyond < 5.0 * MM, "{beyond}");
    }
}
