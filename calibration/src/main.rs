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
