//! Curvature (paper §3.2, eq. 6): balls of radius R0 = 30, 50, 100 mm against the flat block,
//! and the curvature-corrected runtime models against the balls.
//!
//! The paper does not name the law of its curvature FEM; the reproduction of eq. 6 uses the
//! small-deformation linear FEM, the textbook problem its closed forms solve, with the
//! deformed-contact linear FEM and the neo-Hookean FEM beside it. The runtime models are scored
//! against every formulation: the linear FEMs (curvature, and curvature with the exact sphere),
//! and the neo-Hookean FEM, the project's reference for validity, which the neo-Hookean fit also
//! applies to.

use serde::Serialize;
use softhaptic_device::model::LocalGeometry;
use softhaptic_proto::{ModelSpec, ToolShape};

use super::rd::{rd_run, rd_setup};
use super::{
    ExperimentError, IndentationRun, JND_PERCENT, MATERIAL, MM, Mode, Resolution, RunCache,
    RunSpec, ball_body, depths, first_crossing, paper_tools_10mm, spec,
};
use crate::element::LawKind;
use crate::models::{ErrorCurve, RuntimeModel};

/// The formulations of the curvature study: the small-deformation linear FEM first (the
/// reproduction of eq. 6), then the deformed-contact linear FEM and the neo-Hookean one.
pub const CURVATURE_LAWS: [LawKind; 3] = [
    LawKind::LinearSmallDeformation,
    LawKind::LinearDeformedContact,
    LawKind::NeoHookean,
];

/// The balls' radii, metres.
pub const BALL_RADII_M: [f64; 3] = [0.03, 0.05, 0.1];

fn setup(mode: Mode) -> (Resolution, Vec<f64>) {
    match mode {
        Mode::Quick => (
            Resolution {
                name: "quick",
                fine_cell_m: 6.0 * MM,
                coarse_cells: 1,
            },
            depths(2.0, 10.0, 2.0),
        ),
        Mode::Full => (
            Resolution {
                name: "full",
                fine_cell_m: 2.5 * MM,
                coarse_cells: 4,
            },
            depths(1.0, 10.0, 1.0),
        ),
    }
}

fn ball_run(mode: Mode, name: &str, tool: &ToolShape, r0_m: f64, law: LawKind) -> RunSpec {
    let (res, ds) = setup(mode);
    let max_depth = ds.last().copied().unwrap_or(0.01);
    spec(
        format!("ball R0={:.0}mm {name} {}", r0_m / MM, law.name()),
        ball_body(r0_m, tool, max_depth, res),
        tool,
        law,
        res,
        &ds,
        0.0,
    )
}

/// The FEM runs: three balls per tool and law; the flat block is the R_d study's run.
pub fn curvature_runs(mode: Mode) -> Vec<RunSpec> {
    let mut out = Vec::new();
    for (name, tool) in paper_tools_10mm() {
        for law in CURVATURE_LAWS {
            out.push(rd_run(mode, name, &tool, law));
            for r0 in BALL_RADII_M {
                out.push(ball_run(mode, name, &tool, r0, law));
            }
        }
    }
    out
}

/// A runtime model scored against the three balls.
#[derive(Debug, Clone, Serialize)]
pub struct CurvatureModelScore {
    pub name: String,
    pub spec: ModelSpec,
    /// Per ball: forces at the study's depths with the ball's curvature 1/R0.
    pub forces_n: Vec<Vec<f64>>,
    /// Per ball: errors against the ball's FEM (eq. 9 form: over the ball's largest force).
    pub errors: Vec<ErrorCurve>,
    /// Per ball: depth where |eq. 9 error| first reaches 7%.
    pub crossing_m: Vec<Option<f64>>,
}

impl CurvatureModelScore {
    /// Largest |eq. 9 error| over every ball and depth, percent.
    pub fn worst_eq9_percent(&self) -> f64 {
        self.errors
            .iter()
            .map(ErrorCurve::max_eq9_percent)
            .fold(0.0, f64::max)
    }

    /// The shallowest crossing over the balls (`None` when no ball crosses).
    pub fn first_crossing_m(&self) -> Option<f64> {
        self.crossing_m
            .iter()
            .flatten()
            .copied()
            .fold(None, |m: Option<f64>, c| Some(m.map_or(c, |m| m.min(c))))
    }
}

/// One FEM law's part of the curvature study of one tool.
#[derive(Debug, Clone, Serialize)]
pub struct CurvatureLawStudy {
    pub law: LawKind,
    /// The flat block's run (shared with the R_d study) and its forces at the study's depths.
    pub block: IndentationRun,
    pub block_n: Vec<f64>,
    /// One run per ball radius.
    pub balls: Vec<IndentationRun>,
    /// e_f of eq. 6 in percent per ball: (F_s − F_c) / max(F_c).
    pub error_percent: Vec<Vec<f64>>,
    pub crossing_m: Vec<Option<f64>>,
    /// The runtime's curvature law relative to its flat law, normalised the same way (what
    /// docs/physics.md predicts for eq. 6).
    pub predicted_percent: Vec<Vec<f64>>,
    /// The runtime models against the balls.
    pub models: Vec<CurvatureModelScore>,
}

