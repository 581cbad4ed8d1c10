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
//! Exit status: 0 when the host is ready, 1 with warnings, 2 when the loop cannot run as
//! configured (a refused SCHED_FIFO, a CPU the process cannot use, a loop that does not start).

pub mod checks;
#[cfg(test)]
mod tests;
pub mod timing;

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
    /// Could not be read.
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

/// The command line of `softhaptic doctor`.
#[derive(clap::Args, Debug, Clone)]
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
        let (status, exit_code) = match worst {
            Verdict::Fail => ("cannot_run", 2),
            Verdict::Warn => ("warnings", 1),
            Verdict::Good | Verdict::Info | Verdict::Unknown => ("ready", 0),
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
}

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
/// returns the exit status.
pub fn run(args: &DoctorArgs) -> anyhow::Result<i32> {
    let plan = LoopPlan {
        realtime: !args.no_realtime,
        cpu: args.loop_cpu,
    };
    let tree = Tree::new(&args.root);
    let checks = checks::inspect(&tree, &plan, &device_facts());
    let disk_dir = args.record_dir.clone().unwrap_or_else(|| {
        let sessions = PathBuf::from("sessions");
        if sessions.is_dir() {
            sessions
        } else {
            std::env::temp_dir()
        }
    });
    let timing = (!args.no_timing).then(|| timing::measure(args.seconds, &plan, &disk_dir));
    let report = Report::new(checks, timing);
    let text = if args.json {
        let mut s = serde_json::to_string_pretty(&report)?;
        s.push('\n');
        s
    } else {
        render(&report, &tree)
    };
    crate::session::cli::print_report(format_args!("{text}"))?;
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
    let (fails, warns) = (report.count(Verdict::Fail), report.count(Verdict::Warn));
    let verdict = match report.exit_code {
        0 => "ready for the 1 kHz loop".to_owned(),
        1 => format!(
            "{warns} warning{}: the loop runs, and loses ticks or timing the fixes above would save",
            if warns == 1 { "" } else { "s" }
        ),
        _ => format!(
            "{fails} failure{} ({warns} warning{}): the loop cannot run as configured; fix the FAIL items",
            if fails == 1 { "" } else { "s" },
            if warns == 1 { "" } else { "s" }
        ),
    };
    let _ = writeln!(out, "verdict: {verdict} (exit {})", report.exit_code);
    out
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
