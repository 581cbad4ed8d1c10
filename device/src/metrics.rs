//! The trainee's metrics, from every 1 kHz tick: what an instructor judges a press by.
//!
//! [`MetricsAccumulator`] takes one [`TickInput`] per tick (what the world computed and
//! commanded) and keeps running sums, in constant time and without allocating, so the loop
//! thread updates it on every tick ([`crate::world::HapticWorld::tick`]). The same input is in
//! every recorded tick ([`TickInput::from_record`]), so a recording's metrics, computed again from
//! its ticks, are the live ones exactly.
//!
//! Definitions (`dt` is the device time since the previous tick, at most [`MAX_DT_S`], so a
//! pause of the recording or a reconnection does not count as contact):
//! - **peak force**: the largest |F| commanded, and its device time;
//! - **time above the safe force**: Σ dt over ticks with |F| > the scene's safe force;
//! - **time in contact**: Σ dt over ticks in contact;
//! - **path length in contact**: Σ |Δp| of the tip between consecutive ticks both in contact;
//! - **smoothness**: the mean squared jerk of the tip in contact, m²/s⁶, from its position
//!   every 10 ms (six times the third divided difference over four samples all in contact, at
//!   their device times, so a sample delayed by lost ticks is weighed by its real interval): at
//!   1 kHz the third difference of an encoder's positions would be quantisation noise;
//! - **pushes**: contacts that began after at least [`PUSH_GAP_S`] free (a grazing tool's
//!   flicker is one push);
//! - **device faults**: ticks with the `device_fault` flag; **flag onsets**: for each contact flag,
//!   how many times it turned on.
//!
//! A fault tick carries no trustworthy position: it adds to the fault count and breaks the
//! path and jerk chains, nothing else. In particular it neither ends a contact nor moves the
//! time the tool was last in contact: a fault in the middle of one held press is not a release,
//! and the press that goes on after it is the same push.

use glam::DVec3;
use softhaptic_proto::ContactFlags;

use crate::cells::{Words, WordsReader};
use softhaptic_proto::record::DeviceRecord;

/// Longest tick interval counted, s.
pub const MAX_DT_S: f64 = 0.01;
/// Free time that separates two pushes, s.
pub const PUSH_GAP_S: f64 = 0.05;
/// Interval of the positions the jerk is taken from, ns.
const JERK_SAMPLE_NS: u64 = 10_000_000;
/// Flag bits tracked.
pub const FLAG_BITS: usize = 16;

/// What one tick contributes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickInput {
    pub time_ns: u64,
    /// The tip, world frame; `None` on a fault tick.
    pub tip_position_m: Option<DVec3>,
    pub in_contact: bool,
    /// How far the tool is pressed in, m (0 when free).
    pub depth_m: f64,
    pub force_n: DVec3,
    pub flags: ContactFlags,
    /// The device's buttons (bit 0: the first), 0 on a fault tick.
    pub buttons: u32,
    /// The guidance's pull this tick, in a guided session.
    pub guide: Option<softhaptic_proto::GuideState>,
}

impl TickInput {
    /// From a recorded tick.
    pub fn from_record(r: &DeviceRecord) -> Self {
        let flags = ContactFlags::from_bits_retain(r.flags);
        let fault = flags.contains(ContactFlags::DEVICE_FAULT);
        TickInput {
            time_ns: r.time_ns,
            tip_position_m: r
                .sample
                .filter(|_| !fault)
                .map(|s| DVec3::from_array(s.tip_position_m)),
            in_contact: r.in_contact,
            depth_m: if r.depth_m.is_finite() {
                r.depth_m
            } else {
                0.0
            },
            force_n: DVec3::from_array(r.force_n),
            flags,
            buttons: r.sample.filter(|_| !fault).map_or(0, |s| s.buttons),
            guide: r.guide,
        }
    }
}

/// The metrics so far.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TraineeMetrics {
    pub peak_force_n: f64,
    /// Device time of the peak, s.
    pub peak_force_time_s: f64,
    /// The safe force the time above is counted against.
    pub safe_force_n: f64,
    pub time_above_safe_s: f64,
    pub time_in_contact_s: f64,
    pub path_length_in_contact_m: f64,
    /// Mean squared jerk in contact, m²/s⁶ (0 before four 10 ms samples in contact).
    pub mean_squared_jerk_m2_s6: f64,
    pub pushes: u64,
    pub device_fault_ticks: u64,
    /// Onsets of each contact flag (bit i of `ContactFlags`).
    pub flag_onsets: [u64; FLAG_BITS],
    /// Ticks counted.
    pub ticks: u64,
}

