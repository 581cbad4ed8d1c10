//! `softhaptic-calibrate`: runs the offline FEM experiments and writes tables and reports.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use softhaptic_calibration::experiments::{self, Mode, RunCache, RunSpec};
use softhaptic_calibration::report::{self, Results};

#[derive(Parser)]
#[command(
    name = "softhaptic-calibrate",
    version,
    about = "Offline FEM calibration and the paper's experiments"
)]
struct Cli {
    /// Coarse meshes and fewer samples: the whole suite in about a minute (numbers not to quote).
    #[arg(long, global = true)]
    quick: bool,
    /// Directory for the report, CSV and SVG files [default: calibration/report, the committed
    /// report; with --quick, target/calibration-quick, so that quick numbers never replace it].
    #[arg(long, global = true)]
    out: Option<PathBuf>,
    /// Directory the R_d tables and (by `all`) the model limits are written to (full mode).
    /// Quick runs write theirs under `<out>/tables` instead, so a quick run never replaces the
    /// scenes' files.
    #[arg(long, global = true, default_value = "scenes/calibration")]
    tables: PathBuf,
    /// FEM runs solved at once, one per thread (default: the machine's cores).
    #[arg(long, global = true)]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Clone, Copy, PartialEq, Eq)]
enum Command {
    /// δ → R_d tables (paper §3.3.2) for the sphere and cone of radius 10 mm.
    RdTable,
    /// Force against depth, FEM against Hertz / Sneddon (paper §4.3).
    ForceDepth,
    /// Balls of radius 30, 50, 100 mm against the block (paper §3.2, eq. 6), and the
    /// curvature-corrected runtime models against the balls.
    Curvature,
    /// Tilted tools (paper §3.2, eq. 7), and the inclination-corrected cone.
    Inclination,
    /// The hyperelastic fit, then time per force evaluation against force error for every
    /// runtime model; writes the model limits.
    SpeedAccuracy,
    /// Verification: Hertz on a large block, half-space profile, patch tests.
    Verify,
    /// Poisson's ratio 0.30 … 0.49: the hyperelastic factor, the bonded-layer factor and the
    /// R_d tables at each ν.
    Poisson,
    /// Everything, then the report.
    All,
    /// Palpation: the force-ratio table of a stiffer inclusion (written beside the R_d tables
    /// as inclusion_sphere10_50kpa.json), its error on held-out FEM cases and the
    /// perceptibility table, printed beside their goals and written to `<out>` as `<command>.md`, like one study's report.
    /// Not part of `all`.
    Inclusion {
        /// Validate the table already written (same study) instead of solving it again.
        #[arg(long)]
        reuse_table: bool,
    },
}

impl Command {
    fn name(self) -> &'static str {
        match self {
            Command::RdTable => "rd-table",
            Command::ForceDepth => "force-depth",
            Command::Curvature => "curvature",
            Command::Inclination => "inclination",
            Command::SpeedAccuracy => "speed-accuracy",
            Command::Verify => "verify",
            Command::Poisson => "poisson",
            Command::All => "all",
            Command::Inclusion { .. } => "inclusion",
        }
    }
}

/// Which experiments a command runs.
struct Plan {
    verify: bool,
    rd: bool,
    force: bool,
    speed: bool,
    curvature: bool,
    inclination: bool,
    poisson: bool,
}

impl Plan {
    fn of(command: Command) -> Self {
        let all = command == Command::All;
        Plan {
            verify: all || command == Command::Verify,
            rd: all || command == Command::RdTable,
            force: all || command == Command::ForceDepth,
            speed: all || command == Command::SpeedAccuracy,
            curvature: all || command == Command::Curvature,
            inclination: all || command == Command::Inclination,
            poisson: all || command == Command::Poisson,
        }
    }

