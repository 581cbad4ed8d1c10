//! Palpation: the indentation FEM with a stiffer spherical inclusion inside the block, the
//! force-ratio table the runtime interpolates, its validation on held-out cases, and the
//! perceptibility of an inclusion against the discrimination threshold.
//!
//! # The problem
//! The block of the R_d calibration (100 × 100 × 50 mm, bottom clamped) is indented by the
//! scene's sphere pressed straight down at the origin. The inclusion's centre is at
//! (offset, 0, −centre depth): the problem is symmetric about y = 0 only, so half the block is
//! meshed ([`Symmetry::HalfY`]). Each element takes the modulus of the tissue mixed with the
//! inclusion's by the fraction of its volume inside the sphere (sampled at 35 points), so the
//! force changes smoothly as the inclusion moves between cells instead of jumping by a whole
//! element's stiffness; same ν inside and out. The law is the small-deformation linear one,
//! whose stiffness is factorised once per case: the table holds a ratio to the homogeneous
//! block on the same mesh, and the runtime multiplies its own (large-strain-corrected) model by
//! it, so what the FEM must get right is the inclusion's share, not the large-strain force.
//!
//! # What is written
//! [`build_table`] solves the homogeneous block once and every (ratio, radius, centre depth,
//! offset) case once over all the table's indentations, in parallel (one case per thread,
//! as `experiments` does), printing progress and timing, and returns the
//! [`InclusionTable`]. [`validate`] solves cases between the tabulated ones and holds the
//! runtime's interpolation (`softhaptic_device::inclusion`) against them. [`perceptibility`]
//! reads the contrast above the inclusion's centre from a table.

use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use softhaptic_device::inclusion::InclusionField;
use softhaptic_proto::{Inclusion, InclusionTable, Material, ToolShape};

use crate::element::{Constitutive, LawKind};
use crate::experiments::placed_indenter;
use crate::indenter::IndenterShape;
use crate::mesh::{self, BlockSpec, Symmetry};
use crate::solver::{ContactModel, SolveError, SolverOptions};

/// The contrast a trainee can tell apart: compliance discrimination's Weber fraction.
pub const DISCRIMINATION_THRESHOLD: f64 = 0.15;

/// Goal of the force's interpolation error against held-out FEM cases, percent of the FEM force.
pub const FORCE_GOAL_PERCENT: f64 = 5.0;

/// Goal of the contrast's interpolation error, percent of the FEM contrast.
pub const CONTRAST_GOAL_PERCENT: f64 = 10.0;

/// What a table covers and how finely the FEM resolves it.
#[derive(Debug, Clone, Serialize)]
pub struct InclusionStudy {
    pub tool: ToolShape,
    pub material: Material,
    pub block_m: [f64; 3],
    /// Cell edge of the uniform zone that holds the tool's contact and every inclusion.
    pub fine_cell_m: f64,
    /// Growing cells beyond the uniform zone, per axis.
    pub coarse_cells: usize,
    pub depths_m: Vec<f64>,
    pub offsets_m: Vec<f64>,
    pub centre_depths_m: Vec<f64>,
    pub radii_m: Vec<f64>,
    pub stiffness_ratios: Vec<f64>,
}

/// One inclusion case of the FEM.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Case {
    pub offset_m: f64,
    pub centre_depth_m: f64,
    pub radius_m: f64,
    pub stiffness_ratio: f64,
}

