//! Inclination (paper §3.2, eq. 7): tools tilted from the surface normal, and the runtime's
//! inclination-corrected cone.
//!
//! The runtime measures the depth δ along the contact normal and renders the force along it.
//! The FEM places each tilted tool so that its lowest point is at the same normal depth as the
//! perpendicular one, so the perpendicular FEM force F(0) stands for what the runtime renders
//! without a correction (the law's own error against the FEM is the force study's business, not
//! this one's), and k(θ) F(0) with the correction, k the runtime's factor for the tilt.
//!
//! Two linear formulations are tilted. The small-deformation one is the textbook inclined punch
//! on a half-space: the gap is measured along the undeformed surface's normal and the reaction
//! is normal to it, so its force has no lateral part and only its magnitude can depart. The
//! deformed-contact one pushes along the tool's flank where it touches the deformed surface, so
//! its force also turns; it measures the direction error, and the runtime's limits come from it.

use serde::Serialize;
use softhaptic_device::law;
use softhaptic_device::model::LocalGeometry;
use softhaptic_proto::{ModelSpec, ToolShape};

use super::{
    ExperimentError, IndentationRun, JND_PERCENT, MATERIAL, MM, Mode, RD_BLOCK_M, Resolution,
    RunCache, RunSpec, block_body, depths, first_crossing, paper_tools_10mm, spec,
};
use crate::element::LawKind;
use crate::mesh::Symmetry;
use crate::models::RuntimeModel;

#[derive(Debug, Clone, Serialize)]
pub struct InclinationStudy {
    pub tool_name: String,
    /// The FEM formulation of the tilted runs.
    pub law: LawKind,
    pub tool: ToolShape,
    pub depths_m: Vec<f64>,
    pub angles_rad: Vec<f64>,
    pub runs: Vec<IndentationRun>,
    /// Per angle, per depth: |F(θ) − F(0)| / |F(0)| in percent: the perpendicular force
    /// rendered along the normal, δ measured along the normal, against the tilted FEM force.
    pub vector_error_percent: Vec<Vec<f64>>,
    /// Per angle, per depth: 1 − (F(θ)·axis)/|F(0)| in percent, the paper's eq. 7 reading
    /// (force felt along the direction of travel).
    pub axial_error_percent: Vec<Vec<f64>>,
    /// Per angle: the runtime's inclination factor k(θ) (cone; 1 for the sphere).
    pub correction_factor: Vec<f64>,
    /// Per angle, per depth: |F(θ) − k(θ) F(0)| / |F(0)| in percent, the inclination-corrected
    /// runtime model against the tilted FEM force.
    pub corrected_error_percent: Vec<Vec<f64>>,
    /// Per angle, per depth: (|F(θ)| − |F(0)|) / |F(0)| in percent: the error of the force
    /// magnitude, the paper's criterion (its 7% is the just-noticeable difference of force
    /// magnitude).
    pub magnitude_error_percent: Vec<Vec<f64>>,
    /// The same against the corrected magnitude k(θ) |F(0)|.
    pub corrected_magnitude_error_percent: Vec<Vec<f64>>,
    /// Per angle, per depth: angle between the FEM force and the contact normal, along which the
    /// runtime renders its force, degrees (the paper cites 32° as the discrimination threshold
    /// of force direction).
    pub direction_error_deg: Vec<Vec<f64>>,
    /// Smallest depth whose contact radius spans at least one fine cell: below it the contact
    /// rests on one or two nodes and, for the sharp cone, on the apex node alone, whose normal
    /// flips to a 45° flank at the slightest lateral drift. Thresholds use depths from here on.
    pub resolved_from_m: f64,
    /// Smallest angle at which the worst vector error over the resolved depths reaches 7%.
    pub threshold_vector_rad: Option<f64>,
    /// The same for the axial reading.
    pub threshold_axial_rad: Option<f64>,
    /// The same for the corrected model.
    pub threshold_corrected_rad: Option<f64>,
    /// Smallest angle at which the worst magnitude error over the resolved depths reaches 7%.
    pub threshold_magnitude_rad: Option<f64>,
    /// The same for the corrected magnitude.
    pub threshold_corrected_magnitude_rad: Option<f64>,
    /// Largest direction error over the resolved depths and every angle, degrees.
    pub worst_direction_deg: f64,
    /// The cone's inclination correction refitted to this study's FEM (cone only).
    pub refit: Option<InclinationRefit>,
}

