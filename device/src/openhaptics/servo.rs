//! The servo side: the state the driver's servo thread, the clock and the reconnection thread
//! share (`Inner`), the scheduler's start and stop, the callback, and the device the loop reads
//! and commands inside it.
//!
//! # One owner of the error stack
//! The HD error stack is one for the whole process. While the scheduler runs, only the servo
//! thread reads it (in the loop's tick, inside its frame); a control call made then (the stop)
//! learns its outcome from the servo callback, through a flag the callback sets. The control
//! thread reads the stack only while the scheduler is stopped: before it starts it, and after it
//! has stopped it. So a servo fault is never taken by the control thread, and a control error
//! never silences a fault tick.
//!
//! # A start that cannot hang
//! Every control call's error is checked at once. The scheduler counts as running only once the
//! servo callback has been seen running; until then no call that needs a running scheduler is
//! made (there is no synchronous scheduler call anywhere: on the vendor's library one made on a
//! stopped scheduler never returns). A start whose callback has not run after
//! [`START_DEADLINE`] stops the scheduler and reports the driver's own error.
//!
//! # Faults by what they mean
//! - a lost device (`HD_COMM_ERROR`, ...): zero force, reconnected off the servo path
//!   ([`super::recovery`]) after [`RECONNECT_AFTER_FAILED_TICKS`](crate::backend::reconnect::RECONNECT_AFTER_FAILED_TICKS) ticks;
//! - warm motors (`HD_WARM_MOTORS`): a warning, the force goes on, limited by the world to the
//!   device's continuous force while the sample carries [`ContactFlags::MOTORS_WARM`] (held
//!   [`WARM_HOLD_TICKS`] after the last warning, so the limit does not flicker);
//! - the driver's force cut-out tripping (`HD_EXCEEDED_MAX_FORCE`, `_IMPULSE`, `_VELOCITY`,
//!   `HD_FORCE_ERROR`): re-armed at once with the world's ramp at most [`MAX_AUTO_REARMS`] times
//!   in [`REARM_WINDOW_NS`]; one more trip in that window latches the force output off
//!   ([`DeviceError::ForceLatched`]) until an instructor re-arms it ([`RearmHandle`]) or the
//!   server restarts;
//! - calibration: checked every [`CALIBRATION_CHECK_TICKS`] ticks, and on every tick that
//!   commands a force, before the force is sent (a force set while the device needs
//!   calibration is not applied, and the driver does not say so). It is updated where the
//!   device's style allows; until it is OK no force is rendered and the device's state says what
//!   the operator must do;
//! - a panic in the tick: zero force in that frame, the callback unscheduled, and a fatal flag
//!   ([`DeviceError::Fatal`]) until the server restarts.
//!
//! A final clamp in the device's axes keeps the commanded force [`FORCE_MARGIN`] below the
//! device's nominal maximum, whatever rounding the frame rotation adds.

use std::cell::{Cell, UnsafeCell};
use std::ffi::{CString, c_ulong, c_void};
use std::ptr::NonNull;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use glam::{DMat3, DQuat, DVec3};
use softhaptic_proto::{ContactFlags, Pose};

use super::OpenHapticsError;
use super::ffi::{ErrorsSeen, HdCallbackCode, HdEnum, HdError, HdLibrary, HdSchedulerHandle, Hhd};
use super::hd::*;
use super::mapping::{DeviceDescription, WorkspaceMapping};
use crate::backend::reconnect::LinkHealth;
use crate::device::{
    DeviceError, DeviceLimits, DeviceSample, HapticDevice, RearmHandle, ServoClock, ServoStartError,
};
use crate::rt;

/// How long a started scheduler has to call the servo callback before the start counts as
/// failed: far beyond a servo period, short enough that a failed start is reported at once.
pub const START_DEADLINE: Duration = Duration::from_secs(2);

/// How long a stop waits for the servo callback to send its last (zero) force.
pub const STOP_DEADLINE: Duration = Duration::from_millis(250);

/// Ticks the warm-motors limit is held after the driver's last warning.
pub const WARM_HOLD_TICKS: u32 = 200;

/// Force trips re-armed automatically within [`REARM_WINDOW_NS`]; one more latches the output.
pub const MAX_AUTO_REARMS: usize = 3;

/// The window over which force trips are counted, ns.
pub const REARM_WINDOW_NS: u64 = 10_000_000_000;

