//! The Force Dimension backend against the SDK stand-in (`tests/standin/dhd_standin.c`), loaded
//! through the same run-time path as the vendor's `libdhd.so` (`SOFTHAPTIC_DHD_LIBRARY`): the
//! whole server runs with the loop's own thread clocking the device, records the session, and
//! the recording replays bit for bit. The scenarios are the OpenHaptics backend's
//! (`tests/openhaptics_device.rs`), checked by the same assertions
//! ([`softhaptic_tests::device_checks`]): a press that is the simulator's press, a hand stronger
//! than the device pushing a 1 mm sphere in, a communication error and an unplugged cable (zero
//! force on their ticks, the device's state to the viewers, a reconnection off the loop, the
//! ramp back), the stop (zero force, brakes on, closed), the force limit; and what only this
//! SDK has: its watchdog stopping the motors of a stalled loop, its force button, its errors
//! kept per thread.
//!
//! The stand-in is one library per process with one device, so the tests here take turns
//! ([`standin`]).

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use glam::{DQuat, DVec3};
use softhaptic_device::device::{DeviceError, DeviceLimits, HapticDevice};
use softhaptic_device::forcedimension::{
    self as fd, ForceDimensionConfig, ForceDimensionDevice, WATCHDOG_S, WATCHDOG_UNITS,
};
use softhaptic_device::sim::{HandScript, SimParams, SimulatedPhantom};
use softhaptic_proto::wire::DeviceStatus;
use softhaptic_server::devices;
use softhaptic_server::scene::{DeviceChoice, DeviceKind, Scene};
use softhaptic_tests::device_checks::*;
use softhaptic_tests::dhd_standin::{DhdStandIn, dhd, dhd_standin_path};
use softhaptic_tests::{RecordedServer, Viewer, wait_until};

/// One test at a time owns the stand-in.
static STANDIN: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// Takes the stand-in: the backend is pointed at it and it is reset to a fresh omega.3.
async fn standin() -> (tokio::sync::MutexGuard<'static, ()>, DhdStandIn) {
    let guard = STANDIN.lock().await;
    // SAFETY: every test of this binary sets the variable while holding `STANDIN`, before it
    // starts any thread that reads it.
    unsafe { std::env::set_var(fd::LIBRARY_ENV, dhd_standin_path()) };
    let s = DhdStandIn::load().unwrap();
    s.reset();
    (guard, s)
}

/// The built-in scene driven through a Force Dimension device (`model` its preset), the
/// device's origin on the liver's top, where the stand-in's hand presses along the SDK's −z, its
/// z turned to the world's up (a quarter turn about x, as `scenes/forcedimension.toml`).
fn liver_scene(model: DeviceLimits) -> Scene {
    let mut scene = Scene::builtin_default().unwrap();
    scene.choose_device(&DeviceChoice {
        kind: DeviceKind::Forcedimension,
        name: None,
    });
    scene.device_limits = model;
    let (point, _) = scene.press_site_in_object;
    scene.world_from_device.position_m = scene.object_in_world.transform_point(point);
    scene.world_from_device.orientation = DQuat::from_rotation_x(-std::f64::consts::FRAC_PI_2);
    scene
}

/// Opens the scene's device as `softhaptic run` does and starts a recorded server on it.
async fn start(mut scene: Scene, name: &str) -> RecordedServer {
    let device = devices::open(&mut scene).unwrap();
    start_on(scene, device, name).await
}

/// Starts a recorded server on `device`, opened for `scene`.
async fn start_on(scene: Scene, device: Box<dyn HapticDevice>, name: &str) -> RecordedServer {
    start_on_device(scene, device, "Force Dimension", name).await
}

/// Waits for `n` more force commands (the loop's ticks, as the device sees them).
async fn wait_commands(s: &DhdStandIn, n: u64) {
    let target = s.state().commands + n;
    wait_until(&format!("{n} force commands"), || {
        s.state().commands >= target
    })
    .await;
}

