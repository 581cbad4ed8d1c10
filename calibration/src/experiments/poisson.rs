//! Poisson's ratio from 0.30 to 0.49: the hyperelastic factor, the bonded-layer correction and
//! the R_d tables at each ν of [`POISSON_SWEEP`].
//!
//! Soft tissue is nearly incompressible (ν ≈ 0.45–0.49), while the paper and the committed fits
//! use ν = 0.33. At every ν of the sweep the study repeats, on the finest mesh of the §4.3
//! study, the neo-Hookean and small-deformation runs of the 6 mm tools on the 30 mm block, and
//! the neo-Hookean runs of the 10 mm tools on the R_d study's 50 mm block:
//!
//! - the hyperelastic factor is refitted against the closed form of the same ν (exact sphere,
//!   or cone, on the bonded layer, whose factor depends on ν), in sample on the 30 mm block and
//!   scored out of sample on the 50 mm block with the 10 mm tools;
//! - the small-deformation FEM on bonded layers 12, 20 and 30 mm thick measures the bonded-layer
//!   factor at that ν, and the residual the runtime multiplies the published series by
//!   (`softhaptic_device::model::layer_fit`; Dimitriadis' sphere depends on ν, Garcia &
//!   Garcia's cone was derived at ν = 0.5 and does not) is refitted to it, then scored out of
//!   sample on a 15 mm layer;
//! - the 50 mm block's neo-Hookean runs give the R_d table of that ν.

use serde::Serialize;
use softhaptic_device::model::{LayerLaw, LocalGeometry, layer_factor, layer_fit};
use softhaptic_proto::{CalibrationTable, LayerSpec, Material, ModelSpec, ToolShape};

use super::force::{
    FORCE_LAYER_M, HyperelasticConstants, fit_constant_ratio, fit_quadratic_ratio,
    fit_two_term_ratio, force_depths, force_resolutions, force_run, force_tools,
};
use super::rd::{rd_run, rd_setup};
use super::surface::DrawnProfile;
use super::verification::{material_with_poisson, poisson_tag, sneddon_force_n};
use super::{
    ExperimentError, FORCE_BLOCK_M, MATERIAL, MM, Mode, RD_BLOCK_M, RD_BREAKPOINT_M,
    RD_THRESHOLD_M, RunCache, RunSpec, block_body, paper_tools_10mm, spec, tool_description,
};
use crate::element::LawKind;
use crate::mesh::Symmetry;
use crate::models::{ErrorCurve, RuntimeModel, layer};

/// The Poisson's ratios of the sweep; the paper's 0.33 is added from the other studies' runs.
pub const POISSON_SWEEP: [f64; 4] = [0.30, 0.40, 0.45, 0.49];

/// Every ν the study reports: the sweep and the paper's, increasing.
pub fn poisson_ratios() -> Vec<f64> {
    let mut out: Vec<f64> = POISSON_SWEEP.to_vec();
    out.push(MATERIAL.poisson_ratio());
    out.sort_by(f64::total_cmp);
    out
}

fn with_material(mut run: RunSpec, material: &Material) -> RunSpec {
    run.label.push_str(&poisson_tag(material));
    run.material = *material;
    run
}

/// The §4.3 run of `tool` with `law` on the finest mesh, at `material`.
fn layer_run(
    mode: Mode,
    name: &str,
    tool: &ToolShape,
    law: LawKind,
    material: &Material,
) -> RunSpec {
    with_material(
        force_run(mode, name, tool, law, force_resolutions(mode)[2]),
        material,
    )
}

/// Thicknesses of the bonded layers the layer residual is fitted on: the §4.3 block's 30 mm and
/// two thinner ones, so that χ reaches the series' 0.5 at δ = 6 mm.
pub const LAYER_FIT_THICKNESSES_M: [f64; 3] = [0.012, 0.020, FORCE_LAYER_M];
/// The layer held out of the fit to score it.
pub const LAYER_HELD_OUT_M: f64 = 0.015;
/// The fit and its scores start at this depth: at 1 mm the cone's contact spans less than a
/// cell of the finest mesh.
pub const LAYER_FIT_FROM_M: f64 = 2.0 * MM;

