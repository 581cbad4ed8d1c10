//! Rate control: the puck's deflection as the tool's velocity.
//!
//! A SpaceMouse springs back to centre, so its deflection commands a velocity, not a position
//! (docs/devices.md). Each tick [`RateControl::step`] shapes the deflection (dead band, then gain,
//! then the speed limit), lets the velocity follow that target through a first-order filter of
//! time constant `smoothing_s` (the ~60 Hz reports arrive as steps; the filter turns each into
//! a ramp the 1 kHz loop samples smoothly), integrates the position and holds it inside the
//! scene's workspace box. A velocity step between two ticks is therefore at most
//! `(1 − e^(−dt/τ))` times the distance to the target, never the target itself: the bound
//! [`RateControl::max_velocity_step_m_s`] gives it.
//!
//! The puck's frame: the HID's axes (x right, y towards the user, z down) turned so that y is up
//! and z towards the user (pushing the puck down moves the tool down, pulling it moves the tool
//! towards the user); `world_from_puck` then places that frame in the world.

use glam::{DQuat, DVec3};
use softhaptic_proto::Pose;

use super::report::Axes;

/// How the puck drives the tool.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RateConfig {
    /// Deflection (fraction of full scale) below which an axis commands nothing: the puck never
    /// rests exactly at zero.
    pub dead_band: f64,
    /// Tool speed at full deflection of one axis, m/s.
    pub gain_m_s: f64,
    /// Largest tool speed, m/s, whatever the deflection.
    pub max_speed_m_s: f64,
    /// Time constant of the velocity's first-order filter, s (0: no smoothing).
    pub smoothing_s: f64,
    /// The box the tool tip stays in, world frame.
    pub workspace_min_m: DVec3,
    pub workspace_max_m: DVec3,
    /// Where the tool starts and where a reset puts it (above the press site).
    pub home_in_world: Pose,
    /// Whether the puck's twist turns the tool (off for a sphere, whose force does not depend on
    /// its orientation).
    pub rotation: bool,
    /// Turn rate at full twist, rad/s.
    pub angular_gain_rad_s: f64,
    /// The puck frame's orientation in the world.
    pub world_from_puck: DQuat,
    /// Buttons whose press puts the tool back at home (bit 0 the first button).
    pub reset_buttons: u32,
}

impl RateConfig {
    /// Defaults for a tool starting at `home_in_world` inside the box `[min, max]`: 10 % dead
    /// band, 50 mm/s at full deflection and at most, 40 ms smoothing, no rotation, the first
    /// button resets.
    pub fn new(home_in_world: Pose, workspace_min_m: DVec3, workspace_max_m: DVec3) -> Self {
        Self {
            dead_band: 0.1,
            gain_m_s: 0.05,
            max_speed_m_s: 0.05,
            smoothing_s: 0.04,
            workspace_min_m,
            workspace_max_m,
            home_in_world,
            rotation: false,
            angular_gain_rad_s: 1.0,
            world_from_puck: DQuat::IDENTITY,
            reset_buttons: 1,
        }
    }

    /// What is wrong with the configuration, in words naming the field; `None` when it is usable.
    pub fn problem(&self) -> Option<String> {
        let finite = |v: f64| v.is_finite();
        if !(0.0..1.0).contains(&self.dead_band) {
            return Some(format!(
                "dead_band must be in [0, 1), got {}",
                self.dead_band
            ));
        }
        for (name, v) in [
            ("gain_m_s", self.gain_m_s),
            ("max_speed_m_s", self.max_speed_m_s),
            ("angular_gain_rad_s", self.angular_gain_rad_s),
        ] {
            if !(finite(v) && v > 0.0) {
                return Some(format!("{name} must be > 0, got {v}"));
            }
        }
        if !(finite(self.smoothing_s) && self.smoothing_s >= 0.0) {
            return Some(format!("smoothing_s must be ≥ 0, got {}", self.smoothing_s));
        }
        let (lo, hi) = (self.workspace_min_m, self.workspace_max_m);
        if !(lo.is_finite() && hi.is_finite() && lo.cmplt(hi).all()) {
            return Some(format!(
                "the workspace box needs min < max on every axis, got min {lo} max {hi}"
            ));
        }
        let home = self.home_in_world.position_m;
        if !(home.cmpge(lo).all() && home.cmple(hi).all()) {
            return Some(format!(
                "the home position {home} is outside the workspace box {lo} … {hi}"
            ));
        }
        None
    }
}