/// Ticks between two calibration checks while no force is commanded.
pub const CALIBRATION_CHECK_TICKS: u64 = 100;

/// The commanded force stays this fraction below the device's nominal maximum, in its own axes.
pub const FORCE_MARGIN: f64 = 0.01;

thread_local! {
    /// The device whose servo frame this thread has open: set by the servo callback around the
    /// loop's tick, null otherwise. Per thread, so that a tick run on another thread (the loop's
    /// watchdog) while the driver's thread has a frame open is outside the frame.
    static FRAME_OPEN_FOR: Cell<*const Inner> = const { Cell::new(std::ptr::null()) };
}

/// The scheduled callback's context pointer, kept while the callback may run.
pub(crate) struct ContextPtr(NonNull<ServoContext>);
// SAFETY: the pointer is only dereferenced by the servo thread (the callback) and freed by the
// clock's stop after the scheduler stopped; the mutex around it orders the two.
unsafe impl Send for ContextPtr {}

/// Scheduler state, changed only off the servo path (start, reconnection, stop).
#[derive(Default)]
pub(crate) struct Control {
    scheduled: Option<HdSchedulerHandle>,
    scheduler_running: bool,
    context: Option<ContextPtr>,
}

/// Why the scheduler did not start: the call that failed and the driver's error, if it gave one.
#[derive(Debug, Clone, Copy)]
pub(crate) struct StartFailure {
    pub step: &'static str,
    pub code: Option<HdError>,
}

/// State shared by the device (servo thread), its clock and its reconnection thread.
pub(crate) struct Inner {
    pub lib: &'static HdLibrary,
    config_name: Option<CString>,
    pub display_name: String,
    handle: AtomicU32,
    pub period_ns: u64,
    /// CLOCK_MONOTONIC time the current servo tick began.
    tick_start_ns: AtomicU64,
    /// +1 each time the scheduler starts: the device clock's count restarts from there.
    servo_epoch: AtomicU32,
    /// Set (once) by the servo thread when the device must be reconnected.
    pub reconnect_wanted: AtomicBool,
    /// +1 per successful reconnection: the device checks its calibration again.
    pub generation: AtomicU32,
    /// Set by the servo side after [`RECONNECTED_AFTER_GOOD_TICKS`](crate::backend::reconnect::RECONNECTED_AFTER_GOOD_TICKS) good ticks of a connection
    /// (and at open); taken by the reconnection thread, whose backoff restarts only then.
    pub working: AtomicBool,
    /// The clock is stopping: the reconnection thread gives up.
    pub shutting_down: AtomicBool,
    /// Last HD error code the servo side saw (for the reconnection thread's log line).
    pub last_error: AtomicU32,
    /// Servo callbacks run so far: the evidence that a started scheduler runs.
    callback_calls: AtomicU64,
    /// CLOCK_MONOTONIC time of the last servo callback.
    pub last_callback_ns: AtomicU64,
    /// The scheduler was proven running (its callback seen) and has not been stopped since.
    pub servo_running: AtomicBool,
    /// Asked of the servo callback by a stop: send zero force, switch force output off, and
    /// unschedule yourself; `stop_done` is its answer.
    stop_requested: AtomicBool,
    stop_done: AtomicBool,
    /// The tick panicked: no force until the server restarts.
    pub fatal: AtomicBool,
    control: Mutex<Control>,
}

impl Inner {
    pub fn new(
        lib: &'static HdLibrary,
        config_name: Option<CString>,
        display_name: String,
        period_ns: u64,
    ) -> Inner {
        Inner {
            lib,
            config_name,
            display_name,
            handle: AtomicU32::new(HD_INVALID_HANDLE),
            period_ns: period_ns.max(1),
            tick_start_ns: AtomicU64::new(0),
            servo_epoch: AtomicU32::new(0),
            reconnect_wanted: AtomicBool::new(false),
            generation: AtomicU32::new(0),
            working: AtomicBool::new(true),
            shutting_down: AtomicBool::new(false),
            last_error: AtomicU32::new(HD_SUCCESS),
            callback_calls: AtomicU64::new(0),
            last_callback_ns: AtomicU64::new(0),
            servo_running: AtomicBool::new(false),
            stop_requested: AtomicBool::new(false),
            stop_done: AtomicBool::new(false),
            fatal: AtomicBool::new(false),
            control: Mutex::new(Control::default()),
        }
    }