/// The small-deformation run of a §4.3 tool on a 100 × 100 mm block `thickness_m` thick, on the
/// finest mesh, at `material` (the 30 mm one is the §4.3 run itself).
fn thickness_run(
    mode: Mode,
    name: &str,
    tool: &ToolShape,
    thickness_m: f64,
    material: &Material,
) -> RunSpec {
    let law = LawKind::LinearSmallDeformation;
    if (thickness_m - FORCE_LAYER_M).abs() < 1e-12 {
        return layer_run(mode, name, tool, law, material);
    }
    let res = force_resolutions(mode)[2];
    let ds = force_depths(mode);
    let max_depth_m = ds.last().copied().unwrap_or(0.006);
    let size_m = [FORCE_BLOCK_M[0], FORCE_BLOCK_M[1], thickness_m];
    let body = block_body(size_m, tool, max_depth_m, 0.0, res, Symmetry::Quarter);
    let label = format!(
        "block 100×100×{:.0} {name} {} {}",
        thickness_m / MM,
        law.name(),
        res.name
    );
    with_material(spec(label, body, tool, law, res, &ds, 0.0), material)
}

/// The layers of the residual's fit, then the held-out one.
fn layer_thicknesses_m() -> impl Iterator<Item = f64> {
    LAYER_FIT_THICKNESSES_M
        .into_iter()
        .chain(std::iter::once(LAYER_HELD_OUT_M))
}

/// The R_d study's neo-Hookean run of `tool` at `material`.
fn block_run(mode: Mode, name: &str, tool: &ToolShape, material: &Material) -> RunSpec {
    with_material(rd_run(mode, name, tool, LawKind::NeoHookean), material)
}

/// The FEM runs of the sweep (the paper's ν reuses the other studies' runs).
pub fn poisson_runs(mode: Mode) -> Vec<RunSpec> {
    let mut out = Vec::new();
    for nu in poisson_ratios() {
        let Ok(material) = material_with_poisson(nu) else {
            continue;
        };
        for (name, tool) in force_tools() {
            out.push(layer_run(mode, name, &tool, LawKind::NeoHookean, &material));
            for thickness_m in layer_thicknesses_m() {
                out.push(thickness_run(mode, name, &tool, thickness_m, &material));
            }
        }
        for (name, tool) in paper_tools_10mm() {
            out.push(block_run(mode, name, &tool, &material));
        }
    }
    out
}

/// One depth of one layer: the bonded-layer factor the small-deformation FEM measures, and the
/// laws' predictions of it.
#[derive(Debug, Clone, Serialize)]
pub struct LayerSample {
    pub thickness_m: f64,
    pub depth_m: f64,
    /// χ of the series: √(Rδ)/h for a sphere, δ tan α / h for a cone.
    pub chi: f64,
    /// FEM / Sneddon's half-space of the same ν.
    pub measured: f64,
    /// The published series.
    pub published: f64,
    /// The published series times the residual refitted here.
    pub refit: f64,
    /// What the runtime uses at this ν (its table of residuals, interpolated in ν).
    pub runtime: f64,
}

/// The bonded-layer factor of one tool at one ν: the FEM's, the residual refitted to it, and the
/// errors of each law.
#[derive(Debug, Clone, Serialize)]
pub struct LayerFit {
    pub tool_name: String,
    /// [k1, k2] of the residual 1 + k1 χ + k2 χ s (s = δ/R for a sphere, χ for a cone), fitted
    /// on [`LAYER_FIT_THICKNESSES_M`].
    pub fit: [f64; 2],
    /// The runtime's [k1, k2] at this ν.
    pub runtime: [f64; 2],
    /// Every layer and depth from [`LAYER_FIT_FROM_M`], the held-out layer last.
    pub samples: Vec<LayerSample>,
}

impl LayerFit {
    /// Largest |measured / predicted − 1|, percent, of the published series, the refit and the
    /// runtime, over the fitted layers (`held_out` false) or the held-out one.
    pub fn worst_percent(&self, held_out: bool) -> [f64; 3] {
        let mut worst = [0.0_f64; 3];
        for s in &self.samples {
            if ((s.thickness_m - LAYER_HELD_OUT_M).abs() < 1e-12) != held_out {
                continue;
            }
            for (w, p) in worst.iter_mut().zip([s.published, s.refit, s.runtime]) {
                *w = w.max(100.0 * (s.measured / p - 1.0).abs());
            }
        }
        worst
    }
}

