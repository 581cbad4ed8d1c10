//! Force against depth (paper §4.3), the fit of the runtime's hyperelastic correction to the
//! neo-Hookean FEM, and the speed-versus-accuracy table of every runtime model.
//!
//! One file for three studies because they share their FEM runs and constants: the hyperelastic fit
//! is made on the force study's runs and feeds the speed-accuracy table. Hence the length: the
//! shared runs take 145 lines, the force study 125, the fit and its transfer check 235, the
//! speed-accuracy table 190.

use serde::Serialize;
use softhaptic_device::law;
use softhaptic_device::model::{LocalGeometry, hyperelastic_fit as in_use};
use softhaptic_proto::{ModelSpec, ToolShape};

use super::rd::RdStudy;
use super::verification::{SneddonMesh, contact_scaled_run, sneddon_meshes};
use super::{
    ExperimentError, FORCE_BLOCK_M, IndentationRun, JND_PERCENT, MATERIAL, MM, Mode, Resolution,
    RunCache, RunSpec, block_body, depths, first_crossing, spec,
};
// The §4.3 tools stand with what every study shares, since the verification and the ν study
// press them too; they are named from here as well, where a reader of §4.3 looks for them.
pub use super::force_tools;
use crate::analytic;
use crate::element::LawKind;
use crate::mesh::Symmetry;
use crate::models::{self, ErrorCurve, RuntimeModel, layer};

/// Resolutions of the §4.3 study, coarsest first; the last is the reference.
pub fn force_resolutions(mode: Mode) -> [Resolution; 3] {
    match mode {
        Mode::Quick => [
            Resolution {
                name: "coarse",
                fine_cell_m: 6.0 * MM,
                coarse_cells: 2,
            },
            Resolution {
                name: "medium",
                fine_cell_m: 4.5 * MM,
                coarse_cells: 2,
            },
            Resolution {
                name: "fine",
                fine_cell_m: 3.0 * MM,
                coarse_cells: 2,
            },
        ],
        Mode::Full => [
            Resolution {
                name: "coarse",
                fine_cell_m: 3.0 * MM,
                coarse_cells: 3,
            },
            Resolution {
                name: "medium",
                fine_cell_m: 2.0 * MM,
                coarse_cells: 4,
            },
            Resolution {
                name: "fine",
                fine_cell_m: 1.5 * MM,
                coarse_cells: 4,
            },
        ],
    }
}

/// Load steps of the §4.3 runs.
pub fn force_depths(mode: Mode) -> Vec<f64> {
    match mode {
        Mode::Quick => depths(1.0, 6.0, 1.0),
        Mode::Full => depths(0.5, 6.0, 0.5),
    }
}

/// Thickness of the §4.3 block: the layer of the thickness-corrected models.
pub const FORCE_LAYER_M: f64 = FORCE_BLOCK_M[2];

pub(crate) fn force_run(
    mode: Mode,
    name: &str,
    tool: &ToolShape,
    law: LawKind,
    res: Resolution,
) -> RunSpec {
    let ds = force_depths(mode);
    let max_depth = ds.last().copied().unwrap_or(0.006);
    let body = block_body(FORCE_BLOCK_M, tool, max_depth, 0.0, res, Symmetry::Quarter);
    spec(
        format!("block 100×100×30 {name} {} {}", law.name(), res.name),
        body,
        tool,
        law,
        res,
        &ds,
        0.0,
    )
}

/// The formulations of the force study: the textbook small-deformation contact (the problem
/// Hertz and Sneddon solve, the study's "linear" FEM), the small-strain law with contact on the
/// deformed surface beside it, and the neo-Hookean law.
pub const FORCE_LAWS: [LawKind; 3] = [
    LawKind::LinearSmallDeformation,
    LawKind::LinearDeformedContact,
    LawKind::NeoHookean,
];

/// The runs of the force study: both tools, every formulation, on the finest mesh; the
/// small-deformation runs of the bonded-layer check at small depths on meshes scaled to the
/// contact.
pub fn force_runs(mode: Mode) -> Vec<RunSpec> {
    let res = force_resolutions(mode)[2];
    let mut out = Vec::new();
    for (name, tool) in force_tools() {
        for law in FORCE_LAWS {
            out.push(force_run(mode, name, &tool, law, res));
        }
    }
    out.extend(layer_refined_runs(mode));
    out
}

