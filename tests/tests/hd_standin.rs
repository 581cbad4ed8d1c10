//! The HD API stand-in (`tests/standin/hd_standin.c`) keeps the rules of OpenHaptics' HD API that
//! the backend is written against: its scheduler, frames, error stack, force limit, faults,
//! calibration and hand. The tests call its HD API directly, as the backend does, through
//! libloading, and drive it through its test controls ([`StandIn`]).
//!
//! The stand-in is one per process, so the tests take turns ([`LOCK`]) and each starts from
//! `hdStandinReset`. Nothing asserts a wall-clock rate: the tests count servo ticks and poll
//! for conditions with generous deadlines.
//!
//! Long because the stand-in is one per process: its 23 tests share a lock and the HD bindings.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::ffi::{CStr, CString, c_char, c_double, c_int, c_uint, c_ulong, c_ushort, c_void};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard, OnceLock, PoisonError};
use std::thread::ThreadId;
use std::time::{Duration, Instant};

use softhaptic_tests::standin::hd::*;
use softhaptic_tests::standin::{StandIn, missing_symbol_path, standin_path};

/// The deadline of every poll: far beyond what any condition needs on an idle machine.
const WAIT: Duration = Duration::from_secs(10);

/// What an output buffer holds before a call that must leave it untouched.
const UNTOUCHED: f64 = -12345.0;
const UNTOUCHED_INT: c_int = c_int::MIN;

/// An empty error stack.
const NO_ERRORS: [c_uint; 0] = [];

/// The stand-in's hand starts 20 mm above the default press point (the origin).
const START_MM: [f64; 3] = [0.0, 20.0, 0.0];

#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct ErrorInfo {
    code: c_uint,
    internal: c_int,
    device: c_uint,
}

type Callback = unsafe extern "C" fn(*mut c_void) -> c_uint;

/// The HD API as the backend sees it, from the stand-in. The methods are safe because the
/// stand-in is safe to call with any value; the pointers they pass are checked by their types.
struct Hd {
    _library: libloading::Library,
    init_device: unsafe extern "C" fn(*const c_char) -> c_uint,
    disable_device: unsafe extern "C" fn(c_uint),
    make_current_device: unsafe extern "C" fn(c_uint),
    get_current_device: unsafe extern "C" fn() -> c_uint,
    get_error: unsafe extern "C" fn() -> ErrorInfo,
    get_error_string: unsafe extern "C" fn(c_uint) -> *const c_char,
    enable: unsafe extern "C" fn(c_uint),
    disable: unsafe extern "C" fn(c_uint),
    is_enabled: unsafe extern "C" fn(c_uint) -> u8,
    start_scheduler: unsafe extern "C" fn(),
    stop_scheduler: unsafe extern "C" fn(),
    set_scheduler_rate: unsafe extern "C" fn(c_ulong),
    schedule_asynchronous: unsafe extern "C" fn(Option<Callback>, *mut c_void, c_ushort) -> c_ulong,
    schedule_synchronous: unsafe extern "C" fn(Option<Callback>, *mut c_void, c_ushort),
    unschedule: unsafe extern "C" fn(c_ulong),
    get_scheduler_time_stamp: unsafe extern "C" fn() -> c_double,
    begin_frame: unsafe extern "C" fn(c_uint),
    end_frame: unsafe extern "C" fn(c_uint),
    get_doublev: unsafe extern "C" fn(c_uint, *mut c_double),
    get_integerv: unsafe extern "C" fn(c_uint, *mut c_int),
    get_string: unsafe extern "C" fn(c_uint) -> *const c_char,
    set_doublev: unsafe extern "C" fn(c_uint, *const c_double),
    check_calibration: unsafe extern "C" fn() -> c_uint,
    update_calibration: unsafe extern "C" fn(c_uint),
}

macro_rules! symbol {
    ($library:expr, $name:literal) => {{
        // SAFETY: the stand-in exports `$name` with the C signature of the field it is stored in.
        let symbol = unsafe { $library.get(concat!($name, "\0").as_bytes()) }.unwrap();
        *symbol
    }};
}

/// Runs `f` (a `&F` passed as the user pointer) on the scheduler thread.
unsafe extern "C" fn closure_callback<F: Fn() -> c_uint + Sync>(user: *mut c_void) -> c_uint {
    // SAFETY: `user` is the `&F` given to `schedule_async` ('static) or `schedule_sync` (alive
    // until the call returns, after the callback ran).
    let f = unsafe { &*user.cast_const().cast::<F>() };
    f()
}

impl Hd {
    fn load() -> Hd {
        // SAFETY: loading runs only the stand-in's constructor (its own globals).
        let library = unsafe { libloading::Library::new(standin_path()) }.unwrap();
        Hd {
            init_device: symbol!(library, "hdInitDevice"),
            disable_device: symbol!(library, "hdDisableDevice"),
            make_current_device: symbol!(library, "hdMakeCurrentDevice"),
            get_current_device: symbol!(library, "hdGetCurrentDevice"),
            get_error: symbol!(library, "hdGetError"),
            get_error_string: symbol!(library, "hdGetErrorString"),
            enable: symbol!(library, "hdEnable"),
            disable: symbol!(library, "hdDisable"),
            is_enabled: symbol!(library, "hdIsEnabled"),
            start_scheduler: symbol!(library, "hdStartScheduler"),
            stop_scheduler: symbol!(library, "hdStopScheduler"),
            set_scheduler_rate: symbol!(library, "hdSetSchedulerRate"),
            schedule_asynchronous: symbol!(library, "hdScheduleAsynchronous"),
            schedule_synchronous: symbol!(library, "hdScheduleSynchronous"),
            unschedule: symbol!(library, "hdUnschedule"),
            get_scheduler_time_stamp: symbol!(library, "hdGetSchedulerTimeStamp"),
            begin_frame: symbol!(library, "hdBeginFrame"),
            end_frame: symbol!(library, "hdEndFrame"),
            get_doublev: symbol!(library, "hdGetDoublev"),
            get_integerv: symbol!(library, "hdGetIntegerv"),
            get_string: symbol!(library, "hdGetString"),
            set_doublev: symbol!(library, "hdSetDoublev"),
            check_calibration: symbol!(library, "hdCheckCalibration"),
            update_calibration: symbol!(library, "hdUpdateCalibration"),
            _library: library,
        }
    }

    fn init(&self, name: Option<&str>) -> c_uint {
        let name = name.map(|n| CString::new(n).unwrap());
        let pointer = name.as_ref().map_or(std::ptr::null(), |n| n.as_ptr());
        // SAFETY: NULL or a NUL-terminated string alive for the call.
        unsafe { (self.init_device)(pointer) }
    }

    /// Opens the default device and enables its force output, as every application does (it is
    /// off after `hdInitDevice`).
    fn open(&self) -> c_uint {
        let h = self.init(None);
        self.enable(HD_FORCE_OUTPUT);
        h
    }

    fn disable_device(&self, h: c_uint) {
        // SAFETY: plain values (as are all the calls below without a further comment).
        unsafe { (self.disable_device)(h) }
    }

    fn make_current(&self, h: c_uint) {
        // SAFETY: a plain value.
        unsafe { (self.make_current_device)(h) }
    }

    fn current_device(&self) -> c_uint {
        // SAFETY: no arguments.
        unsafe { (self.get_current_device)() }
    }