/// One ν of the sweep.
#[derive(Debug, Clone, Serialize)]
pub struct PoissonPoint {
    pub poisson_ratio: f64,
    /// The §4.3 tools (sphere, cone), their depths, and the neo-Hookean FEM's forces there on the
    /// 30 mm block at this ν (the reference of the limits measured at this ν).
    pub tools: [ToolShape; 2],
    pub layer_depths_m: Vec<f64>,
    pub layer_cell_m: f64,
    pub sphere_nh_n: Vec<f64>,
    pub cone_nh_n: Vec<f64>,
    /// The hyperelastic factor refitted at this ν (against the closed form of this ν).
    pub fit: HyperelasticConstants,
    /// Largest eq. 9 error of the closed form on the layer times the refitted factor against the
    /// neo-Hookean FEM, in sample (6 mm tools, 30 mm block): sphere, cone, percent.
    pub in_sample_percent: [f64; 2],
    /// The same without the factor.
    pub in_sample_unfitted_percent: [f64; 2],
    /// The constants the runtime uses at this ν (`softhaptic_device::model::hyperelastic_fit`,
    /// interpolated in ν between its fits).
    pub runtime: HyperelasticConstants,
    /// The in-sample error with the runtime's constants.
    pub in_sample_runtime_percent: [f64; 2],
    /// The in-sample error with the ν = 0.33 constants (what the runtime did before it used ν).
    pub in_sample_paper_constants_percent: [f64; 2],
    /// The out-of-sample error with the runtime's constants.
    pub out_of_sample_runtime_percent: [f64; 2],
    /// Out of sample (10 mm tools, 50 mm block, δ to 10 mm): sphere, cone, percent.
    pub out_of_sample_percent: [f64; 2],
    /// The same without the factor.
    pub out_of_sample_unfitted_percent: [f64; 2],
    /// The neo-Hookean stiffening at δ = R of the 6 mm sphere: F_nH / closed form.
    pub sphere_ratio_at_radius: f64,
    /// The bonded-layer factor measured by the small-deformation FEM and refitted: sphere, cone.
    pub layer: Vec<LayerFit>,
    /// R_d at the table depths, per tool of radius 10 mm (sphere, cone), metres.
    pub rd_m: Vec<Vec<f64>>,
    /// The scene tables of this ν (50 kPa; the displacement field does not depend on E).
    pub tables: Vec<(String, CalibrationTable)>,
    /// The drawn surface against the FEM surface of this ν's runs, per tool of radius 10 mm
    /// (sphere, cone): what a scene of this ν draws with its table.
    pub surface: Vec<TableSurfaceError>,
}

/// The drawn profiles of one table against the top surface of the FEM run it is made from, at
/// every depth of the run to δ = R (`experiments::surface`'s comparison): the largest |error|
/// over those depths and the depth where it sits, `(depth_m, error_m)`.
#[derive(Debug, Clone, Serialize)]
pub struct TableSurfaceError {
    /// The table's name (`sphere10_50kpa_nu49`); the paper's ν names the rd-table one.
    pub table: String,
    /// The paper's Bézier, drawn with the table's R_d and the streamed contact radius.
    pub paper: Option<(f64, f64)>,
    /// The `fem` profile with the scored depth's row held out (as a depth between rows is
    /// drawn).
    pub fem_held_out: Option<(f64, f64)>,
    /// The `fem` profile as tabulated.
    pub fem: Option<(f64, f64)>,
    /// Depths scored.
    pub depths: usize,
}

