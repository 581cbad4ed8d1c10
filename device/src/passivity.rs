//! Passivity observer and controller (Hannaford & Ryu 2002, IEEE T-RA 18:1).
//!
//! A sampled virtual environment can create energy: the force is held for a whole period while the
//! tip moves, so a stiff contact pushes back harder on the way out than it resisted on the way in.
//! The observer integrates the energy the environment has absorbed from the user. It books, each
//! tick, the exact work of the force held over the last period against the displacement the
//! device actually made, E(n) = −Σ F(k−1)·(x(k) − x(k−1)) (Hannaford & Ryu's T Σ f·v with the
//! velocity integrated exactly; a filtered velocity estimate lags the force and hides exactly the
//! energy the sample-and-hold creates). Positive E means the environment has taken energy in, as a
//! passive spring–damper does. When the next tick, at the predicted displacement, would drive E
//! below zero, the controller adds just enough damping α = −E/(T|v|²) against the velocity,
//! bounded by the damping the device renders stably: an unbounded α pays a large deficit in one
//! tick with a jolt the user feels (and that can itself bounce the tool off the surface), a
//! bounded one pays it over a few ticks.

use glam::DVec3;

/// Velocities below this magnitude carry no measurable energy; the controller does not divide by
/// them (α would be unbounded and the force would be noise amplified).
const MIN_SPEED_M_S: f64 = 1e-6;

/// Energy balance of one contact, and the damping that keeps it non-negative.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PassivityObserver {
    energy_j: f64,
}

/// What the controller did to one tick's force.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PassivityCorrection {
    /// The force after the controller's damping.
    pub force_n: DVec3,
    /// The damping the controller added, N·s/m (0 when it stayed out).
    pub added_damping_n_s_per_m: f64,
}

impl PassivityObserver {
    /// A fresh observer: no energy absorbed yet.
    pub const fn new() -> Self {
        Self { energy_j: 0.0 }
    }

    /// The energy the environment has absorbed so far (≥ 0 for a passive contact).
    pub fn energy_j(&self) -> f64 {
        self.energy_j
    }

    /// The controller: returns `force_n` with enough damping added (at most
    /// `max_damping_n_s_per_m`) that holding it for `period_s` while the tip moves at
    /// `velocity_m_s` keeps the observed energy ≥ 0. Does not change the observer;
    /// [`PassivityObserver::observe`] books what really happened next tick.
    pub fn correct(
        &self,
        force_n: DVec3,
        velocity_m_s: DVec3,
        period_s: f64,
        max_damping_n_s_per_m: f64,
    ) -> PassivityCorrection {
        let untouched = PassivityCorrection {
            force_n,
            added_damping_n_s_per_m: 0.0,
        };
        let speed_sq = velocity_m_s.length_squared();
        if period_s.is_nan() || period_s <= 0.0 || speed_sq < MIN_SPEED_M_S * MIN_SPEED_M_S {
            return untouched;
        }
        let tentative_j = self.energy_j - period_s * force_n.dot(velocity_m_s);
        if tentative_j >= 0.0 {
            return untouched;
        }
        let alpha = (-tentative_j / (period_s * speed_sq)).min(max_damping_n_s_per_m.max(0.0));
        PassivityCorrection {
            force_n: force_n - alpha * velocity_m_s,
            added_damping_n_s_per_m: alpha,
        }
    }

    /// Books the work of `held_force_n`, held over the last period, along the displacement the
    /// tip made meanwhile.
    pub fn observe(&mut self, held_force_n: DVec3, displacement_m: DVec3) {
        let absorbed_j = -held_force_n.dot(displacement_m);
        if absorbed_j.is_finite() {
            self.energy_j += absorbed_j;
        }
    }

    /// Credits energy the environment legitimately releases without the user having put it in
    /// this contact (a force ramp restoring the elastic energy of a contact after a fault).
    pub fn credit(&mut self, energy_j: f64) {
        if energy_j.is_finite() && energy_j > 0.0 {
            self.energy_j += energy_j;
        }
    }

    /// Called when a contact ends: the energy banked by damping during that contact is dropped
    /// (otherwise a long, well-damped contact would let a later one create energy unchecked),
    /// while a deficit is kept so that the next contact pays it back.
    pub fn end_contact(&mut self) {
        self.energy_j = self.energy_j.min(0.0);
    }

    /// Forgets everything (after a device fault: the motion history is meaningless).
    pub fn reset(&mut self) {
        self.energy_j = 0.0;
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    const T: f64 = 1e-3;

    #[test]
    fn held_force_over_the_real_displacement_reveals_created_energy() {
        // A spring pushing along +y; tip moves in (v < 0) then out (v > 0) at the same speed.
        let mut po = PassivityObserver::new();
        po.observe(DVec3::Y * 1.0, DVec3::NEG_Y * 1e-5); // absorbs 1e-5 J
        assert!((po.energy_j() - 1e-5).abs() < 1e-15);
        po.observe(DVec3::Y * 1.5, DVec3::Y * 1e-5); // returns 1.5e-5 J: created energy
        assert!(po.energy_j() < 0.0);
    }

    #[test]
    fn controller_keeps_energy_at_zero() {
        let mut po = PassivityObserver::new();
        po.observe(DVec3::Y, DVec3::NEG_Y * 1e-5);
        let v = DVec3::Y * 0.02;
        let c = po.correct(DVec3::Y * 3.0, v, T, f64::INFINITY);
        assert!(c.added_damping_n_s_per_m > 0.0);
        assert!(c.force_n.y < 3.0);
        po.observe(c.force_n, v * T);
        assert!(po.energy_j().abs() < 1e-15, "{}", po.energy_j());
    }

    #[test]
    fn controller_damping_is_bounded() {
        let mut po = PassivityObserver::new();
        po.observe(DVec3::Y, DVec3::Y * 1e-2); // a 10 mJ deficit
        let v = DVec3::Y * 0.01;
        let c = po.correct(DVec3::ZERO, v, T, 5.0);
        assert_eq!(c.added_damping_n_s_per_m, 5.0);
        assert!((c.force_n - DVec3::NEG_Y * 0.05).length() < 1e-12);
    }

    #[test]
    fn controller_stays_out_when_passive_or_still() {
        let po = PassivityObserver::new();
        let c = po.correct(DVec3::Y, DVec3::NEG_Y * 0.1, T, 5.0);
        assert_eq!(c.added_damping_n_s_per_m, 0.0);
        let c = po.correct(DVec3::Y, DVec3::ZERO, T, 5.0);
        assert_eq!(c.force_n, DVec3::Y);
    }

    #[test]
    fn end_of_contact_drops_banked_energy_but_keeps_deficit() {
        let mut po = PassivityObserver::new();
        po.observe(DVec3::Y, DVec3::NEG_Y * 1e-3);
        po.end_contact();
        assert_eq!(po.energy_j(), 0.0);
        po.observe(DVec3::Y, DVec3::Y * 1e-3);
        po.end_contact();
        assert!(po.energy_j() < 0.0);
        po.credit(1.0);
        po.credit(f64::NAN);
        po.credit(-5.0);
        assert!((po.energy_j() - (1.0 - 1e-3)).abs() < 1e-12);
        po.reset();
        assert_eq!(po.energy_j(), 0.0);
    }
}
