//! Verification of the FEM before the experiments: Hertz on a large block, the surface profile
//! against the half-space, and the patch tests.

use serde::Serialize;
use softhaptic_device::law;
use softhaptic_device::model::LocalGeometry;
use softhaptic_proto::{ModelSpec, ToolShape};

use super::{Body, ExperimentError, MATERIAL, MM, Mode, Resolution, RunCache, RunSpec};
use crate::element::{Constitutive, LawKind};
use crate::indenter::IndenterShape;
use crate::mesh::{self, BlockSpec, Symmetry};
use crate::models::{RuntimeModel, layer};
use crate::solver::{ContactModel, SolveError, SolverOptions};

/// One verification figure.
#[derive(Debug, Clone, Serialize)]
pub struct HertzCheck {
    pub indenter: String,
    pub fine_cell_m: f64,
    pub dofs: usize,
    pub fem_n: f64,
    pub hertz_n: f64,
    /// FEM / Hertz − 1, percent.
    pub error_vs_hertz_percent: f64,
    /// FEM against the runtime's law corrected for the block depth (bonded layer) and, for the
    /// sphere, for the exact sphere shape, percent.
    pub error_vs_corrected_percent: f64,
    /// Largest |FEM − half-space| surface depression for a < r < 4a, relative to δ, percent.
    pub profile_error_percent: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct VerificationStudy {
    pub depth_over_radius: f64,
    pub block_over_radius: f64,
    pub checks: Vec<HertzCheck>,
    /// Largest nodal error of the patch test relative to the largest displacement, per law.
    pub patch_test: Vec<(LawKind, f64)>,
}

const RADIUS_M: f64 = 0.01;
const DEPTH_OVER_RADIUS: f64 = 0.2;
const BLOCK_OVER_RADIUS: f64 = 20.0;

fn cells(mode: Mode) -> &'static [f64] {
    match mode {
        Mode::Quick => &[5.0 * MM, 3.0 * MM],
        Mode::Full => &[2.0 * MM, 1.25 * MM],
    }
}