    fn error(&self) -> ErrorInfo {
        // SAFETY: no arguments; the struct is returned by value, laid out as HDErrorInfo.
        unsafe { (self.get_error)() }
    }

    /// Pops the whole error stack: codes, most recent first.
    fn errors(&self) -> Vec<c_uint> {
        let mut codes = Vec::new();
        for _ in 0..64 {
            let e = self.error();
            if e.code == HD_SUCCESS {
                break;
            }
            codes.push(e.code);
        }
        codes
    }

    fn error_string(&self, code: c_uint) -> String {
        // SAFETY: a plain value; the stand-in returns a static NUL-terminated string.
        let s = unsafe { (self.get_error_string)(code) };
        assert!(!s.is_null());
        // SAFETY: non-null, static and NUL-terminated.
        unsafe { CStr::from_ptr(s) }.to_string_lossy().into_owned()
    }

    fn enable(&self, cap: c_uint) {
        // SAFETY: a plain value.
        unsafe { (self.enable)(cap) }
    }

    fn disable(&self, cap: c_uint) {
        // SAFETY: a plain value.
        unsafe { (self.disable)(cap) }
    }

    fn is_enabled(&self, cap: c_uint) -> bool {
        // SAFETY: a plain value.
        unsafe { (self.is_enabled)(cap) != 0 }
    }

    fn start_scheduler(&self) {
        // SAFETY: no arguments.
        unsafe { (self.start_scheduler)() }
    }

    fn stop_scheduler(&self) {
        // SAFETY: no arguments.
        unsafe { (self.stop_scheduler)() }
    }

    fn set_rate(&self, hz: c_ulong) {
        // SAFETY: a plain value.
        unsafe { (self.set_scheduler_rate)(hz) }
    }

    /// Schedules `f` to run every servo tick while it returns `HD_CALLBACK_CONTINUE`.
    fn schedule_async<F: Fn() -> c_uint + Sync>(
        &'static self,
        f: &'static F,
        priority: u16,
    ) -> u64 {
        let user = std::ptr::from_ref(f).cast_mut().cast::<c_void>();
        // SAFETY: `closure_callback::<F>` reads `user` as the `&'static F` it is.
        unsafe { (self.schedule_asynchronous)(Some(closure_callback::<F>), user, priority) }
    }

    /// Runs `f` once on the scheduler thread and returns after it ran.
    fn schedule_sync<F: Fn() -> c_uint + Sync>(&self, f: &F, priority: u16) {
        let user = std::ptr::from_ref(f).cast_mut().cast::<c_void>();
        // SAFETY: `f` outlives the call, which returns only once the callback ran or never will.
        unsafe { (self.schedule_synchronous)(Some(closure_callback::<F>), user, priority) }
    }

    fn unschedule(&self, handle: u64) {
        // SAFETY: a plain value.
        unsafe { (self.unschedule)(handle) }
    }

    fn time_stamp(&self) -> f64 {
        // SAFETY: no arguments.
        unsafe { (self.get_scheduler_time_stamp)() }
    }

    fn begin(&self, h: c_uint) {
        // SAFETY: a plain value.
        unsafe { (self.begin_frame)(h) }
    }

    fn end(&self, h: c_uint) {
        // SAFETY: a plain value.
        unsafe { (self.end_frame)(h) }
    }

    /// `hdGetDoublev` into 16 doubles (the most any value has), [`UNTOUCHED`] beforehand.
    fn get_doublev(&self, pname: c_uint) -> [f64; 16] {
        let mut out = [UNTOUCHED; 16];
        // SAFETY: room for the largest value (the 16-double transform).
        unsafe { (self.get_doublev)(pname, out.as_mut_ptr()) };
        out
    }

    fn get_integerv(&self, pname: c_uint) -> [c_int; 16] {
        let mut out = [UNTOUCHED_INT; 16];
        // SAFETY: room for the largest value.
        unsafe { (self.get_integerv)(pname, out.as_mut_ptr()) };
        out
    }

    fn get_string(&self, pname: c_uint) -> Option<String> {
        // SAFETY: a plain value; the result is NULL or a NUL-terminated string that stays valid
        // while the device is open.
        let s = unsafe { (self.get_string)(pname) };
        if s.is_null() {
            return None;
        }
        // SAFETY: non-null and NUL-terminated (above).
        Some(unsafe { CStr::from_ptr(s) }.to_string_lossy().into_owned())
    }

    fn set_doublev(&self, pname: c_uint, values: &[f64; 3]) {
        // SAFETY: three readable doubles, all HD_CURRENT_FORCE reads.
        unsafe { (self.set_doublev)(pname, values.as_ptr()) }
    }

    fn check_calibration(&self) -> c_uint {
        // SAFETY: no arguments.
        unsafe { (self.check_calibration)() }
    }

    fn update_calibration(&self, style: c_uint) {
        // SAFETY: a plain value.
        unsafe { (self.update_calibration)(style) }
    }

    /// One frame that sends `force_n`.
    fn send(&self, h: c_uint, force_n: [f64; 3]) {
        self.begin(h);
        self.set_doublev(HD_CURRENT_FORCE, &force_n);
        self.end(h);
    }

    /// One frame's position.
    fn position(&self, h: c_uint) -> [f64; 3] {
        self.begin(h);
        let p = self.get_doublev(HD_CURRENT_POSITION);
        self.end(h);
        [p[0], p[1], p[2]]
    }
}

fn hd() -> &'static Hd {
    static HD: OnceLock<Hd> = OnceLock::new();
    HD.get_or_init(Hd::load)
}

fn standin() -> &'static StandIn {
    static STANDIN: OnceLock<StandIn> = OnceLock::new();
    STANDIN.get_or_init(|| StandIn::load().unwrap())
}

/// The tests share the stand-in's globals: one at a time.
static LOCK: Mutex<()> = Mutex::new(());

/// Takes the turn and resets the stand-in.
fn setup() -> (MutexGuard<'static, ()>, &'static Hd, &'static StandIn) {
    let guard = LOCK.lock().unwrap_or_else(PoisonError::into_inner);
    let s = standin();
    s.reset();
    // Most tests here look at one frame's state from the test thread; the rule that frames
    // belong to the scheduler thread has its own test, which sets this back.
    s.frames_from_any_thread(true);
    (guard, hd(), s)
}

/// Test state the scheduler thread touches: leaked, so a failing test can never leave a callback
/// pointing at freed memory.
fn leak<T>(value: T) -> &'static T {
    Box::leak(Box::new(value))
}

fn wait_until(what: &str, condition: impl Fn() -> bool) {
    let deadline = Instant::now() + WAIT;
    while !condition() {
        assert!(Instant::now() < deadline, "timed out waiting until {what}");
        std::thread::sleep(Duration::from_millis(1));
    }
}

fn close(a: f64, b: f64, tolerance: f64) -> bool {
    (a - b).abs() <= tolerance
}

/// The built-in hand's target height (mm) at script time `t_s`, default press: 20 mm above the
/// origin down to 8 mm below it and back over 3 s, cosine profile.
fn press_target_y_mm(t_s: f64) -> f64 {
    let phase = (t_s % 3.0) / 3.0;
    20.0 - 28.0 * (0.5 - 0.5 * (2.0 * std::f64::consts::PI * phase).cos())
}