/// Why a study failed.
#[derive(Debug, thiserror::Error)]
pub enum InclusionError {
    #[error("mesh: {0}")]
    Mesh(#[from] mesh::MeshError),
    #[error("FEM case {case:?}: {source}")]
    Solve {
        case: Option<Case>,
        #[source]
        source: SolveError,
    },
    #[error("table refused: {0}")]
    Table(#[from] softhaptic_proto::InclusionTableError),
    #[error("{0}")]
    Field(String),
}

impl InclusionStudy {
    fn mesh(&self) -> Result<mesh::TetMesh, InclusionError> {
        let reach = |axis: &[f64]| axis.last().copied().unwrap_or(0.0);
        let r = reach(&self.radii_m);
        let contact = self
            .tool
            .radius_m()
            .min((self.tool.radius_m() * reach(&self.depths_m)).sqrt());
        let spec = BlockSpec {
            size_m: self.block_m,
            fine_cell_m: self.fine_cell_m,
            fine_radius_m: (reach(&self.offsets_m) + r).max(1.5 * contact),
            fine_depth_m: (reach(&self.centre_depths_m) + r).max(contact),
            coarse_cells_lateral: self.coarse_cells,
            coarse_cells_depth: self.coarse_cells,
            symmetry: Symmetry::HalfY,
        };
        Ok(mesh::block(&spec)?)
    }

    /// The FEM's normal force at each of the study's indentations, with `case`'s inclusion (or
    /// none), N.
    pub fn forces_n(&self, case: Option<Case>) -> Result<Vec<f64>, InclusionError> {
        let failed = |source| InclusionError::Solve { case, source };
        let law = Constitutive::new(LawKind::LinearSmallDeformation, &self.material);
        let mut model =
            ContactModel::new(self.mesh()?, law, SolverOptions::default()).map_err(failed)?;
        if let Some(c) = case {
            model = model.with_element_moduli(|corners| {
                1.0 + (c.stiffness_ratio - 1.0) * fraction_inside(corners, c)
            });
        }
        let shape = IndenterShape::from(&self.tool);
        let place = move |d: f64| placed_indenter(shape, d, 0.0);
        let eqs = model
            .follow(&place, 0.0, &self.depths_m, |_, _, _, _| {})
            .map_err(failed)?;
        Ok(eqs.iter().map(|e| e.force_on_tool_n[2]).collect())
    }

    /// Every inclusion case of the table, in its row-major order (ratio, radius, centre depth,
    /// offset).
    pub fn cases(&self) -> Vec<Case> {
        let mut out = Vec::new();
        for &stiffness_ratio in &self.stiffness_ratios {
            for &radius_m in &self.radii_m {
                for &centre_depth_m in &self.centre_depths_m {
                    for &offset_m in &self.offsets_m {
                        out.push(Case {
                            offset_m,
                            centre_depth_m,
                            radius_m,
                            stiffness_ratio,
                        });
                    }
                }
            }
        }
        out
    }
}

/// Fraction of the tetrahedron with these corners inside the case's sphere, from the 35 points
/// of the tetrahedron's order-4 barycentric lattice (corners, edges, faces and interior).
fn fraction_inside(corners: [[f64; 3]; 4], c: Case) -> f64 {
    const N: usize = 4;
    let centre = [c.offset_m, 0.0, -c.centre_depth_m];
    let (mut inside, mut total) = (0usize, 0usize);
    for i in 0..=N {
        for j in 0..=N - i {
            for k in 0..=N - i - j {
                let l = N - i - j - k;
                let w = [i, j, k, l].map(|v| v as f64 / N as f64);
                let mut d2 = 0.0;
                for a in 0..3 {
                    let x: f64 = (0..4).map(|q| w[q] * corners[q][a]).sum();
                    d2 += (x - centre[a]) * (x - centre[a]);
                }
                total += 1;
                if d2 <= c.radius_m * c.radius_m {
                    inside += 1;
                }
            }
        }
    }
    inside as f64 / total as f64
}

/// Solves `jobs` on `threads` threads, one job per thread at a time, with a progress bar that
/// ends with the wall time.
fn solve_all<T: Send>(
    label: &str,
    jobs: usize,
    threads: usize,
    solve: impl Fn(usize) -> Result<T, InclusionError> + Sync,
) -> Result<Vec<T>, InclusionError> {
    let bar = ProgressBar::new(jobs as u64);
    if let Ok(style) = ProgressStyle::with_template(
        "{msg:28} [{bar:30}] {pos}/{len} {elapsed_precise} (eta {eta})",
    ) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.set_message(label.to_owned());
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<Result<T, InclusionError>>>> =
        Mutex::new((0..jobs).map(|_| None).collect());
    let start = Instant::now();
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= jobs {
                        break;
                    }
                    let r = solve(i);
                    if let Ok(mut all) = results.lock() {
                        all[i] = Some(r);
                    }
                    bar.inc(1);
                    if bar.is_hidden() {
                        // Not a terminal (a log, CI): a line per case instead of the bar.
                        tracing::info!(
                            label,
                            done = bar.position(),
                            of = jobs,
                            elapsed_s = start.elapsed().as_secs_f64(),
                            "FEM case solved"
                        );
                    }
                }
            });
        }
    });
    bar.finish_with_message(format!(
        "{label}: {jobs} FEM cases in {:.1} s",
        start.elapsed().as_secs_f64()
    ));
    let all = results
        .into_inner()
        .map_err(|_| InclusionError::Field("a solver thread panicked".into()))?;
    all.into_iter()
        .map(|r| r.unwrap_or_else(|| Err(InclusionError::Field("a case was not solved".into()))))
        .collect()
}

