//! The SDK as the backend sees it: the table of its functions, and the library that holds them,
//! found and loaded by the rules every backend shares ([`crate::backend::library`]): the path in
//! [`LIBRARY_ENV`] when set, otherwise `libdhd.so` through the system's library search and then
//! the directories the SDK is commonly installed into; loaded once per process, never unloaded.
//!
//! Every SDK call takes the device's id last (a C `char`); the SDK keeps the last error of each
//! thread apart, so an error is read (`DhdLibrary::last_error`) on the thread whose call
//! failed, right after it.

use std::ffi::{c_char, c_double, c_int, c_uchar, c_uint, c_ushort};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use super::ForceDimensionError;
use super::dhd::{DHD_MAX_STATUS, error_name};
use crate::backend::library::{LibrarySpec, LoadFailure, bind_symbol, c_text, load_once};

/// Environment variable naming the SDK library to load instead of searching for it.
pub const LIBRARY_ENV: &str = "SOFTHAPTIC_DHD_LIBRARY";

/// The SDK library's file name.
pub const LIBRARY_FILE: &str = "libdhd.so";

/// Directories searched after the system's own search: where the SDK's archive is usually
/// unpacked and its library copied.
pub const LIBRARY_DIRS: [&str; 4] = [
    "/usr/lib",
    "/usr/local/lib",
    "/usr/lib/x86_64-linux-gnu",
    "/opt/forcedimension/lib",
];

/// How to install the library, for the error of a machine without it.
pub const INSTALL_HINT: &str = "install the Force Dimension SDK for Linux (its lib/ holds \
libdhd.so; copy it to /usr/local/lib and run ldconfig), or set SOFTHAPTIC_DHD_LIBRARY to the full \
path of libdhd.so";

/// Where the SDK library is looked for.
pub const LIBRARY: LibrarySpec = LibrarySpec {
    file: LIBRARY_FILE,
    env: LIBRARY_ENV,
    dirs: &LIBRARY_DIRS,
};

/// Where [`DhdLibrary::load`] looks, in order: the override alone when it is set.
pub fn library_candidates() -> Vec<PathBuf> {
    LIBRARY.candidates()
}

type Id = c_char;
type XyzGet = unsafe extern "C" fn(*mut c_double, *mut c_double, *mut c_double, Id) -> c_int;

/// The SDK's functions, looked up once.
pub(crate) struct Api {
    pub get_device_count: unsafe extern "C" fn() -> c_int,
    pub open: unsafe extern "C" fn() -> c_int,
    pub open_id: unsafe extern "C" fn(Id) -> c_int,
    pub close: unsafe extern "C" fn(Id) -> c_int,
    pub get_system_type: unsafe extern "C" fn(Id) -> c_int,
    pub get_system_name: unsafe extern "C" fn(Id) -> *const c_char,
    pub get_serial_number: unsafe extern "C" fn(*mut c_ushort, Id) -> c_int,
    pub get_status: unsafe extern "C" fn(*mut c_int, Id) -> c_int,
    pub get_position: XyzGet,
    pub get_linear_velocity: XyzGet,
    pub config_linear_velocity: unsafe extern "C" fn(c_int, c_int, Id) -> c_int,
    pub get_button_mask: unsafe extern "C" fn(Id) -> c_uint,
    pub set_force: unsafe extern "C" fn(c_double, c_double, c_double, Id) -> c_int,
    pub enable_force: unsafe extern "C" fn(c_uchar, Id) -> c_int,
    pub set_brakes: unsafe extern "C" fn(c_int, Id) -> c_int,
    pub set_gravity_compensation: unsafe extern "C" fn(c_int, Id) -> c_int,
    pub enable_expert_mode: unsafe extern "C" fn() -> c_int,
    pub disable_expert_mode: unsafe extern "C" fn() -> c_int,
    pub set_watchdog: unsafe extern "C" fn(c_uchar, Id) -> c_int,
    pub error_get_last: unsafe extern "C" fn() -> c_int,
    pub error_get_str: unsafe extern "C" fn(c_int) -> *const c_char,
}

/// The loaded SDK library: never unloaded, so its function pointers stay valid for the
/// process' life.
pub struct DhdLibrary {
    pub(crate) api: Api,
    path: PathBuf,
}

/// The libraries loaded so far, by the candidate path they were found at.
static LOADED: Mutex<Vec<&'static DhdLibrary>> = Mutex::new(Vec::new());

/// What an SDK call that failed left: its code, read on the calling thread.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Failed(pub i32);

