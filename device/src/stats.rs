//! Fixed-size timing statistics of the loop: log-linear histograms and the published summary.
//!
//! A histogram records nanosecond durations into a fixed array of buckets (32 linear sub-buckets
//! per power of two, so every bucket is within about 3 % of its values); recording is a few
//! integer operations and never allocates, so the 1 kHz thread can record every tick.

use crate::cells::{Words, WordsReader};

/// Linear sub-buckets per power of two (2^5: ≈ 3 % resolution).
const SUB_BITS: u32 = 5;
const SUB: usize = 1 << SUB_BITS;
/// Largest power of two recorded; bigger values land in the last bucket (2^40 ns ≈ 18 min).
const MAX_EXP: u32 = 40;
const BUCKETS: usize = (MAX_EXP as usize - SUB_BITS as usize + 2) * SUB;

/// A log-linear histogram of durations in nanoseconds.
#[derive(Clone)]
pub struct Histogram {
    counts: [u64; BUCKETS],
    total: u64,
    max_ns: u64,
}

impl Default for Histogram {
    fn default() -> Self {
        Self::new()
    }
}

impl std::fmt::Debug for Histogram {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Histogram")
            .field("count", &self.total)
            .field("p50_ns", &self.quantile_ns(0.5))
            .field("p99_ns", &self.quantile_ns(0.99))
            .field("max_ns", &self.max_ns)
            .finish()
    }
}

fn bucket_of(value_ns: u64) -> usize {
    if value_ns < SUB as u64 {
        return value_ns as usize;
    }
    let exp = (63 - value_ns.leading_zeros()).min(MAX_EXP);
    if exp == MAX_EXP && value_ns >> MAX_EXP > 1 {
        return BUCKETS - 1;
    }
    let mantissa = ((value_ns >> (exp - SUB_BITS)) as usize) & (SUB - 1);
    (exp - SUB_BITS + 1) as usize * SUB + mantissa
}

/// Largest value that falls in bucket `index` (reported quantiles are conservative).
fn bucket_upper_ns(index: usize) -> u64 {
    if index < SUB {
        return index as u64;
    }
    let exp = (index / SUB) as u32 + SUB_BITS - 1;
    let mantissa = (index % SUB) as u64;
    let lower = (SUB as u64 + mantissa) << (exp - SUB_BITS);
    lower + (1u64 << (exp - SUB_BITS)) - 1
}

impl Histogram {
    pub const fn new() -> Self {
        Self {
            counts: [0; BUCKETS],
            total: 0,
            max_ns: 0,
        }
    }

    /// Records one duration.
    #[inline]
    pub fn record(&mut self, value_ns: u64) {
        self.counts[bucket_of(value_ns)] += 1;
        self.total += 1;
        self.max_ns = self.max_ns.max(value_ns);
    }

    pub fn count(&self) -> u64 {
        self.total
    }

    /// Exact largest value recorded.
    pub fn max_ns(&self) -> u64 {
        self.max_ns
    }

    /// The value at quantile `q` in [0, 1]: the upper edge of the bucket holding the ⌈q·n⌉-th
    /// smallest value, never above the exact maximum. 0 when empty.
    pub fn quantile_ns(&self, q: f64) -> u64 {
        if self.total == 0 {
            return 0;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.total as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for (i, &c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= rank {
                return bucket_upper_ns(i).min(self.max_ns);
            }
        }
        self.max_ns
    }

    pub fn clear(&mut self) {
        *self = Self::new();
    }
}

/// The loop's timing summary, as published to other threads. Plain `Copy` data.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LoopStats {
    /// Ticks run since the start.
    pub ticks: u64,
    /// Ticks per second of wall time since the start.
    pub loop_rate_hz: f64,
    /// Lateness of the tick's start behind its absolute deadline, nanoseconds; for a loop on a
    /// device's servo clock, |interval between the driver's servo ticks − period|.
    pub period_error_p50_ns: u64,
    pub period_error_p99_ns: u64,
    pub period_error_p999_ns: u64,
    pub period_error_max_ns: u64,
    /// Deadlines whose tick did not start before the next deadline (ticks lost).
    pub overruns: u64,
    /// Time from wake-up to the force being commanded and published.
    pub compute_p50_ns: u64,
    pub compute_p99_ns: u64,
    pub compute_max_ns: u64,
    /// Tick records the ring to the session log had no room for.
    pub dropped_tick_records: u64,
    /// Ticks whose device read failed or whose sample was refused.
    pub device_faults: u64,
    /// Ticks whose force command the device refused.
    pub command_errors: u64,
    /// Whether SCHED_FIFO and locked memory were both granted.
    pub realtime_granted: bool,
    /// Current spin before each deadline, adapted to the machine's wake-up latency.
    pub spin_ns: u64,
    /// CLOCK_MONOTONIC time ([`crate::rt::now_ns`]) the deadlines count from: tick k is due at
    /// `deadline_origin_ns + (k + 1) · period`.
    pub deadline_origin_ns: u64,
    /// Ticks run by the standby thread because the loop thread had not started them in time.
    pub standby_ticks: u64,
    /// Fault ticks run by the watchdog of a device-clocked loop while the driver's servo clock
    /// was down (the device being reconnected).
    pub watchdog_ticks: u64,
}

