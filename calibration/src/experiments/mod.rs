//! The paper's experiments (§3.2 curvature and inclination, §3.3.2 R_d calibration, §4.3 force
//! accuracy), the fit of the hyperelastic correction and the speed-versus-accuracy study.
//!
//! Long because it holds what every experiment shares (run specs, the run cache, meshes'
//! resolutions); each experiment is in its own file.
//!
//! Every experiment is two functions: one lists the FEM runs it needs ([`RunSpec`]s), the other
//! turns the finished runs into its figures. The command collects the runs of every experiment
//! it was asked for, drops duplicates (the curvature study's flat block is the R_d study's block;
//! the speed-accuracy study's finest meshes are the force study's), and solves them in parallel
//! on the machine's cores ([`RunCache::ensure`]), the longest first. Each run is one independent
//! static FEM problem, so runs are the natural unit of parallel work; the factorisation inside a
//! run stays sequential.
//!
//! Every experiment runs in one of two [`Mode`]s: `Full` uses the meshes the report quotes,
//! `Quick` coarse meshes and fewer samples so that the whole suite checks end to end in about a
//! minute (its numbers are not to be quoted).
//!
//! # Layout
//! - [`rd`]: δ → R_d tables (§3.3.2).
//! - [`surface`]: the surface the viewer draws against the FEM's top surface, on the R_d runs.
//! - [`force`]: force against depth (§4.3), the hyperelastic fit, the speed-accuracy table.
//! - [`curvature`](mod@curvature): balls against the block (§3.2, eq. 6), with the curvature-corrected models.
//! - [`inclination`](mod@inclination): tilted tools (§3.2, eq. 7), with the inclination-corrected cone.
//! - [`limits`]: the measured validity limits of every runtime model evaluated.
//! - [`poisson`]: the hyperelastic factor, the bonded-layer factor and the R_d tables over ν
//!   from 0.30 to 0.49.
//! - [`verification`](mod@verification): Hertz, the half-space profile and the patch tests, before the rest.

pub mod curvature;
pub mod force;
pub mod inclination;
pub mod limits;
pub mod poisson;
pub mod rd;
pub mod surface;
pub mod verification;

pub use curvature::{CurvatureStudy, curvature, curvature_runs};
pub use force::{
    ForceDepthStudy, HyperelasticFit, SpeedAccuracyStudy, force_depth, force_runs,
    hyperelastic_fit, speed_accuracy, speed_accuracy_runs,
};
pub use inclination::{InclinationStudy, inclination, inclination_runs};
pub use limits::model_limits;
pub use poisson::{PoissonStudy, poisson_runs, poisson_study};
pub use rd::{RdStudy, rd_runs, rd_table};
pub use verification::{VerificationStudy, verification, verification_runs};

use std::collections::HashMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Instant;

use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use serde::Serialize;
use softhaptic_device::law;
use softhaptic_proto::{Material, ToolShape};

use crate::element::{Constitutive, LawKind};
use crate::indenter::{Indenter, IndenterShape};
use crate::mesh::{self, BallSpec, BlockSpec, Symmetry, TetMesh};
use crate::solver::{ContactModel, SolveError, SolverOptions, SurfacePoint, deformed_radius_m};

pub(crate) const MM: f64 = 1e-3;

/// Just-noticeable difference of force magnitude the paper uses as its accuracy limit, percent.
pub const JND_PERCENT: f64 = 7.0;

/// Surface depression that bounds the deformed region (paper §3.3.2).
pub const RD_THRESHOLD_M: f64 = 0.5 * MM;

/// Depth below which the paper fits R_d(δ) with a line.
pub const RD_BREAKPOINT_M: f64 = 7.0 * MM;

/// The paper's calibration block (100 × 100 × 50 mm), also the curvature and inclination block.
pub const RD_BLOCK_M: [f64; 3] = [0.1, 0.1, 0.05];

/// The paper's §4.3 block (100 × 100 × 30 mm).
pub const FORCE_BLOCK_M: [f64; 3] = [0.1, 0.1, 0.03];

/// How thorough a run is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    Quick,
    Full,
}

