//! From a device's frame (its own units and axes) to the world (metres), and the limits a
//! device runs with: the same for every vendor's backend.
//!
//! A [`WorkspaceMapping`] scales a device position to metres (`metres_per_unit`: 1e-3 for a
//! library that reports millimetres, 1 for one that reports metres) and by the scene's motion
//! scale, and places it with `world_from_device`; forces go back through the inverse rotation,
//! unscaled (newtons are newtons at the handle). A tip outside the usable workspace is not
//! pinned to its edge (the force would stop following the hand there): it is reported where it
//! is, and flagged; the larger box the device can reach at all bounds what is plausible.

use glam::{DQuat, DVec3};
use softhaptic_proto::Pose;

use crate::device::DeviceLimits;

/// From the device's frame (its units, its own axes) to the world (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorkspaceMapping {
    /// Where the device's origin and axes are in the world.
    pub world_from_device: Pose,
    /// World metres per metre of stylus motion (1: one to one).
    pub scale: f64,
    /// Metres per unit of the device's positions and velocities (1e-3 for millimetres).
    pub metres_per_unit: f64,
    /// The device's usable workspace, device frame and units (minimum and maximum corners): a
    /// tip outside it is flagged.
    pub usable_workspace: [DVec3; 2],
    /// The box the stylus can reach at all, device frame and units: the reach that bounds a
    /// plausible reading.
    pub max_workspace: [DVec3; 2],
}

impl WorkspaceMapping {
    /// Rotation from the stylus frame (its +z from the tip back along the handle) to the tool
    /// frame (+y up the shaft): a quarter turn about x.
    fn tool_from_stylus() -> DQuat {
        DQuat::from_rotation_x(std::f64::consts::FRAC_PI_2)
    }

    /// The tip's position in the world for a device position in device units (not clamped).
    pub fn position_m(&self, device: DVec3) -> DVec3 {
        self.world_from_device
            .transform_point(device * (self.metres_per_unit * self.scale))
    }

    /// Whether a device position lies outside the usable workspace.
    pub fn outside_usable(&self, device: DVec3) -> bool {
        let [lo, hi] = self.usable_workspace;
        device.cmplt(lo.min(hi)).any() || device.cmpgt(hi.max(lo)).any()
    }

    /// The tip's world velocity for a device velocity in device units per second.
    pub fn velocity_m_s(&self, device_per_s: DVec3) -> DVec3 {
        self.world_from_device.orientation * (device_per_s * (self.metres_per_unit * self.scale))
    }

    /// The tool's world orientation for the stylus' rotation in the device frame.
    pub fn orientation(&self, device_rotation: DQuat) -> DQuat {
        (self.world_from_device.orientation * device_rotation * Self::tool_from_stylus())
            .normalize()
    }

    /// A world force in the device's axes (newtons, unscaled).
    pub fn force_device_n(&self, world_n: DVec3) -> DVec3 {
        self.world_from_device.orientation.inverse() * world_n
    }

    /// The radius around the world origin within which this device can put the tip (the
    /// plausibility check of [`crate::world::HapticWorld`] measures from the world origin): the
    /// farthest corner of the box the stylus can reach.
    pub fn reach_m(&self) -> f64 {
        let [lo, hi] = self.max_workspace;
        let corner = lo.abs().max(hi.abs());
        self.world_from_device.position_m.length()
            + corner.length() * self.metres_per_unit * self.scale
    }
}

/// What a device says (or its type implies) of its own limits, in SI units; zero where it says
/// nothing (the preset's applies).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ReportedLimits {
    pub max_force_n: f64,
    pub continuous_force_n: f64,
    pub max_stiffness_n_per_m: f64,
    pub max_damping_n_s_per_m: f64,
}

