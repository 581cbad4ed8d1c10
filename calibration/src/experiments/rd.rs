//! R_d calibration (paper §3.3.2): the δ → R_d tables the viewer's deformation uses.

use serde::Serialize;
use softhaptic_proto::calibration::CalibrationRow;
use softhaptic_proto::{CalibrationSource, CalibrationTable, Material, ToolShape};

use super::surface::{SurfaceComparison, compare_runs, surface_family};
use super::{
    ExperimentError, IndentationRun, MM, Mode, RD_BLOCK_M, RD_BREAKPOINT_M, RD_THRESHOLD_M,
    Resolution, RunCache, RunSpec, block_body, depths, paper_tools_10mm, spec, tool_description,
};
use crate::element::LawKind;
use crate::mesh::Symmetry;

/// One tool's R_d study.
#[derive(Debug, Clone, Serialize)]
pub struct RdStudy {
    pub tool_name: String,
    pub tool: ToolShape,
    pub runs: Vec<IndentationRun>,
    /// R_d of the elastic half-space at the same depths (docs/physics.md).
    pub half_space_m: Vec<f64>,
    /// The tables written for the scenes (one per material).
    pub tables: Vec<(String, CalibrationTable)>,
    /// The surface the viewer draws with the table against each run's top surface, at every
    /// depth up to δ = R.
    pub surface: Vec<SurfaceComparison>,
}

/// The formulations of the R_d study: the neo-Hookean one writes the tables; the two linear
/// ones show what the choice of formulation does to R_d and to the surface's shape.
pub const RD_LAWS: [LawKind; 3] = [
    LawKind::LinearDeformedContact,
    LawKind::LinearSmallDeformation,
    LawKind::NeoHookean,
];

/// Mesh and depths of the R_d study (also the block of the curvature study).
pub fn rd_setup(mode: Mode) -> (Resolution, Vec<f64>) {
    match mode {
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
    }
}

/// The block run of `tool` with `law` on the calibration block.
pub fn rd_run(mode: Mode, name: &str, tool: &ToolShape, law: LawKind) -> RunSpec {
    let (res, ds) = rd_setup(mode);
    let max_depth = ds.last().copied().unwrap_or(0.01);
    let body = block_body(RD_BLOCK_M, tool, max_depth, 0.0, res, Symmetry::Quarter);
    spec(
        format!("block 100×100×50 {name} {}", law.name()),
        body,
        tool,
        law,
        res,
        &ds,
        0.0,
    )
}

/// The FEM runs of the R_d study: sphere and cone of radius 10 mm, each formulation of
/// [`RD_LAWS`].
pub fn rd_runs(mode: Mode) -> Vec<RunSpec> {
    let mut out = Vec::new();
    for (name, tool) in paper_tools_10mm() {
        for law in RD_LAWS {
            out.push(rd_run(mode, name, &tool, law));
        }
    }
    out
}

/// The R_d calibration for the paper's sphere and cone (R = 10 mm, 45°), both linear
/// formulations and neo-Hookean; the tables come from the neo-Hookean run (large strain: the
/// depth reaches the tool radius). The surface the viewer draws with each table is then measured
/// against every run's top surface.
///
/// With the displacement imposed and no body force, the static solution of either law depends
/// on E only through the stress scale: the displacement field, hence R_d, is the same for 50 kPa
/// and 1.5 MPa (a test checks this). One solve per tool and law therefore serves both materials.
pub fn rd_table(mode: Mode, cache: &RunCache) -> Result<Vec<RdStudy>, ExperimentError> {
    let (res, ds) = rd_setup(mode);
    let mut studies = Vec::new();
    for (name, tool) in paper_tools_10mm() {
        let mut runs = Vec::new();
        for law in RD_LAWS {
            runs.push(
                cache
                    .get("rd-table", &rd_run(mode, name, &tool, law))?
                    .clone(),
            );
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
            // The surface the viewer's `fem` profile draws, from the same run as the rows.
            let surface = surface_family(&tool, nh).map_err(|e| ExperimentError::Data {
                study: format!("rd-table {name}"),
                reason: format!("tabulated surface refused: {e}"),
            })?;
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
                })?
                .with_surface(surface.clone());
                tables.push((file, table));
            }
        }
        // Both materials' tables hold the same rows (the solution does not depend on E), so the
        // first one stands for what the viewer draws.
        let surface = match tables.first() {
            Some((_, table)) => {
                compare_runs(&tool, &runs, RD_BLOCK_M[2], |d| table.deformed_radius_m(d))
            }
            None => Vec::new(),
        };
        studies.push(RdStudy {
            tool_name: name.to_owned(),
            tool,
            runs,
            half_space_m,
            tables,
            surface,
        });
    }
    Ok(studies)
}
