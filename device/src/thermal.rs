//! The continuous-force limit: a model of the motors' heating that holds the RMS force at the
//! device's continuous rating, while short peaks up to the peak force still pass.
//!
//! A PHANTOM Desktop exerts 7.9 N briefly but only 1.75 N continuously (docs/physics.md, "Haptic
//! stability"): holding more heats the motor windings until the device's own protection turns
//! the force output off (a device fault in the middle of a session), or damages them.
//! [`ContinuousForceLimiter`] keeps below that.
//!
//! # The model
//! The heat a DC motor makes is I²R, and its current is proportional to its torque, so to the
//! force at the tip (through the arm's Jacobian, taken at the nominal posture where the ratings
//! apply). The winding, one thermal capacitance behind one thermal resistance, low-passes that
//! heat. The limiter therefore tracks the first-order low-pass of the squared force the device
//! delivers, h(t), with time constant τ:
//!
//! h(n+1) = a·h(n) + (1 − a)·min(|F(n)|, F_peak)²,  a = exp(−T/τ)
//!
//! (exact for a force held over the period T). Held at a constant force F, h settles at F², so the
//! continuous rating F_c is exactly the force whose h settles at F_c²; √h is the RMS force the
//! motors "remember".
//!
//! # The time constant
//! τ = [`MOTOR_TIME_CONSTANT_S`] = 5 s. The windings of the small coreless DC motors that drive
//! desktop haptic arms have thermal time constants of the order of ten seconds (their housings
//! of minutes); a single pole at 5 s heats faster than such a winding, so a long push is limited
//! somewhat before the winding would reach its limit (it also cools faster, so a press soon after
//! a long one is forgiven sooner), and the equilibrium, which is what the continuous rating
//! specifies, is the same. It is also long enough that the taps and presses of
//! palpation (a few tenths of a second at several newtons) pass untouched: from cold, a 5 N
//! press is limited only after 0.53 s, a 7.9 N one after 0.13 s.
//!
//! # The limit
//! Below the knee, h ≤ [`KNEE_FRACTION`]·F_c², nothing is limited. Above it the force allowed is
//!
//! F_allow² = F_c² + K·(F_c² − h),  K = (F_peak² − F_c²) / ((1 − knee)·F_c²)
//!
//! which falls continuously from F_peak at the knee to F_c at the rating (and below F_c past it).
//! Delivering F_allow gives τ·dh/dt = (1 + K)(F_c² − h): h settles at the rating from below, with
//! the time constant τ/(1 + K) (0.13 s for the PHANTOM Desktop); a hold at any force up to the
//! peak never takes h past the rating. A command that jumps up while the motors are warm passes
//! at first (the gain falls at its rate), so h exceeds the rating for a moment: that is the short
//! peak the rating allows, and the limit pulls h back (F_allow < F_c past the rating).
//!
//! The commanded force is multiplied by a gain g ∈ [0, 1] that moves toward F_allow/|F| (1 when
//! the command is within it) by at most [`GAIN_RATE_PER_S`]·T per tick, so the limiter never adds
//! a step of its own to the force: it changes the force by at most 0.5 % of the command per
//! millisecond. The direction of the force is never changed, only its magnitude reduced.
//!
//! # Where it goes
//! Last in the force pipeline, after the saturation at the peak force: every force it sees is
//! then one the device delivers, and its gain acts on that. (Before the saturation, a command
//! above the peak would hide the gain's first steps, which would only cut force the saturation
//! cuts anyway, and the model would overshoot the rating for a moment; a force above the peak
//! that reaches it is booked at the peak all the same.) The state lives as long as the device:
//! it must be fed every tick, with zero force out of contact and on faults, so that the model
//! cools as the motors do.
//!
//! Fixed size, no allocation, O(1) per tick, deterministic (the same inputs give the same bits);
//! a non-finite force gives zero force and is booked as zero, so it never reaches the state.

use glam::DVec3;

use crate::device::DeviceLimits;

/// Time constant of the motors' heating model, seconds (see the module documentation); the
/// device presets carry it.
pub use crate::device::MOTOR_TIME_CONSTANT_S;

/// Largest change of the limiter's gain per second: 0.005 per millisecond, 25 mN per tick on a
/// 5 N command, below what a hand resolves, and fast enough that a held press reaches the rating
/// without the model overshooting it.
pub const GAIN_RATE_PER_S: f64 = 5.0;