/// The cone's inclination correction refitted to the tilted FEM.
///
/// Magnitude: the runtime's factor k(θ) (the equal-area equivalent cone) raised to a power β,
/// k(θ)^β, fitted by least squares to |F(θ)| / |F(0)| over the resolved depths of the fitting
/// angles; β = 1 is the equal-area cone alone, and the runtime uses the β fitted to the
/// deformed-contact FEM ([`softhaptic_device::model::INCLINED_CONE_EXPONENT`]). Direction: the angle between the FEM force and the
/// contact normal, φ ≈ γ θ, fitted the same way (the runtime renders along the normal, so γ
/// measures what it leaves out). The angles alternate between the fit and the check, so every
/// checked angle lies between two fitted ones and none of them took part in the fit.
#[derive(Debug, Clone, Serialize)]
pub struct InclinationRefit {
    pub fit_angles_rad: Vec<f64>,
    pub check_angles_rad: Vec<f64>,
    pub exponent: f64,
    pub direction_gain: f64,
    /// Per angle of the study, the refitted magnitude's worst error over the resolved depths
    /// against |F(θ)|, percent (signed, of the largest |value|).
    pub refit_magnitude_error_percent: Vec<f64>,
    /// The same with the runtime's factor ([`softhaptic_device::model::inclined_cone_factor`]).
    pub in_use_magnitude_error_percent: Vec<f64>,
    /// Per angle, the equal-area cone's factor k(θ) the refit raises to β.
    pub equal_area_factor: Vec<f64>,
    /// Per angle, the direction fit's worst error over the resolved depths, degrees.
    pub direction_fit_error_deg: Vec<f64>,
    /// The angle where the refitted magnitude's error first reaches 7% (or the direction 32°),
    /// `None` when it does not within the angles measured.
    pub valid_inclination_rad: Option<f64>,
}

impl InclinationRefit {
    /// Largest |error| over `angles`, percent.
    fn worst_over(&self, errors: &[f64], all: &[f64], angles: &[f64]) -> f64 {
        all.iter()
            .zip(errors)
            .filter(|(a, _)| angles.iter().any(|b| (*a - b).abs() < 1e-12))
            .fold(0.0_f64, |m, (_, e)| m.max(e.abs()))
    }

    /// Largest |refitted magnitude error| over the fitting angles (in sample) and the checking
    /// angles (out of sample), percent.
    pub fn in_and_out_of_sample_percent(&self, all_angles_rad: &[f64]) -> (f64, f64) {
        (
            self.worst_over(
                &self.refit_magnitude_error_percent,
                all_angles_rad,
                &self.fit_angles_rad,
            ),
            self.worst_over(
                &self.refit_magnitude_error_percent,
                all_angles_rad,
                &self.check_angles_rad,
            ),
        )
    }
}