/// The surface errors of `table`, made from `run`.
fn table_surface_error(
    name: &str,
    tool: &ToolShape,
    table: &CalibrationTable,
    run: &super::IndentationRun,
) -> TableSurfaceError {
    let comparisons =
        super::surface::compare_runs(tool, std::slice::from_ref(run), RD_BLOCK_M[2], |d| {
            table.deformed_radius_m(d)
        });
    let worst = |profile| super::surface::worst_error(&comparisons, run.law, profile);
    TableSurfaceError {
        table: name.to_owned(),
        paper: worst(DrawnProfile::Paper),
        fem_held_out: worst(DrawnProfile::FemHeldOut),
        fem: worst(DrawnProfile::Fem),
        depths: comparisons.len(),
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct PoissonStudy {
    /// Depths of the R_d tables.
    pub rd_depths_m: Vec<f64>,
    pub points: Vec<PoissonPoint>,
}

/// The closed form the runtime multiplies by its hyperelastic factor: the exact sphere (or the
/// cone) on a bonded layer of `thickness_m`.
fn closed_form_spec(tool: &ToolShape, thickness_m: f64) -> ModelSpec {
    ModelSpec {
        exact_sphere: matches!(tool, ToolShape::Sphere { .. }),
        thickness: layer(thickness_m, true),
        ..ModelSpec::PAPER
    }
}

/// The factor of `fit` for `tool` at each depth (sphere: in x = δ/R, continued by its tangent
/// past the fitted range as the runtime does; cone: a constant).
fn factor(fit: &HyperelasticConstants, tool: &ToolShape, depths_m: &[f64]) -> Vec<f64> {
    depths_m
        .iter()
        .map(|&d| match *tool {
            ToolShape::Sphere { radius_m } => {
                let x = d / radius_m;
                if x <= fit.sphere_x_max {
                    fit.sphere_ratio(x)
                } else {
                    let m = fit.sphere_x_max;
                    let slope = (fit.sphere_c1 + 2.0 * fit.sphere_c2 * m).max(0.0);
                    fit.sphere_ratio(m) + slope * (x - m)
                }
            }
            ToolShape::Cone { .. } => fit.cone_ratio,
        })
        .collect()
}

fn scaled(forces_n: &[f64], factor: &[f64]) -> Vec<f64> {
    forces_n.iter().zip(factor).map(|(f, k)| f * k).collect()
}

/// The sweep over ν.
pub fn poisson_study(mode: Mode, cache: &RunCache) -> Result<PoissonStudy, ExperimentError> {
    let study = "poisson";
    let ds = force_depths(mode);
    let (rd_res, rd_depths) = rd_setup(mode);
    let [(sphere_name, sphere), (cone_name, cone)] = force_tools();
    let radius_m = sphere.radius_m();
    let mut points = Vec::new();
    for nu in poisson_ratios() {
        let material = material_with_poisson(nu)?;
        let closed = |tool: &ToolShape, thickness_m: f64, depths_m: &[f64]| {
            RuntimeModel::new(*tool, material, closed_form_spec(tool, thickness_m))
                .map(|m| m.forces_n(depths_m, &LocalGeometry::FLAT))
                .map_err(|source| ExperimentError::Model {
                    run: format!("{study} ν = {nu:.2}"),
                    source,
                })
        };
        let fem =
            |name: &str, tool: &ToolShape, law: LawKind| -> Result<Vec<f64>, ExperimentError> {
                Ok(cache
                    .get(study, &layer_run(mode, name, tool, law, &material))?
                    .normal_forces_n())
            };
        // In sample: the 6 mm tools on the 30 mm block.
        let sphere_nh = fem(sphere_name, &sphere, LawKind::NeoHookean)?;
        let cone_nh = fem(cone_name, &cone, LawKind::NeoHookean)?;
        let sphere_closed = closed(&sphere, FORCE_LAYER_M, &ds)?;
        let cone_closed = closed(&cone, FORCE_LAYER_M, &ds)?;
        let x: Vec<f64> = ds.iter().map(|d| d / radius_m).collect();
        let [c1, c2] = fit_quadratic_ratio(&x, &sphere_nh, &sphere_closed);
        let fit = HyperelasticConstants {
            sphere_c1: c1,
            sphere_c2: c2,
            sphere_x_max: x.last().copied().unwrap_or(1.0),
            cone_ratio: fit_constant_ratio(&cone_nh, &cone_closed),
        };
        let in_use = HyperelasticConstants::IN_USE;
        let runtime = {
            let c = softhaptic_device::model::hyperelastic_fit::at(nu);
            HyperelasticConstants {
                sphere_c1: c.sphere_c1,
                sphere_c2: c.sphere_c2,
                cone_ratio: c.cone_ratio,
                ..in_use
            }
        };
        let score = |closed: &[f64], fem: &[f64], k: Option<&[f64]>| {
            let model = match k {
                Some(k) => scaled(closed, k),
                None => closed.to_vec(),
            };
            ErrorCurve::new(&model, fem).max_eq9_percent()
        };
        let sphere_k = factor(&fit, &sphere, &ds);
        let cone_k = factor(&fit, &cone, &ds);
        let in_sample_percent = [
            score(&sphere_closed, &sphere_nh, Some(&sphere_k)),
            score(&cone_closed, &cone_nh, Some(&cone_k)),
        ];
        let in_sample_unfitted_percent = [
            score(&sphere_closed, &sphere_nh, None),
            score(&cone_closed, &cone_nh, None),
        ];
        let in_sample_paper_constants_percent = [
            score(
                &sphere_closed,
                &sphere_nh,
                Some(&factor(&in_use, &sphere, &ds)),
            ),
            score(&cone_closed, &cone_nh, Some(&factor(&in_use, &cone, &ds))),
        ];
        let in_sample_runtime_percent = [
            score(
                &sphere_closed,
                &sphere_nh,
                Some(&factor(&runtime, &sphere, &ds)),
            ),
            score(&cone_closed, &cone_nh, Some(&factor(&runtime, &cone, &ds))),
        ];
        let sphere_ratio_at_radius = ds
            .iter()
            .position(|&d| (d - radius_m).abs() < 1e-9)
            .map_or(f64::NAN, |i| sphere_nh[i] / sphere_closed[i]);
        // Out of sample: the 10 mm tools on the 50 mm block, to δ = 10 mm.
        let mut out_of_sample_percent = [0.0; 2];
        let mut out_of_sample_unfitted_percent = [0.0; 2];
        let mut out_of_sample_runtime_percent = [0.0; 2];
        let mut rd_m = Vec::new();
        let mut tables = Vec::new();
        let mut surface = Vec::new();
        for (k, (name, tool)) in paper_tools_10mm().into_iter().enumerate() {
            let run = cache.get(study, &block_run(mode, name, &tool, &material))?;
            let reference = run.normal_forces_n();
            let closed_n = closed(&tool, RD_BLOCK_M[2], &run.depths_m)?;
            out_of_sample_percent[k] = score(
                &closed_n,
                &reference,
                Some(&factor(&fit, &tool, &run.depths_m)),
            );
            out_of_sample_unfitted_percent[k] = score(&closed_n, &reference, None);
            out_of_sample_runtime_percent[k] = score(
                &closed_n,
                &reference,
                Some(&factor(&runtime, &tool, &run.depths_m)),
            );
            rd_m.push(run.deformed_radius_m.clone());
            let file = if material == MATERIAL {
                format!("{name}_50kpa")
            } else {
                format!("{name}_50kpa_nu{:02.0}", 100.0 * nu)
            };
            let table = rd_table_of(&file, &tool, &material, run, rd_res.fine_cell_m, mode)?;
            surface.push(table_surface_error(&file, &tool, &table, run));
            // The paper's ν's tables are rd-table's, written with the other formulations beside.
            if material != MATERIAL {
                tables.push((file, table));
            }
        }
        // The bonded-layer factor, small-deformation FEM against Sneddon's half-space.
        let mut layer_fits = Vec::new();
        for (name, tool) in force_tools() {
            layer_fits.push(layer_fit_of(mode, cache, name, &tool, &material)?);
        }
        points.push(PoissonPoint {
            poisson_ratio: nu,
            tools: [sphere, cone],
            layer_depths_m: ds.clone(),
            layer_cell_m: force_resolutions(mode)[2].fine_cell_m,
            sphere_nh_n: sphere_nh.clone(),
            cone_nh_n: cone_nh.clone(),
            fit,
            in_sample_percent,
            in_sample_unfitted_percent,
            runtime,
            in_sample_runtime_percent,
            in_sample_paper_constants_percent,
            out_of_sample_runtime_percent,
            out_of_sample_percent,
            out_of_sample_unfitted_percent,
            sphere_ratio_at_radius,
            layer: layer_fits,
            rd_m,
            tables,
            surface,
        });
    }
    Ok(PoissonStudy {
        rd_depths_m: rd_depths,
        points,
    })
}

/// χ of the layer series for `tool` at `depth_m` on a layer `thickness_m` thick.
fn layer_chi(tool: &ToolShape, depth_m: f64, thickness_m: f64) -> f64 {
    match *tool {
        ToolShape::Sphere { radius_m } => (radius_m * depth_m).sqrt() / thickness_m,
        ToolShape::Cone { half_angle_rad, .. } => depth_m * half_angle_rad.tan() / thickness_m,
    }
}

/// The bonded-layer factor of `tool` at `material` on every layer of the study, and the
/// residual on the published series fitted to it.
fn layer_fit_of(
    mode: Mode,
    cache: &RunCache,
    name: &str,
    tool: &ToolShape,
    material: &Material,
) -> Result<LayerFit, ExperimentError> {
    let nu = material.poisson_ratio();
    let runtime_residual = layer_fit::at(nu);
    let runtime = match tool {
        ToolShape::Sphere { .. } => runtime_residual.sphere_bonded,
        ToolShape::Cone { .. } => runtime_residual.cone,
    };
    let mut samples = Vec::new();
    for thickness_m in layer_thicknesses_m() {
        let run = cache.get(
            "poisson",
            &thickness_run(mode, name, tool, thickness_m, material),
        )?;
        let layer = LayerSpec {
            thickness_m,
            bonded: true,
        };
        for (&depth_m, &fem_n) in run.depths_m.iter().zip(&run.normal_forces_n()) {
            if depth_m < LAYER_FIT_FROM_M - 1e-12 {
                continue;
            }
            let law = |law| layer_factor(tool, nu, layer, depth_m, law);
            samples.push(LayerSample {
                thickness_m,
                depth_m,
                chi: layer_chi(tool, depth_m, thickness_m),
                measured: fem_n / sneddon_force_n(tool, material, depth_m),
                published: law(LayerLaw::Published),
                refit: f64::NAN,
                runtime: law(LayerLaw::Runtime),
            });
        }
    }
    let fitted: Vec<&LayerSample> = samples
        .iter()
        .filter(|s| (s.thickness_m - LAYER_HELD_OUT_M).abs() >= 1e-12)
        .collect();
    // The residual's terms [χ, χ s]: s = δ/R (held at 1 past R) for a sphere, χ for a cone, as
    // `softhaptic_device::model::layer_fit` evaluates them.
    let terms = |s: &LayerSample| -> [f64; 2] {
        let second = match *tool {
            ToolShape::Sphere { radius_m } => (s.depth_m / radius_m).min(1.0),
            ToolShape::Cone { .. } => s.chi,
        };
        [s.chi, s.chi * second]
    };
    let fitted_terms: Vec<[f64; 2]> = fitted.iter().map(|s| terms(s)).collect();
    let measured: Vec<f64> = fitted.iter().map(|s| s.measured).collect();
    let published: Vec<f64> = fitted.iter().map(|s| s.published).collect();
    // Least squares on the factor: measured ≈ published · (1 + k1 t1 + k2 t2).
    let fit = fit_two_term_ratio(&fitted_terms, &measured, &published);
    for s in &mut samples {
        let [t1, t2] = terms(s);
        s.refit = s.published * (1.0 + fit[0] * t1 + fit[1] * t2);
    }
    Ok(LayerFit {
        tool_name: name.to_owned(),
        fit,
        runtime,
        samples,
    })
}

/// The R_d table of one ν from its neo-Hookean run on the calibration block.
fn rd_table_of(
    file: &str,
    tool: &ToolShape,
    material: &Material,
    run: &super::IndentationRun,
    fine_cell_m: f64,
    mode: Mode,
) -> Result<CalibrationTable, ExperimentError> {
    let rows = run
        .depths_m
        .iter()
        .zip(&run.deformed_radius_m)
        .map(
            |(&depth_m, &deformed_radius_m)| softhaptic_proto::calibration::CalibrationRow {
                depth_m,
                deformed_radius_m,
            },
        )
        .collect();
    let description = format!(
        "R_d(δ) of a {:.0} × {:.0} × {:.0} mm block (bottom clamped, sides free) indented by a \
         rigid frictionless {}, ν = {:.2}; static compressible neo-Hookean FEM, 10-node tets, \
         quarter symmetry, fine cells {:.1} mm ({:?} mode, softhaptic-calibrate poisson); R_d = \
         outermost radius where the surface sinks more than {:.1} mm. The static solution does \
         not depend on E at fixed ν.",
        RD_BLOCK_M[0] / MM,
        RD_BLOCK_M[1] / MM,
        RD_BLOCK_M[2] / MM,
        tool_description(tool),
        material.poisson_ratio(),
        fine_cell_m / MM,
        mode,
        RD_THRESHOLD_M / MM,
    );
    CalibrationTable::new(
        softhaptic_proto::CalibrationSource::FemNeoHookean,
        description,
        *tool,
        *material,
        RD_THRESHOLD_M,
        Some(RD_BLOCK_M),
        rows,
        RD_BREAKPOINT_M,
    )
    .map_err(|source| ExperimentError::Table {
        run: file.to_owned(),
        source,
    })
    // The surface the viewer's `fem` profile draws, from the same run as the rows (as
    // rd-table's tables carry it), so that a scene of this ν can draw it.
    .and_then(|table| {
        let surface =
            super::surface::surface_family(tool, run).map_err(|e| ExperimentError::Data {
                study: format!("poisson {file}"),
                reason: format!("tabulated surface refused: {e}"),
            })?;
        Ok(table.with_surface(surface))
    })
}
