//! The paper's experiments (§3.2 curvature and inclination, §3.3.2 R_d calibration, §4.3 force
//! accuracy) and the speed-versus-accuracy study, each a function returning its figures.
//!
//! Every experiment runs in one of two [`Mode`]s: `Full` uses the meshes the report quotes,
//! `Quick` coarse meshes and fewer samples so that the whole suite checks end to end in about a
//! minute (its numbers are not to be quoted).

use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use softhaptic_device::law;
use softhaptic_proto::calibration::CalibrationRow;
use softhaptic_proto::{CalibrationSource, CalibrationTable, Material, ToolShape};

use crate::analytic;
use crate::element::{Constitutive, LawKind};
use crate::indenter::{Indenter, IndenterShape};
use crate::mesh::{self, BallSpec, BlockSpec, Symmetry, TetMesh};
use crate::solver::{ContactModel, SolveError, SolverOptions, deformed_radius_m};

const MM: f64 = 1e-3;

/// Just-noticeable difference of force magnitude the paper uses as its accuracy limit.
pub const JND: f64 = 0.07;

/// Surface depression that bounds the deformed region (paper §3.3.2).
pub const RD_THRESHOLD_M: f64 = 0.5 * MM;

/// Depth below which the paper fits R_d(δ) with a line.
pub const RD_BREAKPOINT_M: f64 = 7.0 * MM;

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

/// One indentation run: a tool pressed step by step into one object.
#[derive(Debug, Clone, Serialize)]
pub struct IndentationRun {
    pub label: String,
    pub law: LawKind,
    pub resolution: Resolution,
    pub dofs: usize,
    pub elements: usize,
    /// Normal depth of the tool's lowest point at each step.
    pub depths_m: Vec<f64>,
    /// Force of the body on the tool (FEM frame, +z out of the surface), per step.
    pub forces_n: Vec<[f64; 3]>,
    /// R_d at each step (radius where the depression exceeds [`RD_THRESHOLD_M`]).
    pub deformed_radius_m: Vec<f64>,
    /// Surface profile (reference radius, depression) at the last step.
    pub final_profile_m: Vec<(f64, f64)>,
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
}

fn progress(len: usize, label: &str) -> ProgressBar {
    let pb = ProgressBar::new(len as u64);
    if let Ok(style) =
        ProgressStyle::with_template("{spinner} {msg:48} [{bar:30}] {pos}/{len} {elapsed_precise}")
    {
        pb.set_style(style.progress_chars("=> "));
    }
    pb.set_message(label.to_owned());
    pb
}