impl LoopStats {
    /// Number of `u64` words in [`LoopStats::to_words`].
    pub const WORDS: usize = 18;

    /// Encodes into words for a lock-free publication (f64 by bit pattern).
    pub fn to_words(&self) -> [u64; Self::WORDS] {
        let mut w = Words::new();
        w.u64(self.ticks)
            .f64(self.loop_rate_hz)
            .u64(self.period_error_p50_ns)
            .u64(self.period_error_p99_ns)
            .u64(self.period_error_p999_ns)
            .u64(self.period_error_max_ns)
            .u64(self.overruns)
            .u64(self.compute_p50_ns)
            .u64(self.compute_p99_ns)
            .u64(self.compute_max_ns)
            .u64(self.dropped_tick_records)
            .u64(self.device_faults)
            .u64(self.command_errors)
            .bool(self.realtime_granted)
            .u64(self.spin_ns)
            .u64(self.deadline_origin_ns)
            .u64(self.standby_ticks)
            .u64(self.watchdog_ticks);
        w.finish()
    }

    pub fn from_words(words: &[u64; Self::WORDS]) -> Self {
        let mut r = WordsReader::new(words);
        let s = Self {
            ticks: r.u64(),
            loop_rate_hz: r.f64(),
            period_error_p50_ns: r.u64(),
            period_error_p99_ns: r.u64(),
            period_error_p999_ns: r.u64(),
            period_error_max_ns: r.u64(),
            overruns: r.u64(),
            compute_p50_ns: r.u64(),
            compute_p99_ns: r.u64(),
            compute_max_ns: r.u64(),
            dropped_tick_records: r.u64(),
            device_faults: r.u64(),
            command_errors: r.u64(),
            realtime_granted: r.bool(),
            spin_ns: r.u64(),
            deadline_origin_ns: r.u64(),
            standby_ticks: r.u64(),
            watchdog_ticks: r.u64(),
        };
        r.finish();
        s
    }
}

/// A deadline of the loop that waited more than half a period for a tick to start: a late tick,
/// or a run of lost ticks (then the wait runs from the first deadline no tick served).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LateWake {
    /// The deadline, CLOCK_MONOTONIC nanoseconds ([`crate::rt::now_ns`]).
    pub deadline_ns: u64,
    /// How long after it the next tick started.
    pub late_ns: u64,
}

/// The most recent late ticks and runs of lost ticks of the loop ([`LateWake`]), with their clock times, so that a report can set
/// them beside what other threads saw at the same moments (`loop-timing` asks whether every CPU
/// of the machine was stalled, or only the loop's). Fixed size; the loop writes it only on a late
/// tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LateLog {
    /// Late ticks and runs of lost ticks since the start, including those no longer held.
    pub total: u64,
    ring: [LateWake; LateLog::CAPACITY],
}

impl Default for LateLog {
    fn default() -> Self {
        Self {
            total: 0,
            ring: [LateWake::default(); Self::CAPACITY],
        }
    }
}

impl LateLog {
    /// How many of the latest late wake-ups are kept.
    pub const CAPACITY: usize = 64;
    /// Number of `u64` words in [`LateLog::to_words`].
    pub const WORDS: usize = 1 + 2 * Self::CAPACITY;