/// Depths of the bonded-layer check that get a mesh of their own. The §4.3 mesh has 1.5 mm cells
/// under the tool, wider than the cone's contact radius below 2.4 mm (0.64 mm at δ = 1 mm): there
/// the contact spans one or two cells and the force is off by 10% either way, which no layer
/// factor can be told from.
pub fn layer_small_depths(mode: Mode) -> Vec<f64> {
    match mode {
        Mode::Quick => vec![1.0 * MM, 2.0 * MM],
        Mode::Full => depths(0.5, 2.0, 0.5),
    }
}

/// The mesh of those depths: the finest of the deep-block check (cells of a/4 over 1.5 a,
/// verified there within 0.4% of Sneddon), scaled to each depth's contact radius.
pub fn layer_refined_mesh(mode: Mode) -> SneddonMesh {
    let meshes = sneddon_meshes(mode);
    meshes[meshes.len() - 1]
}

/// The small-deformation run of `tool` at `depth_m` on the §4.3 block, meshed for that depth.
pub fn layer_refined_run(name: &str, tool: &ToolShape, depth_m: f64, mesh: SneddonMesh) -> RunSpec {
    contact_scaled_run(
        format!("block 100×100×30 {name}"),
        FORCE_BLOCK_M,
        tool,
        depth_m,
        mesh,
        LawKind::LinearSmallDeformation,
        &MATERIAL,
        1,
    )
}

/// The refined runs of the bonded-layer check: both tools at every small depth.
pub fn layer_refined_runs(mode: Mode) -> Vec<RunSpec> {
    let mesh = layer_refined_mesh(mode);
    let mut out = Vec::new();
    for (name, tool) in force_tools() {
        for d in layer_small_depths(mode) {
            out.push(layer_refined_run(name, &tool, d, mesh));
        }
    }
    out
}

/// The runs of the speed-accuracy study: both tools, every formulation, three meshes (the
/// finest are the force study's); the small-deformation ones are also the convergence table of
/// the linear FEM on the paper's block.
pub fn speed_accuracy_runs(mode: Mode) -> Vec<RunSpec> {
    let mut out = Vec::new();
    for (name, tool) in force_tools() {
        for law in FORCE_LAWS {
            for res in force_resolutions(mode) {
                out.push(force_run(mode, name, &tool, law, res));
            }
        }
    }
    out
}

fn fine_run<'a>(
    study: &str,
    mode: Mode,
    cache: &'a RunCache,
    name: &str,
    tool: &ToolShape,
    law: LawKind,
) -> Result<&'a IndentationRun, ExperimentError> {
    cache.get(
        study,
        &force_run(mode, name, tool, law, force_resolutions(mode)[2]),
    )
}

// ---------------------------------------------------------------------------------------------
// Force against depth (§4.3)

/// Force–depth curves of one tool, FEM against the closed-form law.
#[derive(Debug, Clone, Serialize)]
pub struct ForceDepthStudy {
    pub tool_name: String,
    pub tool: ToolShape,
    pub depths_m: Vec<f64>,
    /// The law of `softhaptic_device::law` (Hertz or Sneddon).
    pub analytic_n: Vec<f64>,
    pub runs: Vec<IndentationRun>,
    /// e_f of eq. 9 in percent, per run: |f_a − f_f| / f_m, f_m the run's largest FEM force.
    pub error_percent: Vec<Vec<f64>>,
    /// Depth where e_f first reaches 7%, per run.
    pub crossing_m: Vec<Option<f64>>,
    /// The small-deformation FEM on the 30 mm layer against Sneddon's half-space and the
    /// bonded-layer correction.
    pub layer_check: Option<LayerCheck>,
}

