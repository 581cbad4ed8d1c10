//! Checks the real-device tests share (`tests/openhaptics_device.rs`,
//! `tests/forcedimension_device.rs`): the same scenarios hold for every vendor's backend, so
//! their assertions are written once. Each reads a session's recording (or a viewer) and says
//! what it found when it fails.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::time::{Duration, Instant};

use glam::DVec3;
use softhaptic_device::collision::{Collider, CollisionMode};
use softhaptic_device::device::DeviceLimits;
use softhaptic_proto::ContactFlags;
use softhaptic_proto::record::{DeviceErrorRecord, DeviceRecord};
use softhaptic_proto::wire::{DeviceStatus, ServerMessage};
use softhaptic_server::scene::Scene;
use softhaptic_server::session::check::{CheckOverrides, check};
use softhaptic_server::session::reader::Recording;

use crate::Viewer;
use softhaptic_device::device::HapticDevice;
use softhaptic_device::sim::SimulatedPhantom;

/// Starts a recorded server on a real device's backend (`device`, opened for `scene`), and
/// checks that viewers are told its vendor (`vendor`, in the device's name).
pub async fn start_on_device(
    scene: Scene,
    device: Box<dyn HapticDevice>,
    vendor: &str,
    name: &str,
) -> crate::RecordedServer {
    let mut options = crate::test_options();
    options.device = Some(device);
    let live = crate::start_recorded(scene, &crate::scratch_dir(name), options).await;
    let device_name = &live.server.scene_message().device.name;
    assert!(device_name.contains(vendor), "{device_name}");
    live
}

/// Stops the server and returns its loop's final statistics and the recording.
pub async fn finish(
    live: crate::RecordedServer,
) -> (softhaptic_device::stats::LoopStats, Recording) {
    let (stats, _, path, _) = live.finish().await;
    (stats, Recording::open(&path).unwrap())
}

/// A stand-in's hand that is the simulated device's: stepped once per call, fed the force the
/// stand-in's motors gave (from the second call on), its tip reported relative to `origin_m`
/// in the stand-in's units (`units_per_m`: 1e3 for the HD stand-in's millimetres, 1 for the
/// SDK stand-in's metres). `each(force_n, position)` sees every step. Never a panic inside
/// (it cannot unwind into the stand-in) but for a simulated device that fails, which it does not.
pub fn simulated_hand(
    mut hand: SimulatedPhantom,
    origin_m: DVec3,
    units_per_m: f64,
    mut each: impl FnMut([f64; 3], [f64; 3]) + Send + 'static,
) -> impl FnMut([f64; 3], &mut [f64; 3], &mut [f64; 3]) + Send + 'static {
    let mut first = true;
    move |force_n, position, velocity| {
        if !std::mem::replace(&mut first, false) {
            hand.command_force(DVec3::from_array(force_n)).unwrap();
        }
        let sample = hand.read().unwrap();
        *position = ((sample.tip_in_world.position_m - origin_m) * units_per_m).to_array();
        *velocity = (sample.tip_velocity_m_s * units_per_m).to_array();
        each(force_n, *position);
    }
}

/// Reads contact frames until one is flagged `pushed_through` (and in contact): a viewer is
/// told the contact is held, by the flag's name.
pub async fn wait_for_pushed_through_frame(viewer: &mut Viewer, label: &str) {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        assert!(
            Instant::now() < deadline,
            "{label}: no contact frame flagged pushed_through"
        );
        if let Some(Ok(ServerMessage::Contact(c))) = viewer.next(Duration::from_secs(5)).await
            && c.flags.contains(ContactFlags::PUSHED_THROUGH)
        {
            assert!(c.in_contact, "{label}: {c:?}");
            return;
        }
    }
}

pub fn force(d: &DeviceRecord) -> f64 {
    DVec3::from_array(d.force_n).length()
}

pub fn flags(d: &DeviceRecord) -> ContactFlags {
    ContactFlags::from_bits_retain(d.flags)
}

