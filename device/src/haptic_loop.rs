//! The 1 kHz loop thread.
//!
//! [`HapticLoop::spawn`] moves a device and a [`HapticWorld`] onto a dedicated std thread that,
//! every period: waits for its absolute deadline, reads the device, steps the world, commands the
//! force, publishes the [`ContactState`], offers a [`TickRecord`] to the session log's ring, and
//! records its timing. The thread owns everything it touches; other threads see its results only
//! through wait-free publications ([`SeqCell`]), so no reader can ever delay the force
//! (design.md, invariant 1). Per tick it never allocates, locks, logs or does I/O.
//!
//! Before the first tick the thread allocates its timing state, prefaults its stack, binds itself
//! to a CPU and asks for SCHED_FIFO and locked memory ([`rt::request_realtime`]); what the machine
//! still does to the period (and what no thread setting can prevent) is in [`crate::rt`].

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering, fence};
use std::thread::JoinHandle;

use glam::{DQuat, DVec3};
use softhaptic_proto::{ContactFlags, ContactState, Pose};

use crate::device::{DeviceSample, HapticDevice};
use crate::rt::{self, CpuChoice, RealtimeStatus};
use crate::stats::{Histogram, LoopStats};
use crate::world::HapticWorld;

/// How the loop runs.
pub struct LoopConfig {
    /// Period of the loop (1 000 000 ns for 1 kHz).
    pub period_ns: u64,
    /// Ask for SCHED_FIFO and locked memory (see [`crate::rt`] for the privileges needed).
    pub realtime: bool,
    /// Optional ring to the session-log writer; a full ring drops the record (counted), never
    /// waits.
    pub tick_sink: Option<rtrb::Producer<TickRecord>>,
}

impl Default for LoopConfig {
    /// 1 kHz, real-time requested, no tick sink.
    fn default() -> Self {
        Self {
            period_ns: 1_000_000,
            realtime: true,
            tick_sink: None,
        }
    }
}

/// Everything one tick saw and did, for the session log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickRecord {
    /// The device's reading, `None` when the read failed.
    pub sample: Option<DeviceSample>,
    /// The read failed or the sample was refused (NaN, out of workspace).
    pub device_fault: bool,
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
}

/// Bounds of the spin before each deadline ([`rt::SpinBudget`]): at least 20 µs, at most 200 µs
/// (20 % of one core at 1 kHz).
const SPIN_MIN_NS: u64 = 20_000;
const SPIN_MAX_NS: u64 = 200_000;
/// Stats are summarised for readers every this many ticks (percentiles scan the histogram).
const STATS_EVERY_TICKS: u64 = 100;

/// A seqlock over plain `u64` words: one writer, any number of readers, no `unsafe`.
///
/// The writer makes the sequence odd, stores the words, makes it even again; a reader retries
/// when it saw an odd sequence or a different one after reading. The writer never waits (it is
/// wait-free); a reader waits at most for the writer's few stores. Every word is an atomic, so a
/// torn read is detected, never undefined behaviour.
pub struct SeqCell<const N: usize> {
    seq: AtomicU64,
    words: [AtomicU64; N],
}

impl<const N: usize> SeqCell<N> {
    pub fn new(initial: [u64; N]) -> Self {
        Self {
            seq: AtomicU64::new(0),
            words: initial.map(AtomicU64::new),
        }
    }

