//! A simulated PHANTOM Desktop moved by a simulated hand.
//!
//! The tip is a point mass (the device's apparent tip mass plus the hand's) pulled by a
//! spring–damper toward a scripted hand target ([`HandScript`]: approach, press, hold, slide,
//! release) while the rendered force pushes back. The loop is therefore closed: a force law that
//! is too stiff for the 1 kHz sample-and-hold shows up as oscillation, exactly as on a real
//! device.
//!
//! Dynamics advance by a fixed `period_ns` per [`HapticDevice::command_force`] call, never by the
//! wall clock, so the same commands give the same trajectory bit for bit (a replay check).

use glam::{DQuat, DVec3};
use softhaptic_proto::Pose;

use crate::device::{DeviceError, DeviceLimits, DeviceSample, HapticDevice};

/// The hand's intended path, relative to a point on the object's surface and its outward
/// normal (world frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandScript {
    /// Point on the undeformed surface where the hand presses.
    pub surface_point_m: DVec3,
    /// Outward unit normal of the surface there.
    pub surface_normal: DVec3,
    /// Direction of the slide, projected onto the surface's tangent plane at use.
    pub slide_direction: DVec3,
    /// Where the hand starts and returns to: this far above the surface point.
    pub approach_height_m: f64,
    /// How far below the undeformed surface the hand's target goes. The tip stops shallower:
    /// the hand's spring balances the contact force.
    pub press_depth_m: f64,
    /// Length of the slide along the surface, at the pressed depth.
    pub slide_distance_m: f64,
    /// Tilt of the tool axis away from the normal, about the axis normal × slide direction.
    pub tilt_rad: f64,
    /// Phase durations in seconds.
    pub approach_s: f64,
    pub press_s: f64,
    pub hold_s: f64,
    pub slide_s: f64,
    pub release_s: f64,
    /// Start over after the release (the server's demonstration runs forever).
    pub repeat: bool,
    /// Hold the first button down through the hold phase (a trainee marking where the tool
    /// presses, as in a palpation).
    pub button_in_hold: bool,
}

impl HandScript {
    /// A press at `surface_point_m` along `-surface_normal`: 0.5 s approach from 20 mm above,
    /// 0.5 s press, 1 s hold, a 10 mm slide over 1 s, 0.5 s release; no tilt, no repeat.
    pub fn press(surface_point_m: DVec3, surface_normal: DVec3, press_depth_m: f64) -> Self {
        let n = surface_normal.try_normalize().unwrap_or(DVec3::Y);
        Self {
            surface_point_m,
            surface_normal: n,
            slide_direction: n.any_orthonormal_vector(),
            approach_height_m: 0.02,
            press_depth_m,
            slide_distance_m: 0.01,
            tilt_rad: 0.0,
            approach_s: 0.5,
            press_s: 0.5,
            hold_s: 1.0,
            slide_s: 1.0,
            release_s: 0.5,
            repeat: false,
            button_in_hold: false,
        }
    }

    /// The buttons held down at `time_s`: the first through the hold when `button_in_hold`.
    pub fn buttons_at(&self, time_s: f64) -> u32 {
        let total = self.duration_s();
        let mut t = time_s.max(0.0);
        if self.repeat && total > 0.0 {
            t %= total;
        }
        let (from, until) = self.hold_window_s();
        u32::from(self.button_in_hold && (from..until).contains(&t))
    }

    /// Length of one pass of the script.
    pub fn duration_s(&self) -> f64 {
        self.approach_s + self.press_s + self.hold_s + self.slide_s + self.release_s
    }

    /// Start of the hold phase and its end, seconds from the start of a pass.
    pub fn hold_window_s(&self) -> (f64, f64) {
        let start = self.approach_s + self.press_s;
        (start, start + self.hold_s)
    }

    fn normal(&self) -> DVec3 {
        self.surface_normal.try_normalize().unwrap_or(DVec3::Y)
    }

    fn slide(&self) -> DVec3 {
        let n = self.normal();
        let t = self.slide_direction - n * self.slide_direction.dot(n);
        t.try_normalize()
            .unwrap_or_else(|| n.any_orthonormal_vector())
    }

    /// Orientation of the tool: +y along the normal, tilted by `tilt_rad`.
    pub fn tool_orientation(&self) -> DQuat {
        let n = self.normal();
        let upright = DQuat::from_rotation_arc(DVec3::Y, n);
        let tilt_axis = n.cross(self.slide());
        DQuat::from_axis_angle(tilt_axis, self.tilt_rad) * upright
    }

