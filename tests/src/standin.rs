//! The HD API stand-in: where it is built, and a handle on its test controls.
//!
//! `tests/standin/hd_standin.c` is a small C library that exports OpenHaptics' HD API (the
//! functions the OpenHaptics backend calls, same C signatures, same rules: its own servo thread,
//! frames, the error stack, the force limit) and drives a simulated hand instead of a PHANTOM.
//! `build.rs` compiles it into `libHD.so`, the name the backend loads, so a test points the
//! backend at [`standin_path`] and the backend loads it exactly as it loads the vendor's library.
//!
//! [`StandIn`] opens the same path. `dlopen` of a path already loaded returns the object already
//! loaded, so the test's handle and the backend's share one stand-in: one device, one scheduler,
//! one error stack. The controls act on the device the backend is driving. The library is linked
//! with `-z nodelete`, so dropping the last handle never unmaps code the scheduler thread runs.
//!
//! The stand-in's state is process-wide: tests that use it in one process must take turns (a
//! `static` mutex held for the whole test) and start with [`StandIn::reset`].

use std::ffi::{c_double, c_int, c_uint, c_ulonglong, c_void};
use std::path::Path;
use std::sync::{Mutex, PoisonError};
use std::time::{Duration, Instant};

/// The stand-in, `libHD.so` in the build's output directory.
pub fn standin_path() -> &'static Path {
    Path::new(env!("SOFTHAPTIC_HD_STANDIN"))
}

/// The stand-in built without `hdGetSchedulerTimeStamp`: a library missing one of the symbols the
/// backend needs.
pub fn missing_symbol_path() -> &'static Path {
    Path::new(env!("SOFTHAPTIC_HD_STANDIN_MISSING_SYMBOL"))
}

/// The HD API codes the controls take and the tests compare with (OpenHaptics 3.0 values).
pub mod hd {
    pub const HD_INVALID_HANDLE: u32 = 0xFFFF_FFFF;
    pub const HD_CALLBACK_DONE: u32 = 0;
    pub const HD_CALLBACK_CONTINUE: u32 = 1;
    pub const HD_DEFAULT_SCHEDULER_PRIORITY: u16 = u16::MAX / 2;
    pub const HD_MAX_SCHEDULER_PRIORITY: u16 = u16::MAX;
    pub const HD_MIN_SCHEDULER_PRIORITY: u16 = 0;

    pub const HD_SUCCESS: u32 = 0x0000;
    pub const HD_INVALID_ENUM: u32 = 0x0100;
    pub const HD_INVALID_VALUE: u32 = 0x0101;
    pub const HD_INVALID_OPERATION: u32 = 0x0102;
    pub const HD_BAD_HANDLE: u32 = 0x0104;
    pub const HD_EXCEEDED_MAX_FORCE: u32 = 0x0201;
    pub const HD_FORCE_ERROR: u32 = 0x0204;
    pub const HD_DEVICE_FAULT: u32 = 0x0300;
    pub const HD_DEVICE_ALREADY_INITIATED: u32 = 0x0301;
    pub const HD_COMM_ERROR: u32 = 0x0302;
    pub const HD_COMM_CONFIG_ERROR: u32 = 0x0303;
    pub const HD_TIMER_ERROR: u32 = 0x0304;
    pub const HD_ILLEGAL_BEGIN: u32 = 0x0400;
    pub const HD_ILLEGAL_END: u32 = 0x0401;
    pub const HD_FRAME_ERROR: u32 = 0x0402;
    pub const HD_SCHEDULER_FULL: u32 = 0x0501;

    pub const HD_CURRENT_BUTTONS: u32 = 0x2000;
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
    pub const HD_NOMINAL_MAX_DAMPING: u32 = 0x2609;
    pub const HD_CURRENT_FORCE: u32 = 0x2700;
    pub const HD_LAST_FORCE: u32 = 0x2800;

    pub const HD_FORCE_OUTPUT: u32 = 0x4000;
    pub const HD_MAX_FORCE_CLAMPING: u32 = 0x4001;

    pub const HD_CALIBRATION_OK: u32 = 0x5000;
    pub const HD_CALIBRATION_NEEDS_UPDATE: u32 = 0x5001;
    pub const HD_CALIBRATION_NEEDS_MANUAL_INPUT: u32 = 0x5002;
    pub const HD_CALIBRATION_ENCODER_RESET: u32 = 1;
    pub const HD_CALIBRATION_AUTO: u32 = 2;
    pub const HD_CALIBRATION_INKWELL: u32 = 4;
}