    /// Publishes new words. Only one thread may write a given cell (the loop thread); a second
    /// writer would not be unsafe but could let readers see a mix.
    pub fn write(&self, value: &[u64; N]) {
        let s = self.seq.load(Ordering::Relaxed);
        self.seq.store(s.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        for (w, v) in self.words.iter().zip(value) {
            w.store(*v, Ordering::Relaxed);
        }
        self.seq.store(s.wrapping_add(2), Ordering::Release);
    }

    /// Reads a consistent copy of the last published words.
    pub fn read(&self) -> [u64; N] {
        let mut attempts = 0u32;
        loop {
            attempts = attempts.wrapping_add(1);
            if attempts.is_multiple_of(64) {
                // The writer was preempted mid-write (possible when it runs without SCHED_FIFO):
                // let it run instead of burning the reader's time slice.
                std::thread::yield_now();
            }
            let before = self.seq.load(Ordering::Acquire);
            if before & 1 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let out = std::array::from_fn(|i| self.words[i].load(Ordering::Relaxed));
            fence(Ordering::Acquire);
            if self.seq.load(Ordering::Relaxed) == before {
                return out;
            }
        }
    }
}

const CONTACT_WORDS: usize = 26;

fn contact_to_words(c: &ContactState) -> [u64; CONTACT_WORDS] {
    let p = c.tip_in_world.position_m;
    let q = c.tip_in_world.orientation;
    let v = c.tip_velocity_m_s;
    let n = c.normal;
    let cp = c.contact_point_m;
    let f = c.force_n;
    [
        c.tick,
        c.time_ns,
        p.x.to_bits(),
        p.y.to_bits(),
        p.z.to_bits(),
        q.x.to_bits(),
        q.y.to_bits(),
        q.z.to_bits(),
        q.w.to_bits(),
        v.x.to_bits(),
        v.y.to_bits(),
        v.z.to_bits(),
        c.buttons as u64,
        c.in_contact as u64,
        c.depth_m.to_bits(),
        n.x.to_bits(),
        n.y.to_bits(),
        n.z.to_bits(),
        cp.x.to_bits(),
        cp.y.to_bits(),
        cp.z.to_bits(),
        c.contact_radius_m.to_bits(),
        f.x.to_bits(),
        f.y.to_bits(),
        f.z.to_bits(),
        c.flags.bits() as u64,
    ]
}

fn contact_from_words(w: &[u64; CONTACT_WORDS]) -> ContactState {
    let f = |i: usize| f64::from_bits(w[i]);
    let v3 = |i: usize| DVec3::new(f(i), f(i + 1), f(i + 2));
    ContactState {
        tick: w[0],
        time_ns: w[1],
        tip_in_world: Pose {
            position_m: v3(2),
            orientation: DQuat::from_xyzw(f(5), f(6), f(7), f(8)),
        },
        tip_velocity_m_s: v3(9),
        buttons: w[12] as u32,
        in_contact: w[13] != 0,
        depth_m: f(14),
        normal: v3(15),
        contact_point_m: v3(18),
        contact_radius_m: f(21),
        force_n: v3(22),
        flags: ContactFlags::from_bits_retain(w[25] as u32),
    }
}

/// What the loop thread shares with everyone else.
struct Shared {
    stop: AtomicBool,
    contact: SeqCell<CONTACT_WORDS>,
    stats: SeqCell<{ LoopStats::WORDS }>,
}

/// A running haptic loop. Dropping it stops the thread too.
pub struct HapticLoop {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<LoopStats>>,
    realtime: RealtimeStatus,
}

impl HapticLoop {
    /// Starts the loop thread, not bound to a CPU ([`CpuChoice::Unpinned`]): on the machines
    /// measured (`loop-timing --cpu`), binding to the last CPU gave more overruns, not fewer,
    /// where that CPU also took the disk's interrupts; a host with an isolated CPU binds the loop
    /// to it with [`HapticLoop::spawn_on`]. Returns once the thread has asked for real-time
    /// treatment, so the caller learns what was granted ([`HapticLoop::realtime`]) before the
    /// first tick; a refusal is logged here, once, as a warning.
    pub fn spawn(
        device: Box<dyn HapticDevice>,
        world: HapticWorld,
        config: LoopConfig,
    ) -> Result<HapticLoop, LoopError> {
        Self::spawn_on(device, world, config, CpuChoice::Unpinned)
    }

