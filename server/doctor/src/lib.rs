//! `softhaptic doctor`: is this machine ready to run the 1 kHz haptic loop, and if not, what
//! exactly to change.
//!
//! Stock Linux runs the loop within its period error goal most of the time and still loses a few
//! ticks a minute to kernel work that does not yield, to interrupts and to neighbours; the remedies
//! belong to the machine (a preemptible or PREEMPT_RT kernel, a CPU kept for the loop, interrupts
//! moved off it, real-time limits for the user) and are the same for every lab. The doctor reads
//! what decides them and prints, for each item, what it found, whether that is good for the loop,
//! and the fix ([`checks`]); then it runs the server's own loop for a few seconds, idle and beside
//! a loaded neighbour, and sets its lost ticks and period error beside the goal ([`timing`]).
//!
//! It reads `/proc`, `/sys`, `/etc/passwd`, `/boot/config-*` and `/dev` (through a [`Tree`], so
//! tests point it at a copy), tries the haptic devices as `softhaptic devices` does, and changes
//! nothing on the machine.
//!
//! Exit status ([`EXIT_STATUS_HELP`]): 0 when the host is ready, 1 with warnings or an item
//! that could not be read (what the doctor cannot see, it cannot call ready), 2 when the loop
//! cannot run as configured (a refused SCHED_FIFO, a CPU the process cannot use, a loop that
//! does not start) or the doctor itself could not run (a bad option, the report not written):
//! a script that sees 2 without a report on stdout knows it is the second kind.
//!
//! # Layout
//! - here: the report, its items and verdicts, the exit status, `softhaptic doctor`'s options
//!   and its run;
//! - [`checks`]: one file per concern (kernel, CPUs, interrupts, limits, devices, and the formats
//!   they share), each reading a [`Tree`];
//! - [`timing`]: the loop measured idle and under load, on the scene's world and device
//!   (`softhaptic-scene`);
//! - `tests.rs`: the checks on fake machine trees, and `stock_verdicts.rs` the verdicts on stock
//!   kernels.

pub mod checks;
#[cfg(test)]
mod tests;
pub mod timing;

use softhaptic_io::logging;

use std::fmt::Write as _;
use std::path::PathBuf;

use serde::Serialize;
use softhaptic_device::openhaptics::{self, Calibration, Discovery};
use softhaptic_device::rt::CpuChoice;
use softhaptic_device::spacemouse::hid;

pub use checks::{DeviceFacts, OpenHapticsFacts, Tree};

/// How good an item is for the loop, from best to worst.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// Good for a 1 kHz loop.
    Good,
    /// Nothing to judge here (not applicable, or not requested).
    Info,
    /// Could not be read: not shown to be good, so it counts as a warning.
    Unknown,
    /// The loop runs, but this costs it ticks or timing.
    Warn,
    /// The loop cannot run as configured.
    Fail,
}

impl Verdict {
    /// The tag printed before an item.
    fn tag(self) -> &'static str {
        match self {
            Verdict::Good => " ok ",
            Verdict::Info => "info",
            Verdict::Unknown => " ?? ",
            Verdict::Warn => "WARN",
            Verdict::Fail => "FAIL",
        }
    }
}

/// One inspected item.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Check {
    /// A stable name for scripts (`preemption`, `sched_fifo`, …).
    pub id: &'static str,
    pub title: &'static str,
    pub verdict: Verdict,
    /// What was found, with where it was read.
    pub found: String,
    /// What it does to the loop when it is not good.
    pub why: String,
    /// The change that makes it good.
    pub fix: Option<String>,
}

impl Check {
    pub fn new(
        id: &'static str,
        title: &'static str,
        verdict: Verdict,
        found: String,
        why: &str,
        fix: Option<String>,
    ) -> Self {
        Self {
            id,
            title,
            verdict,
            found,
            why: why.to_owned(),
            fix,
        }
    }
}

/// How the loop would be run: the options of `softhaptic run` that decide it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LoopPlan {
    /// SCHED_FIFO and locked memory requested (`run` without `--no-realtime`).
    pub realtime: bool,
    pub cpu: CpuChoice,
}

impl Default for LoopPlan {
    /// As `softhaptic run` runs it by default.
    fn default() -> Self {
        Self {
            realtime: true,
            cpu: CpuChoice::Unpinned,
        }
    }
}

