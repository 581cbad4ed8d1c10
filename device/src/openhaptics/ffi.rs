//! The HD API as the backend sees it: its C types, the table of its functions, and the library
//! that holds them, loaded once per process and never unloaded.
//!
//! # Loading
//! [`HdLibrary::load`] finds and loads the library by the rules every vendor's backend shares
//! ([`crate::backend::library`]): the path in [`LIBRARY_ENV`] when it is set (and nothing else),
//! otherwise `libHD.so` through the system's library search and then the directories
//! OpenHaptics' packages install into; loaded once per process, never unloaded. Each symbol the
//! backend uses is looked up once, at load; a library without one of them is refused with the
//! symbol's name.

use std::ffi::{CStr, c_char, c_double, c_int, c_uint, c_ulong, c_ushort, c_void};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use super::OpenHapticsError;
use super::hd::*;
use crate::backend::library::{LibrarySpec, LoadFailure, bind_symbol, load_once};

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

pub(crate) type Hhd = c_uint;
pub(crate) type HdError = c_uint;
pub(crate) type HdEnum = c_uint;
pub(crate) type HdCallbackCode = c_uint;
pub(crate) type HdSchedulerHandle = c_ulong;
pub(crate) type HdSchedulerCallback = unsafe extern "C" fn(*mut c_void) -> HdCallbackCode;

#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub(crate) struct HdErrorInfo {
    pub error_code: HdError,
    pub internal_error_code: c_int,
    pub hhd: Hhd,
}

/// The HD API's functions, looked up once.
pub(crate) struct Api {
    pub init_device: unsafe extern "C" fn(*const c_char) -> Hhd,
    pub disable_device: unsafe extern "C" fn(Hhd),
    pub make_current_device: unsafe extern "C" fn(Hhd),
    pub get_error: unsafe extern "C" fn() -> HdErrorInfo,
    pub get_error_string: unsafe extern "C" fn(HdError) -> *const c_char,
    pub enable: unsafe extern "C" fn(HdEnum),
    pub disable: unsafe extern "C" fn(HdEnum),
    pub start_scheduler: unsafe extern "C" fn(),
    pub stop_scheduler: unsafe extern "C" fn(),
    pub set_scheduler_rate: unsafe extern "C" fn(c_ulong),
    pub schedule_asynchronous:
        unsafe extern "C" fn(HdSchedulerCallback, *mut c_void, c_ushort) -> HdSchedulerHandle,
    pub unschedule: unsafe extern "C" fn(HdSchedulerHandle),
    pub get_scheduler_time_stamp: unsafe extern "C" fn() -> c_double,
    pub begin_frame: unsafe extern "C" fn(Hhd),
    pub end_frame: unsafe extern "C" fn(Hhd),
    pub get_doublev: unsafe extern "C" fn(HdEnum, *mut c_double),
    pub get_integerv: unsafe extern "C" fn(HdEnum, *mut c_int),
    pub get_string: unsafe extern "C" fn(HdEnum) -> *const c_char,
    pub set_doublev: unsafe extern "C" fn(HdEnum, *const c_double),
    pub check_calibration: unsafe extern "C" fn() -> HdEnum,
    pub update_calibration: unsafe extern "C" fn(HdEnum),
}

/// The loaded HD library: never unloaded (module docs), so its function pointers stay valid for
/// the process' life.
pub struct HdLibrary {
    pub(crate) api: Api,
    path: PathBuf,
}

/// The libraries loaded so far, by the candidate path they were found at.
static LOADED: Mutex<Vec<&'static HdLibrary>> = Mutex::new(Vec::new());

/// Where the HD library is looked for.
pub const LIBRARY: LibrarySpec = LibrarySpec {
    file: LIBRARY_FILE,
    env: LIBRARY_ENV,
    dirs: &LIBRARY_DIRS,
};

/// Where [`HdLibrary::load`] looks, in order: the override alone when it is set.
pub fn library_candidates() -> Vec<PathBuf> {
    LIBRARY.candidates()
}

