//! A loop on a device's own servo clock ([`ServoClock`], as OpenHaptics' scheduler is): every
//! tick runs from the driver's calls, without allocating; while the clock is silent the watchdog
//! keeps ticking and stands aside when it calls again; stopping stops the clock first and then
//! commands zero force. The clock here is a plain thread calling the tick every millisecond (the
//! OpenHaptics stand-in in `tests/` plays the vendor's library itself). One test per binary, so
//! that only its allocations are counted.

// Test code: a panic is how a failure is reported.
#![allow(clippy::unwrap_used)]

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use glam::DVec3;
use softhaptic_device::device::{
    DeviceError, DeviceLimits, DeviceSample, HapticDevice, ServoClock,
};
use softhaptic_device::haptic_loop::{HapticLoop, LoopConfig, TickRecord};
use softhaptic_device::liver;
use softhaptic_device::model::ForceModel;
use softhaptic_device::rt;
use softhaptic_device::sim::{HandScript, SimulatedPhantom};
use softhaptic_proto::{Material, ToolShape};

#[path = "common/counting_allocator.rs"]
mod counting_allocator;
use counting_allocator::ALLOCATIONS;

#[path = "common/liver_world.rs"]
mod liver_world;
use liver_world::{liver_world, test_loop};

/// What the test sees of the clock and the device.
#[derive(Default)]
struct Probe {
    /// The clock calls the tick (cleared: the driver's clock is down).
    calling: AtomicBool,
    /// The clock's calls so far.
    calls: AtomicU64,
    /// `ServoClock::stop` has returned.
    stopped: AtomicBool,
    /// Commands after the clock stopped, and whether any of them was not zero.
    commands_after_stop: AtomicU64,
    nonzero_after_stop: AtomicBool,
    /// Reads inside the clock's calls and outside them: every tick reads the device once.
    reads_in_call: AtomicU64,
    reads_outside: AtomicU64,
}