/// Fraction of the rating's squared force at which the limit begins: the model's RMS force is
/// then F_c/√2 (1.24 N on the PHANTOM Desktop).
pub const KNEE_FRACTION: f64 = 0.5;

/// Why a limiter could not be built from the limits given.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum ThermalError {
    #[error("device limits: {field} must be a finite number > 0, got {value}")]
    NotPositive { field: &'static str, value: f64 },
    #[error(
        "device limits: peak_force_n ({peak_force_n}) must be at least continuous_force_n \
         ({continuous_force_n})"
    )]
    PeakBelowContinuous {
        peak_force_n: f64,
        continuous_force_n: f64,
    },
}

/// Scales the commanded force down, smoothly, so that the motors' RMS force settles at the
/// device's continuous rating (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContinuousForceLimiter {
    /// F_c², N².
    continuous_sq_n2: f64,
    /// F_peak: the most the device delivers, so the most the model books.
    peak_force_n: f64,
    time_constant_s: f64,
    /// h below which nothing is limited, N².
    knee_sq_n2: f64,
    /// K of F_allow² = F_c² + K·(F_c² − h).
    slope: f64,
    /// h: the low-passed squared force delivered, N².
    heat_sq_n2: f64,
    /// g ∈ [0, 1], the factor applied to the last command.
    gain: f64,
    /// The period `decay` was computed for (its bits), so exp() runs only when the period
    /// changes; 0.0 is never a valid period.
    decay_period_bits: u64,
    /// a = exp(−T/τ) for that period.
    decay: f64,
}

impl ContinuousForceLimiter {
    /// A cold limiter for a device's continuous and peak force and its thermal time constant.
    pub fn for_device(limits: &DeviceLimits) -> Result<Self, ThermalError> {
        Self::new(
            limits.continuous_force_n,
            limits.peak_force_n,
            limits.thermal_time_constant_s,
        )
    }