impl DhdLibrary {
    /// The library from the override variable's path, or found by searching (module docs);
    /// loaded once per process.
    pub fn load() -> Result<&'static DhdLibrary, ForceDimensionError> {
        load_once(
            &LIBRARY,
            &LOADED,
            |lib| &lib.path,
            Self::from_library,
            |failure| match failure {
                LoadFailure::NotFound { tried } => ForceDimensionError::NotFound { tried },
                LoadFailure::Load { path, reason } => ForceDimensionError::Load { path, reason },
            },
        )
    }

    fn from_library(
        library: &'static libloading::Library,
        path: PathBuf,
    ) -> Result<DhdLibrary, ForceDimensionError> {
        let missing = |symbol| ForceDimensionError::MissingSymbol {
            path: path.clone(),
            symbol,
        };
        macro_rules! symbol {
            ($name:literal) => {
                bind_symbol!(library, $name, missing)
            };
        }
        let api = Api {
            get_device_count: symbol!("dhdGetDeviceCount"),
            open: symbol!("dhdOpen"),
            open_id: symbol!("dhdOpenID"),
            close: symbol!("dhdClose"),
            get_system_type: symbol!("dhdGetSystemType"),
            get_system_name: symbol!("dhdGetSystemName"),
            get_serial_number: symbol!("dhdGetSerialNumber"),
            get_status: symbol!("dhdGetStatus"),
            get_position: symbol!("dhdGetPosition"),
            get_linear_velocity: symbol!("dhdGetLinearVelocity"),
            config_linear_velocity: symbol!("dhdConfigLinearVelocity"),
            get_button_mask: symbol!("dhdGetButtonMask"),
            set_force: symbol!("dhdSetForce"),
            enable_force: symbol!("dhdEnableForce"),
            set_brakes: symbol!("dhdSetBrakes"),
            set_gravity_compensation: symbol!("dhdSetGravityCompensation"),
            enable_expert_mode: symbol!("dhdEnableExpertMode"),
            disable_expert_mode: symbol!("dhdDisableExpertMode"),
            set_watchdog: symbol!("dhdSetWatchdog"),
            error_get_last: symbol!("dhdErrorGetLast"),
            error_get_str: symbol!("dhdErrorGetStr"),
        };
        Ok(DhdLibrary { api, path })
    }

    /// The file the library was loaded from (as found: a bare name when the system's search
    /// found it).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The calling thread's last error (module docs).
    pub(crate) fn last_error(&self) -> i32 {
        // SAFETY: a function of the loaded library, no arguments.
        unsafe { (self.api.error_get_last)() }
    }

    /// `Ok(value)` for a call's return that is not an error (negative), else the calling
    /// thread's error.
    pub(crate) fn check(&self, returned: c_int) -> Result<c_int, Failed> {
        if returned < 0 {
            Err(Failed(self.last_error()))
        } else {
            Ok(returned)
        }
    }

    /// The SDK's text for an error code.
    pub(crate) fn error_text(&self, code: i32) -> String {
        // SAFETY: the library returns a static NUL-terminated string or null.
        unsafe { c_text((self.api.error_get_str)(code)) }
            .filter(|t| !t.is_empty())
            .unwrap_or_else(|| error_name(code).to_owned())
    }

    /// The number of devices the SDK sees.
    pub(crate) fn device_count(&self) -> Result<c_int, Failed> {
        // SAFETY: a function of the loaded library, no arguments.
        self.check(unsafe { (self.api.get_device_count)() })
    }

    pub(crate) fn position(&self, id: Id) -> Result<[f64; 3], Failed> {
        self.xyz(self.api.get_position, id)
    }

    pub(crate) fn linear_velocity(&self, id: Id) -> Result<[f64; 3], Failed> {
        self.xyz(self.api.get_linear_velocity, id)
    }

    fn xyz(&self, get: XyzGet, id: Id) -> Result<[f64; 3], Failed> {
        let mut v = [0.0; 3];
        let [x, y, z] = &mut v;
        // SAFETY: three writable doubles, alive for the call.
        self.check(unsafe { get(x, y, z, id) })?;
        Ok(v)
    }

    pub(crate) fn status(&self, id: Id) -> Result<[c_int; DHD_MAX_STATUS], Failed> {
        let mut status = [0; DHD_MAX_STATUS];
        // SAFETY: the array holds the DHD_MAX_STATUS ints the SDK writes.
        self.check(unsafe { (self.api.get_status)(status.as_mut_ptr(), id) })?;
        Ok(status)
    }

    pub(crate) fn system_name(&self, id: Id) -> String {
        // SAFETY: the library returns a static NUL-terminated string or null.
        unsafe { c_text((self.api.get_system_name)(id)) }.unwrap_or_default()
    }

    pub(crate) fn serial_number(&self, id: Id) -> Option<u16> {
        let mut serial: c_ushort = 0;
        // SAFETY: one writable unsigned short.
        let returned = unsafe { (self.api.get_serial_number)(&mut serial, id) };
        self.check(returned).ok().map(|_| serial)
    }
}