/// The small-deformation FEM on the paper's 100 × 100 × 30 mm block held against Sneddon's
/// half-space (exact sphere, or cone): a layer bonded to a rigid base must be stiffer than the
/// half-space, by the factor of Dimitriadis et al. (sphere) or Garcia & Garcia (cone) times the
/// FEM residual (`softhaptic_device::model::layer_fit`) that the runtime's bonded-layer
/// correction applies.
#[derive(Debug, Clone, Serialize)]
pub struct LayerCheck {
    pub depths_m: Vec<f64>,
    /// Sneddon's half-space force (exact sphere, or cone), N.
    pub half_space_n: Vec<f64>,
    /// The runtime's closed form on the bonded layer (exact sphere or cone, bonded layer 30 mm).
    pub layer_closed_form_n: Vec<f64>,
    /// The small-deformation FEM on the §4.3 mesh, N, and that mesh's cell under the tool.
    pub fem_n: Vec<f64>,
    pub fem_cell_m: f64,
    /// The small-deformation FEM on a mesh scaled to the contact at the small depths
    /// ([`layer_small_depths`]), N; `None` at the other depths.
    pub refined_fem_n: Vec<Option<f64>>,
    /// That mesh ("a/4": cells of a quarter contact radius) and its unknowns per depth.
    pub refined_mesh: String,
    pub refined_dofs: Vec<Option<usize>>,
}

impl LayerCheck {
    /// The best FEM force at depth `i`: the refined mesh's where there is one.
    pub fn best_fem_n(&self, i: usize) -> f64 {
        self.refined_fem_n[i].unwrap_or(self.fem_n[i])
    }

    /// FEM / half-space, the measured layer factor (best FEM).
    pub fn measured_factor(&self, i: usize) -> f64 {
        self.best_fem_n(i) / self.half_space_n[i]
    }

    /// FEM / (half-space × predicted factor) − 1, percent (best FEM).
    pub fn error_percent(&self, i: usize) -> f64 {
        100.0 * (self.best_fem_n(i) / self.layer_closed_form_n[i] - 1.0)
    }

    /// Closed form on the layer / half-space, the predicted layer factor.
    pub fn predicted_factor(&self, i: usize) -> f64 {
        self.layer_closed_form_n[i] / self.half_space_n[i]
    }

    /// Largest |FEM / closed form on the layer − 1| over the depths from `from_m`, percent (best
    /// FEM).
    pub fn worst_error_percent(&self, from_m: f64) -> f64 {
        (0..self.depths_m.len())
            .filter(|&i| self.depths_m[i] >= from_m - 1e-12)
            .map(|i| self.error_percent(i).abs())
            .fold(0.0, f64::max)
    }
}

/// Paper §4.3: force against depth, the linear FEMs and the neo-Hookean FEM against Hertz /
/// Sneddon.
pub fn force_depth(mode: Mode, cache: &RunCache) -> Result<Vec<ForceDepthStudy>, ExperimentError> {
    let ds = force_depths(mode);
    let mut out = Vec::new();
    for (name, tool) in force_tools() {
        let analytic_n: Vec<f64> = ds
            .iter()
            .map(|&d| law::contact_force_n(&tool, &MATERIAL, d))
            .collect();
        let mut runs = Vec::new();
        let mut error_percent = Vec::new();
        let mut crossing_m = Vec::new();
        let mut layer_check = None;
        for law_kind in FORCE_LAWS {
            let run = fine_run("force-depth", mode, cache, name, &tool, law_kind)?.clone();
            if law_kind == LawKind::LinearSmallDeformation {
                layer_check = Some(layer_check_of(mode, cache, name, &tool, &run)?);
            }
            let err: Vec<f64> = ErrorCurve::new(&analytic_n, &run.normal_forces_n())
                .eq9_percent
                .iter()
                .map(|e| e.abs())
                .collect();
            crossing_m.push(first_crossing(&ds, &err, JND_PERCENT));
            error_percent.push(err);
            runs.push(run);
        }
        out.push(ForceDepthStudy {
            tool_name: name.to_owned(),
            tool,
            depths_m: ds.clone(),
            analytic_n,
            runs,
            error_percent,
            crossing_m,
            layer_check,
        });
    }
    Ok(out)
}