/// Mesh density: the cell edge in the refined zone and the number of growing cells outside it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Resolution {
    pub name: &'static str,
    pub fine_cell_m: f64,
    pub coarse_cells: usize,
}

/// What a run indents.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Body {
    Block(BlockSpec),
    Ball(BallSpec),
}

/// One FEM indentation run, fully specified: a tool pressed step by step into one body.
#[derive(Debug, Clone, Serialize)]
pub struct RunSpec {
    /// Human-readable name (progress bars, report); not part of the identity.
    pub label: String,
    pub body: Body,
    pub indenter: IndenterShape,
    pub law: LawKind,
    pub material: Material,
    pub resolution: Resolution,
    /// Normal depth of the tool's lowest point at each load step, increasing.
    pub depths_m: Vec<f64>,
    /// Tilt of the tool axis from the surface normal, about the y axis.
    pub tilt_rad: f64,
}

impl RunSpec {
    /// Everything that determines the result: two specs with the same key are the same run.
    pub fn key(&self) -> String {
        serde_json::to_string(&(
            &self.body,
            &self.indenter,
            self.law,
            &self.material,
            &self.depths_m,
            self.tilt_rad,
        ))
        .unwrap_or_else(|_| self.label.clone())
    }

    fn mesh(&self) -> Result<TetMesh, ExperimentError> {
        match &self.body {
            Body::Block(spec) => mesh::block(spec),
            Body::Ball(spec) => mesh::quarter_ball(spec),
        }
        .map_err(|source| ExperimentError::Mesh {
            run: self.label.clone(),
            source,
        })
    }

    /// The model to indent, from the mesh of this spec.
    fn model(&self) -> Result<ContactModel, ExperimentError> {
        ContactModel::new(
            self.mesh()?,
            Constitutive::new(self.law, &self.material),
            SolverOptions::default(),
        )
        .map_err(|source| ExperimentError::Solve {
            run: self.label.clone(),
            source,
        })
    }
}

/// One indentation run: a tool pressed step by step into one object.
#[derive(Debug, Clone, Serialize)]
pub struct IndentationRun {
    pub label: String,
    pub law: LawKind,
    pub resolution: Resolution,
    pub dofs: usize,
    pub elements: usize,
    /// Stored entries of the Cholesky factor.
    pub factor_entries: usize,
    /// Normal depth of the tool's lowest point at each step.
    pub depths_m: Vec<f64>,
    /// Force of the body on the tool (FEM frame, +z out of the surface), per step.
    pub forces_n: Vec<[f64; 3]>,
    /// R_d at each step (radius where the depression exceeds [`RD_THRESHOLD_M`]).
    pub deformed_radius_m: Vec<f64>,
    /// Surface profile (reference radius, depression) at the last step.
    pub final_profile_m: Vec<(f64, f64)>,
    /// Top-surface motion along the profile line at each step (what the drawn surface is
    /// measured against).
    pub surfaces: Vec<Vec<SurfacePoint>>,
    /// Wall time of each load step's solve.
    pub step_seconds: Vec<f64>,
    pub newton_iterations: Vec<usize>,
    pub locked_nodes: Vec<usize>,
}

impl IndentationRun {
    /// Force along the surface normal (+z), N.
    pub fn normal_forces_n(&self) -> Vec<f64> {
        self.forces_n.iter().map(|f| f[2]).collect()
    }

    /// Normal force at `depth_m`, which must be one of the run's depths (within 1 nm); NaN
    /// otherwise.
    pub fn normal_force_at_n(&self, depth_m: f64) -> f64 {
        self.depths_m
            .iter()
            .position(|&d| (d - depth_m).abs() < 1e-9)
            .map(|i| self.forces_n[i][2])
            .unwrap_or(f64::NAN)
    }

    /// Median wall time of one load step, seconds.
    pub fn median_step_seconds(&self) -> f64 {
        median(&self.step_seconds)
    }
}

