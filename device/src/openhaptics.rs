//! A PHANTOM / Touch through OpenHaptics' HD API (`libHD.so`), loaded at run time.
//!
//! One file because the FFI declarations, the servo-callback rules and the fault handling share one
//! invariant (what may run inside a servo frame) that has to be read together; the last 110 lines
//! are its tests.
//!
//! # Loading
//! The library is opened with `dlopen` when a scene asks for the device, never linked: the
//! project builds, runs and tests where OpenHaptics is absent. [`HdLibrary::load`] tries the path
//! in [`LIBRARY_ENV`] when it is set (and nothing else), otherwise `libHD.so` through the
//! system's library search and then the directories OpenHaptics' packages install into. Each
//! symbol the backend uses is looked up once, at load; a library without one of them is refused
//! with the symbol's name. The few types and constants of the API are declared here (values
//! from OpenHaptics 3.0's `hdDefines.h`), so no vendor header is needed to build.
//!
//! # Who owns the clock
//! The HD API runs its own servo thread and allows device state to be read and force to be
//! written only inside its callbacks, between `hdBeginFrame` and `hdEndFrame`. The device hands
//! the loop an [`HdServoClock`] ([`HapticDevice::servo_clock`]); the loop's tick runs inside the
//! servo callback, so [`HapticDevice::read`] and [`HapticDevice::command_force`] of one tick fall
//! in one frame and the force answers the reading of the same servo tick (see
//! [`crate::haptic_loop`] for the rejected alternative).
//!
//! # Frames
//! The device reports millimetres in its own axes (y up, z toward the user). A
//! [`WorkspaceMapping`] clamps the position to the device's usable workspace, scales it to metres
//! (and by the scene's motion scale) and places it with `world_from_device`; forces go back
//! through the inverse rotation, unscaled (newtons are newtons at the handle). The stylus' own
//! +z axis (from the tip back along the handle) is the tool's +y.
//!
//! # Limits
//! The device's nominal maximum force, continuous force, stiffness and damping are read when it
//! opens and the tighter of them and the scene's preset is used ([`tighter_limits`]); stiffness
//! and damping are per millimetre in the HD API, and a motion scale s divides the stiffness and
//! damping the world may render (the hand feels K·s).
//!
//! # Faults
//! Errors are read off the HD error stack after every read and every command. A command error or
//! a tick that would send its force after the servo period ended ([`DeviceError::Overrun`]) sends
//! zero on that same frame, and the loop flags the tick; a force error re-enables force output on
//! the next tick (the world ramps the force in again). A device that stays unreachable for
//! [`RECONNECT_AFTER_FAILED_TICKS`] ticks is reconnected by a thread of its own, off the servo
//! path, with exponential backoff: it stops the scheduler (the loop's watchdog then runs fault
//! ticks), disables the old handle, initialises the device again until it answers, and restarts
//! the scheduler. A reconnected device gets its [`RECONNECT_AFTER_FAILED_TICKS`] again, and one
//! lost again before [`RECONNECTED_AFTER_GOOD_TICKS`] good ticks (it opens, but does not work)
//! is reopened only after a wait that keeps doubling from one reconnection to the next. Only the
//! driver's servo thread, inside the frame it opened, touches the device: a tick run on any
//! other thread (the loop's watchdog) reads nothing and sends nothing. An uncalibrated device renders no force ([`DeviceError::NeedsCalibration`])
//! until it reports itself calibrated; a device whose style allows it is recalibrated
//! automatically.

use std::cell::{Cell, UnsafeCell};
use std::ffi::{CStr, CString, c_char, c_double, c_int, c_uint, c_ulong, c_ushort, c_void};
use std::path::{Path, PathBuf};
use std::ptr::NonNull;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use glam::{DMat3, DQuat, DVec3};
use softhaptic_proto::Pose;

use crate::device::{DeviceError, DeviceLimits, DeviceSample, HapticDevice, ServoClock};
use crate::rt;

/// Environment variable naming the HD library to load instead of searching for it.
pub const LIBRARY_ENV: &str = "SOFTHAPTIC_HD_LIBRARY";

/// The HD API library's file name.
pub const LIBRARY_FILE: &str = "libHD.so";

/// Directories OpenHaptics for Linux installs `libHD.so` into, searched after the system's own
/// library search.
pub const LIBRARY_DIRS: [&str; 5] = [
    "/usr/lib64",
    "/usr/lib",
    "/usr/lib/x86_64-linux-gnu",
    "/usr/local/lib",
    "/opt/OpenHaptics/Developer/lib",
];

/// How to install the library, for the error of a machine without it.
pub const INSTALL_HINT: &str = "install the Touch device driver and OpenHaptics for Linux (3D \
Systems' support site), or set SOFTHAPTIC_HD_LIBRARY to the full path of libHD.so";

/// Ticks in a row the device may stay unreachable before it is reconnected (a shorter
/// communication error is ridden out with zero force).
pub const RECONNECT_AFTER_FAILED_TICKS: u32 = 250;

/// First and longest wait between two reconnection attempts.
pub const RECONNECT_BACKOFF_MIN: Duration = Duration::from_millis(100);
pub const RECONNECT_BACKOFF_MAX: Duration = Duration::from_secs(2);

/// Good ticks in a row after which a reconnected device counts as working again: the next loss
/// is reconnected at once and its backoff starts again from [`RECONNECT_BACKOFF_MIN`]. A device
/// lost again before that (it opens, but does not work) is reconnected only after a wait that
/// keeps growing from one reconnection to the next.
pub const RECONNECTED_AFTER_GOOD_TICKS: u32 = 1_000;

thread_local! {
    /// The device whose servo frame this thread has open: set by the servo callback around the
    /// loop's tick, null otherwise. Per thread, so that a tick run on another thread (the loop's
    /// watchdog) while the driver's thread has a frame open is outside the frame.
    static FRAME_OPEN_FOR: Cell<*const Inner> = const { Cell::new(std::ptr::null()) };
}

// The HD API's types and constants (OpenHaptics 3.0 `hdDefines.h`, `hdScheduler.h`).
type Hhd = c_uint;
type HdError = c_uint;
type HdEnum = c_uint;
type HdCallbackCode = c_uint;
type HdSchedulerHandle = c_ulong;
type HdSchedulerCallback = unsafe extern "C" fn(*mut c_void) -> HdCallbackCode;

#[repr(C)]
#[derive(Debug, Clone, Copy)]
struct HdErrorInfo {
    error_code: HdError,
    internal_error_code: c_int,
    hhd: Hhd,
}

