//! SpaceMouse timing report: how long a puck report takes to move the tool, and the lag the
//! velocity's smoothing adds.
//!
//! `cargo run --release -p softhaptic-device --features tools --bin spacemouse-timing -- --pushes 20`
//!
//! The 1 kHz loop runs with the SpaceMouse backend fed by a report stream played in real time
//! (a full push along x, a report every 16 ms for 0.3 s, then a release, repeated): the same
//! reader thread, seqlock and rate control as with a device, the transport only replaced. Each
//! push starts at a random point within its millisecond (seeded by `--seed`): pushes started on
//! whole milliseconds, with reports 16 ms apart, would all land at the same phase of the loop's
//! 1 ms period and give one latency many times over instead of its spread. Each report the
//! transport hands over is stamped (CLOCK_MONOTONIC), and set beside the loop's tick records.
//! USB and the kernel's hidraw are not in these figures: the scripted transport stands in for
//! them. The figures:
//!
//! - *report → motion*: from the first report of a push to the first tick whose velocity moves
//!   (the reader's parse and publication, plus the wait for the next tick: at most one period);
//! - *report → 63 % speed*: to the tick at 1 − 1/e of the commanded speed (the filter's time
//!   constant plus the above);
//! - *position lag*: at the end of a push, how far behind an unsmoothed integration (starting at
//!   the first motion) the tool is, in seconds of travel (a first-order filter trails a constant
//!   velocity by its time constant).

use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::Context;
use clap::Parser;
use glam::DVec3;
use softhaptic_device::collision::{Collider, CollisionMode};
use softhaptic_device::device::DeviceLimits;
use softhaptic_device::force::ForceConfig;
use softhaptic_device::haptic_loop::{HapticLoop, LoopConfig, TickRecord};
use softhaptic_device::mesh::HapticMesh;
use softhaptic_device::rt;
use softhaptic_device::spacemouse::rate::RateConfig;
use softhaptic_device::spacemouse::report::{Model, find_model};
use softhaptic_device::spacemouse::script::{ReportScript, axis_report};
use softhaptic_device::spacemouse::{Connector, SpaceMouseDevice, Transport, TransportError};
use softhaptic_device::world::HapticWorld;
use softhaptic_proto::{Material, Pose, ToolShape};

#[derive(Parser, Debug)]
#[command(about = "Report-to-motion latency and smoothing lag of the SpaceMouse backend")]
struct Args {
    /// Pushes to time (each 0.3 s of full deflection, then 0.3 s at rest).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pushes: u32,
    /// Ask for SCHED_FIFO for the loop thread (granted to root or with an rtprio limit).
    #[arg(long)]
    realtime: bool,
    /// Seed of the pushes' onsets within their millisecond (the same seed, the same stream).
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

const PUSH_S: f64 = 0.3;
const EVERY_S: f64 = 0.6;
const REPORT_EVERY_S: f64 = 0.016;

/// The reports handed over, each with the CLOCK_MONOTONIC time it was handed over at.
type Stamps = Arc<Mutex<Vec<(u64, Vec<u8>)>>>;

/// Stamps every report the inner transport hands over.
struct Stamped<C> {
    inner: C,
    stamps: Stamps,
}

struct StampedTransport {
    inner: Box<dyn Transport>,
    stamps: Stamps,
}

impl<C: Connector> Connector for Stamped<C> {
    fn connect(&mut self) -> Result<(Box<dyn Transport>, &'static Model), TransportError> {
        let (inner, model) = self.inner.connect()?;
        Ok((
            Box::new(StampedTransport {
                inner,
                stamps: Arc::clone(&self.stamps),
            }),
            model,
        ))
    }
}

impl Transport for StampedTransport {
    fn read(&mut self, buf: &mut [u8], timeout_ms: i32) -> Result<usize, TransportError> {
        let n = self.inner.read(buf, timeout_ms)?;
        if n > 0 {
            let now = rt::now_ns();
            if let Ok(mut s) = self.stamps.lock() {
                s.push((now, buf[..n].to_vec()));
            }
        }
        Ok(n)
    }
}

/// SplitMix64: a small, seedable generator of the onsets' phases (the figures need a spread,
/// not a cryptographic quality).
struct SplitMix64(u64);

impl SplitMix64 {
    /// The next value, uniform in [0, 1).
    fn next_unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        // The top 53 bits: every value exactly representable, 1.0 never reached.
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let navigator = find_model(0x046d, 0xc626).context("the SpaceNavigator is a listed model")?;
    let mut script = ReportScript::new(navigator).report(0.0, &axis_report(1, [0; 3]));
    let mut phase = SplitMix64(args.seed);
    for k in 0..args.pushes {
        // Whole milliseconds plus a phase within one: see the module's documentation.
        let t0 = 0.5 + f64::from(k) * EVERY_S + phase.next_unit() * 1e-3;
        script = script.hold_translation(t0, t0 + PUSH_S, REPORT_EVERY_S, [350, 0, 0]);
    }
    let total_s = 0.5 + f64::from(args.pushes) * EVERY_S + 0.2;