impl TraineeMetrics {
    /// Words for publishing through a seqlock ([`crate::cells::SeqCell`]).
    pub const WORDS: usize = 10 + FLAG_BITS;

    pub fn to_words(&self) -> [u64; Self::WORDS] {
        let mut w = Words::new();
        w.f64(self.peak_force_n)
            .f64(self.peak_force_time_s)
            .f64(self.safe_force_n)
            .f64(self.time_above_safe_s)
            .f64(self.time_in_contact_s)
            .f64(self.path_length_in_contact_m)
            .f64(self.mean_squared_jerk_m2_s6)
            .u64(self.pushes)
            .u64(self.device_fault_ticks)
            .u64(self.ticks)
            .u64s(&self.flag_onsets);
        w.finish()
    }

    pub fn from_words(words: &[u64; Self::WORDS]) -> Self {
        let mut r = WordsReader::new(words);
        let m = TraineeMetrics {
            peak_force_n: r.f64(),
            peak_force_time_s: r.f64(),
            safe_force_n: r.f64(),
            time_above_safe_s: r.f64(),
            time_in_contact_s: r.f64(),
            path_length_in_contact_m: r.f64(),
            mean_squared_jerk_m2_s6: r.f64(),
            pushes: r.u64(),
            device_fault_ticks: r.u64(),
            ticks: r.u64(),
            flag_onsets: r.u64s(),
        };
        r.finish();
        m
    }
}

/// The running sums of [`TraineeMetrics`].
#[derive(Debug, Clone)]
pub struct MetricsAccumulator {
    m: TraineeMetrics,
    last_time_ns: Option<u64>,
    last_position_in_contact: Option<DVec3>,
    last_flags: ContactFlags,
    in_contact: bool,
    /// Device time the tool was last in contact (for the push debounce).
    last_contact_ns: Option<u64>,
    /// The last four 10 ms samples of the tip in contact and their device times, newest last,
    /// and their count.
    jerk_samples: [DVec3; 4],
    jerk_times_ns: [u64; 4],
    jerk_count: usize,
    next_jerk_sample_ns: u64,
    jerk_sum: f64,
    jerk_terms: u64,
}

impl MetricsAccumulator {
    pub fn new(safe_force_n: f64) -> Self {
        Self {
            m: TraineeMetrics {
                safe_force_n,
                ..TraineeMetrics::default()
            },
            last_time_ns: None,
            last_position_in_contact: None,
            last_flags: ContactFlags::empty(),
            in_contact: false,
            last_contact_ns: None,
            jerk_samples: [DVec3::ZERO; 4],
            jerk_times_ns: [0; 4],
            jerk_count: 0,
            next_jerk_sample_ns: 0,
            jerk_sum: 0.0,
            jerk_terms: 0,
        }
    }

    pub fn metrics(&self) -> TraineeMetrics {
        self.m
    }

    /// Takes one tick. Constant time, no allocation.
    pub fn update(&mut self, t: &TickInput) {
        let m = &mut self.m;
        m.ticks += 1;
        let dt_s = self
            .last_time_ns
            .map_or(0.0, |last| t.time_ns.saturating_sub(last) as f64 * 1e-9)
            .min(MAX_DT_S);
        self.last_time_ns = Some(t.time_ns);
        let f = t.force_n.length();
        if f.is_finite() && f > m.peak_force_n {
            m.peak_force_n = f;
            m.peak_force_time_s = t.time_ns as f64 * 1e-9;
        }
        if f > m.safe_force_n {
            m.time_above_safe_s += dt_s;
        }
        let onsets = t.flags & !self.last_flags;
        for (i, count) in m.flag_onsets.iter_mut().enumerate() {
            if onsets.bits() & (1 << i) != 0 {
                *count += 1;
            }
        }
        self.last_flags = t.flags;
        if t.flags.contains(ContactFlags::DEVICE_FAULT) {
            m.device_fault_ticks += 1;
        }

        let position = t.tip_position_m.filter(|p| p.is_finite());
        let Some(p) = position else {
            // A fault tick: no position to trust, so nothing is known of the contact. The path
            // and the jerk start again after it; the contact state and the time of the last
            // contact stay as they were, so a press held through a fault stays one push.
            self.last_position_in_contact = None;
            self.jerk_count = 0;
            return;
        };
        let touching = t.in_contact;
        if touching {
            m.time_in_contact_s += dt_s;
            if !self.in_contact {
                let long_free = self
                    .last_contact_ns
                    .is_none_or(|last| t.time_ns.saturating_sub(last) as f64 * 1e-9 >= PUSH_GAP_S);
                if long_free {
                    m.pushes += 1;
                }
            }
            self.last_contact_ns = Some(t.time_ns);
        }
        self.in_contact = touching;

        if touching {
            if let Some(last) = self.last_position_in_contact {
                m.path_length_in_contact_m += (p - last).length();
            }
            self.last_position_in_contact = Some(p);
            self.jerk_sample(t.time_ns, p);
        } else {
            self.last_position_in_contact = None;
            self.jerk_count = 0;
        }
    }