/// Largest contact radius a tool reaches at `depth_m` (capped by the tool's own radius).
fn max_contact_radius_m(tool: &ToolShape, depth_m: f64) -> f64 {
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

/// Runs one indentation on a prepared mesh.
#[allow(clippy::too_many_arguments)] // Each argument is one axis of the experiment grid.
pub fn run_indentation(
    label: &str,
    mesh: TetMesh,
    tool: &ToolShape,
    material: &Material,
    law_kind: LawKind,
    resolution: Resolution,
    depths_m: &[f64],
    tilt_rad: f64,
) -> Result<IndentationRun, ExperimentError> {
    let elements = mesh.elements.len();
    let mut model = ContactModel::new(
        mesh,
        Constitutive::new(law_kind, material),
        SolverOptions::default(),
    )
    .map_err(|source| ExperimentError::Solve {
        run: label.to_owned(),
        source,
    })?;
    let shape = IndenterShape::from(tool);
    let pb = progress(depths_m.len(), label);
    let mut deformed = Vec::with_capacity(depths_m.len());
    let mut step_seconds = Vec::with_capacity(depths_m.len());
    let mut clock = Instant::now();
    let place = move |d: f64| placed_indenter(shape, d, tilt_rad);
    let eqs = model
        .follow(&place, 0.0, depths_m, |_, _, _, m| {
            step_seconds.push(clock.elapsed().as_secs_f64());
            deformed.push(deformed_radius_m(&m.surface_profile(), RD_THRESHOLD_M));
            pb.inc(1);
            clock = Instant::now();
        })
        .map_err(|source| ExperimentError::Solve {
            run: label.to_owned(),
            source,
        })?;
    pb.finish_and_clear();
    Ok(IndentationRun {
        label: label.to_owned(),
        law: law_kind,
        resolution,
        dofs: model.dof_count(),
        elements,
        depths_m: depths_m.to_vec(),
        forces_n: eqs.iter().map(|e| e.force_on_tool_n).collect(),
        deformed_radius_m: deformed,
        final_profile_m: model.surface_profile(),
        step_seconds,
        newton_iterations: eqs.iter().map(|e| e.iterations).collect(),
        locked_nodes: eqs.iter().map(|e| e.locked_nodes).collect(),
    })
}

/// A graded quarter (or half) block for `tool` reaching `max_depth_m`.
pub fn block_mesh(
    label: &str,
    size_m: [f64; 3],
    tool: &ToolShape,
    max_depth_m: f64,
    resolution: Resolution,
    symmetry: Symmetry,
) -> Result<TetMesh, ExperimentError> {
    let a = max_contact_radius_m(tool, max_depth_m);
    let spec = BlockSpec::graded(
        size_m,
        a,
        resolution.fine_cell_m,
        resolution.coarse_cells,
        symmetry,
    );
    mesh::block(&spec).map_err(|source| ExperimentError::Mesh {
        run: label.to_owned(),
        source,
    })
}

fn depths(from_mm: f64, to_mm: f64, step_mm: f64) -> Vec<f64> {
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

// ---------------------------------------------------------------------------------------------
// R_d calibration (§3.3.2)

/// One tool's R_d study.
#[derive(Debug, Clone, Serialize)]
pub struct RdStudy {
    pub tool_name: String,
    pub tool: ToolShape,
    pub runs: Vec<IndentationRun>,
    /// R_d of the elastic half-space at the same depths (physics.md).
    pub half_space_m: Vec<f64>,
    /// The tables written for the scenes (one per material).
    pub tables: Vec<(String, CalibrationTable)>,
}

/// The paper's calibration block (100 × 100 × 50 mm).
pub const RD_BLOCK_M: [f64; 3] = [0.1, 0.1, 0.05];

/// Runs the R_d calibration for the paper's sphere and cone (R = 10 mm, 45°), linear and
/// neo-Hookean, and builds the tables from the neo-Hookean run (large strain: the depth reaches
/// the tool radius).
///
/// With the displacement imposed and no body force, the static solution of either law depends
/// on E only through the stress scale: the displacement field, hence R_d, is the same for 50 kPa
/// and 1.5 MPa (a test checks this). One solve per tool and law therefore serves both materials.
pub fn rd_table(mode: Mode) -> Result<Vec<RdStudy>, ExperimentError> {
    let (res, ds) = match mode {
        Mode::Quick => (
            Resolution {
                name: "quick",
                fine_cell_m: 6.0 * MM,
                coarse_cells: 2,
            },
            depths(2.0, 10.0, 2.0),
        ),
        Mode::Full => (
            Resolution {
                name: "full",
                fine_cell_m: 2.5 * MM,
                coarse_cells: 4,
            },
            depths(0.5, 10.0, 0.5),
        ),
    };
    let tools = [
        ("sphere10", ToolShape::Sphere { radius_m: 0.01 }),
        (
            "cone10_45",
            ToolShape::Cone {
                half_angle_rad: std::f64::consts::FRAC_PI_4,
                radius_m: 0.01,
            },
        ),
    ];
    let max_depth = ds.last().copied().unwrap_or(0.01);
    let mut studies = Vec::new();
    for (name, tool) in tools {
        let mut runs = Vec::new();
        for law_kind in [LawKind::Linear, LawKind::NeoHookean] {
            let label = format!("rd-table {name} {}", law_kind.name());
            let mesh = block_mesh(&label, RD_BLOCK_M, &tool, max_depth, res, Symmetry::Quarter)?;
            runs.push(run_indentation(
                &label,
                mesh,
                &tool,
                &Material::PAPER_SOFT,
                law_kind,
                res,
                &ds,
                0.0,
            )?);
        }
        let half_space_m = ds
            .iter()
            .map(|&d| {
                softhaptic_proto::calibration::half_space_deformed_radius_m(
                    &tool,
                    d,
                    RD_THRESHOLD_M,
                )
            })
            .collect();
        let mut tables = Vec::new();
        if let Some(nh) = runs.iter().find(|r| r.law == LawKind::NeoHookean) {
            let rows: Vec<CalibrationRow> = nh
                .depths_m
                .iter()
                .zip(&nh.deformed_radius_m)
                .map(|(&depth_m, &deformed_radius_m)| CalibrationRow {
                    depth_m,
                    deformed_radius_m,
                })
                .collect();
            for (mat_name, material) in [
                ("50kpa", Material::PAPER_SOFT),
                ("1500kpa", Material::PAPER_STIFF),
            ] {
                let file = format!("{name}_{mat_name}");
                let description = format!(
                    "R_d(δ) of a {:.0} × {:.0} × {:.0} mm block (bottom clamped, sides free) indented by a rigid frictionless {} ; static compressible neo-Hookean FEM, 10-node tets, quarter symmetry, fine cells {:.1} mm ({} mode, softhaptic-calibrate rd-table); R_d = outermost radius where the surface sinks more than {:.1} mm. The static solution does not depend on E at fixed ν.",
                    RD_BLOCK_M[0] / MM,
                    RD_BLOCK_M[1] / MM,
                    RD_BLOCK_M[2] / MM,
                    tool_description(&tool),
                    res.fine_cell_m / MM,
                    res.name,
                    RD_THRESHOLD_M / MM,
                );
                let table = CalibrationTable::new(
                    CalibrationSource::FemNeoHookean,
                    description,
                    tool,
                    material,
                    RD_THRESHOLD_M,
                    Some(RD_BLOCK_M),
                    rows.clone(),
                    RD_BREAKPOINT_M,
                )
                .map_err(|source| ExperimentError::Table {
                    run: file.clone(),
                    source,
                })?;
                tables.push((file, table));
            }
        }
        studies.push(RdStudy {
            tool_name: name.to_owned(),
            tool,
            runs,
            half_space_m,
            tables,
        });
    }
    Ok(studies)
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

// ---------------------------------------------------------------------------------------------
// Force accuracy (§4.3)

/// The paper's §4.3 block (100 × 100 × 30 mm).
pub const FORCE_BLOCK_M: [f64; 3] = [0.1, 0.1, 0.03];

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
}

/// Resolutions of the §4.3 study (sphere R = 6 mm).
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

fn force_depths(mode: Mode) -> Vec<f64> {
    match mode {
        Mode::Quick => depths(1.0, 6.0, 1.0),
        Mode::Full => depths(0.5, 6.0, 0.5),
    }
}

/// A cache of indentation runs shared by experiments that need the same curve (`all` runs
/// force-depth and speed-accuracy on the same meshes).
#[derive(Default)]
pub struct RunCache {
    runs: Vec<(String, IndentationRun)>,
}

impl RunCache {
    fn get_or_run(
        &mut self,
        key: String,
        run: impl FnOnce() -> Result<IndentationRun, ExperimentError>,
    ) -> Result<IndentationRun, ExperimentError> {
        if let Some((_, r)) = self.runs.iter().find(|(k, _)| *k == key) {
            return Ok(r.clone());
        }
        let r = run()?;
        self.runs.push((key, r.clone()));
        Ok(r)
    }
}

fn force_run(
    cache: &mut RunCache,
    tool_name: &str,
    tool: &ToolShape,
    law_kind: LawKind,
    res: Resolution,
    ds: &[f64],
) -> Result<IndentationRun, ExperimentError> {
    let label = format!("force {tool_name} {} {}", law_kind.name(), res.name);
    let max_depth = ds.last().copied().unwrap_or(0.006);
    cache.get_or_run(label.clone(), || {
        let mesh = block_mesh(
            &label,
            FORCE_BLOCK_M,
            tool,
            max_depth,
            res,
            Symmetry::Quarter,
        )?;
        run_indentation(
            &label,
            mesh,
            tool,
            &Material::PAPER_SOFT,
            law_kind,
            res,
            ds,
            0.0,
        )
    })
}

/// The §4.3 tools: sphere R = 6 mm and a 45° cone of base radius 6 mm.
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

/// Paper §4.3: force against depth, linear and neo-Hookean FEM against Hertz / Sneddon.
pub fn force_depth(
    mode: Mode,
    cache: &mut RunCache,
) -> Result<Vec<ForceDepthStudy>, ExperimentError> {
    let res = force_resolutions(mode)[2];
    let ds = force_depths(mode);
    let material = Material::PAPER_SOFT;
    let mut out = Vec::new();
    for (name, tool) in force_tools() {
        let analytic_n: Vec<f64> = ds
            .iter()
            .map(|&d| law::contact_force_n(&tool, &material, d))
            .collect();
        let mut runs = Vec::new();
        let mut error_percent = Vec::new();
        let mut crossing_m = Vec::new();
        for law_kind in [LawKind::Linear, LawKind::NeoHookean] {
            let run = force_run(cache, name, &tool, law_kind, res, &ds)?;
            let fem = run.normal_forces_n();
            let f_m = fem
                .iter()
                .cloned()
                .fold(0.0_f64, f64::max)
                .max(f64::MIN_POSITIVE);
            let err: Vec<f64> = fem
                .iter()
                .zip(&analytic_n)
                .map(|(f, a)| 100.0 * (a - f).abs() / f_m)
                .collect();
            crossing_m.push(first_crossing(&ds, &err, 100.0 * JND));
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
        });
    }
    Ok(out)
}

// ---------------------------------------------------------------------------------------------
// Curvature (§3.2, eq. 6)

#[derive(Debug, Clone, Serialize)]
pub struct CurvatureStudy {
    pub tool_name: String,
    pub tool: ToolShape,
    pub depths_m: Vec<f64>,
    /// Block run first, then one per ball radius.
    pub runs: Vec<IndentationRun>,
    pub object_radii_m: Vec<f64>,
    /// e_f of eq. 6 in percent per ball: (F_s − F_c) / max(F_c).
    pub error_percent: Vec<Vec<f64>>,
    /// The same from the closed-form curvature corrections (physics.md) relative to the flat
    /// law, normalised the same way.
    pub predicted_percent: Vec<Vec<f64>>,
    pub crossing_m: Vec<Option<f64>>,
}

/// Paper §3.2: indentation of balls R0 = 30, 50, 100 mm against the 100 × 100 × 50 mm block,
/// sphere and cone of radius 10 mm, E = 50 kPa, ν = 0.33, linear FEM.
pub fn curvature(mode: Mode) -> Result<Vec<CurvatureStudy>, ExperimentError> {
    let (res, ds) = match mode {
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
    };
    let radii = [0.03, 0.05, 0.1];
    let material = Material::PAPER_SOFT;
    let max_depth = ds.last().copied().unwrap_or(0.01);
    let mut out = Vec::new();
    for (name, tool) in [
        ("sphere10", ToolShape::Sphere { radius_m: 0.01 }),
        (
            "cone10_45",
            ToolShape::Cone {
                half_angle_rad: std::f64::consts::FRAC_PI_4,
                radius_m: 0.01,
            },
        ),
    ] {
        let mut runs = Vec::new();
        let label = format!("curvature {name} block");
        let mesh = block_mesh(&label, RD_BLOCK_M, &tool, max_depth, res, Symmetry::Quarter)?;
        runs.push(run_indentation(
            &label,
            mesh,
            &tool,
            &material,
            LawKind::Linear,
            res,
            &ds,
            0.0,
        )?);
        for &r0 in &radii {
            let label = format!("curvature {name} ball R0={:.0}mm", r0 / MM);
            let a = max_contact_radius_m(&tool, max_depth);
            let mesh = mesh::quarter_ball(&BallSpec {
                radius_m: r0,
                fine_cell_m: res.fine_cell_m,
                fine_radius_m: (1.5 * a).min(0.6 * r0),
                coarse_cells: res.coarse_cells + 1,
            })
            .map_err(|source| ExperimentError::Mesh {
                run: label.clone(),
                source,
            })?;
            runs.push(run_indentation(
                &label,
                mesh,
                &tool,
                &material,
                LawKind::Linear,
                res,
                &ds,
                0.0,
            )?);
        }
        let block = runs[0].normal_forces_n();
        let f_max = block
            .iter()
            .cloned()
            .fold(0.0_f64, f64::max)
            .max(f64::MIN_POSITIVE);
        let flat_law: Vec<f64> = ds
            .iter()
            .map(|&d| law::contact_force_n(&tool, &material, d))
            .collect();
        let law_max = flat_law
            .iter()
            .cloned()
            .fold(0.0_f64, f64::max)
            .max(f64::MIN_POSITIVE);
        let mut error_percent = Vec::new();
        let mut predicted_percent = Vec::new();
        let mut crossing_m = Vec::new();
        for (k, &r0) in radii.iter().enumerate() {
            let ball = runs[k + 1].normal_forces_n();
            let err: Vec<f64> = ball
                .iter()
                .zip(&block)
                .map(|(s, c)| 100.0 * (s - c) / f_max)
                .collect();
            crossing_m.push(first_crossing(&ds, &err, 100.0 * JND));
            error_percent.push(err);
            predicted_percent.push(
                ds.iter()
                    .zip(&flat_law)
                    .map(|(&d, &flat)| {
                        let curved = match tool {
                            ToolShape::Sphere { radius_m } => {
                                analytic::hertz_on_sphere_force_n(&material, radius_m, r0, d)
                            }
                            ToolShape::Cone { half_angle_rad, .. } => {
                                analytic::cone_on_sphere_force_n(&material, half_angle_rad, r0, d)
                            }
                        };
                        100.0 * (curved - flat) / law_max
                    })
                    .collect(),
            );
        }
        out.push(CurvatureStudy {
            tool_name: name.to_owned(),
            tool,
            depths_m: ds.clone(),
            runs,
            object_radii_m: radii.to_vec(),
            error_percent,
            predicted_percent,
            crossing_m,
        });
    }
    Ok(out)
}

// ---------------------------------------------------------------------------------------------
// Inclination (§3.2, eq. 7)

#[derive(Debug, Clone, Serialize)]
pub struct InclinationStudy {
    pub tool_name: String,
    pub tool: ToolShape,
    pub depths_m: Vec<f64>,
    pub angles_rad: Vec<f64>,
    pub runs: Vec<IndentationRun>,
    /// Per angle, per depth: |F(θ) − F(0)| / |F(0)| in percent (the force the device renders
    /// along the normal from the perpendicular law, against the inclined FEM force).
    pub vector_error_percent: Vec<Vec<f64>>,
    /// Per angle, per depth: 1 − (F(θ)·axis)/|F(0)| in percent, the paper's eq. 7 reading
    /// (force felt along the direction of travel).
    pub axial_error_percent: Vec<Vec<f64>>,
    /// Smallest depth whose contact radius spans at least one fine cell: below it the contact
    /// rests on one or two nodes and, for the sharp cone, on the apex node alone, whose normal
    /// flips to a 45° flank at the slightest lateral drift. Thresholds use depths from here on.
    pub resolved_from_m: f64,
    /// Smallest angle at which the worst vector error over the resolved depths reaches 7%.
    pub threshold_vector_rad: Option<f64>,
    /// The same for the axial reading.
    pub threshold_axial_rad: Option<f64>,
}

/// Paper §3.2: tools tilted in the x–z plane and pushed along their axis into the
/// 100 × 100 × 50 mm block (half model, mirror plane y = 0), linear FEM, E = 50 kPa.
pub fn inclination(mode: Mode) -> Result<Vec<InclinationStudy>, ExperimentError> {
    let (res, ds, sphere_angles, cone_angles) = match mode {
        Mode::Quick => (
            Resolution {
                name: "quick",
                fine_cell_m: 6.0 * MM,
                coarse_cells: 2,
            },
            depths(2.0, 6.0, 2.0),
            vec![0.0, 15.0, 30.0],
            vec![0.0, 10.0, 20.0],
        ),
        Mode::Full => (
            Resolution {
                name: "full",
                fine_cell_m: 3.0 * MM,
                coarse_cells: 3,
            },
            depths(1.0, 6.0, 1.0),
            vec![0.0, 10.0, 20.0, 30.0],
            vec![0.0, 5.0, 10.0, 15.0, 20.0],
        ),
    };
    let material = Material::PAPER_SOFT;
    let max_depth = ds.last().copied().unwrap_or(0.006);
    let mut out = Vec::new();
    for (name, tool, angles_deg) in [
        (
            "sphere10",
            ToolShape::Sphere { radius_m: 0.01 },
            sphere_angles,
        ),
        (
            "cone10_45",
            ToolShape::Cone {
                half_angle_rad: std::f64::consts::FRAC_PI_4,
                radius_m: 0.01,
            },
            cone_angles,
        ),
    ] {
        let angles_rad: Vec<f64> = angles_deg.iter().map(|a: &f64| a.to_radians()).collect();
        let mut runs = Vec::new();
        for &theta in &angles_rad {
            let label = format!("inclination {name} {:.0}°", theta.to_degrees());
            // The tilted tool slides sideways by δ tan θ: widen the refined zone to cover it.
            let a = max_contact_radius_m(&tool, max_depth) + max_depth * theta.tan();
            let spec = BlockSpec::graded(
                RD_BLOCK_M,
                a,
                res.fine_cell_m,
                res.coarse_cells,
                Symmetry::HalfY,
            );
            let mesh = mesh::block(&spec).map_err(|source| ExperimentError::Mesh {
                run: label.clone(),
                source,
            })?;
            runs.push(run_indentation(
                &label,
                mesh,
                &tool,
                &material,
                LawKind::Linear,
                res,
                &ds,
                theta,
            )?);
        }
        let perpendicular = runs[0].forces_n.clone();
        let mut vector_error_percent = Vec::new();
        let mut axial_error_percent = Vec::new();
        for (run, &theta) in runs.iter().zip(&angles_rad) {
            let axis = [theta.sin(), 0.0, theta.cos()];
            let mut ve = Vec::new();
            let mut ae = Vec::new();
            for (f, f0) in run.forces_n.iter().zip(&perpendicular) {
                let n0 = norm3(*f0).max(f64::MIN_POSITIVE);
                let diff = [f[0] - f0[0], f[1] - f0[1], f[2] - f0[2]];
                ve.push(100.0 * norm3(diff) / n0);
                let along = f[0] * axis[0] + f[1] * axis[1] + f[2] * axis[2];
                ae.push(100.0 * (1.0 - along / n0));
            }
            vector_error_percent.push(ve);
            axial_error_percent.push(ae);
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
            first_crossing(&angles_rad, &worst, 100.0 * JND)
        };
        out.push(InclinationStudy {
            tool_name: name.to_owned(),
            tool,
            depths_m: ds.clone(),
            resolved_from_m,
            threshold_vector_rad: threshold(&vector_error_percent),
            threshold_axial_rad: threshold(&axial_error_percent),
            angles_rad,
            runs,
            vector_error_percent,
            axial_error_percent,
        });
    }
    Ok(out)
}

fn norm3(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

// ---------------------------------------------------------------------------------------------
// Speed against accuracy

/// One model in the speed-accuracy table.
#[derive(Debug, Clone, Serialize)]
pub struct ModelScore {
    pub name: String,
    /// Mean wall time of one force evaluation, seconds.
    pub seconds_per_evaluation: f64,
    /// Force at each reference depth, N.
    pub forces_n: Vec<f64>,
    /// Largest |F − F_ref| / F_ref over the depths, percent.
    pub max_error_percent: f64,
    /// Largest |F − F_ref| / max F_ref over the depths (eq. 9 form), percent.
    pub max_error_eq9_percent: f64,
    pub dofs: Option<usize>,
}

#[derive(Debug, Clone, Serialize)]
pub struct SpeedAccuracyStudy {
    pub reference: String,
    pub depths_m: Vec<f64>,
    pub reference_n: Vec<f64>,
    pub models: Vec<ModelScore>,
}

fn time_per_call(f: &dyn Fn(f64) -> f64, depths_m: &[f64]) -> f64 {
    let calls = 200_000usize;
    let start = Instant::now();
    let mut acc = 0.0;
    for i in 0..calls {
        acc += f(std::hint::black_box(depths_m[i % depths_m.len()]));
    }
    std::hint::black_box(acc);
    start.elapsed().as_secs_f64() / calls as f64
}

/// Time per force evaluation and error against the finest neo-Hookean FEM at δ = 1…6 mm, for
/// the runtime laws of `softhaptic_device::law`, the closed-form corrections of [`analytic`],
/// and the FEM at three resolutions (linear and neo-Hookean); §4.3's block and sphere R = 6 mm.
pub fn speed_accuracy(
    mode: Mode,
    cache: &mut RunCache,
) -> Result<SpeedAccuracyStudy, ExperimentError> {
    let (name, tool) = force_tools()[0];
    let radius_m = tool.radius_m();
    let material = Material::PAPER_SOFT;
    let ds = force_depths(mode);
    let reference_depths = depths(1.0, 6.0, 1.0);
    let pick = |run: &IndentationRun| -> Vec<f64> {
        reference_depths
            .iter()
            .map(|&d| {
                run.depths_m
                    .iter()
                    .position(|&x| (x - d).abs() < 1e-9)
                    .map(|i| run.forces_n[i][2])
                    .unwrap_or(f64::NAN)
            })
            .collect()
    };
    let resolutions = force_resolutions(mode);
    let mut fem_runs = Vec::new();
    for law_kind in [LawKind::Linear, LawKind::NeoHookean] {
        for res in resolutions {
            fem_runs.push(force_run(cache, name, &tool, law_kind, res, &ds)?);
        }
    }
    let reference_run = fem_runs
        .iter()
        .rev()
        .find(|r| r.law == LawKind::NeoHookean)
        .cloned()
        .ok_or_else(|| ExperimentError::Mesh {
            run: "speed-accuracy".to_owned(),
            source: mesh::MeshError::TooFewCells {
                field: "resolutions",
                value: 0,
                min: 1,
            },
        })?;
    let reference_n = pick(&reference_run);
    let ref_max = reference_n.iter().cloned().fold(0.0_f64, f64::max);
    let score = |name: String, seconds: f64, forces: Vec<f64>, dofs: Option<usize>| {
        let mut max_rel = 0.0_f64;
        let mut max_eq9 = 0.0_f64;
        for (f, r) in forces.iter().zip(&reference_n) {
            max_rel = max_rel.max(100.0 * (f - r).abs() / r);
            max_eq9 = max_eq9.max(100.0 * (f - r).abs() / ref_max);
        }
        ModelScore {
            name,
            seconds_per_evaluation: seconds,
            forces_n: forces,
            max_error_percent: max_rel,
            max_error_eq9_percent: max_eq9,
            dofs,
        }
    };
    let h = FORCE_BLOCK_M[2];
    let nu = material.poisson_ratio();
    type Model<'a> = (&'a str, Box<dyn Fn(f64) -> f64 + 'a>);
    let analytic_models: Vec<Model> = vec![
        (
            "device::law::hertz_force_n (paper eq. 4)",
            Box::new(|d| law::hertz_force_n(&material, radius_m, d)),
        ),
        (
            "analytic::exact_sphere_force_n (Sneddon)",
            Box::new(|d| analytic::exact_sphere_force_n(&material, radius_m, d)),
        ),
        (
            "Hertz × bonded thickness factor (Dimitriadis)",
            Box::new(move |d| {
                law::hertz_force_n(&material, radius_m, d)
                    * analytic::thickness_factor_sphere(nu, radius_m, d, h, true)
            }),
        ),
        (
            "exact sphere × bonded thickness factor",
            Box::new(move |d| {
                analytic::exact_sphere_force_n(&material, radius_m, d)
                    * analytic::thickness_factor_sphere(nu, radius_m, d, h, true)
            }),
        ),
    ];
    let mut models = Vec::new();
    for (name, f) in &analytic_models {
        let forces: Vec<f64> = reference_depths.iter().map(|&d| f(d)).collect();
        let t = time_per_call(f.as_ref(), &reference_depths);
        models.push(score((*name).to_owned(), t, forces, None));
    }
    for run in &fem_runs {
        let seconds = run.step_seconds.iter().sum::<f64>() / run.step_seconds.len().max(1) as f64;
        models.push(score(
            format!(
                "FEM {} {} ({:.1} mm cells)",
                run.law.name(),
                run.resolution.name,
                run.resolution.fine_cell_m / MM
            ),
            seconds,
            pick(run),
            Some(run.dofs),
        ));
    }
    Ok(SpeedAccuracyStudy {
        reference: reference_run.label.clone(),
        depths_m: reference_depths,
        reference_n,
        models,
    })
}

// ---------------------------------------------------------------------------------------------
// Verification (before the experiments)

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
    /// FEM against the closed form corrected for the block depth (and, for the sphere, for the
    /// exact sphere shape), percent.
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

/// The verification figures quoted in the report: Hertz at δ = 0.2 R on a block 20 R wide and
/// deep (sphere and paraboloid, two mesh sizes), the surface profile against Johnson's
/// half-space formula, and the patch test of both laws.
pub fn verification(mode: Mode) -> Result<VerificationStudy, ExperimentError> {
    let r: f64 = 0.01;
    let depth = 0.2 * r;
    let a = (r * depth).sqrt();
    let size = 20.0 * r;
    let material = Material::PAPER_SOFT;
    let cells: &[f64] = match mode {
        Mode::Quick => &[5.0 * MM, 3.0 * MM],
        Mode::Full => &[2.0 * MM, 1.25 * MM],
    };
    let hertz = law::hertz_force_n(&material, r, depth);
    let layer = analytic::thickness_factor_sphere(material.poisson_ratio(), r, depth, size, true);
    let tool = ToolShape::Sphere { radius_m: r };
    let mut checks = Vec::new();
    for &cell in cells {
        let spec = BlockSpec::graded([size, size, size], a, cell, 5, Symmetry::Quarter);
        let label = format!("verification {:.2} mm cells", cell / MM);
        let mesh = mesh::block(&spec).map_err(|source| ExperimentError::Mesh {
            run: label.clone(),
            source,
        })?;
        let mut model = ContactModel::new(
            mesh,
            Constitutive::new(LawKind::Linear, &material),
            SolverOptions::default(),
        )
        .map_err(|source| ExperimentError::Solve {
            run: label.clone(),
            source,
        })?;
        let pb = progress(2, &label);
        for (name, shape, corrected) in [
            (
                "sphere",
                IndenterShape::Sphere { radius_m: r },
                analytic::exact_sphere_force_n(&material, r, depth) * layer,
            ),
            (
                "paraboloid",
                IndenterShape::Paraboloid { radius_m: r },
                hertz * layer,
            ),
        ] {
            model.reset();
            let eq = model
                .solve(&Indenter::vertical(shape, depth), 0, depth)
                .map_err(|source| ExperimentError::Solve {
                    run: label.clone(),
                    source,
                })?;
            let fem = eq.force_on_tool_n[2];
            let profile_error = model
                .surface_profile()
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
                dofs: model.dof_count(),
                fem_n: fem,
                hertz_n: hertz,
                error_vs_hertz_percent: 100.0 * (fem / hertz - 1.0),
                error_vs_corrected_percent: 100.0 * (fem / corrected - 1.0),
                profile_error_percent: 100.0 * profile_error / depth,
            });
            pb.inc(1);
        }
        pb.finish_and_clear();
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
        depth_over_radius: 0.2,
        block_over_radius: 20.0,
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
        Constitutive::new(kind, &Material::PAPER_SOFT),
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
