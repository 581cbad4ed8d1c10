/*
 * A stand-in for OpenHaptics' HD API library (libHD.so), for tests without a PHANTOM.
 *
 * One file of 1500 lines because it is one library: the device, the hand, the scheduler and the
 * error stack are static state that every HD function shares under the locks described below, and
 * one file keeps that state private; the last 200 lines are the test controls.
 *
 * The test build compiles this file into a shared library named libHD.so, and the OpenHaptics
 * backend loads it through the very path it loads the vendor's library through. It exports the
 * HD API functions the backend calls, with the same C signatures, and keeps the rules that make
 * the real library hard to use correctly:
 *
 *   - its own servo scheduler thread, ticking at the set rate on absolute deadlines, calls the
 *     scheduled callbacks (highest priority first); a synchronous call waits for its callback to
 *     have run on that thread;
 *   - device state is read and force written only between hdBeginFrame and hdEndFrame; the force
 *     reaches the motors at hdEndFrame, and only while the servo loop runs;
 *   - misuse and faults land on a bounded error stack read with hdGetError, never in a crash;
 *   - a force above the nominal maximum is refused and switches force output off.
 *
 * The position comes from a simulated hand closed through the force the stand-in sent (the model
 * of device/src/sim.rs), or from a hand the test installs. Extra functions named hdStandin* let a
 * test drive the device (faults, unplugging, calibration, late ticks) and read back what the
 * motors were sent; the backend never calls them. A test that runs the server as a program, in
 * another process, reads the stop instead from the lines HD_STANDIN_REPORT asks for (see report).
 *
 * The vendor's headers are not used: the few types and constants are declared below with the
 * values of OpenHaptics 3.0 (shared/devices.md).
 *
 * Locks, and why there are four. `g_mu` guards the device, the hand's state and the motors; it is
 * held only for copies, never across a call out of the library. `g_err_mu` guards the error stack
 * and is taken last (errors are pushed with `g_mu` held). `g_sched_mu` guards the callback list
 * and the scheduler's life; it is never held while a callback runs, because a callback may
 * unschedule itself or schedule another. `g_hand_mu` is held while an installed hand runs, so that
 * once hdStandinSetHand returns the old hand is not running and its user data may be freed; it is
 * recursive because the hand itself may install another.
 */

#define _POSIX_C_SOURCE 200809L
#define _XOPEN_SOURCE 700 /* PTHREAD_MUTEX_RECURSIVE */

#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <sched.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

/* Only the functions marked API leave the library (it is compiled with -fvisibility=hidden). */
#define API __attribute__((visibility("default")))

/* ---------------------------------------------------------------------------------------------
 * Types and constants of the HD API (OpenHaptics 3.0 values, declared here, not included).
 */

typedef unsigned int HHD;
typedef unsigned int HDerror;
typedef unsigned int HDenum;
typedef unsigned int HDCallbackCode;
typedef unsigned char HDboolean;
typedef unsigned short HDushort;
typedef unsigned long HDulong;
typedef unsigned long HDSchedulerHandle;

typedef struct {
    HDerror errorCode;
    int internalErrorCode;
    HHD hHD;
} HDErrorInfo;

typedef HDCallbackCode (*HDSchedulerCallback)(void *pUserData);

#define HD_INVALID_HANDLE 0xFFFFFFFFu
#define HD_CALLBACK_DONE 0u
#define HD_CALLBACK_CONTINUE 1u

#define HD_SUCCESS 0x0000u
#define HD_INVALID_ENUM 0x0100u
#define HD_INVALID_VALUE 0x0101u
#define HD_INVALID_OPERATION 0x0102u
#define HD_BAD_HANDLE 0x0104u
#define HD_WARM_MOTORS 0x0200u
#define HD_EXCEEDED_MAX_FORCE 0x0201u
#define HD_FORCE_ERROR 0x0204u
#define HD_DEVICE_FAULT 0x0300u
#define HD_DEVICE_ALREADY_INITIATED 0x0301u
#define HD_COMM_ERROR 0x0302u
#define HD_COMM_CONFIG_ERROR 0x0303u
#define HD_TIMER_ERROR 0x0304u
#define HD_ILLEGAL_BEGIN 0x0400u
#define HD_ILLEGAL_END 0x0401u
#define HD_FRAME_ERROR 0x0402u
#define HD_INVALID_PRIORITY 0x0500u
#define HD_SCHEDULER_FULL 0x0501u
#define HD_INVALID_LICENSE 0x0600u

#define HD_CURRENT_BUTTONS 0x2000u
#define HD_CURRENT_POSITION 0x2050u
#define HD_CURRENT_VELOCITY 0x2051u
#define HD_CURRENT_TRANSFORM 0x2052u
#define HD_DEVICE_MODEL_TYPE 0x2501u
#define HD_DEVICE_VENDOR 0x2503u
#define HD_DEVICE_SERIAL_NUMBER 0x2504u
#define HD_MAX_WORKSPACE_DIMENSIONS 0x2550u
#define HD_USABLE_WORKSPACE_DIMENSIONS 0x2551u
#define HD_INPUT_DOF 0x2553u
#define HD_OUTPUT_DOF 0x2554u
#define HD_CALIBRATION_STYLE 0x2555u
#define HD_UPDATE_RATE 0x2600u
#define HD_INSTANTANEOUS_UPDATE_RATE 0x2601u
#define HD_NOMINAL_MAX_STIFFNESS 0x2602u
#define HD_NOMINAL_MAX_FORCE 0x2603u
#define HD_NOMINAL_MAX_CONTINUOUS_FORCE 0x2604u
#define HD_NOMINAL_MAX_DAMPING 0x2609u
#define HD_CURRENT_FORCE 0x2700u
#define HD_LAST_FORCE 0x2800u

#define HD_FORCE_OUTPUT 0x4000u
#define HD_MAX_FORCE_CLAMPING 0x4001u
#define HD_FORCE_RAMPING 0x4002u
#define HD_SOFTWARE_FORCE_LIMIT 0x4003u

#define HD_CALIBRATION_OK 0x5000u
#define HD_CALIBRATION_NEEDS_UPDATE 0x5001u
#define HD_CALIBRATION_NEEDS_MANUAL_INPUT 0x5002u
#define HD_CALIBRATION_ENCODER_RESET 1u
#define HD_CALIBRATION_AUTO 2u
#define HD_CALIBRATION_INKWELL 4u

/* ---------------------------------------------------------------------------------------------
 * The simulated device.
 */

/* The one physical device. Every configuration name refers to it, and like the first device of
 * the real library its handle is 0, so a backend cannot tell a re-initialised device by a new
 * handle: it must follow the error stack. */
#define DEVICE_HANDLE 0u
#define DEFAULT_DEVICE_NAME "Default Device"

#define DEFAULT_MODEL "PHANTOM Desktop"
#define VENDOR "SensAble Technologies"
#define SERIAL "STANDIN-0001"
#define NOMINAL_MAX_FORCE_N 7.9
#define NOMINAL_MAX_CONTINUOUS_FORCE_N 1.75
#define NOMINAL_MAX_STIFFNESS_N_PER_MM 1.86
#define NOMINAL_MAX_DAMPING_N_S_PER_MM 0.005
#define CALIBRATION_STYLES HD_CALIBRATION_INKWELL
static const double USABLE_WORKSPACE_MM[6] = {-80.0, -60.0, -60.0, 80.0, 60.0, 60.0};
static const double MAX_WORKSPACE_MM[6] = {-100.0, -80.0, -80.0, 100.0, 80.0, 80.0};

/* An uncalibrated encoder reads wrong: this much is added to the reported x until calibrated, so a
 * backend that skips calibration sees a tool visibly out of place. */
#define UNCALIBRATED_OFFSET_X_MM 37.0

/* The built-in hand: the simulated PHANTOM's model (device/src/sim.rs, SimParams::default), a
 * point mass (45 g tip + 100 g hand) held by a grip spring-damper toward a scripted target. */
#define HAND_MASS_KG 0.145
#define HAND_STIFFNESS_N_PER_M 300.0
#define HAND_DAMPING_N_S_PER_M 2.0
#define DEVICE_DAMPING_N_S_PER_M 0.05
#define HAND_SUBSTEPS 10
/* The target starts this far above the press point. */
#define PRESS_APPROACH_MM 20.0