    fn runs(&self, mode: Mode) -> Vec<RunSpec> {
        let mut runs = Vec::new();
        if self.verify {
            runs.extend(experiments::verification_runs(mode));
        }
        if self.rd {
            runs.extend(experiments::rd_runs(mode));
        }
        if self.force {
            runs.extend(experiments::force_runs(mode));
        }
        if self.speed {
            runs.extend(experiments::speed_accuracy_runs(mode));
        }
        if self.curvature {
            runs.extend(experiments::curvature_runs(mode));
        }
        if self.inclination {
            runs.extend(experiments::inclination_runs(mode));
        }
        if self.poisson {
            runs.extend(experiments::poisson_runs(mode));
        }
        runs
    }
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .init();
    let started = Instant::now();
    let cli = Cli::parse();
    let mode = if cli.quick { Mode::Quick } else { Mode::Full };
    let out = cli.out.clone().unwrap_or_else(|| match mode {
        Mode::Quick => PathBuf::from("target/calibration-quick"),
        Mode::Full => PathBuf::from("calibration/report"),
    });
    let tables_dir = match mode {
        Mode::Quick => out.join("tables"),
        Mode::Full => cli.tables.clone(),
    };
    let threads = cli.threads.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    });
    if let Command::Inclusion { reuse_table } = cli.command {
        let report =
            inclusion_command(mode == Mode::Quick, reuse_table, &tables_dir, &out, threads)?;
        println!("{report}");
        return Ok(());
    }
    let plan = Plan::of(cli.command);
    let mut results = Results {
        command: cli.command.name().to_owned(),
        ..Results::default()
    };

    // Every FEM run the command needs, each solved once, all cores busy.
    let mut cache = RunCache::new(threads);
    let specs = plan.runs(mode);
    tracing::info!(runs = specs.len(), threads, "solving the FEM runs");
    cache.ensure(&specs).context("FEM runs")?;
    results.fem = Some(cache.timings().clone());
    tracing::info!(
        wall_s = cache.timings().wall_seconds,
        run_s = cache.timings().run_seconds,
        runs = cache.timings().runs,
        "FEM runs solved"
    );

    // The studies read the finished runs; the report is rewritten after each so that a failure
    // leaves the finished parts behind.
    if plan.verify {
        results.verification = Some(experiments::verification(mode, &cache).context("verify")?);
        report::write_report(&out, mode, &results)?;
    }
    if plan.rd {
        let studies = experiments::rd_table(mode, &cache).context("rd-table")?;
        for path in report::write_tables(&tables_dir, &studies)? {
            tracing::info!(path = %path.display(), "calibration table written");
        }
        results.rd = Some(studies);
        report::write_report(&out, mode, &results)?;
    }
    if plan.force {
        results.force = Some(experiments::force_depth(mode, &cache).context("force-depth")?);
        report::write_report(&out, mode, &results)?;
    }
    if plan.speed {
        results.hyperelastic =
            Some(experiments::hyperelastic_fit(mode, &cache).context("hyperelastic fit")?);
        results.speed = Some(experiments::speed_accuracy(mode, &cache).context("speed-accuracy")?);
        report::write_report(&out, mode, &results)?;
    }
    if let Some(rd) = &results.rd {
        results.transfer =
            Some(experiments::force::transfer_check(rd).context("hyperelastic transfer check")?);
    }
    if plan.curvature {
        results.curvature = Some(experiments::curvature(mode, &cache).context("curvature")?);
        report::write_report(&out, mode, &results)?;
    }
    if plan.inclination {
        results.inclination = Some(experiments::inclination(mode, &cache).context("inclination")?);
        report::write_report(&out, mode, &results)?;
    }
    if plan.poisson {
        let study = experiments::poisson_study(mode, &cache).context("poisson")?;
        for path in report::write_poisson_tables(&tables_dir, &study)? {
            tracing::info!(path = %path.display(), "calibration table written");
        }
        results.poisson = Some(study);
        report::write_report(&out, mode, &results)?;
    }
    if cli.command == Command::Poisson {
        // `poisson` alone refreshes the entries measured over ν in the limits file beside the
        // tables, keeping those of the paper's ν (which only `all` measures).
        let path = tables_dir.join("model_limits.json");
        let existing = match std::fs::read_to_string(&path) {
            Ok(text) => serde_json::from_str(&text)
                .with_context(|| format!("{} does not parse", path.display()))?,
            Err(_) => softhaptic_proto::ModelLimitsFile {
                version: softhaptic_proto::ModelLimitsFile::VERSION,
                threshold_percent: experiments::JND_PERCENT,
                limits: Vec::new(),
            },
        };
        let fresh = experiments::limits::poisson_limits(results.poisson.as_ref(), None)
            .context("model limits over ν")?;
        let merged = experiments::limits::merge_poisson_limits(existing, fresh);
        report::write_json(&path, &merged)?;
        tracing::info!(path = %path.display(), entries = merged.limits.len(), "model limits over ν written");
    }
    if cli.command == Command::Inclination
        && let Some(studies) = &results.inclination
    {
        // `inclination` alone refreshes the angles of the limits file beside the tables (every
        // entry's, those measured over ν included), keeping its depth limits, which only `all`
        // measures.
        let path = tables_dir.join("model_limits.json");
        match std::fs::read_to_string(&path) {
            Ok(text) => {
                let existing: softhaptic_proto::ModelLimitsFile = serde_json::from_str(&text)
                    .with_context(|| format!("{} does not parse", path.display()))?;
                let refreshed = experiments::limits::refresh_inclination_limits(existing, studies);
                report::write_json(&path, &refreshed)?;
                tracing::info!(path = %path.display(), entries = refreshed.limits.len(), "inclination limits refreshed");
            }
            Err(error) => tracing::warn!(
                path = %path.display(),
                %error,
                "no limits file to refresh the inclination limits of (run `all` to write one)"
            ),
        }
    }
    if results.speed.is_some() || results.curvature.is_some() {
        let limits = experiments::model_limits(
            results.speed.as_ref(),
            results.curvature.as_deref(),
            results.inclination.as_deref(),
            results.poisson.as_ref(),
        )
        .context("model limits")?;
        // Only `all` measures every model the file lists, so only `all` replaces the file the
        // scenes load; a single study writes its part beside its report.
        let path = if cli.command == Command::All {
            tables_dir.join("model_limits.json")
        } else {
            out.join("model_limits.json")
        };
        report::write_json(&path, &limits)?;
        tracing::info!(path = %path.display(), entries = limits.limits.len(), "model limits written");
        results.limits = Some(limits);
    }
    results.wall_seconds = started.elapsed().as_secs_f64();
    let path = report::write_report(&out, mode, &results)?;
    tracing::info!(
        path = %path.display(),
        wall_s = results.wall_seconds,
        "report written"
    );
    println!("{}", path.display());
    Ok(())
}

