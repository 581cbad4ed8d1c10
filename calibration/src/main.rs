//! `softhaptic-calibrate`: runs the offline FEM experiments and writes tables and reports.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use softhaptic_calibration::experiments::{self, Mode, RunCache};
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
    /// Directory for the report, CSV and SVG files.
    #[arg(long, global = true, default_value = "calibration/report")]
    out: PathBuf,
    /// Directory the R_d tables are written to (full mode). Quick runs write their tables under
    /// `<out>/tables` instead, so a quick run never replaces the scenes' tables.
    #[arg(long, global = true, default_value = "scenes/calibration")]
    tables: PathBuf,
    /// Worker threads for the sparse factorisation (1 = sequential).
    #[arg(long, global = true, default_value_t = 1)]
    threads: usize,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// δ → R_d tables (paper §3.3.2) for the sphere and cone of radius 10 mm.
    RdTable,
    /// Force against depth, FEM against Hertz / Sneddon (paper §4.3).
    ForceDepth,
    /// Balls of radius 30, 50, 100 mm against the block (paper §3.2, eq. 6).
    Curvature,
    /// Tilted tools (paper §3.2, eq. 7).
    Inclination,
    /// Time per force evaluation against force error, every model.
    SpeedAccuracy,
    /// Verification: Hertz on a large block, half-space profile, patch tests.
    Verify,
    /// Everything, then the report.
    All,
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let par = match std::num::NonZeroUsize::new(cli.threads) {
        Some(n) if n.get() > 1 => faer::Par::Rayon(n),
        _ => faer::Par::Seq,
    };
    faer::set_global_parallelism(par);
    let mode = if cli.quick { Mode::Quick } else { Mode::Full };
    let tables_dir = match mode {
        Mode::Quick => cli.out.join("tables"),
        Mode::Full => cli.tables.clone(),
    };
    let mut results = Results {
        command: match cli.command {
            Command::RdTable => "rd-table",
            Command::ForceDepth => "force-depth",
            Command::Curvature => "curvature",
            Command::Inclination => "inclination",
            Command::SpeedAccuracy => "speed-accuracy",
            Command::Verify => "verify",
            Command::All => "all",
        }
        .to_owned(),
        ..Results::default()
    };
    let mut cache = RunCache::default();
    let (verify, rd, force, curv, incl, speed) = match cli.command {
        Command::Verify => (true, false, false, false, false, false),
        Command::RdTable => (false, true, false, false, false, false),
        Command::ForceDepth => (false, false, true, false, false, false),
        Command::Curvature => (false, false, false, true, false, false),
        Command::Inclination => (false, false, false, false, true, false),
        Command::SpeedAccuracy => (false, false, false, false, false, true),
        Command::All => (true, true, true, true, true, true),
    };
    if verify {
        let t = Instant::now();
        results.verification = Some(experiments::verification(mode).context("verify")?);
        results
            .timings_s
            .push(("verify".into(), t.elapsed().as_secs_f64()));
        report::write_report(&cli.out, mode, &results)?;
    }
    if rd {
        let t = Instant::now();
        let studies = experiments::rd_table(mode).context("rd-table")?;
        let written = report::write_tables(&tables_dir, &studies)?;
        for path in &written {
            tracing::info!(path = %path.display(), "calibration table written");
        }
        results
            .timings_s
            .push(("rd-table".into(), t.elapsed().as_secs_f64()));
        results.rd = Some(studies);
        // Written after every stage so a long run leaves its finished parts behind.
        report::write_report(&cli.out, mode, &results)?;
    }
    if force {
        let t = Instant::now();
        results.force = Some(experiments::force_depth(mode, &mut cache).context("force-depth")?);
        results
            .timings_s
            .push(("force-depth".into(), t.elapsed().as_secs_f64()));
        report::write_report(&cli.out, mode, &results)?;
    }
    if speed {
        let t = Instant::now();
        results.speed =
            Some(experiments::speed_accuracy(mode, &mut cache).context("speed-accuracy")?);
        results
            .timings_s
            .push(("speed-accuracy".into(), t.elapsed().as_secs_f64()));
        report::write_report(&cli.out, mode, &results)?;
    }
    if curv {
        let t = Instant::now();
        results.curvature = Some(experiments::curvature(mode).context("curvature")?);
        results
            .timings_s
            .push(("curvature".into(), t.elapsed().as_secs_f64()));
        report::write_report(&cli.out, mode, &results)?;
    }
    if incl {
        let t = Instant::now();
        results.inclination = Some(experiments::inclination(mode).context("inclination")?);
        results
            .timings_s
            .push(("inclination".into(), t.elapsed().as_secs_f64()));
        report::write_report(&cli.out, mode, &results)?;
    }
    let path = report::write_report(&cli.out, mode, &results)?;
    tracing::info!(path = %path.display(), "report written");
    println!("{}", path.display());
    Ok(())
}
