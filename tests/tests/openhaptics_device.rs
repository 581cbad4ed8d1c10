//! The OpenHaptics backend against the HD API stand-in (`tests/standin/hd_standin.c`), loaded
//! through the same run-time path as the vendor's `libHD.so` (`SOFTHAPTIC_HD_LIBRARY`): the
//! whole server runs device-clocked on the stand-in's servo thread, records the session, and the
//! recording replays bit for bit. Each fault the stand-in can inject gives zero force on its
//! tick, the `device_fault` flag, the device's state to viewers, and a ramp back in afterwards.
//!
//! The stand-in is one library per process with one device, so the tests here take turns
//! ([`standin`]).
//!
//! The press checks the read → force → command chain twice: on every tick (the force sent at
//! the end of each servo tick is the one computed from that tick's reading) and in time (the
//! stand-in's latch-to-send latency). A hand far stronger than the device pushes a 1 mm sphere
//! 30 mm into the liver in both collision modes, and the contact holds on the side it entered,
//! flagged `pushed_through` in the recording and on the wire, its force saturated at the peak.
//!
//! Long because its tests share some 200 lines of server and stand-in helpers; the assertions
//! every real device's tests make (the ramp, the contact held, the force sent for each reading)
//! are in [`softhaptic_tests::device_checks`].

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::ffi::{c_double, c_int, c_ulonglong};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use glam::{DMat3, DQuat, DVec3};
use softhaptic_device::device::{DeviceError, DeviceLimits, HapticDevice};
use softhaptic_device::openhaptics::{self, OpenHapticsConfig, OpenHapticsDevice};
use softhaptic_device::sim::{HandScript, SimParams, SimulatedPhantom};
use softhaptic_proto::ContactFlags;
use softhaptic_proto::record::{DeviceErrorRecord, DeviceRecord};
use softhaptic_proto::wire::{DeviceStatus, ServerMessage};
use softhaptic_server::app;
use softhaptic_server::devices;
use softhaptic_server::scene::{DeviceChoice, DeviceKind, Scene};
use softhaptic_server::session::reader::Recording;
use softhaptic_server::session::tools::Info;
use softhaptic_tests::device_checks::*;
use softhaptic_tests::standin::{Grip, StandIn, hd, missing_symbol_path, standin_path};
use softhaptic_tests::{
    RecordedServer, Viewer, scratch_dir, start_recorded, test_options, wait_until,
};

/// One test at a time owns the stand-in (an async mutex: the tests hold it across awaits, and a
/// test that fails releases it as it unwinds).
static STANDIN: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// Takes the stand-in: the backend is pointed at it and it is reset to a fresh device.
async fn standin() -> (tokio::sync::MutexGuard<'static, ()>, StandIn) {
    let guard = STANDIN.lock().await;
    point_backend_at(standin_path());
    let s = StandIn::load().unwrap();
    s.reset();
    // The stylus held pointing down, so the stand-in's hand presses the tool's tip straight
    // into the object.
    s.set_rotation(Some(stylus_rotation(DQuat::IDENTITY)));
    (guard, s)
}

/// The stylus' rotation (column-major 3×3) that gives the tool the world orientation
/// `tool_in_world` with the device's axes on the world's: the tool's +y is the stylus' +z.
fn stylus_rotation(tool_in_world: DQuat) -> [f64; 9] {
    let stylus = tool_in_world * DQuat::from_rotation_x(-std::f64::consts::FRAC_PI_2);
    DMat3::from_quat(stylus).to_cols_array()
}

fn point_backend_at(path: &std::path::Path) {
    // SAFETY: every test of this binary sets the variable while holding `STANDIN`, before it
    // starts any thread that reads it.
    unsafe { std::env::set_var(openhaptics::LIBRARY_ENV, path) };
}

/// The built-in scene driven through OpenHaptics, the device's origin on the liver's top
/// (where the stand-in's own hand presses: along −y through the device's origin).
fn liver_scene() -> Scene {
    let mut scene = Scene::builtin_default().unwrap();
    scene.choose_device(&DeviceChoice {
        kind: DeviceKind::Openhaptics,
        name: None,
    });
    let (point, _) = scene.press_site_in_object;
    scene.world_from_device.position_m = scene.object_in_world.transform_point(point);
    scene
}

async fn start(scene: Scene, name: &str) -> RecordedServer {
    start_with(scene, name, |config| config).await
}

/// [`start`] with the device's configuration adjusted by `configure`.
async fn start_with(
    mut scene: Scene,
    name: &str,
    configure: impl FnOnce(OpenHapticsConfig) -> OpenHapticsConfig,
) -> RecordedServer {
    let config = configure(devices::openhaptics_config(&scene));
    let opened = OpenHapticsDevice::open(&config).unwrap();
    scene.device_limits = opened.limits();
    scene.device_label = Some(format!("{} (OpenHaptics)", opened.description().model));
    start_on_device(scene, Box::new(opened), "OpenHaptics", name).await
}

/// The stand-in's counters of what the backend did to it (controls the backend never calls).
struct Counters {
    _library: libloading::Library,
    inits: unsafe extern "C" fn(*mut c_double, c_int) -> c_int,
    scheduler_starts: unsafe extern "C" fn() -> c_ulonglong,
    outside_frame_calls: unsafe extern "C" fn() -> c_ulonglong,
}

impl Counters {
    fn load() -> Counters {
        // SAFETY: the stand-in, already loaded by `standin`: its constructor does not run again.
        let library = unsafe { libloading::Library::new(standin_path()) }.unwrap();
        // SAFETY: the stand-in exports these with the C signatures of the fields.
        unsafe {
            Counters {
                inits: *library.get(b"hdStandinInits\0").unwrap(),
                scheduler_starts: *library.get(b"hdStandinSchedulerStarts\0").unwrap(),
                outside_frame_calls: *library.get(b"hdStandinOutsideFrameCalls\0").unwrap(),
                _library: library,
            }
        }
    }

    /// The CLOCK_MONOTONIC times (s) of the device's successful `hdInitDevice` calls since the
    /// stand-in's reset (the open, then each reconnection).
    fn init_times_s(&self) -> Vec<f64> {
        let mut times = vec![0.0; 256];
        // SAFETY: `times` holds as many doubles as passed.
        let n = unsafe { (self.inits)(times.as_mut_ptr(), times.len() as c_int) };
        times.truncate(n.max(0) as usize);
        times
    }

    fn scheduler_starts(&self) -> u64 {
        // SAFETY: no arguments.
        unsafe { (self.scheduler_starts)() }
    }

    /// Gets of current state and sets of force made from a thread with no frame open.
    fn outside_frame_calls(&self) -> u64 {
        // SAFETY: no arguments.
        unsafe { (self.outside_frame_calls)() }
    }
}

/// Waits for `n` more servo ticks of the stand-in.
async fn wait_ticks(s: &StandIn, n: u64) {
    let target = s.ticks() + n;
    wait_until(&format!("{n} servo ticks"), || s.ticks() >= target).await;
}