/// The ticks of the first run with a device error, in the recording's `device` channel (a
/// recording without one fails the test).
pub fn first_fault_run(device: &[DeviceRecord]) -> std::ops::Range<usize> {
    let first = device
        .iter()
        .position(|d| d.device_error.is_some())
        .expect("a tick with a device error");
    let run = device[first..]
        .iter()
        .take_while(|d| d.device_error.is_some())
        .count();
    first..first + run
}

/// The recording replays to its recorded forces bit for bit.
pub fn assert_replays(r: &Recording) {
    let report = check(r, CheckOverrides::default()).unwrap();
    assert!(report.passed(), "{report}");
    assert_eq!(report.ticks_compared, r.device.len() as u64);
}

/// After the run of faulted ticks starting at `first_fault`, the force comes back through the
/// ramp: the first good tick is flagged `ramping` and small, and no later tick jumps.
pub fn assert_ramps_in_after(device: &[DeviceRecord], first_fault: usize, before_n: f64) {
    let back = first_fault
        + device[first_fault..]
            .iter()
            .position(|d| !flags(d).contains(ContactFlags::DEVICE_FAULT))
            .expect("the device came back");
    let first = &device[back];
    assert!(
        flags(first).contains(ContactFlags::RAMPING) || force(first) < 1e-9,
        "tick {}: {:?}",
        first.tick,
        flags(first)
    );
    assert!(
        force(first) < 0.1 * before_n,
        "tick {}: {} N right after the fault (before it: {before_n} N)",
        first.tick,
        force(first)
    );
    // The ramp lasts 80 ms: about 1/80 of the force per tick, plus what the hand moves; a
    // force stepped back in would jump by the whole of it.
    for w in device[back..].windows(2) {
        // A tick a loaded machine ran late (its own bound and settling apply, tested apart) or
        // that overran is not the ramp's.
        let late = w[1].time_ns.saturating_sub(w[0].time_ns) > 1_500_000
            || flags(&w[1]).contains(ContactFlags::LATE_TICK_LIMITED)
            || w.iter()
                .any(|d| d.command_error == Some(DeviceErrorRecord::Overrun));
        if late {
            continue;
        }
        let step = force(&w[1]) - force(&w[0]);
        assert!(
            step < 0.15 * before_n,
            "a jump of {step} N at tick {}",
            w[1].tick
        );
    }
    assert!(
        device[back..].iter().any(|d| force(d) > 0.5 * before_n),
        "the force came back"
    );
}

/// One servo tick of a test's hand: the force the motors were sent at the end of the tick
/// before (N, device frame), and the position the hand took for this tick's frame (mm). For a
/// device the loop clocks, a "servo tick" is one read of the position.
pub struct ServoStep {
    pub force_sent_before_n: [f64; 3],
    pub position_mm: [f64; 3],
}

/// The largest difference (N) between the force the loop recorded for each tick and the force
/// the motors were sent `lag` servo ticks after the tick whose frame latched that tick's
/// reading. The servo tick of each recorded tick is found from the positions: the recorded tip
/// positions must be the hand's, servo tick after servo tick, at one offset. The device's axes
/// must be the world's, so forces compare unrotated.
pub fn force_sent_for_reading(
    device: &[DeviceRecord],
    origin_m: DVec3,
    steps: &[ServoStep],
    lag: usize,
) -> f64 {
    let recorded: Vec<DVec3> = device
        .iter()
        .map(|d| {
            let sample = d.sample.as_ref().expect("every tick read the device");
            DVec3::from_array(sample.tip_position_m)
        })
        .collect();
    let hand: Vec<DVec3> = steps
        .iter()
        .map(|s| origin_m + DVec3::from_array(s.position_mm) * 1e-3)
        .collect();
    assert!(hand.len() >= recorded.len(), "fewer servo ticks than ticks");
    // The offset that puts the recorded positions on the hand's (early exit: most offsets are
    // millimetres off within a few ticks).
    let mut best = (f64::INFINITY, 0);
    for offset in 0..=hand.len() - recorded.len() {
        let mut worst = 0.0_f64;
        for (i, p) in recorded.iter().enumerate() {
            worst = worst.max((*p - hand[i + offset]).length());
            if worst >= best.0 {
                break;
            }
        }
        if worst < best.0 {
            best = (worst, offset);
        }
    }
    let (position_error_m, offset) = best;
    assert!(
        position_error_m < 1e-9,
        "the recorded tip positions are not the hand's, servo tick by servo tick ({} m off at \
         best)",
        position_error_m
    );
    // The force sent at the end of servo tick j is what the hand is given at the start of tick
    // j + 1.
    device
        .iter()
        .enumerate()
        .filter_map(|(i, d)| {
            let sent = steps.get(i + offset + lag + 1)?.force_sent_before_n;
            Some((DVec3::from_array(d.force_n) - DVec3::from_array(sent)).length())
        })
        .fold(0.0, f64::max)
}

