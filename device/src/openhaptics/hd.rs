//! The HD API's codes (OpenHaptics 3.0 `hdDefines.h` values), defined once for the whole
//! project: the backend uses them, the tests compare with them, and the test build generates
//! the C header of the HD stand-in from this very file (`tests/build.rs`), so a wrong value
//! cannot agree with itself in three places.
//!
//! Every line that defines a code reads `pub const NAME: TYPE = VALUE;` on its own: the header
//! generator reads exactly that form.

/// An invalid device handle (`HHD`).
pub const HD_INVALID_HANDLE: u32 = 0xFFFF_FFFF;
/// A scheduler callback's return: unschedule me.
pub const HD_CALLBACK_DONE: u32 = 0;
/// A scheduler callback's return: run me again next servo tick.
pub const HD_CALLBACK_CONTINUE: u32 = 1;
pub const HD_MAX_SCHEDULER_PRIORITY: u16 = 0xFFFF;
pub const HD_MIN_SCHEDULER_PRIORITY: u16 = 0;
pub const HD_DEFAULT_SCHEDULER_PRIORITY: u16 = 0x7FFF;

// Errors.
pub const HD_SUCCESS: u32 = 0x0000;
pub const HD_INVALID_ENUM: u32 = 0x0100;
pub const HD_INVALID_VALUE: u32 = 0x0101;
pub const HD_INVALID_OPERATION: u32 = 0x0102;
pub const HD_INVALID_INPUT_TYPE: u32 = 0x0103;
pub const HD_BAD_HANDLE: u32 = 0x0104;
pub const HD_WARM_MOTORS: u32 = 0x0200;
pub const HD_EXCEEDED_MAX_FORCE: u32 = 0x0201;
pub const HD_EXCEEDED_MAX_FORCE_IMPULSE: u32 = 0x0202;
pub const HD_EXCEEDED_MAX_VELOCITY: u32 = 0x0203;
pub const HD_FORCE_ERROR: u32 = 0x0204;
pub const HD_DEVICE_FAULT: u32 = 0x0300;
pub const HD_DEVICE_ALREADY_INITIATED: u32 = 0x0301;
pub const HD_COMM_ERROR: u32 = 0x0302;
pub const HD_COMM_CONFIG_ERROR: u32 = 0x0303;
pub const HD_TIMER_ERROR: u32 = 0x0304;
pub const HD_ILLEGAL_BEGIN: u32 = 0x0400;
pub const HD_ILLEGAL_END: u32 = 0x0401;
pub const HD_FRAME_ERROR: u32 = 0x0402;
pub const HD_INVALID_PRIORITY: u32 = 0x0500;
pub const HD_SCHEDULER_FULL: u32 = 0x0501;
pub const HD_INVALID_LICENSE: u32 = 0x0600;

// State and properties (hdGet*, hdSet*).
pub const HD_CURRENT_BUTTONS: u32 = 0x2000;
pub const HD_CURRENT_SAFETY_SWITCH: u32 = 0x2001;
pub const HD_CURRENT_INKWELL_SWITCH: u32 = 0x2002;
pub const HD_CURRENT_POSITION: u32 = 0x2050;
pub const HD_CURRENT_VELOCITY: u32 = 0x2051;
pub const HD_CURRENT_TRANSFORM: u32 = 0x2052;
pub const HD_DEVICE_MODEL_TYPE: u32 = 0x2501;
pub const HD_DEVICE_VENDOR: u32 = 0x2503;
pub const HD_DEVICE_SERIAL_NUMBER: u32 = 0x2504;
pub const HD_MAX_WORKSPACE_DIMENSIONS: u32 = 0x2550;
pub const HD_USABLE_WORKSPACE_DIMENSIONS: u32 = 0x2551;
pub const HD_INPUT_DOF: u32 = 0x2553;
pub const HD_OUTPUT_DOF: u32 = 0x2554;
pub const HD_CALIBRATION_STYLE: u32 = 0x2555;
pub const HD_UPDATE_RATE: u32 = 0x2600;
pub const HD_INSTANTANEOUS_UPDATE_RATE: u32 = 0x2601;
pub const HD_NOMINAL_MAX_STIFFNESS: u32 = 0x2602;
pub const HD_NOMINAL_MAX_FORCE: u32 = 0x2603;
pub const HD_NOMINAL_MAX_CONTINUOUS_FORCE: u32 = 0x2604;
pub const HD_MOTOR_TEMPERATURE: u32 = 0x2605;
pub const HD_NOMINAL_MAX_DAMPING: u32 = 0x2609;
pub const HD_CURRENT_FORCE: u32 = 0x2700;
pub const HD_LAST_FORCE: u32 = 0x2800;