#[test]
fn the_scheduler_calls_an_asynchronous_callback_once_per_servo_tick() {
    let (_turn, hd, s) = setup();
    let calls = leak(AtomicU64::new(0));
    hd.start_scheduler();
    assert!(s.scheduler_running());
    let before = s.ticks();
    let handle = hd.schedule_async(
        leak(move || {
            calls.fetch_add(1, Ordering::SeqCst);
            HD_CALLBACK_CONTINUE
        }),
        HD_DEFAULT_SCHEDULER_PRIORITY,
    );
    assert_ne!(handle, u64::from(HD_INVALID_HANDLE));
    wait_until("50 calls", || calls.load(Ordering::SeqCst) >= 50);
    hd.unschedule(handle);
    let ticks = s.ticks() - before;
    let n = calls.load(Ordering::SeqCst);
    // A tick already under way when the counts were read may or may not have called it.
    assert!(
        n <= ticks + 1 && n + 2 >= ticks,
        "{n} calls in {ticks} ticks"
    );
    assert!(s.wait_for_ticks(5, WAIT));
    assert_eq!(
        calls.load(Ordering::SeqCst),
        n,
        "unscheduled: no more calls"
    );
    assert_eq!(s.scheduled_callbacks(), 0);
    assert_eq!(hd.errors(), NO_ERRORS);
}

#[test]
fn callbacks_run_highest_priority_first_and_one_returning_done_runs_once() {
    let (_turn, hd, s) = setup();
    let order = leak(Mutex::new(String::new()));
    let once = leak(AtomicU64::new(0));
    // Scheduled before the scheduler starts, so that every pass sees all three.
    hd.schedule_async(
        leak(move || {
            order.lock().unwrap().push('L');
            HD_CALLBACK_CONTINUE
        }),
        HD_MIN_SCHEDULER_PRIORITY,
    );
    hd.schedule_async(
        leak(move || {
            once.fetch_add(1, Ordering::SeqCst);
            HD_CALLBACK_DONE
        }),
        HD_DEFAULT_SCHEDULER_PRIORITY,
    );
    hd.schedule_async(
        leak(move || {
            order.lock().unwrap().push('H');
            HD_CALLBACK_CONTINUE
        }),
        HD_MAX_SCHEDULER_PRIORITY,
    );
    hd.start_scheduler();
    wait_until("20 passes", || order.lock().unwrap().len() >= 40);
    hd.stop_scheduler();
    let order = order.lock().unwrap().clone();
    assert_eq!(
        order,
        "HL".repeat(order.len() / 2),
        "every pass: high, then low"
    );
    assert_eq!(once.load(Ordering::SeqCst), 1);
    assert_eq!(
        s.scheduled_callbacks(),
        2,
        "the one that returned done is gone"
    );
}

#[test]
fn hd_schedule_synchronous_runs_once_on_the_scheduler_thread_and_returns_after_it() {
    let (_turn, hd, s) = setup();
    let servo_thread = leak(Mutex::new(None::<ThreadId>));
    hd.schedule_async(
        leak(move || {
            *servo_thread.lock().unwrap() = Some(std::thread::current().id());
            HD_CALLBACK_DONE
        }),
        HD_DEFAULT_SCHEDULER_PRIORITY,
    );
    hd.start_scheduler();

    let calls = AtomicU64::new(0);
    let ran_on = Mutex::new(None::<ThreadId>);
    let callback = || {
        calls.fetch_add(1, Ordering::SeqCst);
        *ran_on.lock().unwrap() = Some(std::thread::current().id());
        // Even a synchronous callback that asks to continue runs once.
        HD_CALLBACK_CONTINUE
    };
    hd.schedule_sync(&callback, HD_DEFAULT_SCHEDULER_PRIORITY);
    assert_eq!(
        calls.load(Ordering::SeqCst),
        1,
        "it ran before the call returned"
    );
    assert_eq!(hd.errors(), NO_ERRORS);
    let ran_on = ran_on.lock().unwrap().unwrap();
    assert_ne!(ran_on, std::thread::current().id());
    wait_until("the asynchronous callback ran", || {
        servo_thread.lock().unwrap().is_some()
    });
    assert_eq!(
        Some(ran_on),
        *servo_thread.lock().unwrap(),
        "the servo thread"
    );
    assert!(s.wait_for_ticks(5, WAIT));
    assert_eq!(calls.load(Ordering::SeqCst), 1, "and never again");
}

#[test]
fn hd_schedule_synchronous_on_a_stopped_scheduler_never_returns_and_calls_nothing() {
    let (_turn, hd, s) = setup();
    let calls = leak(AtomicU64::new(0));
    let returned = leak(AtomicBool::new(false));
    // On the vendor's library the call waits for a tick that never comes: a caller that makes it
    // hangs. The hang is seen from another thread, within a deadline.
    let caller = std::thread::spawn(move || {
        let callback = || {
            calls.fetch_add(1, Ordering::SeqCst);
            HD_CALLBACK_DONE
        };
        hd.schedule_sync(&callback, HD_DEFAULT_SCHEDULER_PRIORITY);
        returned.store(true, Ordering::SeqCst);
    });
    wait_until("the call is queued", || s.scheduled_callbacks() == 1);
    // Not a count after a sleep: nothing may happen however long one waits; a quarter second
    // is far beyond a servo tick.
    std::thread::sleep(Duration::from_millis(250));
    assert!(
        !returned.load(Ordering::SeqCst),
        "returned without a scheduler"
    );
    assert_eq!(calls.load(Ordering::SeqCst), 0);
    // A stop does not release it either.
    hd.stop_scheduler();
    assert!(!returned.load(Ordering::SeqCst));
    // Only the test control lets it go (the vendor's library would never).
    s.reset();
    caller.join().unwrap();
    assert!(returned.load(Ordering::SeqCst));
    assert_eq!(calls.load(Ordering::SeqCst), 0);
}

#[test]
fn frames_belong_to_the_scheduler_thread_one_per_tick_and_force_output_starts_off() {
    let (_turn, hd, s) = setup();
    s.frames_from_any_thread(false);
    let h = hd.init(None);
    assert!(!s.force_output_enabled(), "off after hdInitDevice");
    hd.begin(h);
    assert_eq!(
        hd.errors(),
        [HD_ILLEGAL_BEGIN],
        "a frame off the servo thread"
    );
    hd.enable(HD_FORCE_OUTPUT);
    let second_begin = leak(Mutex::new(Vec::<c_uint>::new()));
    let ran = leak(AtomicU64::new(0));
    hd.schedule_async(
        leak(move || {
            hd.send(h, [0.0, 0.5, 0.0]);
            // A second frame in the same servo tick is refused (HD_ONE_FRAME_LIMIT).
            hd.begin(h);
            let e = hd.error().code;
            if e != HD_SUCCESS {
                second_begin.lock().unwrap().push(e);
            }
            ran.fetch_add(1, Ordering::SeqCst);
            HD_CALLBACK_CONTINUE
        }),
        HD_DEFAULT_SCHEDULER_PRIORITY,
    );
    hd.start_scheduler();
    wait_until("five ticks", || ran.load(Ordering::SeqCst) >= 5);
    hd.stop_scheduler();
    let refused = second_begin.lock().unwrap().clone();
    assert!(
        refused.len() >= 5 && refused.iter().all(|e| *e == HD_ILLEGAL_BEGIN),
        "{refused:?}"
    );
    // The first frame of each tick worked: its force reached the motors.
    assert!(
        s.last_force_n() == [0.0; 3],
        "a stopped scheduler drives nothing"
    );
}

