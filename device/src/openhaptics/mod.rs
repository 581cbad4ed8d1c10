//! A PHANTOM / Touch through OpenHaptics' HD API (`libHD.so`), loaded at run time.
//!
//! # Layout
//! - [`hd`]: the API's codes, defined once (the test stand-in's C header is generated from it);
//! - [`ffi`]: the C types, the function table, and the library, loaded once per process and
//!   never unloaded;
//! - [`mapping`]: what the device says about itself, validated, and the mapping from its frame
//!   to the world;
//! - [`servo`]: the scheduler's start and stop, the servo callback, and the device the loop
//!   reads and commands inside it, with the faults sorted by what they mean;
//! - [`recovery`]: the thread that reconnects a lost or silent device, off the servo path;
//! - [`discovery`]: `softhaptic devices`' probe of the machine.
//!
//! # Who owns the clock
//! The HD API runs its own servo thread and allows device state to be read and force to be
//! written only inside its callbacks, between `hdBeginFrame` and `hdEndFrame` (one frame per
//! servo tick). The device hands the loop an [`HdServoClock`] ([`HapticDevice::servo_clock`]);
//! the loop's tick runs inside the servo callback, so [`HapticDevice::read`] and
//! [`HapticDevice::command_force`] of one tick fall in one frame and the force answers the
//! reading of the same servo tick (see [`crate::haptic_loop`] for the rejected alternative).
//! Only the driver's servo thread, inside the frame it opened, touches the device: a tick run on
//! any other thread (the loop's watchdog) reads nothing and sends nothing.
//!
//! # Limits
//! The device's nominal maximum force, continuous force, stiffness and damping are read when it
//! opens, checked ([`DeviceDescription::validate`]), and the tighter of them and the scene's
//! preset is used ([`tighter_limits`]); stiffness and damping are per millimetre in the HD API,
//! and a motion scale s divides the stiffness and damping the world may render (the hand feels
//! K·s).
//!
//! # Faults
//! [`servo`] sorts the driver's errors by what they mean (a lost device, warm motors, a force
//! trip, calibration, a failed tick) and [`recovery`] reconnects; both modules say how.
//!
//! [`HapticDevice::servo_clock`]: crate::device::HapticDevice::servo_clock
//! [`HapticDevice::read`]: crate::device::HapticDevice::read
//! [`HapticDevice::command_force`]: crate::device::HapticDevice::command_force

pub mod discovery;
pub mod ffi;
pub mod hd;
pub mod mapping;
pub mod recovery;
pub mod servo;

use std::ffi::CString;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use softhaptic_proto::Pose;

use crate::device::DeviceLimits;

pub use discovery::{Discovery, Probe, discover};
pub use ffi::{
    HdLibrary, INSTALL_HINT, LIBRARY_DIRS, LIBRARY_ENV, LIBRARY_FILE, library_candidates,
};
pub use hd::error_name;
pub use mapping::{
    Calibration, DeviceDescription, ReportedLimits, WorkspaceMapping, tighter_limits,
};
pub use servo::{HdServoClock, OpenHapticsDevice};

pub use crate::backend::reconnect::{
    RECONNECT_AFTER_FAILED_TICKS, RECONNECT_BACKOFF_MAX, RECONNECT_BACKOFF_MIN,
    RECONNECTED_AFTER_GOOD_TICKS,
};

/// Why the OpenHaptics device could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum OpenHapticsError {
    /// No `libHD.so` anywhere it was looked for.
    #[error(
        "the OpenHaptics HD library ({LIBRARY_FILE}) was not found; looked in:{}\n{INSTALL_HINT}",
        .tried.iter().map(|t| format!("\n  - {t}")).collect::<String>()
    )]
    NotFound {
        /// Each place looked in, with why it was not used.
        tried: Vec<String>,
    },
    /// The path in the override variable could not be loaded.
    #[error(
        "could not load the OpenHaptics HD library {} named by {LIBRARY_ENV}: {reason}; \
         point {LIBRARY_ENV} at OpenHaptics' libHD.so, or unset it to search the system",
        .path.display()
    )]
    Load { path: PathBuf, reason: String },
    /// The library loaded, but lacks a function of the HD API.
    #[error(
        "{} is not an OpenHaptics HD library: it has no symbol {symbol} (OpenHaptics 3.0 or \
         later exports it); {INSTALL_HINT}",
        .path.display()
    )]
    MissingSymbol { path: PathBuf, symbol: &'static str },
    /// `hdInitDevice` failed.
    #[error(
        "could not open the haptic device {name:?} through {}: {reason} ({code_name}); check \
         that it is plugged in and powered, that this user may open it (see the device setup \
         in docs/devices.md), and that the name is a configuration made with the vendor's setup \
         tool",
        .library.display()
    )]
    Init {
        name: String,
        library: PathBuf,
        reason: String,
        code_name: &'static str,
    },
    /// A step of the setup after the device opened failed.
    #[error("the haptic device {name:?} refused {step}: {reason} ({code_name})")]
    Setup {
        name: String,
        step: &'static str,
        reason: String,
        code_name: &'static str,
    },
    /// The device reported data the backend cannot use.
    #[error(
        "the haptic device {name:?} reported an unusable {what}: {value} ({why}); the device or \
         its driver is misconfigured: run the vendor's diagnostic tool, or reinstall the driver"
    )]
    Unusable {
        name: String,
        what: &'static str,
        value: String,
        why: &'static str,
    },
    /// The driver's servo scheduler did not start.
    #[error("{text}")]
    SchedulerStart { text: String },
}