/// Errors of the experiments: a failed solve, with the run that failed.
#[derive(Debug, thiserror::Error)]
pub enum ExperimentError {
    #[error("{run}: {source}")]
    Solve {
        run: String,
        #[source]
        source: SolveError,
    },
    #[error("{run}: {source}")]
    Mesh {
        run: String,
        #[source]
        source: mesh::MeshError,
    },
    #[error("{run}: calibration table refused: {source}")]
    Table {
        run: String,
        #[source]
        source: softhaptic_proto::CalibrationError,
    },
    #[error("{run}: runtime model refused: {source}")]
    Model {
        run: String,
        #[source]
        source: softhaptic_proto::ModelError,
    },
    #[error("{study}: the FEM run {run:?} was not solved before the study read it")]
    MissingRun { study: String, run: String },
    #[error("{study}: {reason}")]
    Data { study: String, reason: String },
}

/// Median of `values` (NaN when empty).
pub fn median(values: &[f64]) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| !x.is_nan()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn bar_style() -> Option<ProgressStyle> {
    ProgressStyle::with_template("{spinner} {msg:48} [{bar:30}] {pos}/{len} {elapsed_precise}")
        .ok()
        .map(|s| s.progress_chars("=> "))
}

/// Largest contact radius a tool reaches at `depth_m` (capped by the tool's own radius).
pub fn max_contact_radius_m(tool: &ToolShape, depth_m: f64) -> f64 {
    law::contact_radius_m(tool, depth_m).min(tool.radius_m())
}

/// Where the tool is for a given normal depth of its lowest point, tilted by `tilt_rad` about
/// the y axis (0 = pressing straight down); the tool travels along its own axis.
pub fn placed_indenter(shape: IndenterShape, depth_m: f64, tilt_rad: f64) -> Indenter {
    let (s, c) = tilt_rad.sin_cos();
    let axis = [s, 0.0, c];
    let lateral = -depth_m * tilt_rad.tan();
    match shape {
        IndenterShape::Sphere { radius_m } | IndenterShape::Paraboloid { radius_m } => {
            // Lowest point of the sphere at (lateral, 0, −δ); the tip (on the axis) follows.
            let centre = [lateral, 0.0, radius_m - depth_m];
            Indenter {
                shape,
                tip_m: [
                    centre[0] - radius_m * axis[0],
                    centre[1] - radius_m * axis[1],
                    centre[2] - radius_m * axis[2],
                ],
                axis,
            }
        }
        IndenterShape::Cone { .. } => Indenter {
            shape,
            tip_m: [lateral, 0.0, -depth_m],
            axis,
        },
    }
}

/// Solves one run, step by step along its depths, reporting progress on `pb`.
pub fn run_indentation(
    spec: &RunSpec,
    pb: &ProgressBar,
) -> Result<IndentationRun, ExperimentError> {
    let mut model = spec.model()?;
    let elements = model.mesh().elements.len();
    let shape = spec.indenter;
    let tilt_rad = spec.tilt_rad;
    let mut deformed = Vec::with_capacity(spec.depths_m.len());
    let mut surfaces = Vec::with_capacity(spec.depths_m.len());
    let mut step_seconds = Vec::with_capacity(spec.depths_m.len());
    let mut clock = Instant::now();
    let place = move |d: f64| placed_indenter(shape, d, tilt_rad);
    let eqs = model
        .follow(&place, 0.0, &spec.depths_m, |_, _, _, m| {
            step_seconds.push(clock.elapsed().as_secs_f64());
            let surface = m.surface_motion();
            let profile: Vec<(f64, f64)> = surface
                .iter()
                .map(|p| (p.radius_m, p.depression_m))
                .collect();
            deformed.push(deformed_radius_m(&profile, RD_THRESHOLD_M));
            surfaces.push(surface);
            pb.inc(1);
            clock = Instant::now();
        })
        .map_err(|source| ExperimentError::Solve {
            run: spec.label.clone(),
            source,
        })?;
    Ok(IndentationRun {
        label: spec.label.clone(),
        law: spec.law,
        resolution: spec.resolution,
        dofs: model.dof_count(),
        elements,
        factor_entries: model.factor_entries(),
        depths_m: spec.depths_m.clone(),
        forces_n: eqs.iter().map(|e| e.force_on_tool_n).collect(),
        deformed_radius_m: deformed,
        final_profile_m: model.surface_profile(),
        surfaces,
        step_seconds,
        newton_iterations: eqs.iter().map(|e| e.iterations).collect(),
        locked_nodes: eqs.iter().map(|e| e.locked_nodes).collect(),
    })
}