    /// The hand target's position and velocity at `time_s` (smooth cosine blends between the
    /// phases' waypoints, so the hand never jerks).
    pub fn target_at(&self, time_s: f64) -> (DVec3, DVec3) {
        let n = self.normal();
        let t_dir = self.slide();
        let above = self.surface_point_m + n * self.approach_height_m;
        let surface = self.surface_point_m;
        let pressed = self.surface_point_m - n * self.press_depth_m;
        let slid = pressed + t_dir * self.slide_distance_m;
        let total = self.duration_s();
        let mut t = time_s.max(0.0);
        if self.repeat && total > 0.0 {
            t %= total;
        }
        let phases = [
            (self.approach_s, above, surface),
            (self.press_s, surface, pressed),
            (self.hold_s, pressed, pressed),
            (self.slide_s, pressed, slid),
            // Back to the start, so that a repeating script has no jump at the wrap.
            (self.release_s, slid, above),
        ];
        let mut last = above;
        for (duration, from, to) in phases {
            last = to;
            if t < duration && duration > 0.0 {
                let u = t / duration;
                let blend = 0.5 - 0.5 * (std::f64::consts::PI * u).cos();
                let rate = 0.5 * std::f64::consts::PI * (std::f64::consts::PI * u).sin() / duration;
                return (from + (to - from) * blend, (to - from) * rate);
            }
            t -= duration.max(0.0);
        }
        (last, DVec3::ZERO)
    }
}

/// The hand and device parameters of the simulation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimParams {
    pub limits: DeviceLimits,
    /// Apparent mass of the device at the tip (PHANTOM Desktop datasheet ≈ 45 g).
    pub tip_mass_kg: f64,
    /// Effective mass of the fingers and hand moving with the stylus.
    pub hand_mass_kg: f64,
    /// Stiffness of the grip holding the stylus toward the intended path.
    pub hand_stiffness_n_per_m: f64,
    /// Damping of the grip.
    pub hand_damping_n_s_per_m: f64,
    /// Viscous friction of the mechanism.
    pub device_damping_n_s_per_m: f64,
    /// Fixed time advanced per command.
    pub period_ns: u64,
    /// Integration substeps per period (the force is held across them: zero-order hold).
    pub substeps: u32,
    /// Encoder resolution; positions are reported rounded to it (0: exact).
    pub position_resolution_m: f64,
    /// Cut-off of the first-order filter on the differentiated encoder positions, as a device
    /// driver estimates velocity (≤ 0: report the exact velocity).
    pub velocity_filter_hz: f64,
}

impl Default for SimParams {
    /// A PHANTOM Desktop held in a relaxed pen grip: 45 g tip, 100 g of hand, 300 N/m and
    /// 2 N·s/m of grip, 0.023 mm encoders, velocity filtered at 200 Hz.
    fn default() -> Self {
        Self {
            limits: DeviceLimits::PHANTOM_DESKTOP,
            tip_mass_kg: 0.045,
            hand_mass_kg: 0.1,
            hand_stiffness_n_per_m: 300.0,
            hand_damping_n_s_per_m: 2.0,
            device_damping_n_s_per_m: 0.05,
            period_ns: 1_000_000,
            substeps: 10,
            position_resolution_m: 0.023e-3,
            velocity_filter_hz: 200.0,
        }
    }
}

/// A deterministic fault the simulation produces between two device times (for tests and
/// demonstrations of the fault guard).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SimFault {
    /// `read` returns this error.
    Error(DeviceError),
    /// `read` returns a sample whose position is NaN.
    NonFinite,
}

/// The simulated PHANTOM Desktop.
#[derive(Debug, Clone)]
pub struct SimulatedPhantom {
    script: HandScript,
    params: SimParams,
    orientation: DQuat,
    position_m: DVec3,
    velocity_m_s: DVec3,
    time_ns: u64,
    force_n: DVec3,
    reported_position_m: DVec3,
    reported_velocity_m_s: DVec3,
    work_on_tip_j: f64,
    fault: Option<(u64, u64, SimFault)>,
}

impl SimulatedPhantom {
    /// A PHANTOM Desktop in a relaxed grip, at rest at the script's start.
    pub fn new(script: HandScript) -> Self {
        Self::with_params(script, SimParams::default())
    }