#[test]
fn hd_stop_scheduler_joins_the_servo_thread_so_no_callback_runs_after_it_returns() {
    let (_turn, hd, s) = setup();
    let h = hd.open();
    let inside = leak(AtomicBool::new(false));
    let calls = leak(AtomicU64::new(0));
    hd.schedule_async(
        leak(move || {
            inside.store(true, Ordering::SeqCst);
            calls.fetch_add(1, Ordering::SeqCst);
            hd.send(h, [0.0, 1.0, 0.0]);
            // Long enough that a stop that did not wait would often return in the middle.
            let busy = Instant::now();
            while busy.elapsed() < Duration::from_micros(200) {
                std::hint::spin_loop();
            }
            inside.store(false, Ordering::SeqCst);
            HD_CALLBACK_CONTINUE
        }),
        HD_DEFAULT_SCHEDULER_PRIORITY,
    );
    hd.start_scheduler();
    wait_until("20 calls", || calls.load(Ordering::SeqCst) >= 20);
    assert_eq!(s.last_force_n(), [0.0, 1.0, 0.0]);

    hd.stop_scheduler();
    assert!(!inside.load(Ordering::SeqCst), "stopped mid-callback");
    assert!(!s.scheduler_running());
    assert_eq!(s.last_force_n(), [0.0; 3], "no servo loop, no force");
    let (n, ticks) = (calls.load(Ordering::SeqCst), s.ticks());
    std::thread::sleep(Duration::from_millis(20));
    assert_eq!(calls.load(Ordering::SeqCst), n);
    assert_eq!(s.ticks(), ticks);

    // The callback stays scheduled across a stop.
    assert_eq!(s.scheduled_callbacks(), 1);
    hd.start_scheduler();
    wait_until("a call after the restart", || {
        calls.load(Ordering::SeqCst) > n
    });
    assert_eq!(hd.errors(), NO_ERRORS);
}

#[test]
fn a_callback_may_unschedule_itself_and_unschedule_waits_for_a_running_callback() {
    let (_turn, hd, s) = setup();
    let own = leak(AtomicU64::new(0));
    let calls = leak(AtomicU64::new(0));
    let handle = hd.schedule_async(
        leak(move || {
            calls.fetch_add(1, Ordering::SeqCst);
            hd.unschedule(own.load(Ordering::SeqCst));
            HD_CALLBACK_CONTINUE
        }),
        HD_DEFAULT_SCHEDULER_PRIORITY,
    );
    own.store(handle, Ordering::SeqCst);
    hd.start_scheduler();
    assert!(s.wait_for_ticks(10, WAIT));
    assert_eq!(calls.load(Ordering::SeqCst), 1);
    assert_eq!(s.scheduled_callbacks(), 0);

    let inside = leak(AtomicBool::new(false));
    let slow = hd.schedule_async(
        leak(move || {
            inside.store(true, Ordering::SeqCst);
            std::thread::sleep(Duration::from_millis(20));
            inside.store(false, Ordering::SeqCst);
            HD_CALLBACK_CONTINUE
        }),
        HD_DEFAULT_SCHEDULER_PRIORITY,
    );
    wait_until("the slow callback is running", || {
        inside.load(Ordering::SeqCst)
    });
    hd.unschedule(slow);
    assert!(
        !inside.load(Ordering::SeqCst),
        "hdUnschedule returned while its callback ran"
    );
    // Unscheduling again (or a handle never given) is harmless.
    hd.unschedule(slow);
    hd.unschedule(987_654);
    assert_eq!(hd.errors(), NO_ERRORS);
}

#[test]
fn current_state_gets_and_sets_outside_a_frame_push_frame_error_and_leave_the_output_untouched() {
    let (_turn, hd, _s) = setup();
    let h = hd.open();
    assert_ne!(h, HD_INVALID_HANDLE);
    for pname in [
        HD_CURRENT_POSITION,
        HD_CURRENT_VELOCITY,
        HD_CURRENT_TRANSFORM,
        HD_CURRENT_FORCE,
        HD_LAST_FORCE,
    ] {
        assert_eq!(hd.get_doublev(pname), [UNTOUCHED; 16], "{pname:#x}");
        assert_eq!(hd.errors(), [HD_FRAME_ERROR], "{pname:#x}");
    }
    assert_eq!(hd.get_integerv(HD_CURRENT_BUTTONS), [UNTOUCHED_INT; 16]);
    assert_eq!(hd.errors(), [HD_FRAME_ERROR]);
    hd.set_doublev(HD_CURRENT_FORCE, &[0.0, 1.0, 0.0]);
    assert_eq!(hd.errors(), [HD_FRAME_ERROR]);

    // Inside a frame the same calls work.
    assert_eq!(hd.position(h), START_MM);
    assert_eq!(hd.errors(), NO_ERRORS);

    // A frame belongs to the thread that began it.
    hd.begin(h);
    let elsewhere = std::thread::scope(|scope| {
        scope
            .spawn(|| hd.get_doublev(HD_CURRENT_POSITION))
            .join()
            .unwrap()
    });
    hd.end(h);
    assert_eq!(elsewhere, [UNTOUCHED; 16]);
    assert_eq!(hd.errors(), [HD_FRAME_ERROR]);
}

#[test]
fn a_begin_inside_a_frame_pushes_illegal_begin_and_an_end_without_a_begin_pushes_illegal_end() {
    let (_turn, hd, _s) = setup();
    let h = hd.open();
    hd.end(h);
    assert_eq!(
        hd.error(),
        ErrorInfo {
            code: HD_ILLEGAL_END,
            internal: 0,
            device: h
        }
    );
    hd.begin(h);
    hd.begin(h);
    assert_eq!(hd.errors(), [HD_ILLEGAL_BEGIN]);
    // The first frame is still open.
    assert_eq!(hd.get_doublev(HD_CURRENT_POSITION)[..3], START_MM);
    hd.end(h);
    assert_eq!(hd.errors(), NO_ERRORS);
    hd.end(h);
    assert_eq!(hd.errors(), [HD_ILLEGAL_END]);

    // A bad handle begins no frame.
    hd.begin(h + 7);
    assert_eq!(hd.errors(), [HD_BAD_HANDLE]);
    hd.get_doublev(HD_CURRENT_POSITION);
    assert_eq!(hd.errors(), [HD_FRAME_ERROR]);
}

#[test]
fn the_error_stack_pops_the_most_recent_error_first_and_reads_success_when_empty() {
    let (_turn, hd, _s) = setup();
    let empty = ErrorInfo {
        code: HD_SUCCESS,
        internal: 0,
        device: HD_INVALID_HANDLE,
    };
    assert_eq!(hd.error(), empty);
    hd.end(0); // no frame
    hd.get_doublev(HD_CURRENT_POSITION); // outside a frame
    hd.get_doublev(HD_NOMINAL_MAX_FORCE); // no device open
    assert_eq!(hd.error().code, HD_BAD_HANDLE);
    assert_eq!(hd.error().code, HD_FRAME_ERROR);
    assert_eq!(hd.error().code, HD_ILLEGAL_END);
    assert_eq!(hd.error(), empty);
    assert_eq!(hd.error(), empty);

    // Bounded: the newest 32 are kept.
    for device in 0..40 {
        hd.end(device);
    }
    for device in (8..40).rev() {
        assert_eq!(
            hd.error(),
            ErrorInfo {
                code: HD_ILLEGAL_END,
                internal: 0,
                device
            }
        );
    }
    assert_eq!(hd.error(), empty);

    assert!(hd.error_string(HD_COMM_ERROR).contains("communication"));
    assert!(hd.error_string(HD_EXCEEDED_MAX_FORCE).contains("force"));
    assert!(!hd.error_string(0xBEEF).is_empty());
}

