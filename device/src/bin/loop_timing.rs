//! Loop timing report: runs the 1 kHz loop with the simulated PHANTOM pressing the built-in liver
//! for a number of seconds, prints the statistics once a second and a final table.
//!
//! A report command in one file: its options, the run and the tables; the last 50 lines are its
//! tests.
//!
//! `cargo run --release -p softhaptic-device --features tools --bin loop-timing -- --seconds 10 [--burn]`
//! (`--cpu auto|last|none|N` chooses the loop thread's CPU).
//!
//! `--burn` starts one CPU-burning neighbour process per core beside the loop (this program
//! again, run as a burner; it dies with its parent), to show what a busy machine does to the
//! period error (and what SCHED_FIFO, when granted, protects against). `--no-standby` runs the
//! loop thread without its standby, for comparison.
//!
//! Witness threads, one bound to each CPU at a lower real-time priority than the loop, wake every
//! half period (offset from the loop's deadlines) and note each stretch in which their CPU could
//! not run them. Each late tick, and each run of lost ticks, is then set beside them: if every
//! CPU was stalled at that moment (a virtual machine paused by its host, or the whole kernel
//! held), no thread of the loop's, wherever it ran, could have ticked on time; if some CPU was
//! free, the delay was local to the loop's CPU (`--no-witness` leaves them out).
//!
//! Besides the loop's own statistics it prints what the kernel saw of the loop thread between the
//! end of the first second and the end of the run (page faults, involuntary context switches,
//! migrations between CPUs), the machine's load average and the kernel's preemption model: the
//! causes of a late tick that the loop cannot see itself (see `softhaptic_device::rt`).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Parser;
use softhaptic_device::collision::{Collider, CollisionMode};
use softhaptic_device::device::{DeviceLimits, HapticDevice};
use softhaptic_device::force::ForceConfig;
use softhaptic_device::haptic_loop::{HapticLoop, LoopConfig};
use softhaptic_device::liver;
use softhaptic_device::rt::{self, CpuChoice, RealtimeStatus};
use softhaptic_device::sim::{HandScript, SimulatedPhantom};
use softhaptic_device::stats::{LateWake, LoopStats};
use softhaptic_device::world::HapticWorld;
use softhaptic_proto::{Material, Pose, ToolShape};

#[derive(Parser, Debug)]
#[command(about = "Measure the period error and compute time of the 1 kHz haptic loop")]
struct Args {
    /// How long to run, seconds (0.1 to 86 400: a day).
    #[arg(long, default_value_t = 10.0, value_parser = parse_seconds)]
    seconds: f64,
    /// Start a CPU-burning neighbour process for every core beside the loop.
    #[arg(long)]
    burn: bool,
    /// Burn a CPU until killed or until the parent exits (how `--burn` runs its neighbours).
    #[arg(long, hide = true)]
    burner: bool,
    /// Loop period in microseconds (100 to 100 000: 10 kHz to 10 Hz).
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u64).range(100..=100_000))]
    period_us: u64,
    /// Do not ask for SCHED_FIFO and locked memory.
    #[arg(long)]
    no_realtime: bool,
    /// CPU of the loop thread: `none` (unbound, as the server runs it), `auto` (the last one
    /// when real-time is asked for), `last` or a CPU number.
    #[arg(long, default_value = "none", value_parser = parse_cpu)]
    cpu: CpuChoice,
    /// Run the loop thread alone, without the standby thread that takes over a tick the loop
    /// thread has not started a quarter period after its deadline.
    #[arg(long)]
    no_standby: bool,
    /// Run no witness threads (see the top of this file): the loop alone on the machine.
    #[arg(long)]
    no_witness: bool,
}

fn parse_cpu(text: &str) -> Result<CpuChoice, String> {
    text.parse()
}

/// A run length a person would ask for: long enough to fill the histograms, at most a day (a
/// longer one is a typo, and would overflow the tick counts' clock arithmetic long before).
fn parse_seconds(text: &str) -> Result<f64, String> {
    let seconds: f64 = text
        .parse()
        .map_err(|_| format!("{text:?} is not a number of seconds"))?;
    if (0.1..=86_400.0).contains(&seconds) {
        Ok(seconds)
    } else {
        Err(format!("{seconds} s is outside 0.1 to 86 400 s"))
    }
}