/* Declared here: M_PI is not ISO C. */
#define PI 3.14159265358979323846

#define DEFAULT_RATE_HZ 1000ul
#define MAX_RATE_HZ 20000ul
#define ERROR_STACK_DEPTH 32
#define MAX_CALLBACKS 64
/* Successful hdInitDevice calls whose times are kept (hdStandinInits). */
#define MAX_INIT_TIMES 256
/* Latency histogram: 1 µs bins up to 2 ms, then one overflow bin. */
#define LATENCY_BINS 2000

typedef void (*StandinHand)(void *user, const double force_n[3], double position_mm[3],
                            double velocity_mm_s[3]);

/* Everything `g_mu` guards. */
typedef struct {
    /* hdInitDevice succeeded and hdDisableDevice has not been called since. */
    int open;
    /* Unplugged while open: a real USB device re-enumerates, so its old handle keeps failing
     * after the cable is back until the application disables and re-initialises it. */
    int stale;
    int unplugged;
    int force_output;
    int max_force_clamping;
    int force_ramping;
    int software_force_limit;
    HHD current;
    /* Copied from HD_STANDIN_MODEL at init, so that hdGetString's pointer stays valid. */
    char model[128];
    double nominal_max_force_n;
    HDenum calibration;
    int buttons;
    /* Column-major 3×3. */
    double rotation[9];

    /* The hand, SI units, device frame (y up). */
    double position_m[3];
    double velocity_m_s[3];
    /* Time of the built-in hand's script: advanced by one servo period per tick, never by the
     * wall clock, so the target does not jump when the machine stalls. */
    double hand_time_s;
    /* HD_STANDIN_PRESS: press point x, y, z (mm), depth below it (mm), period (s). */
    double press[5];

    /* The force the motors were sent at the last hdEndFrame (N): what the hand feels. */
    double motor_force_n[3];

    /* The current servo tick. */
    struct timespec tick_start;
    int have_tick;
    double instantaneous_rate_hz;
    HDerror inject_code;
    int inject_ticks;
    HDerror inject_now;
    int delay_ticks;
    double delay_s;
    double delay_now_s;

    /* Read-to-command latency of the frames since the last reset. */
    uint64_t latency_hist[LATENCY_BINS + 1];
    uint64_t latency_frames;
    double latency_max_us;

    /* Successful hdInitDevice calls since the last reset, and the CLOCK_MONOTONIC times of the
     * first MAX_INIT_TIMES of them. */
    int inits;
    struct timespec init_times[MAX_INIT_TIMES];

    /* Frames ended (hdEndFrame) since the last reset, and the last of them that drove the
     * motors with a force other than zero: its number and the force's magnitude (N).
     * HD_STANDIN_REPORT gives them, so that a zero force at the stop can be told from a hand
     * that had already let go. Counted in frames, not servo ticks: a stopping application may
     * be preempted for many ticks between its last frames, but not between frames it did not
     * send. */
    unsigned long long frames;
    unsigned long long last_nonzero_frame;
    double last_nonzero_force_n;
} State;

static pthread_mutex_t g_mu = PTHREAD_MUTEX_INITIALIZER;
static State g;

/* Servo ticks since the library was loaded. */
static atomic_ullong g_ticks;
static atomic_ulong g_rate_hz = DEFAULT_RATE_HZ;
/* Set while the servo loop runs: hdEndFrame drives the motors only then. */
static atomic_int g_servo_running;
/* Scheduler starts since the last reset (hdStartScheduler calls that started its thread). */
static atomic_ullong g_scheduler_starts;
/* Gets of current state and sets of force refused since the last reset because the calling
 * thread had no frame open: a backend touching the device from the wrong thread. */
static atomic_ullong g_outside_frame_calls;
/* Bumped by hdStandinReset: frames begun before it (on any thread) are no longer open. */
static atomic_uint g_epoch;

/* Errors. */
static pthread_mutex_t g_err_mu = PTHREAD_MUTEX_INITIALIZER;
static HDErrorInfo g_errors[ERROR_STACK_DEPTH];
static int g_error_count;

/* The installed hand. */
static pthread_mutex_t g_hand_mu;
static StandinHand g_hand_fn;
static void *g_hand_user;

/* The scheduler. */
typedef struct {
    int done;
    int ran;
} SyncWait;

typedef struct {
    HDSchedulerHandle id;
    HDSchedulerCallback fn;
    void *user;
    HDushort priority;
    /* Order of scheduling: equal priorities run first come, first served. */
    unsigned long long order;
    /* The pass of the scheduler in which this callback last ran: each runs once per tick. */
    unsigned long long last_pass;
    /* Non-NULL for a synchronous call: its waiting caller. */
    SyncWait *sync;
} Entry;

enum { SCHED_STOPPED, SCHED_RUNNING, SCHED_STOPPING };

static pthread_mutex_t g_sched_mu = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t g_sched_cv = PTHREAD_COND_INITIALIZER;
static Entry g_entries[MAX_CALLBACKS];
static int g_entry_count;
static HDSchedulerHandle g_next_id = 1;
static unsigned long long g_next_order = 1;
static unsigned long long g_pass;
/* The callback running now (0: none), so that hdUnschedule from another thread can wait it out. */
static HDSchedulerHandle g_running_id;
static int g_sched_state = SCHED_STOPPED;
static pthread_t g_thread;
static atomic_int g_stop;

/* This thread's open frame. A frame belongs to the thread that began it, as a scheduler callback's
 * frame does on the real library: another thread's gets stay outside it. */
typedef struct {
    int active;
    unsigned epoch;
    HHD device;
    /* The device was unplugged (or its handle stale) when the frame began. */
    int unplugged;
    /* The error injected into this tick, 0 for none. */
    HDerror injected;
    /* This frame's error has been pushed (once per frame). */
    int error_reported;
    double position_mm[3];
    double velocity_mm_s[3];
    double transform[16];
    int buttons;
    double last_force_n[3];
    double force_n[3];
    int force_set;
    /* A force beyond the limit was set: zero goes out and force output switches off. */
    int force_refused;
    struct timespec latched;
} Frame;

static _Thread_local Frame t_frame;
static _Thread_local int t_is_scheduler;

/* ---------------------------------------------------------------------------------------------
 * Small helpers.
 */

static void now_monotonic(struct timespec *t) { clock_gettime(CLOCK_MONOTONIC, t); }

static double seconds_between(const struct timespec *from, const struct timespec *to) {
    return (double)(to->tv_sec - from->tv_sec) + (double)(to->tv_nsec - from->tv_nsec) * 1e-9;
}

static void add_ns(struct timespec *t, long long ns) {
    long long total = (long long)t->tv_nsec + ns;
    t->tv_sec += (time_t)(total / 1000000000LL);
    t->tv_nsec = (long)(total % 1000000000LL);
    if (t->tv_nsec < 0) {
        t->tv_nsec += 1000000000L;
        t->tv_sec -= 1;
    }
}

static void push_error(HDerror code, HHD device) {
    pthread_mutex_lock(&g_err_mu);
    if (g_error_count == ERROR_STACK_DEPTH) {
        /* Full: the oldest error goes, the newest is what the application must see. */
        memmove(&g_errors[0], &g_errors[1], sizeof(g_errors[0]) * (ERROR_STACK_DEPTH - 1));
        g_error_count -= 1;
    }
    g_errors[g_error_count].errorCode = code;
    g_errors[g_error_count].internalErrorCode = 0;
    g_errors[g_error_count].hHD = device;
    g_error_count += 1;
    pthread_mutex_unlock(&g_err_mu);
}

