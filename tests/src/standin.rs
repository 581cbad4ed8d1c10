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
//! one error stack. The controls act on the device the backend is driving. Like the vendor's
//! library, the stand-in is unmapped when its last handle is closed (it is not linked with
//! `-z nodelete`); the handle [`StandIn::load`] opens is never closed, so the library stays mapped
//! while its scheduler thread may run, whatever the backend does.
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

/// The HD API codes the controls take and the tests compare with: the backend's own definition
/// (from which the stand-in's C header is generated too).
pub use softhaptic_device::openhaptics::hd;

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

/// How the built-in hand holds the stylus ([`StandIn::set_grip`]): a spring-damper toward the
/// press's target, acting on the mass that moves with the tip.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grip {
    pub stiffness_n_per_m: f64,
    pub damping_n_s_per_m: f64,
    /// The device's apparent mass at the tip and the part of the hand moving with it.
    pub mass_kg: f64,
}

impl Grip {
    /// The stand-in's default, the simulator's relaxed pen grip (`SimParams::default`): 300 N/m,
    /// 2 N·s/m, the PHANTOM Desktop's 45 g at the tip and 100 g of hand.
    pub const RELAXED: Grip = Grip {
        stiffness_n_per_m: 300.0,
        damping_n_s_per_m: 2.0,
        mass_kg: 0.145,
    };
}

/// A hand the test installs: called on the servo thread at the start of every tick with the
/// force the stand-in sent at the last `hdEndFrame` (N, device frame); it updates the position
/// (mm) and velocity (mm/s), which hold the previous tick's values on entry.
pub type Hand = Box<dyn FnMut([f64; 3], &mut [f64; 3], &mut [f64; 3]) + Send>;

/// The installed hand. Process-wide because the stand-in's hand is: one loaded library, one hand.
static HAND: Mutex<Option<Hand>> = Mutex::new(None);

pub(crate) type HandCallback =
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
    // dhd_standin.c as in
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

/// A stand-in's control that installs a hand (`hdStandinSetHand`, `dhdStandinSetHand`: the
/// same C signature in both stand-ins).
pub(crate) type SetHand = unsafe extern "C" fn(Option<HandCallback>, *mut c_void);

/// Installs `hand` as the stand-in's hand through its control `set`. One hand per process,
/// whichever stand-in calls it: a test binary drives one stand-in.
pub(crate) fn install_hand(set: SetHand, hand: Hand) {
    // Stored before the stand-in is told, so the trampoline never finds the slot empty; a tick
    // already inside the trampoline holds the lock and finishes with the previous hand.
    *HAND.lock().unwrap_or_else(PoisonError::into_inner) = Some(hand);
    // SAFETY: the trampoline has the stand-ins' hand signature and ignores its user pointer.
    unsafe { set(Some(hand_trampoline), std::ptr::null_mut()) };
}

/// Back to the stand-in's built-in hand (which carries on from where the test's hand left it).
pub(crate) fn remove_hand(set: SetHand) {
    // SAFETY: NULL restores the built-in hand; once this returns the trampoline is not running
    // and will not be called again.
    unsafe { set(None, std::ptr::null_mut()) };
    HAND.lock().unwrap_or_else(PoisonError::into_inner).take();
}