/// The classes of HD errors a frame (or a control call) left on the error stack.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct ErrorsSeen {
    /// The device is gone or unreachable (`HD_COMM_ERROR`, `HD_DEVICE_FAULT`, ...): the most
    /// severe one seen.
    pub gone: Option<HdError>,
    /// The driver's force cut-out tripped (`HD_EXCEEDED_MAX_FORCE`, `_IMPULSE`, `_VELOCITY`,
    /// `HD_FORCE_ERROR`): force output is off.
    pub trip: Option<HdError>,
    /// `HD_WARM_MOTORS`: a warning, the driver keeps rendering.
    pub warm: bool,
    /// Any other error (frame misuse, invalid values, the timer).
    pub other: Option<HdError>,
}

impl ErrorsSeen {
    /// The most severe code seen, warm motors last.
    pub fn worst(&self) -> Option<HdError> {
        self.gone
            .or(self.trip)
            .or(self.other)
            .or(self.warm.then_some(HD_WARM_MOTORS))
    }
}

/// Whether an HD error means the device cannot be reached.
pub(crate) fn is_gone(code: HdError) -> bool {
    matches!(
        code,
        HD_COMM_ERROR | HD_COMM_CONFIG_ERROR | HD_DEVICE_FAULT | HD_BAD_HANDLE
    )
}

/// Whether an HD error is the driver's force cut-out tripping.
pub(crate) fn is_trip(code: HdError) -> bool {
    (HD_EXCEEDED_MAX_FORCE..=HD_FORCE_ERROR).contains(&code)
}

impl HdLibrary {
    /// The library from the override variable's path, or found by searching (module docs);
    /// loaded once per process.
    pub fn load() -> Result<&'static HdLibrary, OpenHapticsError> {
        load_once(
            &LIBRARY,
            &LOADED,
            |lib| &lib.path,
            Self::from_library,
            |failure| match failure {
                LoadFailure::NotFound { tried } => OpenHapticsError::NotFound { tried },
                LoadFailure::Load { path, reason } => OpenHapticsError::Load { path, reason },
            },
        )
    }

    fn from_library(
        library: &'static libloading::Library,
        path: PathBuf,
    ) -> Result<HdLibrary, OpenHapticsError> {
        let missing = |symbol| OpenHapticsError::MissingSymbol {
            path: path.clone(),
            symbol,
        };
        macro_rules! symbol {
            ($name:literal) => {
                bind_symbol!(library, $name, missing)
            };
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
        Ok(HdLibrary { api, path })
    }

    /// The file the library was loaded from (as found: a bare name when the system's search
    /// found it).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Pops every error on the HD error stack (at most 16, so a broken driver cannot hold the
    /// servo thread) and sorts them by what they mean. The stack is one for the whole process:
    /// only its owner may call this (the servo thread while the scheduler runs, the control
    /// thread otherwise).
    pub(crate) fn take_errors(&self) -> ErrorsSeen {
        let mut seen = ErrorsSeen::default();
        for _ in 0..16 {
            // SAFETY: a function of the loaded library, no arguments.
            let info = unsafe { (self.api.get_error)() };
            let code = info.error_code;
            if code == HD_SUCCESS {
                break;
            }
            if code == HD_WARM_MOTORS {
                seen.warm = true;
            } else if is_gone(code) {
                seen.gone = Some(seen.gone.map_or(code, |g| g.min(code)));
            } else if is_trip(code) {
                seen.trip.get_or_insert(code);
            } else {
                seen.other.get_or_insert(code);
            }
        }
        seen
    }

    /// The driver's text for an error code.
    pub(crate) fn error_text(&self, code: HdError) -> String {
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

    pub(crate) fn get_doubles<const N: usize>(&self, what: HdEnum) -> [f64; N] {
        let mut out = [0.0; N];
        // SAFETY: `out` holds as many doubles as the HD API writes for `what`.
        unsafe { (self.api.get_doublev)(what, out.as_mut_ptr()) };
        out
    }

    pub(crate) fn get_integer(&self, what: HdEnum) -> i32 {
        let mut out: c_int = 0;
        // SAFETY: one int for the integer parameters used here.
        unsafe { (self.api.get_integerv)(what, &mut out) };
        out
    }

    pub(crate) fn get_string(&self, what: HdEnum) -> String {
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