/// What the stand-in measured of the frames since its statistics were last reset: from the
/// moment `hdBeginFrame` latched the state to the moment `hdEndFrame` sent the force.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Latency {
    /// Median, µs (the upper edge of its 1 µs bin, never above `max_us`).
    pub p50_us: f64,
    /// 99th percentile, µs.
    pub p99_us: f64,
    pub max_us: f64,
    pub frames: u64,
}

/// The true state of the stand-in's hand (no calibration offset, no frame), device frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandState {
    pub position_mm: [f64; 3],
    pub velocity_mm_s: [f64; 3],
}

/// A hand the test installs: called on the servo thread at the start of every tick with the
/// force the stand-in sent at the last `hdEndFrame` (N, device frame); it updates the position
/// (mm) and velocity (mm/s), which hold the previous tick's values on entry.
pub type Hand = Box<dyn FnMut([f64; 3], &mut [f64; 3], &mut [f64; 3]) + Send>;

/// The installed hand. Process-wide because the stand-in's hand is: one loaded library, one hand.
static HAND: Mutex<Option<Hand>> = Mutex::new(None);

type HandCallback =
    unsafe extern "C" fn(*mut c_void, *const c_double, *mut c_double, *mut c_double);

/// The stand-in's end of [`StandIn::set_hand`]. A panic in the test's hand aborts the process
/// (it cannot unwind into C), which fails the test run loudly.
unsafe extern "C" fn hand_trampoline(
    _user: *mut c_void,
    force_n: *const c_double,
    position_mm: *mut c_double,
    velocity_mm_s: *mut c_double,
) {
    if force_n.is_null() || position_mm.is_null() || velocity_mm_s.is_null() {
        return;
    }
    // SAFETY: the stand-in passes three readable doubles of force and three writable doubles
    // each of position and velocity, distinct arrays that live for the call (`advance_hand` in
    // hd_standin.c); they were checked non-null above.
    let (force, position, velocity) = unsafe {
        (
            *force_n.cast::<[f64; 3]>(),
            &mut *position_mm.cast::<[f64; 3]>(),
            &mut *velocity_mm_s.cast::<[f64; 3]>(),
        )
    };
    let mut hand = HAND.lock().unwrap_or_else(PoisonError::into_inner);
    if let Some(hand) = hand.as_mut() {
        hand(force, position, velocity);
    }
}

/// A handle on the stand-in's test controls (the `hdStandin*` functions, which the backend never
/// calls). Every method is thread-safe, as the functions are.
pub struct StandIn {
    /// Keeps the function pointers below valid (the library is never unloaded anyway).
    _library: libloading::Library,
    reset: unsafe extern "C" fn(),
    inject_error: unsafe extern "C" fn(c_uint, c_int),
    unplug: unsafe extern "C" fn(),
    replug: unsafe extern "C" fn(),
    set_nominal_max_force: unsafe extern "C" fn(c_double),
    require_calibration: unsafe extern "C" fn(c_uint),
    complete_manual_calibration: unsafe extern "C" fn(),
    delay_timestamp: unsafe extern "C" fn(c_int, c_double),
    last_force: unsafe extern "C" fn(*mut c_double),
    hand_state: unsafe extern "C" fn(*mut c_double, *mut c_double),
    force_output_enabled: unsafe extern "C" fn() -> c_int,
    scheduler_running: unsafe extern "C" fn() -> c_int,
    ticks: unsafe extern "C" fn() -> c_ulonglong,
    device_open: unsafe extern "C" fn() -> c_int,
    scheduled_callbacks: unsafe extern "C" fn() -> c_int,
    latency: unsafe extern "C" fn(*mut c_double, *mut c_double, *mut c_double, *mut c_ulonglong),
    reset_stats: unsafe extern "C" fn(),
    set_hand: unsafe extern "C" fn(Option<HandCallback>, *mut c_void),
    set_buttons: unsafe extern "C" fn(c_int),
    set_rotation: unsafe extern "C" fn(*const c_double),
}

/// Looks up `$name` in `$library` as the function type of the field it is assigned to.
macro_rules! control {
    ($library:expr, $name:literal) => {{
        // SAFETY: hd_standin.c exports `$name` with exactly the C signature of the field this
        // pointer is stored in; the pointer is used only while `_library` keeps it loaded.
        let symbol = unsafe { $library.get(concat!($name, "\0").as_bytes()) }?;
        *symbol
    }};
}

/// `ticks` as the stand-in's `int`, saturating.
fn c_ticks(ticks: u32) -> c_int {
    c_int::try_from(ticks).unwrap_or(c_int::MAX)
}