/// The spec of a graded quarter (or half) block for `tool` reaching `max_depth_m`, widened by
/// `extra_radius_m` (a tilted tool slides sideways).
pub fn block_body(
    size_m: [f64; 3],
    tool: &ToolShape,
    max_depth_m: f64,
    extra_radius_m: f64,
    resolution: Resolution,
    symmetry: Symmetry,
) -> Body {
    let a = max_contact_radius_m(tool, max_depth_m) + extra_radius_m;
    Body::Block(BlockSpec::graded(
        size_m,
        a,
        resolution.fine_cell_m,
        resolution.coarse_cells,
        symmetry,
    ))
}

/// Depths from `from_mm` to `to_mm` in steps of `step_mm`, metres.
pub fn depths(from_mm: f64, to_mm: f64, step_mm: f64) -> Vec<f64> {
    let n = ((to_mm - from_mm) / step_mm).round() as usize;
    (0..=n)
        .map(|i| (from_mm + i as f64 * step_mm) * MM)
        .collect()
}

/// Depth at which |error| first reaches `limit`, linearly interpolated; `None` if it never does.
pub fn first_crossing(depths_m: &[f64], errors: &[f64], limit: f64) -> Option<f64> {
    let mut prev: Option<(f64, f64)> = None;
    for (&d, &e) in depths_m.iter().zip(errors) {
        let e = e.abs();
        if e >= limit {
            return Some(match prev {
                Some((d0, e0)) if e > e0 => d0 + (d - d0) * (limit - e0) / (e - e0),
                _ => d,
            });
        }
        prev = Some((d, e));
    }
    None
}

/// Human-readable tool description.
pub fn tool_description(tool: &ToolShape) -> String {
    match *tool {
        ToolShape::Sphere { radius_m } => format!("sphere of radius {:.1} mm", radius_m / MM),
        ToolShape::Cone {
            half_angle_rad,
            radius_m,
        } => format!(
            "cone of half-angle {:.0}° and base radius {:.1} mm",
            half_angle_rad.to_degrees(),
            radius_m / MM
        ),
    }
}