// Capabilities (hdEnable, hdDisable).
pub const HD_FORCE_OUTPUT: u32 = 0x4000;
pub const HD_MAX_FORCE_CLAMPING: u32 = 0x4001;
pub const HD_FORCE_RAMPING: u32 = 0x4002;
pub const HD_SOFTWARE_FORCE_LIMIT: u32 = 0x4003;
pub const HD_ONE_FRAME_LIMIT: u32 = 0x4004;

// Calibration (hdCheckCalibration results, hdUpdateCalibration styles).
pub const HD_CALIBRATION_OK: u32 = 0x5000;
pub const HD_CALIBRATION_NEEDS_UPDATE: u32 = 0x5001;
pub const HD_CALIBRATION_NEEDS_MANUAL_INPUT: u32 = 0x5002;
pub const HD_CALIBRATION_ENCODER_RESET: u32 = 1;
pub const HD_CALIBRATION_AUTO: u32 = 2;
pub const HD_CALIBRATION_INKWELL: u32 = 4;

/// The name of an HD error code, for logs and error messages.
pub fn error_name(code: u32) -> &'static str {
    match code {
        HD_SUCCESS => "HD_SUCCESS",
        HD_INVALID_ENUM => "HD_INVALID_ENUM",
        HD_INVALID_VALUE => "HD_INVALID_VALUE",
        HD_INVALID_OPERATION => "HD_INVALID_OPERATION",
        HD_INVALID_INPUT_TYPE => "HD_INVALID_INPUT_TYPE",
        HD_BAD_HANDLE => "HD_BAD_HANDLE",
        HD_WARM_MOTORS => "HD_WARM_MOTORS",
        HD_EXCEEDED_MAX_FORCE => "HD_EXCEEDED_MAX_FORCE",
        HD_EXCEEDED_MAX_FORCE_IMPULSE => "HD_EXCEEDED_MAX_FORCE_IMPULSE",
        HD_EXCEEDED_MAX_VELOCITY => "HD_EXCEEDED_MAX_VELOCITY",
        HD_FORCE_ERROR => "HD_FORCE_ERROR",
        HD_DEVICE_FAULT => "HD_DEVICE_FAULT",
        HD_DEVICE_ALREADY_INITIATED => "HD_DEVICE_ALREADY_INITIATED",
        HD_COMM_ERROR => "HD_COMM_ERROR",
        HD_COMM_CONFIG_ERROR => "HD_COMM_CONFIG_ERROR",
        HD_TIMER_ERROR => "HD_TIMER_ERROR",
        HD_ILLEGAL_BEGIN => "HD_ILLEGAL_BEGIN",
        HD_ILLEGAL_END => "HD_ILLEGAL_END",
        HD_FRAME_ERROR => "HD_FRAME_ERROR",
        HD_INVALID_PRIORITY => "HD_INVALID_PRIORITY",
        HD_SCHEDULER_FULL => "HD_SCHEDULER_FULL",
        HD_INVALID_LICENSE => "HD_INVALID_LICENSE",
        _ => "an unknown HD error",
    }
}