impl StandIn {
    /// Opens the stand-in at [`standin_path`] (the library the backend is pointed at).
    pub fn load() -> Result<StandIn, libloading::Error> {
        // SAFETY: loading runs the stand-in's constructor, which only initialises its own
        // globals (a mutex and the device's default state).
        let library = unsafe { libloading::Library::new(standin_path()) }?;
        Ok(StandIn {
            reset: control!(library, "hdStandinReset"),
            inject_error: control!(library, "hdStandinInjectError"),
            unplug: control!(library, "hdStandinUnplug"),
            replug: control!(library, "hdStandinReplug"),
            set_nominal_max_force: control!(library, "hdStandinSetNominalMaxForce"),
            require_calibration: control!(library, "hdStandinRequireCalibration"),
            complete_manual_calibration: control!(library, "hdStandinCompleteManualCalibration"),
            delay_timestamp: control!(library, "hdStandinDelayTimestamp"),
            last_force: control!(library, "hdStandinLastForce"),
            hand_state: control!(library, "hdStandinHandState"),
            force_output_enabled: control!(library, "hdStandinForceOutputEnabled"),
            scheduler_running: control!(library, "hdStandinSchedulerRunning"),
            ticks: control!(library, "hdStandinTicks"),
            device_open: control!(library, "hdStandinDeviceOpen"),
            scheduled_callbacks: control!(library, "hdStandinScheduledCallbacks"),
            latency: control!(library, "hdStandinLatency"),
            reset_stats: control!(library, "hdStandinResetStats"),
            set_hand: control!(library, "hdStandinSetHand"),
            set_buttons: control!(library, "hdStandinSetButtons"),
            set_rotation: control!(library, "hdStandinSetRotation"),
            _library: library,
        })
    }

    /// Back to a fresh stand-in: the scheduler stopped and its callbacks gone, the device closed
    /// and plugged in, errors, injected faults, calibration, buttons, rotation, limits and
    /// statistics cleared, the built-in hand back at the start of its press. Only the tick count
    /// since load survives. Call it from the test's thread, never from a callback.
    pub fn reset(&self) {
        // SAFETY: no arguments; the stand-in stops and joins its scheduler itself.
        unsafe { (self.reset)() };
        // The stand-in no longer calls the trampoline: drop the test's hand.
        HAND.lock().unwrap_or_else(PoisonError::into_inner).take();
    }

    /// For the next `ticks` servo ticks, the first current-state get of every frame pushes `code`
    /// (e.g. [`hd::HD_COMM_ERROR`]), the frame's gets read zeros and its force is not sent. A
    /// force error (0x02xx) also switches force output off, as a real one does.
    pub fn inject_error(&self, code: u32, ticks: u32) {
        // SAFETY: plain values.
        unsafe { (self.inject_error)(code, c_ticks(ticks)) };
    }

    /// Pulls the cable: every frame pushes `HD_COMM_ERROR` and sends nothing, `hdInitDevice`
    /// fails with `HD_COMM_ERROR`. The scheduler keeps ticking.
    pub fn unplug(&self) {
        // SAFETY: no arguments.
        unsafe { (self.unplug)() };
    }

    /// Plugs the cable back. A handle opened before the unplug keeps failing until the
    /// application disables it and initialises the device again.
    pub fn replug(&self) {
        // SAFETY: no arguments.
        unsafe { (self.replug)() };
    }

    /// The nominal maximum force the device reports and enforces (N; ignored unless finite and
    /// positive).
    pub fn set_nominal_max_force(&self, newtons: f64) {
        // SAFETY: a plain value.
        unsafe { (self.set_nominal_max_force)(newtons) };
    }

    /// What `hdCheckCalibration` reports from now on: [`hd::HD_CALIBRATION_OK`],
    /// [`hd::HD_CALIBRATION_NEEDS_UPDATE`] (cleared by `hdUpdateCalibration` with the device's
    /// style) or [`hd::HD_CALIBRATION_NEEDS_MANUAL_INPUT`] (cleared to `NEEDS_UPDATE` by
    /// [`complete_manual_calibration`](Self::complete_manual_calibration)). While not OK the
    /// reported x is 37 mm off.
    pub fn require_calibration(&self, state: u32) {
        // SAFETY: a plain value; the stand-in ignores values that are no calibration state.
        unsafe { (self.require_calibration)(state) };
    }

    /// The user put the stylus in its inkwell.
    pub fn complete_manual_calibration(&self) {
        // SAFETY: no arguments.
        unsafe { (self.complete_manual_calibration)() };
    }

    /// For the next `ticks` servo ticks `hdGetSchedulerTimeStamp` reads `delay_s` more, as if the
    /// callback had started that late in its tick.
    pub fn delay_timestamp(&self, ticks: u32, delay_s: f64) {
        // SAFETY: plain values.
        unsafe { (self.delay_timestamp)(c_ticks(ticks), delay_s) };
    }