/// What the kernel counts for one thread, from `/proc/self/task/<id>/`.
#[derive(Debug, Clone, Copy, Default)]
struct ThreadCounters {
    minor_faults: u64,
    major_faults: u64,
    involuntary_switches: u64,
    /// `None` when the kernel does not publish `sched` (no CONFIG_SCHED_DEBUG).
    migrations: Option<u64>,
    cpu: Option<u64>,
}

fn thread_counters(os_thread_id: i32) -> anyhow::Result<ThreadCounters> {
    let dir = format!("/proc/self/task/{os_thread_id}");
    let stat_path = format!("{dir}/stat");
    let stat =
        std::fs::read_to_string(&stat_path).with_context(|| format!("reading {stat_path}"))?;
    // Fields after the command name, which is in parentheses and may hold spaces: the first one
    // after it is field 3 of proc(5).
    let after_name = stat
        .rsplit_once(')')
        .map(|(_, rest)| rest)
        .with_context(|| format!("{stat_path}: no command name"))?;
    let fields: Vec<&str> = after_name.split_whitespace().collect();
    let field = |n: usize| -> anyhow::Result<u64> {
        fields
            .get(n - 3)
            .and_then(|v| v.parse().ok())
            .with_context(|| format!("{stat_path}: field {n} missing or not a number"))
    };
    let status_path = format!("{dir}/status");
    let status =
        std::fs::read_to_string(&status_path).with_context(|| format!("reading {status_path}"))?;
    let involuntary_switches = status
        .lines()
        .find_map(|l| l.strip_prefix("nonvoluntary_ctxt_switches:"))
        .and_then(|v| v.trim().parse().ok())
        .with_context(|| format!("{status_path}: no nonvoluntary_ctxt_switches"))?;
    let migrations = std::fs::read_to_string(format!("{dir}/sched"))
        .ok()
        .and_then(|sched| {
            sched.lines().find_map(|l| {
                l.strip_prefix("se.nr_migrations")
                    .and_then(|v| v.trim_start_matches([' ', ':']).trim().parse().ok())
            })
        });
    Ok(ThreadCounters {
        minor_faults: field(10)?,
        major_faults: field(12)?,
        involuntary_switches,
        migrations,
        cpu: field(39).ok(),
    })
}

/// The kernel's preemption model, as far as an unprivileged reader can tell.
fn preemption_model() -> String {
    if let Ok(mode) = std::fs::read_to_string("/sys/kernel/debug/sched/preempt") {
        // The current mode is the one in parentheses.
        if let Some(current) = mode.split_whitespace().find(|w| w.starts_with('(')) {
            return format!("preempt={}", current.trim_matches(['(', ')']));
        }
    }
    let cmdline = std::fs::read_to_string("/proc/cmdline").unwrap_or_default();
    if let Some(p) = cmdline
        .split_whitespace()
        .find(|w| w.starts_with("preempt="))
    {
        return p.to_string();
    }
    let version = std::fs::read_to_string("/proc/version").unwrap_or_default();
    if version.contains("PREEMPT_RT") {
        return "PREEMPT_RT".to_string();
    }
    if version.contains("PREEMPT_DYNAMIC") {
        return "PREEMPT_DYNAMIC, mode chosen at boot (not readable without debugfs; \
                a build's default is often preempt=none)"
            .to_string();
    }
    if version.contains("PREEMPT ") {
        return "PREEMPT (full)".to_string();
    }
    "not preemptible (no PREEMPT in /proc/version)".to_string()
}

/// SCHED_FIFO priority of the witness threads: below the loop's, so that a witness sharing the
/// loop's CPU never delays it.
const WITNESS_PRIORITY: i32 = rt::LOOP_PRIORITY - 10;

/// A witness wake-up later than this counts as a stall of its CPU.
const STALL_THRESHOLD_NS: u64 = 200_000;

/// Room for stalls per witness, allocated before it starts (one per half period would be 2000 per
/// second; a run that overflows stops recording and says so).
const STALL_CAPACITY: usize = 100_000;

/// A stretch `[from_ns, until_ns)` of CLOCK_MONOTONIC in which a CPU did not run its witness.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Stall {
    from_ns: u64,
    until_ns: u64,
}