/// The runtime's closed form on the §4.3 bonded layer (Sneddon's exact sphere or cone times the
/// bonded-layer factor and its FEM residual) for `tool` (named `name` in errors) at `depths_m`.
pub fn layer_closed_form_n(
    name: &str,
    tool: &ToolShape,
    depths_m: &[f64],
) -> Result<Vec<f64>, ExperimentError> {
    let spec = ModelSpec {
        exact_sphere: matches!(tool, ToolShape::Sphere { .. }),
        thickness: layer(FORCE_LAYER_M, true),
        ..ModelSpec::PAPER
    };
    let closed =
        RuntimeModel::new(*tool, MATERIAL, spec).map_err(|source| ExperimentError::Model {
            run: format!("force-depth layer check {name}"),
            source,
        })?;
    Ok(closed.forces_n(depths_m, &LocalGeometry::FLAT))
}

/// The bonded-layer check of one tool's small-deformation run, with the refined runs at the
/// small depths.
pub fn layer_check_of(
    mode: Mode,
    cache: &RunCache,
    name: &str,
    tool: &ToolShape,
    run: &IndentationRun,
) -> Result<LayerCheck, ExperimentError> {
    let layer_closed_form_n = layer_closed_form_n(name, tool, &run.depths_m)?;
    let mesh = layer_refined_mesh(mode);
    let small = layer_small_depths(mode);
    let mut refined_fem_n = Vec::new();
    let mut refined_dofs = Vec::new();
    for &d in &run.depths_m {
        if small.iter().any(|s| (s - d).abs() < 1e-9) {
            let refined = cache.get("force-depth", &layer_refined_run(name, tool, d, mesh))?;
            refined_fem_n.push(Some(refined.normal_force_at_n(d)));
            refined_dofs.push(Some(refined.dofs));
        } else {
            refined_fem_n.push(None);
            refined_dofs.push(None);
        }
    }
    Ok(LayerCheck {
        depths_m: run.depths_m.clone(),
        half_space_n: run
            .depths_m
            .iter()
            .map(|&d| super::verification::sneddon_force_n(tool, &MATERIAL, d))
            .collect(),
        layer_closed_form_n,
        fem_n: run.normal_forces_n(),
        fem_cell_m: run.resolution.fine_cell_m,
        refined_fem_n,
        refined_mesh: mesh.name.to_owned(),
        refined_dofs,
    })
}

// ---------------------------------------------------------------------------------------------
// Hyperelastic fit

/// The constants of `softhaptic_device::model::hyperelastic_fit` the runtime is built with.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct HyperelasticConstants {
    pub sphere_c1: f64,
    pub sphere_c2: f64,
    pub sphere_x_max: f64,
    pub cone_ratio: f64,
}

impl HyperelasticConstants {
    /// What the runtime uses now.
    pub const IN_USE: HyperelasticConstants = HyperelasticConstants {
        sphere_c1: in_use::SPHERE_C1,
        sphere_c2: in_use::SPHERE_C2,
        sphere_x_max: in_use::SPHERE_X_MAX,
        cone_ratio: in_use::CONE_RATIO,
    };

    /// The sphere's ratio at x = δ/R, inside the fitted range.
    pub fn sphere_ratio(&self, x: f64) -> f64 {
        1.0 + x * (self.sphere_c1 + x * self.sphere_c2)
    }
}

/// The neo-Hookean stiffening of the §4.3 runs, and its fit.
///
/// The runtime applies the hyperelastic correction as a factor on its closed-form linear-elastic
/// law, whatever other corrections are on. The factor is therefore fitted against that closed
/// form of the same geometry (for the sphere: Sneddon's exact sphere on the bonded 30 mm layer;
/// for the cone: Sneddon's cone on the bonded layer), by least squares on the force:
/// F_nH ≈ F_closed · (1 + c1 x + c2 x²), x = δ/R, and F_nH ≈ F_closed · c for the cone (no length
/// scale). Least squares on the force, i.e. on the ratio weighted by the force squared, is the
/// fit that minimises the eq. 9 error, and it keeps the depths whose contact spans less than a
/// cell from steering it. The ratio against the linear FEM of the same mesh is fitted too, for
/// comparison: it is not the factor the runtime needs, because the linear FEM itself departs
/// from the closed form at large strain (the report shows by how much).
#[derive(Debug, Clone, Serialize)]
pub struct HyperelasticFit {
    pub sphere_radius_m: f64,
    pub thickness_m: f64,
    pub sphere_depths_m: Vec<f64>,
    pub sphere_nh_n: Vec<f64>,
    pub sphere_linear_fem_n: Vec<f64>,
    /// The runtime's exact sphere on the bonded layer, no hyperelastic factor.
    pub sphere_closed_form_n: Vec<f64>,
    /// Lin et al. (2009) over Hertz at the same depths.
    pub lin_et_al_ratio: Vec<f64>,
    pub cone_depths_m: Vec<f64>,
    pub cone_nh_n: Vec<f64>,
    pub cone_linear_fem_n: Vec<f64>,
    /// The runtime's Sneddon cone on the bonded layer, no hyperelastic factor.
    pub cone_closed_form_n: Vec<f64>,
    /// The refit against the closed form (what the runtime's constants should be).
    pub refit: HyperelasticConstants,
    /// The same fitted against the linear FEM, for comparison.
    pub against_linear_fem: HyperelasticConstants,
    /// The constants the runtime was built with.
    pub in_use: HyperelasticConstants,
}

