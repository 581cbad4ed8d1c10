//! Loop timing report: runs the 1 kHz loop with the simulated PHANTOM pressing the built-in liver
//! for a number of seconds, prints the statistics once a second and a final table.
//!
//! `cargo run --release -p softhaptic-device --bin loop-timing -- --seconds 10 [--burn]`
//!
//! `--burn` starts one CPU-burning thread per core beside the loop, to show what a busy machine
//! does to the period error (and what SCHED_FIFO, when granted, protects against).

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

    let haptic = HapticLoop::spawn(
        Box::new(device),
        world,
        LoopConfig {
            period_ns: args.period_us * 1000,
            realtime: !args.no_realtime,
            tick_sink: None,
        },
    )?;
    println!(
        "loop-timing: {} s, period {} µs, {} burning threads on {cores} cores; {}",
        args.seconds,
        args.period_us,
        burners.len(),
        haptic.realtime()
    );
    let start = Instant::now();
    let total = Duration::from_secs_f64(args.seconds);
    let mut next = Duration::from_secs(1);
    while start.elapsed() < total {
        let wait = next.min(total).saturating_sub(start.elapsed());
        std::thread::sleep(wait);
        if start.elapsed() >= next {
            print_line(start.elapsed().as_secs_f64(), &haptic.stats());
            next += Duration::from_secs(1);
        }
    }
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
    println!(
        "last contact: tick {}, in contact {}, depth {:.2} mm, force {:.3} N",
        last.tick,
        last.in_contact,
        last.depth_m * 1e3,
        last.force_n.length()
    );
    Ok(())
}
