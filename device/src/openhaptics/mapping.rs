//! What the device says about itself, checked before it is used, and the mapping from its frame
//! (millimetres, its own axes) to the world (metres).
//!
//! The device reports millimetres in its own axes (y up, z toward the user). A
//! [`WorkspaceMapping`] scales the position to metres (and by the scene's motion scale) and places
//! it with `world_from_device`; forces go back through the inverse rotation, unscaled (newtons are
//! newtons at the handle). The stylus' own +z axis (from the tip back along the handle) is the
//! tool's +y. A tip outside the usable workspace is not pinned to its edge (the force would stop
//! following the hand there): it is reported where it is, and flagged; the larger box the device
//! can reach at all bounds what is plausible.

use glam::{DQuat, DVec3};
use softhaptic_proto::Pose;

use super::OpenHapticsError;
use super::hd::{HD_CALIBRATION_AUTO, HD_CALIBRATION_ENCODER_RESET, HD_CALIBRATION_INKWELL};
use crate::device::DeviceLimits;

/// What the device says about itself when it opens.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceDescription {
    /// The configuration name asked for (`None`: the default device).
    pub name: Option<String>,
    pub model: String,
    pub vendor: String,
    pub serial: String,
    /// Nominal maximum force, N.
    pub max_force_n: f64,
    /// Nominal maximum continuous force, N.
    pub continuous_force_n: f64,
    /// Nominal maximum stiffness, N/m (the API gives N/mm).
    pub max_stiffness_n_per_m: f64,
    /// Nominal maximum damping, N·s/m (the API gives N·s/mm).
    pub max_damping_n_s_per_m: f64,
    /// Usable workspace box, device frame, millimetres: minimum and maximum corners.
    pub usable_workspace_mm: [DVec3; 2],
    /// The box the stylus can reach at all, device frame, millimetres (the usable box when the
    /// device does not report one).
    pub max_workspace_mm: [DVec3; 2],
    /// Calibration styles the device supports (`HD_CALIBRATION_*` bits).
    pub calibration_styles: u32,
}

/// Largest coordinate of a workspace box a desktop device can report, mm: beyond it a reading is
/// not a workspace but a broken driver.
pub const MAX_WORKSPACE_COORDINATE_MM: f64 = 2_000.0;

/// Smallest extent of a usable workspace box along each axis, mm.
pub const MIN_WORKSPACE_EXTENT_MM: f64 = 1.0;

/// Largest nominal force a desktop haptic device can report, N (the largest in use peak near
/// 40 N); beyond it the reading is broken.
pub const MAX_PLAUSIBLE_FORCE_N: f64 = 100.0;

/// Largest nominal stiffness, N/m, and damping, N·s/m, a desktop device can report.
pub const MAX_PLAUSIBLE_STIFFNESS_N_PER_M: f64 = 100_000.0;
pub const MAX_PLAUSIBLE_DAMPING_N_S_PER_M: f64 = 1_000.0;

impl DeviceDescription {
    /// The configuration's name for people.
    pub fn display_name(&self) -> &str {
        self.name.as_deref().unwrap_or("Default Device")
    }

