//! Fixed-size timing statistics of the loop: log-linear histograms and the published summary.
//!
//! A histogram records nanosecond durations into a fixed array of buckets (32 linear sub-buckets
//! per power of two, so every bucket is within about 3 % of its values); recording is a few
//! integer operations and never allocates, so the 1 kHz thread can record every tick.

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
    /// Lateness of the tick's start behind its absolute deadline, nanoseconds.
    pub period_error_p50_ns: u64,
    pub period_error_p99_ns: u64,
    pub period_error_p999_ns: u64,
    pub period_error_max_ns: u64,
    /// Ticks whose work ended after the next deadline (the next tick started late).
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
}

impl LoopStats {
    /// Number of `u64` words in [`LoopStats::to_words`].
    pub const WORDS: usize = 15;

    /// Encodes into words for a lock-free publication (f64 by bit pattern).
    pub fn to_words(&self) -> [u64; Self::WORDS] {
        [
            self.ticks,
            self.loop_rate_hz.to_bits(),
            self.period_error_p50_ns,
            self.period_error_p99_ns,
            self.period_error_p999_ns,
            self.period_error_max_ns,
            self.overruns,
            self.compute_p50_ns,
            self.compute_p99_ns,
            self.compute_max_ns,
            self.dropped_tick_records,
            self.device_faults,
            self.command_errors,
            self.realtime_granted as u64,
            self.spin_ns,
        ]
    }

    pub fn from_words(w: &[u64; Self::WORDS]) -> Self {
        Self {
            ticks: w[0],
            loop_rate_hz: f64::from_bits(w[1]),
            period_error_p50_ns: w[2],
            period_error_p99_ns: w[3],
            period_error_p999_ns: w[4],
            period_error_max_ns: w[5],
            overruns: w[6],
            compute_p50_ns: w[7],
            compute_p99_ns: w[8],
            compute_max_ns: w[9],
            dropped_tick_records: w[10],
            device_faults: w[11],
            command_errors: w[12],
            realtime_granted: w[13] != 0,
            spin_ns: w[14],
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

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
            ..LoopStats::default()
        };
        assert_eq!(LoopStats::from_words(&s.to_words()), s);
    }
}
