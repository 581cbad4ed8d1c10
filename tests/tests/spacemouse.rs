//! The SpaceMouse backend end to end through a scripted transport: a recorded report stream with
//! realistic timing (a report every 16 ms while the puck moves, silence at rest, an unplug in the
//! middle of a pull and a replug, a button press) drives the tool into the liver through the
//! whole server. The viewer is told that the force is not felt and sees contact, force and R_d as
//! with any device; the tool path is smooth, stays in the scene's box, holds still while
//! unplugged and starts again from rest, and the recorded session replays bit for bit. A
//! SpaceMouse Compact's combined reports turn a cone (and the session replays) but not a sphere,
//! and a scene's box far larger than the preset's workspace is driven to without a device fault.
//! Each recorded session is checked twice: through the library call, and by the built
//! `softhaptic check`, whose exit status a script would read.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use glam::{DQuat, DVec3};
use softhaptic_device::device::HapticDevice;
use softhaptic_device::spacemouse::SpaceMouseDevice;
use softhaptic_device::spacemouse::rate::RateControl;
use softhaptic_device::spacemouse::report::{MODELS, find_model};
use softhaptic_device::spacemouse::script::{ReportScript, axis_report, six_axis_report};
use softhaptic_proto::ContactFlags;
use softhaptic_proto::record::{DeviceErrorRecord, DeviceRecord};
use softhaptic_proto::wire::{DeviceStatus, ServerMessage};
use softhaptic_server::devices;
use softhaptic_server::scene::{DeviceChoice, DeviceKind, Scene};
use softhaptic_server::session::check::{CheckOverrides, check};
use softhaptic_server::session::reader::Recording;
use softhaptic_tests::{
    Viewer, scratch_dir, softhaptic_binary, start_recorded, test_options, wait_until,
};

/// A report every 16 ms, as a wired SpaceMouse sends them while its puck is off centre.
const REPORT_EVERY_S: f64 = 0.016;
/// Raw value of a full deflection (the SpaceNavigator's full scale).
const FULL: i16 = 350;

/// The built-in liver driven by a SpaceMouse; the box's floor 5 mm under the press site, so a
/// push held as long as it likes ends pressing 5 mm deep.
fn liver_scene() -> Scene {
    let mut scene = Scene::builtin_default().unwrap();
    scene.choose_device(&DeviceChoice {
        kind: DeviceKind::Spacemouse,
        name: None,
    });
    let (point, _) = scene.press_site_in_object;
    let site = scene.object_in_world.transform_point(point);
    scene.spacemouse_rate.workspace_min_m.y = site.y - 0.005;
    scene
}

/// When the cable is pulled: in the middle of a pull up, the puck still deflected.
const UNPLUG_AT_S: f64 = 2.9;

