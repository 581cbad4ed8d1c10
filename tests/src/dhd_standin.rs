//! The Force Dimension SDK stand-in: where it is built, and a handle on its test controls.
//!
//! `tests/standin/dhd_standin.c` is a small C library that exports the SDK functions the Force
//! Dimension backend calls (same C signatures, same rules: SI units, errors per thread, forces
//! only while commands keep coming, the watchdog) and drives the hand the HD stand-in drives
//! (`standin_hand.h`) instead of a device. `build.rs` compiles it into `libdhd.so`, the name the
//! backend loads, so a test points the backend at [`dhd_standin_path`] and the backend loads it
//! exactly as it loads the vendor's library.
//!
//! [`DhdStandIn`] opens the same path, so the test's handle and the backend's share one
//! stand-in: one device, one hand. Its state is process-wide: tests that use it in one process
//! must take turns and start with [`DhdStandIn::reset`].

use std::ffi::{c_double, c_int, c_ulonglong};
use std::path::Path;

use crate::standin::{Hand, Latency, SetHand, install_hand, remove_hand};

/// The stand-in, `libdhd.so` in the build's output directory.
pub fn dhd_standin_path() -> &'static Path {
    Path::new(env!("SOFTHAPTIC_DHD_STANDIN"))
}

/// The SDK codes the controls take and the tests compare with: the backend's own definition
/// (from which the stand-in's C header is generated too).
pub use softhaptic_device::forcedimension::dhd;

/// The device's switches and the stand-in's counters since its reset.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DhdState {
    pub open: bool,
    pub force_on: bool,
    pub brakes_on: bool,
    pub gravity_on: bool,
    pub expert_mode: bool,
    /// The watchdog, in the SDK's 125 µs units (0: off).
    pub watchdog_units: u32,
    pub opens: u64,
    pub closes: u64,
    /// Force commands taken.
    pub commands: u64,
    /// Commands beyond the device's maximum, scaled down (answered `DHD_MOTOR_SATURATED`).
    pub saturations: u64,
    /// Times the watchdog stopped the motors because no command came.
    pub watchdog_trips: u64,
    /// Opens refused because the device was open already.
    pub refused_opens: u64,
    /// The velocity estimator's mode (`dhd::DHD_VELOCITY_*`) and window, ms.
    pub velocity_mode: i32,
    pub velocity_window_ms: i32,
}

/// A handle on the stand-in's test controls (the `dhdStandin*` functions, which the backend
/// never calls). Every method is thread-safe, as the functions are.
pub struct DhdStandIn {
    reset: unsafe extern "C" fn(),
    set_type: unsafe extern "C" fn(c_int),
    set_grip: unsafe extern "C" fn(c_double, c_double, c_double),
    set_press: unsafe extern "C" fn(*const c_double),
    inject_error: unsafe extern "C" fn(c_int, c_int),
    unplug: unsafe extern "C" fn(),
    replug: unsafe extern "C" fn(),
    force_button: unsafe extern "C" fn(),
    set_buttons: unsafe extern "C" fn(c_int),
    motor_force: unsafe extern "C" fn(*mut c_double),
    hand_state: unsafe extern "C" fn(*mut c_double, *mut c_double),
    state: unsafe extern "C" fn(*mut c_double),
    max_motor_force: unsafe extern "C" fn() -> c_double,
    latency: unsafe extern "C" fn(*mut c_double, *mut c_double, *mut c_double, *mut c_ulonglong),
    reset_stats: unsafe extern "C" fn(),
    set_hand: SetHand,
    /// The SDK's own error query, for the per-thread checks.
    error_get_last: unsafe extern "C" fn() -> c_int,
    set_force: unsafe extern "C" fn(c_double, c_double, c_double, std::ffi::c_char) -> c_int,
    open: unsafe extern "C" fn() -> c_int,
    close: unsafe extern "C" fn(std::ffi::c_char) -> c_int,
    enable_expert_mode: unsafe extern "C" fn() -> c_int,
    disable_expert_mode: unsafe extern "C" fn() -> c_int,
    set_watchdog: unsafe extern "C" fn(u8, std::ffi::c_char) -> c_int,
    config_velocity: unsafe extern "C" fn(c_int, c_int, std::ffi::c_char) -> c_int,
    enable_force: unsafe extern "C" fn(u8, std::ffi::c_char) -> c_int,
}

macro_rules! control {
    ($library:expr, $name:literal) => {{
        // SAFETY: dhd_standin.c exports `$name` with exactly the C signature of the field this
        // pointer is stored in; the library is never closed.
        let symbol = unsafe { $library.get(concat!($name, "\0").as_bytes()) }?;
        *symbol
    }};
}