/// The refit of the cone's inclination correction from one study's runs.
fn refit_inclination(
    tool: &ToolShape,
    angles_rad: &[f64],
    depths_m: &[f64],
    resolved_from_m: f64,
    runs: &[IndentationRun],
) -> Option<InclinationRefit> {
    let ToolShape::Cone { half_angle_rad, .. } = *tool else {
        return None;
    };
    let perpendicular = &runs.first()?.forces_n;
    let resolved: Vec<usize> = (0..depths_m.len())
        .filter(|&i| depths_m[i] >= resolved_from_m - 1e-12)
        .collect();
    let k_area =
        |theta: f64| softhaptic_device::model::equal_area_cone_factor(half_angle_rad, theta);
    let k_in_use =
        |theta: f64| softhaptic_device::model::inclined_cone_factor(half_angle_rad, theta);
    // Even positions (0°, 10°, 20° …) fit, odd ones (5°, 15°, 25° …) check.
    let fit_angles_rad: Vec<f64> = angles_rad.iter().copied().step_by(2).collect();
    let check_angles_rad: Vec<f64> = angles_rad.iter().copied().skip(1).step_by(2).collect();
    // β minimises Σ (ln r − β ln k)², r = |F(θ)|/|F(0)|: the ratio's error in log space.
    let (mut num, mut den, mut gnum, mut gden) = (0.0, 0.0, 0.0, 0.0);
    for (k, &theta) in angles_rad.iter().enumerate() {
        if !fit_angles_rad.contains(&theta) || theta == 0.0 {
            continue;
        }
        let ln_k = k_area(theta).ln();
        for &i in &resolved {
            let f = runs[k].forces_n[i];
            let ratio = norm3(f) / norm3(perpendicular[i]).max(f64::MIN_POSITIVE);
            num += ratio.ln() * ln_k;
            den += ln_k * ln_k;
            let phi = f[0].hypot(f[1]).atan2(f[2]);
            gnum += phi * theta;
            gden += theta * theta;
        }
    }
    let exponent = if den > 0.0 { num / den } else { 1.0 };
    let direction_gain = if gden > 0.0 { gnum / gden } else { 0.0 };
    let worst = |k: usize, factor: f64| {
        resolved
            .iter()
            .map(|&i| {
                let n0 = norm3(perpendicular[i]).max(f64::MIN_POSITIVE);
                100.0 * (factor * n0 - norm3(runs[k].forces_n[i])) / n0
            })
            .fold(0.0_f64, |m, e| if e.abs() > m.abs() { e } else { m })
    };
    let mut refit_magnitude_error_percent = Vec::new();
    let mut in_use_magnitude_error_percent = Vec::new();
    let mut equal_area_factor = Vec::new();
    let mut direction_fit_error_deg = Vec::new();
    let mut worst_refit = Vec::new();
    let mut worst_direction = Vec::new();
    for (k, &theta) in angles_rad.iter().enumerate() {
        let kf = k_area(theta);
        let e = worst(k, kf.powf(exponent));
        refit_magnitude_error_percent.push(e);
        worst_refit.push(e.abs());
        in_use_magnitude_error_percent.push(worst(k, k_in_use(theta)));
        equal_area_factor.push(kf);
        let de = resolved
            .iter()
            .map(|&i| {
                let f = runs[k].forces_n[i];
                (f[0].hypot(f[1]).atan2(f[2]) - direction_gain * theta).to_degrees()
            })
            .fold(0.0_f64, |m, e| if e.abs() > m.abs() { e } else { m });
        direction_fit_error_deg.push(de);
        worst_direction.push(
            resolved
                .iter()
                .map(|&i| {
                    let f = runs[k].forces_n[i];
                    f[0].hypot(f[1]).atan2(f[2]).to_degrees()
                })
                .fold(0.0_f64, f64::max),
        );
    }
    let magnitude = first_crossing(angles_rad, &worst_refit, JND_PERCENT);
    let direction = first_crossing(angles_rad, &worst_direction, DIRECTION_THRESHOLD_DEG);
    let valid_inclination_rad = match (magnitude, direction) {
        (Some(m), Some(d)) => Some(m.min(d)),
        (m, d) => m.or(d),
    };
    Some(InclinationRefit {
        fit_angles_rad,
        check_angles_rad,
        exponent,
        direction_gain,
        refit_magnitude_error_percent,
        in_use_magnitude_error_percent,
        equal_area_factor,
        direction_fit_error_deg,
        valid_inclination_rad,
    })
}

impl InclinationStudy {
    /// The largest angle measured.
    pub fn max_angle_rad(&self) -> f64 {
        self.angles_rad.iter().copied().fold(0.0, f64::max)
    }

    /// The inclination up to which the model's force is valid by the paper's criterion: the
    /// magnitude within 7% (with the runtime's correction when `corrected`), and the direction
    /// within the 32° discrimination threshold the paper cites; `None` when neither limit is
    /// reached within the angles measured.
    pub fn valid_inclination_rad(&self, corrected: bool) -> Option<f64> {
        let magnitude = if corrected {
            self.threshold_corrected_magnitude_rad
        } else {
            self.threshold_magnitude_rad
        };
        let direction = self.threshold_direction_rad();
        match (magnitude, direction) {
            (Some(m), Some(d)) => Some(m.min(d)),
            (m, d) => m.or(d),
        }
    }

    /// Smallest angle at which the worst direction error over the resolved depths reaches the
    /// paper's 32°.
    pub fn threshold_direction_rad(&self) -> Option<f64> {
        let worst: Vec<f64> = self
            .direction_error_deg
            .iter()
            .map(|e| self.worst_resolved(e))
            .collect();
        first_crossing(&self.angles_rad, &worst, DIRECTION_THRESHOLD_DEG)
    }

    /// Largest |value| over the resolved depths.
    fn worst_resolved(&self, per_depth: &[f64]) -> f64 {
        per_depth
            .iter()
            .zip(&self.depths_m)
            .filter(|(_, d)| **d >= self.resolved_from_m - 1e-12)
            .fold(0.0_f64, |m, (v, _)| m.max(v.abs()))
    }
}

/// The discrimination threshold of force direction the paper cites (§3.2, its ref. 30), degrees.
pub const DIRECTION_THRESHOLD_DEG: f64 = 32.0;