/// What one witness saw.
struct WitnessReport {
    cpu: usize,
    status: RealtimeStatus,
    stalls: Vec<Stall>,
    overflowed: bool,
}

/// Starts a witness bound to `cpu`, waking every `period_ns` at `phase_ns` past multiples of the
/// period from `origin_ns`, until `stop`.
fn spawn_witness(
    cpu: usize,
    realtime: bool,
    origin_ns: u64,
    period_ns: u64,
    phase_ns: u64,
    stop: Arc<AtomicBool>,
) -> std::io::Result<std::thread::JoinHandle<WitnessReport>> {
    std::thread::Builder::new()
        .name(format!("witness-{cpu}"))
        .spawn(move || {
            let mut stalls = Vec::with_capacity(STALL_CAPACITY);
            let status = rt::request_realtime(realtime, WITNESS_PRIORITY, CpuChoice::Index(cpu));
            let mut overflowed = false;
            let mut deadline = origin_ns + phase_ns;
            while !stop.load(Ordering::Relaxed) {
                rt::sleep_until_ns(deadline);
                let woke = rt::now_ns();
                if woke.saturating_sub(deadline) > STALL_THRESHOLD_NS {
                    if stalls.len() < STALL_CAPACITY {
                        stalls.push(Stall {
                            from_ns: deadline,
                            until_ns: woke,
                        });
                    } else {
                        overflowed = true;
                    }
                }
                // The next deadline after the wake-up: the stall above covers the ones lost.
                deadline += ((woke - deadline) / period_ns + 1) * period_ns;
            }
            WitnessReport {
                cpu,
                status,
                stalls,
                overflowed,
            }
        })
}

/// How much of `[from_ns, until_ns)` the stalls cover, as a fraction.
fn stalled_fraction(stalls: &[Stall], from_ns: u64, until_ns: u64) -> f64 {
    if until_ns <= from_ns {
        return 0.0;
    }
    let covered: u64 = stalls
        .iter()
        .map(|s| {
            s.until_ns
                .min(until_ns)
                .saturating_sub(s.from_ns.max(from_ns))
        })
        .sum();
    covered as f64 / (until_ns - from_ns) as f64
}

/// Whether a CPU counts as stalled during a late tick: its witness was held for at least half
/// of the time the loop was late.
const STALLED_FRACTION: f64 = 0.5;

/// For one late tick (or run of lost ticks), the stalled fraction of each witness's CPU.
fn classify(wake: LateWake, witnesses: &[WitnessReport]) -> Vec<f64> {
    witnesses
        .iter()
        .map(|w| stalled_fraction(&w.stalls, wake.deadline_ns, wake.deadline_ns + wake.late_ns))
        .collect()
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|l| {
            let v: Vec<&str> = l.split_whitespace().take(3).collect();
            (v.len() == 3).then(|| v.join(" "))
        })
        .unwrap_or_else(|| "unknown".to_string())
}

fn us(ns: u64) -> f64 {
    ns as f64 / 1000.0
}

fn print_line(elapsed_s: f64, s: &LoopStats) {
    println!(
        "{elapsed_s:5.1} s  ticks {:>7}  rate {:8.2} Hz  period error p50 {:7.1} p99 {:7.1} p99.9 {:7.1} max {:8.1} µs  overruns {:>4}  compute p50 {:6.1} p99 {:6.1} µs  spin {:5.1} µs",
        s.ticks,
        s.loop_rate_hz,
        us(s.period_error_p50_ns),
        us(s.period_error_p99_ns),
        us(s.period_error_p999_ns),
        us(s.period_error_max_ns),
        s.overruns,
        us(s.compute_p50_ns),
        us(s.compute_p99_ns),
        us(s.spin_ns),
    );
}

/// A burner process, killed and reaped when dropped.
struct Burner(std::process::Child);

impl Drop for Burner {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The body of a burner process: spins until killed, or until its parent exits.
#[allow(clippy::disallowed_methods)] // A burner has nothing to close: it only spins.
fn burn() -> ! {
    // SAFETY: PR_SET_PDEATHSIG takes a signal number and affects only the calling process.
    unsafe {
        libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL as libc::c_ulong);
    }
    // The parent may have died before the request: then it is not our parent any more.
    if std::os::unix::process::parent_id() == 1 {
        std::process::exit(0);
    }
    let mut x = 1u64;
    loop {
        x = std::hint::black_box(x.wrapping_mul(6364136223846793005) + 1);
    }
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    if args.burner {
        burn();
    }
    if !(args.seconds.is_finite() && args.seconds > 0.0) {
        anyhow::bail!("--seconds must be a positive number, got {}", args.seconds);
    }
    if args.period_us == 0 {
        anyhow::bail!("--period-us must be > 0");
    }