/// The force-ratio table of `study` (module docs).
pub fn build_table(
    study: &InclusionStudy,
    threads: usize,
) -> Result<InclusionTable, InclusionError> {
    let cases = study.cases();
    // Job 0 is the homogeneous block, the rest the cases.
    let forces = solve_all("inclusion table", cases.len() + 1, threads, |i| {
        study.forces_n(if i == 0 { None } else { Some(cases[i - 1]) })
    })?;
    let homogeneous = &forces[0];
    let mut values = Vec::with_capacity(cases.len() * study.depths_m.len());
    for with in &forces[1..] {
        values.extend(with.iter().zip(homogeneous).map(|(w, h)| w / h));
    }
    Ok(InclusionTable::new(
        format!(
            "force with a stiffer sphere inside over the homogeneous block's, small-deformation linear FEM, {} sphere tool, E = {} Pa, nu = {}, block {:?} m, {} m cells",
            study.tool.radius_m(),
            study.material.youngs_modulus_pa(),
            study.material.poisson_ratio(),
            study.block_m,
            study.fine_cell_m
        ),
        study.tool,
        study.material,
        study.block_m,
        study.depths_m.clone(),
        study.offsets_m.clone(),
        study.centre_depths_m.clone(),
        study.radii_m.clone(),
        study.stiffness_ratios.clone(),
        values,
    )?)
}

/// One held-out case against the runtime's interpolation.
#[derive(Debug, Clone, Serialize)]
pub struct HeldOut {
    pub case: Case,
    pub depths_m: Vec<f64>,
    pub fem_force_n: Vec<f64>,
    /// The homogeneous block's FEM force times the interpolated ratio.
    pub runtime_force_n: Vec<f64>,
    /// |runtime − FEM| / FEM, percent, per depth.
    pub force_error_percent: Vec<f64>,
    /// FEM contrast F/F_homogeneous − 1 and the interpolated one, per depth.
    pub fem_contrast: Vec<f64>,
    pub runtime_contrast: Vec<f64>,
}

impl HeldOut {
    pub fn max_force_error_percent(&self) -> f64 {
        self.force_error_percent.iter().copied().fold(0.0, f64::max)
    }

    /// Largest contrast error, percent of the FEM's contrast, over the depths where the FEM's
    /// contrast is at least `min_contrast` (below it the contrast is imperceptible and its
    /// relative error meaningless).
    pub fn max_contrast_error_percent(&self, min_contrast: f64) -> f64 {
        self.fem_contrast
            .iter()
            .zip(&self.runtime_contrast)
            .filter(|(f, _)| f.abs() >= min_contrast)
            .map(|(f, r)| 100.0 * (r - f).abs() / f.abs())
            .fold(0.0, f64::max)
    }
}