/// Resolution, depths and angles (degrees) of one tool's study.
fn setup(mode: Mode, tool: &ToolShape) -> (Resolution, Vec<f64>, Vec<f64>) {
    let sphere = matches!(tool, ToolShape::Sphere { .. });
    match mode {
        Mode::Quick => (
            Resolution {
                name: "quick",
                fine_cell_m: 6.0 * MM,
                coarse_cells: 2,
            },
            depths(2.0, 6.0, 2.0),
            if sphere {
                vec![0.0, 15.0, 30.0]
            } else {
                vec![0.0, 10.0, 20.0]
            },
        ),
        // The sphere's contact spans a 3 mm cell from δ = 1 mm on; the cone's (a = 2δ/π) needs
        // 1.5 mm cells to be resolved from δ = 3 mm, the depths where the paper found its 9°.
        Mode::Full if sphere => (
            Resolution {
                name: "full",
                fine_cell_m: 3.0 * MM,
                coarse_cells: 3,
            },
            depths(1.0, 6.0, 1.0),
            vec![0.0, 10.0, 20.0, 30.0, 40.0],
        ),
        Mode::Full => (
            Resolution {
                name: "full",
                fine_cell_m: 1.5 * MM,
                coarse_cells: 4,
            },
            depths(1.0, 6.0, 1.0),
            vec![0.0, 5.0, 10.0, 15.0, 20.0, 25.0],
        ),
    }
}

/// The formulations tilted: the small-deformation one (magnitude; the reproduction), and the
/// deformed-contact one (magnitude and direction; the runtime's limits).
pub const INCLINATION_LAWS: [LawKind; 2] = [
    LawKind::LinearSmallDeformation,
    LawKind::LinearDeformedContact,
];

fn tilted_run(mode: Mode, name: &str, tool: &ToolShape, theta_rad: f64, law: LawKind) -> RunSpec {
    let (res, ds, _) = setup(mode, tool);
    let max_depth = ds.last().copied().unwrap_or(0.006);
    // The tilted tool slides sideways by δ tan θ: widen the refined zone to cover it.
    let body = block_body(
        RD_BLOCK_M,
        tool,
        max_depth,
        max_depth * theta_rad.tan(),
        res,
        Symmetry::HalfY,
    );
    // The deformed-contact runs keep their historical labels (the committed report names them).
    let law_tag = match law {
        LawKind::LinearDeformedContact => String::new(),
        other => format!(" {}", other.name()),
    };
    spec(
        format!("tilt {name} {:.0}°{law_tag}", theta_rad.to_degrees()),
        body,
        tool,
        law,
        res,
        &ds,
        theta_rad,
    )
}

fn angles(mode: Mode, tool: &ToolShape) -> Vec<f64> {
    setup(mode, tool).2.iter().map(|a| a.to_radians()).collect()
}

/// The runs: each tool at each angle, half model (mirror plane y = 0), both linear
/// formulations.
pub fn inclination_runs(mode: Mode) -> Vec<RunSpec> {
    let mut out = Vec::new();
    for (name, tool) in paper_tools_10mm() {
        for law in INCLINATION_LAWS {
            for theta in angles(mode, &tool) {
                out.push(tilted_run(mode, name, &tool, theta, law));
            }
        }
    }
    out
}