    /// Adds a late wake-up, replacing the oldest when full.
    pub fn push(&mut self, wake: LateWake) {
        self.ring[(self.total % Self::CAPACITY as u64) as usize] = wake;
        self.total += 1;
    }

    /// The wake-ups held, oldest first.
    pub fn iter(&self) -> impl Iterator<Item = LateWake> + '_ {
        let held = self.total.min(Self::CAPACITY as u64);
        (self.total - held..self.total).map(|i| self.ring[(i % Self::CAPACITY as u64) as usize])
    }

    /// Encodes into words for a lock-free publication.
    pub fn to_words(&self) -> [u64; Self::WORDS] {
        let mut w = Words::new();
        w.u64(self.total);
        for wake in &self.ring {
            w.u64(wake.deadline_ns).u64(wake.late_ns);
        }
        w.finish()
    }

    pub fn from_words(words: &[u64; Self::WORDS]) -> Self {
        let mut r = WordsReader::new(words);
        let total = r.u64();
        let ring = std::array::from_fn(|_| LateWake {
            deadline_ns: r.u64(),
            late_ns: r.u64(),
        });
        r.finish();
        Self { total, ring }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn late_log_keeps_the_latest_in_order_and_survives_words() {
        let mut log = LateLog::default();
        assert_eq!(log.iter().count(), 0);
        for i in 0..(LateLog::CAPACITY as u64 + 5) {
            log.push(LateWake {
                deadline_ns: 1_000 * i,
                late_ns: i,
            });
        }
        assert_eq!(log.total, LateLog::CAPACITY as u64 + 5);
        let held: Vec<u64> = log.iter().map(|w| w.late_ns).collect();
        let expected: Vec<u64> = (5..LateLog::CAPACITY as u64 + 5).collect();
        assert_eq!(
            held, expected,
            "the oldest five were replaced, the rest in order"
        );
        assert_eq!(LateLog::from_words(&log.to_words()), log);
    }

    #[test]
    fn buckets_are_monotone_and_tight() {
        let mut previous = 0;
        for v in (0..100_000u64).chain((17..40).map(|e| (1u64 << e) + 12345)) {
            let b = bucket_of(v);
            assert!(b >= previous, "bucket order at {v}");
            previous = b;
            let upper = bucket_upper_ns(b);
            assert!(upper >= v, "{v} above its bucket's edge {upper}");
            assert!(
                (upper - v) as f64 <= v as f64 / 32.0 + 1.0,
                "{v} vs {upper}"
            );
        }
        assert_eq!(bucket_of(u64::MAX), BUCKETS - 1);
    }

    #[test]
    fn quantiles_of_a_known_distribution() {
        let mut h = Histogram::new();
        for v in 1..=10_000u64 {
            h.record(v * 10);
        }
        let p50 = h.quantile_ns(0.5) as f64;
        let p99 = h.quantile_ns(0.99) as f64;
        assert!((p50 / 50_000.0 - 1.0).abs() < 0.035, "{p50}");
        assert!((p99 / 99_000.0 - 1.0).abs() < 0.035, "{p99}");
        assert_eq!(h.quantile_ns(1.0), 100_000);
        assert_eq!(h.max_ns(), 100_000);
        assert_eq!(h.count(), 10_000);
        h.clear();
        assert_eq!(h.quantile_ns(0.5), 0);
    }

    #[test]
    fn a_single_outlier_shows_in_max_and_p999_only() {
        let mut h = Histogram::new();
        for _ in 0..999 {
            h.record(3_000);
        }
        h.record(2_000_000);
        assert!(h.quantile_ns(0.99) <= 3_100);
        assert_eq!(h.quantile_ns(0.9999), 2_000_000);
        assert_eq!(h.max_ns(), 2_000_000);
    }

    #[test]
    fn stats_round_trip_through_words() {
        let s = LoopStats {
            ticks: 5,
            loop_rate_hz: 999.5,
            period_error_p999_ns: 77,
            compute_max_ns: 12,
            realtime_granted: true,
            command_errors: 3,
            spin_ns: 42_000,
            deadline_origin_ns: 1_234_567_890,
            standby_ticks: 17,
            watchdog_ticks: 4,
            ..LoopStats::default()
        };
        assert_eq!(LoopStats::from_words(&s.to_words()), s);
    }
}