/// The exit statuses, as `softhaptic doctor --help` prints them after the options.
pub const EXIT_STATUS_HELP: &str = "\
Exit status:
  0  ready: every item good (or information only), and the loop met its goal when measured
  1  warnings: the loop runs, but an item costs it ticks or timing, or could not be read
  2  cannot run: the loop cannot run as configured (the FAIL items say why), or the doctor
     itself could not run (a bad option, the report not written: the reason on stderr and no
     report on stdout)";

/// The command line of `softhaptic doctor`.
#[derive(clap::Args, Debug, Clone)]
#[command(after_help = EXIT_STATUS_HELP)]
pub struct DoctorArgs {
    /// Print the report as JSON, for scripts.
    #[arg(long)]
    pub json: bool,
    /// Skip the loop-timing measurement.
    #[arg(long)]
    pub no_timing: bool,
    /// Length of each of the three timing runs (idle, beside CPU-burning threads, beside a disk
    /// writer), seconds (0.2 to 600).
    #[arg(long, default_value_t = 3.0, value_name = "S", value_parser = parse_seconds)]
    pub seconds: f64,
    /// Check the loop as `run --no-realtime` would run it.
    #[arg(long)]
    pub no_realtime: bool,
    /// Check the loop on this CPU, as `run --loop-cpu` would place it: `none`, `auto`, `last`
    /// or a CPU number.
    #[arg(long, default_value = "none", value_name = "CPU")]
    pub loop_cpu: CpuChoice,
    /// Read /proc, /sys, /etc, /boot and /dev under this directory instead of / (a copy of
    /// another machine's files); the device search and the timing still run here.
    #[arg(long, value_name = "DIR", default_value = "/")]
    pub root: PathBuf,
    /// Where the disk writer of the timing's third run writes its scratch file (removed after):
    /// the session recordings' directory, on the disk the host writes to [default: `sessions`
    /// when it exists, else the system's temporary directory].
    #[arg(long, value_name = "DIR")]
    pub record_dir: Option<PathBuf>,
}

fn parse_seconds(text: &str) -> Result<f64, String> {
    let s: f64 = text
        .parse()
        .map_err(|_| format!("{text:?} is not a number of seconds"))?;
    if (0.2..=600.0).contains(&s) {
        Ok(s)
    } else {
        Err(format!("{s} s is outside 0.2 to 600 s"))
    }
}

/// The whole report.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// `ready`, `warnings` or `cannot_run`.
    pub status: &'static str,
    pub exit_code: i32,
    pub checks: Vec<Check>,
    pub timing: Option<timing::Timing>,
}

impl Report {
    pub fn new(checks: Vec<Check>, timing: Option<timing::Timing>) -> Self {
        let worst = checks
            .iter()
            .map(|c| c.verdict)
            .chain(timing.as_ref().map(|t| t.verdict))
            .max()
            .unwrap_or(Verdict::Good);
        // An item that could not be read is not shown to be good: calling the host ready would
        // promise what nothing checked.
        let (status, exit_code) = match worst {
            Verdict::Fail => ("cannot_run", EXIT_CANNOT_RUN),
            Verdict::Warn | Verdict::Unknown => ("warnings", 1),
            Verdict::Good | Verdict::Info => ("ready", 0),
        };
        Self {
            status,
            exit_code,
            checks,
            timing,
        }
    }

    fn count(&self, v: Verdict) -> usize {
        self.checks.iter().filter(|c| c.verdict == v).count()
            + usize::from(self.timing.as_ref().is_some_and(|t| t.verdict == v))
    }

    /// The titles of the items that could not be read.
    fn unread(&self) -> Vec<&'static str> {
        self.checks
            .iter()
            .filter(|c| c.verdict == Verdict::Unknown)
            .map(|c| c.title)
            .chain(
                self.timing
                    .as_ref()
                    .filter(|t| t.verdict == Verdict::Unknown)
                    .map(|_| "Loop timing"),
            )
            .collect()
    }
}

/// The status of a loop that cannot run as configured, and of a doctor that could not run.
pub const EXIT_CANNOT_RUN: i32 = 2;