fn norm3(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// Paper §3.2: tools tilted in the x–z plane and pushed along their axis into the
/// 100 × 100 × 50 mm block (half model, mirror plane y = 0), both linear formulations,
/// E = 50 kPa; one study per tool and formulation, in the order of [`INCLINATION_LAWS`].
pub fn inclination(mode: Mode, cache: &RunCache) -> Result<Vec<InclinationStudy>, ExperimentError> {
    let mut out = Vec::new();
    for (name, tool) in paper_tools_10mm() {
        for law in INCLINATION_LAWS {
            out.push(inclination_of(mode, cache, name, tool, law)?);
        }
    }
    Ok(out)
}

fn inclination_of(
    mode: Mode,
    cache: &RunCache,
    name: &str,
    tool: ToolShape,
    law: LawKind,
) -> Result<InclinationStudy, ExperimentError> {
    let study = "inclination";
    {
        let (res, ds, _) = setup(mode, &tool);
        let max_depth = ds.last().copied().unwrap_or(0.006);
        let angles_rad = angles(mode, &tool);
        let mut runs = Vec::new();
        for &theta in &angles_rad {
            runs.push(
                cache
                    .get(study, &tilted_run(mode, name, &tool, theta, law))?
                    .clone(),
            );
        }
        let Some(perpendicular) = runs.first().map(|r| r.forces_n.clone()) else {
            return Err(ExperimentError::Data {
                study: study.to_owned(),
                reason: format!("{name}: no angle"),
            });
        };
        // The runtime's correction: the inclined model's force over the perpendicular one, at
        // the same normal depth (for the sphere the runtime has no inclination term: k = 1).
        let corrected = RuntimeModel::new(
            tool,
            MATERIAL,
            ModelSpec {
                inclination: matches!(tool, ToolShape::Cone { .. }),
                ..ModelSpec::PAPER
            },
        )
        .map_err(|source| ExperimentError::Model {
            run: format!("{study} {name}"),
            source,
        })?;
        let mut vector_error_percent = Vec::new();
        let mut axial_error_percent = Vec::new();
        let mut corrected_error_percent = Vec::new();
        let mut correction_factor = Vec::new();
        let mut magnitude_error_percent = Vec::new();
        let mut corrected_magnitude_error_percent = Vec::new();
        let mut direction_error_deg = Vec::new();
        for (run, &theta) in runs.iter().zip(&angles_rad) {
            let axis = [theta.sin(), 0.0, theta.cos()];
            let tilted = LocalGeometry {
                curvature_1_per_m: 0.0,
                inclination_rad: theta,
            };
            let probe = 0.5 * max_depth;
            let k =
                corrected.force_n(probe, &tilted) / corrected.force_n(probe, &LocalGeometry::FLAT);
            correction_factor.push(k);
            let mut ve = Vec::new();
            let mut ae = Vec::new();
            let mut ce = Vec::new();
            let mut me = Vec::new();
            let mut cme = Vec::new();
            let mut de = Vec::new();
            for (f, f0) in run.forces_n.iter().zip(&perpendicular) {
                let n0 = norm3(*f0).max(f64::MIN_POSITIVE);
                let n = norm3(*f);
                me.push(100.0 * (n - n0) / n0);
                cme.push(100.0 * (n - k * n0) / n0);
                de.push(f[0].hypot(f[1]).atan2(f[2]).to_degrees());
                ve.push(100.0 * norm3([f[0] - f0[0], f[1] - f0[1], f[2] - f0[2]]) / n0);
                let along = f[0] * axis[0] + f[1] * axis[1] + f[2] * axis[2];
                ae.push(100.0 * (1.0 - along / n0));
                ce.push(100.0 * norm3([f[0] - k * f0[0], f[1] - k * f0[1], f[2] - k * f0[2]]) / n0);
            }
            vector_error_percent.push(ve);
            axial_error_percent.push(ae);
            corrected_error_percent.push(ce);
            magnitude_error_percent.push(me);
            corrected_magnitude_error_percent.push(cme);
            direction_error_deg.push(de);
        }
        let resolved_from_m = ds
            .iter()
            .copied()
            .find(|&d| law::contact_radius_m(&tool, d) >= res.fine_cell_m)
            .unwrap_or(max_depth);
        let threshold = |errors: &[Vec<f64>]| {
            let worst: Vec<f64> = errors
                .iter()
                .map(|e| {
                    e.iter()
                        .zip(&ds)
                        .filter(|(_, d)| **d >= resolved_from_m - 1e-12)
                        .fold(0.0_f64, |m, (v, _)| m.max(v.abs()))
                })
                .collect();
            first_crossing(&angles_rad, &worst, JND_PERCENT)
        };
        let worst_direction_deg = direction_error_deg
            .iter()
            .flat_map(|e| e.iter().zip(&ds))
            .filter(|(_, d)| **d >= resolved_from_m - 1e-12)
            .fold(0.0_f64, |m, (v, _)| m.max(v.abs()));
        let refit = refit_inclination(&tool, &angles_rad, &ds, resolved_from_m, &runs);
        Ok(InclinationStudy {
            refit,
            tool_name: name.to_owned(),
            law,
            tool,
            depths_m: ds.clone(),
            resolved_from_m,
            threshold_vector_rad: threshold(&vector_error_percent),
            threshold_axial_rad: threshold(&axial_error_percent),
            threshold_corrected_rad: threshold(&corrected_error_percent),
            threshold_magnitude_rad: threshold(&magnitude_error_percent),
            threshold_corrected_magnitude_rad: threshold(&corrected_magnitude_error_percent),
            worst_direction_deg,
            magnitude_error_percent,
            corrected_magnitude_error_percent,
            direction_error_deg,
            angles_rad,
            runs,
            vector_error_percent,
            axial_error_percent,
            correction_factor,
            corrected_error_percent,
        })
    }
}