const HD_INVALID_HANDLE: Hhd = 0xFFFF_FFFF;
const HD_SUCCESS: HdError = 0x0000;
const HD_BAD_HANDLE: HdError = 0x0104;
const HD_DEVICE_FAULT: HdError = 0x0300;
const HD_COMM_ERROR: HdError = 0x0302;
const HD_COMM_CONFIG_ERROR: HdError = 0x0303;
const HD_TIMER_ERROR: HdError = 0x0304;
const HD_CALLBACK_DONE: HdCallbackCode = 0;
const HD_CALLBACK_CONTINUE: HdCallbackCode = 1;
const HD_CURRENT_BUTTONS: HdEnum = 0x2000;
const HD_CURRENT_VELOCITY: HdEnum = 0x2051;
const HD_CURRENT_TRANSFORM: HdEnum = 0x2052;
const HD_DEVICE_MODEL_TYPE: HdEnum = 0x2501;
const HD_DEVICE_VENDOR: HdEnum = 0x2503;
const HD_DEVICE_SERIAL_NUMBER: HdEnum = 0x2504;
const HD_USABLE_WORKSPACE_DIMENSIONS: HdEnum = 0x2551;
const HD_CALIBRATION_STYLE: HdEnum = 0x2555;
const HD_NOMINAL_MAX_STIFFNESS: HdEnum = 0x2602;
const HD_NOMINAL_MAX_FORCE: HdEnum = 0x2603;
const HD_NOMINAL_MAX_CONTINUOUS_FORCE: HdEnum = 0x2604;
const HD_NOMINAL_MAX_DAMPING: HdEnum = 0x2609;
const HD_CURRENT_FORCE: HdEnum = 0x2700;
const HD_FORCE_OUTPUT: HdEnum = 0x4000;
const HD_CALIBRATION_OK: HdEnum = 0x5000;
const HD_CALIBRATION_NEEDS_UPDATE: HdEnum = 0x5001;
const HD_CALIBRATION_ENCODER_RESET: HdEnum = 1;
const HD_CALIBRATION_AUTO: HdEnum = 2;
const HD_CALIBRATION_INKWELL: HdEnum = 4;
const HD_DEFAULT_SCHEDULER_PRIORITY: c_ushort = u16::MAX / 2;
const HD_MAX_SCHEDULER_PRIORITY: c_ushort = u16::MAX;

/// The name of an HD error code, for logs and error messages.
pub fn error_name(code: u32) -> &'static str {
    match code {
        0x0000 => "HD_SUCCESS",
        0x0100 => "HD_INVALID_ENUM",
        0x0101 => "HD_INVALID_VALUE",
        0x0102 => "HD_INVALID_OPERATION",
        0x0103 => "HD_INVALID_INPUT_TYPE",
        0x0104 => "HD_BAD_HANDLE",
        0x0200 => "HD_WARM_MOTORS",
        0x0201 => "HD_EXCEEDED_MAX_FORCE",
        0x0202 => "HD_EXCEEDED_MAX_FORCE_IMPULSE",
        0x0203 => "HD_EXCEEDED_MAX_VELOCITY",
        0x0204 => "HD_FORCE_ERROR",
        0x0300 => "HD_DEVICE_FAULT",
        0x0301 => "HD_DEVICE_ALREADY_INITIATED",
        0x0302 => "HD_COMM_ERROR",
        0x0303 => "HD_COMM_CONFIG_ERROR",
        0x0304 => "HD_TIMER_ERROR",
        0x0400 => "HD_ILLEGAL_BEGIN",
        0x0401 => "HD_ILLEGAL_END",
        0x0402 => "HD_FRAME_ERROR",
        0x0500 => "HD_INVALID_PRIORITY",
        0x0501 => "HD_SCHEDULER_FULL",
        0x0600 => "HD_INVALID_LICENSE",
        _ => "an unknown HD error",
    }
}

/// What an HD error means for the loop: the device is gone, its force output was stopped, or
/// something else the driver reports by its code.
fn classify(code: HdError) -> DeviceError {
    match code {
        HD_COMM_ERROR | HD_COMM_CONFIG_ERROR | HD_DEVICE_FAULT | HD_TIMER_ERROR | HD_BAD_HANDLE => {
            DeviceError::Disconnected
        }
        // HD_WARM_MOTORS … HD_FORCE_ERROR: the driver reduced or stopped the force.
        0x0200..=0x02FF => DeviceError::ForceDisabled,
        other => DeviceError::Driver(other as i32),
    }
}

/// Which of two errors to report: a lost device outranks a stopped force, which outranks the
/// rest.
fn severity(code: HdError) -> u8 {
    match classify(code) {
        DeviceError::Disconnected => 3,
        DeviceError::ForceDisabled => 2,
        _ => 1,
    }
}

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
         that it is plugged in and powered, that this user may open it (see the README's device \
         setup), and that the name is a configuration made with the vendor's setup tool",
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
}

/// The HD API's functions, looked up once.
struct Api {
    init_device: unsafe extern "C" fn(*const c_char) -> Hhd,
    disable_device: unsafe extern "C" fn(Hhd),
    make_current_device: unsafe extern "C" fn(Hhd),
    get_error: unsafe extern "C" fn() -> HdErrorInfo,
    get_error_string: unsafe extern "C" fn(HdError) -> *const c_char,
    enable: unsafe extern "C" fn(HdEnum),
    disable: unsafe extern "C" fn(HdEnum),
    start_scheduler: unsafe extern "C" fn(),
    stop_scheduler: unsafe extern "C" fn(),
    set_scheduler_rate: unsafe extern "C" fn(c_ulong),
    schedule_asynchronous:
        unsafe extern "C" fn(HdSchedulerCallback, *mut c_void, c_ushort) -> HdSchedulerHandle,
    schedule_synchronous: unsafe extern "C" fn(HdSchedulerCallback, *mut c_void, c_ushort),
    unschedule: unsafe extern "C" fn(HdSchedulerHandle),
    get_scheduler_time_stamp: unsafe extern "C" fn() -> c_double,
    begin_frame: unsafe extern "C" fn(Hhd),
    end_frame: unsafe extern "C" fn(Hhd),
    get_doublev: unsafe extern "C" fn(HdEnum, *mut c_double),
    get_integerv: unsafe extern "C" fn(HdEnum, *mut c_int),
    get_string: unsafe extern "C" fn(HdEnum) -> *const c_char,
    set_doublev: unsafe extern "C" fn(HdEnum, *const c_double),
    check_calibration: unsafe extern "C" fn() -> HdEnum,
    update_calibration: unsafe extern "C" fn(HdEnum),
}

/// The loaded HD library. The function pointers stay valid as long as `_library` is loaded,
/// and it is dropped last (fields drop in order).
pub struct HdLibrary {
    api: Api,
    path: PathBuf,
    _library: libloading::Library,
}

