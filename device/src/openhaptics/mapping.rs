//! What the device says about itself, checked before it is used.
//!
//! The device reports millimetres in its own axes (y up, z toward the user); the mapping into
//! the world ([`WorkspaceMapping`], `metres_per_unit` 1e-3) and the tighter of its limits and the
//! preset's ([`tighter_limits`]) are shared with the other vendors' backends
//! ([`crate::backend::mapping`]).

use glam::DVec3;

use super::OpenHapticsError;
use super::hd::{HD_CALIBRATION_AUTO, HD_CALIBRATION_ENCODER_RESET, HD_CALIBRATION_INKWELL};
pub use crate::backend::mapping::{ReportedLimits, WorkspaceMapping, tighter_limits};

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

    /// The limits the device reported, in SI units.
    pub fn reported_limits(&self) -> ReportedLimits {
        ReportedLimits {
            max_force_n: self.max_force_n,
            continuous_force_n: self.continuous_force_n,
            max_stiffness_n_per_m: self.max_stiffness_n_per_m,
            max_damping_n_s_per_m: self.max_damping_n_s_per_m,
        }
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

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

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
