//! The haptic loop's timing on a real device's backend, beside the same loop self-clocked on the
//! simulated device: period error p50 / p99 / max, lost ticks, the tick's compute time, and,
//! through the stand-in, the read-to-command latency the device sees.
//!
//! `cargo run --release -p softhaptic-tests --bin device-timing [-- --seconds 10] [--device openhaptics|forcedimension]`
//!
//! - `openhaptics` (the default): the loop on the device's own servo clock; the tick's compute
//!   time runs from the servo callback to the force written, the latency from the frame's state
//!   latch to its force send. The HD stand-in (`tests/standin/hd_standin.c`) plays the device,
//!   its hand pressing the liver; with `SOFTHAPTIC_HD_LIBRARY` pointing at OpenHaptics' own
//!   `libHD.so` and a PHANTOM plugged in, the same command measures the real device.
//! - `forcedimension`: the loop's own thread clocks the device through the SDK; the latency runs
//!   from the position read to the force command, and the stand-in
//!   (`tests/standin/dhd_standin.c`) also counts the watchdog's expiries. With
//!   `SOFTHAPTIC_DHD_LIBRARY` pointing at the SDK's `libdhd.so`, the real device.
//!
//! On a real device hold the handle still, away from the liver: the loop renders the scene's
//! forces.

use std::time::Duration;

use softhaptic_device::device::HapticDevice;
use softhaptic_device::haptic_loop::{HapticLoop, LoopConfig};
use softhaptic_device::stats::LoopStats;
use softhaptic_device::{forcedimension, openhaptics};
use softhaptic_server::devices;
use softhaptic_server::scene::{DeviceChoice, DeviceKind, Scene};
use softhaptic_tests::dhd_standin::{DhdStandIn, dhd_standin_path};
use softhaptic_tests::standin::{Latency, StandIn, standin_path};

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

/// The stand-in playing the device, when no real library was named.
enum Stand {
    Hd(StandIn),
    Dhd(DhdStandIn),
}

impl Stand {
    fn reset_stats(&self) {
        match self {
            Stand::Hd(s) => s.reset_stats(),
            Stand::Dhd(s) => s.reset_stats(),
        }
    }

    fn latency(&self) -> Latency {
        match self {
            Stand::Hd(s) => s.latency(),
            Stand::Dhd(s) => s.latency(),
        }
    }
}

fn option(name: &str) -> Option<String> {
    std::env::args().skip_while(|a| a != name).nth(1)
}

fn main() -> anyhow::Result<()> {
    let seconds: f64 = option("--seconds")
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(10.0);
    let kind = match option("--device").as_deref() {
        None | Some("openhaptics") => DeviceKind::Openhaptics,
        Some("forcedimension") => DeviceKind::Forcedimension,
        Some(other) => anyhow::bail!("--device {other:?}: expected openhaptics or forcedimension"),
    };
    let (env, path) = match kind {
        DeviceKind::Forcedimension => (forcedimension::LIBRARY_ENV, dhd_standin_path()),
        _ => (openhaptics::LIBRARY_ENV, standin_path()),
    };
    let standin = if std::env::var_os(env).is_some() {
        None
    } else {
        // SAFETY: set before any other thread of this process exists.
        unsafe { std::env::set_var(env, path) };
        Some(match kind {
            DeviceKind::Forcedimension => {
                let s = DhdStandIn::load()?;
                s.reset();
                Stand::Dhd(s)
            }
            _ => {
                let s = StandIn::load()?;
                s.reset();
                Stand::Hd(s)
            }
        })
    };

    let mut scene = Scene::builtin_default()?;
    scene.choose_device(&DeviceChoice { kind, name: None });
    if kind == DeviceKind::Forcedimension {
        scene.device_limits = softhaptic_device::device::DeviceLimits::OMEGA3;
    }
    let (point, _) = scene.press_site_in_object;
    scene.world_from_device.position_m = scene.object_in_world.transform_point(point);
    if kind == DeviceKind::Forcedimension {
        // The SDK's z (up) on the world's y, as scenes/forcedimension.toml places it: the
        // stand-in's hand presses down into the liver.
        scene.world_from_device.orientation =
            glam::DQuat::from_rotation_x(-std::f64::consts::FRAC_PI_2);
    }
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
    let latency = standin.as_ref().map(Stand::latency);
    let watchdog = match &standin {
        Some(Stand::Dhd(s)) => Some(s.state()),
        _ => None,
    };

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
    match kind {
        DeviceKind::Forcedimension => row("own thread, Force Dimension", &servo),
        _ => row("device servo clock", &servo),
    }
    row("own thread, simulated", &simulated);
    if let Some(l) = latency {
        let span = match kind {
            DeviceKind::Forcedimension => "position read to force command",
            _ => "state latch to force send",
        };
        println!(
            "read-to-command latency through the stand-in ({span}), {} ticks: p50 {:.0} µs, p99 \
             {:.0} µs, max {:.0} µs; the limit is one period, 1000 µs",
            l.frames, l.p50_us, l.p99_us, l.max_us
        );
    }
    if let Some(state) = watchdog {
        println!(
            "watchdog ({:.0} ms): {} expiries in {} force commands",
            f64::from(state.watchdog_units) * forcedimension::WATCHDOG_UNIT_S * 1e3,
            state.watchdog_trips,
            state.commands
        );
    }
    Ok(())
}