/// Where [`HdLibrary::load`] looks, in order: the override alone when it is set.
pub fn library_candidates() -> Vec<PathBuf> {
    match std::env::var_os(LIBRARY_ENV) {
        Some(path) if !path.is_empty() => vec![PathBuf::from(path)],
        _ => std::iter::once(PathBuf::from(LIBRARY_FILE))
            .chain(LIBRARY_DIRS.iter().map(|d| Path::new(d).join(LIBRARY_FILE)))
            .collect(),
    }
}

impl HdLibrary {
    /// Loads the HD library from the override variable's path, or searches for it (module
    /// docs).
    pub fn load() -> Result<HdLibrary, OpenHapticsError> {
        let overridden = std::env::var_os(LIBRARY_ENV).is_some_and(|p| !p.is_empty());
        let mut tried = Vec::new();
        for candidate in library_candidates() {
            // A bare file name goes through the dynamic loader's own search; a path is used as is
            // and, when absent, skipped with a short reason rather than dlopen's longer one.
            let bare = candidate.components().count() == 1;
            if !overridden && !bare && !candidate.exists() {
                tried.push(format!("{}: no such file", candidate.display()));
                continue;
            }
            // SAFETY: loading a shared library runs its initialisers. The candidates are the
            // vendor's library (or the path the user named for it), whose initialisers only set
            // up its own state.
            match unsafe { libloading::Library::new(&candidate) } {
                Ok(library) => return Self::from_library(library, candidate),
                Err(e) if overridden => {
                    return Err(OpenHapticsError::Load {
                        path: candidate,
                        reason: e.to_string(),
                    });
                }
                Err(e) if bare => tried.push(format!(
                    "the system library path (LD_LIBRARY_PATH, /etc/ld.so.conf): {e}"
                )),
                Err(e) => tried.push(format!("{}: {e}", candidate.display())),
            }
        }
        if !overridden {
            tried.push(format!("{LIBRARY_ENV}: not set"));
        }
        Err(OpenHapticsError::NotFound { tried })
    }

    fn from_library(
        library: libloading::Library,
        path: PathBuf,
    ) -> Result<HdLibrary, OpenHapticsError> {
        macro_rules! symbol {
            ($name:literal) => {{
                // SAFETY: the symbol is declared with the signature OpenHaptics' headers give
                // it (devices.md), and the pointer is used only while `library` is loaded (it is
                // kept in the same struct, dropped last).
                match unsafe { library.get(concat!($name, "\0").as_bytes()) } {
                    Ok(symbol) => *symbol,
                    Err(_) => {
                        return Err(OpenHapticsError::MissingSymbol {
                            path,
                            symbol: $name,
                        });
                    }
                }
            }};
        }
        let api = Api {
            init_device: symbol!("hdInitDevice"),
            disable_device: symbol!("hdDisableDevice"),
            make_current_device: symbol!("hdMakeCurrentDevice"),
            get_error: symbol!("hdGetError"),
            get_error_string: symbol!("hdGetErrorString"),
            enable: symbol!("hdEnable"),
            disable: symbol!("hdDisable"),
            start_scheduler: symbol!("hdStartScheduler"),
            stop_scheduler: symbol!("hdStopScheduler"),
            set_scheduler_rate: symbol!("hdSetSchedulerRate"),
            schedule_asynchronous: symbol!("hdScheduleAsynchronous"),
            schedule_synchronous: symbol!("hdScheduleSynchronous"),
            unschedule: symbol!("hdUnschedule"),
            get_scheduler_time_stamp: symbol!("hdGetSchedulerTimeStamp"),
            begin_frame: symbol!("hdBeginFrame"),
            end_frame: symbol!("hdEndFrame"),
            get_doublev: symbol!("hdGetDoublev"),
            get_integerv: symbol!("hdGetIntegerv"),
            get_string: symbol!("hdGetString"),
            set_doublev: symbol!("hdSetDoublev"),
            check_calibration: symbol!("hdCheckCalibration"),
            update_calibration: symbol!("hdUpdateCalibration"),
        };
        Ok(HdLibrary {
            api,
            path,
            _library: library,
        })
    }

    /// The file the library was loaded from (as found: a bare name when the system's search
    /// found it).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Pops every error on the HD error stack (at most 16, so a broken driver cannot hold the
    /// servo thread) and returns the most severe, `None` when there was none.
    fn take_error(&self) -> Option<HdError> {
        let mut worst: Option<HdError> = None;
        for _ in 0..16 {
            // SAFETY: a function of the loaded library, no arguments.
            let info = unsafe { (self.api.get_error)() };
            if info.error_code == HD_SUCCESS {
                break;
            }
            if worst.is_none_or(|w| severity(info.error_code) > severity(w)) {
                worst = Some(info.error_code);
            }
        }
        worst
    }

    /// The driver's text for an error code.
    fn error_text(&self, code: HdError) -> String {
        // SAFETY: the library returns a static NUL-terminated string or null.
        let text = unsafe { (self.api.get_error_string)(code) };
        if text.is_null() {
            return error_name(code).to_owned();
        }
        // SAFETY: non-null, NUL-terminated, owned by the library (copied out at once).
        unsafe { CStr::from_ptr(text) }
            .to_string_lossy()
            .into_owned()
    }

    fn get_doubles<const N: usize>(&self, what: HdEnum) -> [f64; N] {
        let mut out = [0.0; N];
        // SAFETY: `out` holds as many doubles as the HD API writes for `what` (devices.md).
        unsafe { (self.api.get_doublev)(what, out.as_mut_ptr()) };
        out
    }

    fn get_integer(&self, what: HdEnum) -> i32 {
        let mut out: c_int = 0;
        // SAFETY: one int for the integer parameters used here.
        unsafe { (self.api.get_integerv)(what, &mut out) };
        out
    }

    fn get_string(&self, what: HdEnum) -> String {
        // SAFETY: the library returns a static NUL-terminated string or null.
        let text = unsafe { (self.api.get_string)(what) };
        if text.is_null() {
            return String::new();
        }
        // SAFETY: non-null and NUL-terminated; copied out at once.
        unsafe { CStr::from_ptr(text) }
            .to_string_lossy()
            .trim()
            .to_owned()
    }
}

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
    /// Calibration styles the device supports (`HD_CALIBRATION_*` bits).
    pub calibration_styles: u32,
}

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
    /// positions are clamped into it.
    pub usable_workspace_mm: [DVec3; 2],
}

impl WorkspaceMapping {
    /// Rotation from the stylus frame (its +z from the tip back along the handle) to the tool
    /// frame (+y up the shaft): a quarter turn about x.
    fn tool_from_stylus() -> DQuat {
        DQuat::from_rotation_x(std::f64::consts::FRAC_PI_2)
    }

