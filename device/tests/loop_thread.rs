//! The real loop thread, briefly: spawn against the simulated PHANTOM pressing the liver, read
//! the published contact and statistics from other threads, drain the tick ring, stop.

// Test code: a panic is how a failure is reported.
#![allow(clippy::unwrap_used)]

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use glam::DVec3;
use softhaptic_device::device::{DeviceError, DeviceLimits, DeviceSample, HapticDevice};
use softhaptic_device::haptic_loop::{HapticLoop, LoopConfig, LoopError, TickRecord};
use softhaptic_device::liver;
use softhaptic_device::model::ForceModel;
use softhaptic_device::sim::{HandScript, SimulatedPhantom};
use softhaptic_device::world::HapticWorld;
use softhaptic_proto::{Material, ToolShape};

#[path = "common/liver_world.rs"]
mod liver_world;
use liver_world::{liver_world, test_loop};

/// The simulated PHANTOM, reporting the magnitude of every force it is commanded.
struct Watched {
    inner: SimulatedPhantom,
    last_force_bits: Arc<AtomicU64>,
    commands: Arc<AtomicU64>,
}

impl HapticDevice for Watched {
    fn limits(&self) -> DeviceLimits {
        self.inner.limits()
    }
    fn read(&mut self) -> Result<DeviceSample, DeviceError> {
        self.inner.read()
    }
    fn command_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        self.last_force_bits
            .store(force_n.length().to_bits(), Ordering::Relaxed);
        self.commands.fetch_add(1, Ordering::Relaxed);
        self.inner.command_force(force_n)
    }
}

fn setup() -> (Watched, HapticWorld, Arc<AtomicU64>, Arc<AtomicU64>) {
    let top = liver::top_contact();
    let mut script = HandScript::press(top.point_m, top.normal, 0.01);
    // In contact within 100 ms of device time, then a long hold.
    script.approach_s = 0.05;
    script.press_s = 0.05;
    script.hold_s = 60.0;
    let last_force_bits = Arc::new(AtomicU64::new(0));
    let commands = Arc::new(AtomicU64::new(0));
    let device = Watched {
        inner: SimulatedPhantom::new(script),
        last_force_bits: Arc::clone(&last_force_bits),
        commands: Arc::clone(&commands),
    };
    let tool = ToolShape::sphere(0.01).unwrap();
    let world = liver_world(ForceModel::paper(tool, Material::PAPER_SOFT));
    (device, world, last_force_bits, commands)
}

/// Starts the loop thread on `device` and `world` with `config`: [`test_loop`], or what a test
/// changes of it.
fn spawn(
    device: impl HapticDevice + 'static,
    world: HapticWorld,
    config: LoopConfig,
) -> Result<HapticLoop, LoopError> {
    HapticLoop::spawn(Box::new(device), world, config)
}