/// The puck frame (x right, y up, z towards the user) from the HID's (x right, y towards the
/// user, z down): a proper rotation, so it maps rotation vectors as it maps vectors.
fn puck_from_hid(v: [f64; 3]) -> DVec3 {
    DVec3::new(v[0], -v[2], v[1])
}

/// Dead band then rescale, so that the command starts from zero at the band's edge.
fn shaped(x: f64, dead_band: f64) -> f64 {
    let m = (x.abs() - dead_band).max(0.0) / (1.0 - dead_band);
    m.copysign(x)
}

fn shaped_vec(v: DVec3, dead_band: f64) -> DVec3 {
    DVec3::new(
        shaped(v.x, dead_band),
        shaped(v.y, dead_band),
        shaped(v.z, dead_band),
    )
}

/// The tool driven by the puck: its pose and velocity, integrated tick by tick.
#[derive(Debug, Clone)]
pub struct RateControl {
    config: RateConfig,
    pose: Pose,
    velocity_m_s: DVec3,
    angular_velocity_rad_s: DVec3,
    buttons: u32,
}

impl RateControl {
    pub fn new(config: RateConfig) -> Self {
        Self {
            pose: config.home_in_world,
            config,
            velocity_m_s: DVec3::ZERO,
            angular_velocity_rad_s: DVec3::ZERO,
            buttons: 0,
        }
    }

    pub fn config(&self) -> &RateConfig {
        &self.config
    }

    pub fn pose(&self) -> Pose {
        self.pose
    }

    pub fn velocity_m_s(&self) -> DVec3 {
        self.velocity_m_s
    }

    /// The target velocity, world frame, that a deflection commands.
    pub fn target_velocity_m_s(&self, axes: &Axes) -> DVec3 {
        let c = &self.config;
        let v = shaped_vec(puck_from_hid(axes.translation), c.dead_band) * c.gain_m_s;
        c.world_from_puck * v.clamp_length_max(c.max_speed_m_s)
    }

    /// The largest change of velocity one step of `dt_s` can make (the filter's share of the
    /// largest possible distance to the target, twice the speed limit).
    pub fn max_velocity_step_m_s(&self, dt_s: f64) -> f64 {
        2.0 * self.config.max_speed_m_s * self.filter_share(dt_s)
    }

    fn filter_share(&self, dt_s: f64) -> f64 {
        if self.config.smoothing_s > 0.0 {
            1.0 - (-dt_s / self.config.smoothing_s).exp()
        } else {
            1.0
        }
    }