    /// The tip's position in the world for a device position in millimetres.
    pub fn position_m(&self, device_mm: DVec3) -> DVec3 {
        let [lo, hi] = self.usable_workspace_mm;
        let clamped_mm = device_mm.clamp(lo.min(hi), hi.max(lo));
        self.world_from_device
            .transform_point(clamped_mm * (1e-3 * self.scale))
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
    /// plausibility check of [`crate::world::HapticWorld`] measures from the world origin).
    pub fn reach_m(&self) -> f64 {
        let [lo, hi] = self.usable_workspace_mm;
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
    // A zero, negative or non-finite reading means the device did not report it.
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
    /// sends zero instead ([`DeviceError::Overrun`]); one period by default.
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

/// The scheduled callback's context pointer, kept while the callback may run.
struct ContextPtr(NonNull<ServoContext>);
// SAFETY: the pointer is only dereferenced by the servo thread (the callback) and freed by the
// clock's stop after the scheduler stopped; the mutex around it orders the two.
unsafe impl Send for ContextPtr {}

/// Scheduler state, changed only off the servo path (start, reconnection, stop).
#[derive(Default)]
struct Control {
    scheduled: Option<HdSchedulerHandle>,
    scheduler_running: bool,
    context: Option<ContextPtr>,
}

/// State shared by the device (servo thread), its clock and its reconnection thread.
struct Inner {
    lib: HdLibrary,
    config_name: Option<CString>,
    display_name: String,
    handle: AtomicU32,
    period_ns: u64,
    /// CLOCK_MONOTONIC time the current servo tick began.
    tick_start_ns: AtomicU64,
    /// +1 each time the scheduler starts: the device clock's count restarts from there.
    servo_epoch: AtomicU32,
    /// Set (once) by the servo thread when the device must be reconnected.
    reconnect_wanted: AtomicBool,
    /// +1 per successful reconnection: the device checks its calibration again.
    generation: AtomicU32,
    /// Set by the servo side after [`RECONNECTED_AFTER_GOOD_TICKS`] good ticks of a connection
    /// (and at open); taken by the reconnection thread, whose backoff restarts only then.
    working: AtomicBool,
    /// The clock is stopping: the reconnection thread gives up.
    shutting_down: AtomicBool,
    /// Last HD error code the servo side saw (for the reconnection thread's log line).
    last_error: AtomicU32,
    control: Mutex<Control>,
}

impl Inner {
    fn control(&self) -> MutexGuard<'_, Control> {
        // A panic while holding it cannot leave the HD state half-changed in a way a retry
        // would make worse; keep going.
        self.control.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn setup_error(&self, step: &'static str, code: HdError) -> OpenHapticsError {
        OpenHapticsError::Setup {
            name: self.display_name.clone(),
            step,
            reason: self.lib.error_text(code),
            code_name: error_name(code),
        }
    }

    /// `hdInitDevice` for the configured name; the handle, or the error code.
    fn init_device(&self) -> Result<Hhd, HdError> {
        let name = self
            .config_name
            .as_ref()
            .map_or(std::ptr::null(), |c| c.as_ptr());
        // SAFETY: `name` is null (the default device) or a NUL-terminated string alive for the
        // call.
        let handle = unsafe { (self.lib.api.init_device)(name) };
        let error = self.lib.take_error();
        match (handle, error) {
            (HD_INVALID_HANDLE, e) => Err(e.unwrap_or(HD_COMM_ERROR)),
            (h, _) => {
                // SAFETY: a valid handle just returned by the library.
                unsafe { (self.lib.api.make_current_device)(h) };
                Ok(h)
            }
        }
    }

    /// Enables force output, sets the rate, schedules the servo callback and starts the
    /// scheduler; on an error everything started is undone.
    fn start_servo(&self, control: &mut Control) -> Result<(), HdError> {
        let api = &self.lib.api;
        let Some(context) = control.context.as_ref().map(|c| c.0) else {
            return Err(HD_TIMER_ERROR);
        };
        // SAFETY: functions of the loaded library; the context stays alive until `stop_servo`
        // has unscheduled the callback and stopped the scheduler.
        unsafe {
            (api.enable)(HD_FORCE_OUTPUT);
            (api.set_scheduler_rate)((1_000_000_000 / self.period_ns.max(1)) as c_ulong);
            let handle = (api.schedule_asynchronous)(
                servo_callback,
                context.as_ptr().cast(),
                HD_DEFAULT_SCHEDULER_PRIORITY,
            );
            control.scheduled = Some(handle);
            self.servo_epoch.fetch_add(1, Ordering::AcqRel);
            (api.start_scheduler)();
        }
        control.scheduler_running = true;
        if let Some(code) = self.lib.take_error()
            && severity(code) >= 3
        {
            self.stop_servo(control);
            return Err(code);
        }
        Ok(())
    }

    /// Unschedules the callback, sends zero force in one last frame, disables force output and
    /// stops the scheduler. The callback does not run after this returns.
    fn stop_servo(&self, control: &mut Control) {
        let api = &self.lib.api;
        // SAFETY: functions of the loaded library, on handles it gave.
        unsafe {
            if let Some(handle) = control.scheduled.take() {
                (api.unschedule)(handle);
            }
            if control.scheduler_running {
                (api.schedule_synchronous)(
                    zero_force_frame,
                    (self as *const Inner).cast_mut().cast(),
                    HD_MAX_SCHEDULER_PRIORITY,
                );
                (api.disable)(HD_FORCE_OUTPUT);
                (api.stop_scheduler)();
                control.scheduler_running = false;
            }
        }
        let _ = self.lib.take_error();
    }

    /// Whether the calling thread has this device's servo frame open: only then may the device
    /// be read and commanded.
    fn in_frame_here(&self) -> bool {
        FRAME_OPEN_FOR.with(|f| std::ptr::eq(f.get(), self))
    }

    /// Disables the device handle, if any.
    fn disable_device(&self) {
        let handle = self.handle.swap(HD_INVALID_HANDLE, Ordering::AcqRel);
        if handle != HD_INVALID_HANDLE {
            // SAFETY: a handle the library gave and that was not disabled yet (swapped out).
            unsafe { (self.lib.api.disable_device)(handle) };
            let _ = self.lib.take_error();
        }
    }

    /// Reads the device's description (outside a frame: these are device properties).
    fn describe(&self, name: Option<String>) -> DeviceDescription {
        let lib = &self.lib;
        let box_mm: [f64; 6] = lib.get_doubles(HD_USABLE_WORKSPACE_DIMENSIONS);
        let description = DeviceDescription {
            name,
            model: lib.get_string(HD_DEVICE_MODEL_TYPE),
            vendor: lib.get_string(HD_DEVICE_VENDOR),
            serial: lib.get_string(HD_DEVICE_SERIAL_NUMBER),
            max_force_n: lib.get_doubles::<1>(HD_NOMINAL_MAX_FORCE)[0],
            continuous_force_n: lib.get_doubles::<1>(HD_NOMINAL_MAX_CONTINUOUS_FORCE)[0],
            max_stiffness_n_per_m: lib.get_doubles::<1>(HD_NOMINAL_MAX_STIFFNESS)[0] * 1e3,
            max_damping_n_s_per_m: lib.get_doubles::<1>(HD_NOMINAL_MAX_DAMPING)[0] * 1e3,
            usable_workspace_mm: [
                DVec3::new(box_mm[0], box_mm[1], box_mm[2]),
                DVec3::new(box_mm[3], box_mm[4], box_mm[5]),
            ],
            calibration_styles: lib.get_integer(HD_CALIBRATION_STYLE) as u32,
        };
        // A property the device does not have is not an error of the session.
        let _ = lib.take_error();
        description
    }
}

impl Drop for Inner {
    fn drop(&mut self) {
        let mut control = std::mem::take(&mut *self.control());
        self.stop_servo(&mut control);
        self.disable_device();
    }
}

/// The servo tick: called by the HD scheduler's thread once per servo period.
unsafe extern "C" fn servo_callback(user: *mut c_void) -> HdCallbackCode {
    // SAFETY: `user` is the `ServoContext` the clock scheduled; it is freed only after the
    // callback was unscheduled and the scheduler stopped.
    let context = unsafe { &*user.cast::<ServoContext>() };
    let inner = &context.inner;
    let api = &inner.lib.api;
    let called_ns = rt::now_ns();
    // SAFETY: functions of the loaded library, called on its servo thread as the API requires.
    let since_tick_s = unsafe { (api.get_scheduler_time_stamp)() };
    let since_tick_ns = if since_tick_s.is_finite() && since_tick_s > 0.0 {
        (since_tick_s * 1e9) as u64
    } else {
        0
    };
    let tick_start_ns = called_ns.saturating_sub(since_tick_ns);
    let handle = inner.handle.load(Ordering::Acquire);
    // SAFETY: as above.
    unsafe { (api.begin_frame)(handle) };
    inner.tick_start_ns.store(tick_start_ns, Ordering::Relaxed);
    FRAME_OPEN_FOR.with(|f| f.set(Arc::as_ptr(inner)));
    // SAFETY: only this callback touches the closure, and the scheduler calls it from one
    // thread, one call at a time.
    let tick = unsafe { &mut *context.tick.get() };
    // A panic must not unwind into C (that aborts); the tick's state is released on unwinding.
    let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| tick(tick_start_ns)));
    FRAME_OPEN_FOR.with(|f| f.set(std::ptr::null()));
    // SAFETY: as above; closes the frame this callback opened.
    unsafe { (api.end_frame)(handle) };
    match outcome {
        Ok(()) => HD_CALLBACK_CONTINUE,
        // A bug in the tick: stop calling it (the driver then sends no force).
        Err(_) => HD_CALLBACK_DONE,
    }
}

/// One frame that sends zero force, run once by `hdScheduleSynchronous` when stopping.
unsafe extern "C" fn zero_force_frame(user: *mut c_void) -> HdCallbackCode {
    // SAFETY: `user` is the `Inner` that scheduled this synchronously, alive for the call.
    let inner = unsafe { &*user.cast::<Inner>() };
    let api = &inner.lib.api;
    let handle = inner.handle.load(Ordering::Acquire);
    let zero = [0.0f64; 3];
    // SAFETY: functions of the loaded library on its servo thread; `zero` holds 3 doubles.
    unsafe {
        (api.begin_frame)(handle);
        (api.set_doublev)(HD_CURRENT_FORCE, zero.as_ptr());
        (api.end_frame)(handle);
    }
    HD_CALLBACK_DONE
}

/// One frame that reads the calibration state, for a device that is not running a loop.
unsafe extern "C" fn calibration_frame(user: *mut c_void) -> HdCallbackCode {
    // SAFETY: `user` points to the probe's `(Arc<Inner>, HdEnum)` pair, alive for the
    // synchronous call.
    let (inner, status) = unsafe { &mut *user.cast::<(Arc<Inner>, HdEnum)>() };
    let api = &inner.lib.api;
    let handle = inner.handle.load(Ordering::Acquire);
    // SAFETY: functions of the loaded library on its servo thread.
    unsafe {
        (api.begin_frame)(handle);
        *status = (api.check_calibration)();
        (api.end_frame)(handle);
    }
    HD_CALLBACK_DONE
}

/// What the servo callback calls: the loop's tick.
struct ServoContext {
    inner: Arc<Inner>,
    tick: UnsafeCell<Box<dyn FnMut(u64) + Send>>,
}

/// A PHANTOM / Touch through the HD API (module docs).
pub struct OpenHapticsDevice {
    inner: Arc<Inner>,
    description: DeviceDescription,
    mapping: WorkspaceMapping,
    limits: DeviceLimits,
    overrun_after_ns: u64,
    opened_ns: u64,
    /// The device clock ([`OpenHapticsDevice::device_time_ns`]): the scheduler start it counts
    /// from, the start of that start's first servo tick and its device time.
    epoch_seen: u32,
    epoch_start_ns: u64,
    epoch_time_ns: u64,
    last_time_ns: Option<u64>,
    clock_taken: bool,
    /// Calibrated since the last (re)connection.
    calibrated: bool,
    generation_seen: u32,
    /// The style `hdUpdateCalibration` is asked for when the driver can update by itself.
    update_style: Option<HdEnum>,
    /// Ticks in a row the device was unreachable (since the last reconnection at most).
    failed_ticks: u32,
    /// Good ticks in a row since the last reconnection, up to [`RECONNECTED_AFTER_GOOD_TICKS`].
    good_ticks: u32,
    /// The driver stopped force output after a force error; enabled again next tick.
    force_output_lost: bool,
}

impl OpenHapticsDevice {
    /// Loads the HD library, opens the device and reads its description and limits (logged).
    /// The scheduler starts when the loop starts the device's clock.
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
                    library: lib.path.clone(),
                    reason: "the name contains a NUL byte".into(),
                    code_name: "HD_INVALID_VALUE",
                })?,
            ),
            None => None,
        };
        let inner = Arc::new(Inner {
            lib,
            config_name,
            display_name: display_name.clone(),
            handle: AtomicU32::new(HD_INVALID_HANDLE),
            period_ns: config.period_ns.max(1),
            tick_start_ns: AtomicU64::new(0),
            servo_epoch: AtomicU32::new(0),
            reconnect_wanted: AtomicBool::new(false),
            generation: AtomicU32::new(0),
            working: AtomicBool::new(true),
            shutting_down: AtomicBool::new(false),
            last_error: AtomicU32::new(HD_SUCCESS),
            control: Mutex::new(Control::default()),
        });
        let handle = inner.init_device().map_err(|code| OpenHapticsError::Init {
            name: display_name.clone(),
            library: inner.lib.path.clone(),
            reason: inner.lib.error_text(code),
            code_name: error_name(code),
        })?;
        inner.handle.store(handle, Ordering::Release);
        let description = inner.describe(config.name.clone());
        let mapping = WorkspaceMapping {
            world_from_device: config.world_from_device,
            scale: config.scale,
            usable_workspace_mm: description.usable_workspace_mm,
        };
        let limits = tighter_limits(&config.preset, &description, &mapping);
        tracing::info!(
            device = %display_name,
            model = %description.model,
            serial = %description.serial,
            library = %inner.lib.path.display(),
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
        let styles = description.calibration_styles;
        let update_style = [HD_CALIBRATION_AUTO, HD_CALIBRATION_INKWELL]
            .into_iter()
            .find(|s| styles & s != 0);
        Ok(OpenHapticsDevice {
            inner,
            description,
            mapping,
            limits,
            overrun_after_ns: config.overrun_after_ns.max(1),
            opened_ns: rt::now_ns(),
            epoch_seen: 0,
            epoch_start_ns: 0,
            epoch_time_ns: 0,
            last_time_ns: None,
            clock_taken: false,
            calibrated: false,
            generation_seen: 0,
            update_style,
            failed_ticks: 0,
            good_ticks: 0,
            force_output_lost: false,
        })
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

    /// Reads the calibration state in one frame of a briefly started scheduler (for a device
    /// that is not running a loop: `softhaptic devices`).
    pub fn probe_calibration(&self) -> Result<Calibration, OpenHapticsError> {
        if self.clock_taken {
            return Ok(if self.calibrated {
                Calibration::Ok
            } else {
                Calibration::NeedsManualInput
            });
        }
        let api = &self.inner.lib.api;
        let mut probe: (Arc<Inner>, HdEnum) = (Arc::clone(&self.inner), HD_CALIBRATION_OK);
        // SAFETY: functions of the loaded library; `probe` outlives the synchronous call.
        unsafe {
            (api.start_scheduler)();
            (api.schedule_synchronous)(
                calibration_frame,
                (&mut probe as *mut (Arc<Inner>, HdEnum)).cast(),
                HD_MAX_SCHEDULER_PRIORITY,
            );
            (api.stop_scheduler)();
        }
        if let Some(code) = self.inner.lib.take_error()
            && severity(code) >= 2
        {
            return Err(self.inner.setup_error("a calibration check", code));
        }
        Ok(match probe.1 {
            HD_CALIBRATION_OK => Calibration::Ok,
            HD_CALIBRATION_NEEDS_UPDATE => Calibration::NeedsUpdate,
            _ => Calibration::NeedsManualInput,
        })
    }

    /// The device time of the current servo tick: whole servo periods since the scheduler
    /// started (the device's clock counts ticks; a late wake-up of the servo thread by less than
    /// half a period does not move it), continuing from the wall time at each (re)start, and
    /// increasing from tick to tick. A tick's time then does not depend on how late the host
    /// woke the servo thread, so the force ramps and the heating model see the device's steps.
    fn device_time_ns(&mut self) -> u64 {
        let period_ns = self.inner.period_ns;
        let start_ns = self.inner.tick_start_ns.load(Ordering::Relaxed);
        let epoch = self.inner.servo_epoch.load(Ordering::Acquire);
        if epoch != self.epoch_seen {
            self.epoch_seen = epoch;
            self.epoch_start_ns = start_ns;
            let since_open = start_ns.saturating_sub(self.opened_ns);
            self.epoch_time_ns = (since_open + period_ns / 2) / period_ns * period_ns;
        }
        let periods = (start_ns.saturating_sub(self.epoch_start_ns) + period_ns / 2) / period_ns;
        let time_ns = self.epoch_time_ns + periods * period_ns;
        let time_ns = match self.last_time_ns {
            Some(last) => time_ns.max(last + 1),
            None => time_ns,
        };
        self.last_time_ns = Some(time_ns);
        time_ns
    }

    /// Books an unreachable tick; asks for a reconnection when there have been enough in a row.
    fn unreachable_tick(&mut self) {
        self.failed_ticks = self.failed_ticks.saturating_add(1);
        self.good_ticks = 0;
        if self.failed_ticks >= RECONNECT_AFTER_FAILED_TICKS {
            // The reconnection thread polls the flag every few milliseconds: the servo path
            // signals nothing else (no lock, no system call).
            self.inner.reconnect_wanted.store(true, Ordering::Release);
        }
    }

    /// The error of a tick run outside a servo frame (the loop's watchdog, while the driver's
    /// clock is down).
    fn outside_frame_error(&self) -> DeviceError {
        if self.inner.reconnect_wanted.load(Ordering::Acquire) {
            DeviceError::Disconnected
        } else {
            DeviceError::Timeout
        }
    }

    /// Errors of the frame so far, booked; `Err` when there was one.
    fn check_errors(&mut self) -> Result<(), DeviceError> {
        let Some(code) = self.inner.lib.take_error() else {
            return Ok(());
        };
        self.inner.last_error.store(code, Ordering::Relaxed);
        let error = classify(code);
        match error {
            DeviceError::Disconnected => self.unreachable_tick(),
            DeviceError::ForceDisabled => self.force_output_lost = true,
            _ => {}
        }
        Err(error)
    }

    /// A new connection (the reconnection thread reopened the device): its calibration is
    /// checked again, and its failures are counted from zero, so that it gets
    /// [`RECONNECT_AFTER_FAILED_TICKS`] ticks before it is reconnected again.
    fn follow_generation(&mut self) {
        let generation = self.inner.generation.load(Ordering::Acquire);
        if generation != self.generation_seen {
            self.generation_seen = generation;
            self.calibrated = false;
            self.failed_ticks = 0;
            self.good_ticks = 0;
        }
    }

    /// A good tick: after a run of them the connection counts as working again.
    fn good_tick(&mut self) {
        self.failed_ticks = 0;
        if self.good_ticks < RECONNECTED_AFTER_GOOD_TICKS {
            self.good_ticks += 1;
            if self.good_ticks == RECONNECTED_AFTER_GOOD_TICKS {
                self.inner.working.store(true, Ordering::Release);
            }
        }
    }

    /// The calibration state, checked once per connection (inside a frame).
    fn check_calibration(&mut self) -> Result<(), DeviceError> {
        if self.calibrated {
            return Ok(());
        }
        // A second handle to the library, so that `self` stays free to book errors (an atomic
        // increment, no allocation).
        let inner = Arc::clone(&self.inner);
        let api = &inner.lib.api;
        // SAFETY: a function of the loaded library, inside a frame on its servo thread.
        let status = unsafe { (api.check_calibration)() };
        self.check_errors()?;
        match status {
            HD_CALIBRATION_OK => {
                self.calibrated = true;
                Ok(())
            }
            HD_CALIBRATION_NEEDS_UPDATE if self.update_style.is_some() => {
                if let Some(style) = self.update_style {
                    // SAFETY: as above; takes effect from the next frame.
                    unsafe { (api.update_calibration)(style) };
                }
                let _ = self.check_errors();
                Err(DeviceError::NeedsCalibration)
            }
            _ => Err(DeviceError::NeedsCalibration),
        }
    }
}

