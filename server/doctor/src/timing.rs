//! The short loop-timing measurement of `softhaptic doctor`: the server's own loop (the built-in
//! scene, the simulated device, the same thread placement and real-time request as `run`) on an
//! idle machine, then beside two loaded neighbours — threads burning every CPU, and a writer
//! syncing to disk (the block-I/O kernel work that does not yield on stock kernels) — with its
//! lost ticks and period error set beside the goal.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde::Serialize;
use softhaptic_device::haptic_loop::{HapticLoop, LoopConfig};
use softhaptic_device::stats::LoopStats;

use super::{LoopPlan, Verdict};
use softhaptic_scene::{Scene, devices};

/// The loop's period, nanoseconds (1 kHz, as the server runs it).
pub const PERIOD_NS: u64 = 1_000_000;

/// The goal a device host should meet: the period error at the 99th percentile within a tenth of
/// the period, no tick later than half a period (the standby thread takes over a tick a quarter
/// period late, so a later one means both threads were held), and no tick lost.
pub const GOAL_P99_US: f64 = 100.0;
pub const GOAL_MAX_US: f64 = 500.0;
pub const GOAL_LOST_TICKS: u64 = 0;

/// One measured run.
#[derive(Debug, Clone, Serialize)]
pub struct Run {
    /// What ran beside the loop.
    pub neighbour: String,
    pub seconds: f64,
    pub ticks: u64,
    /// Deadlines whose tick did not start before the next deadline.
    pub lost_ticks: u64,
    pub lost_ticks_per_minute: f64,
    /// Ticks the standby thread ran because the loop thread was held.
    pub ticks_by_standby: u64,
    pub period_error_p50_us: f64,
    pub period_error_p99_us: f64,
    pub period_error_max_us: f64,
    pub compute_p99_us: f64,
    /// What the loop thread was granted (SCHED_FIFO, locked memory, its CPU).
    pub loop_thread: String,
    pub verdict: Verdict,
}

impl Run {
    /// A run's figures from the loop's statistics after `elapsed_s` seconds.
    pub fn from_stats(
        neighbour: String,
        elapsed_s: f64,
        s: &LoopStats,
        loop_thread: String,
    ) -> Self {
        let us = |ns: u64| ns as f64 * 1e-3;
        let mut run = Run {
            neighbour,
            seconds: elapsed_s,
            ticks: s.ticks,
            lost_ticks: s.overruns,
            lost_ticks_per_minute: if elapsed_s > 0.0 {
                s.overruns as f64 * 60.0 / elapsed_s
            } else {
                0.0
            },
            ticks_by_standby: s.standby_ticks,
            period_error_p50_us: us(s.period_error_p50_ns),
            period_error_p99_us: us(s.period_error_p99_ns),
            period_error_max_us: us(s.period_error_max_ns),
            compute_p99_us: us(s.compute_p99_ns),
            loop_thread,
            verdict: Verdict::Good,
        };
        run.verdict = run.judge();
        run
    }

    /// Good when every goal is met, a warning otherwise: the loop runs, but the hand feels the
    /// missed ticks as roughness in a stiff contact.
    pub fn judge(&self) -> Verdict {
        if self.lost_ticks > GOAL_LOST_TICKS
            || self.period_error_p99_us > GOAL_P99_US
            || self.period_error_max_us > GOAL_MAX_US
        {
            Verdict::Warn
        } else {
            Verdict::Good
        }
    }
}

/// The measurement: its runs, or why the loop could not be started.
#[derive(Debug, Clone, Serialize)]
pub struct Timing {
    pub seconds_per_run: f64,
    /// `release`, or `debug` (unoptimised: a tick computes several times slower than in the
    /// release build a device host runs, so its figures are pessimistic).
    pub build: &'static str,
    pub goal: Goal,
    pub runs: Vec<Run>,
    /// Why no run could be made.
    pub error: Option<String>,
    pub verdict: Verdict,
}

#[derive(Debug, Clone, Copy, Serialize)]
pub struct Goal {
    pub period_error_p99_us: f64,
    pub period_error_max_us: f64,
    pub lost_ticks: u64,
}