    /// One tick of `dt_s` seconds with the puck at `axes` and `buttons` pressed. `live` is false
    /// when the reports have stopped (the device is silent or gone): the target is then zero and
    /// the tool comes to rest. Never allocates.
    pub fn step(&mut self, dt_s: f64, axes: &Axes, buttons: u32, live: bool) {
        let dt_s = if dt_s.is_finite() { dt_s.max(0.0) } else { 0.0 };
        let pressed = buttons & !self.buttons & self.config.reset_buttons;
        self.buttons = buttons;
        if pressed != 0 {
            self.reset();
            return;
        }
        let share = self.filter_share(dt_s);
        let target = if live {
            self.target_velocity_m_s(axes)
        } else {
            DVec3::ZERO
        };
        self.velocity_m_s += (target - self.velocity_m_s) * share;

        let c = self.config;
        let unclamped = self.pose.position_m + self.velocity_m_s * dt_s;
        let position = unclamped.clamp(c.workspace_min_m, c.workspace_max_m);
        // Against a face of the box the tool stops on that axis: the velocity says what the
        // tool does, and the damping must not push back against a motion that is not happening.
        let held = position.cmpne(unclamped);
        self.velocity_m_s = DVec3::select(held, DVec3::ZERO, self.velocity_m_s);
        self.pose.position_m = position;

        if c.rotation {
            let target = if live {
                let w =
                    shaped_vec(puck_from_hid(axes.rotation), c.dead_band) * c.angular_gain_rad_s;
                c.world_from_puck * w
            } else {
                DVec3::ZERO
            };
            self.angular_velocity_rad_s += (target - self.angular_velocity_rad_s) * share;
            let turn = DQuat::from_scaled_axis(self.angular_velocity_rad_s * dt_s);
            self.pose.orientation = (turn * self.pose.orientation).normalize();
        }
    }

    /// Puts the tool at home, at rest.
    pub fn reset(&mut self) {
        self.pose = self.config.home_in_world;
        self.velocity_m_s = DVec3::ZERO;
        self.angular_velocity_rad_s = DVec3::ZERO;
    }