impl HapticDevice for OpenHapticsDevice {
    fn limits(&self) -> DeviceLimits {
        self.limits
    }

    fn read(&mut self) -> Result<DeviceSample, DeviceError> {
        if !self.inner.in_frame_here() {
            return Err(self.outside_frame_error());
        }
        self.follow_generation();
        let inner = Arc::clone(&self.inner);
        let api = &inner.lib.api;
        // Errors left by the last frame's end (the force was sent there) count for this tick.
        self.check_errors()?;
        if self.force_output_lost {
            // SAFETY: a function of the loaded library, inside a frame on its servo thread.
            unsafe { (api.enable)(HD_FORCE_OUTPUT) };
            self.force_output_lost = false;
        }
        self.check_calibration()?;
        let lib = &inner.lib;
        let transform: [f64; 16] = lib.get_doubles(HD_CURRENT_TRANSFORM);
        let velocity: [f64; 3] = lib.get_doubles(HD_CURRENT_VELOCITY);
        let buttons = lib.get_integer(HD_CURRENT_BUTTONS);
        self.check_errors()?;
        self.good_tick();
        // Column-major: the rotation's columns, then the translation in millimetres.
        let rotation = DMat3::from_cols_array(&[
            transform[0],
            transform[1],
            transform[2],
            transform[4],
            transform[5],
            transform[6],
            transform[8],
            transform[9],
            transform[10],
        ]);
        let position_mm = DVec3::new(transform[12], transform[13], transform[14]);
        let stylus = DQuat::from_mat3(&rotation);
        // A rotation that is not one (a broken reading) gives a non-finite quaternion, which the
        // world refuses as a fault.
        let orientation = self.mapping.orientation(stylus);
        let time_ns = self.device_time_ns();
        Ok(DeviceSample {
            time_ns,
            tip_in_world: Pose {
                position_m: self.mapping.position_m(position_mm),
                orientation,
            },
            tip_velocity_m_s: self.mapping.velocity_m_s(DVec3::from_array(velocity)),
            buttons: buttons as u32,
        })
    }