/// Solves `cases` (between the table's values) and holds the table's interpolation against
/// them at the table's own indentations.
pub fn validate(
    study: &InclusionStudy,
    table: &InclusionTable,
    cases: &[Case],
    threads: usize,
) -> Result<Vec<HeldOut>, InclusionError> {
    let forces = solve_all("held-out cases", cases.len() + 1, threads, |i| {
        study.forces_n(if i == 0 { None } else { Some(cases[i - 1]) })
    })?;
    let homogeneous = &forces[0];
    cases
        .iter()
        .zip(&forces[1..])
        .map(|(case, fem)| {
            let inclusion = Inclusion {
                centre_in_object_m: [case.offset_m, -case.centre_depth_m, 0.0],
                radius_m: case.radius_m,
                stiffness_ratio: case.stiffness_ratio,
                centre_depth_m: case.centre_depth_m,
            };
            let field =
                InclusionField::new(table.clone(), &[inclusion]).map_err(InclusionError::Field)?;
            let mut held = HeldOut {
                case: *case,
                depths_m: study.depths_m.clone(),
                fem_force_n: fem.clone(),
                runtime_force_n: Vec::new(),
                force_error_percent: Vec::new(),
                fem_contrast: Vec::new(),
                runtime_contrast: Vec::new(),
            };
            for (k, &depth) in study.depths_m.iter().enumerate() {
                let (ratio, _) = field.single(0, depth, case.offset_m, case.centre_depth_m);
                let runtime = ratio * homogeneous[k];
                held.runtime_force_n.push(runtime);
                held.force_error_percent
                    .push(100.0 * (runtime - fem[k]).abs() / fem[k].abs());
                held.fem_contrast.push(fem[k] / homogeneous[k] - 1.0);
                held.runtime_contrast.push(ratio - 1.0);
            }
            Ok(held)
        })
        .collect()
}

/// Contrast above the centre (offset 0) of an inclusion of the table's first radius, at
/// indentation `depth_m`: rows the table's centre depths, columns its ratios.
pub fn perceptibility(
    table: &InclusionTable,
    depth_m: f64,
) -> Result<Vec<Vec<f64>>, InclusionError> {
    let mut rows = Vec::new();
    for &centre in table.centre_depths_m() {
        let mut row = Vec::new();
        for &ratio in table.stiffness_ratios() {
            let inclusion = Inclusion {
                centre_in_object_m: [0.0, -centre, 0.0],
                radius_m: table.radii_m()[0],
                stiffness_ratio: ratio,
                centre_depth_m: centre,
            };
            let field =
                InclusionField::new(table.clone(), &[inclusion]).map_err(InclusionError::Field)?;
            row.push(field.single(0, depth_m, 0.0, centre).0 - 1.0);
        }
        rows.push(row);
    }
    Ok(rows)
}

/// The study the scenes' table comes from (`softhaptic-calibrate inclusion`): the default
/// scene's 10 mm sphere on 50 kPa tissue, inclusions of 5 mm radius 8 to 16 mm deep, ratios 2
/// to 8, in the R_d calibration's block. `quick` is a coarse mesh for checking the command.
pub fn scene_study(quick: bool) -> InclusionStudy {
    const MM: f64 = 1e-3;
    let mm = |v: &[f64]| v.iter().map(|x| x * MM).collect::<Vec<f64>>();
    InclusionStudy {
        tool: ToolShape::Sphere { radius_m: 0.01 },
        material: Material::PAPER_SOFT,
        block_m: [0.1, 0.1, 0.05],
        fine_cell_m: if quick { 4.0 * MM } else { 3.0 * MM },
        coarse_cells: if quick { 2 } else { 4 },
        depths_m: mm(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]),
        offsets_m: mm(&[0.0, 3.0, 6.0, 9.0, 12.0, 16.0, 22.0]),
        // Every 2 mm: the contrast decays about as 1/d³, and rows 4 mm apart left the
        // interpolation 19 % off the FEM's contrast between them.
        centre_depths_m: mm(&[8.0, 10.0, 12.0, 14.0, 16.0]),
        radii_m: mm(&[5.0]),
        stiffness_ratios: vec![2.0, 4.0, 8.0],
    }
}