/// What OpenHaptics and hidapi find here, as `softhaptic devices` finds it.
pub fn device_facts() -> DeviceFacts {
    let openhaptics = match openhaptics::discover(&[]) {
        Discovery::NoLibrary(e) => OpenHapticsFacts::NoLibrary(e.to_string()),
        Discovery::Library { path, devices } => OpenHapticsFacts::Library {
            path,
            devices: devices
                .into_iter()
                .map(|(name, result)| {
                    let result = result
                        .map(|(d, calibration)| {
                            format!(
                                "{}, serial {}, {}",
                                if d.model.is_empty() { "?" } else { &d.model },
                                if d.serial.is_empty() { "?" } else { &d.serial },
                                match calibration {
                                    Calibration::Ok => "calibrated",
                                    Calibration::NeedsUpdate => "calibration updated at start",
                                    Calibration::NeedsManualInput =>
                                        "needs calibration (stylus in its inkwell)",
                                }
                            )
                        })
                        .map_err(|e| e.to_string());
                    (name, result)
                })
                .collect(),
        },
    };
    DeviceFacts {
        openhaptics,
        spacemice: hid::list(),
    }
}

/// Inspects the host (and measures the loop unless `--no-timing`), prints the report, and
/// returns the exit status. A doctor that could not finish (its report not written) says why
/// on stderr and returns [`EXIT_CANNOT_RUN`] rather than an error, which the command line would
/// turn into 1 and so into "warnings".
pub fn run(args: &DoctorArgs) -> anyhow::Result<i32> {
    Ok(report(args).unwrap_or_else(|e| {
        eprintln!("error: {}", logging::error_text(e.as_ref()));
        EXIT_CANNOT_RUN
    }))
}

fn report(args: &DoctorArgs) -> anyhow::Result<i32> {
    let plan = LoopPlan {
        realtime: !args.no_realtime,
        cpu: args.loop_cpu,
    };
    let tree = Tree::new(&args.root);
    let disk_dir = args.record_dir.clone().unwrap_or_else(|| {
        let sessions = PathBuf::from("sessions");
        if sessions.is_dir() {
            sessions
        } else {
            std::env::temp_dir()
        }
    });
    // A directory named for the disk run that is not there is the command line's mistake, told
    // before the inspection rather than as a timing run that failed.
    anyhow::ensure!(
        args.no_timing || disk_dir.is_dir(),
        "--record-dir {}: no such directory (the server makes the recordings' directory when it \
         first starts)",
        disk_dir.display()
    );
    let checks = checks::inspect(&tree, &plan, &device_facts());
    let timing = (!args.no_timing).then(|| timing::measure(args.seconds, &plan, &disk_dir));
    let report = Report::new(checks, timing);
    let text = if args.json {
        let mut s = serde_json::to_string_pretty(&report)?;
        s.push('\n');
        s
    } else {
        render(&report, &tree)
    };
    logging::print_report(format_args!("{text}"))?;
    Ok(report.exit_code)
}

/// Wraps `text` to lines of at most `width` characters, each after `indent`.
fn wrap(out: &mut String, label: &str, text: &str, width: usize) {
    let indent = " ".repeat(7 + label.len());
    let mut line = format!("       {label}");
    let mut empty = true;
    for word in text.split_whitespace() {
        if !empty && line.chars().count() + 1 + word.chars().count() > width {
            let _ = writeln!(out, "{line}");
            line = indent.clone();
            empty = true;
        }
        if !empty {
            line.push(' ');
        }
        line.push_str(word);
        empty = false;
    }
    let _ = writeln!(out, "{line}");
}

/// The report for a person: each item with what was found, why it matters and the fix when it is
/// not good, the timing table, and the verdict.
pub fn render(report: &Report, tree: &Tree) -> String {
    const WIDTH: usize = 100;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "softhaptic doctor: is this machine ready for the 1 kHz haptic loop?"
    );
    if tree.root() != std::path::Path::new("/") {
        let _ = writeln!(out, "(files read under {})", tree.root().display());
    }
    let _ = writeln!(out);
    for c in &report.checks {
        let _ = writeln!(out, "[{}] {}", c.verdict.tag(), c.title);
        wrap(&mut out, "found: ", &c.found, WIDTH);
        if matches!(c.verdict, Verdict::Warn | Verdict::Fail | Verdict::Unknown) {
            wrap(&mut out, "why:   ", &c.why, WIDTH);
        }
        if let Some(fix) = &c.fix {
            wrap(&mut out, "fix:   ", fix, WIDTH);
        }
    }
    if let Some(t) = &report.timing {
        render_timing(&mut out, t);
    }
    let _ = writeln!(out);
    let _ = writeln!(
        out,
        "verdict: {} (exit {})",
        verdict_text(report),
        report.exit_code
    );
    out
}