    fn command_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        if !self.inner.in_frame_here() {
            // Outside a frame nothing can be sent, and the driver sends no force without frames:
            // zero is already what the motors get.
            return if force_n == DVec3::ZERO {
                Ok(())
            } else {
                Err(self.outside_frame_error())
            };
        }
        let inner = Arc::clone(&self.inner);
        let api = &inner.lib.api;
        // SAFETY: a function of the loaded library, inside a frame on its servo thread.
        let since_tick_s = unsafe { (api.get_scheduler_time_stamp)() };
        let overran = since_tick_s.is_finite() && since_tick_s * 1e9 > self.overrun_after_ns as f64;
        let device_n = self.mapping.force_device_n(force_n);
        let sent = if overran || !device_n.is_finite() {
            [0.0; 3]
        } else {
            device_n.to_array()
        };
        // SAFETY: as above; `sent` holds the three doubles HD_CURRENT_FORCE takes.
        unsafe { (api.set_doublev)(HD_CURRENT_FORCE, sent.as_ptr()) };
        if let Err(e) = self.check_errors() {
            let zero = [0.0f64; 3];
            // SAFETY: as above.
            unsafe { (api.set_doublev)(HD_CURRENT_FORCE, zero.as_ptr()) };
            let _ = inner.lib.take_error();
            return Err(e);
        }
        if overran {
            return Err(DeviceError::Overrun);
        }
        Ok(())
    }

    fn servo_clock(&mut self) -> Option<Box<dyn ServoClock>> {
        if std::mem::replace(&mut self.clock_taken, true) {
            return None;
        }
        Some(Box::new(HdServoClock {
            inner: Arc::clone(&self.inner),
            reconnector: None,
        }))
    }
}