/// Waits until the stand-in's motors are sent a force above `newtons` (the hand presses).
async fn wait_pressing(s: &StandIn, newtons: f64) {
    wait_until(&format!("a force above {newtons} N"), || {
        DVec3::from_array(s.last_force_n()).length() > newtons
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_press_through_the_stand_in_feels_like_a_press_through_the_simulator() {
    let (_guard, s) = standin().await;
    let scene = liver_scene();
    // The hand of the simulated device, moved by the forces the stand-in sends its motors: the
    // same hand, the same script, the same loop as a press through the simulator.
    let script = scene.hand_script();
    let params = SimParams {
        limits: DeviceLimits::PHANTOM_DESKTOP,
        ..SimParams::default()
    };
    let hand = SimulatedPhantom::with_params(script, params);
    s.set_rotation(Some(stylus_rotation(script.tool_orientation())));
    let origin = scene.world_from_device.position_m;
    let servo_steps: Arc<Mutex<Vec<ServoStep>>> = Arc::new(Mutex::new(Vec::with_capacity(20_000)));
    let steps = Arc::clone(&servo_steps);
    s.set_hand(simulated_hand(
        hand,
        origin,
        1e3,
        move |force_n, position_mm| {
            // Never a panic here (it cannot unwind into the stand-in): a poisoned log is still a log.
            steps
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .push(ServoStep {
                    force_sent_before_n: force_n,
                    position_mm,
                });
        },
    ));
    // The comparison is of forces, not of this machine's scheduling: a servo thread preempted
    // for a whole period on a loaded test machine must not turn a tick into an overrun here
    // (the overrun has its own test).
    let live = start_with(scene.clone(), "openhaptics-press", |config| {
        OpenHapticsConfig {
            overrun_after_ns: 50_000_000,
            ..config
        }
    })
    .await;
    s.reset_stats();
    // One pass of the script: approach, press, hold, slide, release.
    wait_ticks(&s, 3_600).await;
    let latency = s.latency();
    let (stats, recording) = finish(live).await;
    s.builtin_hand();
    println!(
        "through the stand-in: period error p50 {} µs, p99 {} µs, max {} µs; read-to-command \
         latency p50 {} µs, p99 {} µs, max {} µs over {} frames",
        stats.period_error_p50_ns as f64 * 1e-3,
        stats.period_error_p99_ns as f64 * 1e-3,
        stats.period_error_max_ns as f64 * 1e-3,
        latency.p50_us,
        latency.p99_us,
        latency.max_us,
        latency.frames
    );
    // The force answers the reading of the same servo tick, on every tick: what the motors were
    // sent at the end of each servo tick is the force the loop recorded for the reading that
    // tick's frame latched. The same check one tick late (the force of a reading sent a tick
    // after it, as a loop exchanging with the servo thread would) must fail, or it checks
    // nothing.
    let servo_steps = std::mem::take(&mut *servo_steps.lock().unwrap());
    let same_tick = force_sent_for_reading(&recording.device, origin, &servo_steps, 0);
    let tick_late = force_sent_for_reading(&recording.device, origin, &servo_steps, 1);
    println!(
        "force sent vs force recorded for the reading: {same_tick:e} N off in the same servo \
         tick, {tick_late:e} N off a tick later"
    );
    assert!(
        same_tick <= 1e-9,
        "a force sent differs by {same_tick} N from the one the loop computed from that servo \
         tick's reading"
    );
    assert!(
        tick_late > 1e-3,
        "{tick_late} N: the check cannot tell a tick's delay"
    );
    // And in time, on the stand-in's clock: from the frame's state latch to its force send is
    // the tick's work inside the frame, which must leave the servo period room (a frame that
    // takes a period holds up the next servo tick). The bounds, half a period for the median
    // and a whole one for the 99th percentile, lie far above the tick's compute time even
    // unoptimised (tens of µs), so that a loaded test machine that preempts the servo thread
    // now and then (it runs without real-time priority here) does not fail them; a lag of a
    // whole tick, which a frame-local clock cannot see, is what the check above rules out.
    assert!(latency.frames >= 3_000, "{latency:?}");
    assert!(
        latency.p50_us < 500.0,
        "read-to-command latency p50 {} µs: half a servo period or more",
        latency.p50_us
    );
    assert!(
        latency.p99_us < 1_000.0,
        "read-to-command latency p99 {} µs: a servo period or more",
        latency.p99_us
    );

    // The same press through the simulator, with the limits the session ran with.
    let mut reference_scene = scene.clone();
    reference_scene.device_limits = recording_limits(&recording, &scene);
    let mut world = reference_scene.haptic_world();
    let mut simulated = SimulatedPhantom::with_params(script, params);
    let device = &recording.device;
    assert!(device.len() >= 3_000, "{} ticks recorded", device.len());
    let reference: Vec<DVec3> = device
        .iter()
        .map(|_| world.tick(&mut simulated).state.force_n)
        .collect();
    let peak = reference.iter().map(|f| f.length()).fold(0.0, f64::max);
    assert!(peak > 1.0, "a real press: peak {peak} N");
    let worst = device
        .iter()
        .zip(&reference)
        .map(|(d, r)| (DVec3::from_array(d.force_n) - *r).length())
        .fold(0.0, f64::max);
    println!("largest difference from the simulator: {worst:e} N of a {peak} N peak");
    assert!(
        worst <= 0.01 * peak,
        "forces differ from the simulator's by {worst} N (peak {peak} N)"
    );
    assert!(device.iter().all(|d| d.device_error.is_none()));
    assert_replays(&recording);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hand_stronger_than_the_device_pushes_a_1_mm_sphere_in_and_the_contact_holds() {
    for collision in ["continuous", "paper_vertices"] {
        let (_guard, s) = standin().await;
        let scene = small_sphere_scene(
            "kind = \"openhaptics\"\nmodel = \"phantom_desktop\"",
            collision,
        );
        let (point, normal) = scene.press_site_in_object;
        let n = scene.object_in_world.orientation * normal;
        // Press 30 mm below the surface, hold, slide 10 mm, and pull back out: one pass.
        let mut script = HandScript::press(scene.object_in_world.transform_point(point), n, 0.03);
        script.repeat = false;
        let params = SimParams {
            limits: DeviceLimits::PHANTOM_DESKTOP,
            hand_stiffness_n_per_m: STRONG_GRIP_N_PER_M,
            ..SimParams::default()
        };
        let hand = SimulatedPhantom::with_params(script, params);
        s.set_rotation(Some(stylus_rotation(script.tool_orientation())));
        let origin = scene.world_from_device.position_m;
        s.set_hand(simulated_hand(hand, origin, 1e3, |_, _| {}));
        // The hand's script runs on servo ticks from the scheduler's start, which comes after.
        let start_tick = s.ticks();
        let live = start(
            scene.clone(),
            &format!("openhaptics-pop-through-{collision}"),
        )
        .await;
        let mut viewer = Viewer::connect(live.server.local_addr()).await;
        wait_for_pushed_through_frame(&mut viewer, collision).await;
        // The whole pass, then 300 ticks out of contact.
        let pass_ticks = (script.duration_s() * 1e3).ceil() as u64 + 300;
        let target = start_tick + pass_ticks;
        wait_until("the pass of the hand", || s.ticks() >= target).await;
        let (_, recording) = finish(live).await;
        s.builtin_hand();
        assert_holds_on_the_side_it_entered(&recording, &scene, collision);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_communication_error_mid_press_is_zero_force_on_its_ticks_then_a_ramp() {
    let (_guard, s) = standin().await;
    let live = start(liver_scene(), "openhaptics-comm").await;
    wait_pressing(&s, 1.0).await;
    s.inject_error(hd::HD_COMM_ERROR, 40);
    wait_ticks(&s, 400).await;
    let (stats, recording) = finish(live).await;
    let device = &recording.device;
    let faulted = first_fault_run(device);
    let (first, run) = (faulted.start, faulted.len());
    assert_eq!(run, 40, "one faulted tick per injected servo tick");
    for d in &device[first..first + run] {
        assert_eq!(d.device_error, Some(DeviceErrorRecord::Disconnected));
        assert!(d.device_fault && flags(d).contains(ContactFlags::DEVICE_FAULT));
        assert_eq!(d.force_n, [0.0; 3], "tick {}", d.tick);
    }
    let before = force(&device[first - 1]);
    assert!(before > 0.5, "{before} N before the fault");
    assert_ramps_in_after(device, first, before);
    // Ridden out without a reconnection.
    assert_eq!(stats.watchdog_ticks, 0);
    assert_replays(&recording);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_force_the_driver_refuses_is_zero_on_that_tick_and_ramps_in_after() {
    let (_guard, s) = standin().await;
    let live = start(liver_scene(), "openhaptics-maxforce").await;
    wait_pressing(&s, 1.0).await;
    // The driver's limit drops below the press for a moment: the next command exceeds it, and
    // the driver's cut-out trips once (the force ramps in from zero afterwards, well under the
    // limit on the next ticks).
    s.set_nominal_max_force(0.3);
    wait_ticks(&s, 3).await;
    s.set_nominal_max_force(7.9);
    wait_ticks(&s, 400).await;
    assert!(s.force_output_enabled(), "force output was enabled again");
    let (stats, recording) = finish(live).await;
    let device = &recording.device;
    // A loaded machine may add an overrun of its own before the trip: look for the refusal.
    let first = device
        .iter()
        .position(|d| d.command_error == Some(DeviceErrorRecord::ForceDisabled))
        .expect("a refused command");
    let refused = &device[first];
    assert_eq!(refused.force_n, [0.0; 3], "zero on the refused tick itself");
    assert!(refused.device_fault && flags(refused).contains(ContactFlags::DEVICE_FAULT));
    assert!(stats.command_errors >= 1);
    let before = force(&device[first - 1]);
    assert_ramps_in_after(device, first, before);
    assert_replays(&recording);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tick_that_overruns_its_servo_period_sends_zero_instead_of_a_late_force() {
    let (_guard, s) = standin().await;
    let live = start(liver_scene(), "openhaptics-overrun").await;
    wait_pressing(&s, 1.0).await;
    s.delay_timestamp(5, 2e-3);
    wait_ticks(&s, 300).await;
    let (_, recording) = finish(live).await;
    let device = &recording.device;
    let overran: Vec<&DeviceRecord> = device
        .iter()
        .filter(|d| d.command_error == Some(DeviceErrorRecord::Overrun))
        .collect();
    // The five delayed ticks, and on a loaded machine (a debug build) perhaps one of its own.
    assert!(overran.len() >= 5, "{} overruns", overran.len());
    for d in &overran {
        assert_eq!(d.force_n, [0.0; 3]);
        assert!(flags(d).contains(ContactFlags::DEVICE_FAULT));
    }
    // The delayed ticks are five in a row, after the press began; an overrun the load adds
    // on its own is usually alone, and may come before the press (at zero force).
    let first = device
        .windows(5)
        .position(|w| {
            w.iter()
                .all(|d| d.command_error == Some(DeviceErrorRecord::Overrun))
        })
        .expect("five overruns in a row");
    let before = device[first.saturating_sub(20)..first]
        .iter()
        .map(force)
        .fold(0.0, f64::max);
    assert!(before > 0.5, "{before} N before the delayed ticks");
    assert_ramps_in_after(device, first, before);
    assert_replays(&recording);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unplugged_device_is_reconnected_and_the_force_ramps_in_again() {
    let (_guard, s) = standin().await;
    let live = start(liver_scene(), "openhaptics-unplug").await;
    let mut viewer = Viewer::connect(live.server.local_addr()).await;
    wait_pressing(&s, 1.0).await;
    s.unplug();
    wait_for_device_state(&mut viewer, DeviceStatus::Disconnected).await;
    // The reconnection stops the driver's scheduler and retries while the cable is out.
    wait_until("the scheduler stopped for the reconnection", || {
        !s.scheduler_running()
    })
    .await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    s.replug();
    wait_until("the scheduler restarted", || s.scheduler_running()).await;
    wait_for_device_state(&mut viewer, DeviceStatus::Ok).await;
    wait_ticks(&s, 1_500).await;
    let (stats, recording) = finish(live).await;
    assert!(
        stats.watchdog_ticks > 100,
        "the outage was ticked through: {} watchdog ticks",
        stats.watchdog_ticks
    );
    let device = &recording.device;
    let faulted = first_fault_run(device);
    let (first, outage) = (faulted.start, faulted.len());
    assert!(
        outage as u64
            >= openhaptics::RECONNECT_AFTER_FAILED_TICKS as u64 + stats.watchdog_ticks / 2,
        "{outage} faulted ticks"
    );
    assert!(
        device[first..first + outage]
            .iter()
            .all(|d| d.force_n == [0.0; 3] && d.device_fault)
    );
    // Every tick index is there: the gap is marked by faulted ticks, not missing ones.
    assert!(device.windows(2).all(|w| w[1].tick == w[0].tick + 1));
    // The silence before the watchdog took over (a hundred periods) is counted as lost ticks,
    // and `softhaptic info` says so.
    let lost: u64 = device.iter().map(|d| d.lost_before).sum();
    assert!(lost >= 99, "{lost} ticks counted lost across the outage");
    let info = Info::of(&recording).to_string();
    assert!(!info.contains("lost ticks:        none"), "{info}");
    // The hand kept pressing through the outage: the force ramps in where it is.
    let before = force(&device[first - 1]);
    let back = first + outage;
    assert!(
        device[back..].iter().any(|d| d.in_contact),
        "pressing again after the reconnection"
    );
    assert_ramps_in_after(device, first, before.max(force(&device[back + 100])));
    assert_replays(&recording);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_that_needs_calibration_renders_no_force_until_it_is_calibrated() {
    let (_guard, s) = standin().await;
    s.require_calibration(hd::HD_CALIBRATION_NEEDS_MANUAL_INPUT);
    let live = start(liver_scene(), "openhaptics-calibration").await;
    let mut viewer = Viewer::connect(live.server.local_addr()).await;
    wait_for_device_state(&mut viewer, DeviceStatus::NeedsCalibration).await;
    // Through a whole press of the hand (1500 servo ticks), nothing is sent.
    let target = s.ticks() + 1_500;
    while s.ticks() < target {
        assert_eq!(s.last_force_n(), [0.0; 3]);
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    s.complete_manual_calibration();
    wait_for_device_state(&mut viewer, DeviceStatus::Ok).await;
    wait_pressing(&s, 0.5).await;
    let (_, recording) = finish(live).await;
    let device = &recording.device;
    let calibrated = device
        .iter()
        .position(|d| d.device_error.is_none())
        .unwrap();
    assert!(calibrated >= 1_000, "{calibrated} uncalibrated ticks");
    // Waiting for the stylus in its inkwell, then (once it is there) for the driver's update.
    assert!(device[..calibrated].iter().all(|d| {
        matches!(
            d.device_error,
            Some(DeviceErrorRecord::NeedsCalibration | DeviceErrorRecord::CalibrationUpdating)
        ) && d.force_n == [0.0; 3]
    }));
    assert!(device[calibrated..].iter().any(|d| force(d) > 0.5));
    assert_replays(&recording);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stopping_the_server_sends_zero_force_and_stops_the_scheduler() {
    let (_guard, s) = standin().await;
    // The stylus' second button held through the session: on the wire and in the recording.
    s.set_buttons(2);
    let live = start(liver_scene(), "openhaptics-stop").await;
    wait_pressing(&s, 1.0).await;
    let (stats, recording) = finish(live).await;
    assert!(
        recording
            .device
            .iter()
            .filter_map(|d| d.sample.as_ref())
            .all(|sample| sample.buttons == 2)
    );
    let frame = recording.contacts.last().expect("contact frames recorded");
    match ServerMessage::decode(&frame.json).unwrap() {
        ServerMessage::Contact(c) => assert_eq!(c.buttons, 2),
        other => panic!("{other:?}"),
    }
    assert_eq!(s.last_force_n(), [0.0; 3], "the last force sent is zero");
    assert!(!s.scheduler_running(), "the scheduler stopped");
    assert!(!s.device_open(), "the device was disabled");
    assert_eq!(s.scheduled_callbacks(), 0);
    assert!(stats.ticks > 100);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_library_without_an_hd_function_is_refused_by_name_and_nothing_starts() {
    let (_guard, _s) = standin().await;
    point_backend_at(missing_symbol_path());
    let mut scene = liver_scene();
    let e = devices::open(&mut scene).err().unwrap().to_string();
    assert!(e.contains("hdGetSchedulerTimeStamp"), "{e}");
    assert!(
        e.contains(&missing_symbol_path().display().to_string()),
        "{e}"
    );
    // The server refuses to start: it opens the device before it binds anything.
    let e = app::start(liver_scene(), test_options())
        .await
        .err()
        .unwrap();
    assert!(e.to_string().contains("hdGetSchedulerTimeStamp"), "{e}");
    // A file that is not a library at all.
    let dir = scratch_dir("openhaptics-wrong-library");
    let not_a_library: PathBuf = dir.join("libHD.so");
    std::fs::write(&not_a_library, "not a shared library").unwrap();
    point_backend_at(&not_a_library);
    let e = devices::open(&mut liver_scene()).err().unwrap().to_string();
    assert!(
        e.contains("could not load") && e.contains(openhaptics::LIBRARY_ENV),
        "{e}"
    );
    point_backend_at(standin_path());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_device_listing_shows_the_stand_in_with_its_limits_and_calibration() {
    let (_guard, s) = standin().await;
    let listing = devices::listing(&["Left".into()]);
    assert!(
        listing.contains(&standin_path().display().to_string()),
        "{listing}"
    );
    assert!(listing.contains("PHANTOM Desktop"), "{listing}");
    assert!(listing.contains("STANDIN-0001"), "{listing}");
    assert!(listing.contains("7.90 N peak"), "{listing}");
    assert!(listing.contains("calibrated"), "{listing}");
    // A configuration the vendor's tool never made is named with the driver's reason.
    assert!(listing.contains("\"Left\": cannot be opened"), "{listing}");
    assert!(listing.contains("simulated: always available"), "{listing}");
    assert!(!s.device_open(), "each probed device is closed again");
    // The limits of an opened device are the tighter of its own and the preset's.
    let device = OpenHapticsDevice::open(&OpenHapticsConfig::new(DeviceLimits::TOUCH)).unwrap();
    assert_eq!(device.limits().peak_force_n, 3.3);
    assert_eq!(device.description().max_stiffness_n_per_m, 1860.0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_that_opens_but_keeps_failing_is_reconnected_a_few_times_with_growing_waits() {
    let (_guard, s) = standin().await;
    let counters = Counters::load();
    let live = start(liver_scene(), "openhaptics-keeps-failing").await;
    wait_pressing(&s, 1.0).await;
    // Two seconds of servo ticks that all fail: the device reopens each time, and keeps
    // failing. The stand-in counts them down only while its scheduler runs.
    s.inject_error(hd::HD_COMM_ERROR, 2_000);
    wait_ticks(&s, 2_000 + 1_500).await;
    wait_until("the scheduler running again", || s.scheduler_running()).await;
    wait_pressing(&s, 0.5).await;
    let (stats, recording) = finish(live).await;
    let inits = counters.init_times_s();
    let reconnections = inits.len() - 1;
    println!(
        "{reconnections} reconnections over 2000 failing ticks, {} scheduler starts, at {:?} s",
        counters.scheduler_starts(),
        inits.windows(2).map(|w| w[1] - w[0]).collect::<Vec<_>>()
    );
    // Each reconnection gives the device its RECONNECT_AFTER_FAILED_TICKS failing ticks again.
    let most = (2_000 / openhaptics::RECONNECT_AFTER_FAILED_TICKS) as usize;
    assert!(
        (2..=most).contains(&reconnections),
        "{reconnections} reconnections (at most {most})"
    );
    assert!(counters.scheduler_starts() <= inits.len() as u64);
    // The first reconnection is at once; each one after it, with no run of good ticks between,
    // waits the doubled backoff first (the 250 failing ticks between come on top).
    let mut wait = openhaptics::RECONNECT_BACKOFF_MIN;
    for (k, gap) in inits[1..].windows(2).map(|w| w[1] - w[0]).enumerate() {
        assert!(
            gap >= wait.as_secs_f64() * 0.99,
            "reconnection {} came {gap} s after the one before, not after its {wait:?} wait",
            k + 2
        );
        wait = (wait * 2).min(openhaptics::RECONNECT_BACKOFF_MAX);
    }
    assert!(stats.watchdog_ticks > 0, "the waits were ticked through");
    // The force comes back through the ramp once the device works again.
    let device = &recording.device;
    let first = first_fault_run(device).start;
    let before = force(&device[first - 1]);
    let last_fault = device.len()
        - 1
        - device
            .iter()
            .rev()
            .position(|d| d.device_error.is_some())
            .unwrap();
    assert!(
        device[last_fault + 1..]
            .iter()
            .any(|d| force(d) > 0.5 * before),
        "the force came back"
    );
    assert!(device.windows(2).all(|w| w[1].tick == w[0].tick + 1));
    assert_replays(&recording);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tick_run_off_the_servo_thread_while_a_frame_is_open_does_not_touch_the_device() {
    let (_guard, _s) = standin().await;
    let counters = Counters::load();
    let mut opened =
        OpenHapticsDevice::open(&OpenHapticsConfig::new(DeviceLimits::PHANTOM_DESKTOP)).unwrap();
    let mut clock = opened.servo_clock().unwrap();
    let device = Arc::new(Mutex::new(opened));
    let frame_open = Arc::new(AtomicBool::new(false));
    let release = Arc::new(AtomicBool::new(false));
    let servo_read: Arc<Mutex<Option<Result<(), DeviceError>>>> = Arc::default();
    {
        let (device, frame_open, release, servo_read) = (
            Arc::clone(&device),
            Arc::clone(&frame_open),
            Arc::clone(&release),
            Arc::clone(&servo_read),
        );
        // The servo thread's first tick reads the device in its frame, then keeps the frame
        // open until the test has run its tick on another thread (as the loop's watchdog does
        // when the driver resumes in the middle of a watchdog tick).
        clock
            .start(Box::new(move |_| {
                if frame_open.load(Ordering::Acquire) {
                    return;
                }
                let read = device.lock().unwrap().read().map(|_| ());
                *servo_read.lock().unwrap() = Some(read);
                frame_open.store(true, Ordering::Release);
                let give_up = Instant::now() + Duration::from_secs(30);
                while !release.load(Ordering::Acquire) && Instant::now() < give_up {
                    std::thread::sleep(Duration::from_millis(1));
                }
            }))
            .unwrap();
    }
    let deadline = Instant::now() + Duration::from_secs(30);
    while !frame_open.load(Ordering::Acquire) {
        assert!(Instant::now() < deadline, "no servo tick");
        std::thread::sleep(Duration::from_millis(1));
    }
    let (read, command, touched) = {
        let mut d = device.lock().unwrap();
        let before = counters.outside_frame_calls();
        let read = d.read().map(|_| ());
        let command = d.command_force(DVec3::new(0.0, 1.0, 0.0));
        (read, command, counters.outside_frame_calls() - before)
    };
    release.store(true, Ordering::Release);
    clock.stop();
    assert_eq!(
        *servo_read.lock().unwrap(),
        Some(Ok(())),
        "the servo thread reads in its frame"
    );
    assert_eq!(touched, 0, "the device was touched from outside the frame");
    assert_eq!(read, Err(DeviceError::Timeout));
    assert_eq!(command, Err(DeviceError::Timeout));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fault_of_three_ticks_reaches_the_viewers() {
    let (_guard, s) = standin().await;
    let live = start(liver_scene(), "openhaptics-short-fault").await;
    let mut viewer = Viewer::connect(live.server.local_addr()).await;
    wait_pressing(&s, 1.0).await;
    // Three milliseconds of fault, far shorter than the status' 50 ms poll.
    s.inject_error(hd::HD_COMM_ERROR, 3);
    wait_for_device_state(&mut viewer, DeviceStatus::Disconnected).await;
    wait_for_device_state(&mut viewer, DeviceStatus::Ok).await;
    let (_, recording) = finish(live).await;
    let faulted = recording
        .device
        .iter()
        .filter(|d| d.device_error.is_some())
        .count();
    assert_eq!(faulted, 3);
}

// What a real driver does that the backend must survive: a scheduler that does not start, warm
// motors, calibration lost mid-session, force trips, the nominal limit after the frame rotation,
// a device's own data, a driver that stops calling back, a failed tick, late servo ticks.

/// The stand-in's built-in hand pressing 25 mm below the liver's surface (down and back over
/// 6 s), well past the Desktop's continuous force, instead of its default 8 mm.
fn deep_press(s: &StandIn) {
    // SAFETY: set and removed while the test holds `STANDIN`, before any thread of its own
    // starts; the stand-in reads it in the reset.
    unsafe { std::env::set_var("HD_STANDIN_PRESS", "0,0,0,25,6") };
    s.reset();
    // SAFETY: as above.
    unsafe { std::env::remove_var("HD_STANDIN_PRESS") };
    s.set_rotation(Some(stylus_rotation(DQuat::IDENTITY)));
}

/// Moves the stand-in's stylus by a simulated hand with a strong grip following `script` (the
/// stylus turned to the script's tool orientation in the device's axes); returns the largest
/// force the stand-in's motors are sent, kept up to date.
fn strong_hand(s: &StandIn, scene: &Scene, script: HandScript) -> Arc<Mutex<f64>> {
    s.set_rotation(Some(stylus_rotation(
        scene.world_from_device.orientation.inverse() * script.tool_orientation(),
    )));
    let params = SimParams {
        limits: DeviceLimits::PHANTOM_DESKTOP,
        hand_stiffness_n_per_m: STRONG_GRIP_N_PER_M,
        ..SimParams::default()
    };
    let mut hand = SimulatedPhantom::with_params(script, params);
    let world_from_device = scene.world_from_device;
    let largest = Arc::new(Mutex::new(0.0_f64));
    let seen = Arc::clone(&largest);
    let mut first = true;
    s.set_hand(move |force_n, position_mm, velocity_mm_s| {
        let f = DVec3::from_array(force_n);
        let mut l = seen.lock().unwrap_or_else(PoisonError::into_inner);
        *l = l.max(f.length());
        drop(l);
        if !std::mem::replace(&mut first, false) {
            hand.command_force(world_from_device.orientation * f)
                .unwrap();
        }
        let sample = hand.read().unwrap();
        *position_mm = (world_from_device.inverse_transform_point(sample.tip_in_world.position_m)
            * 1e3)
            .to_array();
        *velocity_mm_s =
            (world_from_device.orientation.inverse() * sample.tip_velocity_m_s * 1e3).to_array();
    });
    largest
}

/// Runs `scene` on the stand-in (the caller set its nominal maximum to 3.3 N), pressed by a strong hand
/// following `script` until the device saturates, then 1 000 more servo ticks; returns the
/// largest force the motors were sent, held below the nominal maximum by the backend's margin,
/// and the session's recording.
async fn saturating_press(
    s: &StandIn,
    scene: Scene,
    script: HandScript,
    name: &str,
) -> (f64, Recording) {
    let largest = strong_hand(s, &scene, script);
    let live = start(scene, name).await;
    wait_until("the hand saturating the device", || {
        *largest.lock().unwrap_or_else(PoisonError::into_inner) > 3.0
    })
    .await;
    wait_ticks(s, 1_000).await;
    let (_, recording) = finish(live).await;
    s.builtin_hand();
    let largest = *largest.lock().unwrap_or_else(PoisonError::into_inner);
    assert!(
        largest <= 3.3 * (1.0 - openhaptics::servo::FORCE_MARGIN) + 1e-12,
        "{largest} N sent"
    );
    (largest, recording)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn guidance_and_a_hard_press_together_stay_below_the_nominal_maximum() {
    let (_guard, s) = standin().await;
    s.set_nominal_max_force(3.3);
    let mut scene = liver_scene();
    let expert = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("sessions/slide.mcap");
    let guide = softhaptic_server::session::guide::guide_from_file(
        &expert,
        &scene,
        softhaptic_proto::GuideParams::default(),
        softhaptic_proto::GuideGain::Fixed { gain: 1.0 },
    )
    .unwrap();
    scene.set_guide(guide).unwrap();
    // A hard press 30 mm deep, 6 mm beside the expert's: the contact saturates the device while
    // the guide pulls sideways at its cap.
    let (point, normal) = scene.press_site_in_object;
    let n = scene.object_in_world.orientation * normal;
    let mut script = HandScript::press(scene.object_in_world.transform_point(point), n, 0.03);
    script.repeat = false;
    let across = n.cross(script.slide_direction).normalize();
    script.surface_point_m += across * 0.006;
    let (largest, recording) = saturating_press(&s, scene, script, "openhaptics-guided").await;
    // The guide pulled while the device was saturated, and the sum was held to the peak.
    let pulling_saturated = recording
        .device
        .iter()
        .filter(|d| {
            flags(d).contains(ContactFlags::SATURATED)
                && d.guide
                    .is_some_and(|g| g.engaged && g.force_n.length() > 0.5)
        })
        .count();
    assert!(pulling_saturated > 100, "{pulling_saturated} ticks");
    // The loop's own command, guide and contact summed, never passed the device's peak (the
    // backend then keeps its margin below the nominal maximum, above).
    let peak_recorded = recording.device.iter().map(force).fold(0.0, f64::max);
    let peak_n = recording.scene.message.device.peak_force_n;
    assert!(
        peak_recorded <= peak_n + 1e-12,
        "{peak_recorded} N of {peak_n} N"
    );
    assert_replays(&recording);
    println!(
        "guided hard press: the largest force sent was {largest:.6} N of 3.3 N, the loop's \
         largest command {peak_recorded:.6} N of its {peak_n} N peak; {pulling_saturated} \
         saturated ticks with the guide pulling over 0.5 N"
    );
}

/// Runs `f` on a thread of its own and waits for it at most `deadline`: a call that hangs (as a
/// synchronous scheduler call on a stopped scheduler does on the vendor's library) fails the
/// test instead of holding it.
fn within<T: Send + 'static>(
    deadline: Duration,
    what: &str,
    f: impl FnOnce() -> T + Send + 'static,
) -> T {
    let (tx, rx) = std::sync::mpsc::sync_channel(1);
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(deadline)
        .unwrap_or_else(|_| panic!("{what} did not return within {deadline:?}: it hangs"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_scheduler_that_does_not_start_is_reported_at_once_with_the_drivers_error() {
    let (_guard, s) = standin().await;
    // The loop's start, as `softhaptic run` makes it.
    s.fail_scheduler_start(1);
    let scene = liver_scene();
    let config = devices::openhaptics_config(&scene);
    let started = Instant::now();
    let error = within(Duration::from_secs(20), "the loop's start", move || {
        let device = OpenHapticsDevice::open(&config).unwrap();
        let world = scene.haptic_world();
        let config = softhaptic_device::haptic_loop::LoopConfig {
            realtime: false,
            standby: false,
            ..Default::default()
        };
        softhaptic_device::haptic_loop::HapticLoop::spawn(Box::new(device), world, config)
            .err()
            .expect("the loop did not start")
            .to_string()
    });
    let took = started.elapsed();
    assert!(error.contains("HD_TIMER_ERROR"), "{error}");
    assert!(error.contains("real-time"), "what to do: {error}");
    assert!(!error.contains("disconnected"), "not the cause: {error}");
    assert!(!s.device_open(), "the device is released");
    assert_eq!(s.scheduled_callbacks(), 0);
    assert!(!s.scheduler_running());
    println!("loop start: the clear error after {took:?}");

    // `softhaptic devices` (the same probe the doctor makes).
    s.reset();
    s.fail_scheduler_start(1);
    let started = Instant::now();
    let discovery = within(Duration::from_secs(20), "the device listing", || {
        openhaptics::discover(&[])
    });
    let took = started.elapsed();
    let openhaptics::Discovery::Library { devices, .. } = discovery else {
        panic!("the stand-in did not load");
    };
    let text = devices[0].1.as_ref().expect_err("reported").to_string();
    assert!(
        text.contains("HD_TIMER_ERROR") && text.contains("real-time"),
        "{text}"
    );
    assert!(!s.device_open());
    println!("device listing: the clear error after {took:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn warm_motors_keep_rendering_limited_to_the_continuous_force() {
    let (_guard, s) = standin().await;
    // A press to 25 mm: well above the Desktop's continuous 1.75 N.
    deep_press(&s);
    let live = start(liver_scene(), "openhaptics-warm").await;
    let mut viewer = Viewer::connect(live.server.local_addr()).await;
    wait_pressing(&s, 2.0).await;
    s.inject_error(hd::HD_WARM_MOTORS, 2_000);
    // The hand feels a force all along: sampled while the motors are warm (from the tick after
    // the first warning on).
    wait_ticks(&s, 5).await;
    let mut felt = Vec::new();
    let end = s.ticks() + 1_900;
    while s.ticks() < end {
        felt.push(DVec3::from_array(s.last_force_n()).length());
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    // The flag reaches the viewers by name.
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        assert!(Instant::now() < deadline, "no frame flagged motors_warm");
        if let Some(Ok(ServerMessage::Contact(c))) = viewer.next(Duration::from_secs(5)).await
            && c.flags.contains(ContactFlags::MOTORS_WARM)
        {
            break;
        }
    }
    wait_ticks(&s, 1_000).await;
    let (_, recording) = finish(live).await;
    let limits = recording_limits(&recording, &liver_scene());
    let warm: Vec<&DeviceRecord> = recording
        .device
        .iter()
        .filter(|d| flags(d).contains(ContactFlags::MOTORS_WARM))
        .collect();
    assert!(warm.len() >= 2_000, "{} ticks flagged warm", warm.len());
    for d in &warm {
        // A warning is no fault (a tick that overran on a loaded machine is one of its own).
        assert!(
            !d.device_fault || d.command_error == Some(DeviceErrorRecord::Overrun),
            "tick {}: a warning is no fault: {d:?}",
            d.tick
        );
        assert!(
            force(d) <= limits.continuous_force_n + 1e-9,
            "tick {}: {} N",
            d.tick,
            force(d)
        );
    }
    let mean_n = warm.iter().map(|d| force(d)).sum::<f64>() / warm.len() as f64;
    assert!(mean_n > 0.5, "{mean_n} N rendered on average while warm");
    let felt_mean = felt.iter().sum::<f64>() / felt.len() as f64;
    assert!(felt.iter().all(|f| *f <= limits.continuous_force_n + 1e-9));
    assert!(felt_mean > 0.5, "the stylus went limp: {felt_mean} N felt");
    println!(
        "warm motors: {} ticks, {mean_n:.2} N commanded and {felt_mean:.2} N felt on average (limit {} N)",
        warm.len(),
        limits.continuous_force_n
    );
    // Once they cool, the force is released back without a step.
    let last_warm = recording
        .device
        .iter()
        .rposition(|d| flags(d).contains(ContactFlags::MOTORS_WARM))
        .unwrap();
    for w in recording.device[last_warm..].windows(2) {
        assert!(
            force(&w[1]) - force(&w[0]) < 0.1,
            "a step of {} N at tick {}",
            force(&w[1]) - force(&w[0]),
            w[1].tick
        );
    }
    let info = Info::of(&recording).to_string();
    assert!(info.contains("motors_warm"), "{info}");
    assert_replays(&recording);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn calibration_lost_mid_session_is_caught_before_any_force_goes_unapplied() {
    let (_guard, s) = standin().await;
    s.set_calibration_styles(hd::HD_CALIBRATION_AUTO | hd::HD_CALIBRATION_INKWELL);
    let live = start(liver_scene(), "openhaptics-calibration-lost").await;
    let mut viewer = Viewer::connect(live.server.local_addr()).await;
    wait_pressing(&s, 1.0).await;
    // Lost where the driver can update it by itself: updated, and the force ramps in again.
    s.require_calibration(hd::HD_CALIBRATION_NEEDS_UPDATE);
    wait_ticks(&s, 500).await;
    wait_pressing(&s, 1.0).await;
    // Lost so that the operator must act: no force, and the viewers are told what to do.
    s.require_calibration(hd::HD_CALIBRATION_NEEDS_MANUAL_INPUT);
    wait_for_device_state(&mut viewer, DeviceStatus::NeedsCalibration).await;
    wait_ticks(&s, 300).await;
    assert_eq!(s.last_force_n(), [0.0; 3]);
    s.complete_manual_calibration();
    wait_for_device_state(&mut viewer, DeviceStatus::Ok).await;
    wait_pressing(&s, 1.0).await;
    let unapplied = s.unapplied_frames();
    let (_, recording) = finish(live).await;
    assert_eq!(
        unapplied, 0,
        "ticks of force commanded and silently not applied"
    );
    let updating = recording
        .device
        .iter()
        .filter(|d| d.device_error == Some(DeviceErrorRecord::CalibrationUpdating))
        .count();
    let waiting = recording
        .device
        .iter()
        .filter(|d| d.device_error == Some(DeviceErrorRecord::NeedsCalibration))
        .count();
    assert!(
        updating >= 1 && waiting >= 300,
        "{updating} updating, {waiting} waiting"
    );
    for d in recording
        .device
        .iter()
        .filter(|d| d.device_error.is_some() || d.command_error.is_some())
    {
        assert_eq!(d.force_n, [0.0; 3], "tick {}", d.tick);
    }
    println!(
        "calibration: {updating} ticks updating, {waiting} waiting for the inkwell, {unapplied} unapplied"
    );
    assert_replays(&recording);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn force_trips_are_rearmed_a_few_times_then_latched_until_an_instructor_rearms() {
    let (_guard, s) = standin().await;
    let mut options = test_options();
    options.access.tokens = Some(softhaptic_tests::test_tokens());
    let mut scene = liver_scene();
    let config = devices::openhaptics_config(&scene);
    let opened = OpenHapticsDevice::open(&config).unwrap();
    scene.device_limits = opened.limits();
    options.device = Some(Box::new(opened));
    let live = start_recorded(scene, &scratch_dir("openhaptics-trips"), options).await;
    let addr = live.server.local_addr();
    let mut instructor = Viewer::connect(addr).await;
    instructor
        .authenticate(softhaptic_tests::INSTRUCTOR_TOKEN)
        .await;
    let mut observer = Viewer::connect(addr).await;
    observer
        .authenticate(softhaptic_tests::OBSERVER_TOKEN)
        .await;
    wait_pressing(&s, 1.0).await;
    let enables_before = s.force_output_enables();
    // The driver's cut-out trips on an impulse, again and again.
    for _ in 0..6 {
        s.inject_error(hd::HD_EXCEEDED_MAX_FORCE_IMPULSE, 1);
        wait_ticks(&s, 150).await;
    }
    wait_for_device_state(&mut instructor, DeviceStatus::ForceLatched).await;
    let rearms = s.force_output_enables() - enables_before;
    assert_eq!(
        rearms,
        openhaptics::servo::MAX_AUTO_REARMS as u64,
        "automatic re-arms in the window"
    );
    wait_ticks(&s, 300).await;
    assert!(!s.force_output_enabled(), "latched off");
    assert_eq!(s.last_force_n(), [0.0; 3]);
    // An observer may not re-arm it; an instructor may.
    observer.send_text(r#"{"type":"rearm_device"}"#).await;
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        assert!(
            Instant::now() < deadline,
            "the observer's re-arm was not refused"
        );
        if let Some(Ok(ServerMessage::Refused(r))) = observer.next(Duration::from_secs(5)).await {
            assert_eq!(r.request, "rearm_device");
            break;
        }
    }
    wait_ticks(&s, 100).await;
    assert!(!s.force_output_enabled(), "an observer re-armed it");
    instructor.send_text(r#"{"type":"rearm_device"}"#).await;
    wait_until("force output re-armed", || s.force_output_enabled()).await;
    wait_pressing(&s, 1.0).await;
    let (_, recording) = finish(live).await;
    let latched = recording
        .device
        .iter()
        .filter(|d| d.command_error == Some(DeviceErrorRecord::ForceLatched))
        .count();
    assert!(latched >= 300, "{latched} latched ticks");
    let first_latched = recording
        .device
        .iter()
        .position(|d| d.command_error == Some(DeviceErrorRecord::ForceLatched))
        .unwrap();
    assert_ramps_in_after(&recording.device, first_latched, 1.0);
    println!(
        "force trips: {rearms} re-armed automatically, then {latched} ticks latched until the instructor's re-arm"
    );
    assert_replays(&recording);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_force_sent_stays_below_the_nominal_maximum_in_the_devices_axes() {
    let (_guard, s) = standin().await;
    s.set_nominal_max_force(3.3);
    let mut scene = liver_scene();
    // The device turned on the table: every force is rotated into its axes.
    scene.world_from_device.orientation = DQuat::from_rotation_y(0.7) * DQuat::from_rotation_x(0.3);
    let (point, normal) = scene.press_site_in_object;
    let n = scene.object_in_world.orientation * normal;
    let mut script = HandScript::press(scene.object_in_world.transform_point(point), n, 0.03);
    script.repeat = false;
    let (largest, recording) = saturating_press(&s, scene, script, "openhaptics-nominal").await;
    assert!(
        recording
            .device
            .iter()
            .any(|d| flags(d).contains(ContactFlags::SATURATED))
    );
    // (A tick that overran on a loaded machine sent zero instead: not a refusal.)
    assert!(
        recording.device.iter().all(|d| !matches!(
            d.command_error,
            Some(DeviceErrorRecord::ForceDisabled | DeviceErrorRecord::ForceLatched)
        ) && !matches!(
            d.device_error,
            Some(DeviceErrorRecord::ForceDisabled | DeviceErrorRecord::ForceLatched)
        )),
        "the driver refused a force"
    );
    println!("nominal limit: the largest force sent was {largest:.6} N of 3.3 N");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_devices_own_data_are_checked_and_a_tip_outside_the_usable_box_is_flagged_not_pinned() {
    let (_guard, s) = standin().await;
    let config = devices::openhaptics_config(&liver_scene());
    s.set_workspace(Some([0.0; 6]), None);
    let error = OpenHapticsDevice::open(&config)
        .err()
        .expect("refused")
        .to_string();
    assert!(
        error.contains("HD_USABLE_WORKSPACE_DIMENSIONS") && error.contains("empty"),
        "{error}"
    );
    assert!(!s.device_open(), "released after the refusal");
    // A usable box only 5 mm high: the hand's press (20 mm above to 8 mm below) leaves it.
    s.set_workspace(
        Some([-80.0, -5.0, -60.0, 80.0, 5.0, 60.0]),
        Some([-100.0, -80.0, -80.0, 100.0, 80.0, 80.0]),
    );
    let live = start(liver_scene(), "openhaptics-workspace").await;
    wait_pressing(&s, 1.0).await;
    wait_ticks(&s, 3_000).await;
    let (_, recording) = finish(live).await;
    let origin = liver_scene().world_from_device.position_m;
    let heights_mm: Vec<(f64, bool)> = recording
        .device
        .iter()
        .filter_map(|d| {
            let p = DVec3::from_array(d.sample.as_ref()?.tip_position_m);
            Some((
                (p - origin).y * 1e3,
                flags(d).contains(ContactFlags::OUTSIDE_WORKSPACE),
            ))
        })
        .collect();
    assert!(
        heights_mm.iter().any(|(y, _)| *y > 10.0),
        "the tip followed the hand above the box"
    );
    for (y, flagged) in &heights_mm {
        assert_eq!(*flagged, y.abs() > 5.0 + 1e-6, "at {y} mm");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_driver_that_stops_calling_back_is_reconnected() {
    let (_guard, s) = standin().await;
    let counters = Counters::load();
    let live = start(liver_scene(), "openhaptics-silent").await;
    let mut viewer = Viewer::connect(live.server.local_addr()).await;
    wait_pressing(&s, 1.0).await;
    assert_eq!(counters.init_times_s().len(), 1);
    // The driver's thread runs on, but calls nothing for 3 s: no error tick ever comes.
    s.stall_callbacks(3_000);
    wait_for_device_state(&mut viewer, DeviceStatus::NotAnswering).await;
    wait_until("the device reopened", || counters.init_times_s().len() >= 2).await;
    wait_for_device_state(&mut viewer, DeviceStatus::Ok).await;
    let (stats, recording) = finish(live).await;
    assert!(stats.watchdog_ticks > 0);
    assert_replays(&recording);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tick_that_panics_sends_zero_in_its_frame_and_raises_a_fatal_flag() {
    let (_guard, s) = standin().await;
    let config = devices::openhaptics_config(&liver_scene());
    let mut device = OpenHapticsDevice::open(&config).unwrap();
    let mut clock = device.servo_clock().unwrap();
    let device = Arc::new(Mutex::new(device));
    let in_tick = Arc::clone(&device);
    let ticks = Arc::new(std::sync::atomic::AtomicU64::new(0));
    let counted = Arc::clone(&ticks);
    clock
        .start(Box::new(move |_| {
            let mut d = in_tick.lock().unwrap_or_else(PoisonError::into_inner);
            let _ = d.read();
            let _ = d.command_force(DVec3::new(0.0, 1.5, 0.0));
            drop(d);
            if counted.fetch_add(1, Ordering::SeqCst) == 200 {
                panic!("a bug in the tick, after it set its force");
            }
        }))
        .unwrap();
    wait_until("the panic", || ticks.load(Ordering::SeqCst) > 200).await;
    // The failed tick raises the fatal state inside its frame, just before ending it.
    let failed = || {
        let mut d = device.lock().unwrap_or_else(PoisonError::into_inner);
        d.read().err() == Some(DeviceError::Fatal)
    };
    wait_until("the fatal state", failed).await;
    // Its frame has ended once the servo thread has ticked again, or once the silence its report
    // caused had the scheduler stopped (a failed tick is never restarted).
    let after = s.ticks();
    wait_until("the failed frame's end", || {
        !s.scheduler_running() || s.ticks() > after
    })
    .await;
    assert_eq!(
        s.last_force_n(),
        [0.0; 3],
        "the force set before the panic went out"
    );
    let mut d = device.lock().unwrap_or_else(PoisonError::into_inner);
    assert_eq!(d.read().err(), Some(DeviceError::Fatal));
    drop(d);
    clock.stop();
}

/// A light pinch grip on the stylus: 1000 N/m and 0.5 N·s/m toward the press's target, on the
/// PHANTOM Desktop's 45 g at the tip and 5 g of fingertips. Stiffer, less damped and three times
/// lighter than the stand-in's relaxed pen grip ([`Grip::RELAXED`]), it is the hand a stall finds
/// least stable: over a 10 ms tick the force the device holds moves the tip so far that the next
/// tick's force overshoots (K_max T² / m ≈ 2), and a contact rendered at the device's stable
/// stiffness without the late-tick bound chatters. At 3 ms (K_max T² / m ≈ 0.2) it does not.
const PINCH: Grip = Grip {
    stiffness_n_per_m: 1_000.0,
    damping_n_s_per_m: 0.5,
    mass_kg: 0.05,
};

/// A press held by `grip` stalled for 50 servo ticks of `tick_s` each, and what the force did.
struct Stall {
    /// Late ticks found, and the indices in the recording of the first and the last.
    late: usize,
    first: usize,
    last: usize,
    /// Largest per-tick change of the force vector from the first late tick to 50 ticks after
    /// the last (N), the number over 1 N, and the steps left out beside an overrun.
    largest_step_n: f64,
    steps_over_1_n: usize,
    overrun_steps: usize,
    /// Ticks of that span whose force was the device's peak.
    at_peak: usize,
    /// Ticks after the last late tick until the first whose force the late-tick bound no longer
    /// limits (0: it was not limiting at the stall's end).
    settled_after: usize,
}

async fn stall(grip: Grip, tick_s: f64) -> (Stall, Recording) {
    let (_guard, s) = standin().await;
    // Near the bottom of a press 25 mm down.
    deep_press(&s);
    s.set_grip(grip);
    let scene = liver_scene();
    let live = start(scene.clone(), "openhaptics-late").await;
    wait_pressing(&s, 2.0).await;
    wait_ticks(&s, 200).await;
    s.late_ticks(50, tick_s);
    wait_ticks(&s, 600).await;
    let (_, recording) = finish(live).await;
    let peak_n = recording_limits(&recording, &scene).peak_force_n;
    let device = &recording.device;
    // The stall: the longest run of ticks at least 3/4 of `tick_s` after the one before, at most
    // 20 on-time ticks apart (a loaded machine splits it: overruns, and servo calls it delays). A tick a loaded machine makes late
    // by itself elsewhere in the session is not part of it.
    let late: Vec<usize> = (1..device.len())
        .filter(|&i| (device[i].time_ns - device[i - 1].time_ns) as f64 > 0.75 * tick_s * 1e9)
        .collect();
    let mut runs: Vec<&[usize]> = Vec::new();
    let mut begin = 0;
    for k in 1..=late.len() {
        if k == late.len() || late[k] - late[k - 1] > 20 {
            runs.push(&late[begin..k]);
            begin = k;
        }
    }
    let run = runs.into_iter().max_by_key(|r| r.len()).unwrap_or(&[]);
    // The stand-in runs 50 (42 to 50 counted here, unloaded): a loaded machine may run some on
    // time, or record them as overruns.
    assert!(
        run.len() >= 30,
        "{tick_s} s ticks: {} late ticks",
        run.len()
    );
    let (first, last) = (run[0], run[run.len() - 1]);
    // A tick that overran its servo period (a loaded machine) sends zero and ramps in again:
    // that fault is the overrun's, tested on its own, not chatter.
    let overrun =
        |d: &DeviceRecord| d.device_fault && d.command_error == Some(DeviceErrorRecord::Overrun);
    let end = (last + 50).min(device.len());
    let mut figures = Stall {
        late: run.len(),
        first,
        last,
        largest_step_n: 0.0,
        steps_over_1_n: 0,
        overrun_steps: 0,
        at_peak: 0,
        settled_after: device[last..end]
            .iter()
            .position(|d| !flags(d).contains(ContactFlags::LATE_TICK_LIMITED))
            .unwrap_or(end - last),
    };
    for i in first..end {
        if overrun(&device[i]) || overrun(&device[i - 1]) {
            figures.overrun_steps += 1;
            continue;
        }
        let step = (DVec3::from_array(device[i].force_n)
            - DVec3::from_array(device[i - 1].force_n))
        .length();
        let onset = !device[i - 1].in_contact && device[i].in_contact;
        figures.largest_step_n = figures.largest_step_n.max(step);
        if step > 1.0 && !onset {
            figures.steps_over_1_n += 1;
        }
        if force(&device[i]) >= peak_n * (1.0 - 1e-9) {
            figures.at_peak += 1;
        }
    }
    (figures, recording)
}

/// A stalled servo thread (50 ticks of 3 ms, then of 10 ms) under a press held by the stand-in's
/// relaxed grip and by a pinch grip ([`PINCH`]). The late-tick bound keeps every step of the
/// force under 1 N and the force off the peak, and the lag it leaves is settled within a few
/// ticks of the stall's end. Without the bound, the pinch grip's 10 ms stall chatters: the force
/// swings by several newtons from one tick to the next (5.1 N at most, 12 steps over 1 N).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn late_servo_ticks_do_not_make_a_held_press_chatter() {
    for (name, grip) in [("relaxed", Grip::RELAXED), ("pinch", PINCH)] {
        for tick_s in [3e-3, 10e-3] {
            let (f, recording) = stall(grip, tick_s).await;
            println!(
                "{name} grip, late ticks of {} ms: {} late; largest step {:.3} N, {} over 1 N, \
                 {} at the peak, settled {} ticks after ({} steps beside an overrun left out)",
                tick_s * 1e3,
                f.late,
                f.largest_step_n,
                f.steps_over_1_n,
                f.at_peak,
                f.settled_after,
                f.overrun_steps
            );
            let what = format!(
                "{name} grip, {tick_s} s ticks (ticks {}..={})",
                f.first, f.last
            );
            assert_eq!(
                f.steps_over_1_n, 0,
                "{what}: steps over 1 N, the largest {:.3} N",
                f.largest_step_n
            );
            assert_eq!(f.at_peak, 0, "{what}: ticks at the peak force");
            assert!(
                f.settled_after <= 10,
                "{what}: settled {} ticks after",
                f.settled_after
            );
            assert_replays(&recording);
        }
    }
}
