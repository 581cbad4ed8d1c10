//! Output: calibration tables (JSON), CSV series, SVG plots and the markdown report that puts
//! each figure beside the paper's.
//!
//! [`write_report`] here assembles `report.md` (`<command>.md` for one study) from one section
//! per experiment, each in the file named like the experiment's own under `experiments/` (`rd`, `surface`, `force`, `curvature`,
//! `inclination`, `hyperelastic`, `speed`, `limits`, `verification`, `poisson`). A section writes
//! its figures through `figure`: the numbers as a CSV (`figure::Columns`) and the chart drawn
//! from them as an SVG (`line_plot`, `scatter_plot`), so a reader can re-plot any figure.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use plotters::prelude::*;

use softhaptic_proto::ModelLimitsFile;
use softhaptic_proto::model::ToolKind;

use crate::element::LawKind;
use crate::experiments::JND_PERCENT;
use crate::experiments::force::{HyperelasticConstants, LayerCheck, RowKind, TransferCheck};
use crate::experiments::poisson::PoissonStudy;
use crate::experiments::surface::{DrawnProfile, DrawnSurface};
use crate::experiments::{
    CurvatureStudy, ForceDepthStudy, HyperelasticFit, InclinationStudy, Mode, RdStudy, RunTimings,
    SpeedAccuracyStudy, VerificationStudy,
};
use crate::solver::SurfacePoint;

mod curvature;
mod figure;
mod force;
mod hyperelastic;
mod inclination;
mod limits;
mod poisson;
mod rd;
mod speed;
mod surface;
mod verification;

use curvature::{curvature_models_section, curvature_section};
use figure::{Columns, Series, csv, line_plot, scatter_plot};
use force::force_section;
use hyperelastic::hyperelastic_section;
use inclination::{inclination_models_section, inclination_section};
use limits::limits_section;
use poisson::poisson_section;
use rd::rd_section;
use speed::speed_section;
use surface::surface_section;
use verification::verification_section;

const MM: f64 = 1e-3;

/// Errors while writing outputs; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("cannot write {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot encode {path}: {source}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    #[error("cannot draw {path}: {message}")]
    Plot { path: PathBuf, message: String },
}

fn write(path: &Path, text: &str) -> Result<(), ReportError> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| ReportError::Io {
            path: dir.to_owned(),
            source,
        })?;
    }
    std::fs::write(path, text).map_err(|source| ReportError::Io {
        path: path.to_owned(),
        source,
    })
}

/// Writes `value` as pretty JSON.
pub fn write_json(path: &Path, value: &impl serde::Serialize) -> Result<(), ReportError> {
    let text = serde_json::to_string_pretty(value).map_err(|source| ReportError::Json {
        path: path.to_owned(),
        source,
    })?;
    write(path, &(text + "\n"))
}

fn fmt_depth(d: Option<f64>) -> String {
    match d {
        Some(d) => format!("{:.2} mm", d / MM),
        None => "not reached".to_owned(),
    }
}

/// Results gathered by `all` (each experiment is optional so single commands reuse this).
#[derive(Default)]
pub struct Results {
    pub rd: Option<Vec<RdStudy>>,
    pub force: Option<Vec<ForceDepthStudy>>,
    pub hyperelastic: Option<HyperelasticFit>,
    pub transfer: Option<Vec<TransferCheck>>,
    pub curvature: Option<Vec<CurvatureStudy>>,
    pub inclination: Option<Vec<InclinationStudy>>,
    pub speed: Option<SpeedAccuracyStudy>,
    pub verification: Option<VerificationStudy>,
    pub limits: Option<ModelLimitsFile>,
    pub poisson: Option<PoissonStudy>,
    /// The FEM stage: runs, threads, wall and run times.
    pub fem: Option<RunTimings>,
    /// Wall time of the whole command, seconds (0 until it finishes).
    pub wall_seconds: f64,
    /// The subcommand that produced these results (`all`, `rd-table`, …), named in the report.
    pub command: String,
}