/// The limits the recording says the session ran with (the tighter of the preset's and the
/// stand-in's).
pub fn recording_limits(recording: &Recording, scene: &Scene) -> DeviceLimits {
    let d = &recording.scene.message.device;
    DeviceLimits {
        peak_force_n: d.peak_force_n,
        continuous_force_n: d.continuous_force_n,
        max_stiffness_n_per_m: d.max_stiffness_n_per_m,
        damping_n_s_per_m: d.damping_n_s_per_m,
        workspace_radius_m: d.workspace_radius_m,
        ..scene.device_limits
    }
}

/// The liver pressed with a 1 mm sphere through a real device's backend (`device`: the scene's
/// `[device]` lines, its kind and model), the combined model in `collision` mode ("continuous"
/// or "paper_vertices"). The press site moves to the haptic mesh's vertex
/// nearest it, along that vertex's normal: the paper's mode starts a contact only with a vertex
/// inside the tool, and between the liver's vertices a tip this small has none. The device's
/// origin is on the press site.
pub fn small_sphere_scene(device: &str, collision: &str) -> Scene {
    let text = format!(
        r#"
[object]
name = "liver"
builtin = "liver"

[object.model]
exact_sphere = true
curvature = true
hyperelastic = true

[material]
youngs_modulus_pa = 50000.0
poisson_ratio = 0.33

[tool]
shape = "sphere"
radius_m = 0.001

[device]
{device}

[calibration]
table = "half_space"

[haptics]
collision = "{collision}"
"#
    );
    let mut scene = Scene::from_toml(&text, std::path::Path::new("<pop-through>"), None).unwrap();
    let (site, _) = scene.press_site_in_object;
    let mesh = &scene.haptic_mesh;
    let nearest = (0..mesh.positions_m().len())
        .min_by(|&a, &b| {
            let distance = |i: usize| (mesh.positions_m()[i] - site).length();
            distance(a).total_cmp(&distance(b))
        })
        .unwrap();
    scene.press_site_in_object = (mesh.positions_m()[nearest], mesh.normals()[nearest]);
    let (point, _) = scene.press_site_in_object;
    scene.world_from_device.position_m = scene.object_in_world.transform_point(point);
    scene
}

/// A grip ten times the default (the simulated hand's 300 N/m): toward a target 30 mm below the
/// surface the hand pushes with up to 90 N, against the device's 7.9 N.
pub const STRONG_GRIP_N_PER_M: f64 = 3000.0;