/// Waits until the motors give a force above `newtons` (the hand presses).
async fn wait_pressing(s: &DhdStandIn, newtons: f64) {
    wait_until(&format!("a force above {newtons} N"), || {
        DVec3::from_array(s.motor_force_n()).length() > newtons
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_press_through_the_stand_in_feels_like_a_press_through_the_simulator() {
    let (_guard, s) = standin().await;
    let mut scene = liver_scene(DeviceLimits::OMEGA3);
    // The device's axes on the world's, so that forces compare unrotated; the test's hand, not
    // the stand-in's, presses.
    scene.world_from_device.orientation = DQuat::IDENTITY;
    // The simulated device's hand, moved by the force the stand-in's motors give, stepped once
    // per position read: the same hand, script and loop as a press through the simulator.
    let script = scene.hand_script();
    let params = SimParams {
        limits: DeviceLimits::OMEGA3,
        ..SimParams::default()
    };
    let hand = SimulatedPhantom::with_params(script, params);
    let origin = scene.world_from_device.position_m;
    let steps: Arc<Mutex<Vec<ServoStep>>> = Arc::new(Mutex::new(Vec::with_capacity(20_000)));
    let log = Arc::clone(&steps);
    s.set_hand(simulated_hand(
        hand,
        origin,
        1.0,
        move |force_n, position_m| {
            log.lock()
                .unwrap_or_else(PoisonError::into_inner)
                .push(ServoStep {
                    force_sent_before_n: force_n,
                    position_mm: (DVec3::from_array(position_m) * 1e3).to_array(),
                });
        },
    ));
    // The comparison is of forces, not of this machine's scheduling: a loop thread held off
    // its CPU for 10 ms on a loaded test machine must not let the watchdog zero a force here
    // (the watchdog has its own test), so it is set to its longest, 32 ms.
    let config = ForceDimensionConfig {
        watchdog_units: u8::MAX,
        ..devices::forcedimension_config(&scene)
    };
    let opened = ForceDimensionDevice::open(&config).unwrap();
    let mut running = scene.clone();
    running.device_limits = opened.limits();
    running.device_label = Some(format!(
        "{} (Force Dimension)",
        opened.description().label()
    ));
    let live = start_on(running, Box::new(opened), "forcedimension-press").await;
    wait_commands(&s, 3_600).await;
    let (stats, recording) = finish(live).await;
    s.builtin_hand();
    println!(
        "self-clocked through the stand-in: period error p50 {} µs, p99 {} µs, max {} µs",
        stats.period_error_p50_ns as f64 * 1e-3,
        stats.period_error_p99_ns as f64 * 1e-3,
        stats.period_error_max_ns as f64 * 1e-3,
    );
    // Each tick's force reaches the motors before the next reading: what the hand is given at
    // each read is the force the loop computed from the read before. A tick late beyond the
    // watchdog would give zero instead; none is here, or the check names it.
    let steps = std::mem::take(&mut *steps.lock().unwrap());
    let same = force_sent_for_reading(&recording.device, origin, &steps, 0);
    let late = force_sent_for_reading(&recording.device, origin, &steps, 1);
    println!("force given vs force recorded: {same:e} N off at once, {late:e} N a read later");
    assert!(same <= 1e-9, "a force given differs by {same} N");
    assert!(
        late > 1e-3,
        "{late} N: the check cannot tell a tick's delay"
    );

    // The same press through the simulator, with the limits the session ran with.
    let mut reference_scene = scene.clone();
    reference_scene.device_limits = recording_limits(&recording, &scene);
    let mut world = reference_scene.haptic_world();
    let mut simulated = SimulatedPhantom::with_params(script, params);
    let device = &recording.device;
    assert!(device.len() >= 3_000, "{} ticks recorded", device.len());
    let peak = device.iter().map(force).fold(0.0, f64::max);
    let worst = device
        .iter()
        .map(|d| {
            let r = world.tick(&mut simulated).state.force_n;
            (DVec3::from_array(d.force_n) - r).length()
        })
        .fold(0.0, f64::max);
    println!("largest difference from the simulator: {worst:e} N of a {peak} N peak");
    assert!(peak > 1.0, "a real press: peak {peak} N");
    assert!(worst <= 0.01 * peak, "{worst} N off the simulator's press");
    assert!(device.iter().all(|d| d.device_error.is_none()));
    assert_replays(&recording);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hand_stronger_than_the_device_pushes_a_1_mm_sphere_in_and_the_contact_holds() {
    for collision in ["continuous", "paper_vertices"] {
        let (_guard, s) = standin().await;
        s.set_type(dhd::DHD_DEVICE_FALCON);
        let scene = small_sphere_scene("kind = \"forcedimension\"\nmodel = \"falcon\"", collision);
        let (point, normal) = scene.press_site_in_object;
        let n = scene.object_in_world.orientation * normal;
        let mut script = HandScript::press(scene.object_in_world.transform_point(point), n, 0.03);
        script.repeat = false;
        let params = SimParams {
            limits: DeviceLimits::FALCON,
            hand_stiffness_n_per_m: STRONG_GRIP_N_PER_M,
            ..SimParams::default()
        };
        let hand = SimulatedPhantom::with_params(script, params);
        let origin = scene.world_from_device.position_m;
        let reads = Arc::new(Mutex::new(0u64));
        let counted = Arc::clone(&reads);
        s.set_hand(simulated_hand(hand, origin, 1.0, move |_, _| {
            *counted.lock().unwrap_or_else(PoisonError::into_inner) += 1;
        }));
        let live = start(
            scene.clone(),
            &format!("forcedimension-pop-through-{collision}"),
        )
        .await;
        let mut viewer = Viewer::connect(live.server.local_addr()).await;
        wait_for_pushed_through_frame(&mut viewer, collision).await;
        let pass = (script.duration_s() * 1e3).ceil() as u64 + 300;
        wait_until("the pass of the hand", || {
            *reads.lock().unwrap_or_else(PoisonError::into_inner) >= pass
        })
        .await;
        let (_, recording) = finish(live).await;
        s.builtin_hand();
        assert_holds_on_the_side_it_entered(&recording, &scene, collision);
        // The backend held the force below the Falcon's 8 N itself: the SDK never saturated.
        let state = s.state();
        assert_eq!(state.saturations, 0, "{collision}: {state:?}");
        assert!(s.max_motor_force_n() <= 8.0 * (1.0 - fd::FORCE_MARGIN) + 1e-9);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_communication_error_mid_press_is_zero_force_on_its_ticks_then_a_ramp() {
    let (_guard, s) = standin().await;
    let live = start(
        liver_scene(DeviceLimits::OMEGA3),
        "forcedimension-com-error",
    )
    .await;
    wait_pressing(&s, 1.0).await;
    // Three ticks' worth of calls (the position, the velocity, the buttons and the force each)
    // fail, from wherever in a tick the next call falls.
    s.inject_error(dhd::DHD_ERROR_COM, 12);
    wait_commands(&s, 1_000).await;
    let (_, recording) = finish(live).await;
    let device = &recording.device;
    let faulted_tick = |d: &&softhaptic_proto::record::DeviceRecord| {
        d.device_error.is_some() || d.command_error.is_some()
    };
    let first = device
        .iter()
        .position(|d| faulted_tick(&d))
        .expect("a faulted tick");
    let faulted: Vec<_> = device[first..].iter().take_while(faulted_tick).collect();
    // A tick whose read fails makes two calls (the position, then the zero force).
    assert!(
        !faulted.is_empty() && faulted.len() <= 6,
        "{}",
        faulted.len()
    );
    assert!(
        faulted
            .iter()
            .all(|d| d.force_n == [0.0; 3] && d.device_fault)
    );
    // Ridden out with zero force: far fewer failures than a reconnection takes.
    assert_eq!(s.state().opens, 1);
    let before = force(&device[first - 1]);
    assert_ramps_in_after(device, first, before);
    assert_replays(&recording);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unplugged_device_is_reconnected_and_the_force_ramps_in_again() {
    let (_guard, s) = standin().await;
    let live = start(liver_scene(DeviceLimits::OMEGA3), "forcedimension-unplug").await;
    let mut viewer = Viewer::connect(live.server.local_addr()).await;
    wait_pressing(&s, 1.0).await;
    s.unplug();
    wait_for_device_state(&mut viewer, DeviceStatus::Disconnected).await;
    // The loop hands the device over after a run of failed ticks; the reconnection closes the
    // lost connection and tries again with backoff while the cable is out.
    wait_until("the lost connection closed", || !s.state().open).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    s.replug();
    wait_until("the device reopened", || s.state().open).await;
    wait_for_device_state(&mut viewer, DeviceStatus::Ok).await;
    let state = s.state();
    // Closed before it was opened again (the SDK refuses a second open), and set up again.
    assert_eq!(state.refused_opens, 0, "{state:?}");
    assert_eq!(state.opens, 2, "{state:?}");
    assert!(
        state.force_on && !state.brakes_on && state.watchdog_units == u32::from(WATCHDOG_UNITS)
    );
    // The velocity's window configured again on the new connection.
    assert_eq!(
        (state.velocity_mode, state.velocity_window_ms),
        (dhd::DHD_VELOCITY_WINDOWING, fd::VELOCITY_WINDOW_MS)
    );
    // The hand presses again, and on.
    wait_pressing(&s, 1.0).await;
    wait_commands(&s, 300).await;
    let (_, recording) = finish(live).await;
    let device = &recording.device;
    let faulted = first_fault_run(device);
    let (first, outage) = (faulted.start, faulted.len());
    assert!(
        outage >= softhaptic_device::backend::reconnect::RECONNECT_AFTER_FAILED_TICKS as usize,
        "{outage} faulted ticks"
    );
    assert!(
        device[first..first + outage]
            .iter()
            .all(|d| d.force_n == [0.0; 3] && d.device_fault)
    );
    let before = force(&device[first - 1]);
    let back = first + outage;
    assert!(device[back..].iter().any(|d| d.in_contact));
    assert_ramps_in_after(device, first, before.max(force(&device[back + 100])));
    assert_replays(&recording);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stopping_the_server_sends_zero_force_puts_the_brakes_on_and_closes() {
    let (_guard, s) = standin().await;
    let live = start(liver_scene(DeviceLimits::OMEGA3), "forcedimension-stop").await;
    wait_pressing(&s, 1.0).await;
    let (_, recording) = finish(live).await;
    let state = s.state();
    assert!(!state.open && state.brakes_on, "{state:?}");
    assert_eq!(state.closes, 1);
    assert_eq!(s.motor_force_n(), [0.0; 3]);
    assert!(recording.device.iter().any(|d| force(d) > 1.0));
}

/// The loop stalls (here: the test stops calling the device it opened): the watchdog stops the
/// motors within its duration, and the next command renders again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stalled_loop_lets_the_watchdog_stop_the_motors() {
    let (_guard, s) = standin().await;
    let mut device =
        ForceDimensionDevice::open(&ForceDimensionConfig::new(DeviceLimits::OMEGA3)).unwrap();
    let state = s.state();
    // Set up as the SDK expects: the watchdog (in expert mode, left again at once), gravity
    // compensation, brakes off, forces on.
    assert!(state.open && state.force_on && !state.brakes_on && state.gravity_on);
    assert!(!state.expert_mode, "expert mode left on: {state:?}");
    assert_eq!(state.watchdog_units, u32::from(WATCHDOG_UNITS));
    device.read().unwrap();
    device.command_force(DVec3::new(0.0, 2.0, 0.0)).unwrap();
    let given = s.motor_force_n();
    assert!((given[1] - 2.0).abs() < 1e-12, "{given:?}");
    // No more commands: after the watchdog's duration (and a margin for this machine), nothing.
    std::thread::sleep(Duration::from_secs_f64(WATCHDOG_S * 3.0));
    assert_eq!(s.motor_force_n(), [0.0; 3]);
    assert_eq!(s.state().watchdog_trips, 1);
    // The next command renders again.
    device.read().unwrap();
    device.command_force(DVec3::new(0.0, 1.0, 0.0)).unwrap();
    assert!((s.motor_force_n()[1] - 1.0).abs() < 1e-12);
    device.close();
    let state = s.state();
    assert!(!state.open && state.brakes_on, "{state:?}");
}

/// The operator presses the device's force button: the tick that finds the force off is a
/// fault, the force is switched on again and ramps in.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_force_button_is_a_fault_then_the_force_ramps_in() {
    let (_guard, s) = standin().await;
    let live = start(
        liver_scene(DeviceLimits::OMEGA3),
        "forcedimension-force-button",
    )
    .await;
    wait_pressing(&s, 1.0).await;
    s.press_force_button();
    wait_until("the force switched on again", || s.state().force_on).await;
    // A whole press of the hand's (3 s) after it.
    wait_commands(&s, 3_000).await;
    let (_, recording) = finish(live).await;
    let device = &recording.device;
    // The tick that found the force off.
    let first = first_fault_run(device).start;
    assert_eq!(
        device[first].device_error,
        Some(softhaptic_proto::record::DeviceErrorRecord::ForceDisabled)
    );
    let before = force(&device[first - 1]);
    assert_ramps_in_after(device, first, before);
    assert_replays(&recording);
}

/// The SDK's errors are per thread: a failure on one thread is not another's last error, and
/// the backend reads each on the thread that failed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn errors_are_kept_per_thread() {
    let (_guard, s) = standin().await;
    // No device open: a force command fails with "no device" on the thread that made it.
    assert_eq!(s.set_force_here([0.0; 3], -1), -1);
    assert_eq!(s.last_error_here(), dhd::DHD_ERROR_NO_DEVICE_FOUND);
    let other = std::thread::spawn(|| {
        let s = DhdStandIn::load().unwrap();
        let fresh = s.last_error_here();
        // A bad parameter on this thread.
        let returned = s.set_force_here([f64::NAN, 0.0, 0.0], -1);
        (fresh, returned, s.last_error_here())
    })
    .join()
    .unwrap();
    assert_eq!(other, (dhd::DHD_NO_ERROR, -1, dhd::DHD_ERROR_INVALID_PARAM));
    // This thread's error is still its own.
    assert_eq!(s.last_error_here(), dhd::DHD_ERROR_NO_DEVICE_FOUND);
    // The backend on a device whose calls fail from another thread reports the right error.
    let mut device =
        ForceDimensionDevice::open(&ForceDimensionConfig::new(DeviceLimits::OMEGA3)).unwrap();
    s.inject_error(dhd::DHD_ERROR_INVALID_PARAM, 1);
    let error = std::thread::spawn(move || {
        let e = device.read().err();
        device.close();
        e
    })
    .join()
    .unwrap();
    assert_eq!(
        error,
        Some(DeviceError::Driver(dhd::DHD_ERROR_INVALID_PARAM))
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_device_listing_shows_the_stand_in_with_its_type_serial_and_limits() {
    let (_guard, s) = standin().await;
    let listing = devices::listing(&[]);
    assert!(
        listing.contains("Force Dimension (omega, delta, sigma, Falcon): library"),
        "{listing}"
    );
    assert!(
        listing.contains("omega.3 (type 33, serial 11042)"),
        "{listing}"
    );
    assert!(listing.contains("12.0 N peak"), "{listing}");
    // Closed again after the listing.
    assert!(!s.state().open);
    // A Falcon: no serial the SDK can read.
    s.set_type(dhd::DHD_DEVICE_FALCON);
    let listing = devices::listing(&[]);
    assert!(listing.contains("Falcon (type 60, serial ?)"), "{listing}");
    assert!(listing.contains("8.0 N peak"), "{listing}");
    // An omega.7 drives the omega.3's base: its limits and preset.
    s.set_type(dhd::DHD_DEVICE_OMEGA331);
    let listing = devices::listing(&[]);
    assert!(listing.contains("omega.7 (type 35, serial"), "{listing}");
    assert!(
        listing.contains("12.0 N peak") && listing.contains("(scene preset omega3)"),
        "{listing}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_tighter_of_the_type_and_the_preset_applies() {
    let (_guard, s) = standin().await;
    s.set_type(dhd::DHD_DEVICE_FALCON);
    // A delta.3 preset on a Falcon: the Falcon's 8 N and 3000 N/m win.
    let mut scene = liver_scene(DeviceLimits::DELTA3);
    let device = devices::open(&mut scene).unwrap();
    assert_eq!(device.limits().peak_force_n, 8.0);
    assert_eq!(device.limits().max_stiffness_n_per_m, 3000.0);
    assert_eq!(scene.device_limits, device.limits());
    drop(device);
    // A library that is not there: the error names where it looked.
    // SAFETY: as in `standin`, under the guard.
    unsafe { std::env::set_var(fd::LIBRARY_ENV, "/nonexistent/libdhd.so") };
    let mut scene = liver_scene(DeviceLimits::OMEGA3);
    let error = devices::open(&mut scene).err().unwrap().to_string();
    assert!(
        error.contains("/nonexistent/libdhd.so") && error.contains(fd::LIBRARY_ENV),
        "{error}"
    );
}

/// The stand-in keeps the SDK's rules the backend must follow: forces off and brakes on at
/// open, one application at a time, the watchdog an expert function, a force beyond the peak
/// scaled and answered `DHD_MOTOR_SATURATED`, an unplugged connection failing until reopened.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_stand_in_keeps_the_sdks_rules() {
    let (_guard, s) = standin().await;
    let id = s.open_here();
    assert_eq!(id, 0);
    let state = s.state();
    assert!(
        state.open && !state.force_on && state.brakes_on,
        "{state:?}"
    );
    // A force before the force is on reaches no motor.
    assert_eq!(s.set_force_here([0.0, 1.0, 0.0], -1), dhd::DHD_NO_ERROR);
    assert_eq!(s.motor_force_n(), [0.0; 3]);
    // A second open is refused.
    assert_eq!(s.open_here(), -1);
    assert_eq!(s.last_error_here(), dhd::DHD_ERROR_DEVICE_IN_USE);
    // The watchdog only in expert mode.
    assert_eq!(s.set_watchdog_here(8, -1), -1);
    assert_eq!(s.last_error_here(), dhd::DHD_ERROR_EXPERT_MODE_DISABLED);
    assert_eq!(s.expert_mode_here(true), 0);
    assert_eq!(s.set_watchdog_here(8, -1), 0);
    assert_eq!(s.expert_mode_here(false), 0);
    // The velocity estimator: the SDK's 20 ms window at open, another on request, a mode the
    // SDK does not have refused.
    let state = s.state();
    assert_eq!(
        (state.velocity_mode, state.velocity_window_ms),
        (dhd::DHD_VELOCITY_WINDOWING, dhd::DHD_VELOCITY_WINDOW)
    );
    assert_eq!(
        s.config_velocity_here(5, dhd::DHD_VELOCITY_WINDOWING, -1),
        0
    );
    assert_eq!(s.state().velocity_window_ms, 5);
    assert_eq!(s.config_velocity_here(5, 1, -1), -1);
    assert_eq!(s.last_error_here(), dhd::DHD_ERROR_INVALID_PARAM);
    assert_eq!(
        s.config_velocity_here(0, dhd::DHD_VELOCITY_WINDOWING, -1),
        -1
    );
    assert_eq!(s.state().velocity_window_ms, 5);
    // Forces on (the brakes released): a force within the peak is given as is, one beyond it
    // scaled to the omega.3's 12 N and answered DHD_MOTOR_SATURATED, which is no error.
    assert_eq!(s.enable_force_here(true, -1), 0);
    assert!(!s.state().brakes_on);
    assert_eq!(s.set_force_here([0.0, 1.5, 0.0], -1), dhd::DHD_NO_ERROR);
    assert_eq!(s.motor_force_n(), [0.0, 1.5, 0.0]);
    assert_eq!(
        s.set_force_here([0.0, 0.0, 24.0], -1),
        dhd::DHD_MOTOR_SATURATED
    );
    assert_eq!(s.motor_force_n(), [0.0, 0.0, 12.0]);
    assert_eq!(s.last_error_here(), dhd::DHD_NO_ERROR);
    // Unplugged: every call fails; replugged, the old connection still fails until reopened.
    s.unplug();
    assert_eq!(s.set_force_here([0.0; 3], -1), -1);
    assert_eq!(s.last_error_here(), dhd::DHD_ERROR_COM);
    assert_eq!(s.motor_force_n(), [0.0; 3]);
    s.replug();
    assert_eq!(s.set_force_here([0.0; 3], -1), -1);
    assert_eq!(s.last_error_here(), dhd::DHD_ERROR_COM);
    assert_eq!(
        s.open_here(),
        -1,
        "still open: the lost connection must be closed first"
    );
    assert_eq!(s.close_here(0), 0);
    assert_eq!(s.open_here(), 0);
    assert_eq!(s.set_force_here([0.0; 3], -1), dhd::DHD_NO_ERROR);
    assert_eq!(s.close_here(0), 0);
}