    /// The force the motors were sent at the last `hdEndFrame` (N, device frame): zero when
    /// force output is off, the device unplugged or the scheduler stopped.
    pub fn last_force_n(&self) -> [f64; 3] {
        let mut force = [0.0; 3];
        // SAFETY: the stand-in writes three doubles into `force`.
        unsafe { (self.last_force)(force.as_mut_ptr()) };
        force
    }

    /// Where the hand is now.
    pub fn hand_state(&self) -> HandState {
        let mut state = HandState {
            position_mm: [0.0; 3],
            velocity_mm_s: [0.0; 3],
        };
        // SAFETY: the stand-in writes three doubles into each array.
        unsafe {
            (self.hand_state)(
                state.position_mm.as_mut_ptr(),
                state.velocity_mm_s.as_mut_ptr(),
            )
        };
        state
    }

    /// The device is open and its force output on.
    pub fn force_output_enabled(&self) -> bool {
        // SAFETY: no arguments.
        unsafe { (self.force_output_enabled)() != 0 }
    }

    pub fn scheduler_running(&self) -> bool {
        // SAFETY: no arguments.
        unsafe { (self.scheduler_running)() != 0 }
    }

    /// Servo ticks since the library was loaded (not reset by [`reset`](Self::reset)).
    pub fn ticks(&self) -> u64 {
        // SAFETY: no arguments.
        unsafe { (self.ticks)() }
    }

    /// Waits until the scheduler has ticked `ticks` more times; false if `timeout` passed first.
    pub fn wait_for_ticks(&self, ticks: u64, timeout: Duration) -> bool {
        let target = self.ticks().saturating_add(ticks);
        let deadline = Instant::now() + timeout;
        while self.ticks() < target {
            if Instant::now() > deadline {
                return false;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        true
    }

    pub fn device_open(&self) -> bool {
        // SAFETY: no arguments.
        unsafe { (self.device_open)() != 0 }
    }

    /// Callbacks scheduled now (asynchronous ones and synchronous calls waiting for their tick).
    pub fn scheduled_callbacks(&self) -> usize {
        // SAFETY: no arguments.
        let n = unsafe { (self.scheduled_callbacks)() };
        usize::try_from(n).unwrap_or(0)
    }

    pub fn latency(&self) -> Latency {
        let mut latency = Latency {
            p50_us: 0.0,
            p99_us: 0.0,
            max_us: 0.0,
            frames: 0,
        };
        // SAFETY: the stand-in writes one value through each pointer.
        unsafe {
            (self.latency)(
                &mut latency.p50_us,
                &mut latency.p99_us,
                &mut latency.max_us,
                &mut latency.frames,
            )
        };
        latency
    }

    /// Starts the frame latency statistics afresh.
    pub fn reset_stats(&self) {
        // SAFETY: no arguments.
        unsafe { (self.reset_stats)() };
    }

    /// Replaces the built-in hand by `hand` (see [`Hand`]) until [`builtin_hand`](Self::builtin_hand)
    /// or [`reset`](Self::reset).
    pub fn set_hand<F>(&self, hand: F)
    where
        F: FnMut([f64; 3], &mut [f64; 3], &mut [f64; 3]) + Send + 'static,
    {
        // Stored before the stand-in is told, so the trampoline never finds the slot empty; a
        // tick already inside the trampoline holds the lock and finishes with the previous hand.
        *HAND.lock().unwrap_or_else(PoisonError::into_inner) = Some(Box::new(hand));
        // SAFETY: the trampoline has the stand-in's hand signature and ignores its user pointer.
        unsafe { (self.set_hand)(Some(hand_trampoline), std::ptr::null_mut()) };
    }

    /// Back to the built-in hand (which carries on from where the test's hand left it).
    pub fn builtin_hand(&self) {
        // SAFETY: NULL restores the built-in hand; once this returns the trampoline is not
        // running and will not be called again.
        unsafe { (self.set_hand)(None, std::ptr::null_mut()) };
        HAND.lock().unwrap_or_else(PoisonError::into_inner).take();
    }

    /// The stylus buttons, a bitmask (`HD_DEVICE_BUTTON_1` = 1, `_2` = 2, ...).
    pub fn set_buttons(&self, buttons: i32) {
        // SAFETY: a plain value.
        unsafe { (self.set_buttons)(buttons) };
    }

    /// The stylus' rotation, a column-major 3×3 matrix, or `None` for the identity.
    pub fn set_rotation(&self, rotation: Option<[f64; 9]>) {
        let pointer = rotation.as_ref().map_or(std::ptr::null(), |m| m.as_ptr());
        // SAFETY: NULL or nine readable doubles, alive for the call.
        unsafe { (self.set_rotation)(pointer) };
    }
}