    /// Stops the tool where it is (an unplugged device: the tool holds still, and a replug
    /// starts it from rest).
    pub fn hold(&mut self) {
        self.velocity_m_s = DVec3::ZERO;
        self.angular_velocity_rad_s = DVec3::ZERO;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn control() -> RateControl {
        RateControl::new(RateConfig::new(
            Pose::from_position(DVec3::new(0.0, 0.05, 0.0)),
            DVec3::splat(-0.1),
            DVec3::splat(0.1),
        ))
    }

    fn push(translation: [f64; 3]) -> Axes {
        Axes {
            translation,
            rotation: [0.0; 3],
        }
    }

    #[test]
    fn axes_map_to_the_world_with_their_signs() {
        let c = control();
        let v = |t| c.target_velocity_m_s(&push(t));
        assert!(v([1.0, 0.0, 0.0]).abs_diff_eq(DVec3::X * 0.05, 1e-12));
        // Pushing the puck down (+z in the HID) moves the tool down.
        assert!(v([0.0, 0.0, 1.0]).abs_diff_eq(-DVec3::Y * 0.05, 1e-12));
        // Pulling it towards the user (+y in the HID) moves the tool towards the user.
        assert!(v([0.0, 1.0, 0.0]).abs_diff_eq(DVec3::Z * 0.05, 1e-12));
        assert!(v([-1.0, 0.0, 0.0]).abs_diff_eq(-DVec3::X * 0.05, 1e-12));
    }

    #[test]
    fn dead_band_commands_nothing_and_the_speed_is_limited() {
        let mut c = control();
        assert_eq!(
            c.target_velocity_m_s(&push([0.09, -0.05, 0.1])),
            DVec3::ZERO
        );
        // Just past the band the command starts from zero, not from the band's value.
        let just = c.target_velocity_m_s(&push([0.1 + 0.9e-3, 0.0, 0.0]));
        assert!((just.x - 0.05e-3).abs() < 1e-12, "{just}");
        // All three axes at full deflection: √3 × gain is limited to the speed limit.
        let all = c.target_velocity_m_s(&push([1.0, 1.0, 1.0]));
        assert!((all.length() - 0.05).abs() < 1e-12);
        c.step(0.001, &push([0.05, 0.0, 0.0]), 0, true);
        assert_eq!(c.pose().position_m, DVec3::new(0.0, 0.05, 0.0));
    }

    #[test]
    fn a_held_deflection_reaches_its_speed_with_the_filters_lag_and_no_step() {
        let mut c = control();
        let dt = 0.001;
        let mut previous = DVec3::ZERO;
        let mut t = 0.0;
        let mut time_to_63 = None;
        for _ in 0..400 {
            c.step(dt, &push([1.0, 0.0, 0.0]), 0, true);
            t += dt;
            let v = c.velocity_m_s();
            assert!((v - previous).length() <= c.max_velocity_step_m_s(dt) + 1e-15);
            if time_to_63.is_none() && v.x >= 0.05 * (1.0 - (-1.0f64).exp()) {
                time_to_63 = Some(t);
            }
            previous = v;
        }
        // The first-order filter's rise to 63 % takes one time constant.
        let lag = time_to_63.expect("reached");
        assert!((lag - 0.04).abs() <= 0.0011, "{lag}");
        assert!((c.velocity_m_s().x - 0.05).abs() < 1e-5);
    }

    #[test]
    fn the_box_holds_the_tool_and_stops_it_on_that_axis() {
        let mut c = control();
        for _ in 0..10_000 {
            c.step(0.001, &push([1.0, 0.0, -1.0]), 0, true);
            let p = c.pose().position_m;
            assert!(p.cmple(DVec3::splat(0.1)).all() && p.cmpge(DVec3::splat(-0.1)).all());
        }
        assert_eq!(c.pose().position_m.x, 0.1);
        assert_eq!(c.pose().position_m.y, 0.1);
        assert_eq!(c.velocity_m_s(), DVec3::ZERO);
    }

    #[test]
    fn silence_brings_the_tool_to_rest_and_a_button_sends_it_home() {
        let mut c = control();
        for _ in 0..200 {
            c.step(0.001, &push([0.0, 0.0, 1.0]), 0, true);
        }
        let moving = c.velocity_m_s().length();
        assert!(moving > 0.04);
        for _ in 0..400 {
            c.step(0.001, &push([0.0, 0.0, 1.0]), 0, false);
        }
        assert!(c.velocity_m_s().length() < moving * 1e-4);
        let rest = c.pose();
        assert!(rest.position_m.y < 0.05 - 0.005);
        // Held: the button still down does not reset again; its press does, once.
        c.step(0.001, &push([0.0; 3]), 1, true);
        assert_eq!(c.pose(), c.config().home_in_world);
        c.step(0.001, &push([1.0, 0.0, 0.0]), 1, true);
        assert_ne!(c.pose(), c.config().home_in_world);
    }

    #[test]
    fn rotation_turns_the_tool_only_when_enabled() {
        let twist = Axes {
            translation: [0.0; 3],
            rotation: [0.0, 0.0, -1.0],
        };
        let mut off = control();
        off.step(0.01, &twist, 0, true);
        assert_eq!(off.pose().orientation, DQuat::IDENTITY);
        let mut config = *control().config();
        config.rotation = true;
        config.smoothing_s = 0.0;
        let mut on = RateControl::new(config);
        on.step(0.01, &twist, 0, true);
        // The HID's −rz is a twist about the puck's +y (up): 1 rad/s for 10 ms.
        let (axis, angle) = on.pose().orientation.to_axis_angle();
        assert!(axis.abs_diff_eq(DVec3::Y, 1e-9) && (angle - 0.01).abs() < 1e-12);
    }

    #[test]
    fn configuration_problems_name_the_field() {
        let good = *control().config();
        assert_eq!(good.problem(), None);
        let mut bad = good;
        bad.dead_band = 1.0;
        assert!(bad.problem().expect("refused").contains("dead_band"));
        let mut bad = good;
        bad.gain_m_s = f64::NAN;
        assert!(bad.problem().expect("refused").contains("gain_m_s"));
        let mut bad = good;
        bad.workspace_max_m.y = -0.2;
        assert!(bad.problem().expect("refused").contains("min < max"));
        let mut bad = good;
        bad.home_in_world.position_m.x = 0.5;
        assert!(bad.problem().expect("refused").contains("home"));
    }
}
