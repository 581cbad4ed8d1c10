//! The 1 kHz loop thread.
//!
//! One file because the tick's order (read, step, command, publish) and its real-time rules are
//! checked by reading it top to bottom; its second half is its tests.
//!
//! [`HapticLoop::spawn`] moves a device and a [`HapticWorld`] onto a dedicated std thread that,
//! every period: waits for its absolute deadline, reads the device, steps the world, commands the
//! force, publishes the [`ContactState`], offers a [`TickRecord`] to the session log's ring, and
//! records its timing. Other threads see its results only through wait-free publications
//! ([`crate::cells::SeqCell`]), so no reader can ever delay the force (docs/design.md, invariant 1). Per tick it
//! never allocates, logs, does I/O or waits for another thread.
//!
//! A standby thread on a second CPU wakes a quarter period after each deadline and runs the tick
//! when the loop thread has not started it (its CPU held by the kernel or by the host). The
//! tick's state (device, world, timing) is a `Baton` that the two pass by compare-and-swap:
//! whoever finds it taken leaves the tick to the holder, so neither ever waits.
//!
//! # Who owns the clock
//! A device whose vendor library runs its own servo thread (OpenHaptics' scheduler: device
//! state may be read and force written only inside its callback, between begin and end frame)
//! returns a [`ServoClock`] from [`HapticDevice::servo_clock`], and the loop is then
//! *device-clocked*: each tick runs inside the driver's servo callback, so the reading, the
//! force and the command of a tick share one servo frame (read-to-command latency: the tick's
//! compute time, well under one servo period). The alternative, our own thread exchanging
//! samples and forces with the callback through wait-free cells, was rejected: two 1 kHz clocks
//! drift against each other, so a force would reach the motors between one and two servo
//! periods after the reading it answers, and the extra period of delay costs stability margin
//! on a stiff contact. A device-clocked tick is the same `TickCore` tick behind the same
//! `Baton`: statistics (the period from the driver's tick starts), the recording ring, the
//! published contact and the final zero force work unchanged. While the driver's clock is down
//! (the device is being reconnected) a watchdog thread runs fault ticks at the period, so
//! viewers, the recording and the fault counters see the gap as it happens.
//!
//! Before the first tick the loop allocates its timing state, and each thread prefaults its
//! stack, binds itself to a CPU and asks for SCHED_FIFO and locked memory
//! ([`rt::request_realtime`]); what the machine still does to the period (and what no thread
//! setting can prevent) is in [`crate::rt`].

use std::cell::UnsafeCell;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;

use glam::DVec3;
use softhaptic_proto::{ContactFlags, ContactState, GuideState, Pose};

use crate::cells::{SeqCell, Words, WordsReader};
use crate::device::{DeviceError, DeviceSample, HapticDevice, ServoClock};
use crate::metrics::TraineeMetrics;
use crate::rt::{self, CpuChoice, RealtimeStatus};
use crate::stats::{Histogram, LateLog, LateWake, LoopStats};
use crate::world::{HapticWorld, TickOutcome};

/// How the loop runs.
pub struct LoopConfig {
    /// Period of the loop (1 000 000 ns for 1 kHz).
    pub period_ns: u64,
    /// Ask for SCHED_FIFO and locked memory (see [`crate::rt`] for the privileges needed).
    pub realtime: bool,
    /// Optional ring to the session-log writer; a full ring drops the record (counted), never
    /// waits.
    pub tick_sink: Option<rtrb::Producer<TickRecord>>,
    /// Run a standby thread on a second CPU that takes over a tick the loop thread has not
    /// started a quarter period after its deadline ([`HapticLoop::spawn_on`]).
    pub standby: bool,
}

impl Default for LoopConfig {
    /// 1 kHz, real-time requested, no tick sink, with a standby thread.
    fn default() -> Self {
        Self {
            period_ns: 1_000_000,
            realtime: true,
            tick_sink: None,
            standby: true,
        }
    }
}

/// Everything one tick saw and did, for the session log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickRecord {
    /// The device's reading, `None` when the read failed.
    pub sample: Option<DeviceSample>,
    /// The read failed, the sample was refused (NaN, out of workspace) or the device refused the
    /// command.
    pub device_fault: bool,
    /// Why the read failed, when it did.
    pub device_error: Option<DeviceError>,
    /// Why the device refused the command, when it did (the tick's force is then zero).
    pub command_error: Option<DeviceError>,
    /// Ticks lost right before this one: deadlines (or periods of a device's servo clock) that
    /// passed with no tick run.
    pub lost_before: u64,
    /// What the world computed, including the force commanded.
    pub contact: ContactState,
}