/// The HD scheduler as the loop's clock, and the reconnection thread that restarts it.
pub struct HdServoClock {
    inner: Arc<Inner>,
    reconnector: Option<JoinHandle<()>>,
}

impl ServoClock for HdServoClock {
    fn period_ns(&self) -> u64 {
        self.inner.period_ns
    }

    fn start(&mut self, tick: Box<dyn FnMut(u64) + Send>) -> Result<(), DeviceError> {
        let context = Box::new(ServoContext {
            inner: Arc::clone(&self.inner),
            tick: UnsafeCell::new(tick),
        });
        {
            let mut control = self.inner.control();
            control.context = Some(ContextPtr(NonNull::from(Box::leak(context))));
            if let Err(code) = self.inner.start_servo(&mut control) {
                tracing::error!(
                    device = %self.inner.display_name,
                    error = %self.inner.lib.error_text(code),
                    code = error_name(code),
                    "the haptic device's scheduler did not start"
                );
                free_context(&mut control);
                return Err(classify(code));
            }
        }
        let inner = Arc::clone(&self.inner);
        let spawned = std::thread::Builder::new()
            .name("haptic-reconnect".into())
            .spawn(move || reconnect_when_asked(&inner));
        match spawned {
            Ok(handle) => self.reconnector = Some(handle),
            // Without it a lost device stays lost (zero force, flagged); the session goes on.
            Err(e) => tracing::warn!(error = %e, "no reconnection thread for the haptic device"),
        }
        Ok(())
    }

    fn stop(&mut self) {
        self.inner.shutting_down.store(true, Ordering::Release);
        if let Some(handle) = self.reconnector.take() {
            handle.thread().unpark();
            let _ = handle.join();
        }
        let mut control = self.inner.control();
        self.inner.stop_servo(&mut control);
        free_context(&mut control);
        drop(control);
        self.inner.disable_device();
    }
}

impl Drop for HdServoClock {
    fn drop(&mut self) {
        self.stop();
    }
}

/// Frees the servo callback's context; only once the callback can no longer run.
fn free_context(control: &mut Control) {
    if let Some(ContextPtr(ptr)) = control.context.take() {
        // SAFETY: the pointer came from `Box::leak` in `start`, and the callback that used it
        // was unscheduled and its scheduler stopped (or never started).
        drop(unsafe { Box::from_raw(ptr.as_ptr()) });
    }
}