/// The checks of a hand stronger than the device pushing a 1 mm sphere in
/// ([`small_sphere_scene`]) on one recorded pass: the contact holds on the side it entered.
pub fn assert_holds_on_the_side_it_entered(recording: &Recording, scene: &Scene, collision: &str) {
    let device = &recording.device;
    let (_, normal) = scene.press_site_in_object;
    let n = scene.object_in_world.orientation * normal;
    let limit_n = recording_limits(recording, scene).peak_force_n;
    // The tip's depth below the liver's surface, measured on a collider of the test's own.
    let mut surface = Collider::new(scene.haptic_mesh.clone(), CollisionMode::Continuous);
    // Below the surface means deeper than the encoders' step; in the paper's vertex mode deeper
    // than half the tip's height (2 mm), since between vertices that mode sees no surface at
    // all near a tip this small.
    let tolerance_m = match collision {
        "paper_vertices" => 1e-3 + 5e-5,
        _ => 5e-5,
    };
    let mut pushed_through = 0;
    let mut deepest_m = 0.0_f64;
    // A tick whose command the device refused (a tick that overran on a loaded machine) is a
    // fault: the force ramps in again from zero on the next.
    let mut after_refusal = false;
    for d in device {
        assert!(
            d.device_error.is_none(),
            "{collision}: tick {}: {d:?}",
            d.tick
        );
        let ramp_start = std::mem::replace(&mut after_refusal, d.command_error.is_some())
            && ContactFlags::from_bits_retain(d.flags).contains(ContactFlags::RAMPING);
        let sample = d.sample.as_ref().expect("every tick read the device");
        let tip = DVec3::from_array(sample.tip_position_m);
        let below_m = surface
            .closest_surface_point(scene.object_in_world.inverse_transform_point(tip), 1.0)
            .map_or(f64::NAN, |p| -p.signed_distance_m);
        deepest_m = deepest_m.max(below_m);
        pushed_through += flags(d).contains(ContactFlags::PUSHED_THROUGH) as usize;
        let f = DVec3::from_array(d.force_n);
        assert!(
            f.dot(n) >= -1e-9,
            "{collision}: tick {}: the force {f} N pushes the tool in",
            d.tick
        );
        if below_m > tolerance_m {
            let moving_out = DVec3::from_array(sample.tip_velocity_m_s).dot(n) > 0.0;
            assert!(
                d.in_contact,
                "{collision}: tick {}: contact lost {} mm below the surface",
                d.tick,
                below_m * 1e3
            );
            // Zero only on the way out, where the damping may cancel the spring (paper Fig. 9b),
            // or where the motors' heat limit holds it after a long press at the peak (the hand
            // here outpushes the device for seconds; how long depends on the machine's pace).
            let cooling = flags(d).contains(ContactFlags::CONTINUOUS_FORCE_LIMITED);
            assert!(
                f.length() > 0.0
                    || moving_out
                    || ramp_start
                    || cooling
                    || d.command_error.is_some(),
                "{collision}: tick {}: no force {} mm below the surface, pressing in ({:?}, {:?}, \
                 flags {:?})",
                d.tick,
                below_m * 1e3,
                d.device_error,
                d.command_error,
                ContactFlags::from_bits_retain(d.flags)
            );
        }
    }
    println!(
        "{collision}: tip {:.1} mm below the surface at the deepest, {pushed_through} ticks held \
         pushed through",
        deepest_m * 1e3
    );
    // Far past the tip's own 2 mm height, where the collision alone loses the contact.
    assert!(deepest_m > 0.004, "{collision}: only {deepest_m} m deep");
    assert!(
        pushed_through > 100,
        "{collision}: {pushed_through} ticks flagged"
    );
    // The force saturates at the device's peak rather than vanishing.
    let peak_n = device.iter().map(force).fold(0.0, f64::max);
    assert!(
        peak_n >= 0.99 * limit_n && peak_n <= limit_n * (1.0 + 1e-9),
        "{collision}: peak {peak_n} N against the device's {limit_n} N"
    );
    assert!(
        device
            .iter()
            .any(|d| flags(d).contains(ContactFlags::SATURATED | ContactFlags::PUSHED_THROUGH)),
        "{collision}: never saturated while held"
    );
    // Released only back out on the side it entered: out of contact, no force, no flag.
    let last = device.last().unwrap();
    assert!(
        !last.in_contact && force(last) == 0.0 && flags(last).is_empty(),
        "{collision}: {last:?}"
    );
    // In the recording's wire frames too.
    let recorded_frames_flagged = recording.contacts.iter().any(|frame| {
        matches!(
            ServerMessage::decode(&frame.json),
            Ok(ServerMessage::Contact(c)) if c.flags.contains(ContactFlags::PUSHED_THROUGH)
        )
    });
    assert!(
        recorded_frames_flagged,
        "{collision}: no recorded contact frame flagged"
    );
    assert_replays(recording);
}

/// Reads stats until one says the device is in `state`.
pub async fn wait_for_device_state(viewer: &mut Viewer, state: DeviceStatus) {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        assert!(Instant::now() < deadline, "no stats saying {state:?}");
        if let Some(Ok(ServerMessage::Stats(m))) = viewer.next(Duration::from_secs(5)).await
            && m.device == state
        {
            return;
        }
    }
}