    /// A cold limiter (no heat remembered). Every argument must be finite and > 0, and the peak
    /// at least the continuous force.
    pub fn new(
        continuous_force_n: f64,
        peak_force_n: f64,
        time_constant_s: f64,
    ) -> Result<Self, ThermalError> {
        for (field, value) in [
            ("continuous_force_n", continuous_force_n),
            ("peak_force_n", peak_force_n),
            ("thermal_time_constant_s", time_constant_s),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(ThermalError::NotPositive { field, value });
            }
        }
        if peak_force_n < continuous_force_n {
            return Err(ThermalError::PeakBelowContinuous {
                peak_force_n,
                continuous_force_n,
            });
        }
        let continuous_sq_n2 = continuous_force_n * continuous_force_n;
        let knee_sq_n2 = KNEE_FRACTION * continuous_sq_n2;
        let slope =
            (peak_force_n * peak_force_n - continuous_sq_n2) / (continuous_sq_n2 - knee_sq_n2);
        Ok(Self {
            continuous_sq_n2,
            peak_force_n,
            time_constant_s,
            knee_sq_n2,
            slope,
            heat_sq_n2: 0.0,
            gain: 1.0,
            decay_period_bits: 0.0f64.to_bits(),
            decay: 1.0,
        })
    }

    /// One tick: returns the force to command instead of `force_n`, to be held for `period_s`,
    /// and whether the limiter reduced it. Books the force delivered in the heating model.
    ///
    /// A non-finite force (or one whose magnitude overflows) gives zero force, booked as zero. A
    /// period that is not a finite number > 0 advances nothing: the force is scaled by the
    /// current gain and the state is kept.
    #[inline]
    pub fn apply(&mut self, force_n: DVec3, period_s: f64) -> (DVec3, bool) {
        let magnitude_n = force_n.length();
        let (force_n, magnitude_n) = if magnitude_n.is_finite() {
            (force_n, magnitude_n)
        } else {
            (DVec3::ZERO, 0.0)
        };
        if !(period_s.is_finite() && period_s > 0.0) {
            let acted = self.gain < 1.0 && magnitude_n > 0.0;
            return (force_n * self.gain, acted);
        }

        let target = self.target_gain(magnitude_n);
        let step = GAIN_RATE_PER_S * period_s;
        // Rate-limited move toward the target; written with max/min (not clamp) so that no
        // combination of values can panic.
        self.gain = target
            .max(self.gain - step)
            .min(self.gain + step)
            .clamp(0.0, 1.0);

        if period_s.to_bits() != self.decay_period_bits {
            self.decay_period_bits = period_s.to_bits();
            self.decay = (-period_s / self.time_constant_s).exp();
        }
        let delivered_n = (self.gain * magnitude_n).min(self.peak_force_n);
        self.heat_sq_n2 =
            self.decay * self.heat_sq_n2 + (1.0 - self.decay) * delivered_n * delivered_n;

        let acted = self.gain < 1.0 && magnitude_n > 0.0;
        (force_n * self.gain, acted)
    }

    /// The gain the limit asks for at the present heat: 1 below the knee or when the command is
    /// within F_allow, else F_allow/|F|.
    fn target_gain(&self, magnitude_n: f64) -> f64 {
        if self.heat_sq_n2 <= self.knee_sq_n2 || magnitude_n == 0.0 {
            return 1.0;
        }
        let allowed_sq_n2 = (self.continuous_sq_n2
            + self.slope * (self.continuous_sq_n2 - self.heat_sq_n2))
            .max(0.0);
        let allowed_n = allowed_sq_n2.sqrt();
        if magnitude_n <= allowed_n {
            1.0
        } else {
            allowed_n / magnitude_n
        }
    }

    /// The gain applied at the last tick, in [0, 1] (1: not limiting).
    pub fn gain(&self) -> f64 {
        self.gain
    }

    /// The RMS force the model remembers, √h, newtons.
    pub fn rms_force_n(&self) -> f64 {
        self.heat_sq_n2.sqrt()
    }

    /// h / F_c²: 1 when the model sits at the continuous rating.
    pub fn heat_fraction(&self) -> f64 {
        self.heat_sq_n2 / self.continuous_sq_n2
    }

    /// The continuous rating the limiter holds, newtons.
    pub fn continuous_force_n(&self) -> f64 {
        self.continuous_sq_n2.sqrt()
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use proptest::prelude::*;

    const T: f64 = 0.001;
    const DESKTOP: DeviceLimits = DeviceLimits::PHANTOM_DESKTOP;

    #[test]
    fn every_preset_gives_a_heating_model() {
        for l in [
            DeviceLimits::PHANTOM_DESKTOP,
            DeviceLimits::TOUCH,
            DeviceLimits::OMNI,
        ] {
            // A continuous rating the heating model accepts (below the peak, positive time
            // constant): otherwise the continuous-force limit would silently be off.
            assert!(ContinuousForceLimiter::for_device(&l).is_ok(), "{}", l.name);
        }
    }

    fn limiter() -> ContinuousForceLimiter {
        ContinuousForceLimiter::for_device(&DESKTOP).unwrap()
    }

    /// A force of `magnitude_n` along a direction that is not an axis (so every component
    /// matters).
    fn force(magnitude_n: f64) -> DVec3 {
        DVec3::new(0.3, 0.9, -0.2).normalize() * magnitude_n
    }

    #[test]
    fn every_device_gets_a_limiter_and_bad_limits_are_named() {
        for l in [
            DeviceLimits::PHANTOM_DESKTOP,
            DeviceLimits::TOUCH,
            DeviceLimits::OMNI,
        ] {
            let t = ContinuousForceLimiter::for_device(&l).unwrap();
            assert_eq!(t.continuous_force_n(), l.continuous_force_n, "{}", l.name);
            assert_eq!((t.gain(), t.rms_force_n()), (1.0, 0.0));
        }
        let err = ContinuousForceLimiter::new(f64::NAN, 7.9, 5.0).unwrap_err();
        assert!(err.to_string().contains("continuous_force_n"), "{err}");
        let err = ContinuousForceLimiter::new(1.75, 7.9, 0.0).unwrap_err();
        assert!(err.to_string().contains("thermal_time_constant_s"), "{err}");
        let err = ContinuousForceLimiter::new(1.75, 1.0, 5.0).unwrap_err();
        assert!(matches!(err, ThermalError::PeakBelowContinuous { .. }));
        assert!(err.to_string().contains("peak_force_n (1)"), "{err}");
    }

    #[test]
    fn a_5_n_hold_settles_at_the_rating_without_exceeding_it() {
        let mut t = limiter();
        let rating = DESKTOP.continuous_force_n;
        let command = force(5.0);
        let mut first_limited_s = None;
        let mut window_sq_sum = 0.0;
        let mut window_ticks = 0;
        for k in 0..20_000 {
            let now_s = k as f64 * T;
            let (out, acted) = t.apply(command, T);
            let out_n = out.length();
            assert!(out_n <= 5.0 + 1e-12, "never more than commanded: {out_n}");
            assert!(
                (out.normalize() - command.normalize()).length() < 1e-12,
                "direction kept"
            );
            assert!(
                t.rms_force_n() <= rating * (1.0 + 1e-12),
                "model RMS {} above the rating at {now_s} s",
                t.rms_force_n()
            );
            if acted && first_limited_s.is_none() {
                first_limited_s = Some(now_s);
            }
            if now_s >= 1.5 {
                assert!(
                    out_n <= rating * 1.01,
                    "{out_n} N at {now_s} s, not yet settled"
                );
            }
            if now_s >= 10.0 {
                window_sq_sum += out_n * out_n;
                window_ticks += 1;
            }
        }
        // As the module documentation says: limiting begins at 0.53 s.
        let first = first_limited_s.unwrap();
        assert!((0.5..0.56).contains(&first), "limited from {first} s");
        // Measured independently of the model: the RMS over the last 10 s is the rating (not
        // less: the limiter does not take more than it must).
        let rms = (window_sq_sum / window_ticks as f64).sqrt();
        assert!((rms / rating - 1.0).abs() < 1e-3, "RMS {rms} N");
    }

    #[test]
    fn no_hold_up_to_the_peak_takes_the_model_past_the_rating() {
        let rating = DESKTOP.continuous_force_n;
        for magnitude_n in [1.8, 2.5, 3.5, 5.0, 6.5, DESKTOP.peak_force_n] {
            let mut t = limiter();
            for _ in 0..30_000 {
                t.apply(force(magnitude_n), T);
                assert!(
                    t.rms_force_n() <= rating * (1.0 + 1e-12),
                    "{magnitude_n} N hold: model RMS {}",
                    t.rms_force_n()
                );
            }
            // ... and every one of them ends at the rating, not below it.
            let (out, acted) = t.apply(force(magnitude_n), T);
            assert!(acted, "{magnitude_n} N");
            assert!(
                (out.length() / rating - 1.0).abs() < 1e-3,
                "{magnitude_n} N: {out}"
            );
        }
    }

    #[test]
    fn commands_above_the_peak_are_booked_at_the_peak() {
        // The device delivers at most its peak: one tick of 20 N from cold books 7.9 N.
        let mut t = limiter();
        let (out, acted) = t.apply(force(20.0), T);
        assert_eq!((out, acted), (force(20.0), false));
        let a = (-T / MOTOR_TIME_CONSTANT_S).exp();
        let expected = (1.0 - a) * DESKTOP.peak_force_n * DESKTOP.peak_force_n;
        assert!((t.rms_force_n() * t.rms_force_n() / expected - 1.0).abs() < 1e-12);
    }

    #[test]
    fn a_short_tap_passes_unscaled() {
        let mut t = limiter();
        for _ in 0..300 {
            let (out, acted) = t.apply(force(5.0), T);
            assert_eq!(out, force(5.0));
            assert!(!acted);
        }
        // A 0.1 s press at the full peak passes too.
        let mut t = limiter();
        for _ in 0..100 {
            assert_eq!(t.apply(force(7.9), T), (force(7.9), false));
        }
    }

    #[test]
    fn the_limiter_remembers_heat_and_recovers_after_release() {
        let mut t = limiter();
        for _ in 0..10_000 {
            t.apply(force(5.0), T);
        }
        assert!(t.gain() < 0.4 && t.heat_fraction() > 0.99);
        // One second after release the motors are still warm: a tap is limited at once.
        for _ in 0..1000 {
            assert_eq!(t.apply(DVec3::ZERO, T), (DVec3::ZERO, false));
        }
        let mut warm = t;
        let limited = (0..300).any(|_| warm.apply(force(5.0), T).1);
        assert!(limited, "a warm motor is not forgotten");
        // After 30 s (6 τ) of rest the same tap passes untouched.
        for _ in 0..29_000 {
            t.apply(DVec3::ZERO, T);
        }
        assert_eq!(t.gain(), 1.0);
        for _ in 0..300 {
            assert_eq!(t.apply(force(5.0), T), (force(5.0), false));
        }
    }

    #[test]
    fn the_gain_never_moves_faster_than_its_rate() {
        let mut t = limiter();
        let mut previous = t.gain();
        let mut lowest: f64 = 1.0;
        // Presses of 0 … 7.9 N switching every 0.37 s, with rests: steps in the command that the
        // limiter must not turn into steps of its own.
        for k in 0..40_000u64 {
            let level = [5.0, 0.0, 7.9, 3.0, 0.0, 6.0, 1.0][(k / 370 % 7) as usize];
            t.apply(force(level), T);
            let g = t.gain();
            assert!(
                (g - previous).abs() <= GAIN_RATE_PER_S * T * (1.0 + 1e-12),
                "tick {k}: gain {previous} → {g}"
            );
            previous = g;
            lowest = lowest.min(g);
        }
        assert!(lowest < 0.5, "the limit engaged: lowest gain {lowest}");
    }

    #[test]
    fn nan_gives_zero_and_does_not_poison_the_state() {
        let (mut a, mut b) = (limiter(), limiter());
        for _ in 0..3000 {
            a.apply(force(5.0), T);
            b.apply(force(5.0), T);
        }
        let bad = [
            DVec3::new(f64::NAN, 1.0, 0.0),
            DVec3::new(0.0, f64::INFINITY, 0.0),
            DVec3::splat(1e300), // finite components, overflowing magnitude
        ];
        for f in bad {
            let (out, acted) = a.apply(f, T);
            assert_eq!((out, acted), (DVec3::ZERO, false), "{f}");
            b.apply(DVec3::ZERO, T);
        }
        // Booked exactly as zero force: the two limiters agree to the bit afterwards.
        assert_eq!(a, b);
        assert!(a.rms_force_n().is_finite() && a.gain().is_finite());
    }

    #[test]
    fn an_invalid_period_advances_nothing() {
        let mut t = limiter();
        for _ in 0..3000 {
            t.apply(force(5.0), T);
        }
        let before = t;
        for period in [0.0, -T, f64::NAN, f64::INFINITY] {
            let (out, acted) = t.apply(force(5.0), period);
            assert_eq!(out, force(5.0) * before.gain());
            assert_eq!(acted, before.gain() < 1.0);
            assert_eq!(t, before, "period {period}");
        }
    }

    fn any_force() -> impl Strategy<Value = DVec3> {
        prop_oneof![
            8 => (-10.0..10.0f64, -10.0..10.0f64, -10.0..10.0f64)
                .prop_map(|(x, y, z)| DVec3::new(x, y, z)),
            1 => (-1e6..1e6f64, -1e6..1e6f64).prop_map(|(x, y)| DVec3::new(x, y, 0.0)),
            1 => Just(DVec3::new(f64::NAN, 0.0, 1.0)),
            1 => Just(DVec3::new(f64::NEG_INFINITY, 0.0, 0.0)),
            1 => Just(DVec3::ZERO),
        ]
    }

    fn any_period() -> impl Strategy<Value = f64> {
        prop_oneof![
            8 => Just(T),
            3 => 1e-5..0.05f64,
            1 => Just(0.0),
            1 => Just(-T),
            1 => Just(f64::NAN),
            1 => Just(1e6),
        ]
    }

    proptest! {
        #[test]
        fn outputs_are_finite_bounded_and_deterministic(
            ticks in prop::collection::vec((any_force(), any_period(), 1usize..400), 1..40)
        ) {
            let mut t = limiter();
            let mut twin = limiter();
            for (f, period, repeat) in ticks {
                for _ in 0..repeat {
                    let g_before = t.gain();
                    let (out, acted) = t.apply(f, period);
                    let again = twin.apply(f, period);
                    prop_assert_eq!(
                        again.0.to_array().map(f64::to_bits),
                        out.to_array().map(f64::to_bits)
                    );
                    prop_assert_eq!(again.1, acted);
                    prop_assert!(out.is_finite());
                    prop_assert!((0.0..=1.0).contains(&t.gain()));
                    let h = t.rms_force_n();
                    prop_assert!((0.0..=DESKTOP.peak_force_n * (1.0 + 1e-12)).contains(&h));
                    if f.length().is_finite() {
                        prop_assert!(out.length() <= f.length() * (1.0 + 1e-12));
                        prop_assert_eq!(acted, t.gain() < 1.0 && f.length() > 0.0);
                    } else {
                        prop_assert_eq!(out, DVec3::ZERO);
                    }
                    if period.is_finite() && period > 0.0 {
                        let step = (t.gain() - g_before).abs();
                        prop_assert!(step <= GAIN_RATE_PER_S * period * (1.0 + 1e-12) + 1e-15);
                    } else {
                        prop_assert_eq!(t.gain(), g_before);
                    }
                }
            }
        }
    }
}