thread_local! {
    /// Set on the clock's thread while it calls the tick: the device may be read then, as a
    /// driver allows reads only inside its servo callback.
    static IN_CLOCK_CALL: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// A servo clock: a thread calling the tick once per period while `calling` is set.
struct ThreadClock {
    probe: Arc<Probe>,
    running: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl ServoClock for ThreadClock {
    fn period_ns(&self) -> u64 {
        1_000_000
    }

    fn start(
        &mut self,
        mut tick: Box<dyn FnMut(u64) + Send>,
    ) -> Result<(), softhaptic_device::device::ServoStartError> {
        let probe = Arc::clone(&self.probe);
        let running = Arc::clone(&self.running);
        running.store(true, Ordering::Release);
        self.thread = Some(std::thread::spawn(move || {
            let mut next = rt::now_ns();
            while running.load(Ordering::Acquire) {
                next += 1_000_000;
                rt::sleep_until_ns(next);
                next = next.max(rt::now_ns().saturating_sub(500_000));
                if probe.calling.load(Ordering::Acquire) {
                    probe.calls.fetch_add(1, Ordering::Relaxed);
                    IN_CLOCK_CALL.set(true);
                    tick(rt::now_ns());
                    IN_CLOCK_CALL.set(false);
                }
            }
        }));
        Ok(())
    }

    fn stop(&mut self) {
        self.running.store(false, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            thread.join().unwrap();
        }
        self.probe.stopped.store(true, Ordering::Release);
    }
}

/// The simulated PHANTOM behind a driver that owns the clock: readable only inside its calls.
struct ClockedPhantom {
    sim: SimulatedPhantom,
    probe: Arc<Probe>,
    clock_given: bool,
}

impl HapticDevice for ClockedPhantom {
    fn limits(&self) -> DeviceLimits {
        self.sim.limits()
    }

    fn read(&mut self) -> Result<DeviceSample, DeviceError> {
        if !IN_CLOCK_CALL.get() {
            self.probe.reads_outside.fetch_add(1, Ordering::Relaxed);
            return Err(DeviceError::Timeout);
        }
        self.probe.reads_in_call.fetch_add(1, Ordering::Relaxed);
        self.sim.read()
    }

    fn command_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        if self.probe.stopped.load(Ordering::Acquire) {
            self.probe
                .commands_after_stop
                .fetch_add(1, Ordering::Relaxed);
            if force_n != DVec3::ZERO {
                self.probe.nonzero_after_stop.store(true, Ordering::Relaxed);
            }
            return Ok(());
        }
        if IN_CLOCK_CALL.get() {
            self.sim.command_force(force_n)
        } else {
            Ok(())
        }
    }

    fn servo_clock(&mut self) -> Option<Box<dyn ServoClock>> {
        if std::mem::replace(&mut self.clock_given, true) {
            return None;
        }
        Some(Box::new(ThreadClock {
            probe: Arc::clone(&self.probe),
            running: Arc::new(AtomicBool::new(false)),
            thread: None,
        }))
    }
}

fn wait_until(what: &str, condition: impl Fn() -> bool) {
    let give_up = Instant::now() + Duration::from_secs(60);
    while !condition() {
        assert!(Instant::now() < give_up, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(2));
    }
}

#[test]
fn a_device_clocked_loop_ticks_on_the_driver_s_calls_without_allocating_and_stops_with_zero_force()
{
    let top = liver::top_contact();
    let mut script = HandScript::press(top.point_m, top.normal, 0.01);
    script.repeat = true;
    let tool = ToolShape::sphere(0.01).unwrap();
    let world = liver_world(ForceModel::paper(tool, Material::PAPER_SOFT));
    let probe = Arc::new(Probe::default());
    probe.calling.store(true, Ordering::Release);
    let device = ClockedPhantom {
        sim: SimulatedPhantom::new(script),
        probe: Arc::clone(&probe),
        clock_given: false,
    };
    let (producer, mut consumer) = rtrb::RingBuffer::<TickRecord>::new(16);
    let haptic = HapticLoop::spawn(
        Box::new(device),
        world,
        LoopConfig {
            // Ignored: the driver's clock sets the period.
            period_ns: 7_000_000,
            ..test_loop(Some(producer))
        },
    )
    .unwrap();
    assert!(haptic.device_clocked());
    assert!(
        haptic.standby().is_none(),
        "the driver's thread runs the ticks"
    );

    // The ticks run on the clock's calls, and none allocates.
    wait_until("50 ticks", || haptic.latest_contact().tick >= 50);
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    let (in_call_before, tick_before) = (
        probe.reads_in_call.load(Ordering::Relaxed),
        haptic.latest_contact().tick,
    );
    let mut drained = 0;
    while haptic.latest_contact().tick < tick_before + 500 {
        while consumer.pop().is_ok() {
            drained += 1;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let after = ALLOCATIONS.load(Ordering::Relaxed);
    assert_eq!(
        after, before,
        "allocations while the device clocked the loop"
    );
    assert!(drained > 0);
    // Most of them inside the driver's calls (a clock thread starved for 100 ms on a loaded
    // machine lets the watchdog run a few, which the end of the test accounts for).
    let in_call = probe.reads_in_call.load(Ordering::Relaxed) - in_call_before;
    assert!(
        in_call >= 250,
        "{in_call} of 500 ticks inside the clock's calls"
    );

    // The driver's clock falls silent: after 100 periods the watchdog ticks, and the device
    // (outside its driver's calls) reports the error that the loop publishes.
    probe.calling.store(false, Ordering::Release);
    wait_until("watchdog ticks", || haptic.stats().watchdog_ticks >= 50);
    assert_eq!(haptic.device_error(), Some(DeviceError::Timeout));
    let fault = haptic.latest_contact();
    assert_eq!(fault.force_n, DVec3::ZERO);
    // It calls again: the ticks come from its calls again.
    probe.calling.store(true, Ordering::Release);
    wait_until("the device back", || haptic.device_error().is_none());
    let in_call = probe.reads_in_call.load(Ordering::Relaxed);
    wait_until("300 more ticks in the clock's calls", || {
        probe.reads_in_call.load(Ordering::Relaxed) >= in_call + 300
    });

    let stats = haptic.stop();
    assert!(probe.stopped.load(Ordering::Acquire));
    assert_eq!(
        probe.commands_after_stop.load(Ordering::Relaxed),
        1,
        "one command after the clock stopped"
    );
    assert!(
        !probe.nonzero_after_stop.load(Ordering::Relaxed),
        "and it was zero force"
    );
    assert!(stats.ticks >= 700);
    // Every tick was either the driver's or the watchdog's, and the watchdog's are exactly the
    // ticks that read the device outside the driver's calls.
    let (inside, outside) = (
        probe.reads_in_call.load(Ordering::Relaxed),
        probe.reads_outside.load(Ordering::Relaxed),
    );
    assert_eq!(stats.ticks, inside + outside);
    assert_eq!(stats.watchdog_ticks, outside);
}
