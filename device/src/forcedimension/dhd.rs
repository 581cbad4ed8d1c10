//! The Force Dimension SDK's codes (`dhdc.h`), defined once for the whole project: the backend
//! uses them, the tests compare with them, and the test build generates the C header of the
//! SDK stand-in from this very file (`tests/build.rs`), so a wrong value cannot agree with
//! itself in three places. The values are those of the SDK's public header `dhdc.h` (checked
//! against release 3.7's); a first run on a real device checks them again (docs/devices.md).
//!
//! Every line that defines a code reads `pub const NAME: TYPE = VALUE;` on its own, with a
//! non-negative value: the header generator reads exactly that form.

// Switches (dhdEnableForce, dhdSetBrakes, dhdSetGravityCompensation).
pub const DHD_ON: i32 = 1;
pub const DHD_OFF: i32 = 0;

// Positive return values that are not errors: the call did its work.
/// The call came sooner than the SDK's time guard lets a new command through (it was skipped).
pub const DHD_TIMEGUARD: i32 = 1;
/// The force asked for was beyond what the motors give: it was scaled down to fit.
pub const DHD_MOTOR_SATURATED: i32 = 2;

// Velocity estimator modes (dhdConfigLinearVelocity): the mean over a sliding window of the
// given milliseconds, or the instantaneous difference of the last two readings.
pub const DHD_VELOCITY_WINDOWING: i32 = 0;
pub const DHD_VELOCITY_INSTANT: i32 = 2;
/// The SDK's default window, ms, when none is configured.
pub const DHD_VELOCITY_WINDOW: i32 = 20;

// Device types (dhdGetSystemType). The omega.6 and omega.7 are `OMEGA33` and `OMEGA331`, the
// sigma.7 `SIGMA331`; `_LEFT` is the left-handed build of the same mechanism.
pub const DHD_DEVICE_NONE: i32 = 0;
pub const DHD_DEVICE_OMEGA3: i32 = 33;
pub const DHD_DEVICE_OMEGA33: i32 = 34;
pub const DHD_DEVICE_OMEGA331: i32 = 35;
pub const DHD_DEVICE_OMEGA33_LEFT: i32 = 36;
pub const DHD_DEVICE_OMEGA331_LEFT: i32 = 37;
pub const DHD_DEVICE_FALCON: i32 = 60;
pub const DHD_DEVICE_DELTA3: i32 = 63;
pub const DHD_DEVICE_DELTA6: i32 = 64;
pub const DHD_DEVICE_SIGMA331: i32 = 104;
pub const DHD_DEVICE_SIGMA331_LEFT: i32 = 105;
pub const DHD_DEVICE_SIGMA33P: i32 = 106;
pub const DHD_DEVICE_SIGMA33P_LEFT: i32 = 107;

// Errors (dhdErrorGetLast), per calling thread.
pub const DHD_NO_ERROR: i32 = 0;
pub const DHD_ERROR: i32 = 1;
pub const DHD_ERROR_COM: i32 = 2;
pub const DHD_ERROR_DHC_BUSY: i32 = 3;
pub const DHD_ERROR_NO_DRIVER_FOUND: i32 = 4;
pub const DHD_ERROR_NO_DEVICE_FOUND: i32 = 5;
pub const DHD_ERROR_NOT_AVAILABLE: i32 = 6;
pub const DHD_ERROR_TIMEOUT: i32 = 7;
pub const DHD_ERROR_GEOMETRY: i32 = 8;
pub const DHD_ERROR_EXPERT_MODE_DISABLED: i32 = 9;
pub const DHD_ERROR_NOT_IMPLEMENTED: i32 = 10;
pub const DHD_ERROR_OUT_OF_MEMORY: i32 = 11;
pub const DHD_ERROR_DEVICE_NOT_READY: i32 = 12;
pub const DHD_ERROR_FILE_NOT_FOUND: i32 = 13;
pub const DHD_ERROR_CONFIGURATION: i32 = 14;
pub const DHD_ERROR_INVALID_INDEX: i32 = 15;
pub const DHD_ERROR_DEPRECATED: i32 = 16;
pub const DHD_ERROR_NULL_ARGUMENT: i32 = 17;
pub const DHD_ERROR_REDUNDANT_FAIL: i32 = 18;
pub const DHD_ERROR_NOT_ENABLED: i32 = 19;
pub const DHD_ERROR_DEVICE_IN_USE: i32 = 20;
pub const DHD_ERROR_INVALID_PARAM: i32 = 21;