/* HD_STANDIN_REPORT=path: what a test in another process (the server run as a program) cannot
 * ask through the hdStandin* controls. One line is appended to the file at each hdStopScheduler
 * that stops a running scheduler, at each hdDisableDevice of an open device, and when the library
 * is unloaded (at the process' normal exit: a process killed outright writes no "unload" line):
 *
 *   event=hdStopScheduler tick=5210 motor_force_n=0,0,0 frames=5170 last_nonzero_frame=5169
 *   last_nonzero_force_n=2.31 scheduler=stopped device=open force_output=off callbacks=0
 *
 * (one line in the file). `motor_force_n` is the force the motors were driven with when the call
 * came, before the call itself zeroes it (stopping the servo loop and releasing the device both
 * do, as on the real library): the last force the application commanded. `tick` is the servo
 * tick count since load, `frames` and `last_nonzero_frame` count frames since the last reset
 * (see State); the other fields are the state once the call is done. */
static void report(const char *event, const double motor_force_n[3]) {
    const char *path = getenv("HD_STANDIN_REPORT");
    if (path == NULL || path[0] == '\0') return;
    pthread_mutex_lock(&g_mu);
    unsigned long long frames = g.frames;
    unsigned long long last_nonzero_frame = g.last_nonzero_frame;
    double last_nonzero_force_n = g.last_nonzero_force_n;
    int open = g.open;
    int force_output = g.open && g.force_output;
    pthread_mutex_unlock(&g_mu);
    pthread_mutex_lock(&g_sched_mu);
    int callbacks = g_entry_count;
    const char *scheduler = g_sched_state == SCHED_RUNNING    ? "running"
                            : g_sched_state == SCHED_STOPPING ? "stopping"
                                                              : "stopped";
    pthread_mutex_unlock(&g_sched_mu);
    FILE *file = fopen(path, "a");
    if (file == NULL) {
        fprintf(stderr, "hd_standin: cannot append to HD_STANDIN_REPORT=\"%s\": %s\n", path,
                strerror(errno));
        return;
    }
    fprintf(file,
            "event=%s tick=%llu motor_force_n=%.17g,%.17g,%.17g frames=%llu "
            "last_nonzero_frame=%llu last_nonzero_force_n=%.17g scheduler=%s device=%s "
            "force_output=%s callbacks=%d\n",
            event, (unsigned long long)atomic_load(&g_ticks), motor_force_n[0], motor_force_n[1],
            motor_force_n[2], frames, last_nonzero_frame, last_nonzero_force_n, scheduler,
            open ? "open" : "closed", force_output ? "on" : "off", callbacks);
    fclose(file);
}

static int frame_active(void) {
    return t_frame.active && t_frame.epoch == atomic_load(&g_epoch);
}

static int is_force_error(HDerror code) { return code >= 0x0200u && code < 0x0300u; }

static double clamp_to_int(double v) {
    if (!(v == v)) return 0.0; /* NaN */
    if (v > 2147483647.0) return 2147483647.0;
    if (v < -2147483648.0) return -2147483648.0;
    return v;
}

/* The built-in hand's target and its velocity (mm, mm/s) at script time `t` (s): a press along
 * −y from PRESS_APPROACH_MM above the point to `depth` below it and back, with a cosine profile,
 * so neither the target nor its velocity ever jumps (also at the wrap of the period). */
static void press_target(const double press[5], double t, double target_mm[3],
                         double target_mm_s[3]) {
    double travel = PRESS_APPROACH_MM + press[3];
    double period = press[4];
    double offset = 0.0;
    double rate = 0.0;
    if (period > 0.0) {
        double phase = fmod(t, period) / period;
        offset = travel * (0.5 - 0.5 * cos(2.0 * PI * phase));
        rate = travel * PI / period * sin(2.0 * PI * phase);
    }
    target_mm[0] = press[0];
    target_mm[1] = press[1] + PRESS_APPROACH_MM - offset;
    target_mm[2] = press[2];
    target_mm_s[0] = 0.0;
    target_mm_s[1] = -rate;
    target_mm_s[2] = 0.0;
}

/* Reads HD_STANDIN_PRESS ("x_mm,y_mm,z_mm,depth_mm,period_s"); a malformed value is said once on
 * stderr and the default used, rather than quietly pressing somewhere else. */
static void read_press(double press[5]) {
    const double defaults[5] = {0.0, 0.0, 0.0, 8.0, 3.0};
    memcpy(press, defaults, sizeof(defaults));
    const char *text = getenv("HD_STANDIN_PRESS");
    if (text == NULL || text[0] == '\0') return;
    double v[5];
    char tail;
    int n = sscanf(text, " %lf , %lf , %lf , %lf , %lf %c", &v[0], &v[1], &v[2], &v[3], &v[4],
                   &tail);
    int ok = n == 5;
    for (int i = 0; ok && i < 5; i++) ok = isfinite(v[i]);
    ok = ok && v[3] >= 0.0 && v[4] > 0.0;
    if (!ok) {
        fprintf(stderr,
                "hd_standin: HD_STANDIN_PRESS=\"%s\" is not \"x_mm,y_mm,z_mm,depth_mm,period_s\" "
                "with depth >= 0 and period > 0; using the default 0,0,0,8,3\n",
                text);
        return;
    }
    memcpy(press, v, sizeof(v));
}

/* Reads HD_STANDIN_MAX_FORCE_N, the nominal maximum force the device reports and enforces (N),
 * for a test that runs the server as a program and cannot call hdStandinSetNominalMaxForce; a
 * value that is not a positive number is said on stderr and the PHANTOM Desktop's used. */
static double read_max_force(void) {
    const char *text = getenv("HD_STANDIN_MAX_FORCE_N");
    if (text == NULL || text[0] == '\0') return NOMINAL_MAX_FORCE_N;
    double v;
    char tail;
    if (sscanf(text, " %lf %c", &v, &tail) != 1 || !isfinite(v) || !(v > 0.0)) {
        fprintf(stderr,
                "hd_standin: HD_STANDIN_MAX_FORCE_N=\"%s\" is not a positive number of newtons; "
                "using %g\n",
                text, NOMINAL_MAX_FORCE_N);
        return NOMINAL_MAX_FORCE_N;
    }
    return v;
}

/* Back to a freshly loaded library's state. Called with `g_mu` held (or before any thread). */
static void reset_state_locked(void) {
    memset(&g, 0, sizeof(g));
    g.current = HD_INVALID_HANDLE;
    g.force_output = 1;
    g.software_force_limit = 1;
    g.nominal_max_force_n = read_max_force();
    g.calibration = HD_CALIBRATION_OK;
    g.rotation[0] = g.rotation[4] = g.rotation[8] = 1.0;
    read_press(g.press);
    double target_mm[3], target_mm_s[3];
    press_target(g.press, 0.0, target_mm, target_mm_s);
    for (int i = 0; i < 3; i++) g.position_m[i] = target_mm[i] * 1e-3;
    snprintf(g.model, sizeof(g.model), "%s", DEFAULT_MODEL);
}

__attribute__((constructor)) static void standin_load(void) {
    pthread_mutexattr_t attr;
    pthread_mutexattr_init(&attr);
    pthread_mutexattr_settype(&attr, PTHREAD_MUTEX_RECURSIVE);
    pthread_mutex_init(&g_hand_mu, &attr);
    pthread_mutexattr_destroy(&attr);
    pthread_mutex_lock(&g_mu);
    reset_state_locked();
    pthread_mutex_unlock(&g_mu);
}

/* Runs when the library is unmapped, which with -z nodelete is at the process' normal exit. */
__attribute__((destructor)) static void standin_unload(void) {
    double motor_force_n[3];
    pthread_mutex_lock(&g_mu);
    memcpy(motor_force_n, g.motor_force_n, sizeof(motor_force_n));
    pthread_mutex_unlock(&g_mu);
    report("unload", motor_force_n);
}

/* Is `name` one of the configuration names in HD_STANDIN_DEVICES (comma-separated)? */
static int configured(const char *name) {
    const char *list = getenv("HD_STANDIN_DEVICES");
    if (list == NULL) return 0;
    size_t want = strlen(name);
    const char *p = list;
    while (*p != '\0') {
        while (*p == ' ') p++;
        const char *end = strchr(p, ',');
        size_t len = end ? (size_t)(end - p) : strlen(p);
        size_t trimmed = len;
        while (trimmed > 0 && p[trimmed - 1] == ' ') trimmed--;
        if (trimmed == want && want > 0 && strncmp(p, name, want) == 0) return 1;
        if (end == NULL) break;
        p = end + 1;
    }
    return 0;
}