#[test]
fn a_force_beyond_the_nominal_maximum_is_refused_sends_zero_and_switches_force_output_off() {
    let (_turn, hd, s) = setup();
    let h = hd.open();
    hd.start_scheduler();
    assert!(hd.is_enabled(HD_FORCE_OUTPUT), "on after init");
    hd.send(h, [0.0, 1.0, 0.0]);
    assert_eq!(s.last_force_n(), [0.0, 1.0, 0.0]);
    assert_eq!(hd.errors(), NO_ERRORS);

    hd.send(h, [0.0, 0.0, 9.0]);
    assert_eq!(hd.errors(), [HD_EXCEEDED_MAX_FORCE]);
    assert_eq!(s.last_force_n(), [0.0; 3]);
    assert!(!s.force_output_enabled());
    assert!(!hd.is_enabled(HD_FORCE_OUTPUT));
    hd.send(h, [0.0, 1.0, 0.0]);
    assert_eq!(s.last_force_n(), [0.0; 3], "off until enabled again");
    assert_eq!(hd.errors(), NO_ERRORS);
    hd.enable(HD_FORCE_OUTPUT);
    hd.send(h, [0.0, 1.0, 0.0]);
    assert_eq!(s.last_force_n(), [0.0, 1.0, 0.0]);

    // The limit is the device's nominal maximum.
    s.set_nominal_max_force(2.0);
    assert_eq!(hd.get_doublev(HD_NOMINAL_MAX_FORCE)[0], 2.0);
    hd.send(h, [3.0, 0.0, 0.0]);
    assert_eq!(hd.errors(), [HD_EXCEEDED_MAX_FORCE]);
    assert!(!s.force_output_enabled());

    // With clamping on, the force is scaled to the limit instead.
    hd.enable(HD_FORCE_OUTPUT);
    hd.enable(HD_MAX_FORCE_CLAMPING);
    hd.send(h, [0.0, 0.0, 10.0]);
    assert_eq!(hd.errors(), NO_ERRORS);
    assert_eq!(s.last_force_n(), [0.0, 0.0, 2.0]);
    hd.disable(HD_MAX_FORCE_CLAMPING);

    // No amplifier outputs NaN.
    hd.send(h, [f64::NAN, 0.0, 0.0]);
    assert_eq!(hd.errors(), [HD_FORCE_ERROR]);
    assert_eq!(s.last_force_n(), [0.0; 3]);
    assert!(!s.force_output_enabled());

    // A frame that sets no force sends zero.
    hd.enable(HD_FORCE_OUTPUT);
    hd.send(h, [1.0, 0.0, 0.0]);
    assert_eq!(s.last_force_n(), [1.0, 0.0, 0.0]);
    hd.begin(h);
    hd.end(h);
    assert_eq!(s.last_force_n(), [0.0; 3]);

    // The readback of the last force inside a frame, and hdDisable.
    hd.send(h, [0.5, 0.0, 0.0]);
    hd.begin(h);
    assert_eq!(hd.get_doublev(HD_LAST_FORCE)[..3], [0.5, 0.0, 0.0]);
    hd.end(h);
    hd.disable(HD_FORCE_OUTPUT);
    hd.send(h, [0.5, 0.0, 0.0]);
    assert_eq!(s.last_force_n(), [0.0; 3]);
    assert_eq!(hd.errors(), NO_ERRORS);
}

/// What a servo-tick probe saw in one frame.
struct Seen {
    errors: Vec<c_uint>,
    position_mm: [f64; 3],
}

/// Schedules a callback that each tick reads the position in a frame and pops the error stack.
fn schedule_probe(hd: &'static Hd, h: c_uint) -> (&'static Mutex<Vec<Seen>>, u64) {
    let seen = leak(Mutex::new(Vec::new()));
    let handle = hd.schedule_async(
        leak(move || {
            hd.begin(h);
            let p = hd.get_doublev(HD_CURRENT_POSITION);
            hd.end(h);
            seen.lock().unwrap().push(Seen {
                errors: hd.errors(),
                position_mm: [p[0], p[1], p[2]],
            });
            HD_CALLBACK_CONTINUE
        }),
        HD_DEFAULT_SCHEDULER_PRIORITY,
    );
    (seen, handle)
}

#[test]
fn an_injected_error_fails_the_first_get_of_every_frame_for_that_many_ticks() {
    let (_turn, hd, s) = setup();
    let h = hd.open();
    let (seen, probe) = schedule_probe(hd, h);
    hd.start_scheduler();
    for (code, ticks) in [(HD_COMM_ERROR, 5), (HD_DEVICE_FAULT, 3)] {
        wait_until("a few clean frames", || seen.lock().unwrap().len() >= 5);
        let from = seen.lock().unwrap().len();
        s.inject_error(code, ticks);
        wait_until("30 more frames", || seen.lock().unwrap().len() >= from + 30);
        let frames = seen.lock().unwrap().drain(..).collect::<Vec<_>>();
        let failed: Vec<usize> = (from..frames.len())
            .filter(|&i| !frames[i].errors.is_empty())
            .collect();
        assert_eq!(
            failed.len(),
            ticks as usize,
            "{code:#x}: one failed frame per tick"
        );
        assert_eq!(
            failed.last().unwrap() - failed[0] + 1,
            failed.len(),
            "consecutive ticks"
        );
        for (i, frame) in frames.iter().enumerate() {
            if failed.contains(&i) {
                assert_eq!(frame.errors, [code], "once per frame");
                assert_eq!(frame.position_mm, [0.0; 3], "stale zeros");
            } else {
                assert_eq!(frame.errors, NO_ERRORS);
                assert!(frame.position_mm[1] > 1.0, "a real reading");
            }
        }
    }
    hd.unschedule(probe);

    // An injected force error also switches force output off.
    assert!(s.force_output_enabled());
    let (_, sender) = schedule_probe(hd, h);
    s.inject_error(HD_EXCEEDED_MAX_FORCE, 1);
    wait_until("force output off", || !s.force_output_enabled());
    hd.unschedule(sender);
}