/// c1, c2 minimising Σ (F_nH − F_b (1 + c1 x + c2 x²))².
pub(crate) fn fit_quadratic_ratio(x: &[f64], nh: &[f64], base: &[f64]) -> [f64; 2] {
    let terms: Vec<[f64; 2]> = x.iter().map(|&x| [x, x * x]).collect();
    fit_two_term_ratio(&terms, nh, base)
}

/// [k1, k2] minimising Σ (F − F_b (1 + k1 t1 + k2 t2))² over the samples' terms [t1, t2].
pub(crate) fn fit_two_term_ratio(terms: &[[f64; 2]], target: &[f64], base: &[f64]) -> [f64; 2] {
    // Normal equations of y = k1 u + k2 v with u = F_b t1, v = F_b t2, y = F − F_b.
    let (mut uu, mut uv, mut vv, mut uy, mut vy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for ((&[t1, t2], &f), &b) in terms.iter().zip(target).zip(base) {
        let (u, v, y) = (b * t1, b * t2, f - b);
        uu += u * u;
        uv += u * v;
        vv += v * v;
        uy += u * y;
        vy += v * y;
    }
    let det = uu * vv - uv * uv;
    if det.abs() <= f64::MIN_POSITIVE {
        return [0.0, 0.0];
    }
    [(uy * vv - vy * uv) / det, (vy * uu - uy * uv) / det]
}

/// c minimising Σ (F_nH − c F_b)².
pub(crate) fn fit_constant_ratio(nh: &[f64], base: &[f64]) -> f64 {
    let num: f64 = nh.iter().zip(base).map(|(f, b)| f * b).sum();
    let den: f64 = base.iter().map(|b| b * b).sum();
    if den > 0.0 { num / den } else { 1.0 }
}

/// Fits the hyperelastic correction to the §4.3 neo-Hookean runs on the finest mesh.
pub fn hyperelastic_fit(mode: Mode, cache: &RunCache) -> Result<HyperelasticFit, ExperimentError> {
    let study = "hyperelastic fit";
    let ds = force_depths(mode);
    let [(sphere_name, sphere), (cone_name, cone)] = force_tools();
    let radius_m = sphere.radius_m();
    let model_err = |source| ExperimentError::Model {
        run: study.to_owned(),
        source,
    };
    let closed = |tool: ToolShape, spec: ModelSpec| -> Result<Vec<f64>, ExperimentError> {
        Ok(RuntimeModel::new(tool, MATERIAL, spec)
            .map_err(model_err)?
            .forces_n(&ds, &LocalGeometry::FLAT))
    };
    let sphere_closed_form_n = closed(
        sphere,
        ModelSpec {
            exact_sphere: true,
            thickness: layer(FORCE_LAYER_M, true),
            ..ModelSpec::PAPER
        },
    )?;
    let cone_closed_form_n = closed(
        cone,
        ModelSpec {
            thickness: layer(FORCE_LAYER_M, true),
            ..ModelSpec::PAPER
        },
    )?;
    let forces =
        |name: &str, tool: &ToolShape, law: LawKind| -> Result<Vec<f64>, ExperimentError> {
            Ok(fine_run(study, mode, cache, name, tool, law)?.normal_forces_n())
        };
    let sphere_nh_n = forces(sphere_name, &sphere, LawKind::NeoHookean)?;
    let sphere_linear_fem_n = forces(sphere_name, &sphere, LawKind::LinearDeformedContact)?;
    let cone_nh_n = forces(cone_name, &cone, LawKind::NeoHookean)?;
    let cone_linear_fem_n = forces(cone_name, &cone, LawKind::LinearDeformedContact)?;
    let x: Vec<f64> = ds.iter().map(|d| d / radius_m).collect();
    let sphere_x_max = x.last().copied().unwrap_or(1.0);
    let refit_sphere = fit_quadratic_ratio(&x, &sphere_nh_n, &sphere_closed_form_n);
    let fem_sphere = fit_quadratic_ratio(&x, &sphere_nh_n, &sphere_linear_fem_n);
    let lin_et_al_ratio = ds
        .iter()
        .map(|&d| {
            analytic::lin_neo_hookean_sphere_force_n(&MATERIAL, radius_m, d)
                / law::hertz_force_n(&MATERIAL, radius_m, d)
        })
        .collect();
    Ok(HyperelasticFit {
        sphere_radius_m: radius_m,
        thickness_m: FORCE_LAYER_M,
        sphere_depths_m: ds.clone(),
        refit: HyperelasticConstants {
            sphere_c1: refit_sphere[0],
            sphere_c2: refit_sphere[1],
            sphere_x_max,
            cone_ratio: fit_constant_ratio(&cone_nh_n, &cone_closed_form_n),
        },
        against_linear_fem: HyperelasticConstants {
            sphere_c1: fem_sphere[0],
            sphere_c2: fem_sphere[1],
            sphere_x_max,
            cone_ratio: fit_constant_ratio(&cone_nh_n, &cone_linear_fem_n),
        },
        in_use: HyperelasticConstants::IN_USE,
        sphere_nh_n,
        sphere_linear_fem_n,
        sphere_closed_form_n,
        lin_et_al_ratio,
        cone_depths_m: ds,
        cone_nh_n,
        cone_linear_fem_n,
        cone_closed_form_n,
    })
}

/// The fitted correction carried to a geometry it was not fitted on: the R_d study's tools of
/// radius 10 mm on the 50 mm block, neo-Hookean FEM to δ = 10 mm.
#[derive(Debug, Clone, Serialize)]
pub struct TransferCheck {
    pub tool_name: String,
    pub depths_m: Vec<f64>,
    pub reference_n: Vec<f64>,
    /// (model name, eq. 9 error per depth) for the uncorrected law, the closed form without the
    /// hyperelastic factor, and with it.
    pub models: Vec<(String, ErrorCurve)>,
}

/// Scores the runtime models against the R_d study's neo-Hookean runs (a held-out geometry).
pub fn transfer_check(rd: &[RdStudy]) -> Result<Vec<TransferCheck>, ExperimentError> {
    let thickness_m = super::RD_BLOCK_M[2];
    let mut out = Vec::new();
    for s in rd {
        let Some(run) = s.runs.iter().find(|r| r.law == LawKind::NeoHookean) else {
            continue;
        };
        let reference_n = run.normal_forces_n();
        let specs: Vec<ModelSpec> = match s.tool {
            ToolShape::Sphere { .. } => vec![
                ModelSpec::PAPER,
                ModelSpec {
                    exact_sphere: true,
                    thickness: layer(thickness_m, true),
                    ..ModelSpec::PAPER
                },
                models::best_combined_sphere(thickness_m),
            ],
            ToolShape::Cone { .. } => vec![
                ModelSpec::PAPER,
                ModelSpec {
                    thickness: layer(thickness_m, true),
                    ..ModelSpec::PAPER
                },
                ModelSpec {
                    thickness: layer(thickness_m, true),
                    hyperelastic: true,
                    ..ModelSpec::PAPER
                },
            ],
        };
        let mut models = Vec::new();
        for spec in specs {
            let m = RuntimeModel::new(s.tool, MATERIAL, spec).map_err(|source| {
                ExperimentError::Model {
                    run: format!("transfer check {}", s.tool_name),
                    source,
                }
            })?;
            let f = m.forces_n(&run.depths_m, &LocalGeometry::FLAT);
            models.push((m.name(), ErrorCurve::new(&f, &reference_n)));
        }
        out.push(TransferCheck {
            tool_name: s.tool_name.clone(),
            depths_m: run.depths_m.clone(),
            reference_n,
            models,
        });
    }
    Ok(out)
}

// ---------------------------------------------------------------------------------------------
// Speed against accuracy

/// What a row of the speed-accuracy table is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RowKind {
    /// A runtime model (`ForceModel`), as the loop runs it.
    Runtime,
    /// A closed-form reference that is not a runtime model.
    Reference,
    /// A formula from the literature, for comparison.
    Literature,
    /// The FEM itself.
    Fem,
}