// dhdGetStatus: the array's length and the entries read here.
pub const DHD_MAX_STATUS: usize = 16;
pub const DHD_STATUS_POWER: usize = 0;
pub const DHD_STATUS_CONNECTED: usize = 1;
pub const DHD_STATUS_FORCE: usize = 5;
pub const DHD_STATUS_BRAKE: usize = 6;

/// The name of an SDK error code, for logs and error messages.
pub fn error_name(code: i32) -> &'static str {
    match code {
        DHD_NO_ERROR => "DHD_NO_ERROR",
        DHD_ERROR => "DHD_ERROR",
        DHD_ERROR_COM => "DHD_ERROR_COM",
        DHD_ERROR_DHC_BUSY => "DHD_ERROR_DHC_BUSY",
        DHD_ERROR_NO_DRIVER_FOUND => "DHD_ERROR_NO_DRIVER_FOUND",
        DHD_ERROR_NO_DEVICE_FOUND => "DHD_ERROR_NO_DEVICE_FOUND",
        DHD_ERROR_NOT_AVAILABLE => "DHD_ERROR_NOT_AVAILABLE",
        DHD_ERROR_TIMEOUT => "DHD_ERROR_TIMEOUT",
        DHD_ERROR_GEOMETRY => "DHD_ERROR_GEOMETRY",
        DHD_ERROR_EXPERT_MODE_DISABLED => "DHD_ERROR_EXPERT_MODE_DISABLED",
        DHD_ERROR_NOT_IMPLEMENTED => "DHD_ERROR_NOT_IMPLEMENTED",
        DHD_ERROR_OUT_OF_MEMORY => "DHD_ERROR_OUT_OF_MEMORY",
        DHD_ERROR_DEVICE_NOT_READY => "DHD_ERROR_DEVICE_NOT_READY",
        DHD_ERROR_FILE_NOT_FOUND => "DHD_ERROR_FILE_NOT_FOUND",
        DHD_ERROR_CONFIGURATION => "DHD_ERROR_CONFIGURATION",
        DHD_ERROR_INVALID_INDEX => "DHD_ERROR_INVALID_INDEX",
        DHD_ERROR_DEPRECATED => "DHD_ERROR_DEPRECATED",
        DHD_ERROR_NULL_ARGUMENT => "DHD_ERROR_NULL_ARGUMENT",
        DHD_ERROR_REDUNDANT_FAIL => "DHD_ERROR_REDUNDANT_FAIL",
        DHD_ERROR_NOT_ENABLED => "DHD_ERROR_NOT_ENABLED",
        DHD_ERROR_DEVICE_IN_USE => "DHD_ERROR_DEVICE_IN_USE",
        DHD_ERROR_INVALID_PARAM => "DHD_ERROR_INVALID_PARAM",
        _ => "an unknown DHD error",
    }
}

/// Whether an error means the device cannot be reached (reconnected after a run of them).
pub fn is_gone(code: i32) -> bool {
    matches!(
        code,
        DHD_ERROR_COM
            | DHD_ERROR_NO_DEVICE_FOUND
            | DHD_ERROR_NO_DRIVER_FOUND
            | DHD_ERROR_DEVICE_NOT_READY
            | DHD_ERROR_TIMEOUT
            | DHD_ERROR_NOT_AVAILABLE
    )
}