pub const GOAL: Goal = Goal {
    period_error_p99_us: GOAL_P99_US,
    period_error_max_us: GOAL_MAX_US,
    lost_ticks: GOAL_LOST_TICKS,
};

impl Timing {
    fn new(seconds: f64, runs: Vec<Run>, error: Option<String>) -> Self {
        let verdict = if error.is_some() {
            Verdict::Fail
        } else {
            runs.iter()
                .map(|r| r.verdict)
                .max()
                .unwrap_or(Verdict::Unknown)
        };
        Self {
            seconds_per_run: seconds,
            build: if cfg!(debug_assertions) {
                "debug"
            } else {
                "release"
            },
            goal: GOAL,
            runs,
            error,
            verdict,
        }
    }
}

/// Threads that keep every CPU busy at normal priority until dropped: the loaded neighbour.
struct Burners {
    stop: Arc<AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl Burners {
    fn start(count: usize) -> std::io::Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let mut burners = Burners {
            stop: Arc::clone(&stop),
            threads: Vec::with_capacity(count),
        };
        for i in 0..count {
            let stop = Arc::clone(&stop);
            burners.threads.push(
                std::thread::Builder::new()
                    .name(format!("doctor-burn-{i}"))
                    .spawn(move || {
                        let mut x = 1u64;
                        while !stop.load(Ordering::Relaxed) {
                            for _ in 0..10_000 {
                                x = std::hint::black_box(
                                    x.wrapping_mul(6_364_136_223_846_793_005) + 1,
                                );
                            }
                        }
                    })?,
            );
        }
        Ok(burners)
    }
}

impl Drop for Burners {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// Bytes the disk writer writes between two syncs, and the size its file is kept within.
const WRITE_BLOCK_BYTES: usize = 1 << 20;
const WRITE_FILE_BYTES: u64 = 32 << 20;

/// A thread that writes and syncs a scratch file until dropped: the block-I/O neighbour (a
/// recording, a log, a backup on the same host). The file is removed when it stops.
struct DiskWriter {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
    path: std::path::PathBuf,
}

impl DiskWriter {
    fn start(dir: &std::path::Path) -> std::io::Result<Self> {
        use std::io::{Seek, SeekFrom, Write};
        let path = dir.join(format!("softhaptic-doctor-{}.tmp", std::process::id()));
        let mut file = std::fs::File::create(&path)?;
        let stop = Arc::new(AtomicBool::new(false));
        let thread = std::thread::Builder::new()
            .name("doctor-disk".into())
            .spawn({
                let stop = Arc::clone(&stop);
                move || {
                    // Not zeros: a filesystem that compresses or skips zero blocks would write less.
                    let block: Vec<u8> = (0..WRITE_BLOCK_BYTES)
                        .map(|i| (i * 31 % 251) as u8)
                        .collect();
                    let mut written = 0u64;
                    while !stop.load(Ordering::Relaxed) {
                        if written >= WRITE_FILE_BYTES {
                            if file.seek(SeekFrom::Start(0)).is_err() {
                                return;
                            }
                            written = 0;
                        }
                        if file.write_all(&block).is_err() || file.sync_data().is_err() {
                            return;
                        }
                        written += WRITE_BLOCK_BYTES as u64;
                    }
                }
            });
        match thread {
            Ok(thread) => Ok(DiskWriter {
                stop,
                thread: Some(thread),
                path,
            }),
            Err(e) => {
                let _ = std::fs::remove_file(&path);
                Err(e)
            }
        }
    }
}

impl Drop for DiskWriter {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let _ = std::fs::remove_file(&self.path);
    }
}

/// What runs beside the loop in one timing run.
#[derive(Debug, Clone, PartialEq)]
pub enum Neighbour {
    None,
    /// This many threads burning CPU at normal priority.
    Cpu(usize),
    /// A writer syncing 1 MiB at a time to a scratch file in this directory.
    Disk(std::path::PathBuf),
}

impl Neighbour {
    /// How the run's report names it (its first word tells the kind; see the table's rows).
    fn describe(&self) -> String {
        match self {
            Neighbour::None => "none (idle machine)".to_owned(),
            Neighbour::Cpu(n) => format!("{n} threads burning CPU at normal priority, one per CPU"),
            Neighbour::Disk(dir) => format!(
                "disk: a writer syncing 1 MiB at a time to a {} MiB scratch file in {}",
                WRITE_FILE_BYTES >> 20,
                dir.display()
            ),
        }
    }
}