    // The tool far above a small plate: no contact, only the motion is timed.
    let home = Pose::from_position(DVec3::new(0.0, 0.5, 0.0));
    let rate = RateConfig::new(home, DVec3::new(-10.0, 0.0, -10.0), DVec3::splat(10.0));
    let stamps = Arc::new(Mutex::new(Vec::new()));
    let (connector, clock) = script.connector_started_later();
    let device = SpaceMouseDevice::open(
        Box::new(Stamped {
            inner: connector,
            stamps: Arc::clone(&stamps),
        }),
        rate,
        DeviceLimits::PHANTOM_DESKTOP,
    )?;
    let opened_ns = device.opened_ns();
    let tool = ToolShape::sphere(0.01)?;
    let world = HapticWorld::new(
        Collider::new(HapticMesh::grid(5, 0.04), CollisionMode::Continuous),
        Pose::IDENTITY,
        tool,
        Material::PAPER_SOFT,
        ForceConfig::for_tool(&tool),
        DeviceLimits::PHANTOM_DESKTOP,
    );
    let capacity = (total_s * 1000.0) as usize + 5000;
    let (producer, mut consumer) = rtrb::RingBuffer::<TickRecord>::new(capacity);
    let haptic = HapticLoop::spawn(
        Box::new(device),
        world,
        LoopConfig {
            period_ns: 1_000_000,
            realtime: args.realtime,
            tick_sink: Some(producer),
            standby: true,
        },
    )?;
    clock.start();
    eprintln!("{} pushes, {total_s:.1} s ...", args.pushes);
    std::thread::sleep(Duration::from_secs_f64(total_s));
    let stats = haptic.stop();
    let mut ticks = Vec::new();
    while let Ok(r) = consumer.pop() {
        if let Some(s) = r.sample {
            ticks.push((
                opened_ns + s.time_ns,
                s.tip_in_world.position_m.x,
                s.tip_velocity_m_s.x,
            ));
        }
    }
    let stamps = stamps.lock().map(|s| s.clone()).unwrap_or_default();

    // The first report of each push: a full deflection after a report at rest.
    let onsets: Vec<u64> = stamps
        .windows(2)
        .filter(|w| w[0].1 == axis_report(1, [0; 3]) && w[1].1 != w[0].1)
        .map(|w| w[1].0)
        .collect();
    let target = softhaptic_device::spacemouse::rate::RateControl::new(rate).target_velocity_m_s(
        &softhaptic_device::spacemouse::report::Axes {
            translation: [1.0, 0.0, 0.0],
            rotation: [0.0; 3],
        },
    );
    let target_x = target.x;
    let (mut motion, mut rise, mut lag) = (Vec::new(), Vec::new(), Vec::new());
    for &onset in &onsets {
        let after: Vec<_> = ticks.iter().filter(|t| t.0 >= onset).collect();
        let Some(first) = after.iter().find(|t| t.2 > 0.0) else {
            continue;
        };
        motion.push((first.0 - onset) as f64 * 1e-6);
        if let Some(r) = after
            .iter()
            .find(|t| t.2 >= target_x * (1.0 - (-1.0f64).exp()))
        {
            rise.push((r.0 - onset) as f64 * 1e-6);
        }
        // The last tick before the release's report reaches the loop: the push's end.
        let start_x = after.first().map_or(0.0, |t| t.1);
        let end_ns = onset + ((PUSH_S - 0.002) * 1e9) as u64;
        if let Some(end) = after.iter().rev().find(|t| t.0 <= end_ns) {
            let ideal = target_x * (end.0 - first.0) as f64 * 1e-9;
            lag.push((ideal - (end.1 - start_x)) / target_x * 1e3);
        }
    }
    for v in [&mut motion, &mut rise, &mut lag] {
        v.sort_by(f64::total_cmp);
    }
    println!(
        "SpaceMouse backend, {} pushes timed of {}, onsets seeded {} (loop: {} ticks, {} lost; real-time {})",
        motion.len(),
        args.pushes,
        args.seed,
        stats.ticks,
        stats.overruns,
        if stats.realtime_granted {
            "granted"
        } else {
            "not granted"
        }
    );
    println!(
        "{:<28} {:>9} {:>9} {:>9}   for comparison",
        "", "p50 ms", "p90 ms", "max ms"
    );
    let row = |name: &str, v: &[f64], note: &str| {
        println!(
            "{name:<28} {:>9.2} {:>9.2} {:>9.2}   {note}",
            percentile(v, 0.5),
            percentile(v, 0.9),
            v.last().copied().unwrap_or(f64::NAN)
        );
    };
    row(
        "report → first motion",
        &motion,
        "one loop period: 1.00 ms; report interval: 16 ms",
    );
    row(
        "report → 63 % of speed",
        &rise,
        &format!("smoothing time constant: {:.0} ms", rate.smoothing_s * 1e3),
    );
    row(
        "position lag (steady push)",
        &lag,
        &format!(
            "a first-order filter trails by τ = {:.0} ms",
            rate.smoothing_s * 1e3
        ),
    );
    Ok(())
}