    pub fn with_params(script: HandScript, params: SimParams) -> Self {
        let (start, _) = script.target_at(0.0);
        let mut sim = Self {
            script,
            params,
            orientation: script.tool_orientation(),
            position_m: start,
            velocity_m_s: DVec3::ZERO,
            time_ns: 0,
            force_n: DVec3::ZERO,
            reported_position_m: start,
            reported_velocity_m_s: DVec3::ZERO,
            work_on_tip_j: 0.0,
            fault: None,
        };
        sim.reported_position_m = sim.quantise(start);
        sim
    }

    pub fn script(&self) -> &HandScript {
        &self.script
    }

    pub fn params(&self) -> &SimParams {
        &self.params
    }

    /// Makes `read` fail with `fault` for device times in `[from_ns, until_ns)`.
    pub fn schedule_fault(&mut self, from_ns: u64, until_ns: u64, fault: SimFault) {
        self.fault = Some((from_ns, until_ns, fault));
    }

    /// Exact tip position (not quantised).
    pub fn true_position_m(&self) -> DVec3 {
        self.position_m
    }

    /// Exact tip velocity.
    pub fn true_velocity_m_s(&self) -> DVec3 {
        self.velocity_m_s
    }

    /// Device time in nanoseconds.
    pub fn time_ns(&self) -> u64 {
        self.time_ns
    }

    /// Work the device's force has done on the tip so far, ∫ F·v dt with the exact velocity.
    /// A passive environment does no net positive work over a contact that ends where it began
    /// out of contact.
    pub fn work_on_tip_j(&self) -> f64 {
        self.work_on_tip_j
    }

    fn quantise(&self, p: DVec3) -> DVec3 {
        let r = self.params.position_resolution_m;
        if r > 0.0 { (p / r).round() * r } else { p }
    }

    fn advance(&mut self) {
        let p = self.params;
        let steps = p.substeps.max(1);
        let period_s = p.period_ns as f64 * 1e-9;
        let h = period_s / steps as f64;
        let mass = (p.tip_mass_kg + p.hand_mass_kg).max(1e-6);
        let t0 = self.time_ns as f64 * 1e-9;
        for i in 0..steps {
            let (target, target_velocity) = self.script.target_at(t0 + i as f64 * h);
            let hand = p.hand_stiffness_n_per_m * (target - self.position_m)
                + p.hand_damping_n_s_per_m * (target_velocity - self.velocity_m_s);
            let friction = -p.device_damping_n_s_per_m * self.velocity_m_s;
            let v_before = self.velocity_m_s;
            self.velocity_m_s += (hand + friction + self.force_n) * (h / mass);
            self.position_m += self.velocity_m_s * h;
            // Trapezoid of F·v over the substep (F is held).
            self.work_on_tip_j += self.force_n.dot(v_before + self.velocity_m_s) * 0.5 * h;
        }
        self.time_ns += p.period_ns;
        let measured = self.quantise(self.position_m);
        if p.velocity_filter_hz > 0.0 && period_s > 0.0 {
            let raw = (measured - self.reported_position_m) / period_s;
            let beta = 1.0 - (-2.0 * std::f64::consts::PI * p.velocity_filter_hz * period_s).exp();
            self.reported_velocity_m_s += (raw - self.reported_velocity_m_s) * beta;
        } else {
            self.reported_velocity_m_s = self.velocity_m_s;
        }
        self.reported_position_m = measured;
    }
}

impl HapticDevice for SimulatedPhantom {
    fn limits(&self) -> DeviceLimits {
        self.params.limits
    }

    fn read(&mut self) -> Result<DeviceSample, DeviceError> {
        let mut sample = DeviceSample {
            time_ns: self.time_ns,
            tip_in_world: Pose {
                position_m: self.reported_position_m,
                orientation: self.orientation,
            },
            tip_velocity_m_s: self.reported_velocity_m_s,
            buttons: self.script.buttons_at(self.time_ns as f64 * 1e-9),
            flags: softhaptic_proto::ContactFlags::empty(),
        };
        if let Some((from, until, fault)) = self.fault
            && (from..until).contains(&self.time_ns)
        {
            match fault {
                SimFault::Error(e) => return Err(e),
                SimFault::NonFinite => sample.tip_in_world.position_m.x = f64::NAN,
            }
        }
        Ok(sample)
    }