impl DhdStandIn {
    /// Opens the stand-in at [`dhd_standin_path`] (the library the backend is pointed at).
    pub fn load() -> Result<DhdStandIn, libloading::Error> {
        // SAFETY: loading runs the stand-in's constructor, which only initialises its globals.
        let library = unsafe { libloading::Library::new(dhd_standin_path()) }?;
        // Never closed: the function pointers below stay valid.
        let library: &'static libloading::Library = Box::leak(Box::new(library));
        Ok(DhdStandIn {
            reset: control!(library, "dhdStandinReset"),
            set_type: control!(library, "dhdStandinSetType"),
            set_grip: control!(library, "dhdStandinSetGrip"),
            set_press: control!(library, "dhdStandinSetPress"),
            inject_error: control!(library, "dhdStandinInjectError"),
            unplug: control!(library, "dhdStandinUnplug"),
            replug: control!(library, "dhdStandinReplug"),
            force_button: control!(library, "dhdStandinForceButton"),
            set_buttons: control!(library, "dhdStandinSetButtons"),
            motor_force: control!(library, "dhdStandinMotorForce"),
            hand_state: control!(library, "dhdStandinHandState"),
            state: control!(library, "dhdStandinState"),
            max_motor_force: control!(library, "dhdStandinMaxMotorForce"),
            latency: control!(library, "dhdStandinLatency"),
            reset_stats: control!(library, "dhdStandinResetStats"),
            set_hand: control!(library, "dhdStandinSetHand"),
            error_get_last: control!(library, "dhdErrorGetLast"),
            set_force: control!(library, "dhdSetForce"),
            open: control!(library, "dhdOpen"),
            close: control!(library, "dhdClose"),
            enable_expert_mode: control!(library, "dhdEnableExpertMode"),
            disable_expert_mode: control!(library, "dhdDisableExpertMode"),
            set_watchdog: control!(library, "dhdSetWatchdog"),
            config_velocity: control!(library, "dhdConfigLinearVelocity"),
            enable_force: control!(library, "dhdEnableForce"),
        })
    }

    /// Back to a freshly loaded library's state: an omega.3, closed, the built-in hand.
    pub fn reset(&self) {
        self.builtin_hand();
        // SAFETY: no arguments.
        unsafe { (self.reset)() };
    }

    /// The type the device reports from its next open (`dhd::DHD_DEVICE_*`).
    pub fn set_type(&self, type_id: i32) {
        // SAFETY: a plain value.
        unsafe { (self.set_type)(type_id) };
    }

    /// The built-in hand's grip: stiffness (N/m), damping (N·s/m), moving mass (kg).
    pub fn set_grip(&self, stiffness_n_per_m: f64, damping_n_s_per_m: f64, mass_kg: f64) {
        // SAFETY: plain values.
        unsafe { (self.set_grip)(stiffness_n_per_m, damping_n_s_per_m, mass_kg) };
    }

    /// The built-in hand's press: point x, y, z and depth below it (mm), period (s).
    pub fn set_press(&self, press: [f64; 5]) {
        // SAFETY: five readable doubles, alive for the call.
        unsafe { (self.set_press)(press.as_ptr()) };
    }

    /// The next `calls` device calls fail with `code`.
    pub fn inject_error(&self, code: i32, calls: u32) {
        let calls = c_int::try_from(calls).unwrap_or(c_int::MAX);
        // SAFETY: plain values.
        unsafe { (self.inject_error)(code, calls) };
    }

    /// Pulls the cable: every call fails with `DHD_ERROR_COM`, opens with
    /// `DHD_ERROR_NO_DEVICE_FOUND`; the connection open now keeps failing after a replug.
    pub fn unplug(&self) {
        // SAFETY: no arguments.
        unsafe { (self.unplug)() };
    }

    pub fn replug(&self) {
        // SAFETY: no arguments.
        unsafe { (self.replug)() };
    }

    /// The operator presses the device's force button: forces off.
    pub fn press_force_button(&self) {
        // SAFETY: no arguments.
        unsafe { (self.force_button)() };
    }

    pub fn set_buttons(&self, buttons: i32) {
        // SAFETY: a plain value.
        unsafe { (self.set_buttons)(buttons) };
    }

    /// The force the motors give now (N, device frame): zero once the watchdog expired, with
    /// forces off or the brakes on, or the device closed.
    pub fn motor_force_n(&self) -> [f64; 3] {
        let mut f = [0.0; 3];
        // SAFETY: three writable doubles.
        unsafe { (self.motor_force)(f.as_mut_ptr()) };
        f
    }