    /// The calibration styles the device supports, for people.
    pub fn calibration_style_names(&self) -> Vec<&'static str> {
        [
            (HD_CALIBRATION_ENCODER_RESET, "encoder reset"),
            (HD_CALIBRATION_AUTO, "automatic"),
            (HD_CALIBRATION_INKWELL, "inkwell"),
        ]
        .into_iter()
        .filter(|(bit, _)| self.calibration_styles & bit != 0)
        .map(|(_, name)| name)
        .collect()
    }

    /// Checks what the device reported before anything relies on it: a workspace box that is not
    /// finite, is empty or absurd, or a limit that is not a finite, plausible, non-negative
    /// number refuses the device, naming the value. A limit of zero means "not reported" (the
    /// preset's applies); a maximum box of zeros too (the usable box bounds the reach).
    pub fn validate(mut self) -> Result<DeviceDescription, OpenHapticsError> {
        let name = self.display_name().to_owned();
        let unusable =
            |what: &'static str, value: String, why: &'static str| OpenHapticsError::Unusable {
                name: name.clone(),
                what,
                value,
                why,
            };
        let check_box = |b: [DVec3; 2]| -> Result<(), &'static str> {
            let [lo, hi] = b;
            if !(lo.is_finite() && hi.is_finite()) {
                return Err("not a finite box");
            }
            if lo.abs().max_element() > MAX_WORKSPACE_COORDINATE_MM
                || hi.abs().max_element() > MAX_WORKSPACE_COORDINATE_MM
            {
                return Err("a corner beyond 2 m: not a desktop device's workspace");
            }
            if (hi - lo).min_element() < MIN_WORKSPACE_EXTENT_MM {
                return Err("empty: each maximum must exceed its minimum by at least 1 mm");
            }
            Ok(())
        };
        let show =
            |b: [DVec3; 2]| format!("min {:?} max {:?} mm", b[0].to_array(), b[1].to_array());
        if let Err(why) = check_box(self.usable_workspace_mm) {
            return Err(unusable(
                "usable workspace (HD_USABLE_WORKSPACE_DIMENSIONS)",
                show(self.usable_workspace_mm),
                why,
            ));
        }
        let max = self.max_workspace_mm;
        if max[0] == DVec3::ZERO && max[1] == DVec3::ZERO {
            self.max_workspace_mm = self.usable_workspace_mm;
        } else if let Err(why) = check_box(max) {
            return Err(unusable(
                "maximum workspace (HD_MAX_WORKSPACE_DIMENSIONS)",
                show(max),
                why,
            ));
        } else {
            // The reach covers the usable box whatever the device says of the larger one.
            let [ulo, uhi] = self.usable_workspace_mm;
            self.max_workspace_mm = [max[0].min(ulo), max[1].max(uhi)];
        }
        let limits = [
            (
                "nominal maximum force (HD_NOMINAL_MAX_FORCE)",
                self.max_force_n,
                MAX_PLAUSIBLE_FORCE_N,
                "N",
            ),
            (
                "nominal continuous force (HD_NOMINAL_MAX_CONTINUOUS_FORCE)",
                self.continuous_force_n,
                MAX_PLAUSIBLE_FORCE_N,
                "N",
            ),
            (
                "nominal maximum stiffness (HD_NOMINAL_MAX_STIFFNESS)",
                self.max_stiffness_n_per_m,
                MAX_PLAUSIBLE_STIFFNESS_N_PER_M,
                "N/m",
            ),
            (
                "nominal maximum damping (HD_NOMINAL_MAX_DAMPING)",
                self.max_damping_n_s_per_m,
                MAX_PLAUSIBLE_DAMPING_N_S_PER_M,
                "N·s/m",
            ),
        ];
        for (what, value, most, unit) in limits {
            if !value.is_finite() || value < 0.0 {
                return Err(unusable(
                    what,
                    format!("{value} {unit}"),
                    "not a finite, non-negative number",
                ));
            }
            if value > most {
                return Err(unusable(
                    what,
                    format!("{value} {unit}"),
                    "beyond what a desktop haptic device renders",
                ));
            }
        }
        if self.max_force_n > 0.0 && self.continuous_force_n > self.max_force_n {
            return Err(unusable(
                "nominal continuous force (HD_NOMINAL_MAX_CONTINUOUS_FORCE)",
                format!(
                    "{} N (the maximum is {} N)",
                    self.continuous_force_n, self.max_force_n
                ),
                "above the device's maximum force",
            ));
        }
        Ok(self)
    }
}

/// Calibration state of a device.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Calibration {
    Ok,
    /// The driver can update it by itself (auto or inkwell style).
    NeedsUpdate,
    /// The operator must act: put the stylus in its inkwell, or hold it at the reset position.
    NeedsManualInput,
}

/// From the device's frame (millimetres, its own axes) to the world (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorkspaceMapping {
    /// Where the device's origin and axes are in the world.
    pub world_from_device: Pose,
    /// World metres per metre of stylus motion (1: one to one).
    pub scale: f64,
    /// The device's usable workspace, device frame, millimetres (minimum and maximum corners):
    /// a tip outside it is flagged.
    pub usable_workspace_mm: [DVec3; 2],
    /// The box the stylus can reach at all, device frame, millimetres: the reach that bounds a
    /// plausible reading.
    pub max_workspace_mm: [DVec3; 2],
}

impl WorkspaceMapping {
    /// Rotation from the stylus frame (its +z from the tip back along the handle) to the tool
    /// frame (+y up the shaft): a quarter turn about x.
    fn tool_from_stylus() -> DQuat {
        DQuat::from_rotation_x(std::f64::consts::FRAC_PI_2)
    }

    /// The tip's position in the world for a device position in millimetres (not clamped).
    pub fn position_m(&self, device_mm: DVec3) -> DVec3 {
        self.world_from_device
            .transform_point(device_mm * (1e-3 * self.scale))
    }