    let tool = ToolShape::sphere(0.01).context("tool radius")?;
    let material = Material::PAPER_SOFT;
    let top = liver::top_contact();
    let mut script = HandScript::press(top.point_m, top.normal, 0.012);
    script.repeat = true;
    let device = SimulatedPhantom::new(script);
    let limits: DeviceLimits = device.limits();
    let world = HapticWorld::new(
        Collider::new(liver::haptic_mesh(), CollisionMode::default()),
        Pose::IDENTITY,
        tool,
        material,
        ForceConfig::for_tool(&tool),
        limits,
    );

    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut burners = Vec::new();
    if args.burn {
        let me = std::env::current_exe().context("finding this program to start the burners")?;
        for _ in 0..cores {
            let child = std::process::Command::new(&me)
                .arg("--burner")
                .stdin(std::process::Stdio::null())
                .spawn()
                .with_context(|| format!("starting a burner process ({})", me.display()))?;
            burners.push(Burner(child));
        }
    }

    let haptic = HapticLoop::spawn_on(
        Box::new(device),
        world,
        LoopConfig {
            period_ns: args.period_us * 1000,
            realtime: !args.no_realtime,
            tick_sink: None,
            standby: !args.no_standby,
        },
        args.cpu,
    )?;
    let os_thread_id = haptic.realtime().os_thread_id;
    let witness_stop = Arc::new(AtomicBool::new(false));
    let witnesses = if args.no_witness {
        Vec::new()
    } else {
        start_witnesses(&haptic_origin(&haptic)?, &args, &witness_stop)?
    };
    println!(
        "loop-timing: {} s, period {} µs, {} burning processes on {cores} cores; {}",
        args.seconds,
        args.period_us,
        burners.len(),
        haptic.realtime()
    );
    match haptic.standby() {
        Some(status) => println!("standby thread: {status}"),
        None if args.no_standby => println!("standby thread: none (--no-standby)"),
        None => println!("standby thread: none (the process has one CPU)"),
    }
    println!(
        "machine: load average {}, kernel {}",
        load_average(),
        preemption_model()
    );
    let mut warm: Option<ThreadCounters> = None;
    let start = Instant::now();
    let total = Duration::from_secs_f64(args.seconds);
    let mut next = Duration::from_secs(1);
    while start.elapsed() < total {
        let wait = next.min(total).saturating_sub(start.elapsed());
        std::thread::sleep(wait);
        if start.elapsed() >= next {
            print_line(start.elapsed().as_secs_f64(), &haptic.stats());
            next += Duration::from_secs(1);
            if warm.is_none() {
                warm = thread_counters(os_thread_id).ok();
            }
        }
    }
    let end_counters = thread_counters(os_thread_id);
    let last = haptic.latest_contact();
    let late = haptic.late_wakes();
    let s = haptic.stop();
    witness_stop.store(true, Ordering::Relaxed);
    let witnesses: Vec<WitnessReport> = witnesses
        .into_iter()
        .filter_map(|w| w.join().ok())
        .collect();
    drop(burners);