#[derive(Debug, Clone, Serialize)]
pub struct CurvatureStudy {
    pub tool_name: String,
    pub tool: ToolShape,
    pub depths_m: Vec<f64>,
    pub object_radii_m: Vec<f64>,
    /// In the order of [`CURVATURE_LAWS`]: small-deformation linear first (the paper's
    /// reproduction), then deformed-contact linear and neo-Hookean.
    pub laws: Vec<CurvatureLawStudy>,
}

/// The runtime models scored against balls of the given FEM law.
pub fn curvature_specs(tool: &ToolShape, law: LawKind) -> Vec<ModelSpec> {
    let base = ModelSpec::PAPER;
    let curved = ModelSpec {
        curvature: true,
        ..base
    };
    let mut specs = vec![base, curved];
    match (tool, law) {
        (ToolShape::Sphere { .. }, _) => {
            specs.push(ModelSpec {
                exact_sphere: true,
                ..curved
            });
            if law == LawKind::NeoHookean {
                specs.push(ModelSpec {
                    exact_sphere: true,
                    hyperelastic: true,
                    ..curved
                });
            }
        }
        (ToolShape::Cone { .. }, LawKind::NeoHookean) => specs.push(ModelSpec {
            hyperelastic: true,
            ..curved
        }),
        (ToolShape::Cone { .. }, _) => {}
    }
    specs
}

/// Paper §3.2: indentation of balls R0 = 30, 50, 100 mm against the 100 × 100 × 50 mm block,
/// sphere and cone of radius 10 mm, E = 50 kPa, ν = 0.33, linear and neo-Hookean FEM.
pub fn curvature(mode: Mode, cache: &RunCache) -> Result<Vec<CurvatureStudy>, ExperimentError> {
    let study = "curvature";
    let (_, ds) = setup(mode);
    let (_, block_depths) = rd_setup(mode);
    if !ds
        .iter()
        .all(|d| block_depths.iter().any(|b| (b - d).abs() < 1e-9))
    {
        return Err(ExperimentError::Data {
            study: study.to_owned(),
            reason: "the curvature depths are not among the block run's depths".to_owned(),
        });
    }
    let mut out = Vec::new();
    for (name, tool) in paper_tools_10mm() {
        let mut laws = Vec::new();
        for law in CURVATURE_LAWS {
            let block = cache.get(study, &rd_run(mode, name, &tool, law))?.clone();
            let block_n: Vec<f64> = ds.iter().map(|&d| block.normal_force_at_n(d)).collect();
            let f_max = block_n
                .iter()
                .copied()
                .fold(0.0_f64, f64::max)
                .max(f64::MIN_POSITIVE);
            let mut balls = Vec::new();
            for r0 in BALL_RADII_M {
                balls.push(
                    cache
                        .get(study, &ball_run(mode, name, &tool, r0, law))?
                        .clone(),
                );
            }
            let runtime = |spec: ModelSpec| {
                RuntimeModel::new(tool, MATERIAL, spec).map_err(|source| ExperimentError::Model {
                    run: format!("{study} {name}"),
                    source,
                })
            };
            let curved_geometry = |r0: f64| LocalGeometry {
                curvature_1_per_m: 1.0 / r0,
                inclination_rad: 0.0,
            };
            let flat_law = runtime(ModelSpec::PAPER)?.forces_n(&ds, &LocalGeometry::FLAT);
            let law_max = flat_law.iter().copied().fold(f64::MIN_POSITIVE, f64::max);
            let curvature_law = runtime(ModelSpec {
                curvature: true,
                ..ModelSpec::PAPER
            })?;
            let mut error_percent = Vec::new();
            let mut predicted_percent = Vec::new();
            let mut crossing_m = Vec::new();
            for (ball, &r0) in balls.iter().zip(&BALL_RADII_M) {
                let err: Vec<f64> = ball
                    .normal_forces_n()
                    .iter()
                    .zip(&block_n)
                    .map(|(s, c)| 100.0 * (s - c) / f_max)
                    .collect();
                crossing_m.push(first_crossing(&ds, &err, JND_PERCENT));
                error_percent.push(err);
                let curved = curvature_law.forces_n(&ds, &curved_geometry(r0));
                predicted_percent.push(
                    curved
                        .iter()
                        .zip(&flat_law)
                        .map(|(c, f)| 100.0 * (c - f) / law_max)
                        .collect(),
                );
            }
            let mut models = Vec::new();
            for spec in curvature_specs(&tool, law) {
                let m = runtime(spec)?;
                let mut forces_n = Vec::new();
                let mut errors = Vec::new();
                let mut crossings = Vec::new();
                for (ball, &r0) in balls.iter().zip(&BALL_RADII_M) {
                    let f = m.forces_n(&ds, &curved_geometry(r0));
                    let e = ErrorCurve::new(&f, &ball.normal_forces_n());
                    crossings.push(first_crossing(&ds, &e.eq9_percent, JND_PERCENT));
                    errors.push(e);
                    forces_n.push(f);
                }
                models.push(CurvatureModelScore {
                    name: m.name(),
                    spec,
                    forces_n,
                    errors,
                    crossing_m: crossings,
                });
            }
            laws.push(CurvatureLawStudy {
                law,
                block,
                block_n,
                balls,
                error_percent,
                crossing_m,
                predicted_percent,
                models,
            });
        }
        out.push(CurvatureStudy {
            tool_name: name.to_owned(),
            tool,
            depths_m: ds.clone(),
            object_radii_m: BALL_RADII_M.to_vec(),
            laws,
        });
    }
    Ok(out)
}