/// One row of the speed-accuracy table.
#[derive(Debug, Clone, Serialize)]
pub struct ScoredModel {
    pub name: String,
    pub kind: RowKind,
    /// The runtime spec (runtime rows only).
    pub spec: Option<ModelSpec>,
    pub best_combined: bool,
    /// Median wall time of one evaluation, nanoseconds (a whole static solve for the FEM).
    pub nanoseconds: f64,
    /// Force at each table depth, N.
    pub forces_n: Vec<f64>,
    /// Errors at each table depth against the reference.
    pub errors: ErrorCurve,
    pub dofs: Option<usize>,
    /// Depth where the eq. 9 error first reaches 7% over the force study's whole depth grid
    /// (runtime rows), or `None`.
    pub crossing_m: Option<f64>,
    /// Deepest depth of that grid.
    pub deepest_m: f64,
}

/// The speed-accuracy table of one tool.
#[derive(Debug, Clone, Serialize)]
pub struct ToolAccuracy {
    pub tool_name: String,
    pub tool: ToolShape,
    /// The reference run (the finest neo-Hookean FEM), its unknowns and its fine cell.
    pub reference: String,
    pub reference_dofs: usize,
    pub reference_cell_m: f64,
    pub reference_n: Vec<f64>,
    pub models: Vec<ScoredModel>,
}