    pub fn control(&self) -> MutexGuard<'_, Control> {
        // A panic while holding it cannot leave the HD state half-changed in a way a retry
        // would make worse; keep going.
        self.control.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub fn setup_error(&self, step: &'static str, code: HdError) -> OpenHapticsError {
        OpenHapticsError::Setup {
            name: self.display_name.clone(),
            step,
            reason: self.lib.error_text(code),
            code_name: error_name(code),
        }
    }

    /// `hdInitDevice` for the configured name (scheduler stopped: this thread owns the error
    /// stack); the handle, or the error code.
    pub fn init_device(&self) -> Result<Hhd, HdError> {
        let name = self
            .config_name
            .as_ref()
            .map_or(std::ptr::null(), |c| c.as_ptr());
        // SAFETY: `name` is null (the default device) or a NUL-terminated string alive for the
        // call.
        let handle = unsafe { (self.lib.api.init_device)(name) };
        let error = self.lib.take_errors().worst();
        match (handle, error) {
            (HD_INVALID_HANDLE, e) => Err(e.unwrap_or(HD_COMM_ERROR)),
            (h, _) => {
                // SAFETY: a valid handle just returned by the library.
                unsafe { (self.lib.api.make_current_device)(h) };
                self.handle.store(h, Ordering::Release);
                Ok(h)
            }
        }
    }

    /// The device handle in use (`HD_INVALID_HANDLE` when none).
    pub fn current_handle(&self) -> Hhd {
        self.handle.load(Ordering::Acquire)
    }

    /// Puts the servo callback's context in place.
    pub fn set_context(control: &mut Control, context: Box<ServoContext>) {
        control.context = Some(ContextPtr(NonNull::from(Box::leak(context))));
    }