/// How to open an OpenHaptics device.
#[derive(Debug, Clone, PartialEq)]
pub struct OpenHapticsConfig {
    /// Device configuration name (`None`: the default device).
    pub name: Option<String>,
    /// From the device frame to the world (the usable workspace is read from the device).
    pub world_from_device: Pose,
    /// World metres per metre of stylus motion.
    pub scale: f64,
    /// The scene's device preset; the tighter of it and the device's own limits applies.
    pub preset: DeviceLimits,
    /// Servo period asked of the scheduler.
    pub period_ns: u64,
    /// A tick whose force would reach the driver later than this after its servo tick began
    /// sends zero instead ([`crate::device::DeviceError::Overrun`]); one period by default.
    pub overrun_after_ns: u64,
}

impl OpenHapticsConfig {
    /// The default device, placed at the world origin with its own axes, one to one, at 1 kHz.
    pub fn new(preset: DeviceLimits) -> Self {
        Self {
            name: None,
            world_from_device: Pose::IDENTITY,
            scale: 1.0,
            preset,
            period_ns: 1_000_000,
            overrun_after_ns: 1_000_000,
        }
    }
}

impl OpenHapticsDevice {
    /// Loads the HD library (once per process), opens the device, reads and checks its
    /// description and limits (logged). The scheduler starts when the loop starts the device's
    /// clock.
    pub fn open(config: &OpenHapticsConfig) -> Result<OpenHapticsDevice, OpenHapticsError> {
        let lib = HdLibrary::load()?;
        let display_name = config
            .name
            .clone()
            .unwrap_or_else(|| "Default Device".into());
        let config_name = match &config.name {
            Some(n) => Some(
                CString::new(n.as_str()).map_err(|_| OpenHapticsError::Init {
                    name: n.clone(),
                    library: lib.path().to_path_buf(),
                    reason: "the name contains a NUL byte".into(),
                    code_name: "HD_INVALID_VALUE",
                })?,
            ),
            None => None,
        };
        let inner = Arc::new(servo::Inner::new(
            lib,
            config_name,
            display_name.clone(),
            config.period_ns,
        ));
        inner.init_device().map_err(|code| OpenHapticsError::Init {
            name: display_name.clone(),
            library: lib.path().to_path_buf(),
            reason: lib.error_text(code),
            code_name: error_name(code),
        })?;
        // Dropping `inner` on an error below disables the device again.
        let description = inner.describe(config.name.clone()).validate()?;
        let mapping = WorkspaceMapping {
            world_from_device: config.world_from_device,
            scale: config.scale,
            metres_per_unit: 1e-3,
            usable_workspace: description.usable_workspace_mm,
            max_workspace: description.max_workspace_mm,
        };
        let limits = tighter_limits(&config.preset, &description.reported_limits(), &mapping);
        tracing::info!(
            device = %display_name,
            model = %description.model,
            serial = %description.serial,
            library = %lib.path().display(),
            max_force_n = description.max_force_n,
            continuous_force_n = description.continuous_force_n,
            max_stiffness_n_per_m = description.max_stiffness_n_per_m,
            max_damping_n_s_per_m = description.max_damping_n_s_per_m,
            usable_workspace_mm = ?description.usable_workspace_mm,
            "haptic device opened"
        );
        tracing::info!(
            peak_force_n = limits.peak_force_n,
            continuous_force_n = limits.continuous_force_n,
            max_stiffness_n_per_m = limits.max_stiffness_n_per_m,
            damping_n_s_per_m = limits.damping_n_s_per_m,
            preset = config.preset.name,
            "haptic device limits in use: the tighter of the device's and the preset's"
        );
        Ok(OpenHapticsDevice::new(
            inner,
            description,
            mapping,
            limits,
            config.overrun_after_ns,
        ))
    }

    /// What the device reported when it opened.
    pub fn description(&self) -> &DeviceDescription {
        &self.description
    }

    /// The mapping from the device's frame to the world.
    pub fn mapping(&self) -> &WorkspaceMapping {
        &self.mapping
    }

    /// The library's path.
    pub fn library_path(&self) -> &Path {
        self.inner.lib.path()
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn hd_errors_sort_by_what_they_mean_for_the_force() {
        use hd::*;
        assert!(ffi::is_gone(HD_COMM_ERROR) && ffi::is_gone(HD_DEVICE_FAULT));
        assert!(ffi::is_trip(HD_EXCEEDED_MAX_FORCE) && ffi::is_trip(HD_FORCE_ERROR));
        // Warm motors are a warning, not a trip; the timer is neither a trip nor a lost device.
        assert!(!ffi::is_trip(HD_WARM_MOTORS) && !ffi::is_gone(HD_WARM_MOTORS));
        assert!(!ffi::is_gone(HD_TIMER_ERROR) && !ffi::is_trip(HD_TIMER_ERROR));
        assert_eq!(error_name(0x0302), "HD_COMM_ERROR");
    }

    #[test]
    fn a_missing_library_names_where_it_looked_and_how_to_install() {
        // The override set to a file that does not exist: only that path is tried.
        // (Environment changes are process-wide; this is the only test here that reads it.)
        // SAFETY: no other thread of this test binary reads the variable concurrently.
        unsafe { std::env::set_var(LIBRARY_ENV, "/nonexistent/dir/libHD.so") };
        let err = HdLibrary::load().err().unwrap().to_string();
        // SAFETY: as above.
        unsafe { std::env::remove_var(LIBRARY_ENV) };
        assert!(err.contains("/nonexistent/dir/libHD.so"), "{err}");
        assert!(err.contains(LIBRARY_ENV), "{err}");
        let searched = OpenHapticsError::NotFound {
            tried: vec!["/usr/lib64/libHD.so: no such file".into()],
        }
        .to_string();
        assert!(searched.contains("/usr/lib64/libHD.so") && searched.contains("install"));
    }
}