/// A handle on the stand-in's test controls (the `hdStandin*` functions, which the backend never
/// calls). Every method is thread-safe, as the functions are.
pub struct StandIn {
    reset: unsafe extern "C" fn(),
    frames_from_any_thread: unsafe extern "C" fn(c_int),
    unapplied_frames: unsafe extern "C" fn() -> c_ulonglong,
    force_output_enables: unsafe extern "C" fn() -> c_ulonglong,
    fail_scheduler_start: unsafe extern "C" fn(c_int),
    stall_callbacks: unsafe extern "C" fn(c_int),
    late_ticks: unsafe extern "C" fn(c_int, c_double),
    set_grip: unsafe extern "C" fn(c_double, c_double, c_double),
    set_calibration_styles: unsafe extern "C" fn(c_int),
    set_workspace: unsafe extern "C" fn(*const c_double, *const c_double),
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
    set_hand: SetHand,
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
        // Never closed: the function pointers below stay valid, and the stand-in stays mapped
        // while its scheduler thread may be running its code.
        let library: &'static libloading::Library = Box::leak(Box::new(library));
        Ok(StandIn {
            reset: control!(library, "hdStandinReset"),
            frames_from_any_thread: control!(library, "hdStandinFramesFromAnyThread"),
            unapplied_frames: control!(library, "hdStandinUnappliedFrames"),
            force_output_enables: control!(library, "hdStandinForceOutputEnables"),
            fail_scheduler_start: control!(library, "hdStandinFailSchedulerStart"),
            stall_callbacks: control!(library, "hdStandinStallCallbacks"),
            late_ticks: control!(library, "hdStandinLateTicks"),
            set_grip: control!(library, "hdStandinSetGrip"),
            set_calibration_styles: control!(library, "hdStandinSetCalibrationStyles"),
            set_workspace: control!(library, "hdStandinSetWorkspace"),
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
        })
    }

    /// Back to a fresh stand-in: the scheduler stopped and its callbacks gone, the device closed
    /// and plugged in, errors, injected faults, calibration, buttons, rotation, limits and
    /// statistics cleared, the built-in hand back at the start of its press with its default
    /// grip. Only the tick count since load survives. Call it from the test's thread, never from
    /// a callback.
    pub fn reset(&self) {
        // SAFETY: no arguments; the stand-in stops and joins its scheduler itself.
        unsafe { (self.reset)() };
        // The stand-in no longer calls the trampoline: drop the test's hand.
        HAND.lock().unwrap_or_else(PoisonError::into_inner).take();
    }

    /// For the next `ticks` servo ticks, every frame reports `code`. A device error (e.g.
    /// [`hd::HD_COMM_ERROR`]) is pushed by the frame's first current-state get, the frame's gets
    /// read zeros and its force is not sent. [`hd::HD_WARM_MOTORS`] is a warning pushed at
    /// `hdBeginFrame`: the frame works and its force is sent. A force error (0x0201–0x0204) is
    /// the driver's cut-out tripping: pushed at `hdBeginFrame` with force output switched off
    /// until the application enables it again; the readings stay good.
    pub fn inject_error(&self, code: u32, ticks: u32) {
        // SAFETY: plain values.
        unsafe { (self.inject_error)(code, c_ticks(ticks)) };
    }

    /// Lets frames be begun off the scheduler thread (`true`) or not (`false`, as after
    /// [`reset`](Self::reset)): only for tests of the stand-in's own frame state, which read
    /// better from the test thread. A backend's tests never relax it.
    pub fn frames_from_any_thread(&self, on: bool) {
        // SAFETY: a plain value.
        unsafe { (self.frames_from_any_thread)(c_int::from(on)) };
    }

    /// Frames since the last reset that set a force other than zero which the driver dropped
    /// silently because the device needed calibration: a force the viewers were shown and the
    /// hand never felt.
    pub fn unapplied_frames(&self) -> u64 {
        // SAFETY: no arguments.
        unsafe { (self.unapplied_frames)() }
    }

    /// `hdEnable(HD_FORCE_OUTPUT)` calls since the last reset.
    pub fn force_output_enables(&self) -> u64 {
        // SAFETY: no arguments.
        unsafe { (self.force_output_enables)() }
    }

    /// The next `times` `hdStartScheduler` calls fail with `HD_TIMER_ERROR` (the OS refused the
    /// servo timer) and start nothing.
    pub fn fail_scheduler_start(&self, times: u32) {
        // SAFETY: a plain value.
        unsafe { (self.fail_scheduler_start)(c_ticks(times)) };
    }

    /// For the next `ticks` servo ticks the driver calls no callback (its thread runs on, the
    /// hand moves on).
    pub fn stall_callbacks(&self, ticks: u32) {
        // SAFETY: a plain value.
        unsafe { (self.stall_callbacks)(c_ticks(ticks)) };
    }

    /// The next `ticks` servo ticks each last `tick_s` instead of one period: the callbacks run
    /// that late and the hand moves that much further between two of them.
    pub fn late_ticks(&self, ticks: u32, tick_s: f64) {
        // SAFETY: plain values.
        unsafe { (self.late_ticks)(c_ticks(ticks), tick_s) };
    }

    /// The built-in hand's grip until the next [`reset`](Self::reset): the stiffness (N/m) and
    /// damping (N·s/m) holding the stylus toward the press's target, and the mass moving with the
    /// tip (kg: the device's and the hand's). The default is [`Grip::RELAXED`]. A value that is
    /// not finite, a negative stiffness or damping, or a mass that is not positive changes
    /// nothing.
    pub fn set_grip(&self, grip: Grip) {
        // SAFETY: plain values.
        unsafe { (self.set_grip)(grip.stiffness_n_per_m, grip.damping_n_s_per_m, grip.mass_kg) };
    }

    /// The calibration styles the device reports and accepts ([`hd::HD_CALIBRATION_AUTO`], ...).
    pub fn set_calibration_styles(&self, styles: u32) {
        // SAFETY: a plain value.
        unsafe { (self.set_calibration_styles)(styles as c_int) };
    }

    /// The usable and maximum workspace boxes the device reports (min x y z, max x y z, mm);
    /// `None` keeps that box.
    pub fn set_workspace(&self, usable_mm: Option<[f64; 6]>, max_mm: Option<[f64; 6]>) {
        let usable = usable_mm.as_ref().map_or(std::ptr::null(), |b| b.as_ptr());
        let max = max_mm.as_ref().map_or(std::ptr::null(), |b| b.as_ptr());
        // SAFETY: NULL or six readable doubles each, alive for the call.
        unsafe { (self.set_workspace)(usable, max) };
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
        install_hand(self.set_hand, Box::new(hand));
    }

    /// Back to the built-in hand (which carries on from where the test's hand left it).
    pub fn builtin_hand(&self) {
        remove_hand(self.set_hand);
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