/* ---------------------------------------------------------------------------------------------
 * Devices.
 */

API HHD hdInitDevice(const char *pConfigName) {
    if (pConfigName != NULL && strcmp(pConfigName, DEFAULT_DEVICE_NAME) != 0 &&
        !configured(pConfigName)) {
        push_error(HD_COMM_CONFIG_ERROR, HD_INVALID_HANDLE);
        return HD_INVALID_HANDLE;
    }
    const char *model = getenv("HD_STANDIN_MODEL");
    pthread_mutex_lock(&g_mu);
    if (g.open) {
        pthread_mutex_unlock(&g_mu);
        push_error(HD_DEVICE_ALREADY_INITIATED, DEVICE_HANDLE);
        return HD_INVALID_HANDLE;
    }
    if (g.unplugged) {
        pthread_mutex_unlock(&g_mu);
        push_error(HD_COMM_ERROR, HD_INVALID_HANDLE);
        return HD_INVALID_HANDLE;
    }
    g.open = 1;
    g.stale = 0;
    if (g.inits < MAX_INIT_TIMES) now_monotonic(&g.init_times[g.inits]);
    g.inits += 1;
    /* As on the real library, force output is on once the device is initialised. */
    g.force_output = 1;
    g.current = DEVICE_HANDLE;
    snprintf(g.model, sizeof(g.model), "%s",
             model != NULL && model[0] != '\0' ? model : DEFAULT_MODEL);
    pthread_mutex_unlock(&g_mu);
    return DEVICE_HANDLE;
}

API void hdDisableDevice(HHD hHD) {
    pthread_mutex_lock(&g_mu);
    if (!g.open || hHD != DEVICE_HANDLE) {
        pthread_mutex_unlock(&g_mu);
        push_error(HD_BAD_HANDLE, hHD);
        return;
    }
    g.open = 0;
    g.stale = 0;
    g.current = HD_INVALID_HANDLE;
    double motor_force_n[3];
    memcpy(motor_force_n, g.motor_force_n, sizeof(motor_force_n));
    /* A released device's amplifiers are off. */
    memset(g.motor_force_n, 0, sizeof(g.motor_force_n));
    pthread_mutex_unlock(&g_mu);
    report("hdDisableDevice", motor_force_n);
}

API void hdMakeCurrentDevice(HHD hHD) {
    pthread_mutex_lock(&g_mu);
    int ok = g.open && hHD == DEVICE_HANDLE;
    if (ok) g.current = hHD;
    pthread_mutex_unlock(&g_mu);
    if (!ok) push_error(HD_BAD_HANDLE, hHD);
}

API HHD hdGetCurrentDevice(void) {
    pthread_mutex_lock(&g_mu);
    HHD h = g.open ? g.current : HD_INVALID_HANDLE;
    pthread_mutex_unlock(&g_mu);
    return h;
}

/* ---------------------------------------------------------------------------------------------
 * Errors.
 */

API HDErrorInfo hdGetError(void) {
    HDErrorInfo info = {HD_SUCCESS, 0, HD_INVALID_HANDLE};
    pthread_mutex_lock(&g_err_mu);
    if (g_error_count > 0) {
        g_error_count -= 1;
        info = g_errors[g_error_count];
    }
    pthread_mutex_unlock(&g_err_mu);
    return info;
}

API const char *hdGetErrorString(HDerror code) {
    switch (code) {
    case HD_SUCCESS: return "success";
    case HD_INVALID_ENUM: return "invalid enumeration";
    case HD_INVALID_VALUE: return "invalid value";
    case HD_INVALID_OPERATION: return "invalid operation";
    case 0x0103u: return "invalid input type";
    case HD_BAD_HANDLE: return "bad device handle";
    case HD_WARM_MOTORS: return "motors warm: force reduced";
    case HD_EXCEEDED_MAX_FORCE: return "exceeded the maximum force";
    case 0x0202u: return "exceeded the maximum force impulse";
    case 0x0203u: return "exceeded the maximum velocity";
    case HD_FORCE_ERROR: return "force error";
    case HD_DEVICE_FAULT: return "device fault";
    case HD_DEVICE_ALREADY_INITIATED: return "device already initiated";
    case HD_COMM_ERROR: return "communication error";
    case HD_COMM_CONFIG_ERROR: return "communication configuration error";
    case HD_TIMER_ERROR: return "timer error";
    case HD_ILLEGAL_BEGIN: return "illegal begin frame";
    case HD_ILLEGAL_END: return "illegal end frame";
    case HD_FRAME_ERROR: return "frame error: state access outside a frame";
    case HD_INVALID_PRIORITY: return "invalid scheduler priority";
    case HD_SCHEDULER_FULL: return "scheduler full";
    case HD_INVALID_LICENSE: return "invalid license";
    default: return "unknown error";
    }
}

/* ---------------------------------------------------------------------------------------------
 * Capabilities.
 */

static int *capability_locked(HDenum cap) {
    switch (cap) {
    case HD_FORCE_OUTPUT: return &g.force_output;
    /* Kept and reported; of these only clamping changes what the stand-in does. */
    case HD_MAX_FORCE_CLAMPING: return &g.max_force_clamping;
    case HD_FORCE_RAMPING: return &g.force_ramping;
    case HD_SOFTWARE_FORCE_LIMIT: return &g.software_force_limit;
    default: return NULL;
    }
}

static void set_capability(HDenum cap, int on) {
    HDerror err = HD_SUCCESS;
    pthread_mutex_lock(&g_mu);
    if (!g.open) {
        err = HD_BAD_HANDLE;
    } else {
        int *flag = capability_locked(cap);
        if (flag == NULL) err = HD_INVALID_ENUM;
        else *flag = on;
    }
    HHD h = g.open ? g.current : HD_INVALID_HANDLE;
    pthread_mutex_unlock(&g_mu);
    if (err != HD_SUCCESS) push_error(err, h);
}

API void hdEnable(HDenum cap) { set_capability(cap, 1); }

API void hdDisable(HDenum cap) { set_capability(cap, 0); }

API HDboolean hdIsEnabled(HDenum cap) {
    HDerror err = HD_SUCCESS;
    int on = 0;
    pthread_mutex_lock(&g_mu);
    if (!g.open) {
        err = HD_BAD_HANDLE;
    } else {
        int *flag = capability_locked(cap);
        if (flag == NULL) err = HD_INVALID_ENUM;
        else on = *flag;
    }
    HHD h = g.open ? g.current : HD_INVALID_HANDLE;
    pthread_mutex_unlock(&g_mu);
    if (err != HD_SUCCESS) push_error(err, h);
    return (HDboolean)(on ? 1 : 0);
}

/* ---------------------------------------------------------------------------------------------
 * The hand and the servo tick.
 */

/* One servo period of the built-in hand, semi-implicit Euler with HAND_SUBSTEPS substeps and the
 * force held across them (zero-order hold, as sim.rs). Called with `g_mu` held. */
static void builtin_hand_step_locked(double period_s, const double force_n[3]) {
    double h = period_s / HAND_SUBSTEPS;
    for (int step = 0; step < HAND_SUBSTEPS; step++) {
        double target_mm[3], target_mm_s[3];
        press_target(g.press, g.hand_time_s + step * h, target_mm, target_mm_s);
        for (int i = 0; i < 3; i++) {
            double grip = HAND_STIFFNESS_N_PER_M * (target_mm[i] * 1e-3 - g.position_m[i]) +
                          HAND_DAMPING_N_S_PER_M * (target_mm_s[i] * 1e-3 - g.velocity_m_s[i]);
            double friction = -DEVICE_DAMPING_N_S_PER_M * g.velocity_m_s[i];
            g.velocity_m_s[i] += (grip + friction + force_n[i]) * (h / HAND_MASS_KG);
            g.position_m[i] += g.velocity_m_s[i] * h;
        }
    }
}