/// The §4.3 tools: sphere R = 6 mm and a 45° cone of base radius 6 mm; the deep-block check of
/// the verification and the ν study press the same two.
pub fn force_tools() -> [(&'static str, ToolShape); 2] {
    [
        ("sphere6", ToolShape::Sphere { radius_m: 0.006 }),
        (
            "cone6_45",
            ToolShape::Cone {
                half_angle_rad: std::f64::consts::FRAC_PI_4,
                radius_m: 0.006,
            },
        ),
    ]
}

/// The paper's tools of radius 10 mm: a sphere and a 45° cone.
pub fn paper_tools_10mm() -> [(&'static str, ToolShape); 2] {
    [
        ("sphere10", ToolShape::Sphere { radius_m: 0.01 }),
        (
            "cone10_45",
            ToolShape::Cone {
                half_angle_rad: std::f64::consts::FRAC_PI_4,
                radius_m: 0.01,
            },
        ),
    ]
}

/// Wall and compute time of the FEM runs solved by a [`RunCache`].
#[derive(Debug, Clone, Default, Serialize)]
pub struct RunTimings {
    /// Runs solved.
    pub runs: usize,
    /// Runs asked for more than once (solved once).
    pub shared: usize,
    /// Worker threads.
    pub threads: usize,
    /// Wall time of the parallel stage, seconds.
    pub wall_seconds: f64,
    /// Sum of the runs' own times, seconds.
    pub run_seconds: f64,
}

/// FEM runs solved once and shared by every experiment that needs them.
pub struct RunCache {
    runs: HashMap<String, IndentationRun>,
    threads: usize,
    timings: RunTimings,
}

impl RunCache {
    /// A cache that solves with `threads` worker threads (at least one).
    pub fn new(threads: usize) -> Self {
        let threads = threads.max(1);
        RunCache {
            runs: HashMap::new(),
            threads,
            timings: RunTimings {
                threads,
                ..RunTimings::default()
            },
        }
    }

    pub fn timings(&self) -> &RunTimings {
        &self.timings
    }

    /// The finished run of `spec`.
    pub fn get(&self, study: &str, spec: &RunSpec) -> Result<&IndentationRun, ExperimentError> {
        self.runs
            .get(&spec.key())
            .ok_or_else(|| ExperimentError::MissingRun {
                study: study.to_owned(),
                run: spec.label.clone(),
            })
    }

    /// Solves every run of `specs` not solved yet, each once, in parallel on the cache's
    /// threads. The longest runs start first (their cost is estimated from the unknowns and the
    /// load steps), which keeps the threads busy to the end. The first failure stops the
    /// remaining runs and is returned.
    pub fn ensure(&mut self, specs: &[RunSpec]) -> Result<(), ExperimentError> {
        let mut pending: Vec<(String, &RunSpec, f64)> = Vec::new();
        for spec in specs {
            let key = spec.key();
            if self.runs.contains_key(&key) || pending.iter().any(|(k, _, _)| *k == key) {
                self.timings.shared += 1;
                continue;
            }
            // Factorisation work of a 3D mesh grows about as the square of its unknowns. The
            // neo-Hookean tangent is factorised in every Newton iteration, the linear laws'
            // stiffness once per run: a neo-Hookean run takes four to seven times as long as a
            // linear one on the same mesh (§4.3 sphere block, one thread: 14.9 s against 2.1 s).
            let nodes = spec.mesh()?.node_count() as f64;
            let neo = if spec.law == LawKind::NeoHookean {
                5.0
            } else {
                1.0
            };
            let cost = nodes * nodes * spec.depths_m.len() as f64 * neo;
            pending.push((key, spec, cost));
        }
        if pending.is_empty() {
            return Ok(());
        }
        pending.sort_by(|a, b| b.2.total_cmp(&a.2));
        let multi = MultiProgress::new();
        let overall = multi.add(ProgressBar::new(pending.len() as u64));
        if let Some(style) = bar_style() {
            overall.set_style(style);
        }
        overall.set_message(format!("FEM runs on {} threads", self.threads));
        let next = AtomicUsize::new(0);
        let failed = AtomicBool::new(false);
        let results: Mutex<Vec<(usize, Result<IndentationRun, ExperimentError>)>> =
            Mutex::new(Vec::new());
        let start = Instant::now();
        std::thread::scope(|scope| {
            for _ in 0..self.threads.min(pending.len()) {
                let worker = || {
                    loop {
                        if failed.load(Ordering::Relaxed) {
                            break;
                        }
                        let i = next.fetch_add(1, Ordering::Relaxed);
                        let Some((_, spec, _)) = pending.get(i) else {
                            break;
                        };
                        let pb = multi.add(ProgressBar::new(spec.depths_m.len() as u64));
                        if let Some(style) = bar_style() {
                            pb.set_style(style);
                        }
                        pb.set_message(spec.label.clone());
                        let result = run_indentation(spec, &pb);
                        pb.finish_and_clear();
                        multi.remove(&pb);
                        overall.inc(1);
                        if result.is_err() {
                            failed.store(true, Ordering::Relaxed);
                        }
                        if let Ok(mut r) = results.lock() {
                            r.push((i, result));
                        }
                    }
                };
                // The solver keeps its element matrices on the stack; give the workers room. A
                // worker that cannot be spawned leaves the queue to the others (or, if none
                // started, to the main thread below).
                let _spawned = std::thread::Builder::new()
                    .stack_size(16 << 20)
                    .spawn_scoped(scope, worker);
            }
        });
        overall.finish_and_clear();
        let mut results = results.into_inner().unwrap_or_default();
        // Runs no worker took (threads could not be spawned) are solved here, in order.
        let taken: Vec<usize> = results.iter().map(|(i, _)| *i).collect();
        if !failed.load(Ordering::Relaxed) {
            for (i, (_, spec, _)) in pending.iter().enumerate() {
                if !taken.contains(&i) {
                    let pb = ProgressBar::hidden();
                    results.push((i, run_indentation(spec, &pb)));
                }
            }
        }
        self.timings.wall_seconds += start.elapsed().as_secs_f64();
        results.sort_by_key(|(i, _)| *i);
        for (i, result) in results {
            let run = result?;
            self.timings.runs += 1;
            self.timings.run_seconds += run.step_seconds.iter().sum::<f64>();
            self.runs.insert(pending[i].0.clone(), run);
        }
        Ok(())
    }
}

/// The same material as the paper's experiments: E = 50 kPa, ν = 0.33.
pub const MATERIAL: Material = Material::PAPER_SOFT;

/// A vertical (or tilted) indentation spec of `tool` into `body`.
#[allow(clippy::too_many_arguments)] // Each argument is one axis of the experiment grid.
pub fn spec(
    label: String,
    body: Body,
    tool: &ToolShape,
    law: LawKind,
    resolution: Resolution,
    depths_m: &[f64],
    tilt_rad: f64,
) -> RunSpec {
    RunSpec {
        label,
        body,
        indenter: IndenterShape::from(tool),
        law,
        material: MATERIAL,
        resolution,
        depths_m: depths_m.to_vec(),
        tilt_rad,
    }
}

/// The quarter ball of radius `r0` meshed for `tool` reaching `max_depth_m`.
pub fn ball_body(r0_m: f64, tool: &ToolShape, max_depth_m: f64, resolution: Resolution) -> Body {
    let a = max_contact_radius_m(tool, max_depth_m);
    Body::Ball(BallSpec {
        radius_m: r0_m,
        fine_cell_m: resolution.fine_cell_m,
        fine_radius_m: (1.5 * a).min(0.6 * r0_m),
        coarse_cells: resolution.coarse_cells + 1,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn crossing_is_interpolated_and_none_when_never_reached() {
        let d = [1.0, 2.0, 3.0];
        assert_eq!(first_crossing(&d, &[1.0, 5.0, 9.0], 7.0), Some(2.5));
        assert_eq!(first_crossing(&d, &[8.0, 9.0, 9.0], 7.0), Some(1.0));
        assert_eq!(
            first_crossing(&d, &[1.0, -8.0, 0.0], 7.0).unwrap(),
            1.0 + 6.0 / 7.0
        );
        assert_eq!(first_crossing(&d, &[1.0, 2.0, 3.0], 7.0), None);
        assert!((median(&[3.0, 1.0, 2.0]) - 2.0).abs() < 1e-15);
        assert!((median(&[4.0, 1.0, 2.0, 3.0]) - 2.5).abs() < 1e-15);
        assert!(median(&[]).is_nan());
    }

    #[test]
    fn identical_runs_share_a_key_and_labels_do_not_matter() {
        let tool = ToolShape::Sphere { radius_m: 0.01 };
        let res = Resolution {
            name: "t",
            fine_cell_m: 0.006,
            coarse_cells: 1,
        };
        let body = block_body(RD_BLOCK_M, &tool, 0.004, 0.0, res, Symmetry::Quarter);
        let a = spec(
            "a".into(),
            body,
            &tool,
            LawKind::LinearDeformedContact,
            res,
            &[0.002],
            0.0,
        );
        let b = spec(
            "b".into(),
            body,
            &tool,
            LawKind::LinearDeformedContact,
            res,
            &[0.002],
            0.0,
        );
        let c = spec(
            "c".into(),
            body,
            &tool,
            LawKind::NeoHookean,
            res,
            &[0.002],
            0.0,
        );
        assert_eq!(a.key(), b.key());
        assert_ne!(a.key(), c.key());
        let mut cache = RunCache::new(2);
        cache.ensure(&[a.clone(), b.clone(), c.clone()]).unwrap();
        assert_eq!(cache.timings().runs, 2);
        assert_eq!(cache.timings().shared, 1);
        let ra = cache.get("test", &a).unwrap();
        let rc = cache.get("test", &c).unwrap();
        // Same small-strain limit: the two laws agree to a few percent at δ = 0.2 R.
        assert!((ra.forces_n[0][2] / rc.forces_n[0][2] - 1.0).abs() < 0.05);
        let other = spec(
            "d".into(),
            body,
            &tool,
            LawKind::LinearDeformedContact,
            res,
            &[0.003],
            0.0,
        );
        assert!(matches!(
            cache.get("test", &other),
            Err(ExperimentError::MissingRun { .. })
        ));
    }
}