    /// [`HapticLoop::spawn`], with the loop thread bound to the CPU `cpu` says (a refused
    /// binding is reported in [`HapticLoop::realtime`] and the loop runs unbound).
    pub fn spawn_on(
        device: Box<dyn HapticDevice>,
        world: HapticWorld,
        config: LoopConfig,
        cpu: CpuChoice,
    ) -> Result<HapticLoop, LoopError> {
        if config.period_ns == 0 {
            return Err(LoopError::Period(0));
        }
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            contact: SeqCell::new(contact_to_words(&ContactState::IDLE)),
            stats: SeqCell::new(LoopStats::default().to_words()),
        });
        // Bounded, one message: the thread's real-time status, sent once before the first tick.
        let (started_tx, started_rx) = std::sync::mpsc::sync_channel(1);
        let thread_shared = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("haptic-loop".into())
            .stack_size(rt::LOOP_STACK_BYTES)
            .spawn(move || {
                // Allocated before the real-time request, so that mlockall locks it too; this is
                // the one allocation of the thread.
                let timing = Box::new(Timing::new(config.period_ns));
                let status = rt::request_realtime(config.realtime, rt::LOOP_PRIORITY, cpu);
                // The spawner may have given up waiting; the loop runs either way.
                let _ = started_tx.send(status);
                run(device, world, config, &thread_shared, status, timing)
            })
            .map_err(LoopError::Spawn)?;
        let realtime = started_rx.recv().map_err(|_| LoopError::StartLost)?;
        if config_requested_and_refused(&realtime) {
            tracing::warn!(status = %realtime, "haptic loop runs without real-time guarantees");
        } else {
            tracing::info!(status = %realtime, "haptic loop started");
        }
        Ok(HapticLoop {
            shared,
            thread: Some(thread),
            realtime,
        })
    }

    /// What the operating system granted the loop thread.
    pub fn realtime(&self) -> RealtimeStatus {
        self.realtime
    }

    /// The contact state of the last tick. Wait-free for the loop; callable from any thread.
    pub fn latest_contact(&self) -> ContactState {
        contact_from_words(&self.shared.contact.read())
    }

    /// The timing summary, refreshed every 100 ticks.
    pub fn stats(&self) -> LoopStats {
        LoopStats::from_words(&self.shared.stats.read())
    }

    /// Stops the loop (the device is commanded zero force first), joins the thread and returns
    /// the final statistics.
    pub fn stop(mut self) -> LoopStats {
        self.halt()
    }

    fn halt(&mut self) -> LoopStats {
        self.shared.stop.store(true, Ordering::Release);
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(stats)) => stats,
            // The thread panicked (a bug) or was already joined: the last published summary.
            _ => self.stats(),
        }
    }
}

impl Drop for HapticLoop {
    fn drop(&mut self) {
        if self.thread.is_some() {
            self.halt();
        }
    }
}

fn config_requested_and_refused(status: &RealtimeStatus) -> bool {
    status.requested && !status.granted()
}

/// Timing state of the loop thread; fixed size, allocated once before the first tick.
struct Timing {
    period_error: Histogram,
    compute: Histogram,
    ticks: u64,
    overruns: u64,
    dropped: u64,
    device_faults: u64,
    command_errors: u64,
    start_ns: u64,
    realtime_granted: bool,
    spin: rt::SpinBudget,
}

impl Timing {
    /// Fresh state for a loop of period `period_ns`; its clock starts in [`run`].
    fn new(period_ns: u64) -> Self {
        Self {
            period_error: Histogram::new(),
            compute: Histogram::new(),
            ticks: 0,
            overruns: 0,
            dropped: 0,
            device_faults: 0,
            command_errors: 0,
            start_ns: 0,
            realtime_granted: false,
            spin: rt::SpinBudget::new(SPIN_MIN_NS, SPIN_MAX_NS.min(period_ns / 2)),
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
            spin_ns: self.spin.spin_ns(),
        }
    }
}

/// The deadline after `deadline`, given that the tick's work ended at `done_ns`, and how many
/// deadlines were lost. When the work ran past the next deadline, the periods already lost are
/// skipped instead of running a burst of late ticks (a burst would hand the device several
/// forces within microseconds); the next tick starts at once, at the last lost deadline.
fn next_deadline(deadline_ns: u64, done_ns: u64, period_ns: u64) -> (u64, u64) {
    let next = deadline_ns + period_ns;
    if done_ns <= next {
        return (next, 0);
    }
    let missed = (done_ns - next) / period_ns + 1;
    (next + (missed - 1) * period_ns, missed)
}