fn shapes() -> [(&'static str, IndenterShape); 2] {
    [
        ("sphere", IndenterShape::Sphere { radius_m: RADIUS_M }),
        (
            "paraboloid",
            IndenterShape::Paraboloid { radius_m: RADIUS_M },
        ),
    ]
}

fn check_run(cell_m: f64, name: &str, shape: IndenterShape) -> RunSpec {
    let depth = DEPTH_OVER_RADIUS * RADIUS_M;
    let a = (RADIUS_M * depth).sqrt();
    let size = BLOCK_OVER_RADIUS * RADIUS_M;
    RunSpec {
        label: format!("verification {name} {:.2} mm cells", cell_m / MM),
        body: Body::Block(BlockSpec::graded(
            [size, size, size],
            a,
            cell_m,
            5,
            Symmetry::Quarter,
        )),
        indenter: shape,
        law: LawKind::Linear,
        material: MATERIAL,
        resolution: Resolution {
            name: "verification",
            fine_cell_m: cell_m,
            coarse_cells: 5,
        },
        depths_m: vec![depth],
        tilt_rad: 0.0,
    }
}

/// The runs: sphere and paraboloid, two mesh sizes.
pub fn verification_runs(mode: Mode) -> Vec<RunSpec> {
    let mut out = Vec::new();
    for &cell in cells(mode) {
        for (name, shape) in shapes() {
            out.push(check_run(cell, name, shape));
        }
    }
    out
}

/// The verification figures quoted in the report: Hertz at δ = 0.2 R on a block 20 R wide and
/// deep (sphere and paraboloid, two mesh sizes), the surface profile against Johnson's
/// half-space formula, and the patch test of both laws.
pub fn verification(mode: Mode, cache: &RunCache) -> Result<VerificationStudy, ExperimentError> {
    let study = "verify";
    let depth = DEPTH_OVER_RADIUS * RADIUS_M;
    let a = (RADIUS_M * depth).sqrt();
    let size = BLOCK_OVER_RADIUS * RADIUS_M;
    let tool = ToolShape::Sphere { radius_m: RADIUS_M };
    let hertz = law::hertz_force_n(&MATERIAL, RADIUS_M, depth);
    // The runtime's corrections for the block's finite depth, and for the sphere's shape.
    let corrected = |exact_sphere: bool| -> Result<f64, ExperimentError> {
        let spec = ModelSpec {
            exact_sphere,
            thickness: layer(size, true),
            ..ModelSpec::PAPER
        };
        Ok(RuntimeModel::new(tool, MATERIAL, spec)
            .map_err(|source| ExperimentError::Model {
                run: study.to_owned(),
                source,
            })?
            .force_n(depth, &LocalGeometry::FLAT))
    };
    let mut checks = Vec::new();
    for &cell in cells(mode) {
        for (name, shape) in shapes() {
            let run = cache.get(study, &check_run(cell, name, shape))?;
            let fem = run.forces_n.first().map(|f| f[2]).unwrap_or(f64::NAN);
            let reference = corrected(matches!(shape, IndenterShape::Sphere { .. }))?;
            let profile_error = run
                .final_profile_m
                .iter()
                .filter(|(radius, _)| *radius > a && *radius < 4.0 * a)
                .map(|&(radius, d)| {
                    (d - softhaptic_proto::calibration::half_space_depression_m(
                        &tool, depth, radius,
                    ))
                    .abs()
                })
                .fold(0.0_f64, f64::max);
            checks.push(HertzCheck {
                indenter: name.to_owned(),
                fine_cell_m: cell,
                dofs: run.dofs,
                fem_n: fem,
                hertz_n: hertz,
                error_vs_hertz_percent: 100.0 * (fem / hertz - 1.0),
                error_vs_corrected_percent: 100.0 * (fem / reference - 1.0),
                profile_error_percent: 100.0 * profile_error / depth,
            });
        }
    }
    let mut patch_test = Vec::new();
    for kind in [LawKind::Linear, LawKind::NeoHookean] {
        patch_test.push((
            kind,
            patch_test_error(kind).map_err(|source| ExperimentError::Solve {
                run: format!("patch test {}", kind.name()),
                source,
            })?,
        ));
    }
    Ok(VerificationStudy {
        depth_over_radius: DEPTH_OVER_RADIUS,
        block_over_radius: BLOCK_OVER_RADIUS,
        checks,
        patch_test,
    })
}

/// Imposes u = G·X (G a constant displacement gradient, 5% strain for the neo-Hookean law) on
/// the boundary of a graded block and returns the largest interior error relative to the
/// largest displacement.
pub fn patch_test_error(kind: LawKind) -> Result<f64, SolveError> {
    let spec = BlockSpec {
        size_m: [0.04, 0.03, 0.02],
        fine_cell_m: 0.004,
        fine_radius_m: 0.006,
        fine_depth_m: 0.006,
        coarse_cells_lateral: 2,
        coarse_cells_depth: 2,
        symmetry: Symmetry::Full,
    };
    let Ok(mut m) = mesh::block(&spec) else {
        return Ok(f64::NAN);
    };
    m.fixed.iter_mut().for_each(|f| *f = 0);
    let scale = if kind == LawKind::NeoHookean {
        25.0
    } else {
        1.0
    };
    let grad = [
        [2e-3, 1e-3, -5e-4],
        [3e-4, -1.5e-3, 8e-4],
        [-7e-4, 6e-4, 1e-3],
    ];
    let field = |p: [f64; 3]| -> [f64; 3] {
        std::array::from_fn(|i| (0..3).map(|j| scale * grad[i][j] * p[j]).sum())
    };
    let mut lo = [f64::MAX; 3];
    let mut hi = [f64::MIN; 3];
    for p in &m.nodes_m {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let targets: Vec<(usize, [f64; 3])> = m
        .nodes_m
        .iter()
        .enumerate()
        .filter(|(_, p)| {
            (0..3).any(|k| (p[k] - lo[k]).abs() < 1e-12 || (p[k] - hi[k]).abs() < 1e-12)
        })
        .map(|(i, p)| (i, field(*p)))
        .collect();
    let nodes = m.nodes_m.clone();
    let mut model = ContactModel::new(
        m,
        Constitutive::new(kind, &MATERIAL),
        SolverOptions::default(),
    )?;
    model.solve_prescribed(&targets)?;
    let mut worst = 0.0_f64;
    let mut biggest = 0.0_f64;
    for (u, p) in model.displacements_m().iter().zip(&nodes) {
        let exact = field(*p);
        for k in 0..3 {
            worst = worst.max((u[k] - exact[k]).abs());
            biggest = biggest.max(exact[k].abs());
        }
    }
    Ok(worst / biggest.max(f64::MIN_POSITIVE))
}