/// Why the loop could not start.
#[derive(Debug, thiserror::Error)]
pub enum LoopError {
    #[error("period_ns must be > 0, got {0}")]
    Period(u64),
    #[error("could not spawn the haptic loop thread: {0}")]
    Spawn(#[source] std::io::Error),
    #[error("the haptic loop thread ended before reporting its start")]
    StartLost,
    #[error("{0}")]
    ServoClock(crate::device::ServoStartError),
}

/// Bounds of the spin before each deadline ([`rt::SpinBudget`]): at least 20 µs, at most 200 µs
/// (20 % of one core at 1 kHz).
const SPIN_MIN_NS: u64 = 20_000;
const SPIN_MAX_NS: u64 = 200_000;
/// Stats are summarised for readers every this many ticks (percentiles scan the histogram).
const STATS_EVERY_TICKS: u64 = 100;
/// A device-clocked loop whose driver has not called for this many periods is taken to be down
/// (reconnecting), and its watchdog starts running fault ticks. Long enough that a servo thread
/// the host merely held back (tens of milliseconds at worst, on a loaded machine without
/// real-time scheduling) is waited for: a watchdog tick is a fault, and the force ramps in again
/// after it.
const WATCHDOG_SILENT_PERIODS: u64 = 100;

const CONTACT_WORDS: usize = 38;

fn contact_to_words(c: &ContactState) -> [u64; CONTACT_WORDS] {
    let mut w = Words::new();
    w.u64(c.tick)
        .u64(c.time_ns)
        .vec3(c.tip_in_world.position_m)
        .quat(c.tip_in_world.orientation)
        .vec3(c.tip_velocity_m_s)
        .u64(u64::from(c.buttons))
        .bool(c.in_contact)
        .f64(c.depth_m)
        .vec3(c.normal)
        .vec3(c.contact_point_m)
        .f64(c.contact_radius_m)
        .vec3(c.force_n)
        .u64(u64::from(c.flags.bits()));
    let g = c.guide.unwrap_or(GuideState {
        force_n: DVec3::ZERO,
        target_m: DVec3::ZERO,
        progress: 0.0,
        gain: 0.0,
        effective_gain: 0.0,
        engaged: false,
        pass: 0,
    });
    w.bool(c.guide.is_some())
        .vec3(g.force_n)
        .vec3(g.target_m)
        .f64(g.progress)
        .f64(g.gain)
        .f64(g.effective_gain)
        .bool(g.engaged)
        .u64(u64::from(g.pass));
    w.finish()
}

fn contact_from_words(words: &[u64; CONTACT_WORDS]) -> ContactState {
    let mut r = WordsReader::new(words);
    let c = ContactState {
        tick: r.u64(),
        time_ns: r.u64(),
        tip_in_world: Pose {
            position_m: r.vec3(),
            orientation: r.quat(),
        },
        tip_velocity_m_s: r.vec3(),
        buttons: r.u64() as u32,
        in_contact: r.bool(),
        depth_m: r.f64(),
        normal: r.vec3(),
        contact_point_m: r.vec3(),
        contact_radius_m: r.f64(),
        force_n: r.vec3(),
        flags: ContactFlags::from_bits_retain(r.u64() as u32),
        guide: None,
    };
    let guided = r.bool();
    let g = GuideState {
        force_n: r.vec3(),
        target_m: r.vec3(),
        progress: r.f64(),
        gain: r.f64(),
        effective_gain: r.f64(),
        engaged: r.bool(),
        pass: r.u64() as u32,
    };
    let c = ContactState {
        guide: guided.then_some(g),
        ..c
    };
    r.finish();
    c
}

/// What the loop threads share with everyone else. Only the holder of the `Baton` writes the
/// cells, so each has one writer at a time.
struct Shared {
    stop: AtomicBool,
    contact: SeqCell<CONTACT_WORDS>,
    stats: SeqCell<{ LoopStats::WORDS }>,
    metrics: SeqCell<{ TraineeMetrics::WORDS }>,
    late: SeqCell<{ LateLog::WORDS }>,
    /// A copy of [`TickCore::next_tick`], so that a thread can see a tick was run without taking
    /// the baton: a thread that took it only to look, and was then held back by its CPU, would
    /// make the other thread skip ticks.
    next_tick: AtomicU64,
    /// The device's error on the last tick ([`DeviceError::to_word`]; 0 when it had none).
    device_error: AtomicU64,
    /// The most severe device error of any tick since the last [`Shared::take_device_error`]
    /// ([`latched_error_word`]; 0: none): a fault of a tick or two between two polls of the
    /// status still reaches the log and the viewers.
    worst_device_error: AtomicU64,
    /// CLOCK_MONOTONIC time of the last call from the driver's servo clock (device-clocked
    /// loops only): the watchdog's evidence that the driver is running.
    last_servo_call_ns: AtomicU64,
}

impl Shared {
    fn new() -> Self {
        Shared {
            stop: AtomicBool::new(false),
            contact: SeqCell::new(contact_to_words(&ContactState::IDLE)),
            stats: SeqCell::new(LoopStats::default().to_words()),
            metrics: SeqCell::new(TraineeMetrics::default().to_words()),
            late: SeqCell::new(LateLog::default().to_words()),
            next_tick: AtomicU64::new(0),
            device_error: AtomicU64::new(0),
            worst_device_error: AtomicU64::new(0),
            last_servo_call_ns: AtomicU64::new(0),
        }
    }
}

impl Shared {
    /// Books a tick's device error into the latch: one atomic maximum, wait-free.
    fn latch_device_error(&self, error: DeviceError) {
        self.worst_device_error
            .fetch_max(latched_error_word(error), Ordering::AcqRel);
    }

    /// The most severe device error since the last call, and clears it (`None`: every tick since
    /// then ran without one).
    fn take_device_error(&self) -> Option<DeviceError> {
        let word = self.worst_device_error.swap(0, Ordering::AcqRel);
        DeviceError::from_word(word & !(0xff << SEVERITY_SHIFT))
    }
}

/// Where a latched error word keeps its severity: above every bit of [`DeviceError::to_word`].
const SEVERITY_SHIFT: u32 = 56;

/// How severe a device error is for the operator: a failed servo tick (no force until a
/// restart) first, then a lost or silent device, a force output latched off, a force the driver
/// stopped, a force sent late, the driver's other errors, and last a device waiting for its
/// calibration (which renders no force, but is not a fault of the moment).
fn severity(error: DeviceError) -> u64 {
    match error {
        DeviceError::Fatal => 8,
        DeviceError::Disconnected => 7,
        DeviceError::Timeout => 6,
        DeviceError::ForceLatched => 5,
        DeviceError::ForceDisabled => 4,
        DeviceError::Overrun => 3,
        DeviceError::Driver(_) => 2,
        DeviceError::NeedsCalibration
        | DeviceError::NeedsCalibrationReset
        | DeviceError::CalibrationUpdating => 1,
    }
}

/// An error as a word whose order is its severity's, for the latch's atomic maximum.
fn latched_error_word(error: DeviceError) -> u64 {
    severity(error) << SEVERITY_SHIFT | error.to_word()
}

/// Which of the two loop threads a thread is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    /// Wakes at each deadline (spinning the last stretch) and runs the tick.
    Loop,
    /// Wakes a grace time after each deadline, on another CPU, and runs the tick only if the loop
    /// thread has not started it.
    Standby,
}

/// Where a tick came from, for its bookkeeping.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum TickSource {
    /// The loop's own threads, on their deadlines.
    Thread(Role),
    /// The device driver's servo thread, at the servo tick that began at this CLOCK_MONOTONIC
    /// time.
    Servo { tick_start_ns: u64 },
    /// The watchdog of a device-clocked loop whose driver stopped calling.
    Watchdog,
}

/// Everything a tick touches: held by one loop thread at a time (`Baton`).
struct TickCore {
    device: Box<dyn HapticDevice>,
    world: HapticWorld,
    tick_sink: Option<rtrb::Producer<TickRecord>>,
    // Boxed so the two 9 kB histograms are on the heap (locked with the rest), not a stack.
    timing: Box<Timing>,
    /// Index of the first tick not yet run; the ticks before it ran, or were lost.
    next_tick: u64,
    /// Start of the last servo tick of a device-clocked loop, `None` before the first and after
    /// a watchdog tick (the driver's clock was down: its next interval is not a period).
    last_servo_start_ns: Option<u64>,
    /// The run of servo ticks since the driver's clock (re)started: its first tick's start, the
    /// ticks run, and the ticks the clock skipped (its grid's periods without a tick).
    servo_run_start_ns: u64,
    servo_run_ticks: u64,
    servo_run_lost: u64,
    /// CLOCK_MONOTONIC time of the last tick of a device-clocked loop, servo or watchdog (the
    /// servo tick's start, the watchdog's wake-up): the periods since it with no tick are lost.
    last_device_tick_ns: Option<u64>,
    /// Ticks lost right before the tick being run, for its record.
    lost_before: u64,
}