#[derive(Debug, Clone, Serialize)]
pub struct SpeedAccuracyStudy {
    /// The table's depths (δ = 1 … 6 mm).
    pub depths_m: Vec<f64>,
    /// Thickness of the layer of the thickness-corrected models (the block's).
    pub thickness_m: f64,
    pub tools: Vec<ToolAccuracy>,
}

/// Time per force evaluation and error against the finest neo-Hookean FEM at δ = 1…6 mm, for
/// every runtime model of the §4.3 tools (`softhaptic_device::model::ForceModel`, the paper's
/// law, each correction alone and the combinations), the exact-sphere closed form, Lin et al.'s
/// formula, and the FEM at three resolutions (linear and neo-Hookean).
pub fn speed_accuracy(mode: Mode, cache: &RunCache) -> Result<SpeedAccuracyStudy, ExperimentError> {
    let study = "speed-accuracy";
    let grid = force_depths(mode);
    let table_depths = depths(1.0, 6.0, 1.0);
    let max_depth_m = grid.last().copied().unwrap_or(0.006);
    let mut tools = Vec::new();
    for (name, tool) in force_tools() {
        let reference_run = fine_run(study, mode, cache, name, &tool, LawKind::NeoHookean)?;
        let reference_n: Vec<f64> = table_depths
            .iter()
            .map(|&d| reference_run.normal_force_at_n(d))
            .collect();
        if reference_n.iter().any(|f| !f.is_finite()) {
            return Err(ExperimentError::Data {
                study: study.to_owned(),
                reason: format!(
                    "the reference run {} lacks one of the depths 1…6 mm",
                    reference_run.label
                ),
            });
        }
        let grid_reference = reference_run.normal_forces_n();
        let mut models = Vec::new();
        let specs = match tool {
            ToolShape::Sphere { .. } => models::sphere_specs(FORCE_LAYER_M),
            ToolShape::Cone { .. } => models::cone_specs(FORCE_LAYER_M),
        };
        let best = models::best_combined_sphere(FORCE_LAYER_M);
        for spec in specs {
            let m = RuntimeModel::new(tool, MATERIAL, spec).map_err(|source| {
                ExperimentError::Model {
                    run: format!("{study} {name}"),
                    source,
                }
            })?;
            let forces_n = m.forces_n(&table_depths, &LocalGeometry::FLAT);
            let grid_errors = ErrorCurve::new(
                &m.forces_n(&reference_run.depths_m, &LocalGeometry::FLAT),
                &grid_reference,
            );
            models.push(ScoredModel {
                name: m.name(),
                kind: RowKind::Runtime,
                spec: Some(spec),
                best_combined: matches!(tool, ToolShape::Sphere { .. }) && spec == best,
                nanoseconds: m.nanoseconds_per_evaluation(&LocalGeometry::FLAT, max_depth_m),
                errors: ErrorCurve::new(&forces_n, &reference_n),
                forces_n,
                dofs: None,
                crossing_m: first_crossing(
                    &reference_run.depths_m,
                    &grid_errors.eq9_percent,
                    JND_PERCENT,
                ),
                deepest_m: max_depth_m,
            });
        }
        let mut extra = |name: String, kind: RowKind, f: &dyn Fn(f64) -> f64| {
            let forces_n: Vec<f64> = table_depths.iter().map(|&d| f(d)).collect();
            models.push(ScoredModel {
                name,
                kind,
                spec: None,
                best_combined: false,
                nanoseconds: models::time_per_call_ns(f, max_depth_m),
                errors: ErrorCurve::new(&forces_n, &reference_n),
                forces_n,
                dofs: None,
                crossing_m: None,
                deepest_m: max_depth_m,
            });
        };
        if let ToolShape::Sphere { radius_m } = tool {
            extra(
                "Sneddon's exact sphere, closed form by bisection (reference)".to_owned(),
                RowKind::Reference,
                &|d| analytic::exact_sphere_force_n(&MATERIAL, radius_m, d),
            );
            extra(
                "Lin et al. 2009 neo-Hookean sphere (literature)".to_owned(),
                RowKind::Literature,
                &|d| analytic::lin_neo_hookean_sphere_force_n(&MATERIAL, radius_m, d),
            );
        }
        for law_kind in FORCE_LAWS {
            for res in force_resolutions(mode) {
                let run = cache.get(study, &force_run(mode, name, &tool, law_kind, res))?;
                let forces_n: Vec<f64> = table_depths
                    .iter()
                    .map(|&d| run.normal_force_at_n(d))
                    .collect();
                models.push(ScoredModel {
                    name: format!(
                        "FEM {} {} ({:.1} mm cells)",
                        run.law.name(),
                        res.name,
                        res.fine_cell_m / MM
                    ),
                    kind: RowKind::Fem,
                    spec: None,
                    best_combined: false,
                    nanoseconds: run.median_step_seconds() * 1e9,
                    errors: ErrorCurve::new(&forces_n, &reference_n),
                    forces_n,
                    dofs: Some(run.dofs),
                    crossing_m: None,
                    deepest_m: max_depth_m,
                });
            }
        }
        tools.push(ToolAccuracy {
            tool_name: name.to_owned(),
            tool,
            reference: reference_run.label.clone(),
            reference_dofs: reference_run.dofs,
            reference_cell_m: reference_run.resolution.fine_cell_m,
            reference_n,
            models,
        });
    }
    Ok(SpeedAccuracyStudy {
        depths_m: table_depths,
        thickness_m: FORCE_LAYER_M,
        tools,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn least_squares_recovers_known_ratios() {
        let x = [0.1, 0.3, 0.5, 0.8, 1.0];
        let base = [1.0, 2.0, 3.0, 5.0, 7.0];
        let nh: Vec<f64> = x
            .iter()
            .zip(&base)
            .map(|(x, b)| b * (1.0 + 0.2 * x - 0.05 * x * x))
            .collect();
        let [c1, c2] = fit_quadratic_ratio(&x, &nh, &base);
        assert!(
            (c1 - 0.2).abs() < 1e-12 && (c2 + 0.05).abs() < 1e-12,
            "{c1} {c2}"
        );
        let scaled: Vec<f64> = base.iter().map(|b| 1.15 * b).collect();
        assert!((fit_constant_ratio(&scaled, &base) - 1.15).abs() < 1e-12);
    }
}