    /// Enables force output, sets the rate, schedules the servo callback and starts the
    /// scheduler, checking each call's error at once; succeeds only once the callback has been
    /// seen running. On an error everything started is undone (module docs).
    pub fn start_servo(&self, control: &mut Control) -> Result<(), StartFailure> {
        let api = &self.lib.api;
        let Some(context) = control.context.as_ref().map(|c| c.0) else {
            return Err(StartFailure {
                step: "starting the servo loop (no tick to run)",
                code: None,
            });
        };
        let check = |step: &'static str| match self.lib.take_errors().worst() {
            Some(code) => Err(StartFailure {
                step,
                code: Some(code),
            }),
            None => Ok(()),
        };
        // The scheduler is stopped: this thread owns the error stack. Whatever is on it is left
        // from before and says nothing about this start.
        let _ = self.lib.take_errors();
        // SAFETY: functions of the loaded library with plain arguments.
        unsafe { (api.enable)(HD_FORCE_OUTPUT) };
        check("hdEnable(HD_FORCE_OUTPUT)")?;
        // SAFETY: as above.
        unsafe { (api.set_scheduler_rate)((1_000_000_000 / self.period_ns.max(1)) as c_ulong) };
        check("hdSetSchedulerRate")?;
        // SAFETY: the context stays alive until `stop_servo` has unscheduled the callback and
        // stopped the scheduler (or this start undid both).
        let handle = unsafe {
            (api.schedule_asynchronous)(
                servo_callback,
                context.as_ptr().cast(),
                HD_DEFAULT_SCHEDULER_PRIORITY,
            )
        };
        if let Err(failure) = check("hdScheduleAsynchronous") {
            // SAFETY: unscheduling an unknown handle is harmless.
            unsafe { (api.unschedule)(handle) };
            let _ = self.lib.take_errors();
            return Err(failure);
        }
        control.scheduled = Some(handle);
        self.stop_requested.store(false, Ordering::Release);
        self.stop_done.store(false, Ordering::Release);
        let calls = self.callback_calls.load(Ordering::Acquire);
        self.servo_epoch.fetch_add(1, Ordering::AcqRel);
        // SAFETY: a function of the loaded library, no arguments.
        unsafe { (api.start_scheduler)() };
        // From here the servo thread may own the error stack: it is not read here again until
        // the callback has been seen, or the scheduler has been stopped.
        let deadline = Instant::now() + START_DEADLINE;
        while self.callback_calls.load(Ordering::Acquire) == calls && Instant::now() < deadline {
            std::thread::park_timeout(Duration::from_millis(1));
        }
        if self.callback_calls.load(Ordering::Acquire) != calls {
            control.scheduler_running = true;
            self.last_callback_ns.store(rt::now_ns(), Ordering::Release);
            self.servo_running.store(true, Ordering::Release);
            return Ok(());
        }
        // Never called back: stop the scheduler (harmless when it never started), and the stack
        // is this thread's again.
        // SAFETY: functions of the loaded library on a handle it gave.
        unsafe {
            (api.stop_scheduler)();
            (api.unschedule)(handle);
            (api.disable)(HD_FORCE_OUTPUT);
        }
        control.scheduled = None;
        Err(StartFailure {
            step: "hdStartScheduler",
            code: self.lib.take_errors().worst(),
        })
    }

    /// Stops the servo loop: asks the callback to send zero force, switch force output off and
    /// unschedule itself, waits for it (at most [`STOP_DEADLINE`]: a driver that stopped calling
    /// back does not hold the stop), then stops the scheduler. The callback does not run after
    /// this returns.
    pub fn stop_servo(&self, control: &mut Control) {
        let api = &self.lib.api;
        if control.scheduler_running {
            self.stop_requested.store(true, Ordering::Release);
            let deadline = Instant::now() + STOP_DEADLINE;
            while !self.stop_done.load(Ordering::Acquire) && Instant::now() < deadline {
                std::thread::park_timeout(Duration::from_millis(1));
            }
            // SAFETY: functions of the loaded library, on handles it gave; unscheduling a
            // callback that already returned done is harmless.
            unsafe {
                if let Some(handle) = control.scheduled.take() {
                    (api.unschedule)(handle);
                }
                (api.stop_scheduler)();
            }
            control.scheduler_running = false;
            self.servo_running.store(false, Ordering::Release);
            if !self.stop_done.load(Ordering::Acquire) {
                // The callback did not answer: switch the output off from here (the stack is
                // this thread's now that the scheduler is stopped).
                // SAFETY: a function of the loaded library.
                unsafe { (api.disable)(HD_FORCE_OUTPUT) };
            }
            let _ = self.lib.take_errors();
        } else if let Some(handle) = control.scheduled.take() {
            // SAFETY: as above.
            unsafe { (api.unschedule)(handle) };
            let _ = self.lib.take_errors();
        }
        self.stop_requested.store(false, Ordering::Release);
    }

    /// Whether the calling thread has this device's servo frame open: only then may the device
    /// be read and commanded.
    fn in_frame_here(&self) -> bool {
        FRAME_OPEN_FOR.with(|f| std::ptr::eq(f.get(), self))
    }

    /// Disables the device handle, if any.
    pub fn disable_device(&self) {
        let handle = self.handle.swap(HD_INVALID_HANDLE, Ordering::AcqRel);
        if handle != HD_INVALID_HANDLE {
            // SAFETY: a handle the library gave and that was not disabled yet (swapped out).
            unsafe { (self.lib.api.disable_device)(handle) };
            let _ = self.lib.take_errors();
        }
    }

    /// Reads the device's description (outside a frame, scheduler stopped: these are device
    /// properties).
    pub fn describe(&self, name: Option<String>) -> DeviceDescription {
        let lib = self.lib;
        let usable: [f64; 6] = lib.get_doubles(HD_USABLE_WORKSPACE_DIMENSIONS);
        let max: [f64; 6] = lib.get_doubles(HD_MAX_WORKSPACE_DIMENSIONS);
        let corners = |b: [f64; 6]| [DVec3::new(b[0], b[1], b[2]), DVec3::new(b[3], b[4], b[5])];
        let description = DeviceDescription {
            name,
            model: lib.get_string(HD_DEVICE_MODEL_TYPE),
            vendor: lib.get_string(HD_DEVICE_VENDOR),
            serial: lib.get_string(HD_DEVICE_SERIAL_NUMBER),
            max_force_n: lib.get_doubles::<1>(HD_NOMINAL_MAX_FORCE)[0],
            continuous_force_n: lib.get_doubles::<1>(HD_NOMINAL_MAX_CONTINUOUS_FORCE)[0],
            max_stiffness_n_per_m: lib.get_doubles::<1>(HD_NOMINAL_MAX_STIFFNESS)[0] * 1e3,
            max_damping_n_s_per_m: lib.get_doubles::<1>(HD_NOMINAL_MAX_DAMPING)[0] * 1e3,
            usable_workspace_mm: corners(usable),
            max_workspace_mm: corners(max),
            calibration_styles: lib.get_integer(HD_CALIBRATION_STYLE) as u32,
        };
        // A property the device does not have is not an error of the session.
        let _ = lib.take_errors();
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

/// What the servo callback calls: the loop's tick.
pub(crate) struct ServoContext {
    pub inner: Arc<Inner>,
    pub tick: UnsafeCell<Box<dyn FnMut(u64) + Send>>,
}

/// Sends zero force in the open frame (the servo thread's).
fn send_zero(inner: &Inner) {
    let zero = [0.0f64; 3];
    // SAFETY: a function of the loaded library, inside a frame on its servo thread; `zero`
    // holds the three doubles HD_CURRENT_FORCE takes.
    unsafe { (inner.lib.api.set_doublev)(HD_CURRENT_FORCE, zero.as_ptr()) };
}

/// The servo tick: called by the HD scheduler's thread once per servo period.
unsafe extern "C" fn servo_callback(user: *mut c_void) -> HdCallbackCode {
    // SAFETY: `user` is the `ServoContext` the clock scheduled; it is freed only after the
    // callback was unscheduled and the scheduler stopped.
    let context = unsafe { &*user.cast::<ServoContext>() };
    let inner = &context.inner;
    let api = &inner.lib.api;
    let called_ns = rt::now_ns();
    inner.callback_calls.fetch_add(1, Ordering::AcqRel);
    inner.last_callback_ns.store(called_ns, Ordering::Release);
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
    if inner.stop_requested.load(Ordering::Acquire) {
        // The stop's last frame: zero force, output off, and no more calls.
        send_zero(inner);
        // SAFETY: as above; closes the frame this callback opened.
        unsafe {
            (api.end_frame)(handle);
            (api.disable)(HD_FORCE_OUTPUT);
        }
        // This thread owns the error stack: what the stop left there is of no further use.
        let _ = inner.lib.take_errors();
        inner.stop_done.store(true, Ordering::Release);
        return HD_CALLBACK_DONE;
    }
    inner.tick_start_ns.store(tick_start_ns, Ordering::Relaxed);
    FRAME_OPEN_FOR.with(|f| f.set(Arc::as_ptr(inner)));
    // SAFETY: only this callback touches the closure, and the scheduler calls it from one
    // thread, one call at a time.
    let tick = unsafe { &mut *context.tick.get() };
    // A panic must not unwind into C (that aborts); the tick's state is released on unwinding.
    let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| tick(tick_start_ns)));
    FRAME_OPEN_FOR.with(|f| f.set(std::ptr::null()));
    if outcome.is_err() {
        // A bug in the tick: whatever force it set before it failed must not go out.
        send_zero(inner);
        inner.fatal.store(true, Ordering::Release);
    }
    // SAFETY: as above; closes the frame this callback opened.
    unsafe { (api.end_frame)(handle) };
    match outcome {
        Ok(()) => HD_CALLBACK_CONTINUE,
        // Stop calling the tick (the driver then sends no force).
        Err(_) => HD_CALLBACK_DONE,
    }
}

