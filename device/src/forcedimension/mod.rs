//! A Force Dimension device (omega.3, delta.3, sigma.7, and the Novint Falcon, which the same
//! SDK drives) through the SDK's `libdhd.so`, loaded at run time.
//!
//! # Layout
//! - [`dhd`]: the SDK's codes, defined once (the test stand-in's C header is generated from it);
//! - [`ffi`]: the function table and the library, found and loaded by the rules every backend
//!   shares ([`crate::backend::library`]);
//! - [`link`]: the connection: opening and setting up the device, its hand-over between the
//!   loop and the reconnection thread, and that thread;
//! - [`device`]: [`ForceDimensionDevice`], what the loop reads and commands each tick;
//! - [`discovery`]: `softhaptic devices`' probe of the machine.
//!
//! # Who owns the clock
//! Unlike OpenHaptics, this SDK runs no servo thread of its own: the caller reads and commands
//! the device when it wants, and the device renders force only while commands keep coming. So
//! the loop's own 1 kHz thread (and its standby) clocks the device: each tick reads the position
//! and velocity and sends the force ([`crate::haptic_loop`]). The SDK's watchdog is set so that
//! a loop that stops sending (a stalled or killed process) stops the motors within
//! [`WATCHDOG_S`].
//!
//! # Units and limits
//! The SDK speaks SI: metres, metres per second, newtons; the shared [`WorkspaceMapping`] maps
//! with `metres_per_unit` 1. The SDK says which device it is (`dhdGetSystemType`), not its
//! limits; the limits and workspace of the type ([`type_limits`]) and the scene's preset are
//! combined as for every backend, the tighter of each ([`tighter_limits`]).
//!
//! # Faults
//! A negative return is an error (the SDK's positive [`dhd::DHD_TIMEGUARD`] and
//! [`dhd::DHD_MOTOR_SATURATED`] are not), read on the thread that made the call. A device
//! that cannot be reached gives zero force and the `device_fault` flag on each tick; after
//! [`RECONNECT_AFTER_FAILED_TICKS`](crate::backend::reconnect::RECONNECT_AFTER_FAILED_TICKS) of them in a row the loop hands the device to the
//! reconnection thread ([`link`]), which reopens it off the loop with the shared backoff; the
//! world ramps the force back in afterwards.

pub mod device;
pub mod dhd;
pub mod discovery;
pub mod ffi;
pub mod link;

use std::path::PathBuf;

use glam::DVec3;
use softhaptic_proto::Pose;

use crate::backend::mapping::{ReportedLimits, WorkspaceMapping, tighter_limits};
use crate::device::DeviceLimits;

pub use device::ForceDimensionDevice;
pub use discovery::{Discovery, discover};
pub use ffi::{
    DhdLibrary, INSTALL_HINT, LIBRARY_DIRS, LIBRARY_ENV, LIBRARY_FILE, library_candidates,
};

/// The SDK's watchdog unit, s: its duration is set in multiples of 125 µs.
pub const WATCHDOG_UNIT_S: f64 = 125e-6;

/// The watchdog, in units: 10 ms, ten servo periods. Longer than the few late ticks a loaded
/// machine gives (the loop's standby catches most after a quarter period), far shorter than a
/// hand needs to notice a stale force held.
pub const WATCHDOG_UNITS: u8 = 80;

/// The watchdog's duration, s.
pub const WATCHDOG_S: f64 = WATCHDOG_UNITS as f64 * WATCHDOG_UNIT_S;

/// The window of the SDK's velocity estimate, ms. The loop's damping multiplies this velocity,
/// and a mean over a window lags by about half of it: the SDK's default of 20 ms would act
/// 10 ms, ten servo periods, late, and a damper that late can feed energy into the hand it
/// should take it from. 5 ms lags 2.5 ms and averages five readings against the encoders'
/// quantisation.
pub const VELOCITY_WINDOW_MS: i32 = 5;

/// The commanded force stays this fraction below the type's peak force, in the device's axes.
pub const FORCE_MARGIN: f64 = 0.01;

/// Ticks between two reads of the device's status (the force switch: a user may press the
/// device's force button, or the firmware may cut the force). Every 10 ms: for at most that long
/// a force the loop computed, recorded and streamed was not given by motors switched off, and
/// it costs one more USB exchange in ten ticks rather than in every one.
pub const STATUS_CHECK_TICKS: u64 = 10;