/// `inclusion`: the table, its held-out validation and the perceptibility table (module
/// `softhaptic_calibration::inclusion`); returns the markdown it wrote.
fn inclusion_command(
    quick: bool,
    reuse_table: bool,
    tables_dir: &std::path::Path,
    out: &std::path::Path,
    threads: usize,
) -> Result<String> {
    use softhaptic_calibration::inclusion::{
        self as inc, CONTRAST_GOAL_PERCENT, DISCRIMINATION_THRESHOLD, FORCE_GOAL_PERCENT,
    };
    let study = inc::scene_study(quick);
    let started = Instant::now();
    let path = tables_dir.join("inclusion_sphere10_50kpa.json");
    let table = if reuse_table {
        let table: softhaptic_proto::InclusionTable = serde_json::from_str(
            &std::fs::read_to_string(&path).with_context(|| path.display().to_string())?,
        )
        .with_context(|| path.display().to_string())?;
        anyhow::ensure!(
            table.depths_m() == study.depths_m.as_slice()
                && table.offsets_m() == study.offsets_m.as_slice()
                && table.centre_depths_m() == study.centre_depths_m.as_slice()
                && table.stiffness_ratios() == study.stiffness_ratios.as_slice(),
            "{} is not this study's table (was it written with or without --quick?)",
            path.display()
        );
        table
    } else {
        let table = inc::build_table(&study, threads).context("inclusion table")?;
        std::fs::create_dir_all(tables_dir)?;
        report::write_json(&path, &table)?;
        tracing::info!(path = %path.display(), "inclusion table written");
        table
    };
    let table_s = started.elapsed().as_secs_f64();
    let started = Instant::now();
    let held =
        inc::validate(&study, &table, &inc::held_out_cases(), threads).context("held-out cases")?;
    let held_s = started.elapsed().as_secs_f64();
    let mut md = String::from("# Palpation: inclusion table, validation, perceptibility\n\n");
    md += &format!(
        "{}{}{} FEM cases tabulated in {table_s:.0} s; {} held-out cases solved in {held_s:.0} s on {threads} threads.\n\n",
        if quick {
            "QUICK MODE (coarse mesh, not to quote). "
        } else {
            ""
        },
        if reuse_table {
            "Table reused, not solved again: "
        } else {
            ""
        },
        study.cases().len() + 1,
        held.len()
    );
    md += &format!(
        "## Held-out cases (goal: force within {FORCE_GOAL_PERCENT} %, contrast within {CONTRAST_GOAL_PERCENT} % where it is at least 0.05)\n\n| offset mm | centre depth mm | ratio | max force error % | max contrast error % | FEM contrast at 1..6 mm |\n|---|---|---|---|---|---|\n"
    );
    let (mut worst_force, mut worst_contrast) = (0.0_f64, 0.0_f64);
    for h in &held {
        let f = h.max_force_error_percent();
        let c = h.max_contrast_error_percent(0.05);
        worst_force = worst_force.max(f);
        worst_contrast = worst_contrast.max(c);
        let contrasts: Vec<String> = h.fem_contrast.iter().map(|v| format!("{v:.3}")).collect();
        md += &format!(
            "| {:.1} | {:.1} | {:.1} | {f:.2} | {c:.1} | {} |\n",
            h.case.offset_m * 1e3,
            h.case.centre_depth_m * 1e3,
            h.case.stiffness_ratio,
            contrasts.join(" ")
        );
    }
    md += &format!(
        "\nWorst force error {worst_force:.2} % (goal {FORCE_GOAL_PERCENT} %), worst contrast error {worst_contrast:.1} % (goal {CONTRAST_GOAL_PERCENT} %).\n\n"
    );
    for depth_mm in [2.0, 4.0, 6.0] {
        let rows = inc::perceptibility(&table, depth_mm * 1e-3).context("perceptibility")?;
        md += &format!(
            "## Contrast above the centre at {depth_mm} mm indentation (perceptible at >= {DISCRIMINATION_THRESHOLD}; * marks perceptible)\n\n| centre depth mm |"
        );
        for k in table.stiffness_ratios() {
            md += &format!(" ratio {k} |");
        }
        md += "\n|---|";
        md += &"---|".repeat(table.stiffness_ratios().len());
        md += "\n";
        for (row, centre) in rows.iter().zip(table.centre_depths_m()) {
            md += &format!("| {:.0} |", centre * 1e3);
            for v in row {
                let mark = if *v >= DISCRIMINATION_THRESHOLD {
                    "*"
                } else {
                    ""
                };
                md += &format!(" {v:.3}{mark} |");
            }
            md += "\n";
        }
        md += "\n";
    }
    std::fs::create_dir_all(out)?;
    // `<command>.md`, as one study of the other commands writes its report.
    std::fs::write(
        out.join(format!("{}.md", Command::Inclusion { reuse_table }.name())),
        &md,
    )?;
    Ok(md)
}