/// The tighter of the scene's preset and what the device reports, in the world's terms:
/// stiffness and damping divided by the motion scale (the hand feels K·s).
pub fn tighter_limits(
    preset: &DeviceLimits,
    device: &ReportedLimits,
    mapping: &WorkspaceMapping,
) -> DeviceLimits {
    // A zero reading means the device did not report it (each backend refuses every other
    // unusable one before this).
    let tighter = |preset: f64, read: f64| {
        if read.is_finite() && read > 0.0 {
            preset.min(read)
        } else {
            preset
        }
    };
    let scale = if mapping.scale.is_finite() && mapping.scale > 0.0 {
        mapping.scale
    } else {
        1.0
    };
    DeviceLimits {
        name: preset.name,
        peak_force_n: tighter(preset.peak_force_n, device.max_force_n),
        continuous_force_n: tighter(preset.continuous_force_n, device.continuous_force_n),
        thermal_time_constant_s: preset.thermal_time_constant_s,
        max_stiffness_n_per_m: tighter(preset.max_stiffness_n_per_m, device.max_stiffness_n_per_m)
            / scale,
        damping_n_s_per_m: tighter(preset.damping_n_s_per_m, device.max_damping_n_s_per_m) / scale,
        workspace_radius_m: mapping.reach_m(),
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    fn mapping() -> WorkspaceMapping {
        WorkspaceMapping {
            world_from_device: Pose {
                position_m: DVec3::new(0.0, 0.1, 0.0),
                orientation: DQuat::from_rotation_y(std::f64::consts::FRAC_PI_2),
            },
            scale: 2.0,
            metres_per_unit: 1e-3,
            usable_workspace: [DVec3::splat(-80.0), DVec3::splat(80.0)],
            max_workspace: [DVec3::splat(-100.0), DVec3::splat(100.0)],
        }
    }

    fn reported() -> ReportedLimits {
        ReportedLimits {
            max_force_n: 7.9,
            continuous_force_n: 0.5,
            max_stiffness_n_per_m: 1860.0,
            max_damping_n_s_per_m: 0.0,
        }
    }

    #[test]
    fn device_millimetres_map_to_world_metres_and_back() {
        let m = mapping();
        // 10 mm along device x, doubled, turned a quarter about y (x → −z), raised 0.1 m.
        let p = m.position_m(DVec3::new(10.0, 0.0, 0.0));
        assert!((p - DVec3::new(0.0, 0.1, -0.02)).length() < 1e-12, "{p}");
        let v = m.velocity_m_s(DVec3::new(0.0, 100.0, 0.0));
        assert!((v - DVec3::new(0.0, 0.2, 0.0)).length() < 1e-12, "{v}");
        // Forces turn back, unscaled.
        let f = m.force_device_n(DVec3::new(0.0, 0.0, -1.5));
        assert!((f - DVec3::new(1.5, 0.0, 0.0)).length() < 1e-12, "{f}");
    }

    #[test]
    fn a_device_in_metres_maps_one_to_one() {
        let m = WorkspaceMapping {
            metres_per_unit: 1.0,
            scale: 1.0,
            usable_workspace: [DVec3::splat(-0.04), DVec3::splat(0.04)],
            max_workspace: [DVec3::splat(-0.06), DVec3::splat(0.06)],
            ..mapping()
        };
        let p = m.position_m(DVec3::new(0.01, 0.0, 0.0));
        assert!((p - DVec3::new(0.0, 0.1, -0.01)).length() < 1e-12, "{p}");
        assert!(m.outside_usable(DVec3::new(0.05, 0.0, 0.0)));
        assert!((m.reach_m() - (0.1 + 0.06 * 3f64.sqrt())).abs() < 1e-12);
    }

    #[test]
    fn a_tip_outside_the_usable_box_is_flagged_where_it_is_not_pinned() {
        let mut m = mapping();
        m.world_from_device = Pose::IDENTITY;
        m.scale = 1.0;
        let outside = DVec3::new(90.0, -61.0, 10.0);
        assert!(m.outside_usable(outside));
        assert!(!m.outside_usable(DVec3::new(10.0, -10.0, 0.0)));
        let p = m.position_m(outside);
        assert!((p - DVec3::new(0.09, -0.061, 0.01)).length() < 1e-12, "{p}");
        // The reach is the maximum box's corner, not the usable one's.
        assert!((m.reach_m() - 0.1 * 3f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn the_stylus_axis_is_the_tool_shaft() {
        let plain = WorkspaceMapping {
            world_from_device: Pose::IDENTITY,
            ..mapping()
        };
        // Stylus at rest: its +z (tip back toward the user) is the tool's +y.
        let q = plain.orientation(DQuat::IDENTITY);
        assert!((q * DVec3::Y - DVec3::Z).length() < 1e-12);
    }

    #[test]
    fn the_tighter_limit_wins_in_world_terms() {
        let mut m = mapping();
        m.scale = 1.0;
        let l = tighter_limits(&DeviceLimits::TOUCH, &reported(), &m);
        assert_eq!(l.peak_force_n, 3.3);
        assert_eq!(l.continuous_force_n, 0.5);
        assert_eq!(l.max_stiffness_n_per_m, 400.0);
        // Not reported: the preset's.
        assert_eq!(l.damping_n_s_per_m, 2.0);
        m.scale = 2.0;
        let scaled = tighter_limits(&DeviceLimits::TOUCH, &reported(), &m);
        assert_eq!(scaled.max_stiffness_n_per_m, 200.0);
        assert_eq!(scaled.damping_n_s_per_m, 1.0);
    }
}