    fn jerk_sample(&mut self, time_ns: u64, p: DVec3) {
        if self.jerk_count > 0 && time_ns < self.next_jerk_sample_ns {
            return;
        }
        self.next_jerk_sample_ns = time_ns + JERK_SAMPLE_NS;
        self.jerk_samples.rotate_left(1);
        self.jerk_samples[3] = p;
        self.jerk_times_ns.rotate_left(1);
        self.jerk_times_ns[3] = time_ns;
        self.jerk_count = (self.jerk_count + 1).min(4);
        if self.jerk_count == 4 {
            let jerk = third_derivative(self.jerk_samples, self.jerk_times_ns);
            self.jerk_sum += jerk.length_squared();
            self.jerk_terms += 1;
            self.m.mean_squared_jerk_m2_s6 = self.jerk_sum / self.jerk_terms as f64;
        }
    }
}

/// The third derivative of a path through four samples at increasing device times `t_ns`: six
/// times their third divided difference, exact for a cubic whatever the intervals (for equal
/// intervals h it is the third backward difference over h³). The intervals are taken as
/// differences of the integer times before they become seconds, so a long session's large
/// times lose no precision. Samples are at least a tick apart (`jerk_sample`), so no interval
/// is zero.
fn third_derivative(p: [DVec3; 4], t_ns: [u64; 4]) -> DVec3 {
    let dt_s = |i: usize, j: usize| t_ns[j].saturating_sub(t_ns[i]) as f64 * 1e-9;
    let first = |i: usize| (p[i + 1] - p[i]) / dt_s(i, i + 1);
    let second = |i: usize| (first(i + 1) - first(i)) / dt_s(i, i + 2);
    6.0 * (second(1) - second(0)) / dt_s(0, 3)
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn tick(time_ms: u64, y_m: f64, in_contact: bool, force: f64) -> TickInput {
        TickInput {
            time_ns: time_ms * MS,
            tip_position_m: Some(DVec3::new(0.0, y_m, 0.0)),
            in_contact,
            depth_m: 0.0,
            force_n: DVec3::new(0.0, force, 0.0),
            flags: ContactFlags::empty(),
            buttons: 0,
            guide: None,
        }
    }

    #[test]
    fn a_constant_press_counts_its_time_force_and_one_push() {
        let mut acc = MetricsAccumulator::new(1.0);
        // 100 ms free, 1 s pressing still with 1.5 N, 100 ms free.
        for t in 0..1200 {
            let pressing = (100..1100).contains(&t);
            acc.update(&tick(t, 0.0, pressing, if pressing { 1.5 } else { 0.0 }));
        }
        let m = acc.metrics();
        assert_eq!(m.peak_force_n, 1.5);
        assert!((m.peak_force_time_s - 0.1).abs() < 1e-12);
        // 1000 ticks in contact, each counting the 1 ms since the tick before.
        assert!(
            (m.time_in_contact_s - 1.0).abs() < 1e-9,
            "{}",
            m.time_in_contact_s
        );
        assert!((m.time_above_safe_s - 1.0).abs() < 1e-9);
        assert_eq!(m.pushes, 1);
        assert_eq!(m.path_length_in_contact_m, 0.0);
        assert_eq!(m.mean_squared_jerk_m2_s6, 0.0);
        assert_eq!(m.ticks, 1200);
    }

    #[test]
    fn a_ramp_has_its_path_length_no_jerk_and_the_time_above_only_where_it_is() {
        let mut acc = MetricsAccumulator::new(1.0);
        // In contact for 1 s, moving down 10 mm/s; the force rises 0 → 2 N.
        for t in 0..=1000u64 {
            let s = t as f64 * 1e-3;
            acc.update(&tick(t, -0.01 * s, true, 2.0 * s));
        }
        let m = acc.metrics();
        assert!((m.path_length_in_contact_m - 0.01).abs() < 1e-12);
        // A constant velocity has no jerk (to rounding).
        assert!(
            m.mean_squared_jerk_m2_s6 < 1e-12,
            "{}",
            m.mean_squared_jerk_m2_s6
        );
        // Above 1 N from t = 0.5 s: the ticks from 501 ms to 1000 ms, each 1 ms.
        assert!(
            (m.time_above_safe_s - 0.5).abs() < 1e-9,
            "{}",
            m.time_above_safe_s
        );
        assert!((m.peak_force_n - 2.0).abs() < 1e-12);
        assert_eq!(m.pushes, 1);
    }

    #[test]
    fn a_cubic_path_has_its_known_jerk_even_across_lost_ticks() {
        // y = k t³ has jerk 6k everywhere: the third difference is exact for a cubic. With 63
        // ticks lost from 200 ms, the 10 ms samples around the gap are 70 ms apart, and the
        // jerk, taken at the samples' device times, is still 6k.
        let k = 0.02;
        let expected = (6.0 * k) * (6.0 * k);
        for lost in [None, Some(201..=263u64)] {
            let mut acc = MetricsAccumulator::new(10.0);
            for t in (0..=500u64).filter(|t| lost.as_ref().is_none_or(|l| !l.contains(t))) {
                let s = t as f64 * 1e-3;
                acc.update(&tick(t, k * s * s * s, true, 0.1));
            }
            let m = acc.metrics();
            assert!(
                (m.mean_squared_jerk_m2_s6 - expected).abs() < 1e-6 * expected,
                "{lost:?}: {} vs {expected}",
                m.mean_squared_jerk_m2_s6
            );
        }
    }

    #[test]
    fn a_jittered_press_has_its_hand_computed_path_length_and_jerk() {
        // A slow press (5 mm/s down) with a square-wave jitter of ±50 µm that flips every 10 ms:
        // +a in [0, 10) ms, -a in [10, 20) ms, … over 1 s at 1 kHz, all in contact.
        let (a, v) = (50e-6, 0.005);
        let jitter = |t: u64| if (t / 10).is_multiple_of(2) { a } else { -a };
        let mut acc = MetricsAccumulator::new(10.0);
        for t in 0..=1000u64 {
            acc.update(&tick(t, -v * t as f64 * 1e-3 + jitter(t), true, 0.5));
        }
        let m = acc.metrics();
        // Path: 1000 steps of 1 ms. The 100 flips (at 10, 20, … 1000 ms) alternate down (2a + v
        // dt, with the press) and up (2a - v dt, against it): 100 · 2a in all; the other 900
        // steps are the press alone, v dt each.
        let path_m = 100.0 * 2.0 * a + 900.0 * v * 1e-3;
        assert!(
            (m.path_length_in_contact_m - path_m).abs() < 1e-12,
            "{} vs {path_m}",
            m.path_length_in_contact_m
        );
        // Jerk: the 10 ms samples (0, 10, … 1000 ms) alternate +a, -a, so every third difference
        // is ±(a + 3a + 3a + a) = ±8a (the press, linear, adds none) over h³ = (10 ms)³: the mean
        // of its square over all 98 windows is (8a / h³)².
        let h = 0.01;
        let jerk = 8.0 * a / (h * h * h);
        assert!(
            (m.mean_squared_jerk_m2_s6 - jerk * jerk).abs() < 1e-9 * jerk * jerk,
            "{} vs {}",
            m.mean_squared_jerk_m2_s6,
            jerk * jerk
        );
        assert_eq!(m.pushes, 1);
        assert!((m.time_in_contact_s - 1.0).abs() < 1e-9);
    }

    #[test]
    fn flickers_count_as_one_push_and_separate_presses_as_two() {
        // Contact lost for 5 ms twice: a flicker, not new pushes.
        let mut flicker = MetricsAccumulator::new(10.0);
        for t in 0..=1000u64 {
            let lost = (300..305).contains(&t) || (700..705).contains(&t);
            flicker.update(&tick(t, 0.0, !lost, 0.5));
        }
        assert_eq!(flicker.metrics().pushes, 1);
        // Separate presses 100 ms apart are two.
        let mut two = MetricsAccumulator::new(10.0);
        for t in 0..400u64 {
            two.update(&tick(t, 0.0, !(150..250).contains(&t), 0.5));
        }
        assert_eq!(two.metrics().pushes, 2);
    }

    #[test]
    fn a_fault_during_one_held_press_leaves_it_one_push() {
        let mut acc = MetricsAccumulator::new(10.0);
        // 100 ms free, a press from 100 ms to 1 s with the device faulting for 200 ms in it.
        for t in 0..1000u64 {
            let pressing = t >= 100;
            let input = if (400..600).contains(&t) {
                TickInput {
                    tip_position_m: None,
                    flags: ContactFlags::DEVICE_FAULT,
                    ..tick(t, 0.0, false, 0.0)
                }
            } else {
                tick(t, 0.0, pressing, if pressing { 1.0 } else { 0.0 })
            };
            acc.update(&input);
        }
        let m = acc.metrics();
        assert_eq!(m.pushes, 1);
        assert_eq!(m.device_fault_ticks, 200);
        // In contact from 100 ms to 1 s but for the 200 faulted ticks (and the first tick after
        // the fault, whose 1 ms is the fault's last).
        assert!(
            (m.time_in_contact_s - 0.7).abs() < 1e-9,
            "{}",
            m.time_in_contact_s
        );
        // A release during the fault, and a press 100 ms after the last contact: two.
        let mut two = MetricsAccumulator::new(10.0);
        for t in 0..400u64 {
            let input = if (150..200).contains(&t) {
                TickInput {
                    tip_position_m: None,
                    flags: ContactFlags::DEVICE_FAULT,
                    ..tick(t, 0.0, true, 0.0)
                }
            } else {
                tick(t, 0.0, !(150..250).contains(&t), 0.5)
            };
            two.update(&input);
        }
        assert_eq!(two.metrics().pushes, 2);
    }

    #[test]
    fn faults_and_flags_are_counted_and_a_fault_breaks_the_path() {
        let mut acc = MetricsAccumulator::new(10.0);
        acc.update(&tick(0, 0.0, true, 0.5));
        acc.update(&tick(1, -0.001, true, 0.5));
        // A fault tick: its position is not trusted; the path resumes after it.
        acc.update(&TickInput {
            tip_position_m: None,
            flags: ContactFlags::DEVICE_FAULT,
            ..tick(2, -0.5, true, 0.0)
        });
        acc.update(&TickInput {
            flags: ContactFlags::SATURATED | ContactFlags::RAMPING,
            ..tick(3, -0.002, true, 0.5)
        });
        acc.update(&TickInput {
            flags: ContactFlags::SATURATED,
            ..tick(4, -0.003, true, 0.5)
        });
        acc.update(&tick(5, -0.004, true, 0.5));
        acc.update(&TickInput {
            flags: ContactFlags::SATURATED,
            ..tick(6, -0.005, true, 0.5)
        });
        let m = acc.metrics();
        assert_eq!(m.device_fault_ticks, 1);
        let bit = |f: ContactFlags| f.bits().trailing_zeros() as usize;
        assert_eq!(m.flag_onsets[bit(ContactFlags::SATURATED)], 2);
        assert_eq!(m.flag_onsets[bit(ContactFlags::RAMPING)], 1);
        assert_eq!(m.flag_onsets[bit(ContactFlags::DEVICE_FAULT)], 1);
        // 1 mm before the fault, 3 mm after it: the jump across it is not path.
        assert!(
            (m.path_length_in_contact_m - 0.004).abs() < 1e-12,
            "{}",
            m.path_length_in_contact_m
        );
        // A long gap in device time counts at most MAX_DT_S.
        let mut gap = MetricsAccumulator::new(10.0);
        gap.update(&tick(0, 0.0, true, 0.5));
        gap.update(&tick(5000, 0.0, true, 0.5));
        assert!((gap.metrics().time_in_contact_s - MAX_DT_S).abs() < 1e-12);
    }
}