/// The tick state, handed between the loop thread and its standby without either ever waiting.
///
/// A thread takes the baton with one compare-and-swap. When the other thread holds it, that one
/// is running a tick, and the taker leaves the tick to it instead of waiting: the baton is only
/// ever tried, never waited for, so the loop never waits on another thread (docs/design.md,
/// invariant 1). `Mutex::try_lock` would behave alike; this type says in its API that no caller
/// blocks, and has no poisoning to handle on the 1 kHz path.
struct Baton<T> {
    held: AtomicBool,
    core: UnsafeCell<T>,
}

// SAFETY: the core is reached only through a `BatonGuard`, and at most one guard exists at a time
// (the compare-and-swap in `try_take` succeeds for one taker until the guard's drop releases it),
// so no two threads touch the core at once. Handing the core from thread to thread is sound
// because it is `Send`.
unsafe impl<T: Send> Sync for Baton<T> {}

impl<T> Baton<T> {
    fn new(core: T) -> Self {
        Self {
            held: AtomicBool::new(false),
            core: UnsafeCell::new(core),
        }
    }

    /// The core, if no other thread holds it.
    fn try_take(&self) -> Option<BatonGuard<'_, T>> {
        self.held
            .compare_exchange(false, true, Ordering::Acquire, Ordering::Relaxed)
            .ok()
            .map(|_| BatonGuard { baton: self })
    }
}

/// Exclusive access to the `TickCore`; released when dropped (also while unwinding).
struct BatonGuard<'a, T> {
    baton: &'a Baton<T>,
}

impl<T> std::ops::Deref for BatonGuard<'_, T> {
    type Target = T;
    fn deref(&self) -> &T {
        // SAFETY: this guard is the only one alive (see `Baton`), and its Acquire in `try_take`
        // saw every write the previous holder made before its Release in `drop`.
        unsafe { &*self.baton.core.get() }
    }
}

impl<T> std::ops::DerefMut for BatonGuard<'_, T> {
    fn deref_mut(&mut self) -> &mut T {
        // SAFETY: as in `deref`; `&mut self` makes this the only reference through the guard.
        unsafe { &mut *self.baton.core.get() }
    }
}

impl<T> Drop for BatonGuard<'_, T> {
    fn drop(&mut self) {
        self.baton.held.store(false, Ordering::Release);
    }
}

/// A running haptic loop. Dropping it stops the threads too.
pub struct HapticLoop {
    shared: Arc<Shared>,
    baton: Arc<Baton<TickCore>>,
    threads: Vec<JoinHandle<()>>,
    realtime: RealtimeStatus,
    standby: Option<RealtimeStatus>,
    /// The driver's servo clock of a device-clocked loop. Behind a mutex only so the loop can be
    /// shared between threads; it is touched at start and stop, never by a tick.
    servo: Option<std::sync::Mutex<Box<dyn ServoClock>>>,
}

impl HapticLoop {
    /// Starts the loop thread, not bound to a CPU ([`CpuChoice::Unpinned`]), with its standby
    /// when [`LoopConfig::standby`] asks for one (see [`HapticLoop::spawn_on`]).
    pub fn spawn(
        device: Box<dyn HapticDevice>,
        world: HapticWorld,
        config: LoopConfig,
    ) -> Result<HapticLoop, LoopError> {
        Self::spawn_on(device, world, config, CpuChoice::Unpinned)
    }

    /// Starts the loop thread, placed as `cpu` says (a refused binding is reported in
    /// [`HapticLoop::realtime`] and the thread runs unbound).
    ///
    /// With [`LoopConfig::standby`] and more than one CPU, a standby thread is bound to another
    /// CPU ([`rt::standby_placement`]; an unbound loop thread is then kept off that CPU). It
    /// wakes a quarter period after each deadline and runs the tick itself when the loop thread
    /// has not started it: a wake-up held back on one CPU (non-preemptible kernel work, a
    /// virtual CPU descheduled by its host, measured by `loop-timing`) then costs a quarter period
    /// instead of a lost tick. The tick state passes between the two without either waiting
    /// (`Baton`).
    ///
    /// Returns once the threads have asked for real-time treatment, so the caller learns what
    /// was granted ([`HapticLoop::realtime`], [`HapticLoop::standby`]) before the first tick; a
    /// refusal is logged here, once, as a warning.
    ///
    /// A device with a [`ServoClock`] runs device-clocked instead (see the module docs): `cpu`,
    /// `config.period_ns`, `config.realtime` and `config.standby` then do not apply, because the
    /// driver's servo thread sets the period, its priority and its CPU.
    pub fn spawn_on(
        mut device: Box<dyn HapticDevice>,
        world: HapticWorld,
        config: LoopConfig,
        cpu: CpuChoice,
    ) -> Result<HapticLoop, LoopError> {
        if let Some(clock) = device.servo_clock() {
            return Self::spawn_device_clocked(device, clock, world, config);
        }
        let period_ns = config.period_ns;
        if period_ns == 0 {
            return Err(LoopError::Period(0));
        }
        let shared = Arc::new(Shared::new());
        // Allocated before the threads' real-time requests, so that mlockall locks it too: the
        // only allocation of the loop.
        let baton = Arc::new(Baton::new(TickCore::new(device, world, config.tick_sink)));
        let placement = if config.standby {
            rt::standby_placement(cpu, config.realtime)
        } else {
            None
        };
        let mut roles = vec![(Role::Loop, placement.map_or(cpu, |(loop_cpu, _)| loop_cpu))];
        if let Some((_, standby_cpu)) = placement {
            roles.push((Role::Standby, CpuChoice::Index(standby_cpu)));
        }

        // Each thread reports what it was granted, then waits for the deadlines' common origin.
        let (status_tx, status_rx) = std::sync::mpsc::sync_channel(roles.len());
        let mut origin_txs = Vec::with_capacity(roles.len());
        let mut threads = Vec::with_capacity(roles.len());
        for (role, cpu_choice) in roles {
            let (origin_tx, origin_rx) = std::sync::mpsc::sync_channel::<u64>(1);
            let status_tx = status_tx.clone();
            let thread_shared = Arc::clone(&shared);
            let thread_baton = Arc::clone(&baton);
            let name = match role {
                Role::Loop => "haptic-loop",
                Role::Standby => "haptic-standby",
            };
            let spawned = std::thread::Builder::new()
                .name(name.into())
                .stack_size(rt::LOOP_STACK_BYTES)
                .spawn(move || {
                    let status =
                        rt::request_realtime(config.realtime, rt::LOOP_PRIORITY, cpu_choice);
                    // The spawner may have given up waiting; then no origin comes either.
                    let _ = status_tx.send((role, status));
                    if let Ok(origin_ns) = origin_rx.recv() {
                        run(&thread_baton, &thread_shared, role, origin_ns, period_ns);
                    }
                });
            match spawned {
                Ok(handle) => {
                    threads.push(handle);
                    origin_txs.push(origin_tx);
                }
                // Threads already started end when their origin sender is dropped here.
                Err(e) => return Err(LoopError::Spawn(e)),
            }
        }
        drop(status_tx);
        let mut realtime = None;
        let mut standby = None;
        for _ in 0..threads.len() {
            match status_rx.recv().map_err(|_| LoopError::StartLost)? {
                (Role::Loop, status) => realtime = Some(status),
                (Role::Standby, status) => standby = Some(status),
            }
        }
        let realtime = realtime.ok_or(LoopError::StartLost)?;

        let origin_ns = rt::now_ns();
        if let Some(mut core) = baton.try_take() {
            // No thread has its origin yet, so the baton is free.
            core.timing.start_ns = origin_ns;
            core.timing.realtime_granted =
                realtime.granted() && standby.is_none_or(|s| s.granted());
            // Published at once, so that readers know the deadlines' origin before the first tick.
            shared
                .stats
                .write(&core.timing.summary(origin_ns).to_words());
        }
        for tx in origin_txs {
            let _ = tx.send(origin_ns);
        }

        for (label, status) in [("loop", Some(realtime)), ("standby", standby)] {
            let Some(status) = status else { continue };
            if config_requested_and_refused(&status) {
                tracing::warn!(thread = label, status = %status, "haptic thread runs without real-time guarantees");
            } else {
                tracing::info!(thread = label, status = %status, "haptic thread started");
            }
        }
        if config.standby && standby.is_none() {
            tracing::info!("haptic loop runs without a standby thread: the process has one CPU");
        }
        Ok(HapticLoop {
            shared,
            baton,
            threads,
            realtime,
            standby,
            servo: None,
        })
    }