#[test]
fn unplugging_fails_frames_and_init_with_comm_error_until_replugged_and_reinitialised() {
    let (_turn, hd, s) = setup();
    let h = hd.open();
    hd.start_scheduler();
    hd.send(h, [0.0, 1.0, 0.0]);
    assert_eq!(s.last_force_n(), [0.0, 1.0, 0.0]);

    s.unplug();
    assert_eq!(s.last_force_n(), [0.0; 3], "the motors lost power");
    hd.begin(h);
    let p = hd.get_doublev(HD_CURRENT_POSITION);
    hd.get_doublev(HD_CURRENT_VELOCITY);
    hd.set_doublev(HD_CURRENT_FORCE, &[0.0, 1.0, 0.0]);
    hd.end(h);
    assert_eq!(p[..3], [0.0; 3]);
    assert_eq!(hd.errors(), [HD_COMM_ERROR], "once per frame");
    assert_eq!(s.last_force_n(), [0.0; 3]);
    hd.begin(h);
    hd.end(h);
    assert_eq!(
        hd.errors(),
        [HD_COMM_ERROR],
        "also a frame that reads nothing"
    );
    assert!(s.wait_for_ticks(20, WAIT), "the servo thread keeps ticking");

    // The cable is back, but the old handle belongs to the device before it re-enumerated.
    s.replug();
    hd.send(h, [0.0, 1.0, 0.0]);
    assert_eq!(hd.errors(), [HD_COMM_ERROR]);
    assert_eq!(s.last_force_n(), [0.0; 3]);
    assert_eq!(hd.init(None), HD_INVALID_HANDLE, "still open");
    assert_eq!(hd.errors(), [HD_DEVICE_ALREADY_INITIATED]);
    hd.disable_device(h);
    assert!(!s.device_open());

    // Initialising an unplugged device fails.
    s.unplug();
    assert_eq!(hd.init(None), HD_INVALID_HANDLE);
    assert_eq!(hd.errors(), [HD_COMM_ERROR]);
    s.replug();
    let h = hd.open();
    assert_ne!(h, HD_INVALID_HANDLE);
    assert_eq!(hd.errors(), NO_ERRORS);
    assert!(hd.position(h)[1] > 1.0);
    hd.send(h, [0.0, 1.0, 0.0]);
    assert_eq!(s.last_force_n(), [0.0, 1.0, 0.0]);
    assert_eq!(hd.errors(), NO_ERRORS);
}

#[test]
fn calibration_states_offset_the_position_until_the_right_step_clears_them() {
    let (_turn, hd, s) = setup();
    assert_eq!(hd.check_calibration(), 0, "no device");
    assert_eq!(hd.errors(), [HD_BAD_HANDLE]);
    let h = hd.open();
    assert_eq!(hd.get_integerv(HD_CALIBRATION_STYLE)[0], 4);
    assert_eq!(hd.check_calibration(), HD_CALIBRATION_OK);
    assert_eq!(hd.position(h), START_MM);

    s.require_calibration(HD_CALIBRATION_NEEDS_UPDATE);
    assert_eq!(hd.check_calibration(), HD_CALIBRATION_NEEDS_UPDATE);
    assert_eq!(
        hd.position(h),
        [37.0, 20.0, 0.0],
        "an uncalibrated encoder reads wrong"
    );
    hd.update_calibration(HD_CALIBRATION_AUTO);
    assert_eq!(hd.errors(), [HD_INVALID_ENUM], "not this device's style");
    assert_eq!(hd.check_calibration(), HD_CALIBRATION_NEEDS_UPDATE);
    hd.update_calibration(HD_CALIBRATION_INKWELL);
    assert_eq!(hd.check_calibration(), HD_CALIBRATION_OK);
    assert_eq!(hd.position(h), START_MM);

    s.require_calibration(HD_CALIBRATION_NEEDS_MANUAL_INPUT);
    hd.update_calibration(HD_CALIBRATION_INKWELL);
    assert_eq!(
        hd.check_calibration(),
        HD_CALIBRATION_NEEDS_MANUAL_INPUT,
        "only the user can help"
    );
    assert_eq!(hd.position(h)[0], 37.0);
    s.complete_manual_calibration();
    assert_eq!(hd.check_calibration(), HD_CALIBRATION_NEEDS_UPDATE);
    hd.update_calibration(HD_CALIBRATION_INKWELL);
    assert_eq!(hd.check_calibration(), HD_CALIBRATION_OK);
    assert_eq!(hd.position(h), START_MM);
    assert_eq!(hd.errors(), NO_ERRORS);
}

#[test]
fn device_properties_are_readable_outside_frames_and_unknown_enums_are_refused() {
    let (_turn, hd, _s) = setup();
    assert_eq!(hd.get_doublev(HD_NOMINAL_MAX_FORCE), [UNTOUCHED; 16]);
    assert_eq!(hd.get_string(HD_DEVICE_MODEL_TYPE), None);
    assert_eq!(hd.errors(), [HD_BAD_HANDLE, HD_BAD_HANDLE], "no device yet");

    let h = hd.open();
    assert_eq!(
        hd.get_string(HD_DEVICE_MODEL_TYPE).unwrap(),
        "PHANTOM Desktop"
    );
    assert_eq!(
        hd.get_string(HD_DEVICE_VENDOR).unwrap(),
        "SensAble Technologies"
    );
    assert_eq!(
        hd.get_string(HD_DEVICE_SERIAL_NUMBER).unwrap(),
        "STANDIN-0001"
    );
    for (pname, value) in [
        (HD_NOMINAL_MAX_FORCE, 7.9),
        (HD_NOMINAL_MAX_CONTINUOUS_FORCE, 1.75),
        (HD_NOMINAL_MAX_STIFFNESS, 1.86),
        (HD_NOMINAL_MAX_DAMPING, 0.005),
    ] {
        let v = hd.get_doublev(pname);
        assert_eq!(v[0], value, "{pname:#x}");
        assert_eq!(v[1], UNTOUCHED, "{pname:#x} is one value");
    }
    let usable = hd.get_doublev(HD_USABLE_WORKSPACE_DIMENSIONS);
    assert_eq!(usable[..6], [-80.0, -60.0, -60.0, 80.0, 60.0, 60.0]);
    assert_eq!(usable[6], UNTOUCHED);
    let max = hd.get_doublev(HD_MAX_WORKSPACE_DIMENSIONS);
    assert!((0..3).all(|i| max[i] < usable[i] && max[i + 3] > usable[i + 3]));
    assert_eq!(hd.get_integerv(HD_INPUT_DOF)[0], 6);
    assert_eq!(hd.get_integerv(HD_OUTPUT_DOF)[0], 3);
    assert_eq!(hd.get_integerv(HD_UPDATE_RATE)[0], 1000);
    hd.set_rate(500);
    assert_eq!(hd.get_doublev(HD_UPDATE_RATE)[0], 500.0);
    assert_eq!(hd.errors(), NO_ERRORS);

    // From another thread, and inside a frame.
    let elsewhere = std::thread::scope(|scope| {
        scope
            .spawn(|| hd.get_doublev(HD_NOMINAL_MAX_FORCE)[0])
            .join()
            .unwrap()
    });
    assert_eq!(elsewhere, 7.9);
    hd.begin(h);
    assert_eq!(hd.get_doublev(HD_NOMINAL_MAX_CONTINUOUS_FORCE)[0], 1.75);
    hd.end(h);
    assert_eq!(hd.errors(), NO_ERRORS);

    assert_eq!(hd.get_doublev(0x1234), [UNTOUCHED; 16]);
    assert_eq!(hd.get_string(HD_NOMINAL_MAX_FORCE), None);
    hd.enable(0x1234);
    hd.begin(h);
    hd.set_doublev(HD_NOMINAL_MAX_FORCE, &[1.0, 0.0, 0.0]);
    hd.end(h);
    assert_eq!(hd.errors(), [HD_INVALID_ENUM; 4]);
    hd.set_rate(0);
    assert_eq!(hd.errors(), [HD_INVALID_VALUE]);
}