    /// Whether a device position lies outside the usable workspace.
    pub fn outside_usable(&self, device_mm: DVec3) -> bool {
        let [lo, hi] = self.usable_workspace_mm;
        device_mm.cmplt(lo.min(hi)).any() || device_mm.cmpgt(hi.max(lo)).any()
    }

    /// The tip's world velocity for a device velocity in mm/s.
    pub fn velocity_m_s(&self, device_mm_s: DVec3) -> DVec3 {
        self.world_from_device.orientation * (device_mm_s * (1e-3 * self.scale))
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
        let [lo, hi] = self.max_workspace_mm;
        let corner_mm = lo.abs().max(hi.abs());
        self.world_from_device.position_m.length() + corner_mm.length() * 1e-3 * self.scale
    }
}

/// The tighter of the scene's preset and what the device reports, in the world's terms:
/// stiffness and damping divided by the motion scale (the hand feels K·s).
pub fn tighter_limits(
    preset: &DeviceLimits,
    device: &DeviceDescription,
    mapping: &WorkspaceMapping,
) -> DeviceLimits {
    // A zero reading means the device did not report it ([`DeviceDescription::validate`]
    // refused every other unusable one).
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
            usable_workspace_mm: [DVec3::splat(-80.0), DVec3::splat(80.0)],
            max_workspace_mm: [DVec3::splat(-100.0), DVec3::splat(100.0)],
        }
    }

    fn desktop() -> DeviceDescription {
        DeviceDescription {
            name: None,
            model: "PHANTOM Desktop".into(),
            vendor: String::new(),
            serial: String::new(),
            max_force_n: 7.9,
            continuous_force_n: 0.5,
            max_stiffness_n_per_m: 1860.0,
            max_damping_n_s_per_m: 0.0,
            usable_workspace_mm: [DVec3::splat(-80.0), DVec3::splat(80.0)],
            max_workspace_mm: [DVec3::splat(-100.0), DVec3::splat(100.0)],
            calibration_styles: 4,
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
        let m = mapping();
        let plain = WorkspaceMapping {
            world_from_device: Pose::IDENTITY,
            ..m
        };
        // Stylus at rest: its +z (tip back toward the user) is the tool's +y.
        let q = plain.orientation(DQuat::IDENTITY);
        assert!((q * DVec3::Y - DVec3::Z).length() < 1e-12);
    }

    #[test]
    fn the_tighter_limit_wins_in_world_terms() {
        let device = desktop();
        let mut m = mapping();
        m.scale = 1.0;
        let l = tighter_limits(&DeviceLimits::TOUCH, &device, &m);
        assert_eq!(l.peak_force_n, 3.3);
        assert_eq!(l.continuous_force_n, 0.5);
        assert_eq!(l.max_stiffness_n_per_m, 400.0);
        // Not reported: the preset's.
        assert_eq!(l.damping_n_s_per_m, 2.0);
        m.scale = 2.0;
        let scaled = tighter_limits(&DeviceLimits::TOUCH, &device, &m);
        assert_eq!(scaled.max_stiffness_n_per_m, 200.0);
        assert_eq!(scaled.damping_n_s_per_m, 1.0);
    }

    #[test]
    fn unusable_device_data_are_refused_naming_the_value() {
        let err = |d: DeviceDescription| d.validate().err().unwrap().to_string();
        let mut zero = desktop();
        zero.usable_workspace_mm = [DVec3::ZERO, DVec3::ZERO];
        let e = err(zero);
        assert!(
            e.contains("HD_USABLE_WORKSPACE_DIMENSIONS") && e.contains("empty"),
            "{e}"
        );
        let mut nan = desktop();
        nan.usable_workspace_mm[1].y = f64::NAN;
        assert!(err(nan).contains("NaN"));
        let mut force = desktop();
        force.max_force_n = -3.0;
        let e = err(force);
        assert!(
            e.contains("HD_NOMINAL_MAX_FORCE") && e.contains("-3 N"),
            "{e}"
        );
        let mut huge = desktop();
        huge.max_stiffness_n_per_m = 1e9;
        assert!(err(huge).contains("HD_NOMINAL_MAX_STIFFNESS"));
        let mut hot = desktop();
        hot.continuous_force_n = 9.0;
        assert!(err(hot).contains("above the device's maximum force"));
        // A maximum box of zeros is "not reported": the usable box bounds the reach.
        let mut no_max = desktop();
        no_max.max_workspace_mm = [DVec3::ZERO, DVec3::ZERO];
        let ok = no_max.validate().unwrap();
        assert_eq!(ok.max_workspace_mm, ok.usable_workspace_mm);
    }
}
