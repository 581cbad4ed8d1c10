//! Runs the mutation fuzzer (`softhaptic_tests::fuzz`) offline over every parser that takes
//! outside input and prints what each target saw. See `--help`.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use softhaptic_tests::fuzz::{self, Stats, TARGET_NAMES};

// Every input is held to its target's memory limit: this counts what each one allocates.
#[global_allocator]
static ALLOCATOR: fuzz::CountingAllocator = fuzz::CountingAllocator;

const HELP: &str = "\
fuzz-report: runs the mutation fuzzer over every parser that takes outside input.

USAGE:
    cargo run --release -p softhaptic-tests --bin fuzz-report -- [OPTIONS]

OPTIONS:
    --inputs N      inputs per target (default 100000)
    --target NAME   only this target (repeatable): scene, obj, calibration, limits, mcap, wire
    --seed N        generator seed (default 1); the same seed gives the same inputs
    --start N       first input index (default 0): input N is rebuilt from (seed, target, N)
                    alone, so a run that died of an abort resumes or reproduces from the last
                    index its progress printed
    --max-seconds S stop each target after S seconds (default: no limit); the table gives the
                    exact count run
    --crashes DIR   where inputs that panicked are saved (default target/fuzz-crashes), as
                    <target>-<hash>.<ext> with the panic in <target>-<hash>.panic.txt
    -h, --help      this text

Progress goes to stderr every few seconds; a table goes to stdout at the end: inputs run,
inputs per second, inputs accepted and refused, distinct refusal messages (digits removed),
crashes. Exits with status 1 if any input panicked, naming the saved files. An accepted scene
builds its collider (BVH, curvature) only when no earlier input gave the same mesh, collision
mode and curvature request; the count of builds is printed under the table.

A release build has no overflow checks; to count an overflow as the panic it is in a debug
build, run with CARGO_PROFILE_RELEASE_OVERFLOW_CHECKS=true and
CARGO_PROFILE_RELEASE_DEBUG_ASSERTIONS=true (and --target-dir target/fuzz, so the usual release
build is not rebuilt).";

struct Options {
    inputs: u64,
    targets: Vec<String>,
    seed: u64,
    start: u64,
    crashes: PathBuf,
    max_seconds: Option<u64>,
}

fn parse_args() -> anyhow::Result<Option<Options>> {
    let mut options = Options {
        inputs: 100_000,
        targets: Vec::new(),
        seed: 1,
        start: 0,
        crashes: fuzz::repo_root().join("target/fuzz-crashes"),
        max_seconds: None,
    };
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = || args.next().with_context(|| format!("{arg} needs a value"));
        match arg.as_str() {
            "-h" | "--help" => return Ok(None),
            "--inputs" => options.inputs = parse_count(&arg, &value()?)?,
            "--seed" => options.seed = parse_count(&arg, &value()?)?,
            "--start" => options.start = parse_count(&arg, &value()?)?,
            "--max-seconds" => options.max_seconds = Some(parse_count(&arg, &value()?)?),
            "--crashes" => options.crashes = PathBuf::from(value()?),
            "--target" => {
                let name = value()?;
                if !TARGET_NAMES.contains(&name.as_str()) {
                    bail!(
                        "--target: unknown target {name:?}; the targets are {}",
                        TARGET_NAMES.join(", ")
                    );
                }
                options.targets.push(name);
            }
            other => bail!("unknown argument {other:?} (see --help)"),
        }
    }
    Ok(Some(options))
}

/// A whole number, with `_` separators allowed (`10_000_000`).
fn parse_count(arg: &str, text: &str) -> anyhow::Result<u64> {
    text.replace('_', "")
        .parse()
        .with_context(|| format!("{arg}: expected a whole number ≥ 0, got {text:?}"))
}

fn main() -> ExitCode {
    match run() {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            eprintln!("fuzz-report: {e:#}");
            ExitCode::from(2)
        }
    }
}

/// A finished target's line of the table.
struct Row {
    name: &'static str,
    stats: Stats,
    elapsed: Duration,
}

/// Ok(true) when no input panicked.
fn run() -> anyhow::Result<bool> {
    let Some(options) = parse_args()? else {
        println!("{HELP}");
        return Ok(true);
    };
    let targets = fuzz::targets(&fuzz::repo_root()).map_err(anyhow::Error::msg)?;
    fuzz::install_quiet_panic_hook();
    let mut rows = Vec::new();
    for target in &targets {
        if !options.targets.is_empty() && !options.targets.iter().any(|t| t == target.name) {
            continue;
        }
        eprintln!(
            "{}: {} inputs from {} seeds, seed {}, starting at input {}",
            target.name,
            options.inputs,
            target.seeds.len(),
            options.seed,
            options.start
        );
        let started = Instant::now();
        let mut last_report = started;
        let budget = options.max_seconds.map(Duration::from_secs);
        let stats = fuzz::run(
            target,
            options.seed,
            options.start,
            options.inputs,
            &options.crashes,
            |stats| {
                // Checked every few hundred inputs; a clock read costs nothing beside a parse.
                if last_report.elapsed() >= Duration::from_secs(5) {
                    last_report = Instant::now();
                    let elapsed = started.elapsed().as_secs_f64();
                    eprintln!(
                        "{}: {} inputs (next index {}), {:.0}/s, {} crashes",
                        target.name,
                        stats.inputs,
                        options.start + stats.inputs,
                        stats.inputs as f64 / elapsed,
                        stats.crashes.len()
                    );
                }
                budget.is_none_or(|b| started.elapsed() < b)
            },
        );
        rows.push(Row {
            name: target.name,
            stats,
            elapsed: started.elapsed(),
        });
    }
    print_table(&rows);
    if rows.iter().any(|r| r.name == "scene") {
        println!(
            "scene: {} colliders built; every other accepted scene reused one built from the same \
             mesh, collision mode and curvature request",
            fuzz::scene_collider_builds()
        );
    }
    let crashes: Vec<&fuzz::Crash> = rows.iter().flat_map(|r| &r.stats.crashes).collect();
    for crash in &crashes {
        let saved = crash
            .saved
            .as_ref()
            .map(|p| p.display().to_string())
            .unwrap_or_else(|| "(not saved)".into());
        eprintln!(
            "crash at input {}: {} — {saved}",
            crash.index, crash.message
        );
    }
    Ok(crashes.is_empty())
}

fn print_table(rows: &[Row]) {
    println!(
        "{:<12} {:>12} {:>10} {:>12} {:>12} {:>10} {:>9} {:>8} {:>9}",
        "target",
        "inputs",
        "inputs/s",
        "accepted",
        "refused",
        "skipped",
        "distinct",
        "crashes",
        "peak MiB"
    );
    for row in rows {
        let s = &row.stats;
        let rate = s.inputs as f64 / row.elapsed.as_secs_f64().max(1e-9);
        println!(
            "{:<12} {:>12} {:>10.0} {:>12} {:>12} {:>10} {:>9} {:>8} {:>9}",
            row.name,
            s.inputs,
            rate,
            s.accepted,
            s.refused,
            s.skipped,
            s.distinct_errors.len(),
            s.crashes.len(),
            s.max_memory_bytes >> 20
        );
    }
}