/// Force Dimension's USB vendor id, which its omega, delta, sigma and lambda devices report.
pub const USB_VENDOR_FORCE_DIMENSION: u16 = 0x1451;

/// The Novint Falcon's USB ids: the FTDI serial bridge it is built around (FTDI's vendor id
/// 0x0403) with the product id Novint gave it, 0xcb48.
pub const USB_VENDOR_FALCON: u16 = 0x0403;
pub const USB_PRODUCT_FALCON: u16 = 0xcb48;

/// Whether a USB device (vendor, product) is one this backend drives.
pub fn is_haptic_usb_device(vendor: u16, product: u16) -> bool {
    vendor == USB_VENDOR_FORCE_DIMENSION
        || (vendor == USB_VENDOR_FALCON && product == USB_PRODUCT_FALCON)
}

/// The udev rule that lets the desk's user (`uaccess`) and the `plugdev` group a service runs
/// in open these devices' USB nodes (the SDK opens them through libusb).
pub const UDEV_RULE_PATH: &str = "/etc/udev/rules.d/70-softhaptic-forcedimension.rules";
pub const UDEV_RULE: &str = concat!(
    "SUBSYSTEM==\"usb\", ATTRS{idVendor}==\"1451\", MODE=\"0660\", GROUP=\"plugdev\", TAG+=\"uaccess\"\n",
    "SUBSYSTEM==\"usb\", ATTRS{idVendor}==\"0403\", ATTRS{idProduct}==\"cb48\", MODE=\"0660\", GROUP=\"plugdev\", TAG+=\"uaccess\"\n",
);

/// How to install the rule, for messages.
pub fn udev_hint() -> String {
    format!(
        "give your user access to the Force Dimension device with a udev rule: write\n{}to {UDEV_RULE_PATH}, then run `sudo udevadm control --reload && sudo udevadm trigger` and replug the device",
        UDEV_RULE
            .lines()
            .map(|l| format!("    {l}\n"))
            .collect::<String>()
    )
}

/// What the device type tells of a device: its name and its limits (the SDK reports the type,
/// not the numbers).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceType {
    /// `dhdGetSystemType`'s value.
    pub id: i32,
    pub limits: DeviceLimits,
}

/// The scene preset (`[device] model`) and limits of a device type the project knows, `None` for
/// another (the scene's preset alone applies, with a warning).
///
/// The force loop drives the translation only, so a device takes its base's limits: the omega.6
/// and omega.7 are an omega.3 base with a wrist (and a gripper), the delta.6 a delta.3 base with
/// a wrist, the sigma types one base with different wrists, and a left-handed build mirrors its
/// right-handed twin.
pub fn type_preset(type_id: i32) -> Option<(&'static str, DeviceLimits)> {
    use dhd::*;
    Some(match type_id {
        DHD_DEVICE_FALCON => ("falcon", DeviceLimits::FALCON),
        DHD_DEVICE_OMEGA3
        | DHD_DEVICE_OMEGA33
        | DHD_DEVICE_OMEGA331
        | DHD_DEVICE_OMEGA33_LEFT
        | DHD_DEVICE_OMEGA331_LEFT => ("omega3", DeviceLimits::OMEGA3),
        DHD_DEVICE_DELTA3 | DHD_DEVICE_DELTA6 => ("delta3", DeviceLimits::DELTA3),
        DHD_DEVICE_SIGMA331
        | DHD_DEVICE_SIGMA331_LEFT
        | DHD_DEVICE_SIGMA33P
        | DHD_DEVICE_SIGMA33P_LEFT => ("sigma7", DeviceLimits::SIGMA7),
        _ => return None,
    })
}

/// The limits of a device type the project knows ([`type_preset`]).
pub fn type_limits(type_id: i32) -> Option<DeviceLimits> {
    type_preset(type_id).map(|(_, limits)| limits)
}

/// What the device says (and its type implies) about itself when it opens.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceDescription {
    /// The device index asked for (`None`: the SDK's default, the first device).
    pub index: Option<u8>,
    /// `dhdGetSystemType`.
    pub type_id: i32,
    /// `dhdGetSystemName`.
    pub name: String,
    /// `dhdGetSerialNumber`, when the device gives one.
    pub serial: Option<u16>,
    /// The type's limits, when the type is known.
    pub type_limits: Option<DeviceLimits>,
}