    /// Starts a device-clocked loop: the driver's servo thread runs the ticks, a watchdog thread
    /// covers the times its clock is down.
    fn spawn_device_clocked(
        device: Box<dyn HapticDevice>,
        mut clock: Box<dyn ServoClock>,
        world: HapticWorld,
        config: LoopConfig,
    ) -> Result<HapticLoop, LoopError> {
        let period_ns = clock.period_ns();
        if period_ns == 0 {
            return Err(LoopError::Period(0));
        }
        let shared = Arc::new(Shared::new());
        let baton = Arc::new(Baton::new(TickCore::new(device, world, config.tick_sink)));
        let origin_ns = rt::now_ns();
        // Counted as called now, so the watchdog gives the driver its first periods to start.
        shared
            .last_servo_call_ns
            .store(origin_ns, Ordering::Release);
        if let Some(mut core) = baton.try_take() {
            core.timing.start_ns = origin_ns;
            shared
                .stats
                .write(&core.timing.summary(origin_ns).to_words());
        }

        // The watchdog asks for nothing: it runs only while the driver's clock is down, when
        // there is no force to keep on time.
        let (status_tx, status_rx) = std::sync::mpsc::sync_channel(1);
        let watchdog = {
            let shared = Arc::clone(&shared);
            let baton = Arc::clone(&baton);
            std::thread::Builder::new()
                .name("haptic-watchdog".into())
                .stack_size(rt::LOOP_STACK_BYTES)
                .spawn(move || {
                    let status =
                        rt::request_realtime(false, rt::LOOP_PRIORITY, CpuChoice::Unpinned);
                    let _ = status_tx.send(status);
                    watch(&baton, &shared, period_ns);
                })
                .map_err(LoopError::Spawn)?
        };
        let mut realtime = status_rx.recv().map_err(|_| LoopError::StartLost)?;
        if config.realtime {
            // The ticks run on the driver's thread, which no setting here reaches; the memory
            // they touch is locked as for a self-clocked loop (its state is allocated above).
            realtime.requested = true;
            (realtime.memory_locked, realtime.mlock_errno) = rt::lock_memory();
        }

        let tick_shared = Arc::clone(&shared);
        let tick_baton = Arc::clone(&baton);
        let started = clock.start(Box::new(move |tick_start_ns| {
            let called_ns = rt::now_ns();
            tick_shared
                .last_servo_call_ns
                .store(called_ns, Ordering::Release);
            if tick_shared.stop.load(Ordering::Acquire) {
                return;
            }
            // Taken only by the watchdog otherwise, which runs only while this clock is silent.
            if let Some(mut core) = tick_baton.try_take() {
                core.run_tick(
                    TickSource::Servo { tick_start_ns },
                    called_ns,
                    &tick_shared,
                    period_ns,
                );
            }
        }));
        if let Err(e) = started {
            shared.stop.store(true, Ordering::Release);
            clock.stop();
            let _ = watchdog.join();
            return Err(LoopError::ServoClock(e));
        }
        tracing::info!(
            period_us = period_ns as f64 * 1e-3,
            "haptic loop runs on the device driver's servo clock"
        );
        Ok(HapticLoop {
            shared,
            baton,
            threads: vec![watchdog],
            realtime,
            standby: None,
            servo: Some(std::sync::Mutex::new(clock)),
        })
    }

    /// Whether the driver's servo thread clocks the loop ([`ServoClock`]).
    pub fn device_clocked(&self) -> bool {
        self.servo.is_some()
    }

    /// The device's error on the last tick, `None` when the last tick read and commanded it
    /// without one. Wait-free; for the operator's and the viewers' status line.
    pub fn device_error(&self) -> Option<DeviceError> {
        DeviceError::from_word(self.shared.device_error.load(Ordering::Acquire))
    }

    /// The most severe device error of any tick since the last call (`None`: every tick since
    /// then ran without one), and clears it: a fault of a single tick between two calls is still
    /// seen. Wait-free. For one poller (the status line's); a second would take errors from the
    /// first.
    pub fn take_device_error(&self) -> Option<DeviceError> {
        self.shared.take_device_error()
    }

    /// What the operating system granted the loop thread.
    pub fn realtime(&self) -> RealtimeStatus {
        self.realtime
    }

    /// What the operating system granted the standby thread, `None` when there is none.
    pub fn standby(&self) -> Option<RealtimeStatus> {
        self.standby
    }

    /// The contact state of the last tick. Wait-free for the loop; callable from any thread.
    pub fn latest_contact(&self) -> ContactState {
        contact_from_words(&self.shared.contact.read())
    }

    /// The trainee's metrics, refreshed every 100 ticks (and by [`HapticLoop::stop`]'s last tick).
    pub fn metrics(&self) -> TraineeMetrics {
        TraineeMetrics::from_words(&self.shared.metrics.read())
    }

    /// The timing summary, refreshed every 100 ticks.
    pub fn stats(&self) -> LoopStats {
        LoopStats::from_words(&self.shared.stats.read())
    }