/// `1 warning`, `2 warnings`.
fn counted(n: usize, thing: &str) -> String {
    format!("{n} {thing}{}", if n == 1 { "" } else { "s" })
}

/// The last line's verdict: ready, or what stands in the way and what it means.
fn verdict_text(report: &Report) -> String {
    let (fails, warns) = (report.count(Verdict::Fail), report.count(Verdict::Warn));
    let unread = report.unread();
    let not_read = (!unread.is_empty()).then(|| {
        format!(
            "{} not read ({})",
            counted(unread.len(), "item"),
            unread.join(", ")
        )
    });
    match report.exit_code {
        0 => "ready for the 1 kHz loop".to_owned(),
        1 => {
            let mut parts = Vec::new();
            if warns > 0 {
                parts.push(counted(warns, "warning"));
            }
            parts.extend(not_read);
            let mut meaning = Vec::new();
            if warns > 0 {
                meaning.push("the loop runs, and loses ticks or timing the fixes above would save");
            }
            if !unread.is_empty() {
                meaning.push(
                    "what could not be read is not shown to be ready (run the doctor where it \
                     can read it: as the server's user, outside a container)",
                );
            }
            format!("{}: {}", parts.join(", "), meaning.join("; "))
        }
        _ => {
            let mut parts = vec![counted(warns, "warning")];
            parts.extend(not_read);
            format!(
                "{} ({}): the loop cannot run as configured; fix the FAIL items",
                counted(fails, "failure"),
                parts.join(", ")
            )
        }
    }
}

fn render_timing(out: &mut String, t: &timing::Timing) {
    let _ = writeln!(out);
    let _ = writeln!(
        out,
        "[{}] Loop timing: the server's loop at 1 kHz on the built-in scene and the simulated \
         device, {:.1} s per run",
        t.verdict.tag(),
        t.seconds_per_run
    );
    wrap(
        out,
        "goal:  ",
        &format!(
            "period error p99 ≤ {:.0} µs, max ≤ {:.0} µs, {} lost ticks",
            t.goal.period_error_p99_us, t.goal.period_error_max_us, t.goal.lost_ticks
        ),
        100,
    );
    if t.build == "debug" {
        wrap(
            out,
            "note:  ",
            "a debug build: each tick computes slower than in the release build a device host \
             runs; measure with `cargo run --release -p softhaptic-server --bin softhaptic -- \
             doctor`",
            100,
        );
    }
    if !t.runs.is_empty() {
        let _ = writeln!(
            out,
            "       {:<16} {:>7} {:>6} {:>9} {:>9} {:>9} {:>10} {:>8}",
            "neighbour", "ticks", "lost", "lost/min", "p99 µs", "max µs", "by standby", "goal"
        );
    }
    for r in &t.runs {
        let name = if r.neighbour.starts_with("none") {
            "idle"
        } else if r.neighbour.starts_with("disk") {
            "disk writing"
        } else {
            "CPUs loaded"
        };
        let _ = writeln!(
            out,
            "       {:<16} {:>7} {:>6} {:>9.1} {:>9.1} {:>9.1} {:>10} {:>8}",
            name,
            r.ticks,
            r.lost_ticks,
            r.lost_ticks_per_minute,
            r.period_error_p99_us,
            r.period_error_max_us,
            r.ticks_by_standby,
            match r.verdict {
                Verdict::Good => "meets",
                _ => "misses",
            }
        );
    }
    for loaded in t.runs.iter().filter(|r| !r.neighbour.starts_with("none")) {
        wrap(out, "beside: ", &loaded.neighbour, 100);
    }
    if let Some(first) = t.runs.first() {
        wrap(out, "loop thread: ", &first.loop_thread, 100);
    }
    if let Some(e) = &t.error {
        wrap(out, "error: ", e, 100);
    }
    if t.verdict == Verdict::Warn {
        wrap(
            out,
            "fix:   ",
            "the items marked WARN above, most often the kernel's preemption model, a CPU kept \
             for the loop (--loop-cpu) and real-time limits; then run the doctor again",
            100,
        );
    }
}