impl DeviceDescription {
    /// The limits the type implies, in the shared form (zeros: not known).
    pub fn reported_limits(&self) -> ReportedLimits {
        self.type_limits
            .map(|l| ReportedLimits {
                max_force_n: l.peak_force_n,
                continuous_force_n: l.continuous_force_n,
                max_stiffness_n_per_m: l.max_stiffness_n_per_m,
                max_damping_n_s_per_m: l.damping_n_s_per_m,
            })
            .unwrap_or_default()
    }

    /// The usable workspace, device frame, metres: the cube of the type's workspace radius
    /// (`None` for an unknown type).
    pub fn workspace_m(&self) -> Option<[DVec3; 2]> {
        self.type_limits.map(|l| {
            let r = l.workspace_radius_m;
            [DVec3::splat(-r), DVec3::splat(r)]
        })
    }

    /// The device for people: its name, type and serial.
    pub fn label(&self) -> String {
        format!(
            "{} (type {}, serial {})",
            if self.name.is_empty() {
                "Force Dimension device"
            } else {
                &self.name
            },
            self.type_id,
            self.serial
                .map_or_else(|| "?".to_owned(), |s| s.to_string())
        )
    }
}

/// Why the Force Dimension device could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum ForceDimensionError {
    /// No `libdhd.so` anywhere it was looked for.
    #[error(
        "the Force Dimension SDK library ({LIBRARY_FILE}) was not found; looked in:{}\n{INSTALL_HINT}",
        .tried.iter().map(|t| format!("\n  - {t}")).collect::<String>()
    )]
    NotFound { tried: Vec<String> },
    /// The path in the override variable could not be loaded.
    #[error(
        "could not load the Force Dimension SDK library {} named by {LIBRARY_ENV}: {reason}; \
         point {LIBRARY_ENV} at the SDK's libdhd.so, or unset it to search the system",
        .path.display()
    )]
    Load { path: PathBuf, reason: String },
    /// The library loaded, but lacks a function of the SDK.
    #[error(
        "{} is not the Force Dimension SDK library: it has no symbol {symbol}; {INSTALL_HINT}",
        .path.display()
    )]
    MissingSymbol { path: PathBuf, symbol: &'static str },
    /// The device did not open.
    #[error(
        "could not open the Force Dimension device {which} through {}: {reason} ({code_name}); \
         check that it is plugged in and powered, that this user may open its USB device (see \
         `softhaptic doctor` and the device setup in docs/devices.md), and that no other program \
         holds it",
        .library.display()
    )]
    Open {
        which: String,
        library: PathBuf,
        reason: String,
        code_name: &'static str,
    },
    /// A step of the setup after the device opened failed.
    #[error("the Force Dimension device {which} refused {step}: {reason} ({code_name})")]
    Setup {
        which: String,
        step: &'static str,
        reason: String,
        code_name: &'static str,
    },
}

/// How to open a Force Dimension device.
#[derive(Debug, Clone, PartialEq)]
pub struct ForceDimensionConfig {
    /// The device's index among those plugged in (`None`: the SDK's default device).
    pub index: Option<u8>,
    /// From the device frame to the world.
    pub world_from_device: Pose,
    /// World metres per metre of handle motion.
    pub scale: f64,
    /// The tool's orientation in the device frame: the translational devices (Falcon, omega.3,
    /// delta.3) have no wrist, so the tool keeps this one.
    pub tool_in_device: glam::DQuat,
    /// The scene's device preset; the tighter of it and the type's limits applies.
    pub preset: DeviceLimits,
    /// The loop's period: the device's time counts whole periods (below).
    pub period_ns: u64,
    /// The SDK's watchdog, in its 125 µs units ([`WATCHDOG_UNITS`] by default; 1 to 255).
    pub watchdog_units: u8,
}

impl ForceDimensionConfig {
    /// The default device at the world origin with its own axes, one to one, the tool upright.
    pub fn new(preset: DeviceLimits) -> Self {
        Self {
            index: None,
            world_from_device: Pose::IDENTITY,
            scale: 1.0,
            tool_in_device: glam::DQuat::IDENTITY,
            preset,
            period_ns: 1_000_000,
            watchdog_units: WATCHDOG_UNITS,
        }
    }

    /// The words for which device this is, in errors and logs.
    pub fn which(&self) -> String {
        match self.index {
            Some(i) => format!("at index {i}"),
            None => "(the default device)".to_owned(),
        }
    }
}