/// Cases between the scene study's tabulated values: offsets, centre depths and ratios none of
/// which is on the grid, and the centre with ratios between the grid's.
pub fn held_out_cases() -> Vec<Case> {
    const MM: f64 = 1e-3;
    let case = |offset: f64, centre: f64, ratio: f64| Case {
        offset_m: offset * MM,
        centre_depth_m: centre * MM,
        radius_m: 5.0 * MM,
        stiffness_ratio: ratio,
    };
    vec![
        case(0.0, 9.0, 3.0),
        case(0.0, 13.0, 5.5),
        case(4.5, 11.0, 3.0),
        case(4.5, 9.0, 5.5),
        case(7.5, 15.0, 6.0),
        case(10.5, 11.0, 2.8),
    ]
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    const MM: f64 = 1e-3;

    /// A coarse study: seconds, not minutes; its numbers check behaviour, not accuracy.
    fn coarse() -> InclusionStudy {
        InclusionStudy {
            tool: ToolShape::sphere(0.01).unwrap(),
            material: Material::PAPER_SOFT,
            block_m: [0.06, 0.06, 0.03],
            fine_cell_m: 4.0 * MM,
            coarse_cells: 2,
            depths_m: vec![1.0 * MM, 3.0 * MM],
            offsets_m: vec![0.0, 8.0 * MM, 16.0 * MM],
            centre_depths_m: vec![8.0 * MM],
            radii_m: vec![5.0 * MM],
            stiffness_ratios: vec![2.0, 6.0],
        }
    }

    #[test]
    fn the_fraction_inside_is_the_sphere_sampled() {
        let c = Case {
            offset_m: 0.0,
            centre_depth_m: 0.0,
            radius_m: 1.0,
            stiffness_ratio: 2.0,
        };
        let tet = |s: f64| [[0.0, 0.0, 0.0], [s, 0.0, 0.0], [0.0, s, 0.0], [0.0, 0.0, s]];
        assert_eq!(fraction_inside(tet(0.5), c), 1.0);
        assert_eq!(
            fraction_inside(tet(5.0).map(|p| p.map(|x| x + 3.0)), c),
            0.0
        );
        let part = fraction_inside(tet(1.5), c);
        assert!(part > 0.2 && part < 1.0, "{part}");
    }

    #[test]
    fn a_stiffer_inclusion_stiffens_the_contact_most_above_it_and_more_when_stiffer() {
        let study = coarse();
        let table = build_table(&study, 2).unwrap();
        // Above the centre: the stiffer inclusion raises the force, more when stiffer. (Not
        // necessarily more when pressed deeper: once the contact is wider than the inclusion,
        // a smaller share of the strained tissue is stiff.)
        let above = |k: usize, d: usize| table.at(k, 0, 0, 0, d);
        assert!(above(0, 1) > 1.02, "{}", above(0, 1));
        assert!(above(1, 1) > above(0, 1) && above(1, 0) > above(0, 0));
        // Far to the side it hardly matters.
        let far = table.at(1, 0, 0, 2, 1);
        assert!(far < above(1, 1) && (far - 1.0).abs() < 0.5 * (above(1, 1) - 1.0));
        // A held-out case between the offsets and ratios lies between its neighbours, and the
        // interpolation's error is reported per depth.
        let held = validate(
            &study,
            &table,
            &[Case {
                offset_m: 4.0 * MM,
                centre_depth_m: 8.0 * MM,
                radius_m: 5.0 * MM,
                stiffness_ratio: 3.5,
            }],
            2,
        )
        .unwrap();
        let h = &held[0];
        assert_eq!(h.force_error_percent.len(), 2);
        assert!(h.fem_contrast[1] > 0.0 && h.fem_contrast[1] < above(1, 1) - 1.0);
        assert!(h.max_force_error_percent().is_finite());
        let p = perceptibility(&table, 3.0 * MM).unwrap();
        assert!((p[0][1] - (above(1, 1) - 1.0)).abs() < 1e-12);
    }
}