/* Moves the hand by one servo period under the force sent at the last hdEndFrame. */
static void advance_hand(double period_s) {
    pthread_mutex_lock(&g_hand_mu);
    StandinHand hand = g_hand_fn;
    void *user = g_hand_user;
    double force_n[3], position_mm[3], velocity_mm_s[3];
    pthread_mutex_lock(&g_mu);
    memcpy(force_n, g.motor_force_n, sizeof(force_n));
    if (hand == NULL) {
        builtin_hand_step_locked(period_s, force_n);
    } else {
        for (int i = 0; i < 3; i++) {
            position_mm[i] = g.position_m[i] * 1e3;
            velocity_mm_s[i] = g.velocity_m_s[i] * 1e3;
        }
    }
    g.hand_time_s += period_s;
    pthread_mutex_unlock(&g_mu);
    if (hand != NULL) {
        /* Outside `g_mu`: the test's hand may call the stand-in's controls. */
        hand(user, force_n, position_mm, velocity_mm_s);
        pthread_mutex_lock(&g_mu);
        for (int i = 0; i < 3; i++) {
            g.position_m[i] = position_mm[i] * 1e-3;
            g.velocity_m_s[i] = velocity_mm_s[i] * 1e-3;
        }
        pthread_mutex_unlock(&g_mu);
    }
    pthread_mutex_unlock(&g_hand_mu);
}

static void remove_entry_locked(HDSchedulerHandle id) {
    for (int i = 0; i < g_entry_count; i++) {
        if (g_entries[i].id == id) {
            if (g_entries[i].sync != NULL) {
                /* Its caller waits: let it go, told the callback never ran. */
                g_entries[i].sync->done = 1;
                g_entries[i].sync->ran = 0;
            }
            g_entries[i] = g_entries[g_entry_count - 1];
            g_entry_count -= 1;
            pthread_cond_broadcast(&g_sched_cv);
            return;
        }
    }
}

/* Calls every scheduled callback once, highest priority first. The list may change while a
 * callback runs (it may unschedule itself or others, or schedule more), so the next callback is
 * chosen afresh after each: the one of highest priority that has not run in this pass. */
static void run_callbacks(void) {
    pthread_mutex_lock(&g_sched_mu);
    unsigned long long pass = ++g_pass;
    for (;;) {
        int best = -1;
        for (int i = 0; i < g_entry_count; i++) {
            if (g_entries[i].last_pass == pass) continue;
            if (best < 0 || g_entries[i].priority > g_entries[best].priority ||
                (g_entries[i].priority == g_entries[best].priority &&
                 g_entries[i].order < g_entries[best].order)) {
                best = i;
            }
        }
        if (best < 0) break;
        g_entries[best].last_pass = pass;
        Entry e = g_entries[best];
        g_running_id = e.id;
        pthread_mutex_unlock(&g_sched_mu);
        HDCallbackCode code = e.fn(e.user);
        pthread_mutex_lock(&g_sched_mu);
        g_running_id = 0;
        if (e.sync != NULL) {
            /* Still listed unless hdStandinReset or hdUnschedule took it; either way its
             * caller is waiting on `e.sync`, which stays valid until `done` is seen. */
            for (int i = 0; i < g_entry_count; i++) {
                if (g_entries[i].id == e.id) {
                    g_entries[i] = g_entries[g_entry_count - 1];
                    g_entry_count -= 1;
                    e.sync->ran = 1;
                    e.sync->done = 1;
                    break;
                }
            }
        } else if (code != HD_CALLBACK_CONTINUE) {
            remove_entry_locked(e.id);
        }
        pthread_cond_broadcast(&g_sched_cv);
    }
    pthread_mutex_unlock(&g_sched_mu);
}

static void servo_tick(double period_s) {
    struct timespec now;
    now_monotonic(&now);
    atomic_fetch_add(&g_ticks, 1ull);
    pthread_mutex_lock(&g_mu);
    if (g.have_tick) {
        double since = seconds_between(&g.tick_start, &now);
        g.instantaneous_rate_hz = since > 0.0 ? 1.0 / since : 0.0;
    }
    g.tick_start = now;
    g.have_tick = 1;
    g.inject_now = 0;
    if (g.inject_ticks > 0) {
        g.inject_now = g.inject_code;
        g.inject_ticks -= 1;
    }
    g.delay_now_s = 0.0;
    if (g.delay_ticks > 0) {
        g.delay_now_s = g.delay_s;
        g.delay_ticks -= 1;
    }
    pthread_mutex_unlock(&g_mu);
    advance_hand(period_s);
    run_callbacks();
}

static void *scheduler_main(void *arg) {
    (void)arg;
    t_is_scheduler = 1;
    /* The vendor's servo thread runs at a real-time priority; ask for one too, and carry on at
     * normal priority where the process is not allowed it (a test machine without the rights).
     * Without it the servo ticks here would stall behind ordinary work, which the real device's
     * would not. */
    struct sched_param param = {.sched_priority = 80};
    (void)pthread_setschedparam(pthread_self(), SCHED_FIFO, &param);
    struct timespec next;
    now_monotonic(&next);
    while (!atomic_load(&g_stop)) {
        unsigned long rate = atomic_load(&g_rate_hz);
        long long period_ns = 1000000000LL / (long long)rate;
        servo_tick((double)period_ns * 1e-9);
        add_ns(&next, period_ns);
        struct timespec now;
        now_monotonic(&now);
        /* More than a period behind (the machine stalled): start again from now rather than
         * run a burst of late ticks, as a hardware timer would simply have missed them. */
        if (seconds_between(&next, &now) > (double)period_ns * 1e-9) next = now;
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL) == EINTR) {
        }
    }
    return NULL;
}

/* ---------------------------------------------------------------------------------------------
 * The scheduler's API.
 */

API void hdSetSchedulerRate(HDulong hz) {
    if (hz == 0 || hz > MAX_RATE_HZ) {
        push_error(HD_INVALID_VALUE, HD_INVALID_HANDLE);
        return;
    }
    atomic_store(&g_rate_hz, hz);
}

API void hdStartScheduler(void) {
    if (t_is_scheduler) return; /* it runs: this very thread is it */
    pthread_mutex_lock(&g_sched_mu);
    while (g_sched_state == SCHED_STOPPING) pthread_cond_wait(&g_sched_cv, &g_sched_mu);
    if (g_sched_state == SCHED_RUNNING) {
        pthread_mutex_unlock(&g_sched_mu);
        return;
    }
    atomic_store(&g_stop, 0);
    atomic_store(&g_servo_running, 1);
    if (pthread_create(&g_thread, NULL, scheduler_main, NULL) != 0) {
        atomic_store(&g_servo_running, 0);
        pthread_mutex_unlock(&g_sched_mu);
        push_error(HD_TIMER_ERROR, HD_INVALID_HANDLE);
        return;
    }
    g_sched_state = SCHED_RUNNING;
    atomic_fetch_add(&g_scheduler_starts, 1ull);
    pthread_mutex_unlock(&g_sched_mu);
}

API void hdStopScheduler(void) {
    if (t_is_scheduler) {
        /* Joining itself would never return. */
        push_error(HD_TIMER_ERROR, HD_INVALID_HANDLE);
        return;
    }
    pthread_mutex_lock(&g_sched_mu);
    if (g_sched_state == SCHED_STOPPING) {
        /* Another thread is joining it: wait for that rather than join twice. */
        while (g_sched_state != SCHED_STOPPED) pthread_cond_wait(&g_sched_cv, &g_sched_mu);
        pthread_mutex_unlock(&g_sched_mu);
        return;
    }
    if (g_sched_state == SCHED_STOPPED) {
        pthread_mutex_unlock(&g_sched_mu);
        return;
    }
    g_sched_state = SCHED_STOPPING;
    atomic_store(&g_servo_running, 0);
    atomic_store(&g_stop, 1);
    pthread_t thread = g_thread;
    pthread_mutex_unlock(&g_sched_mu);

    pthread_join(thread, NULL);

    /* Without the servo loop nothing drives the motors. */
    double motor_force_n[3];
    pthread_mutex_lock(&g_mu);
    memcpy(motor_force_n, g.motor_force_n, sizeof(motor_force_n));
    memset(g.motor_force_n, 0, sizeof(g.motor_force_n));
    pthread_mutex_unlock(&g_mu);

    pthread_mutex_lock(&g_sched_mu);
    /* Synchronous calls that never got their tick return now (their callers push the error). */
    for (int i = g_entry_count - 1; i >= 0; i--) {
        if (g_entries[i].sync != NULL) remove_entry_locked(g_entries[i].id);
    }
    g_sched_state = SCHED_STOPPED;
    pthread_cond_broadcast(&g_sched_cv);
    pthread_mutex_unlock(&g_sched_mu);
    report("hdStopScheduler", motor_force_n);
}