/// A PHANTOM / Touch through the HD API (module docs of [`super`]).
pub struct OpenHapticsDevice {
    pub(crate) inner: Arc<Inner>,
    pub(crate) description: DeviceDescription,
    pub(crate) mapping: WorkspaceMapping,
    pub(crate) limits: DeviceLimits,
    pub(crate) overrun_after_ns: u64,
    pub(crate) opened_ns: u64,
    /// The device clock ([`OpenHapticsDevice::device_time_ns`]): the scheduler start it counts
    /// from, the start of that start's first servo tick and its device time.
    epoch_seen: u32,
    epoch_start_ns: u64,
    epoch_time_ns: u64,
    last_time_ns: Option<u64>,
    pub(crate) clock_taken: bool,
    /// Ticks read so far (the calibration check's clock).
    ticks: u64,
    /// The tick of the last calibration check.
    checked_at_tick: Option<u64>,
    /// The device reported itself calibrated at the last check.
    pub(crate) calibrated: bool,
    generation_seen: u32,
    /// The style `hdUpdateCalibration` is asked for when the driver can update by itself.
    update_style: Option<HdEnum>,
    /// The device resets its encoders at a reset position (the operator confirms with the
    /// stylus' button).
    encoder_reset: bool,
    /// The stylus' buttons at the last calibration check (a press is a new button).
    calibration_buttons: i32,
    /// Good and unreachable ticks in a row (since the last reconnection at most).
    health: LinkHealth,
    /// The driver's cut-out switched force output off: enabled again this tick unless latched.
    force_output_off: bool,
    /// Force output latched off after too many trips; an instructor's re-arm clears it.
    latched: bool,
    /// CLOCK_MONOTONIC times of the automatic re-arms within the window.
    rearm_times_ns: [u64; MAX_AUTO_REARMS],
    rearms: usize,
    rearm: RearmHandle,
    /// Ticks left of the warm-motors limit.
    warm_ticks: u32,
    /// Largest force magnitude sent, device axes, N.
    force_clamp_n: f64,
}