/// The reconnection thread: waits for the servo side to ask, then stops the scheduler, reopens
/// the device with backoff and restarts the scheduler.
///
/// The backoff outlives one reconnection: a device that opens but is lost again before
/// [`RECONNECTED_AFTER_GOOD_TICKS`] good ticks (`Inner::working`) is reopened only after the
/// next, doubled, wait, so a device that keeps failing is not stopped and restarted every few
/// milliseconds. Only a working connection starts the next loss over at the shortest wait.
fn reconnect_when_asked(inner: &Inner) {
    let mut backoff = RECONNECT_BACKOFF_MIN;
    // The last loss ended in a reconnection that has not yet worked for a run of good ticks.
    let mut reconnected_unproven = false;
    while !inner.shutting_down.load(Ordering::Acquire) {
        std::thread::park_timeout(Duration::from_millis(5));
        if !inner.reconnect_wanted.load(Ordering::Acquire) {
            continue;
        }
        if inner.working.swap(false, Ordering::AcqRel) {
            backoff = RECONNECT_BACKOFF_MIN;
            reconnected_unproven = false;
        }
        let code = inner.last_error.load(Ordering::Relaxed);
        if reconnected_unproven {
            tracing::warn!(
                device = %inner.display_name,
                error = %inner.lib.error_text(code),
                code = error_name(code),
                wait_ms = backoff.as_millis() as u64,
                "haptic device lost again right after reconnecting: force is off; reconnecting \
                 after a longer wait"
            );
        } else {
            tracing::warn!(
                device = %inner.display_name,
                error = %inner.lib.error_text(code),
                code = error_name(code),
                "haptic device lost: force is off; reconnecting"
            );
        }
        {
            let mut control = inner.control();
            inner.stop_servo(&mut control);
        }
        inner.disable_device();
        let mut attempts = 0u32;
        loop {
            if attempts > 0 || reconnected_unproven {
                // Sleep in slices, so that a stop does not wait for a long backoff.
                let wake = std::time::Instant::now() + backoff;
                while std::time::Instant::now() < wake
                    && !inner.shutting_down.load(Ordering::Acquire)
                {
                    std::thread::park_timeout(Duration::from_millis(10));
                }
                backoff = (backoff * 2).min(RECONNECT_BACKOFF_MAX);
            }
            if inner.shutting_down.load(Ordering::Acquire) {
                return;
            }
            attempts += 1;
            match inner.init_device() {
                Ok(handle) => {
                    inner.handle.store(handle, Ordering::Release);
                    inner.generation.fetch_add(1, Ordering::AcqRel);
                    let mut control = inner.control();
                    inner.reconnect_wanted.store(false, Ordering::Release);
                    match inner.start_servo(&mut control) {
                        Ok(()) => {
                            tracing::info!(
                                device = %inner.display_name,
                                attempts,
                                "haptic device reconnected: force ramps in again"
                            );
                            reconnected_unproven = true;
                            break;
                        }
                        Err(code) => {
                            inner.reconnect_wanted.store(true, Ordering::Release);
                            drop(control);
                            inner.disable_device();
                            tracing::debug!(code = error_name(code), "scheduler did not restart");
                        }
                    }
                }
                Err(code) if attempts == 1 => tracing::info!(
                    device = %inner.display_name,
                    error = %inner.lib.error_text(code),
                    "haptic device not back yet; retrying with backoff up to every {} s",
                    RECONNECT_BACKOFF_MAX.as_secs()
                ),
                Err(_) => {}
            }
        }
    }
}

/// What opening one device configuration gave: its description and calibration state, or why
/// it could not be opened.
pub type Probe = Result<(DeviceDescription, Calibration), OpenHapticsError>;

/// What `softhaptic devices` reports about the OpenHaptics side of this machine.
#[derive(Debug)]
pub enum Discovery {
    /// The library could not be loaded.
    NoLibrary(OpenHapticsError),
    /// The library loaded; each named configuration tried, with what it gave.
    Library {
        path: PathBuf,
        devices: Vec<(String, Probe)>,
    },
}

/// Loads the library and tries to open the default device and each of `names` in turn (each
/// closed again before the next).
pub fn discover(names: &[String]) -> Discovery {
    let path = match HdLibrary::load() {
        Ok(lib) => lib.path.clone(),
        Err(e) => return Discovery::NoLibrary(e),
    };
    let mut tried: Vec<Option<String>> = vec![None];
    tried.extend(names.iter().cloned().map(Some));
    tried.dedup();
    let devices = tried
        .into_iter()
        .map(|name| {
            let label = name.clone().unwrap_or_else(|| "Default Device".into());
            let config = OpenHapticsConfig {
                name,
                ..OpenHapticsConfig::new(DeviceLimits::PHANTOM_DESKTOP)
            };
            let result = OpenHapticsDevice::open(&config).and_then(|device| {
                let calibration = device.probe_calibration()?;
                Ok((device.description().clone(), calibration))
            });
            (label, result)
        })
        .collect();
    Discovery::Library { path, devices }
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
    fn positions_are_clamped_to_the_usable_workspace() {
        let m = WorkspaceMapping {
            world_from_device: Pose::IDENTITY,
            scale: 1.0,
            usable_workspace_mm: [
                DVec3::new(-80.0, -60.0, -60.0),
                DVec3::new(80.0, 60.0, 60.0),
            ],
        };
        let p = m.position_m(DVec3::new(200.0, -61.0, 10.0));
        assert!((p - DVec3::new(0.08, -0.06, 0.01)).length() < 1e-12, "{p}");
        assert!(m.reach_m() >= 0.08);
    }

    #[test]
    fn the_stylus_axis_is_the_tool_shaft() {
        let m = WorkspaceMapping {
            world_from_device: Pose::IDENTITY,
            scale: 1.0,
            usable_workspace_mm: [DVec3::splat(-1.0), DVec3::splat(1.0)],
        };
        // Stylus at rest: its +z (tip back toward the user) is the tool's +y.
        let q = m.orientation(DQuat::IDENTITY);
        assert!((q * DVec3::Y - DVec3::Z).length() < 1e-12);
    }

    #[test]
    fn the_tighter_limit_wins_in_world_terms() {
        let device = DeviceDescription {
            name: None,
            model: "PHANTOM Desktop".into(),
            vendor: String::new(),
            serial: String::new(),
            max_force_n: 7.9,
            continuous_force_n: 0.5,
            max_stiffness_n_per_m: 1860.0,
            max_damping_n_s_per_m: 0.0,
            usable_workspace_mm: [DVec3::splat(-80.0), DVec3::splat(80.0)],
            calibration_styles: 4,
        };
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
    fn hd_errors_classify_by_what_they_mean_for_the_force() {
        assert_eq!(classify(HD_COMM_ERROR), DeviceError::Disconnected);
        assert_eq!(classify(HD_DEVICE_FAULT), DeviceError::Disconnected);
        assert_eq!(classify(0x0201), DeviceError::ForceDisabled);
        assert_eq!(classify(0x0402), DeviceError::Driver(0x402));
        assert!(severity(HD_COMM_ERROR) > severity(0x0201));
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