/* Adds a callback; returns its handle, or 0 with `*err` set. Called with `g_sched_mu` held. */
static HDSchedulerHandle add_entry_locked(HDSchedulerCallback fn, void *user, HDushort priority,
                                          SyncWait *sync, HDerror *err) {
    if (g_entry_count == MAX_CALLBACKS) {
        *err = HD_SCHEDULER_FULL;
        return 0;
    }
    Entry *e = &g_entries[g_entry_count];
    e->id = g_next_id++;
    e->fn = fn;
    e->user = user;
    e->priority = priority;
    e->order = g_next_order++;
    e->last_pass = 0;
    e->sync = sync;
    g_entry_count += 1;
    return e->id;
}

API HDSchedulerHandle hdScheduleAsynchronous(HDSchedulerCallback pCallback, void *pUserData,
                                             HDushort nPriority) {
    if (pCallback == NULL) {
        push_error(HD_INVALID_VALUE, HD_INVALID_HANDLE);
        return (HDSchedulerHandle)HD_INVALID_HANDLE;
    }
    HDerror err = HD_SUCCESS;
    pthread_mutex_lock(&g_sched_mu);
    HDSchedulerHandle id = add_entry_locked(pCallback, pUserData, nPriority, NULL, &err);
    pthread_mutex_unlock(&g_sched_mu);
    if (err != HD_SUCCESS) {
        push_error(err, HD_INVALID_HANDLE);
        return (HDSchedulerHandle)HD_INVALID_HANDLE;
    }
    return id;
}

API void hdScheduleSynchronous(HDSchedulerCallback pCallback, void *pUserData,
                               HDushort nPriority) {
    if (pCallback == NULL) {
        push_error(HD_INVALID_VALUE, HD_INVALID_HANDLE);
        return;
    }
    if (t_is_scheduler) {
        /* Called from a callback: waiting for the next tick on this thread would wait forever,
         * and the call is already on the scheduler thread, so run it here. */
        pCallback(pUserData);
        return;
    }
    HDerror err = HD_SUCCESS;
    SyncWait wait = {0, 0};
    pthread_mutex_lock(&g_sched_mu);
    if (g_sched_state != SCHED_RUNNING) {
        err = HD_TIMER_ERROR;
    } else {
        add_entry_locked(pCallback, pUserData, nPriority, &wait, &err);
        if (err == HD_SUCCESS) {
            while (!wait.done) pthread_cond_wait(&g_sched_cv, &g_sched_mu);
            if (!wait.ran) err = HD_TIMER_ERROR;
        }
    }
    pthread_mutex_unlock(&g_sched_mu);
    if (err != HD_SUCCESS) push_error(err, HD_INVALID_HANDLE);
}

/* Once this returns (on any thread but the scheduler's), the callback is neither running nor
 * scheduled, so its user data may be freed. An unknown handle (a callback that already returned
 * HD_CALLBACK_DONE) is not an error: unscheduling is idempotent. */
API void hdUnschedule(HDSchedulerHandle hHandle) {
    pthread_mutex_lock(&g_sched_mu);
    remove_entry_locked(hHandle);
    if (!t_is_scheduler) {
        while (hHandle != 0 && g_running_id == hHandle) {
            pthread_cond_wait(&g_sched_cv, &g_sched_mu);
        }
    }
    pthread_mutex_unlock(&g_sched_mu);
}

#ifndef STANDIN_OMIT_TIMESTAMP
/* Seconds since the current servo tick began (plus any delay the test injected into it). */
API double hdGetSchedulerTimeStamp(void) {
    struct timespec now;
    now_monotonic(&now);
    pthread_mutex_lock(&g_mu);
    double t = g.have_tick ? seconds_between(&g.tick_start, &now) + g.delay_now_s : 0.0;
    pthread_mutex_unlock(&g_mu);
    return t;
}
#endif

/* ---------------------------------------------------------------------------------------------
 * Frames and state.
 */

API void hdBeginFrame(HHD hHD) {
    if (frame_active()) {
        push_error(HD_ILLEGAL_BEGIN, hHD);
        return;
    }
    pthread_mutex_lock(&g_mu);
    if (!g.open || hHD != DEVICE_HANDLE) {
        pthread_mutex_unlock(&g_mu);
        push_error(HD_BAD_HANDLE, hHD);
        return;
    }
    memset(&t_frame, 0, sizeof(t_frame));
    t_frame.active = 1;
    t_frame.epoch = atomic_load(&g_epoch);
    t_frame.device = hHD;
    t_frame.unplugged = g.unplugged || g.stale;
    t_frame.injected = g.inject_now;
    double offset_x_mm = g.calibration == HD_CALIBRATION_OK ? 0.0 : UNCALIBRATED_OFFSET_X_MM;
    for (int i = 0; i < 3; i++) {
        t_frame.position_mm[i] = g.position_m[i] * 1e3;
        t_frame.velocity_mm_s[i] = g.velocity_m_s[i] * 1e3;
    }
    t_frame.position_mm[0] += offset_x_mm;
    for (int col = 0; col < 3; col++) {
        for (int row = 0; row < 3; row++) {
            t_frame.transform[col * 4 + row] = g.rotation[col * 3 + row];
        }
    }
    t_frame.transform[12] = t_frame.position_mm[0];
    t_frame.transform[13] = t_frame.position_mm[1];
    t_frame.transform[14] = t_frame.position_mm[2];
    t_frame.transform[15] = 1.0;
    t_frame.buttons = g.buttons;
    memcpy(t_frame.last_force_n, g.motor_force_n, sizeof(t_frame.last_force_n));
    pthread_mutex_unlock(&g_mu);
    now_monotonic(&t_frame.latched);
}

/* Pushes the frame's error, once per frame: the cable is out, or the test injected one. */
static int frame_failed(void) {
    if (!t_frame.unplugged && t_frame.injected == HD_SUCCESS) return 0;
    if (!t_frame.error_reported) {
        t_frame.error_reported = 1;
        push_error(t_frame.unplugged ? HD_COMM_ERROR : t_frame.injected, t_frame.device);
    }
    return 1;
}

static void record_latency_locked(double us) {
    int bin = us < 0.0 ? 0 : (us >= LATENCY_BINS ? LATENCY_BINS : (int)us);
    g.latency_hist[bin] += 1;
    g.latency_frames += 1;
    if (us > g.latency_max_us) g.latency_max_us = us;
}

API void hdEndFrame(HHD hHD) {
    if (!frame_active() || hHD != t_frame.device) {
        push_error(HD_ILLEGAL_END, hHD);
        return;
    }
    t_frame.active = 0;
    /* A frame that cannot reach the device says so even when it read nothing. */
    int failed = frame_failed();
    struct timespec now;
    now_monotonic(&now);
    pthread_mutex_lock(&g_mu);
    if (t_frame.force_refused || is_force_error(t_frame.injected)) {
        /* A force error switches force output off until the application enables it again. */
        g.force_output = 0;
    }
    int drive = g.open && !g.unplugged && !g.stale && !failed && !t_frame.force_refused &&
                t_frame.force_set && g.force_output && atomic_load(&g_servo_running);
    for (int i = 0; i < 3; i++) g.motor_force_n[i] = drive ? t_frame.force_n[i] : 0.0;
    double sent_n = sqrt(g.motor_force_n[0] * g.motor_force_n[0] +
                         g.motor_force_n[1] * g.motor_force_n[1] +
                         g.motor_force_n[2] * g.motor_force_n[2]);
    g.frames += 1;
    if (sent_n > 0.0) {
        g.last_nonzero_frame = g.frames;
        g.last_nonzero_force_n = sent_n;
    }
    record_latency_locked(seconds_between(&t_frame.latched, &now) * 1e6);
    pthread_mutex_unlock(&g_mu);
}