impl OpenHapticsDevice {
    pub(crate) fn new(
        inner: Arc<Inner>,
        description: DeviceDescription,
        mapping: WorkspaceMapping,
        limits: DeviceLimits,
        overrun_after_ns: u64,
    ) -> OpenHapticsDevice {
        let styles = description.calibration_styles;
        let update_style = [HD_CALIBRATION_AUTO, HD_CALIBRATION_INKWELL]
            .into_iter()
            .find(|s| styles & s != 0);
        // The device's own maximum where it reports one, else the limit in use.
        let nominal_n = if description.max_force_n > 0.0 {
            description.max_force_n
        } else {
            limits.peak_force_n
        };
        OpenHapticsDevice {
            inner,
            force_clamp_n: nominal_n * (1.0 - FORCE_MARGIN),
            encoder_reset: styles & HD_CALIBRATION_ENCODER_RESET != 0,
            description,
            mapping,
            limits,
            overrun_after_ns: overrun_after_ns.max(1),
            opened_ns: rt::now_ns(),
            epoch_seen: 0,
            epoch_start_ns: 0,
            epoch_time_ns: 0,
            last_time_ns: None,
            clock_taken: false,
            ticks: 0,
            checked_at_tick: None,
            calibrated: false,
            generation_seen: 0,
            update_style,
            calibration_buttons: 0,
            health: LinkHealth::default(),
            force_output_off: false,
            latched: false,
            rearm_times_ns: [0; MAX_AUTO_REARMS],
            rearms: 0,
            rearm: RearmHandle::default(),
            warm_ticks: 0,
        }
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
        if self.health.unreachable_tick() {
            // The reconnection thread polls the flag every few milliseconds: the servo path
            // signals nothing else (no lock, no system call).
            self.inner.reconnect_wanted.store(true, Ordering::Release);
        }
    }

    /// The error of a tick run outside a servo frame (the loop's watchdog, while the driver's
    /// clock is down).
    fn outside_frame_error(&self) -> DeviceError {
        if self.inner.fatal.load(Ordering::Acquire) {
            DeviceError::Fatal
        } else if self.inner.reconnect_wanted.load(Ordering::Acquire) {
            DeviceError::Disconnected
        } else {
            DeviceError::Timeout
        }
    }

    /// A force trip: re-armed at once unless it is one too many in the window, which latches the
    /// output off.
    fn book_trip(&mut self) -> DeviceError {
        self.force_output_off = true;
        let now = rt::now_ns();
        // Forget the re-arms that have left the window (in place: the servo thread never
        // allocates).
        let mut kept = 0;
        for i in 0..self.rearms {
            let t = self.rearm_times_ns[i];
            if now.saturating_sub(t) < REARM_WINDOW_NS {
                self.rearm_times_ns[kept] = t;
                kept += 1;
            }
        }
        self.rearms = kept;
        if self.rearms >= MAX_AUTO_REARMS {
            self.latched = true;
            return DeviceError::ForceLatched;
        }
        self.rearm_times_ns[self.rearms] = now;
        self.rearms += 1;
        DeviceError::ForceDisabled
    }

    /// Books what the error stack held; `Err` for a tick that must render no force.
    fn book(&mut self, seen: ErrorsSeen) -> Result<(), DeviceError> {
        if seen.warm {
            self.warm_ticks = WARM_HOLD_TICKS;
        }
        if let Some(code) = seen.worst().filter(|c| *c != HD_WARM_MOTORS) {
            self.inner.last_error.store(code, Ordering::Relaxed);
        }
        if seen.gone.is_some() {
            self.unreachable_tick();
            return Err(DeviceError::Disconnected);
        }
        if seen.trip.is_some() {
            return Err(self.book_trip());
        }
        if let Some(code) = seen.other {
            return Err(DeviceError::Driver(code as i32));
        }
        Ok(())
    }