/// Writes CSV, SVG, JSON and the report under `dir`: `report.md` for `all`, `<command>.md` for a
/// single study, so that a study run on its own beside the committed report does not replace
/// the whole report with its one section. Returns the report path.
pub fn write_report(dir: &Path, mode: Mode, results: &Results) -> Result<PathBuf, ReportError> {
    let mut md = String::new();
    let _ = writeln!(md, "# Calibration report\n");
    let _ = writeln!(
        md,
        "Produced by `softhaptic-calibrate{} {}` (mode: {:?}). Static FEM, 10-node tetrahedra, \
         rigid frictionless indenters, bottom face clamped, side faces free, E = 50 kPa, ν = 0.33 \
         unless stated. Each figure stands beside the seed paper's (He & Choi).\n",
        if mode == Mode::Quick { " --quick" } else { "" },
        if results.command.is_empty() {
            "all"
        } else {
            &results.command
        },
        mode
    );
    if mode == Mode::Quick {
        let _ = writeln!(
            md,
            "> Quick mode: coarse meshes for an end-to-end check; do not quote these numbers.\n"
        );
    }
    timing_section(results, &mut md);
    if let Some(v) = &results.verification {
        verification_section(dir, v, &mut md)?;
    }
    if let Some(rd) = &results.rd {
        rd_section(dir, rd, &mut md)?;
        surface_section(dir, rd, &mut md)?;
    }
    if let Some(force) = &results.force {
        force_section(dir, force, &mut md)?;
    }
    if let Some(curv) = &results.curvature {
        curvature_section(dir, curv, &mut md)?;
    }
    if let Some(inc) = &results.inclination {
        inclination_section(dir, inc, &mut md)?;
    }
    if results.hyperelastic.is_some()
        || results.speed.is_some()
        || results.curvature.is_some()
        || results.limits.is_some()
    {
        corrections_intro(&mut md);
    }
    if let Some(fit) = &results.hyperelastic {
        hyperelastic_section(dir, fit, results.transfer.as_deref(), &mut md)?;
    }
    if let Some(speed) = &results.speed {
        speed_section(dir, speed, &mut md)?;
    }
    if let Some(curv) = &results.curvature {
        curvature_models_section(dir, curv, &mut md)?;
    }
    if let Some(inc) = &results.inclination {
        inclination_models_section(inc, &mut md);
    }
    if let Some(poisson) = &results.poisson {
        poisson_section(dir, poisson, &mut md)?;
    }
    if let Some(limits) = &results.limits {
        limits_section(limits, &mut md);
    }
    if let Some(fem) = &results.fem {
        runs_section(fem, results, &mut md);
    }
    let path = dir.join(report_file_name(&results.command));
    write(&path, &md)?;
    Ok(path)
}

/// `report.md` for `all` (or an unnamed command), `<command>.md` for one study.
fn report_file_name(command: &str) -> String {
    if command.is_empty() || command == "all" {
        "report.md".to_owned()
    } else {
        format!("{command}.md")
    }
}

/// Writes the R_d tables of every ν of the sweep but the paper's into `dir` as `<name>.json`.
pub fn write_poisson_tables(dir: &Path, study: &PoissonStudy) -> Result<Vec<PathBuf>, ReportError> {
    let mut out = Vec::new();
    for p in &study.points {
        for (name, table) in &p.tables {
            let path = dir.join(format!("{name}.json"));
            write_json(&path, table)?;
            out.push(path);
        }
    }
    Ok(out)
}

/// Writes the scene tables of an R_d study into `dir` as `<name>.json`.
pub fn write_tables(dir: &Path, studies: &[RdStudy]) -> Result<Vec<PathBuf>, ReportError> {
    let mut out = Vec::new();
    for s in studies {
        for (name, table) in &s.tables {
            let path = dir.join(format!("{name}.json"));
            write_json(&path, table)?;
            out.push(path);
        }
    }
    Ok(out)
}

/// The name of an FEM formulation in the report's prose and tables.
fn formulation_name(law: LawKind) -> &'static str {
    match law {
        LawKind::LinearSmallDeformation => "linear, small deformation",
        LawKind::LinearDeformedContact => "linear, contact on the deformed surface",
        LawKind::NeoHookean => "neo-Hookean",
    }
}

fn fmt_angle(a: Option<f64>) -> String {
    match a {
        Some(a) => format!("{:.1}°", a.to_degrees()),
        None => "not reached".to_owned(),
    }
}

fn fmt_ns(ns: f64) -> String {
    if ns < 1e5 {
        format!("{ns:.1} ns")
    } else {
        format!("{:.2} s", ns * 1e-9)
    }
}

fn timing_section(results: &Results, md: &mut String) {
    let Some(fem) = &results.fem else {
        return;
    };
    let _ = writeln!(
        md,
        "FEM stage: {} runs solved on {} threads in {:.1} s wall ({:.1} s of run time; {} \
         requests served from runs shared between studies). Whole command: {}.\n",
        fem.runs,
        fem.threads,
        fem.wall_seconds,
        fem.run_seconds,
        fem.shared,
        if results.wall_seconds > 0.0 {
            format!("{:.1} s wall", results.wall_seconds)
        } else {
            "still running".to_owned()
        }
    );
}