static int is_frame_state(HDenum pname) {
    switch (pname) {
    case HD_CURRENT_BUTTONS:
    case HD_CURRENT_POSITION:
    case HD_CURRENT_VELOCITY:
    case HD_CURRENT_TRANSFORM:
    case HD_CURRENT_FORCE:
    case HD_LAST_FORCE: return 1;
    default: return 0;
    }
}

/* The frame's latched value of `pname` (zeros when the frame failed); returns the count. */
static int frame_values(HDenum pname, double out[16]) {
    int n = 0;
    const double *src = NULL;
    double buttons = (double)t_frame.buttons;
    switch (pname) {
    case HD_CURRENT_BUTTONS: n = 1; src = &buttons; break;
    case HD_CURRENT_POSITION: n = 3; src = t_frame.position_mm; break;
    case HD_CURRENT_VELOCITY: n = 3; src = t_frame.velocity_mm_s; break;
    case HD_CURRENT_TRANSFORM: n = 16; src = t_frame.transform; break;
    case HD_CURRENT_FORCE: n = 3; src = t_frame.force_n; break;
    case HD_LAST_FORCE: n = 3; src = t_frame.last_force_n; break;
    default: return 0;
    }
    if (frame_failed()) {
        /* The read did not reach the device: stale zeros. */
        memset(out, 0, sizeof(double) * (size_t)n);
    } else {
        memcpy(out, src, sizeof(double) * (size_t)n);
    }
    return n;
}

/* A device property (any thread, in a frame or not). Called with `g_mu` held; returns the count,
 * 0 for an unknown enum. */
static int property_values_locked(HDenum pname, double out[16]) {
    switch (pname) {
    case HD_NOMINAL_MAX_FORCE: out[0] = g.nominal_max_force_n; return 1;
    case HD_NOMINAL_MAX_CONTINUOUS_FORCE: out[0] = NOMINAL_MAX_CONTINUOUS_FORCE_N; return 1;
    case HD_NOMINAL_MAX_STIFFNESS: out[0] = NOMINAL_MAX_STIFFNESS_N_PER_MM; return 1;
    case HD_NOMINAL_MAX_DAMPING: out[0] = NOMINAL_MAX_DAMPING_N_S_PER_MM; return 1;
    case HD_USABLE_WORKSPACE_DIMENSIONS:
        memcpy(out, USABLE_WORKSPACE_MM, sizeof(USABLE_WORKSPACE_MM));
        return 6;
    case HD_MAX_WORKSPACE_DIMENSIONS:
        memcpy(out, MAX_WORKSPACE_MM, sizeof(MAX_WORKSPACE_MM));
        return 6;
    case HD_CALIBRATION_STYLE: out[0] = CALIBRATION_STYLES; return 1;
    case HD_UPDATE_RATE: out[0] = (double)atomic_load(&g_rate_hz); return 1;
    case HD_INSTANTANEOUS_UPDATE_RATE: out[0] = g.instantaneous_rate_hz; return 1;
    case HD_INPUT_DOF: out[0] = 6.0; return 1;
    case HD_OUTPUT_DOF: out[0] = 3.0; return 1;
    default: return 0;
    }
}

/* hdGetDoublev and hdGetIntegerv: the value of `pname` as doubles; returns the count, or 0 after
 * pushing the error (the output is then untouched). */
static int get_values(HDenum pname, const void *out, double values[16]) {
    if (is_frame_state(pname)) {
        if (!frame_active()) {
            atomic_fetch_add(&g_outside_frame_calls, 1ull);
            push_error(HD_FRAME_ERROR, HD_INVALID_HANDLE);
            return 0;
        }
        if (out == NULL) {
            push_error(HD_INVALID_VALUE, t_frame.device);
            return 0;
        }
        return frame_values(pname, values);
    }
    pthread_mutex_lock(&g_mu);
    HDerror err = HD_SUCCESS;
    int n = 0;
    if (!g.open) err = HD_BAD_HANDLE;
    else if ((n = property_values_locked(pname, values)) == 0) err = HD_INVALID_ENUM;
    else if (out == NULL) err = HD_INVALID_VALUE;
    HHD h = g.open ? g.current : HD_INVALID_HANDLE;
    pthread_mutex_unlock(&g_mu);
    if (err != HD_SUCCESS) {
        push_error(err, h);
        return 0;
    }
    return n;
}

API void hdGetDoublev(HDenum pname, double *params) {
    double values[16];
    int n = get_values(pname, params, values);
    for (int i = 0; i < n; i++) params[i] = values[i];
}

API void hdGetIntegerv(HDenum pname, int *params) {
    double values[16];
    int n = get_values(pname, params, values);
    for (int i = 0; i < n; i++) params[i] = (int)clamp_to_int(values[i]);
}

API const char *hdGetString(HDenum pname) {
    const char *s = NULL;
    HDerror err = HD_SUCCESS;
    pthread_mutex_lock(&g_mu);
    if (!g.open) {
        err = HD_BAD_HANDLE;
    } else {
        switch (pname) {
        case HD_DEVICE_MODEL_TYPE: s = g.model; break;
        case HD_DEVICE_VENDOR: s = VENDOR; break;
        case HD_DEVICE_SERIAL_NUMBER: s = SERIAL; break;
        default: err = HD_INVALID_ENUM; break;
        }
    }
    HHD h = g.open ? g.current : HD_INVALID_HANDLE;
    pthread_mutex_unlock(&g_mu);
    if (err != HD_SUCCESS) push_error(err, h);
    return s;
}

API void hdSetDoublev(HDenum pname, const double *params) {
    if (!frame_active()) {
        atomic_fetch_add(&g_outside_frame_calls, 1ull);
        push_error(HD_FRAME_ERROR, HD_INVALID_HANDLE);
        return;
    }
    if (pname != HD_CURRENT_FORCE) {
        push_error(HD_INVALID_ENUM, t_frame.device);
        return;
    }
    if (params == NULL) {
        push_error(HD_INVALID_VALUE, t_frame.device);
        return;
    }
    if (t_frame.unplugged) frame_failed();
    pthread_mutex_lock(&g_mu);
    double max_n = g.nominal_max_force_n;
    int clamping = g.max_force_clamping;
    pthread_mutex_unlock(&g_mu);
    double f[3] = {params[0], params[1], params[2]};
    double magnitude = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
    if (!isfinite(magnitude)) {
        /* No amplifier can output NaN or infinity. */
        push_error(HD_FORCE_ERROR, t_frame.device);
        t_frame.force_refused = 1;
        return;
    }
    if (magnitude > max_n) {
        if (clamping) {
            for (int i = 0; i < 3; i++) f[i] *= max_n / magnitude;
        } else {
            push_error(HD_EXCEEDED_MAX_FORCE, t_frame.device);
            t_frame.force_refused = 1;
            return;
        }
    }
    memcpy(t_frame.force_n, f, sizeof(f));
    t_frame.force_set = 1;
}

/* ---------------------------------------------------------------------------------------------
 * Calibration.
 */

API HDenum hdCheckCalibration(void) {
    pthread_mutex_lock(&g_mu);
    int open = g.open;
    HDenum state = g.calibration;
    pthread_mutex_unlock(&g_mu);
    if (!open) {
        /* 0 is no calibration state: nothing to mistake for HD_CALIBRATION_OK. */
        push_error(HD_BAD_HANDLE, HD_INVALID_HANDLE);
        return 0;
    }
    return state;
}

API void hdUpdateCalibration(HDenum style) {
    HDerror err = HD_SUCCESS;
    pthread_mutex_lock(&g_mu);
    if (!g.open) {
        err = HD_BAD_HANDLE;
    } else if ((style & CALIBRATION_STYLES) == 0 || (style & (style - 1)) != 0) {
        /* One style, and one this device supports. */
        err = HD_INVALID_ENUM;
    } else if (g.calibration == HD_CALIBRATION_NEEDS_UPDATE) {
        /* A device that needs manual input (the stylus in its inkwell) is not helped by this. */
        g.calibration = HD_CALIBRATION_OK;
    }
    HHD h = g.open ? g.current : HD_INVALID_HANDLE;
    pthread_mutex_unlock(&g_mu);
    if (err != HD_SUCCESS) push_error(err, h);
}