    /// A new connection (the reconnection thread reopened the device): its calibration is
    /// checked again, and its failures are counted from zero, so that it gets
    /// [`RECONNECT_AFTER_FAILED_TICKS`](crate::backend::reconnect::RECONNECT_AFTER_FAILED_TICKS) ticks before it is reconnected again.
    fn follow_generation(&mut self) {
        let generation = self.inner.generation.load(Ordering::Acquire);
        if generation != self.generation_seen {
            self.generation_seen = generation;
            self.calibrated = false;
            self.checked_at_tick = None;
            self.health.restart();
            // A new connection's output starts off: enabled by the start.
            self.force_output_off = false;
        }
    }

    /// A good tick: after a run of them the connection counts as working again.
    fn good_tick(&mut self) {
        if self.health.good_tick() {
            self.inner.working.store(true, Ordering::Release);
        }
    }

    /// Checks the calibration (inside a frame), updates it where the device's style allows, and
    /// says what the operator must do otherwise.
    fn check_calibration(&mut self) -> Result<(), DeviceError> {
        self.checked_at_tick = Some(self.ticks);
        let lib = self.inner.lib;
        let api = &lib.api;
        // SAFETY: a function of the loaded library, inside a frame on its servo thread.
        let status = unsafe { (api.check_calibration)() };
        self.book(lib.take_errors())?;
        if status == HD_CALIBRATION_OK {
            self.calibrated = true;
            return Ok(());
        }
        self.calibrated = false;
        if status == HD_CALIBRATION_NEEDS_UPDATE
            && let Some(style) = self.update_style
        {
            // SAFETY: as above; takes effect from a later frame.
            unsafe { (api.update_calibration)(style) };
            let _ = self.book(lib.take_errors());
            return Err(DeviceError::CalibrationUpdating);
        }
        if self.encoder_reset && self.update_style.is_none() {
            // The operator holds the stylus at its reset position and presses its button.
            let buttons = lib.get_integer(HD_CURRENT_BUTTONS);
            let pressed = buttons & !self.calibration_buttons & 1 != 0;
            self.calibration_buttons = buttons;
            if pressed {
                // SAFETY: as above.
                unsafe { (api.update_calibration)(HD_CALIBRATION_ENCODER_RESET) };
            }
            let _ = self.book(lib.take_errors());
            return Err(DeviceError::NeedsCalibrationReset);
        }
        Err(DeviceError::NeedsCalibration)
    }