    println!();
    println!("| quantity | p50 | p99 | p99.9 | max |");
    println!("|---|---|---|---|---|");
    println!(
        "| period error (µs) | {:.1} | {:.1} | {:.1} | {:.1} |",
        us(s.period_error_p50_ns),
        us(s.period_error_p99_ns),
        us(s.period_error_p999_ns),
        us(s.period_error_max_ns)
    );
    println!(
        "| compute (µs) | {:.1} | {:.1} | – | {:.1} |",
        us(s.compute_p50_ns),
        us(s.compute_p99_ns),
        us(s.compute_max_ns)
    );
    println!();
    println!(
        "ticks {} (by the standby {}), rate {:.2} Hz, overruns {}, device faults {}, real-time granted: {}, burn: {}, spin before deadline now {:.0} µs",
        s.ticks,
        s.standby_ticks,
        s.loop_rate_hz,
        s.overruns,
        s.device_faults,
        s.realtime_granted,
        args.burn,
        us(s.spin_ns)
    );
    match (warm, end_counters) {
        (Some(a), Ok(b)) => println!(
            "loop thread after the first second: minor faults {}, major faults {}, involuntary context switches {}, migrations {}, on CPU {}; load average now {}",
            b.minor_faults.saturating_sub(a.minor_faults),
            b.major_faults.saturating_sub(a.major_faults),
            b.involuntary_switches
                .saturating_sub(a.involuntary_switches),
            match (a.migrations, b.migrations) {
                (Some(x), Some(y)) => y.saturating_sub(x).to_string(),
                _ => "unknown".to_string(),
            },
            b.cpu.map_or("unknown".to_string(), |c| c.to_string()),
            load_average(),
        ),
        (None, _) => println!("loop thread counters: the run was shorter than a second"),
        (_, Err(e)) => println!("loop thread counters unavailable: {e:#}"),
    }
    println!(
        "last contact: tick {}, in contact {}, depth {:.2} mm, force {:.3} N",
        last.tick,
        last.in_contact,
        last.depth_m * 1e3,
        last.force_n.length()
    );
    if !args.no_witness {
        print_late_wakes(late.total, &late.iter().collect::<Vec<_>>(), &witnesses, &s);
    }
    Ok(())
}

/// The origin of the loop's deadlines, as soon as the loop has published it.
fn haptic_origin(haptic: &HapticLoop) -> anyhow::Result<u64> {
    // Published before `spawn_on` returns.
    match haptic.stats().deadline_origin_ns {
        0 => anyhow::bail!("the loop published no deadline origin"),
        origin => Ok(origin),
    }
}

/// One witness per CPU the process may use, waking half-way between the loop's half periods so
/// that none wakes while the loop spins before its deadline.
fn start_witnesses(
    origin_ns: &u64,
    args: &Args,
    stop: &Arc<AtomicBool>,
) -> anyhow::Result<Vec<std::thread::JoinHandle<WitnessReport>>> {
    let period_ns = args.period_us * 1000;
    let cpus = rt::allowed_cpus().map_err(|e| {
        anyhow::anyhow!(
            "reading the CPUs this process may use: {}",
            std::io::Error::from_raw_os_error(e)
        )
    })?;
    // Start a few periods ahead, so every witness is set up before its first deadline.
    let now = rt::now_ns();
    let periods_ahead = now.saturating_sub(*origin_ns) / period_ns + 10;
    let witness_origin = origin_ns + periods_ahead * period_ns;
    cpus.into_iter()
        .map(|cpu| {
            spawn_witness(
                cpu,
                !args.no_realtime,
                witness_origin,
                period_ns / 2,
                period_ns / 4,
                Arc::clone(stop),
            )
            .with_context(|| format!("starting the witness thread of CPU {cpu}"))
        })
        .collect()
}