/* ---------------------------------------------------------------------------------------------
 * Test controls. The backend never calls these; all are thread-safe.
 */

API void hdStandinInjectError(HDerror code, int ticks) {
    pthread_mutex_lock(&g_mu);
    g.inject_code = code;
    g.inject_ticks = ticks > 0 && code != HD_SUCCESS ? ticks : 0;
    pthread_mutex_unlock(&g_mu);
}

API void hdStandinUnplug(void) {
    pthread_mutex_lock(&g_mu);
    g.unplugged = 1;
    if (g.open) g.stale = 1;
    memset(g.motor_force_n, 0, sizeof(g.motor_force_n));
    pthread_mutex_unlock(&g_mu);
}

API void hdStandinReplug(void) {
    pthread_mutex_lock(&g_mu);
    g.unplugged = 0;
    pthread_mutex_unlock(&g_mu);
}

API void hdStandinSetNominalMaxForce(double n) {
    if (!(n > 0.0) || !isfinite(n)) return;
    pthread_mutex_lock(&g_mu);
    g.nominal_max_force_n = n;
    pthread_mutex_unlock(&g_mu);
}

API void hdStandinRequireCalibration(HDenum state) {
    if (state != HD_CALIBRATION_OK && state != HD_CALIBRATION_NEEDS_UPDATE &&
        state != HD_CALIBRATION_NEEDS_MANUAL_INPUT) {
        return;
    }
    pthread_mutex_lock(&g_mu);
    g.calibration = state;
    pthread_mutex_unlock(&g_mu);
}

/* The user put the stylus in its inkwell: the encoders have their reference, and the library
 * still has to be told (hdUpdateCalibration), as OpenHaptics' own calibration example goes. */
API void hdStandinCompleteManualCalibration(void) {
    pthread_mutex_lock(&g_mu);
    if (g.calibration == HD_CALIBRATION_NEEDS_MANUAL_INPUT) {
        g.calibration = HD_CALIBRATION_NEEDS_UPDATE;
    }
    pthread_mutex_unlock(&g_mu);
}

API void hdStandinDelayTimestamp(int ticks, double delay_s) {
    pthread_mutex_lock(&g_mu);
    g.delay_ticks = ticks > 0 ? ticks : 0;
    g.delay_s = isfinite(delay_s) ? delay_s : 0.0;
    pthread_mutex_unlock(&g_mu);
}

API void hdStandinLastForce(double out_n[3]) {
    if (out_n == NULL) return;
    pthread_mutex_lock(&g_mu);
    memcpy(out_n, g.motor_force_n, sizeof(double) * 3);
    pthread_mutex_unlock(&g_mu);
}

API void hdStandinHandState(double position_mm[3], double velocity_mm_s[3]) {
    pthread_mutex_lock(&g_mu);
    for (int i = 0; i < 3; i++) {
        if (position_mm != NULL) position_mm[i] = g.position_m[i] * 1e3;
        if (velocity_mm_s != NULL) velocity_mm_s[i] = g.velocity_m_s[i] * 1e3;
    }
    pthread_mutex_unlock(&g_mu);
}

API int hdStandinForceOutputEnabled(void) {
    pthread_mutex_lock(&g_mu);
    int on = g.open && g.force_output;
    pthread_mutex_unlock(&g_mu);
    return on;
}

API int hdStandinSchedulerRunning(void) { return atomic_load(&g_servo_running); }

API unsigned long long hdStandinTicks(void) { return atomic_load(&g_ticks); }

API unsigned long long hdStandinSchedulerStarts(void) {
    return atomic_load(&g_scheduler_starts);
}

API unsigned long long hdStandinOutsideFrameCalls(void) {
    return atomic_load(&g_outside_frame_calls);
}

/* The number of successful hdInitDevice calls since the last reset; the CLOCK_MONOTONIC times
 * (seconds) of the first `max` of them (at most MAX_INIT_TIMES) go to `times_s`. */
API int hdStandinInits(double *times_s, int max) {
    pthread_mutex_lock(&g_mu);
    int n = g.inits;
    int kept = n < MAX_INIT_TIMES ? n : MAX_INIT_TIMES;
    for (int i = 0; times_s != NULL && i < kept && i < max; i++) {
        times_s[i] = (double)g.init_times[i].tv_sec + (double)g.init_times[i].tv_nsec * 1e-9;
    }
    pthread_mutex_unlock(&g_mu);
    return n;
}

API int hdStandinDeviceOpen(void) {
    pthread_mutex_lock(&g_mu);
    int open = g.open;
    pthread_mutex_unlock(&g_mu);
    return open;
}

API int hdStandinScheduledCallbacks(void) {
    pthread_mutex_lock(&g_sched_mu);
    int n = g_entry_count;
    pthread_mutex_unlock(&g_sched_mu);
    return n;
}

API void hdStandinSetHand(StandinHand hand, void *user) {
    pthread_mutex_lock(&g_hand_mu);
    g_hand_fn = hand;
    g_hand_user = user;
    pthread_mutex_unlock(&g_hand_mu);
}

API void hdStandinSetButtons(int buttons) {
    pthread_mutex_lock(&g_mu);
    g.buttons = buttons;
    pthread_mutex_unlock(&g_mu);
}

API void hdStandinSetRotation(const double m[9]) {
    pthread_mutex_lock(&g_mu);
    for (int i = 0; i < 9; i++) g.rotation[i] = m != NULL ? m[i] : (i % 4 == 0 ? 1.0 : 0.0);
    pthread_mutex_unlock(&g_mu);
}

/* The percentile's bin's upper edge, never above the largest latency seen. */
static double percentile_locked(double p) {
    if (g.latency_frames == 0) return 0.0;
    uint64_t rank = (uint64_t)ceil(p * (double)g.latency_frames);
    if (rank == 0) rank = 1;
    uint64_t seen = 0;
    for (int bin = 0; bin < LATENCY_BINS; bin++) {
        seen += g.latency_hist[bin];
        if (seen >= rank) {
            double edge = (double)(bin + 1);
            return edge < g.latency_max_us ? edge : g.latency_max_us;
        }
    }
    return g.latency_max_us; /* in the overflow bin */
}

API void hdStandinLatency(double *p50_us, double *p99_us, double *max_us,
                          unsigned long long *frames) {
    pthread_mutex_lock(&g_mu);
    if (p50_us != NULL) *p50_us = percentile_locked(0.50);
    if (p99_us != NULL) *p99_us = percentile_locked(0.99);
    if (max_us != NULL) *max_us = g.latency_max_us;
    if (frames != NULL) *frames = g.latency_frames;
    pthread_mutex_unlock(&g_mu);
}

API void hdStandinResetStats(void) {
    pthread_mutex_lock(&g_mu);
    memset(g.latency_hist, 0, sizeof(g.latency_hist));
    g.latency_frames = 0;
    g.latency_max_us = 0.0;
    pthread_mutex_unlock(&g_mu);
}

/* Back to a freshly loaded library (the tick count since load excepted), so that the tests in one
 * process each start clean. Call it from a test thread, not from a callback or hand. */
API void hdStandinReset(void) {
    if (t_is_scheduler) {
        push_error(HD_INVALID_OPERATION, HD_INVALID_HANDLE);
        return;
    }
    hdStopScheduler();
    pthread_mutex_lock(&g_sched_mu);
    while (g_entry_count > 0) remove_entry_locked(g_entries[0].id);
    pthread_mutex_unlock(&g_sched_mu);
    hdStandinSetHand(NULL, NULL);
    atomic_store(&g_rate_hz, DEFAULT_RATE_HZ);
    pthread_mutex_lock(&g_mu);
    reset_state_locked();
    atomic_fetch_add(&g_epoch, 1u);
    pthread_mutex_unlock(&g_mu);
    pthread_mutex_lock(&g_err_mu);
    g_error_count = 0;
    pthread_mutex_unlock(&g_err_mu);
    atomic_store(&g_scheduler_starts, 0ull);
    atomic_store(&g_outside_frame_calls, 0ull);
}