    /// The handle an instructor's re-arm goes through.
    pub fn rearm(&self) -> RearmHandle {
        self.rearm.clone()
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
        self.ticks += 1;
        self.follow_generation();
        let lib = self.inner.lib;
        let api = &lib.api;
        // Errors left by the last frame's end (the force was sent there) count for this tick.
        let booked = self.book(lib.take_errors());
        let requested = self.rearm.take();
        if self.latched && requested {
            // An instructor re-armed the output: the trips are forgotten, and the world ramps
            // the force in again after the latched ticks.
            self.latched = false;
            self.rearms = 0;
        }
        if self.force_output_off && !self.latched {
            // SAFETY: a function of the loaded library, inside a frame on its servo thread.
            unsafe { (api.enable)(HD_FORCE_OUTPUT) };
            self.force_output_off = false;
            self.book(lib.take_errors())?;
        }
        booked?;
        let due = !self.calibrated
            || self
                .checked_at_tick
                .is_none_or(|t| self.ticks - t >= CALIBRATION_CHECK_TICKS);
        if due {
            self.check_calibration()?;
        }
        let transform: [f64; 16] = lib.get_doubles(HD_CURRENT_TRANSFORM);
        let velocity: [f64; 3] = lib.get_doubles(HD_CURRENT_VELOCITY);
        let buttons = lib.get_integer(HD_CURRENT_BUTTONS);
        self.book(lib.take_errors())?;
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
        let mut flags = ContactFlags::empty();
        if self.warm_ticks > 0 {
            self.warm_ticks -= 1;
            flags |= ContactFlags::MOTORS_WARM;
        }
        if self.mapping.outside_usable(position_mm) {
            flags |= ContactFlags::OUTSIDE_WORKSPACE;
        }
        Ok(DeviceSample {
            time_ns,
            tip_in_world: Pose {
                position_m: self.mapping.position_m(position_mm),
                orientation,
            },
            tip_velocity_m_s: self.mapping.velocity_m_s(DVec3::from_array(velocity)),
            buttons: buttons as u32,
            flags,
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
        if self.latched {
            send_zero(&inner);
            return Err(DeviceError::ForceLatched);
        }
        // A force the driver would not apply (the device lost its calibration since the last
        // check) must not be shown as rendered: check before sending any.
        if force_n != DVec3::ZERO
            && self.checked_at_tick != Some(self.ticks)
            && let Err(e) = self.check_calibration()
        {
            send_zero(&inner);
            return Err(e);
        }
        // SAFETY: a function of the loaded library, inside a frame on its servo thread.
        let since_tick_s = unsafe { (api.get_scheduler_time_stamp)() };
        let overran = since_tick_s.is_finite() && since_tick_s * 1e9 > self.overrun_after_ns as f64;
        let mut device_n = self.mapping.force_device_n(force_n);
        let size = device_n.length();
        if size > self.force_clamp_n {
            // The world saturates in its own axes; the rotation into the device's may round a
            // hair above the device's limit, which the driver would refuse.
            device_n *= self.force_clamp_n / size;
        }
        let sent = if overran || !device_n.is_finite() {
            [0.0; 3]
        } else {
            device_n.to_array()
        };
        // SAFETY: as above; `sent` holds the three doubles HD_CURRENT_FORCE takes.
        unsafe { (api.set_doublev)(HD_CURRENT_FORCE, sent.as_ptr()) };
        if let Err(e) = self.book(inner.lib.take_errors()) {
            send_zero(&inner);
            let _ = inner.lib.take_errors();
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

    fn rearm_handle(&self) -> Option<RearmHandle> {
        Some(self.rearm.clone())
    }
}

/// The words of a failed start: the call, the driver's error and what to do about it.
pub(crate) fn start_failure_text(inner: &Inner, failure: StartFailure) -> String {
    let what = match failure.code {
        Some(code) => format!("{} ({})", inner.lib.error_text(code), error_name(code)),
        None => format!(
            "the scheduler's servo callback was not called within {} s and the driver gave no error",
            START_DEADLINE.as_secs()
        ),
    };
    let hint = match failure.code {
        Some(HD_TIMER_ERROR) => {
            "the operating system refused the driver's 1 kHz servo timer: give this user \
             real-time scheduling (an rtprio limit, as the service unit sets), and make sure no \
             other program is using the device"
        }
        Some(code) if super::ffi::is_gone(code) => {
            "check that the device is plugged in and powered, and that no other program holds it"
        }
        _ => {
            "another program may hold the device, or its driver is stuck: close other haptic \
             programs, unplug and replug the device, and try again"
        }
    };
    format!(
        "the haptic device {:?} did not start: {} failed: {what}; {hint}",
        inner.display_name, failure.step
    )
}

/// The HD scheduler as the loop's clock, and the reconnection thread that restarts it.
pub struct HdServoClock {
    inner: Arc<Inner>,
    reconnector: Option<std::thread::JoinHandle<()>>,
}

impl ServoClock for HdServoClock {
    fn period_ns(&self) -> u64 {
        self.inner.period_ns
    }

    fn start(&mut self, tick: Box<dyn FnMut(u64) + Send>) -> Result<(), ServoStartError> {
        let context = Box::new(ServoContext {
            inner: Arc::clone(&self.inner),
            tick: UnsafeCell::new(tick),
        });
        {
            let mut control = self.inner.control();
            Inner::set_context(&mut control, context);
            if let Err(failure) = self.inner.start_servo(&mut control) {
                let text = start_failure_text(&self.inner, failure);
                tracing::error!(device = %self.inner.display_name, "{text}");
                free_context(&mut control);
                return Err(ServoStartError(text));
            }
        }
        let inner = Arc::clone(&self.inner);
        let spawned = std::thread::Builder::new()
            .name("haptic-reconnect".into())
            .spawn(move || super::recovery::reconnect_when_asked(&inner));
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
pub(crate) fn free_context(control: &mut Control) {
    if let Some(ContextPtr(ptr)) = control.context.take() {
        // SAFETY: the pointer came from `Box::leak` in `set_context`, and the callback that used
        // it was unscheduled and its scheduler stopped (or never started).
        drop(unsafe { Box::from_raw(ptr.as_ptr()) });
    }
}