/// The loop thread's body.
fn run(
    mut device: Box<dyn HapticDevice>,
    mut world: HapticWorld,
    mut config: LoopConfig,
    shared: &Shared,
    status: RealtimeStatus,
    // Boxed so the two 9 kB histograms are not on the thread's stack.
    mut timing: Box<Timing>,
) -> LoopStats {
    timing.start_ns = rt::now_ns();
    timing.realtime_granted = status.granted();
    let period = config.period_ns;
    let mut deadline = timing.start_ns + period;
    while !shared.stop.load(Ordering::Acquire) {
        if let Some(overshoot) = rt::wait_until_ns(deadline, timing.spin.spin_ns()) {
            timing.spin.observe(overshoot);
        }
        let woke = rt::now_ns();
        timing.period_error.record(woke.saturating_sub(deadline));

        let read = device.read();
        let state = world.step(read);
        if device.command_force(state.force_n).is_err() {
            timing.command_errors += 1;
        }
        shared.contact.write(&contact_to_words(&state));
        let device_fault = state.flags.contains(ContactFlags::DEVICE_FAULT);
        if device_fault {
            timing.device_faults += 1;
        }
        if let Some(sink) = config.tick_sink.as_mut() {
            let record = TickRecord {
                sample: read.ok(),
                device_fault,
                contact: state,
            };
            if sink.push(record).is_err() {
                timing.dropped += 1;
            }
        }
        timing.ticks += 1;
        let done = rt::now_ns();
        timing.compute.record(done.saturating_sub(woke));
        if timing.ticks.is_multiple_of(STATS_EVERY_TICKS) {
            shared.stats.write(&timing.summary(done).to_words());
        }

        let (next, missed) = next_deadline(deadline, done, period);
        deadline = next;
        timing.overruns += missed;
    }
    // Never leave the device pushing: the last command of the loop is zero force.
    if device.command_force(DVec3::ZERO).is_err() {
        timing.command_errors += 1;
    }
    let summary = timing.summary(rt::now_ns());
    shared.stats.write(&summary.to_words());
    summary
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn lost_deadlines_are_skipped_and_counted() {
        const P: u64 = 1_000_000;
        // On time: the next deadline, nothing lost.
        assert_eq!(next_deadline(10 * P, 10 * P + 30_000, P), (11 * P, 0));
        assert_eq!(next_deadline(10 * P, 11 * P, P), (11 * P, 0));
        // 2.5 ms of work: deadlines 11 and 12 passed; start at once against 12, not 11 then 12.
        let (next, missed) = next_deadline(10 * P, 12 * P + 500_000, P);
        assert_eq!((next, missed), (12 * P, 2));
        assert!(
            12 * P + 500_000 - next < P,
            "the next tick is late by less than a period"
        );
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
                orientation: DQuat::from_rotation_x(0.3),
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
        };
        assert_eq!(contact_from_words(&contact_to_words(&c)), c);
    }

    #[test]
    fn seqlock_readers_never_see_a_torn_value() {
        let cell = Arc::new(SeqCell::<8>::new([0; 8]));
        let stop = Arc::new(AtomicBool::new(false));
        let readers: Vec<_> = (0..2)
            .map(|_| {
                let (cell, stop) = (Arc::clone(&cell), Arc::clone(&stop));
                std::thread::spawn(move || {
                    let mut reads = 0u64;
                    while !stop.load(Ordering::Relaxed) {
                        let w = cell.read();
                        assert!(w.iter().all(|&x| x == w[0]), "torn read {w:?}");
                        reads += 1;
                    }
                    reads
                })
            })
            .collect();
        for i in 1..=200_000u64 {
            cell.write(&[i; 8]);
        }
        stop.store(true, Ordering::Relaxed);
        for r in readers {
            assert!(r.join().unwrap() > 0);
        }
        assert_eq!(cell.read(), [200_000; 8]);
    }
}