    /// The latest deadlines that waited more than half a period for a tick to start (a late
    /// tick, or a run of lost ticks), with their clock times; refreshed on each.
    pub fn late_wakes(&self) -> LateLog {
        LateLog::from_words(&self.shared.late.read())
    }

    /// Stops the loop (the device is commanded zero force last), joins the threads and returns
    /// the final statistics.
    pub fn stop(mut self) -> LoopStats {
        self.halt()
    }

    /// [`HapticLoop::stop`] keeping the loop's last publications readable ([`HapticLoop::metrics`]).
    pub fn stop_ref(&mut self) -> LoopStats {
        self.halt()
    }

    fn halt(&mut self) -> LoopStats {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(servo) = self.servo.take() {
            // Zero force, force output off, the driver's thread stopped: no tick runs after this.
            let mut clock = servo
                .into_inner()
                .unwrap_or_else(|poisoned| poisoned.into_inner());
            clock.stop();
        }
        for thread in self.threads.drain(..) {
            // A thread that panicked (a bug) released the baton while unwinding.
            let _ = thread.join();
        }
        // Both threads have ended, so the baton is free.
        match self.baton.try_take() {
            Some(mut core) => {
                // Never leave the device pushing: the last command of the loop is zero force.
                if core.device.command_force(DVec3::ZERO).is_err() {
                    core.timing.command_errors += 1;
                }
                let summary = core.timing.summary(rt::now_ns());
                self.shared.stats.write(&summary.to_words());
                // Every tick's metrics, the last ones included, for the session's end.
                self.shared.metrics.write(&core.world.metrics().to_words());
                summary
            }
            None => self.stats(),
        }
    }
}

impl Drop for HapticLoop {
    fn drop(&mut self) {
        if !self.threads.is_empty() {
            self.halt();
        }
    }
}

fn config_requested_and_refused(status: &RealtimeStatus) -> bool {
    status.requested && !status.granted()
}

/// Timing state of the loop; fixed size, allocated once before the first tick.
struct Timing {
    period_error: Histogram,
    compute: Histogram,
    ticks: u64,
    standby_ticks: u64,
    /// Fault ticks the watchdog of a device-clocked loop ran while the driver's clock was down.
    watchdog_ticks: u64,
    overruns: u64,
    dropped: u64,
    device_faults: u64,
    command_errors: u64,
    start_ns: u64,
    realtime_granted: bool,
    /// The loop thread's current spin before each deadline ([`rt::SpinBudget`]).
    spin_ns: u64,
    late: LateLog,
}

impl Timing {
    /// Fresh state; its clock starts in [`HapticLoop::spawn_on`].
    fn new() -> Self {
        Self {
            period_error: Histogram::new(),
            compute: Histogram::new(),
            ticks: 0,
            standby_ticks: 0,
            watchdog_ticks: 0,
            overruns: 0,
            dropped: 0,
            device_faults: 0,
            command_errors: 0,
            start_ns: 0,
            realtime_granted: false,
            spin_ns: 0,
            late: LateLog::default(),
        }
    }

    fn summary(&self, now_ns: u64) -> LoopStats {
        let elapsed_s = now_ns.saturating_sub(self.start_ns) as f64 * 1e-9;
        LoopStats {
            ticks: self.ticks,
            loop_rate_hz: if elapsed_s > 0.0 {
                self.ticks as f64 / elapsed_s
            } else {
                0.0
            },
            period_error_p50_ns: self.period_error.quantile_ns(0.5),
            period_error_p99_ns: self.period_error.quantile_ns(0.99),
            period_error_p999_ns: self.period_error.quantile_ns(0.999),
            period_error_max_ns: self.period_error.max_ns(),
            overruns: self.overruns,
            compute_p50_ns: self.compute.quantile_ns(0.5),
            compute_p99_ns: self.compute.quantile_ns(0.99),
            compute_max_ns: self.compute.max_ns(),
            dropped_tick_records: self.dropped,
            device_faults: self.device_faults,
            command_errors: self.command_errors,
            realtime_granted: self.realtime_granted,
            spin_ns: self.spin_ns,
            deadline_origin_ns: self.start_ns,
            standby_ticks: self.standby_ticks,
            watchdog_ticks: self.watchdog_ticks,
        }
    }
}

/// CLOCK_MONOTONIC time at which tick `tick` is due: one period after the origin for tick 0.
fn due_at(origin_ns: u64, period_ns: u64, tick: u64) -> u64 {
    origin_ns + (tick + 1) * period_ns
}

/// The latest tick due at `now_ns` (`now_ns` at or after tick 0's deadline). A thread that wakes
/// late runs this one, not the oldest one missed: the lost ticks are skipped instead of run as a
/// burst (a burst would hand the device several forces within microseconds).
fn latest_due(origin_ns: u64, period_ns: u64, now_ns: u64) -> u64 {
    (now_ns.saturating_sub(origin_ns) / period_ns).saturating_sub(1)
}

impl TickCore {
    /// The tick state before the first tick.
    fn new(
        device: Box<dyn HapticDevice>,
        world: HapticWorld,
        tick_sink: Option<rtrb::Producer<TickRecord>>,
    ) -> Self {
        TickCore {
            device,
            world,
            tick_sink,
            timing: Box::new(Timing::new()),
            next_tick: 0,
            last_servo_start_ns: None,
            servo_run_start_ns: 0,
            servo_run_ticks: 0,
            servo_run_lost: 0,
            last_device_tick_ns: None,
            lost_before: 0,
        }
    }

    /// Books the deadline (or servo tick) that tick `tick` serves, run by a thread that woke (or
    /// was called) at `woke_ns`.
    fn book_deadline(
        &mut self,
        tick: u64,
        woke_ns: u64,
        role: Role,
        shared: &Shared,
        origin_ns: u64,
        period_ns: u64,
    ) {
        let timing = &mut self.timing;
        let deadline = due_at(origin_ns, period_ns, tick);
        timing.period_error.record(woke_ns.saturating_sub(deadline));
        // How long the earliest deadline no tick has served waited: this tick's lateness, or,
        // when ticks were lost, the whole gap since the first of them.
        let first_unserved = due_at(origin_ns, period_ns, self.next_tick.min(tick));
        let waited_ns = woke_ns.saturating_sub(first_unserved);
        if waited_ns > period_ns / 2 {
            // Rare, and fixed size: written only when a deadline waited that long.
            timing.late.push(LateWake {
                deadline_ns: first_unserved,
                late_ns: waited_ns,
            });
            shared.late.write(&timing.late.to_words());
        }
        // Deadlines that passed with no tick started before the next one.
        self.lost_before = tick - self.next_tick;
        timing.overruns += self.lost_before;
        if role == Role::Standby {
            timing.standby_ticks += 1;
        }
    }