/// Each late tick or run of lost ticks beside what the witnesses saw, and how many came while every
/// CPU was stalled.
fn print_late_wakes(total: u64, late: &[LateWake], witnesses: &[WitnessReport], s: &LoopStats) {
    println!();
    for w in witnesses {
        println!(
            "witness on CPU {}: {} stalls over {} µs{}; {}",
            w.cpu,
            w.stalls.len(),
            STALL_THRESHOLD_NS / 1000,
            if w.overflowed {
                " (more than it had room for)"
            } else {
                ""
            },
            w.status
        );
    }
    if late.is_empty() {
        println!("late ticks or lost ones (a deadline waiting over half a period): none");
        return;
    }
    println!(
        "late ticks or runs of lost ones (a deadline waiting over half a period): {total}{}",
        if total > late.len() as u64 {
            format!(", the last {} shown", late.len())
        } else {
            String::new()
        }
    );
    println!(
        "(times from the loop's deadline origin, CLOCK_MONOTONIC {:.6} s, to set beside a kernel \
         trace taken with trace_clock mono)",
        s.deadline_origin_ns as f64 * 1e-9
    );
    let header: Vec<String> = witnesses
        .iter()
        .map(|w| format!("CPU {} stalled", w.cpu))
        .collect();
    println!("| at (s) | waited (µs) | {} |", header.join(" | "));
    println!("|---|---|{}", "---|".repeat(witnesses.len()));
    let mut everywhere = 0;
    for &wake in late {
        let fractions = classify(wake, witnesses);
        if !fractions.is_empty() && fractions.iter().all(|&f| f >= STALLED_FRACTION) {
            everywhere += 1;
        }
        let cells: Vec<String> = fractions
            .iter()
            .map(|f| format!("{:.0} %", f * 100.0))
            .collect();
        println!(
            "| {:.3} | {:.1} | {} |",
            wake.deadline_ns.saturating_sub(s.deadline_origin_ns) as f64 * 1e-9,
            us(wake.late_ns),
            cells.join(" | ")
        );
    }
    println!(
        "{everywhere} of the {} shown came while every CPU was stalled (each for at least {:.0} % \
         of the wait): no thread on any CPU could have run a tick then",
        late.len(),
        STALLED_FRACTION * 100.0
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_length_or_a_period_no_one_means_is_refused_naming_the_option_and_its_range() {
        for (args, says) in [
            (&["--seconds", "1e12"][..], "outside 0.1 to 86 400 s"),
            (&["--seconds", "0"][..], "outside 0.1 to 86 400 s"),
            (&["--seconds", "NaN"][..], "outside 0.1 to 86 400 s"),
            (&["--seconds", "ten"][..], "is not a number of seconds"),
            (&["--period-us", "1"][..], "100..=100000"),
            (&["--period-us", "1000000"][..], "100..=100000"),
        ] {
            let argv = std::iter::once("loop-timing").chain(args.iter().copied());
            let error = Args::try_parse_from(argv).expect_err(&format!("{args:?} accepted"));
            let text = error.to_string();
            assert_eq!(error.exit_code(), 2, "{args:?}: {text}");
            assert!(
                text.contains(args[0]) && text.contains(says),
                "{args:?}: {text}"
            );
        }
        // The limits themselves are runs a person may ask for.
        let args =
            Args::try_parse_from(["loop-timing", "--seconds", "86400", "--period-us", "100"])
                .expect("the limits are accepted");
        assert_eq!((args.seconds, args.period_us), (86_400.0, 100));
        let args =
            Args::try_parse_from(["loop-timing", "--seconds", "0.1", "--period-us", "100000"])
                .expect("the limits are accepted");
        assert_eq!((args.seconds, args.period_us), (0.1, 100_000));
    }

    fn witness(cpu: usize, stalls: &[(u64, u64)]) -> WitnessReport {
        WitnessReport {
            cpu,
            status: RealtimeStatus::default(),
            stalls: stalls
                .iter()
                .map(|&(from_ns, until_ns)| Stall { from_ns, until_ns })
                .collect(),
            overflowed: false,
        }
    }

    #[test]
    fn stalled_fraction_counts_only_the_overlap() {
        let stalls = [
            Stall {
                from_ns: 100,
                until_ns: 200,
            },
            Stall {
                from_ns: 300,
                until_ns: 400,
            },
        ];
        assert_eq!(stalled_fraction(&stalls, 100, 200), 1.0);
        assert_eq!(stalled_fraction(&stalls, 150, 350), 0.5);
        assert_eq!(stalled_fraction(&stalls, 200, 300), 0.0);
        assert_eq!(stalled_fraction(&stalls, 500, 500), 0.0, "an empty stretch");
        assert_eq!(stalled_fraction(&[], 0, 1000), 0.0);
    }

    #[test]
    fn a_late_tick_is_set_beside_every_cpu() {
        // The loop waited 1 ms from t = 10 ms: CPU 0 was stalled all along, CPU 1 for a fifth.
        let wake = LateWake {
            deadline_ns: 10_000_000,
            late_ns: 1_000_000,
        };
        let witnesses = [
            witness(0, &[(9_750_000, 11_250_000)]),
            witness(1, &[(10_250_000, 10_450_000)]),
        ];
        let fractions = classify(wake, &witnesses);
        assert_eq!(fractions.len(), 2);
        assert!((fractions[0] - 1.0).abs() < 1e-12);
        assert!((fractions[1] - 0.2).abs() < 1e-12);
    }
}
