//! The recorded sessions of `tests/sessions/` replay through this build's haptic world to the
//! recorded forces, bit for bit; replaying twice gives the same bytes; a deliberate change of the
//! damping is caught and reported at its first tick (the command line's side is in
//! `server/tests/session_cli.rs`).

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::path::{Path, PathBuf};

use softhaptic_proto::ContactFlags;
use softhaptic_proto::record::DeviceErrorRecord;
use softhaptic_server::session::check::{CheckOverrides, check};
use softhaptic_server::session::reader::Recording;

const RECORDINGS: [&str; 5] = [
    "sphere-press.mcap",
    "cone-press.mcap",
    "slide.mcap",
    "fault-mid-press.mcap",
    "guided-slide.mcap",
];

fn recording_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("sessions")
        .join(name)
}

fn open(name: &str) -> Recording {
    Recording::open(&recording_path(name)).expect("the test recording reads")
}

#[test]
fn every_test_recording_replays_to_its_recorded_forces_bit_for_bit() {
    for name in RECORDINGS {
        let r = open(name);
        assert!(r.is_complete(), "{}", r.recovery());
        assert!(r.device.len() >= 2500, "{name}: {} ticks", r.device.len());
        let report = check(&r, CheckOverrides::default()).unwrap();
        assert!(report.passed(), "{report}");
        assert_eq!(report.ticks_compared, r.device.len() as u64);
        // The recordings are about contact: each presses the object with a real force.
        let peak = r
            .device
            .iter()
            .map(|d| glam::DVec3::from_array(d.force_n).length())
            .fold(0.0, f64::max);
        assert!(peak > 0.5, "{name}: peak force {peak} N");
    }
}

#[test]
fn replaying_the_same_recording_twice_gives_identical_force_bytes() {
    let r = open("slide.mcap");
    let a = check(&r, CheckOverrides::default()).unwrap();
    let b = check(&r, CheckOverrides::default()).unwrap();
    let bytes = |forces: &[[f64; 3]]| -> Vec<u8> {
        forces
            .iter()
            .flatten()
            .flat_map(|f| f.to_le_bytes())
            .collect()
    };
    assert!(a.ticks_compared == 4000 && a.replayed_n.len() == 4000);
    assert!(
        bytes(&a.replayed_n) == bytes(&b.replayed_n),
        "two replays of the same recording differ"
    );
    let recorded: Vec<[f64; 3]> = r.device.iter().map(|d| d.force_n).collect();
    assert!(
        bytes(&a.replayed_n) == bytes(&recorded),
        "the replay differs from the recording: {a}"
    );
}

#[test]
fn the_fault_recording_replays_its_device_errors() {
    let r = open("fault-mid-press.mcap");
    let faulted: Vec<_> = r
        .device
        .iter()
        .filter(|d| d.device_error == Some(DeviceErrorRecord::Disconnected))
        .collect();
    assert_eq!(faulted.len(), 200, "200 ms of disconnection");
    for d in &faulted {
        assert!(d.sample.is_none() && d.device_fault);
        assert_eq!(d.force_n, [0.0; 3], "zero force while the device is gone");
        assert!(ContactFlags::from_bits_truncate(d.flags).contains(ContactFlags::DEVICE_FAULT));
    }
    // After the fault the force ramps back in.
    let after = r
        .device
        .iter()
        .find(|d| d.tick == faulted.last().unwrap().tick + 1)
        .unwrap();
    assert!(ContactFlags::from_bits_truncate(after.flags).contains(ContactFlags::RAMPING));
    assert!(check(&r, CheckOverrides::default()).unwrap().passed());
}

#[test]
fn a_damping_change_fails_the_check_at_the_first_tick_it_affects() {
    let r = open("sphere-press.mcap");
    let report = check(
        &r,
        CheckOverrides {
            damping_n_s_per_m: Some(3.0),
        },
    )
    .unwrap();
    assert!(!report.passed());
    let d = report.first_difference.expect("a difference");
    // Damping acts only in contact: every tick before the reported one is unchanged, and the
    // reported one is in contact.
    let recorded = r.device.iter().find(|x| x.tick == d.tick).unwrap();
    assert!(recorded.in_contact, "tick {} is in contact", d.tick);
    assert_eq!(d.recorded_n, recorded.force_n);
    for (k, f) in report.replayed_n.iter().enumerate().take(d.tick as usize) {
        assert_eq!(
            f, &r.device[k].force_n,
            "tick {k} changed before the reported one"
        );
    }
    assert_ne!(d.replayed_n, d.recorded_n);
    let text = report.to_string();
    assert!(
        text.contains(&format!("forces differ at tick {}", d.tick))
            && text.contains("recorded force_n")
            && text.contains("replayed force_n")
            && text.contains("difference"),
        "{text}"
    );
}