    /// Books a servo tick of the driver's clock that began at `tick_start_ns`: the period comes
    /// from the device's clock, and the periods of its grid that passed without a tick count as
    /// lost (a late tick followed by an early one lost nothing).
    ///
    /// The first tick of a run (the driver's clock started again after a reconnection, or after
    /// the watchdog covered a silence) is preceded by the periods since the loop's last tick,
    /// servo or watchdog, that no tick served.
    fn book_servo_tick(&mut self, tick_start_ns: u64, shared: &Shared, period_ns: u64) {
        let restart_lost = if self.last_servo_start_ns.is_none() {
            self.servo_run_start_ns = tick_start_ns;
            self.servo_run_ticks = 0;
            self.servo_run_lost = 0;
            self.periods_without_a_tick(tick_start_ns, period_ns)
        } else {
            0
        };
        self.last_device_tick_ns = Some(tick_start_ns);
        let timing = &mut self.timing;
        timing.overruns += restart_lost;
        self.servo_run_ticks += 1;
        // Whole periods since the run began: a tick late by less than a period still serves its
        // own slot (the next tick, back on the grid, shows nothing was skipped).
        let periods = tick_start_ns.saturating_sub(self.servo_run_start_ns) / period_ns;
        let lost = (periods + 1).saturating_sub(self.servo_run_ticks);
        self.lost_before = lost.saturating_sub(self.servo_run_lost) + restart_lost;
        if lost > self.servo_run_lost {
            timing.overruns += lost - self.servo_run_lost;
            self.servo_run_lost = lost;
        }
        if let Some(previous) = self.last_servo_start_ns {
            let interval_ns = tick_start_ns.saturating_sub(previous);
            timing.period_error.record(interval_ns.abs_diff(period_ns));
            if interval_ns > period_ns + period_ns / 2 {
                timing.late.push(LateWake {
                    deadline_ns: previous + period_ns,
                    late_ns: interval_ns - period_ns,
                });
                shared.late.write(&timing.late.to_words());
            }
        }
        self.last_servo_start_ns = Some(tick_start_ns);
    }

    /// Whole periods of a device-clocked loop between its last tick (servo or watchdog) and a tick
    /// at `now_ns` that no tick served: none before the first tick, none for a tick one period
    /// (or up to just under two) after the last.
    fn periods_without_a_tick(&self, now_ns: u64, period_ns: u64) -> u64 {
        self.last_device_tick_ns.map_or(0, |last| {
            (now_ns.saturating_sub(last) / period_ns).saturating_sub(1)
        })
    }

    /// Runs the next tick for `source`, whose thread woke (or was called) at `woke_ns`.
    fn run_tick(&mut self, source: TickSource, woke_ns: u64, shared: &Shared, period_ns: u64) {
        match source {
            TickSource::Servo { tick_start_ns } => {
                self.book_servo_tick(tick_start_ns, shared, period_ns)
            }
            TickSource::Watchdog => {
                // The silence before the watchdog's first tick (it waits that long before it
                // takes over), and any period it missed itself, are ticks lost.
                self.lost_before = self.periods_without_a_tick(woke_ns, period_ns);
                self.last_device_tick_ns = Some(woke_ns);
                self.last_servo_start_ns = None;
                self.timing.watchdog_ticks += 1;
                self.timing.overruns += self.lost_before;
            }
            // Booked by the caller, which knows the deadline.
            TickSource::Thread(_) => {}
        }
        let tick = self.next_tick;
        self.next_tick = tick + 1;
        shared.next_tick.store(self.next_tick, Ordering::Release);

        let TickOutcome {
            state,
            read,
            command,
        } = self.world.tick(self.device.as_mut());
        let timing = &mut self.timing;
        if command.is_err() {
            timing.command_errors += 1;
        }
        shared.contact.write(&contact_to_words(&state));
        let error = read.err().or(command.err());
        shared
            .device_error
            .store(error.map_or(0, DeviceError::to_word), Ordering::Release);
        for e in [read.err(), command.err()].into_iter().flatten() {
            shared.latch_device_error(e);
        }
        let device_fault = state.flags.contains(ContactFlags::DEVICE_FAULT);
        if device_fault {
            timing.device_faults += 1;
        }
        if let Some(sink) = self.tick_sink.as_mut() {
            let record = TickRecord {
                sample: read.ok(),
                device_fault,
                device_error: read.err(),
                command_error: command.err(),
                lost_before: self.lost_before,
                contact: state,
            };
            if sink.push(record).is_err() {
                timing.dropped += 1;
            }
        }
        timing.ticks += 1;
        let done = rt::now_ns();
        timing.compute.record(done.saturating_sub(woke_ns));
        if timing.ticks.is_multiple_of(STATS_EVERY_TICKS) {
            shared.stats.write(&timing.summary(done).to_words());
            shared.metrics.write(&self.world.metrics().to_words());
        }
    }
}

/// The watchdog of a device-clocked loop: while the driver's servo clock is silent (the device
/// is being reconnected, or its driver stalled), it runs a fault tick every period, so the
/// viewers, the recording and the fault counters follow the outage. It stands aside as soon as
/// the driver calls again.
fn watch(baton: &Baton<TickCore>, shared: &Shared, period_ns: u64) {
    let silent_ns = WATCHDOG_SILENT_PERIODS * period_ns;
    let mut next_ns = rt::now_ns() + period_ns;
    while !shared.stop.load(Ordering::Acquire) {
        rt::sleep_until_ns(next_ns);
        let now = rt::now_ns();
        // After a long sleep, keep the period from now rather than catching up in a burst.
        next_ns = (next_ns + period_ns).max(now + period_ns / 2);
        let last_call = shared.last_servo_call_ns.load(Ordering::Acquire);
        if now.saturating_sub(last_call) <= silent_ns || shared.stop.load(Ordering::Acquire) {
            continue;
        }
        if let Some(mut core) = baton.try_take() {
            core.run_tick(TickSource::Watchdog, now, shared, period_ns);
        }
    }
}