/// Sets an environment variable for one test and removes it afterwards, even on a panic.
struct EnvVar(&'static str);

impl EnvVar {
    fn set(name: &'static str, value: &str) -> EnvVar {
        // SAFETY: the only readers of the environment while the tests run are the stand-in's
        // hdInitDevice and hdStandinReset, called only by the test holding LOCK, as this one does.
        unsafe { std::env::set_var(name, value) };
        EnvVar(name)
    }
}

impl Drop for EnvVar {
    fn drop(&mut self) {
        // SAFETY: as in `set`.
        unsafe { std::env::remove_var(self.0) };
    }
}

#[test]
fn init_opens_the_default_device_and_configured_names_only() {
    let (_turn, hd, s) = setup();
    assert!(!s.device_open());
    assert_eq!(hd.current_device(), HD_INVALID_HANDLE);
    assert_eq!(hd.init(Some("Left")), HD_INVALID_HANDLE);
    assert_eq!(
        hd.error(),
        ErrorInfo {
            code: HD_COMM_CONFIG_ERROR,
            internal: 0,
            device: HD_INVALID_HANDLE
        }
    );

    let h = hd.open();
    assert_ne!(h, HD_INVALID_HANDLE);
    assert!(s.device_open());
    assert_eq!(hd.current_device(), h, "opening makes it current");
    assert!(hd.is_enabled(HD_FORCE_OUTPUT));
    assert_eq!(hd.init(Some("Default Device")), HD_INVALID_HANDLE);
    assert_eq!(hd.errors(), [HD_DEVICE_ALREADY_INITIATED]);
    hd.make_current(h);
    hd.make_current(h + 5);
    assert_eq!(hd.errors(), [HD_BAD_HANDLE]);
    hd.disable_device(h);
    assert_eq!(hd.current_device(), HD_INVALID_HANDLE);
    hd.disable_device(h);
    assert_eq!(hd.errors(), [HD_BAD_HANDLE]);

    let _devices = EnvVar::set("HD_STANDIN_DEVICES", "Left, Right");
    let _model = EnvVar::set("HD_STANDIN_MODEL", "Touch X");
    let h = hd.init(Some("Right"));
    assert_ne!(h, HD_INVALID_HANDLE);
    assert_eq!(hd.get_string(HD_DEVICE_MODEL_TYPE).unwrap(), "Touch X");
    hd.disable_device(h);
    assert_eq!(hd.init(Some("Middle")), HD_INVALID_HANDLE);
    assert_eq!(hd.errors(), [HD_COMM_CONFIG_ERROR]);
}

#[test]
fn the_built_in_hand_follows_its_press_and_is_pushed_back_by_the_force_it_is_sent() {
    let (_turn, hd, s) = setup();
    let h = hd.open();
    let at_rest = s.hand_state();
    assert_eq!(at_rest.position_mm, START_MM);
    assert_eq!(at_rest.velocity_mm_s, [0.0; 3]);

    // Free: the hand follows the scripted press. Its clock is the servo ticks, one millisecond
    // each, however late they came.
    let before = s.ticks();
    hd.start_scheduler();
    assert!(s.wait_for_ticks(300, WAIT));
    hd.stop_scheduler();
    let t_s = (s.ticks() - before) as f64 * 1e-3;
    let free = s.hand_state();
    let target = press_target_y_mm(t_s);
    assert!(
        close(free.position_mm[1], target, 1.0),
        "at {t_s} s the hand is at y = {} mm, its target at {target} mm",
        free.position_mm[1]
    );
    assert_eq!([free.position_mm[0], free.position_mm[2]], [0.0, 0.0]);
    assert_eq!(hd.position(h), free.position_mm, "as the frame reports it");

    // Pushed: 3 N upward every tick holds the hand F/k = 10 mm above its target.
    s.reset();
    let h = hd.open();
    hd.schedule_async(
        leak(move || {
            hd.send(h, [0.0, 3.0, 0.0]);
            HD_CALLBACK_CONTINUE
        }),
        HD_DEFAULT_SCHEDULER_PRIORITY,
    );
    let before = s.ticks();
    hd.start_scheduler();
    assert!(s.wait_for_ticks(800, WAIT));
    assert_eq!(s.last_force_n(), [0.0, 3.0, 0.0]);
    hd.stop_scheduler();
    let t_s = (s.ticks() - before) as f64 * 1e-3;
    let pushed = s.hand_state().position_mm[1] - press_target_y_mm(t_s);
    assert!(
        close(pushed, 10.0, 1.5),
        "at {t_s} s the hand is {pushed} mm above its target"
    );
}

#[test]
fn an_installed_hand_feels_the_force_sent_and_sets_the_reported_state() {
    let (_turn, hd, s) = setup();
    let felt = leak(Mutex::new(Vec::<[f64; 3]>::new()));
    s.set_hand(move |force_n, position_mm, velocity_mm_s| {
        felt.lock().unwrap().push(force_n);
        *position_mm = [1.0, 2.0, 3.0];
        *velocity_mm_s = [4.0, 5.0, 6.0];
    });
    let h = hd.open();
    hd.schedule_async(
        leak(move || {
            hd.send(h, [0.5, 0.0, 0.0]);
            HD_CALLBACK_CONTINUE
        }),
        HD_DEFAULT_SCHEDULER_PRIORITY,
    );
    hd.start_scheduler();
    wait_until("the hand felt the force", || {
        felt.lock().unwrap().contains(&[0.5, 0.0, 0.0])
    });
    hd.stop_scheduler();
    assert_eq!(
        felt.lock().unwrap()[0],
        [0.0; 3],
        "nothing sent before the first tick"
    );
    hd.begin(h);
    let p = hd.get_doublev(HD_CURRENT_POSITION);
    let v = hd.get_doublev(HD_CURRENT_VELOCITY);
    hd.end(h);
    assert_eq!(p[..3], [1.0, 2.0, 3.0]);
    assert_eq!(v[..3], [4.0, 5.0, 6.0]);

    // The built-in hand takes over from there.
    s.builtin_hand();
    let calls = felt.lock().unwrap().len();
    hd.start_scheduler();
    assert!(s.wait_for_ticks(5, WAIT));
    hd.stop_scheduler();
    assert_eq!(felt.lock().unwrap().len(), calls);
    assert_ne!(hd.position(h), [1.0, 2.0, 3.0]);
}

#[test]
fn buttons_and_rotation_are_latched_at_begin_frame() {
    let (_turn, hd, s) = setup();
    let h = hd.open();
    s.set_buttons(3);
    // 90° about y, column-major: x → −z, z → x.
    s.set_rotation(Some([0.0, 0.0, -1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0]));
    hd.begin(h);
    s.set_buttons(1);
    let buttons = hd.get_integerv(HD_CURRENT_BUTTONS);
    let transform = hd.get_doublev(HD_CURRENT_TRANSFORM);
    hd.end(h);
    assert_eq!(buttons[0], 3, "latched before the change");
    assert_eq!(buttons[1], UNTOUCHED_INT);
    assert_eq!(
        transform,
        [
            0.0,
            0.0,
            -1.0,
            0.0, //
            0.0,
            1.0,
            0.0,
            0.0, //
            1.0,
            0.0,
            0.0,
            0.0, //
            START_MM[0],
            START_MM[1],
            START_MM[2],
            1.0,
        ]
    );
    hd.begin(h);
    assert_eq!(hd.get_integerv(HD_CURRENT_BUTTONS)[0], 1);
    hd.end(h);
    s.set_rotation(None);
    hd.begin(h);
    let identity = hd.get_doublev(HD_CURRENT_TRANSFORM);
    hd.end(h);
    assert_eq!(
        identity[..11],
        [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    );
    assert_eq!(hd.errors(), NO_ERRORS);
}

#[test]
fn the_timestamp_reads_the_injected_delay_for_that_many_ticks() {
    let (_turn, hd, s) = setup();
    let stamps = leak(Mutex::new(Vec::<f64>::new()));
    let probe = hd.schedule_async(
        leak(move || {
            stamps.lock().unwrap().push(hd.time_stamp());
            HD_CALLBACK_CONTINUE
        }),
        HD_DEFAULT_SCHEDULER_PRIORITY,
    );
    hd.start_scheduler();
    wait_until("a few ticks", || stamps.lock().unwrap().len() >= 5);
    let from = stamps.lock().unwrap().len();
    s.delay_timestamp(3, 0.5);
    wait_until("30 more ticks", || {
        stamps.lock().unwrap().len() >= from + 30
    });
    hd.unschedule(probe);
    let stamps = stamps.lock().unwrap();
    assert!(stamps.iter().all(|&t| t >= 0.0));
    let late: Vec<f64> = stamps.iter().copied().filter(|&t| t >= 0.5).collect();
    assert_eq!(late.len(), 3, "{late:?}");
    assert!(late.iter().all(|&t| t < 0.6), "{late:?}");
}

#[test]
fn the_missing_symbol_variant_lacks_only_the_timestamp() {
    let (_turn, _hd, _s) = setup();
    assert_eq!(missing_symbol_path().file_name().unwrap(), "libHD.so");
    assert_ne!(missing_symbol_path(), standin_path());
    // SAFETY: loading runs only the variant's constructor (its own globals).
    let library = unsafe { libloading::Library::new(missing_symbol_path()) }.unwrap();
    // SAFETY: looked up only, never called.
    let stamp =
        unsafe { library.get::<unsafe extern "C" fn() -> c_double>(b"hdGetSchedulerTimeStamp\0") };
    assert!(stamp.is_err());
    // SAFETY: looked up only, never called.
    let init =
        unsafe { library.get::<unsafe extern "C" fn(*const c_char) -> c_uint>(b"hdInitDevice\0") };
    assert!(init.is_ok());
}

#[test]
fn frame_latency_is_measured_from_begin_to_end_until_reset() {
    let (_turn, hd, s) = setup();
    let h = hd.open();
    for _ in 0..10 {
        hd.position(h);
    }
    hd.begin(h);
    std::thread::sleep(Duration::from_millis(3));
    hd.end(h);
    let latency = s.latency();
    assert_eq!(latency.frames, 11);
    assert!(latency.max_us >= 3000.0, "{latency:?}");
    assert!(
        0.0 <= latency.p50_us && latency.p50_us <= latency.p99_us,
        "{latency:?}"
    );
    assert!(latency.p50_us < 3000.0, "{latency:?}");
    assert_eq!(
        latency.p99_us, latency.max_us,
        "the slowest of 11 is the 99th percentile"
    );
    s.reset_stats();
    let latency = s.latency();
    assert_eq!((latency.frames, latency.max_us), (0, 0.0));
}

#[test]
fn misuse_is_reported_on_the_error_stack_not_crashed() {
    let (_turn, hd, s) = setup();
    let h = hd.open();
    // SAFETY: NULL pointers are what is tested; the stand-in must refuse them.
    unsafe {
        (hd.get_doublev)(HD_NOMINAL_MAX_FORCE, std::ptr::null_mut());
        (hd.begin_frame)(h);
        (hd.get_doublev)(HD_CURRENT_POSITION, std::ptr::null_mut());
        (hd.get_integerv)(HD_CURRENT_BUTTONS, std::ptr::null_mut());
        (hd.set_doublev)(HD_CURRENT_FORCE, std::ptr::null());
        (hd.end_frame)(h);
    }
    assert_eq!(hd.errors(), [HD_INVALID_VALUE; 4]);
    // SAFETY: as above.
    let handle = unsafe {
        (hd.schedule_synchronous)(None, std::ptr::null_mut(), 0);
        (hd.schedule_asynchronous)(None, std::ptr::null_mut(), 0)
    };
    assert_eq!(handle, c_ulong::from(HD_INVALID_HANDLE));
    assert_eq!(hd.errors(), [HD_INVALID_VALUE; 2]);

    // hdStopScheduler from a callback cannot join its own thread.
    let stopped = leak(AtomicBool::new(false));
    hd.start_scheduler();
    let callback = move || {
        hd.stop_scheduler();
        stopped.store(true, Ordering::SeqCst);
        HD_CALLBACK_DONE
    };
    hd.schedule_sync(&callback, HD_DEFAULT_SCHEDULER_PRIORITY);
    assert!(stopped.load(Ordering::SeqCst));
    assert!(s.scheduler_running());
    assert_eq!(hd.errors(), [HD_TIMER_ERROR]);

    // A reset closes a frame left open.
    hd.begin(h);
    s.reset();
    hd.end(h);
    assert_eq!(hd.errors(), [HD_ILLEGAL_END]);
}

/// The stand-in's counters of what a backend did to it (controls the backend never calls).
struct Counters {
    inits: libloading::Symbol<'static, unsafe extern "C" fn(*mut c_double, c_int) -> c_int>,
    scheduler_starts: libloading::Symbol<'static, unsafe extern "C" fn() -> u64>,
    outside_frame_calls: libloading::Symbol<'static, unsafe extern "C" fn() -> u64>,
}

fn counters() -> Counters {
    let library = &hd()._library;
    // SAFETY: the stand-in exports these with these C signatures; the library is never unloaded
    // (`hd()` is a static).
    unsafe {
        Counters {
            inits: library.get(b"hdStandinInits\0").unwrap(),
            scheduler_starts: library.get(b"hdStandinSchedulerStarts\0").unwrap(),
            outside_frame_calls: library.get(b"hdStandinOutsideFrameCalls\0").unwrap(),
        }
    }
}

#[test]
fn the_stand_in_counts_inits_scheduler_starts_and_calls_from_outside_a_frame() {
    let (_turn, hd, _s) = setup();
    let c = counters();
    // SAFETY (all calls below): plain values, or a buffer as long as passed.
    let inits = |times: &mut [f64]| unsafe { (c.inits)(times.as_mut_ptr(), times.len() as c_int) };
    assert_eq!(inits(&mut []), 0, "cleared by the reset");
    assert_eq!(unsafe { (c.scheduler_starts)() }, 0);
    assert_eq!(unsafe { (c.outside_frame_calls)() }, 0);

    let h = hd.open();
    hd.disable_device(h);
    // A refused init is not counted.
    hd.init(Some("No Such Device"));
    let h = hd.open();
    let mut times = [0.0; 4];
    assert_eq!(inits(&mut times), 2);
    assert!(times[0] > 0.0 && times[1] >= times[0], "{times:?}");
    assert_eq!(times[2..], [0.0, 0.0]);

    hd.start_scheduler();
    hd.start_scheduler(); // already running: not a start
    hd.stop_scheduler();
    hd.start_scheduler();
    assert_eq!(unsafe { (c.scheduler_starts)() }, 2);
    hd.stop_scheduler();

    // Gets of current state and force sets without a frame on this thread; properties and
    // calls inside a frame are not counted.
    hd.get_doublev(HD_CURRENT_POSITION);
    hd.set_doublev(HD_CURRENT_FORCE, &[0.0; 3]);
    hd.get_doublev(HD_NOMINAL_MAX_FORCE);
    hd.position(h);
    let _ = hd.errors();
    assert_eq!(unsafe { (c.outside_frame_calls)() }, 2);
}