    /// Holds `force_n` for one period and advances the simulation. The amplifiers clip at the
    /// device's peak force and output nothing for a non-finite command, as hardware would.
    fn command_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        let peak = self.params.limits.peak_force_n;
        self.force_n = if force_n.is_finite() {
            force_n.clamp_length_max(peak)
        } else {
            DVec3::ZERO
        };
        self.advance();
        Ok(())
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn script_passes_through_its_waypoints() {
        let s = HandScript::press(DVec3::new(0.0, 0.01, 0.0), DVec3::Y, 0.005);
        let (p0, v0) = s.target_at(0.0);
        assert!((p0 - DVec3::new(0.0, 0.03, 0.0)).length() < 1e-12);
        assert_eq!(v0, DVec3::ZERO);
        let (hold_start, hold_end) = s.hold_window_s();
        let (p, v) = s.target_at(0.5 * (hold_start + hold_end));
        assert!((p - DVec3::new(0.0, 0.005, 0.0)).length() < 1e-12);
        assert_eq!(v, DVec3::ZERO);
        let (held, _) = s.target_at(hold_end);
        let (slid, _) = s.target_at(hold_end + s.slide_s);
        assert!(((slid - held).length() - 0.01).abs() < 1e-12);
        assert!(
            (slid - held).dot(DVec3::Y).abs() < 1e-12,
            "the slide is tangential"
        );
        let (end, _) = s.target_at(s.duration_s() + 1.0);
        assert!((end - p0).length() < 1e-12);
    }

    #[test]
    fn script_velocity_is_the_derivative_of_its_position() {
        let mut s = HandScript::press(DVec3::ZERO, DVec3::new(0.0, 1.0, 1.0), 0.004);
        s.repeat = true;
        let h = 1e-7;
        for k in 0..70 {
            let t = k as f64 * 0.073;
            let (a, v) = s.target_at(t);
            let (b, _) = s.target_at(t + h);
            assert!(((b - a) / h - v).length() < 1e-4, "t = {t}");
        }
        // Continuous across the wrap of a repeating script.
        let (before_wrap, _) = s.target_at(s.duration_s() - 1e-9);
        let (start, _) = s.target_at(0.0);
        assert!((before_wrap - start).length() < 1e-9);
        let (once, _) = s.target_at(0.3);
        let (again, _) = s.target_at(0.3 + s.duration_s());
        assert!((once - again).length() < 1e-12);
    }

    #[test]
    fn free_hand_follows_the_script_and_is_deterministic() {
        let s = HandScript::press(DVec3::ZERO, DVec3::Y, 0.005);
        let run = || {
            let mut sim = SimulatedPhantom::new(s);
            let mut ys = Vec::new();
            for _ in 0..1500 {
                let r = sim.read().unwrap();
                ys.push(r.tip_in_world.position_m.y);
                sim.command_force(DVec3::ZERO).unwrap();
            }
            (ys, sim)
        };
        let (a, sim) = run();
        let (b, _) = run();
        assert_eq!(a, b);
        assert_eq!(sim.time_ns(), 1_500_000_000);
        // Mid-hold with no object: the tip sits at the hand's target.
        assert!((sim.true_position_m().y + 0.005).abs() < 2e-4);
        assert_eq!(sim.work_on_tip_j(), 0.0);
    }

    #[test]
    fn faults_are_produced_in_their_window_only() {
        let mut sim = SimulatedPhantom::new(HandScript::press(DVec3::ZERO, DVec3::Y, 0.0));
        sim.schedule_fault(2_000_000, 4_000_000, SimFault::Error(DeviceError::Timeout));
        let mut results = Vec::new();
        for _ in 0..5 {
            results.push(sim.read().is_ok());
            sim.command_force(DVec3::ZERO).unwrap();
        }
        assert_eq!(results, [true, true, false, false, true]);
        sim.schedule_fault(5_000_000, 6_000_000, SimFault::NonFinite);
        assert!(!sim.read().unwrap().is_finite());
    }

    #[test]
    fn commanded_force_is_clipped_and_sanitised() {
        let mut sim = SimulatedPhantom::new(HandScript::press(DVec3::ZERO, DVec3::Y, 0.0));
        sim.command_force(DVec3::Y * 100.0).unwrap();
        assert!((sim.force_n.length() - 7.9).abs() < 1e-12);
        sim.command_force(DVec3::new(f64::NAN, 0.0, 0.0)).unwrap();
        assert_eq!(sim.force_n, DVec3::ZERO);
    }
}
