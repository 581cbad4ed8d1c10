//! The haptic loop's timing on a device's own servo clock (OpenHaptics), beside the same loop
//! self-clocked on the simulated device: period error p50 / p99 / max, lost ticks, the tick's
//! compute time (from the servo callback to the force written), and, through the HD stand-in,
//! the read-to-command latency the device sees (from the frame's state latch to its force send).
//!
//! `cargo run --release -p softhaptic-tests --bin device-timing [-- --seconds 10]`
//!
//! By default the HD stand-in (`tests/standin/hd_standin.c`) plays the device, its hand pressing
//! the liver. With `SOFTHAPTIC_HD_LIBRARY` pointing at OpenHaptics' own `libHD.so` and a PHANTOM
//! plugged in, the same command measures the real device (hold the stylus still, away from the
//! liver: the loop renders the scene's forces).

use std::time::Duration;

use softhaptic_device::device::HapticDevice;
use softhaptic_device::haptic_loop::{HapticLoop, LoopConfig};
use softhaptic_device::openhaptics;
use softhaptic_device::stats::LoopStats;
use softhaptic_server::devices;
use softhaptic_server::scene::{DeviceChoice, DeviceKind, Scene};
use softhaptic_tests::standin::{StandIn, standin_path};

fn us(ns: u64) -> f64 {
    ns as f64 * 1e-3
}

fn row(label: &str, s: &LoopStats) {
    println!(
        "{label:<28} {:>8} {:>6} {:>9.1} {:>9.1} {:>9.1} {:>10.1} {:>10.1} {:>10.1}",
        s.ticks,
        s.overruns,
        us(s.period_error_p50_ns),
        us(s.period_error_p99_ns),
        us(s.period_error_max_ns),
        us(s.compute_p50_ns),
        us(s.compute_p99_ns),
        us(s.compute_max_ns),
    );
}

fn run(device: Box<dyn HapticDevice>, scene: &Scene, seconds: f64) -> anyhow::Result<LoopStats> {
    let haptic_loop = HapticLoop::spawn(device, scene.haptic_world(), LoopConfig::default())?;
    std::thread::sleep(Duration::from_secs_f64(seconds));
    Ok(haptic_loop.stop())
}

fn main() -> anyhow::Result<()> {
    let seconds: f64 = std::env::args()
        .skip_while(|a| a != "--seconds")
        .nth(1)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(10.0);
    let real = std::env::var_os(openhaptics::LIBRARY_ENV).is_some();
    let standin = if real {
        None
    } else {
        // SAFETY: set before any other thread of this process exists.
        unsafe { std::env::set_var(openhaptics::LIBRARY_ENV, standin_path()) };
        let s = StandIn::load()?;
        s.reset();
        Some(s)
    };

    let mut scene = Scene::builtin_default()?;
    scene.choose_device(&DeviceChoice {
        kind: DeviceKind::Openhaptics,
        name: None,
    });
    let (point, _) = scene.press_site_in_object;
    scene.world_from_device.position_m = scene.object_in_world.transform_point(point);
    let device = devices::open(&mut scene)?;
    println!(
        "{} for {seconds} s each, {} build",
        scene.device_label.as_deref().unwrap_or("device"),
        if cfg!(debug_assertions) {
            "debug (use --release for figures)"
        } else {
            "release"
        }
    );
    if let Some(s) = &standin {
        s.reset_stats();
    }
    let servo = run(device, &scene, seconds)?;
    let latency = standin.as_ref().map(StandIn::latency);

    let mut simulated_scene = Scene::builtin_default()?;
    let simulated_device = devices::open(&mut simulated_scene)?;
    let simulated = run(simulated_device, &simulated_scene, seconds)?;

    println!(
        "{:<28} {:>8} {:>6} {:>9} {:>9} {:>9} {:>10} {:>10} {:>10}",
        "loop",
        "ticks",
        "lost",
        "err p50",
        "err p99",
        "err max",
        "tick p50",
        "tick p99",
        "tick max"
    );
    println!("{:<28} {:>8} {:>6} {:>29} {:>32}", "", "", "", "µs", "µs");
    row("device servo clock", &servo);
    row("own thread, simulated", &simulated);
    if let Some(l) = latency {
        println!(
            "read-to-command latency through the stand-in (state latch to force send), {} frames: \
             p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs; the limit is one servo period, 1000 µs",
            l.frames, l.p50_us, l.p99_us, l.max_us
        );
    }
    Ok(())
}
