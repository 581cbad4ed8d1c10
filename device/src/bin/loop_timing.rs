//! Loop timing report: runs the 1 kHz loop with the simulated PHANTOM pressing the built-in liver
//! for a number of seconds, prints the statistics once a second and a final table.
//!
//! `cargo run --release -p softhaptic-device --bin loop-timing -- --seconds 10 [--burn]`
//! (`--cpu auto|last|none|N` chooses the loop thread's CPU).
//!
//! `--burn` starts one CPU-burning thread per core beside the loop, to show what a busy machine
//! does to the period error (and what SCHED_FIFO, when granted, protects against).
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
use softhaptic_device::haptic_loop::{HapticLoop, LoopConfig};
use softhaptic_device::liver;
use softhaptic_device::render::RenderConfig;
use softhaptic_device::rt::CpuChoice;
use softhaptic_device::sim::{HandScript, SimulatedPhantom};
use softhaptic_device::stats::LoopStats;
use softhaptic_device::world::HapticWorld;
use softhaptic_proto::{Material, Pose, ToolShape};

#[derive(Parser, Debug)]
#[command(about = "Measure the period error and compute time of the 1 kHz haptic loop")]
struct Args {
    /// How long to run, seconds.
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// Start a CPU-burning thread on every core beside the loop.
    #[arg(long)]
    burn: bool,
    /// Loop period in microseconds.
    #[arg(long, default_value_t = 1000)]
    period_us: u64,
    /// Do not ask for SCHED_FIFO and locked memory.
    #[arg(long)]
    no_realtime: bool,
    /// CPU of the loop thread: `none` (unbound, as the server runs it), `auto` (the last one
    /// when real-time is asked for), `last` or a CPU number.
    #[arg(long, default_value = "none", value_parser = parse_cpu)]
    cpu: CpuChoice,
}

fn parse_cpu(text: &str) -> Result<CpuChoice, String> {
    text.parse()
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

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
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
        RenderConfig::for_tool(&tool),
        limits,
    );

    let burning = Arc::new(AtomicBool::new(args.burn));
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let burners: Vec<_> = if args.burn {
        (0..cores)
            .map(|_| {
                let burning = Arc::clone(&burning);
                std::thread::spawn(move || {
                    let mut x = 1u64;
                    while burning.load(Ordering::Relaxed) {
                        for _ in 0..10_000 {
                            x = std::hint::black_box(x.wrapping_mul(6364136223846793005) + 1);
                        }
                    }
                    x
                })
            })
            .collect()
    } else {
        Vec::new()
    };

    let haptic = HapticLoop::spawn_on(
        Box::new(device),
        world,
        LoopConfig {
            period_ns: args.period_us * 1000,
            realtime: !args.no_realtime,
            tick_sink: None,
        },
        args.cpu,
    )?;
    let os_thread_id = haptic.realtime().os_thread_id;
    println!(
        "loop-timing: {} s, period {} µs, {} burning threads on {cores} cores; {}",
        args.seconds,
        args.period_us,
        burners.len(),
        haptic.realtime()
    );
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
    let s = haptic.stop();
    burning.store(false, Ordering::Relaxed);
    for b in burners {
        let _ = b.join();
    }

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
        "ticks {}, rate {:.2} Hz, overruns {}, device faults {}, real-time granted: {}, burn: {}, spin before deadline now {:.0} µs",
        s.ticks,
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
    Ok(())
}