impl ForceDimensionDevice {
    /// Loads the SDK (once per process), opens the device and sets it up ([`link`]), and works
    /// out the limits it runs with (logged). The loop's thread clocks it from its first tick.
    pub fn open(
        config: &ForceDimensionConfig,
    ) -> Result<ForceDimensionDevice, ForceDimensionError> {
        let lib = DhdLibrary::load()?;
        let which = config.which();
        let (link, description) = link::Link::open(
            lib,
            config.index,
            which.clone(),
            config.watchdog_units.max(1),
        )?;
        let known = description.type_limits.is_some();
        let workspace = description.workspace_m().unwrap_or_else(|| {
            let r = config.preset.workspace_radius_m;
            [DVec3::splat(-r), DVec3::splat(r)]
        });
        let mapping = WorkspaceMapping {
            world_from_device: config.world_from_device,
            scale: config.scale,
            metres_per_unit: 1.0,
            usable_workspace: workspace,
            max_workspace: workspace,
        };
        let limits = tighter_limits(&config.preset, &description.reported_limits(), &mapping);
        tracing::info!(
            device = %description.label(),
            library = %lib.path().display(),
            type_known = known,
            "Force Dimension device opened"
        );
        if !known {
            tracing::warn!(
                device = %description.label(),
                preset = config.preset.name,
                "this device type's limits are not known here: the scene's preset alone bounds \
                 the force; choose the preset of the nearest model"
            );
        }
        tracing::info!(
            peak_force_n = limits.peak_force_n,
            continuous_force_n = limits.continuous_force_n,
            max_stiffness_n_per_m = limits.max_stiffness_n_per_m,
            damping_n_s_per_m = limits.damping_n_s_per_m,
            preset = config.preset.name,
            "haptic device limits in use: the tighter of the device type's and the preset's"
        );
        Ok(ForceDimensionDevice::new(
            link,
            description,
            mapping,
            limits,
            config.tool_in_device,
            config.period_ns,
        ))
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn known_types_have_their_presets_and_others_none() {
        assert_eq!(type_limits(60).unwrap().peak_force_n, 8.0);
        assert_eq!(type_limits(33).unwrap().max_stiffness_n_per_m, 5000.0);
        assert_eq!(type_limits(63).unwrap().peak_force_n, 20.0);
        assert_eq!(type_limits(104).unwrap().name, "sigma.7");
        assert_eq!(type_limits(7), None);
        // The omega.7 (left-handed too) and the delta.6 drive their base's translation.
        assert_eq!(type_preset(35).unwrap().0, "omega3");
        assert_eq!(type_preset(37).unwrap().1, DeviceLimits::OMEGA3);
        assert_eq!(type_preset(64).unwrap().1.peak_force_n, 20.0);
        assert_eq!(type_preset(105).unwrap().0, "sigma7");
        // A retired type (the 6DOF) is not guessed at.
        assert_eq!(type_preset(61), None);
        // The watchdog: 10 ms in the SDK's 125 µs units.
        assert!((WATCHDOG_S - 0.010).abs() < 1e-12);
    }

    #[test]
    fn errors_sort_into_a_lost_device_and_the_rest() {
        use dhd::*;
        assert!(is_gone(DHD_ERROR_COM) && is_gone(DHD_ERROR_NO_DEVICE_FOUND));
        assert!(!is_gone(DHD_ERROR_INVALID_PARAM) && !is_gone(DHD_ERROR_EXPERT_MODE_DISABLED));
        assert_eq!(error_name(2), "DHD_ERROR_COM");
    }

    #[test]
    fn a_missing_library_names_where_it_looked_and_how_to_install() {
        // SAFETY: no other thread of this test binary reads this variable.
        unsafe { std::env::set_var(LIBRARY_ENV, "/nonexistent/dir/libdhd.so") };
        let err = DhdLibrary::load().err().unwrap().to_string();
        // SAFETY: as above.
        unsafe { std::env::remove_var(LIBRARY_ENV) };
        assert!(err.contains("/nonexistent/dir/libdhd.so"), "{err}");
        assert!(err.contains(LIBRARY_ENV), "{err}");
        let searched = ForceDimensionError::NotFound {
            tried: vec!["/usr/local/lib/libdhd.so: no such file".into()],
        }
        .to_string();
        assert!(searched.contains("/usr/local/lib/libdhd.so") && searched.contains("SDK"));
    }
}