/// Runs the loop for `seconds` beside `neighbour`.
fn one_run(seconds: f64, plan: &LoopPlan, neighbour: &Neighbour) -> Result<Run, String> {
    let mut scene = Scene::builtin_default().map_err(|e| format!("the built-in scene: {e}"))?;
    let device = devices::open(&mut scene).map_err(|e| format!("the simulated device: {e}"))?;
    let _burners = match neighbour {
        Neighbour::Cpu(n) => {
            Some(Burners::start(*n).map_err(|e| format!("starting the neighbour: {e}"))?)
        }
        _ => None,
    };
    let _writer = match neighbour {
        Neighbour::Disk(dir) => Some(
            DiskWriter::start(dir)
                .map_err(|e| format!("starting the disk writer in {}: {e}", dir.display()))?,
        ),
        _ => None,
    };
    let haptic = HapticLoop::spawn_on(
        device,
        scene.haptic_world(),
        LoopConfig {
            period_ns: PERIOD_NS,
            realtime: plan.realtime,
            tick_sink: None,
            standby: true,
        },
        plan.cpu,
    )
    .map_err(|e| format!("the loop did not start: {e}"))?;
    let loop_thread = haptic.realtime().to_string();
    let start = Instant::now();
    // `doctor` runs on the main thread with no async runtime: nothing else waits for it.
    #[allow(clippy::disallowed_methods)]
    std::thread::sleep(Duration::from_secs_f64(seconds));
    let elapsed = start.elapsed().as_secs_f64();
    let stats = haptic.stop();
    Ok(Run::from_stats(
        neighbour.describe(),
        elapsed,
        &stats,
        loop_thread,
    ))
}

/// Measures the loop for `seconds` idle, then for `seconds` beside CPU-burning threads, then
/// for `seconds` beside a disk writer in `disk_dir` (where recordings go: the disk the host
/// writes).
pub fn measure(seconds: f64, plan: &LoopPlan, disk_dir: &std::path::Path) -> Timing {
    let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut runs = Vec::with_capacity(3);
    for neighbour in [
        Neighbour::None,
        Neighbour::Cpu(cpus),
        Neighbour::Disk(disk_dir.to_path_buf()),
    ] {
        match one_run(seconds, plan, &neighbour) {
            Ok(run) => runs.push(run),
            Err(e) => return Timing::new(seconds, runs, Some(e)),
        }
    }
    Timing::new(seconds, runs, None)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    fn stats(overruns: u64, p99_us: u64, max_us: u64) -> LoopStats {
        LoopStats {
            ticks: 3000,
            overruns,
            period_error_p99_ns: p99_us * 1000,
            period_error_max_ns: max_us * 1000,
            ..LoopStats::default()
        }
    }

    #[test]
    fn a_run_meets_the_goal_only_without_lost_ticks_and_within_both_bounds() {
        let run = |s: LoopStats| Run::from_stats("none".into(), 3.0, &s, String::new());
        assert_eq!(run(stats(0, 20, 300)).verdict, Verdict::Good);
        assert_eq!(run(stats(1, 20, 300)).verdict, Verdict::Warn);
        assert_eq!(run(stats(0, 150, 300)).verdict, Verdict::Warn);
        assert_eq!(run(stats(0, 20, 1200)).verdict, Verdict::Warn);
        let lost = run(stats(3, 20, 2000));
        assert!((lost.lost_ticks_per_minute - 60.0).abs() < 1e-9);
        assert!((lost.period_error_max_us - 2000.0).abs() < 1e-9);
    }

    #[test]
    fn a_loop_that_does_not_start_fails_the_measurement() {
        let t = Timing::new(1.0, vec![], Some("no".into()));
        assert_eq!(t.verdict, Verdict::Fail);
        let ok = Timing::new(
            1.0,
            vec![Run::from_stats(
                "none".into(),
                1.0,
                &stats(0, 10, 10),
                String::new(),
            )],
            None,
        );
        assert_eq!(ok.verdict, Verdict::Good);
    }
}