/// The session's puck: at rest, a push down held against the box's floor, a release, a pull up
/// cut short by an unplug, a replug and silence, a pull up, and the reset button.
fn puck_script() -> ReportScript {
    let navigator = find_model(0x046d, 0xc626).unwrap();
    let mut s = ReportScript::new(navigator).report(0.0, &axis_report(1, [0; 3]));
    // Pushing the puck down is +z in the HID.
    s = s.hold_translation(0.2, 2.4, REPORT_EVERY_S, [0, 0, FULL]);
    // Pulling it up from 2.6 s, until the cable is pulled: no release, the tool is still moving
    // (about 13 mm above the floor, 47 mm under the box's top) when the reports stop.
    let mut t = 2.6;
    while t < UNPLUG_AT_S {
        s = s.report(t, &axis_report(1, [0, 0, -FULL]));
        t += REPORT_EVERY_S;
    }
    // Unplugged for two seconds (longer than the 1 s between two `stats`), then plugged back in
    // and silent for 0.3 s: the reader's fresh puck is at rest.
    s = s.unplug(UNPLUG_AT_S).replug(4.9);
    s = s.hold_translation(5.2, 5.8, REPORT_EVERY_S, [0, 0, -FULL]);
    s.report(6.1, &[3, 1]).report(6.4, &[3, 0])
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_scripted_spacemouse_presses_the_liver_through_the_whole_server() {
    let mut scene = liver_scene();
    let rate = scene.spacemouse_rate;
    let (connector, clock) = puck_script().connector_started_later();
    let device = SpaceMouseDevice::open(Box::new(connector), rate, scene.device_limits).unwrap();
    assert!(!device.renders_force());
    scene.device_label = Some(format!("{} (SpaceMouse)", device.model().name));
    scene.device_renders_force = device.renders_force();

    let mut options = test_options();
    options.device = Some(Box::new(device));
    let live = start_recorded(scene, &scratch_dir("spacemouse-press"), options).await;
    let server = &live.server;
    assert!(!server.scene_message().device.force_feedback);

    let mut viewer = Viewer::connect(server.local_addr()).await;
    match viewer.expect_message(Duration::from_secs(10)).await {
        ServerMessage::Hello(h) => assert!(!h.force_feedback, "{h:?}"),
        other => panic!("expected hello, got {other:?}"),
    }
    match viewer.expect_message(Duration::from_secs(10)).await {
        ServerMessage::Scene(s) => {
            assert!(!s.device.force_feedback);
            assert!(
                s.device.name.contains("SpaceNavigator"),
                "{}",
                s.device.name
            );
        }
        other => panic!("expected scene, got {other:?}"),
    }
    // The stream starts with the loop running.
    clock.start();
    let started = Instant::now();

    // Contact, force and R_d on the wire, then the unplug and the replug in `stats`.
    let (mut pressed, mut unplugged, mut back) = (None, false, false);
    let deadline = Instant::now() + Duration::from_secs(60);
    while !(pressed.is_some() && unplugged && back) {
        assert!(
            Instant::now() < deadline,
            "pressed {pressed:?}, unplugged {unplugged}, back {back}"
        );
        match viewer.next(Duration::from_secs(5)).await {
            // A steady press: not the ramp back in after the unplug (its force is still small).
            Some(Ok(ServerMessage::Contact(c)))
                if c.in_contact
                    && c.depth_m > 0.003
                    && !c
                        .flags
                        .intersects(ContactFlags::RAMPING | ContactFlags::DEVICE_FAULT) =>
            {
                assert!(c.force_n.length() > 0.1, "{c:?}");
                assert!(c.deformed_radius_m > c.depth_m, "{c:?}");
                pressed.get_or_insert(c.depth_m);
            }
            Some(Ok(ServerMessage::Stats(s))) => {
                if s.device == DeviceStatus::Disconnected {
                    unplugged = true;
                } else if unplugged && s.device == DeviceStatus::Ok {
                    back = true;
                }
            }
            _ => {}
        }
    }
    // Until the reset button's press has been read.
    wait_until("the script's end", || {
        started.elapsed() > Duration::from_secs(7)
    })
    .await;
    let (_, _, path, _) = live.finish().await;
    let recorded = Recording::open(&path).unwrap();
    assert!(!recorded.scene.message.device.force_feedback);

    let report = check(&recorded, CheckOverrides::default()).unwrap();
    assert!(report.passed(), "{report}");
    assert_eq!(report.ticks_compared, recorded.device.len() as u64);
    assert_softhaptic_check_passes(&path, recorded.device.len());

    assert_path(&recorded.device, &RateControl::new(rate));
}

/// Runs the built `softhaptic check` on `recording` and asserts it passes: exit status 0 and
/// the report on stdout.
fn assert_softhaptic_check_passes(recording: &Path, ticks: usize) {
    let out = Command::new(softhaptic_binary())
        .arg("check")
        .arg(recording)
        .env_remove("RUST_BACKTRACE")
        .output()
        .unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert_eq!(
        out.status.code(),
        Some(0),
        "softhaptic check {}:\n{stdout}\n{stderr}",
        recording.display()
    );
    assert!(
        stdout.contains(&format!(
            "{ticks} ticks replayed, every force identical bit for bit"
        )),
        "{stdout}"
    );
}

fn position(d: &DeviceRecord) -> Option<DVec3> {
    d.sample.map(|s| DVec3::from_array(s.tip_position_m))
}

/// The recorded path: in the box, no velocity step beyond what the smoothing allows, still while
/// unplugged, and home after the reset button.
fn assert_path(device: &[DeviceRecord], rate: &RateControl) {
    let c = rate.config();
    let at_face = |p: DVec3| p.cmpeq(c.workspace_min_m).any() || p.cmpeq(c.workspace_max_m).any();
    let mut steps_checked = 0;
    for pair in device.windows(2) {
        let (Some(a), Some(b)) = (pair[0].sample, pair[1].sample) else {
            continue;
        };
        let p = DVec3::from_array(b.tip_position_m);
        assert!(
            p.cmpge(c.workspace_min_m - 1e-12).all() && p.cmple(c.workspace_max_m + 1e-12).all(),
            "tick {} leaves the box: {p}",
            pair[1].tick
        );
        let home = p == c.home_in_world.position_m;
        if at_face(p) || at_face(DVec3::from_array(a.tip_position_m)) || home {
            continue;
        }
        let dt_s = (b.time_ns - a.time_ns) as f64 * 1e-9;
        let step = (DVec3::from_array(b.tip_velocity_m_s) - DVec3::from_array(a.tip_velocity_m_s))
            .length();
        assert!(
            step <= rate.max_velocity_step_m_s(dt_s.min(0.02)) + 1e-12,
            "tick {}: velocity step {step} m/s in {dt_s} s",
            pair[1].tick
        );
        steps_checked += 1;
    }
    assert!(steps_checked > 1000, "{steps_checked}");

    // The unplug: a run of faulted ticks with zero force, and the tool where it was.
    let first = device
        .iter()
        .position(|d| d.device_error == Some(DeviceErrorRecord::Disconnected))
        .expect("the unplug is recorded");
    let last = first
        + device[first..]
            .iter()
            .position(|d| d.device_error != Some(DeviceErrorRecord::Disconnected))
            .expect("the replug is recorded");
    assert!(last - first > 100, "{first}..{last}");
    for d in &device[first..last] {
        assert!(d.device_fault && d.force_n == [0.0; 3], "{d:?}");
    }
    // The reports stopped mid-pull: the tool was moving, off every face of the box (a tool
    // at rest, or held by a face, would stand still across the outage whatever the backend did).
    let moving = device[first - 1].sample.unwrap();
    let before = DVec3::from_array(moving.tip_position_m);
    let speed_m_s = DVec3::from_array(moving.tip_velocity_m_s).length();
    assert!(
        speed_m_s > 0.5 * c.gain_m_s,
        "{speed_m_s} m/s at the unplug"
    );
    let clearance_m = (before - c.workspace_min_m)
        .min(c.workspace_max_m - before)
        .min_element();
    assert!(
        clearance_m > 0.005,
        "{clearance_m} m from a face at the unplug"
    );
    // It holds still over the outage, and starts again from rest.
    let replugged = device[last].sample.unwrap();
    let after = DVec3::from_array(replugged.tip_position_m);
    assert!(
        (after - before).length() <= 1e-6,
        "the tool moved {} m across the unplug",
        (after - before).length()
    );
    assert_eq!(
        replugged.tip_velocity_m_s, [0.0; 3],
        "the first sample after the replug"
    );

    // The pull up after the replug moved it, and the button brought it home.
    assert!(
        device[last..]
            .iter()
            .filter_map(position)
            .any(|p| p.y > before.y + 0.01)
    );
    assert_eq!(
        position(device.last().unwrap()).unwrap(),
        c.home_in_world.position_m
    );
}

#[test]
fn the_scene_opens_a_spacemouse_from_its_report_script_and_names_a_missing_one() {
    let dir = scratch_dir("spacemouse-scene");
    let script = dir.join("puck.hid");
    std::fs::write(
        &script,
        "model 256f:c635\n0 01 00 00 00 00 00 00 00 00 00 00 00 00\n",
    )
    .unwrap();
    let mut scene = liver_scene();
    scene.spacemouse_script = Some(script.clone());
    let device = devices::open(&mut scene).unwrap();
    assert!(!device.renders_force());
    assert!(!scene.device_renders_force);
    let label = scene.device_label.clone().unwrap();
    assert!(
        label.contains("SpaceMouse Compact") && label.contains("renders no force"),
        "{label}"
    );
    drop(device);

    let mut scene = liver_scene();
    scene.spacemouse_script = Some(dir.join("missing.hid"));
    let e = devices::open(&mut scene).err().unwrap().to_string();
    assert!(e.contains("missing.hid"), "{e}");

    std::fs::write(&script, "0 01 00\n5 zz\n").unwrap();
    let mut scene = liver_scene();
    scene.spacemouse_script = Some(script);
    let e = devices::open(&mut scene).err().unwrap().to_string();
    assert!(e.contains("puck.hid") && e.contains("line 2"), "{e}");
    assert!(MODELS.len() > 10);
}

/// The default scene's text with `device` as its `[device]` section.
fn scene_with_device(device: &str) -> String {
    let text =
        std::fs::read_to_string(softhaptic_tests::repo_scenes().join("default.toml")).unwrap();
    let start = text
        .find("[device]")
        .expect("the default scene has a [device] section");
    let end = text[start + 1..]
        .find("\n[")
        .map_or(text.len(), |i| start + 2 + i);
    // The table by its absolute path: the scene is written outside `scenes/`.
    let table = softhaptic_tests::repo_scenes().join("calibration/sphere10_50kpa.json");
    format!("{}{device}\n{}", &text[..start], &text[end..]).replace(
        "\"calibration/sphere10_50kpa.json\"",
        &format!("{:?}", table.display().to_string()),
    )
}

#[test]
fn a_scene_file_sets_the_rate_control_and_refuses_bad_values_by_field() {
    let dir = scratch_dir("spacemouse-rate");
    let text = scene_with_device(
        "[device]\nkind = \"spacemouse\"\nserial = \"A1\"\nreport_script = \"puck.hid\"\n\n\
         [device.rate]\ndead_band = 0.2\ngain_m_s = 0.02\nhome_height_m = 0.05\nreset_button = 2\n",
    );
    let scene = softhaptic_tests::load_scene_text(&dir, &text).unwrap();
    assert_eq!(scene.device_kind, DeviceKind::Spacemouse);
    assert_eq!(scene.device_name.as_deref(), Some("A1"));
    assert_eq!(scene.spacemouse_script, Some(dir.join("puck.hid")));
    let r = scene.spacemouse_rate;
    assert_eq!((r.dead_band, r.gain_m_s, r.reset_buttons), (0.2, 0.02, 4));
    let (point, normal) = scene.press_site_in_object;
    let home = scene.object_in_world.transform_point(point)
        + scene.object_in_world.orientation * normal * 0.05;
    assert!(r.home_in_world.position_m.abs_diff_eq(home, 1e-12));

    for (device, expected) in [
        (
            "[device]\nkind = \"spacemouse\"\n[device.rate]\ndead_band = 1.5\n",
            &["device.rate", "dead_band", "1.5"][..],
        ),
        (
            "[device]\nkind = \"spacemouse\"\n[device.rate]\nworkspace_half_extent_m = [0.1, 0.0, 0.1]\n",
            &["device.rate.workspace_half_extent_m"],
        ),
        (
            "[device]\nkind = \"spacemouse\"\n[device.rate]\nhome_height_m = 2.0\n",
            &["device.rate", "home"],
        ),
        (
            "[device]\nkind = \"spacemouse\"\n[device.rate]\nreset_button = 40\n",
            &["device.rate.reset_button", "40"],
        ),
        (
            "[device]\nkind = \"spacemouse\"\n[device.rate]\nspeed = 1\n",
            &["unknown field", "speed"],
        ),
        (
            "[device]\nkind = \"simulated\"\nreport_script = \"x.hid\"\n",
            &["device.report_script", "spacemouse"],
        ),
        (
            "[device]\nkind = \"spacemouse\"\nserial = \"\"\n",
            &["device.serial"],
        ),
    ] {
        softhaptic_tests::assert_scene_refused(&dir, &scene_with_device(device), expected);
    }
}

#[test]
fn device_choice_names_a_spacemouse_and_its_serial() {
    let c: DeviceChoice = "spacemouse".parse().unwrap();
    assert_eq!((c.kind, c.name), (DeviceKind::Spacemouse, None));
    let c: DeviceChoice = "spacemouse:1234ABCD".parse().unwrap();
    assert_eq!(c.name.as_deref(), Some("1234ABCD"));
    let e = "spacemouse:".parse::<DeviceChoice>().unwrap_err();
    assert!(e.contains("empty serial"), "{e}");
    let e = "joystick".parse::<DeviceChoice>().unwrap_err();
    assert!(e.contains("spacemouse"), "{e}");
}

#[test]
fn the_twist_turns_a_cone_by_default_and_not_a_sphere() {
    let cone = Scene::load(&softhaptic_tests::repo_scenes().join("cone.toml")).unwrap();
    assert!(cone.spacemouse_rate.rotation);
    assert!(!liver_scene().spacemouse_rate.rotation);
}

#[test]
fn a_scene_whose_box_reaches_far_from_the_origin_drives_the_tool_there_without_a_fault() {
    let dir = scratch_dir("spacemouse-far");
    // A full push to the right (+x), a report every 16 ms for 20 s.
    let mut script = String::from("model 046d:c626\n");
    for k in 0..1250 {
        script.push_str(&format!("{} 01 5e 01 00 00 00 00\n", k * 16));
    }
    std::fs::write(dir.join("far.hid"), script).unwrap();
    let text = scene_with_device(
        "[device]\nkind = \"spacemouse\"\nreport_script = \"far.hid\"\n\n\
         [device.rate]\ngain_m_s = 1.0\nmax_speed_m_s = 1.0\n\
         workspace_half_extent_m = [1.0, 1.0, 1.0]\n",
    );
    let mut scene = softhaptic_tests::load_scene_text(&dir, &text).unwrap();
    let preset_reach_m = scene.device_limits.workspace_radius_m;
    let mut device = devices::open(&mut scene).unwrap();
    // The limits the world (and the `scene` message, and the replay check) use reach the box's
    // farthest corner.
    let rate = scene.spacemouse_rate;
    let corner_m = rate
        .workspace_min_m
        .abs()
        .max(rate.workspace_max_m.abs())
        .length();
    assert!(scene.device_limits.workspace_radius_m >= corner_m);
    assert!(corner_m > 1.0 && preset_reach_m < 0.2);
    assert_eq!(
        scene.message().device.workspace_radius_m,
        scene.device_limits.workspace_radius_m
    );

    // The loop's ticks, one a millisecond, until the tool is far beyond the preset's workspace
    // (and twice it, where a PHANTOM's reading is taken for a broken one).
    let mut world = scene.haptic_world();
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut farthest_m = 0.0f64;
    while farthest_m < 0.6 {
        let outcome = world.tick(device.as_mut());
        let state = outcome.state;
        assert!(
            !state.flags.contains(ContactFlags::DEVICE_FAULT),
            "tick {} at {} ({} m from the origin) faulted",
            state.tick,
            state.tip_in_world.position_m,
            state.tip_in_world.position_m.length()
        );
        farthest_m = farthest_m.max(state.tip_in_world.position_m.length());
        assert!(
            Instant::now() < deadline,
            "the tool reached only {farthest_m} m"
        );
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// A SpaceMouse Compact's stream (the combined 12-byte report, all six axes in one): from 0.2 s
/// a push down while the puck is twisted about its vertical and tilted a little, a report every
/// 16 ms until 1.7 s, then a release.
fn compact_twist_script() -> ReportScript {
    let compact = find_model(0x256f, 0xc635).unwrap();
    let mut s = ReportScript::new(compact).report(0.0, &six_axis_report([0; 3], [0; 3]));
    let mut t = 0.2;
    while t < 1.7 {
        // +z down, −rz a twist about the puck's up axis, +rx a tilt.
        s = s.report(t, &six_axis_report([0, 0, FULL], [FULL / 4, 0, -FULL]));
        t += REPORT_EVERY_S;
    }
    s.report(1.7, &six_axis_report([0; 3], [0; 3]))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_compact_s_twist_turns_the_cone_and_the_session_replays_bit_for_bit() {
    let mut scene = Scene::load(&softhaptic_tests::repo_scenes().join("cone.toml")).unwrap();
    scene.choose_device(&DeviceChoice {
        kind: DeviceKind::Spacemouse,
        name: None,
    });
    let (point, _) = scene.press_site_in_object;
    let site = scene.object_in_world.transform_point(point);
    scene.spacemouse_rate.workspace_min_m.y = site.y - 0.005;
    let rate = scene.spacemouse_rate;
    assert!(rate.rotation, "a cone turns with the puck by default");
    let home = rate.home_in_world.orientation;

    let (connector, clock) = compact_twist_script().connector_started_later();
    let device = SpaceMouseDevice::open(Box::new(connector), rate, scene.device_limits).unwrap();
    assert_eq!(device.model().name, "SpaceMouse Compact");
    let mut options = test_options();
    options.device = Some(Box::new(device));
    let live = start_recorded(scene, &scratch_dir("spacemouse-twist"), options).await;
    let mut viewer = Viewer::connect(live.server.local_addr()).await;
    clock.start();

    // Until the cone has pressed and turned by a radian on the wire.
    let (mut pressed, mut turned_rad) = (false, 0.0f64);
    let deadline = Instant::now() + Duration::from_secs(60);
    while !(pressed && turned_rad > 1.0) {
        assert!(
            Instant::now() < deadline,
            "pressed {pressed}, turned {turned_rad} rad"
        );
        if let Some(Ok(ServerMessage::Contact(c))) = viewer.next(Duration::from_secs(5)).await {
            pressed |= c.in_contact && c.force_n.length() > 0.05;
            turned_rad = turned_rad.max(c.tip_in_world.orientation.angle_between(home));
        }
    }
    let (_, _, path, _) = live.finish().await;
    let recorded = Recording::open(&path).unwrap();
    let orientations: Vec<DQuat> = recorded
        .device
        .iter()
        .filter_map(|d| d.sample)
        .map(|s| DQuat::from_array(s.tip_orientation))
        .collect();
    assert!(orientations[0].angle_between(home) < 1e-12);
    let last = orientations.last().unwrap();
    assert!(last.angle_between(home) > 1.0, "{last}");
    assert!(recorded.device.iter().any(|d| d.in_contact));

    let report = check(&recorded, CheckOverrides::default()).unwrap();
    assert!(report.passed(), "{report}");
    assert_eq!(report.ticks_compared, recorded.device.len() as u64);
    assert_softhaptic_check_passes(&path, recorded.device.len());
}

#[test]
fn a_sphere_ignores_the_compact_s_twist() {
    let scene = liver_scene();
    let rate = scene.spacemouse_rate;
    assert!(!rate.rotation);
    let mut device = SpaceMouseDevice::open(
        Box::new(compact_twist_script().connector()),
        rate,
        scene.device_limits,
    )
    .unwrap();
    // Until the push down has brought the tool to the box's floor: the stream is being read.
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let s = device.read().unwrap();
        assert_eq!(s.tip_in_world.orientation, rate.home_in_world.orientation);
        if s.tip_in_world.position_m.y == rate.workspace_min_m.y {
            break;
        }
        assert!(Instant::now() < deadline, "{s:?}");
        std::thread::sleep(Duration::from_millis(1));
    }
}