    /// The hand's position (m) and velocity (m/s), device frame.
    pub fn hand_state(&self) -> ([f64; 3], [f64; 3]) {
        let (mut p, mut v) = ([0.0; 3], [0.0; 3]);
        // SAFETY: three writable doubles each.
        unsafe { (self.hand_state)(p.as_mut_ptr(), v.as_mut_ptr()) };
        (p, v)
    }

    pub fn state(&self) -> DhdState {
        let mut v = [0.0; 14];
        // SAFETY: fourteen writable doubles.
        unsafe { (self.state)(v.as_mut_ptr()) };
        DhdState {
            open: v[0] != 0.0,
            force_on: v[1] != 0.0,
            brakes_on: v[2] != 0.0,
            gravity_on: v[3] != 0.0,
            expert_mode: v[4] != 0.0,
            watchdog_units: v[5] as u32,
            opens: v[6] as u64,
            closes: v[7] as u64,
            commands: v[8] as u64,
            saturations: v[9] as u64,
            watchdog_trips: v[10] as u64,
            refused_opens: v[11] as u64,
            velocity_mode: v[12] as i32,
            velocity_window_ms: v[13] as i32,
        }
    }

    /// The largest force magnitude the motors gave since the reset, N.
    pub fn max_motor_force_n(&self) -> f64 {
        // SAFETY: no arguments.
        unsafe { (self.max_motor_force)() }
    }

    /// From each position read to the force command after it on the same thread (the tick's
    /// work between reading and commanding), since the last [`reset_stats`](Self::reset_stats);
    /// `frames` counts the commands.
    pub fn latency(&self) -> Latency {
        let mut l = Latency {
            p50_us: 0.0,
            p99_us: 0.0,
            max_us: 0.0,
            frames: 0,
        };
        // SAFETY: the stand-in writes one value through each pointer.
        unsafe { (self.latency)(&mut l.p50_us, &mut l.p99_us, &mut l.max_us, &mut l.frames) };
        l
    }

    /// Starts the latency statistics afresh.
    pub fn reset_stats(&self) {
        // SAFETY: no arguments.
        unsafe { (self.reset_stats)() };
    }

    /// Replaces the built-in hand: called at each position read with the force the motors give
    /// (N), the position (m) and velocity (m/s) to update.
    pub fn set_hand<F>(&self, hand: F)
    where
        F: FnMut([f64; 3], &mut [f64; 3], &mut [f64; 3]) + Send + 'static,
    {
        let hand: Hand = Box::new(hand);
        install_hand(self.set_hand, hand);
    }

    /// Back to the built-in hand.
    pub fn builtin_hand(&self) {
        remove_hand(self.set_hand);
    }

    /// The calling thread's last SDK error.
    pub fn last_error_here(&self) -> i32 {
        // SAFETY: no arguments.
        unsafe { (self.error_get_last)() }
    }

    /// `dhdSetForce` from the calling thread, for the stand-in's own checks of its rules.
    pub fn set_force_here(&self, force_n: [f64; 3], id: i8) -> i32 {
        // SAFETY: plain values.
        unsafe { (self.set_force)(force_n[0], force_n[1], force_n[2], id as std::ffi::c_char) }
    }

    /// `dhdOpen` from the calling thread: the id, or −1.
    pub fn open_here(&self) -> i32 {
        // SAFETY: no arguments.
        unsafe { (self.open)() }
    }

    /// `dhdClose` from the calling thread.
    pub fn close_here(&self, id: i8) -> i32 {
        // SAFETY: a plain value.
        unsafe { (self.close)(id as std::ffi::c_char) }
    }

    /// `dhdEnableExpertMode` (`on`) or `dhdDisableExpertMode`.
    pub fn expert_mode_here(&self, on: bool) -> i32 {
        // SAFETY: no arguments.
        unsafe {
            if on {
                (self.enable_expert_mode)()
            } else {
                (self.disable_expert_mode)()
            }
        }
    }

    /// `dhdSetWatchdog` from the calling thread.
    pub fn set_watchdog_here(&self, units: u8, id: i8) -> i32 {
        // SAFETY: plain values.
        unsafe { (self.set_watchdog)(units, id as std::ffi::c_char) }
    }

    /// `dhdConfigLinearVelocity` from the calling thread.
    pub fn config_velocity_here(&self, ms: i32, mode: i32, id: i8) -> i32 {
        // SAFETY: plain values.
        unsafe { (self.config_velocity)(ms, mode, id as std::ffi::c_char) }
    }

    /// `dhdEnableForce` from the calling thread.
    pub fn enable_force_here(&self, on: bool, id: i8) -> i32 {
        // SAFETY: plain values.
        unsafe { (self.enable_force)(u8::from(on), id as std::ffi::c_char) }
    }
}