/// The body of the loop thread and of its standby.
fn run(baton: &Baton<TickCore>, shared: &Shared, role: Role, origin_ns: u64, period_ns: u64) {
    let mut spin = rt::SpinBudget::new(SPIN_MIN_NS, SPIN_MAX_NS.min(period_ns / 2));
    // Past the loop thread's usual lateness (its p99.9 on the machines measured is under 250 µs
    // at 1 kHz), so the standby rarely takes a tick the loop thread was about to run.
    let grace_ns = period_ns / 4;
    // The tick this thread waits for next.
    let mut tick = 0;
    while !shared.stop.load(Ordering::Acquire) {
        let deadline = due_at(origin_ns, period_ns, tick);
        match role {
            Role::Loop => {
                if let Some(overshoot) = rt::wait_until_ns(deadline, spin.spin_ns()) {
                    spin.observe(overshoot);
                }
            }
            Role::Standby => rt::sleep_until_ns(deadline + grace_ns),
        }
        let woke = rt::now_ns();
        let due = latest_due(origin_ns, period_ns, woke).max(tick);
        // Already run by the other thread: the baton is left alone.
        if due >= shared.next_tick.load(Ordering::Acquire) {
            // Not taken: the other thread is running this tick, or an earlier one that overran.
            if let Some(mut core) = baton.try_take() {
                if role == Role::Loop {
                    core.timing.spin_ns = spin.spin_ns();
                }
                // Checked again under the baton: the other thread may have run it meanwhile.
                if due >= core.next_tick {
                    core.book_deadline(due, woke, role, shared, origin_ns, period_ns);
                    core.next_tick = due;
                    core.run_tick(TickSource::Thread(role), woke, shared, period_ns);
                }
            }
        }
        tick = due + 1;
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn a_late_thread_runs_the_latest_due_tick() {
        const P: u64 = 1_000_000;
        let origin = 5 * P;
        assert_eq!(due_at(origin, P, 0), 6 * P);
        // On time, or late by less than a period: the tick waited for.
        assert_eq!(latest_due(origin, P, due_at(origin, P, 9)), 9);
        assert_eq!(latest_due(origin, P, due_at(origin, P, 9) + P - 1), 9);
        // 2.5 periods late: ticks 10 and 11 are lost, 12 runs, late by half a period.
        let woke = due_at(origin, P, 10) + 2 * P + P / 2;
        assert_eq!(latest_due(origin, P, woke), 12);
        assert_eq!(woke - due_at(origin, P, 12), P / 2);
        // Before the first deadline (never passed by the threads, but defined).
        assert_eq!(latest_due(origin, P, origin), 0);
    }

    #[test]
    fn the_baton_is_held_by_one_thread_at_a_time() {
        // Two threads bump a pair of plain integers through the baton with a pause between the
        // two writes; a second holder would see them differ, or lose an update.
        let baton = Arc::new(Baton::new((0u64, 0u64)));
        let takes: Vec<u64> = std::thread::scope(|s| {
            let workers: Vec<_> = (0..2)
                .map(|_| {
                    let baton = Arc::clone(&baton);
                    s.spawn(move || {
                        let mut taken = 0;
                        for _ in 0..200_000 {
                            if let Some(mut pair) = baton.try_take() {
                                assert_eq!(pair.0, pair.1, "another holder was mid-update");
                                pair.0 += 1;
                                std::hint::spin_loop();
                                pair.1 += 1;
                                taken += 1;
                            }
                        }
                        taken
                    })
                })
                .collect();
            workers.into_iter().map(|w| w.join().unwrap()).collect()
        });
        let pair = baton.try_take().unwrap();
        assert_eq!(*pair, (takes[0] + takes[1], takes[0] + takes[1]));
        assert!(baton.try_take().is_none(), "held while the guard lives");
        drop(pair);
        assert!(baton.try_take().is_some(), "released by the guard's drop");
    }

    /// The simulated PHANTOM pressing a flat grid.
    fn grid_core() -> TickCore {
        use crate::collision::{Collider, CollisionMode};
        use crate::device::DeviceLimits;
        use crate::force::ForceConfig;
        use crate::mesh::HapticMesh;
        use crate::sim::{HandScript, SimulatedPhantom};
        use softhaptic_proto::{Material, ToolShape};
        let tool = ToolShape::sphere(0.01).unwrap();
        let world = HapticWorld::new(
            Collider::new(HapticMesh::grid(40, 0.1), CollisionMode::default()),
            Pose::IDENTITY,
            tool,
            Material::PAPER_SOFT,
            ForceConfig::for_tool(&tool),
            DeviceLimits::PHANTOM_DESKTOP,
        );
        TickCore::new(
            Box::new(SimulatedPhantom::new(HandScript::press(
                DVec3::ZERO,
                DVec3::Y,
                0.005,
            ))),
            world,
            None,
        )
    }

    #[test]
    fn the_standby_runs_the_ticks_of_a_held_back_loop_thread_once_each() {
        const P: u64 = 1_000_000;
        let baton = Baton::new(grid_core());
        let shared = Shared::new();
        let origin = rt::now_ns();
        let released = AtomicBool::new(false);
        let published = || LoopStats::from_words(&shared.stats.read());
        let wait_for = |what: &str, done: &dyn Fn(&LoopStats) -> bool| {
            let give_up = std::time::Instant::now() + std::time::Duration::from_secs(30);
            while !done(&published()) {
                assert!(std::time::Instant::now() < give_up, "timed out: {what}");
                std::thread::sleep(std::time::Duration::from_millis(2));
            }
        };
        std::thread::scope(|s| {
            // The loop thread is held back until the standby has run ticks in its place, as a CPU
            // busy in the kernel would hold it; then it runs as usual.
            s.spawn(|| {
                while !released.load(Ordering::Acquire) {
                    std::thread::sleep(std::time::Duration::from_millis(1));
                }
                run(&baton, &shared, Role::Loop, origin, P);
            });
            s.spawn(|| run(&baton, &shared, Role::Standby, origin, P));
            // Stats are published every 100 ticks: polled, however loaded the machine is.
            wait_for("the standby's ticks", &|st| st.standby_ticks >= 5);
            released.store(true, Ordering::Release);
            wait_for("the loop thread's ticks", &|st| {
                st.ticks - st.standby_ticks >= 5
            });
            shared.stop.store(true, Ordering::Release);
        });
        let core = baton.try_take().unwrap();
        let t = &core.timing;
        println!(
            "ticks {}, by the standby {}, lost {}",
            t.ticks, t.standby_ticks, t.overruns
        );
        assert!(
            t.standby_ticks >= 5,
            "the standby covered the held-back loop thread"
        );
        assert!(
            t.ticks - t.standby_ticks >= 5,
            "the loop thread ran the ticks once released"
        );
        // No tick ran twice: each index up to the last either ran once or was lost.
        assert_eq!(t.ticks + t.overruns, core.next_tick);
        assert_eq!(core.world.ticks(), t.ticks, "one world step per tick");
        assert_eq!(shared.next_tick.load(Ordering::Relaxed), core.next_tick);
    }

    #[test]
    fn servo_ticks_count_as_lost_only_the_periods_the_device_clock_skipped() {
        const P: u64 = 1_000_000;
        let mut core = grid_core();
        let (producer, mut consumer) = rtrb::RingBuffer::new(16);
        core.tick_sink = Some(producer);
        let shared = Shared::new();
        // On time, on time, 0.7 period late, then back on the grid (nothing lost), then two
        // periods skipped.
        for start in [0, P, 2 * P + 7 * P / 10, 3 * P, 6 * P] {
            core.run_tick(
                TickSource::Servo {
                    tick_start_ns: 10 * P + start,
                },
                10 * P + start,
                &shared,
                P,
            );
        }
        assert_eq!(core.timing.overruns, 2);
        assert_eq!(core.timing.ticks, 5);
        // Each tick's record says how many were lost right before it.
        let lost: Vec<u64> = std::iter::from_fn(|| consumer.pop().ok())
            .map(|r| r.lost_before)
            .collect();
        assert_eq!(lost, [0, 0, 0, 0, 2]);
        assert_eq!(core.timing.period_error.max_ns(), 2 * P);
        // A watchdog tick while the driver's clock was down, then a new run of the clock: the
        // periods of the silences before each are lost (the last servo tick began at 16 P), but
        // neither interval is a servo period.
        core.run_tick(TickSource::Watchdog, 200 * P, &shared, P);
        core.run_tick(
            TickSource::Servo {
                tick_start_ns: 500 * P,
            },
            500 * P,
            &shared,
            P,
        );
        assert_eq!(core.timing.overruns, 2 + 183 + 299);
        assert_eq!(core.timing.period_error.max_ns(), 2 * P);
        assert_eq!(core.timing.watchdog_ticks, 1);
        assert_eq!(core.next_tick, 7);
    }

    #[test]
    fn an_outage_counts_the_ticks_lost_before_the_watchdog_and_across_the_restart() {
        const P: u64 = 1_000_000;
        let mut core = grid_core();
        let (producer, mut consumer) = rtrb::RingBuffer::new(32);
        core.tick_sink = Some(producer);
        let shared = Shared::new();
        let servo = |core: &mut TickCore, at: u64| {
            core.run_tick(
                TickSource::Servo {
                    tick_start_ns: at * P,
                },
                at * P,
                &shared,
                P,
            )
        };
        for at in 10..15 {
            servo(&mut core, at);
        }
        // The driver's clock stops after the tick at 14 P; the watchdog takes over a hundred
        // periods later, ticks each period (missing one, at 118 P), and the clock restarts at
        // 150 P.
        for at in [115, 116, 117, 119] {
            core.run_tick(TickSource::Watchdog, at * P, &shared, P);
        }
        servo(&mut core, 150);
        servo(&mut core, 151);
        let lost: Vec<u64> = std::iter::from_fn(|| consumer.pop().ok())
            .map(|r| r.lost_before)
            .collect();
        assert_eq!(lost, [0, 0, 0, 0, 0, 100, 0, 0, 1, 30, 0]);
        assert_eq!(core.timing.overruns, 131);
        // Each tick index once: the lost ticks are counted, not numbered.
        assert_eq!(core.next_tick, 11);
    }

    /// A device that fails to read on some ticks, the simulated PHANTOM otherwise.
    struct Flaky {
        inner: crate::sim::SimulatedPhantom,
        reads: u64,
        fail: std::ops::Range<u64>,
        error: DeviceError,
    }

    impl HapticDevice for Flaky {
        fn limits(&self) -> crate::device::DeviceLimits {
            self.inner.limits()
        }
        fn read(&mut self) -> Result<DeviceSample, DeviceError> {
            let n = self.reads;
            self.reads += 1;
            let sample = self.inner.read();
            if self.fail.contains(&n) {
                return Err(self.error);
            }
            sample
        }
        fn command_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
            self.inner.command_force(force_n)
        }
    }

    #[test]
    fn a_fault_of_a_few_ticks_between_two_polls_is_latched_for_the_next_poll() {
        const P: u64 = 1_000_000;
        let mut core = grid_core();
        let shared = Shared::new();
        core.device = Box::new(Flaky {
            inner: crate::sim::SimulatedPhantom::new(crate::sim::HandScript::press(
                DVec3::ZERO,
                DVec3::Y,
                0.005,
            )),
            reads: 0,
            fail: 5..7,
            error: DeviceError::Disconnected,
        });
        let mut at = 10;
        let mut ticks = |core: &mut TickCore, n: u64| {
            for _ in 0..n {
                core.run_tick(
                    TickSource::Servo {
                        tick_start_ns: at * P,
                    },
                    at * P,
                    &shared,
                    P,
                );
                at += 1;
            }
        };
        // Fifty ticks between two polls, two of them faulted: the last tick's error is gone by
        // the poll, the latch still has the fault.
        ticks(&mut core, 50);
        assert_eq!(
            DeviceError::from_word(shared.device_error.load(Ordering::Acquire)),
            None
        );
        assert_eq!(shared.take_device_error(), Some(DeviceError::Disconnected));
        // Taken: the next poll sees the good ticks since.
        ticks(&mut core, 50);
        assert_eq!(shared.take_device_error(), None);
        // The most severe of the errors since the last poll wins, whatever their order.
        for e in [
            DeviceError::Overrun,
            DeviceError::Disconnected,
            DeviceError::NeedsCalibration,
            DeviceError::Driver(0x402),
        ] {
            shared.latch_device_error(e);
        }
        assert_eq!(shared.take_device_error(), Some(DeviceError::Disconnected));
        shared.latch_device_error(DeviceError::Driver(-7));
        shared.latch_device_error(DeviceError::NeedsCalibration);
        assert_eq!(shared.take_device_error(), Some(DeviceError::Driver(-7)));
    }

    #[test]
    fn handles_cross_threads() {
        // The server shares the loop between tasks, and ships tick records to a writer thread.
        fn shareable<T: Send + Sync>() {}
        fn sendable<T: Send + Copy>() {}
        shareable::<HapticLoop>();
        sendable::<TickRecord>();
        sendable::<LoopStats>();
    }

    #[test]
    fn contact_state_round_trips_through_words() {
        let c = ContactState {
            tick: 7,
            time_ns: 9,
            tip_in_world: Pose {
                position_m: DVec3::new(0.1, -0.2, 0.3),
                orientation: glam::DQuat::from_rotation_x(0.3),
            },
            tip_velocity_m_s: DVec3::new(1.0, 2.0, 3.0),
            buttons: 5,
            in_contact: true,
            depth_m: 0.004,
            normal: DVec3::Y,
            contact_point_m: DVec3::new(-1.0, 0.5, 0.25),
            contact_radius_m: 0.002,
            force_n: DVec3::new(0.0, 1.5, 0.1),
            flags: ContactFlags::SATURATED | ContactFlags::RAMPING,
            guide: None,
        };
        assert_eq!(contact_from_words(&contact_to_words(&c)), c);
        let guided = ContactState {
            guide: Some(GuideState {
                force_n: DVec3::new(0.5, -0.25, 0.125),
                target_m: DVec3::new(0.01, 0.02, 0.03),
                progress: 0.4,
                gain: 0.8,
                effective_gain: 0.6,
                engaged: true,
                pass: 3,
            }),
            ..c
        };
        assert_eq!(contact_from_words(&contact_to_words(&guided)), guided);
    }
}