fn corrections_intro(md: &mut String) {
    let _ = writeln!(md, "## Corrections beyond the paper\n");
    let _ = writeln!(
        md,
        "The runtime (`softhaptic_device::model::ForceModel`) multiplies the paper's law by the \
         corrections a scene turns on (docs/physics.md): the exact sphere (Sneddon), a layer of \
         finite thickness on a rigid base (Dimitriadis; Garcia & Garcia for the cone; bonded, times a \
         residual fitted here to the small-deformation FEM over ν), the object's curvature (Johnson), the tool's inclination, and a hyperelastic factor fitted here. \
         Every model below is that very `ForceModel`, built from its `ModelSpec` and evaluated \
         as the 1 kHz loop evaluates it; the reference is the neo-Hookean FEM unless stated.\n"
    );
}

/// A compact, comma-free name of a spec for CSV headers.
fn spec_tag(spec: &softhaptic_proto::ModelSpec) -> String {
    if spec.is_paper() {
        "paper".to_owned()
    } else {
        spec.corrections().join("+")
    }
}

/// "0°, 10°, 20°".
fn degrees_list(angles_rad: &[f64]) -> String {
    angles_rad
        .iter()
        .map(|a| format!("{:.0}°", a.to_degrees()))
        .collect::<Vec<_>>()
        .join(", ")
}

fn runs_section(fem: &RunTimings, results: &Results, md: &mut String) {
    let _ = writeln!(md, "## Where the time goes\n");
    let _ = writeln!(
        md,
        "{} FEM runs on {} threads: {:.1} s wall, {:.1} s of run time. The linear laws' \
         stiffness does not change during a run, so it is factorised once, without contact, and \
         each Newton iteration solves the contact as a small dense system on the contacted \
         nodes' columns of its inverse (`solver::ContactModel::constant_stiffness_increment`): \
         the same increments to rounding, two triangular solves instead of a factorisation. The \
         neo-Hookean tangent is factorised in every Newton iteration, which profiling (perf) \
         puts at most of such a run (dense supernodal kernels); the fill-reducing ordering is a \
         geometric nested dissection of the structured grid \
         (`sparse::nested_dissection_order`), which halves the factorisation against minimum \
         degree. Runs shared between studies are solved once; independent runs go to the cores \
         longest first.\n",
        fem.runs, fem.threads, fem.wall_seconds, fem.run_seconds
    );
    let mut runs: Vec<&crate::experiments::IndentationRun> = Vec::new();
    if let Some(v) = &results.rd {
        runs.extend(v.iter().flat_map(|s| &s.runs));
    }
    if let Some(v) = &results.force {
        runs.extend(v.iter().flat_map(|s| &s.runs));
    }
    if let Some(v) = &results.curvature {
        runs.extend(v.iter().flat_map(|s| s.laws.iter().flat_map(|l| &l.balls)));
    }
    if let Some(v) = &results.inclination {
        runs.extend(v.iter().flat_map(|s| &s.runs));
    }
    let mut seen = std::collections::HashSet::new();
    runs.retain(|r| seen.insert(r.label.clone()));
    if runs.is_empty() {
        return;
    }
    let _ = writeln!(
        md,
        "| run | unknowns | factor entries | steps | Newton iterations | time (s) |\n|---|---|---|---|---|---|"
    );
    for r in runs {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {:.1} |",
            r.label,
            r.dofs,
            r.factor_entries,
            r.depths_m.len(),
            r.newton_iterations.iter().sum::<usize>(),
            r.step_seconds.iter().sum::<f64>()
        );
    }
    md.push('\n');
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn a_single_study_writes_its_own_report_beside_the_whole_one() {
        let dir = std::env::temp_dir().join(format!("softhaptic-report-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("report.md"), "the whole report").unwrap();
        let poisson = Results {
            command: "poisson".to_owned(),
            ..Results::default()
        };
        let path = write_report(&dir, Mode::Quick, &poisson).unwrap();
        assert_eq!(path, dir.join("poisson.md"));
        assert!(
            std::fs::read_to_string(&path)
                .unwrap()
                .contains("softhaptic-calibrate --quick poisson")
        );
        assert_eq!(
            std::fs::read_to_string(dir.join("report.md")).unwrap(),
            "the whole report"
        );
        let all = Results {
            command: "all".to_owned(),
            ..Results::default()
        };
        assert_eq!(
            write_report(&dir, Mode::Quick, &all).unwrap(),
            dir.join("report.md")
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