/// Polls `done` every 5 ms until it holds, however loaded the machine; fails with `what` after
/// 20 s.
fn wait_until(what: &str, mut done: impl FnMut() -> bool) {
    let give_up = Instant::now() + Duration::from_secs(20);
    while !done() {
        assert!(Instant::now() < give_up, "{what}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[test]
fn loop_runs_publishes_and_stops_with_zero_force() {
    let (device, world, last_force_bits, commands) = setup();
    // A small ring that the test drains only partly: some records arrive, some are dropped.
    let (producer, mut consumer) = rtrb::RingBuffer::<TickRecord>::new(64);
    let haptic = spawn(device, world, test_loop(Some(producer))).unwrap();
    assert!(!haptic.realtime().requested);

    // Wait for 150 ms of device time (the hand is pressing by then).
    wait_until("the loop does not advance", || {
        haptic.latest_contact().time_ns >= 150_000_000
    });
    let early = haptic.latest_contact();
    // Read the publication from another thread while the loop runs.
    let reader = std::thread::scope(|s| {
        s.spawn(|| {
            let mut ticks = Vec::new();
            for _ in 0..10 {
                ticks.push(haptic.latest_contact().tick);
                std::thread::sleep(Duration::from_millis(10));
            }
            ticks
        })
        .join()
        .unwrap()
    });
    assert!(reader.windows(2).all(|w| w[1] >= w[0]));
    assert!(reader.last() > reader.first(), "{reader:?}");
    let late = haptic.latest_contact();
    assert!(late.tick > early.tick);
    assert!(late.time_ns > early.time_ns);
    assert!(late.in_contact, "the hand presses by now: {late:?}");
    assert!(late.force_n.length() > 0.0);
    let mid_stats = haptic.stats();
    assert!(
        mid_stats.ticks >= 100,
        "published every 100 ticks: {mid_stats:?}"
    );

    // The ring is full (the loop keeps running, so a drain could also see records pushed into
    // the slots it frees: count what is there at one instant).
    assert_eq!(consumer.slots(), 64);
    for _ in 0..64 {
        let record = consumer.pop().unwrap();
        assert!(record.sample.is_some() && !record.device_fault);
    }

    let stats = haptic.stop();
    println!("{stats:?}");
    assert!(stats.ticks > late.tick, "{stats:?}");
    assert!(stats.loop_rate_hz > 0.0);
    // Every tick run and every tick lost answers a deadline that has passed: the loop never
    // runs ahead of its clock (a property of the code, not of this machine's speed).
    let deadlines_passed = (softhaptic_device::rt::now_ns() - stats.deadline_origin_ns) / 1_000_000;
    assert!(
        stats.ticks + stats.overruns <= deadlines_passed,
        "{} ticks and {} lost for {deadlines_passed} deadlines",
        stats.ticks,
        stats.overruns
    );
    assert!(stats.dropped_tick_records > 0);
    assert!(stats.compute_max_ns > 0 && stats.compute_p50_ns <= stats.compute_max_ns);
    assert!(stats.period_error_p50_ns <= stats.period_error_max_ns);
    assert!(!stats.realtime_granted);
    assert_eq!(stats.device_faults, 0);
    // The loop's last command released the device.
    assert_eq!(f64::from_bits(last_force_bits.load(Ordering::Relaxed)), 0.0);
    assert_eq!(commands.load(Ordering::Relaxed), stats.ticks + 1);
}

#[test]
fn zero_period_is_refused() {
    let (device, world, _, _) = setup();
    let err = spawn(
        device,
        world,
        LoopConfig {
            period_ns: 0,
            ..test_loop(None)
        },
    )
    .err()
    .unwrap();
    assert!(matches!(err, LoopError::Period(0)));
    assert!(err.to_string().contains("period_ns"));
}

#[test]
fn dropping_the_loop_stops_the_thread_and_releases_the_device() {
    let (device, world, last_force_bits, commands) = setup();
    let haptic = spawn(device, world, test_loop(None)).unwrap();
    // Pressing with a force by now.
    wait_until("no force commanded", || {
        f64::from_bits(last_force_bits.load(Ordering::Relaxed)) != 0.0
    });
    drop(haptic);
    // The threads are gone with the device they held (their handles to the counters with it),
    // and the device's last command was zero force.
    assert_eq!(
        Arc::strong_count(&commands),
        1,
        "a thread still holds the device"
    );
    assert_eq!(Arc::strong_count(&last_force_bits), 1);
    assert_eq!(f64::from_bits(last_force_bits.load(Ordering::Relaxed)), 0.0);
}

/// A device whose every 50th read takes 2.5 ms, as a driver stalling on its bus would.
struct Stalling {
    inner: SimulatedPhantom,
    reads: u64,
    stalls: Arc<AtomicU64>,
}

impl HapticDevice for Stalling {
    fn limits(&self) -> DeviceLimits {
        self.inner.limits()
    }
    fn read(&mut self) -> Result<DeviceSample, DeviceError> {
        self.reads += 1;
        if self.reads.is_multiple_of(50) {
            let until = Instant::now() + Duration::from_micros(2500);
            while Instant::now() < until {
                std::hint::spin_loop();
            }
            self.stalls.fetch_add(1, Ordering::Relaxed);
        }
        self.inner.read()
    }
    fn command_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        self.inner.command_force(force_n)
    }
}

#[test]
fn stalls_are_counted_as_overruns() {
    let (watched, world, _, _) = setup();
    let stalls = Arc::new(AtomicU64::new(0));
    let device = Stalling {
        inner: watched.inner,
        reads: 0,
        stalls: Arc::clone(&stalls),
    };
    let haptic = spawn(device, world, test_loop(None)).unwrap();
    wait_until("the loop does not advance", || {
        stalls.load(Ordering::Relaxed) >= 4
    });
    let stats = haptic.stop();
    let stalled = stalls.load(Ordering::Relaxed);
    println!("{stalled} stalls: {stats:?}");
    // Each 2.5 ms stall holds the device across at least one whole period: a deadline passes
    // with no tick started before the next one. The standby cannot help: the tick in progress
    // holds the device.
    assert!(stats.overruns >= stalled, "{stats:?}");
    assert!(stats.compute_max_ns >= 2_500_000);
}

#[test]
fn realtime_request_is_reported_consistently() {
    let (device, world, _, _) = setup();
    let haptic = spawn(
        device,
        world,
        LoopConfig {
            realtime: true,
            ..test_loop(None)
        },
    )
    .unwrap();
    let status = haptic.realtime();
    // Granted (root, CAP_SYS_NICE) or refused (an ordinary user): either way it is said.
    println!("{status}");
    // A standby thread on a second CPU whenever the process has one, never on the loop's CPU.
    let cpus = softhaptic_device::rt::allowed_cpus().unwrap();
    let standby = haptic.standby();
    println!("standby: {standby:?}");
    assert_eq!(standby.is_some(), cpus.len() >= 2);
    if let Some(standby) = standby {
        assert!(standby.cpu.is_some(), "the standby is bound to a CPU");
        assert_ne!(standby.cpu, status.cpu);
        assert_ne!(standby.os_thread_id, status.os_thread_id);
    }
    assert!(status.requested);
    assert_eq!(status.fifo_priority.is_some(), status.fifo_errno.is_none());
    assert_eq!(status.memory_locked, status.mlock_errno.is_none());
    std::thread::sleep(Duration::from_millis(30));
    let stats = haptic.stop();
    assert_eq!(stats.realtime_granted, status.granted());
    assert!(stats.ticks > 0);
}
