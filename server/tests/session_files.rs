//! Session files on disk: what the writer and the recorder thread write reads back exactly,
//! truncated files recover every complete chunk, and files that cannot be trusted (wrong magic,
//! wrong schema, newer versions, invalid messages) are refused with a message naming the file and
//! the cause, never a panic.
//!
//! Long because its 14 tests share the fixtures of a recording (build, scene, ticks, foreign file).

// Test code, synchronous: reads the recordings it wrote, and waits for the ring it fills.
#![allow(clippy::disallowed_methods)]
#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::DVec3;
use softhaptic_device::device::{DeviceError, DeviceSample};
use softhaptic_device::haptic_loop::TickRecord;
use softhaptic_proto::record::{
    BuildRecord, DeviceRecord, MCAP_PROFILE, SESSION_FORMAT_VERSION, SceneRecord, topic,
};
use softhaptic_proto::wire::PROTOCOL_VERSION;
use softhaptic_proto::{ContactFlags, ContactState, Pose};
use softhaptic_server::scene::Scene;
use softhaptic_server::session::SessionError;
use softhaptic_server::session::reader::{Ending, Recording};
use softhaptic_server::session::tools::Info;
use softhaptic_server::session::writer::{Recorder, SessionWriter};

/// A fresh directory under the system's temporary directory, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> TempDir {
        let dir = std::env::temp_dir().join(format!(
            "softhaptic-{name}-{}-{:?}",
            std::process::id(),
            std::thread::current().id()
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }
    fn join(&self, file: &str) -> PathBuf {
        self.0.join(file)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn sessions_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join("tests")
        .join("sessions")
}

fn build(format: u32, protocol: u32) -> BuildRecord {
    BuildRecord {
        session_format_version: format,
        protocol_version: protocol,
        writer: "softhaptic test".into(),
        git_commit: None,
        session_id: "test-session".into(),
        started_unix_ns: 1,
    }
}

fn scene_record() -> SceneRecord {
    let text = include_str!("../../scenes/default.toml");
    let scene = Scene::from_toml(text, Path::new("default.toml"), None).unwrap();
    SceneRecord {
        message: scene.message(),
        scene_toml: text.into(),
        scene_file: None,
        period_ns: 1_000_000,
        meshes: None,
        inclusions: None,
        guide: None,
    }
}

fn sample(k: u64) -> DeviceSample {
    DeviceSample {
        time_ns: k * 1_000_000,
        tip_in_world: Pose::from_position(DVec3::new(0.01, 0.07 - 1e-6 * k as f64, 1.0 / 3.0)),
        tip_velocity_m_s: DVec3::new(0.0, -1e-3, 0.0),
        buttons: 1,
        flags: ContactFlags::empty(),
    }
}

fn tick(k: u64, fault: bool) -> TickRecord {
    let sample = (!fault).then(|| sample(k));
    TickRecord {
        sample,
        device_fault: fault,
        device_error: fault.then_some(softhaptic_device::device::DeviceError::Disconnected),
        command_error: None,
        // Now and then the loop lost ticks before this one.
        lost_before: if k % 97 == 5 { k % 3 + 1 } else { 0 },
        contact: ContactState {
            tick: k,
            time_ns: k * 1_000_000,
            in_contact: k.is_multiple_of(3),
            depth_m: 1e-4 * k as f64,
            force_n: DVec3::new(0.1 / 7.0, k as f64 / 3.0, -0.0),
            flags: if fault {
                ContactFlags::DEVICE_FAULT
            } else {
                ContactFlags::empty()
            },
            ..ContactState::IDLE
        },
    }
}

#[test]
fn recorder_thread_writes_every_tick_of_the_ring_bit_for_bit_and_counts_gaps() {
    let dir = TempDir::new("recorder");
    let path = dir.join("run.mcap");
    let (mut producer, consumer) = rtrb::RingBuffer::new(64);
    let recorder = Recorder::start(&path, &build(1, 1), &scene_record(), consumer).unwrap();
    let tap = recorder.stream_tap();
    let mut pushed = Vec::new();
    for k in 0..2500u64 {
        // Ticks 1000..1010 never reach the ring: a gap the recorder must count.
        if (1000..1010).contains(&k) {
            continue;
        }
        let t = tick(k, k == 1500);
        while producer.push(t).is_err() {
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        pushed.push(t);
        if k.is_multiple_of(20) {
            tap.record_contact(
                k * 1_000_000,
                format!(
                    r#"{{"type":"contact","seq":{},"tick":{k},"time_ns":{},"tip_in_world":{{"position_m":[0,0,0],"orientation":[0,0,0,1]}},"in_contact":false,"depth_m":0,"normal":[0,1,0],"contact_point_m":[0,0,0],"contact_radius_m":0,"deformed_radius_m":0,"force_n":[0,0,0],"flags":[],"dropped":0}}"#,
                    k / 20,
                    k * 1_000_000
                ),
            );
        }
    }
    let stats = recorder.finish().unwrap();
    assert_eq!(stats.ticks_recorded, 2490);
    assert_eq!(stats.ticks_dropped, 10);
    assert!(stats.is_final);

    let r = Recording::open(&path).unwrap();
    assert_eq!(r.ending, Ending::Complete, "{}", r.recovery());
    assert_eq!(r.device.len(), pushed.len());
    assert_eq!(r.missing_ticks(), 10);
    assert_eq!(r.last_stats.unwrap().ticks_dropped, 10);
    // Every 20th tick but 1000, which fell in the gap.
    assert_eq!(r.contacts.len(), 124);
    for (rec, t) in r.device.iter().zip(&pushed) {
        assert_eq!(rec.tick, t.contact.tick);
        assert_eq!(rec.lost_before, t.lost_before, "tick {}", rec.tick);
        for (a, b) in rec.force_n.iter().zip(t.contact.force_n.to_array()) {
            assert_eq!(a.to_bits(), b.to_bits(), "tick {}", rec.tick);
        }
        match (&rec.sample, &t.sample) {
            (Some(a), Some(b)) => {
                for (x, y) in a
                    .tip_position_m
                    .iter()
                    .zip(b.tip_in_world.position_m.to_array())
                {
                    assert_eq!(x.to_bits(), y.to_bits());
                }
            }
            (None, None) => assert!(rec.device_fault),
            other => panic!("sample mismatch at tick {}: {other:?}", rec.tick),
        }
    }
    assert_eq!(r.build.session_id, "test-session");
    assert_eq!(r.scene.message.tool, scene_record().message.tool);
    // The loop's lost ticks are counted by info, with the longest run.
    let info = Info::of(&r);
    let lost: Vec<&TickRecord> = pushed.iter().filter(|t| t.lost_before > 0).collect();
    assert_eq!(info.lost_runs, lost.len() as u64);
    assert_eq!(
        info.ticks_lost,
        lost.iter().map(|t| t.lost_before).sum::<u64>()
    );
    assert_eq!(info.longest_lost_run.map(|(n, _)| n), Some(3));
    assert!(info.to_string().contains(&format!(
        "lost ticks:        {} in {} runs",
        info.ticks_lost, info.lost_runs
    )));
}

/// Cut the slide recording at many lengths: every cut either recovers a prefix of the ticks (more
/// for longer cuts, and everything before the last complete chunk), or is refused with a clear
/// error when it ends before the scene. Never a panic.
#[test]
fn truncated_files_recover_complete_chunks_and_say_what_was_lost() {
    let path = sessions_dir().join("slide.mcap");
    let bytes = std::fs::read(&path).unwrap();
    let full = Recording::from_bytes(&path, &bytes).unwrap();
    assert!(full.is_complete());
    let mut last_ticks = 0;
    let mut recovered_some = 0;
    for cut in (0..bytes.len()).step_by(4099).chain([bytes.len() - 1]) {
        match Recording::from_bytes(&path, &bytes[..cut]) {
            Ok(r) => {
                assert!(!r.is_complete(), "cut at {cut} reads as complete");
                assert!(r.device.len() >= last_ticks, "cut at {cut} recovered less");
                last_ticks = r.device.len();
                assert_eq!(&full.device[..r.device.len()], &r.device[..]);
                let text = r.recovery().to_string();
                assert!(
                    text.contains("truncated") && text.contains("recovered"),
                    "{text}"
                );
                if !r.device.is_empty() {
                    recovered_some += 1;
                }
            }
            Err(e) => {
                let text = e.to_string();
                assert!(text.contains("slide.mcap"), "{text}");
                assert!(
                    matches!(
                        e,
                        SessionError::NotMcap { .. } | SessionError::TruncatedBeforeStart { .. }
                    ),
                    "cut at {cut}: {text}"
                );
            }
        }
    }
    assert!(
        recovered_some > 40,
        "only {recovered_some} cuts recovered ticks"
    );
    // One byte short of the end loses only the footer: every tick is still there.
    assert_eq!(last_ticks, full.device.len());
}

#[test]
fn a_recording_path_that_is_not_a_regular_file_is_refused_before_it_is_read() {
    let e = Recording::open(Path::new("/dev/zero"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("/dev/zero") && e.contains("character device"),
        "{e}"
    );
    let dir = TempDir::new("not-regular");
    let e = Recording::open(&dir.0).unwrap_err().to_string();
    assert!(e.contains("is a directory, not a regular file"), "{e}");
}

#[test]
fn a_file_that_is_not_mcap_is_refused_naming_its_first_bytes() {
    let dir = TempDir::new("magic");
    let path = dir.join("notes.mcap");
    std::fs::write(&path, b"PK\x03\x04 this is a zip").unwrap();
    let e = Recording::open(&path).unwrap_err();
    let text = e.to_string();
    assert!(
        text.contains("notes.mcap") && text.contains("not an MCAP file"),
        "{text}"
    );
    assert!(text.contains("50 4b 03 04"), "{text}");
    let empty = dir.join("empty.mcap");
    std::fs::write(&empty, b"").unwrap();
    assert!(matches!(
        Recording::open(&empty),
        Err(SessionError::NotMcap { .. })
    ));
    let missing = dir.join("missing.mcap");
    let e = Recording::open(&missing).unwrap_err();
    assert!(e.to_string().contains("missing.mcap"), "{e}");
}

/// An MCAP file written with the plain library: `device_schema` for /device, one message.
fn write_foreign(path: &Path, device_schema: &str, device_message: &[u8]) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = mcap::WriteOptions::new()
        .profile(MCAP_PROFILE)
        .create(file)
        .unwrap();
    let add = |w: &mut mcap::Writer<_>, topic: &str, schema: &str| {
        let s = w.add_schema(schema, "jsonschema", b"{}").unwrap();
        w.add_channel(s, topic, "json", &BTreeMap::new()).unwrap()
    };
    let build_ch = add(&mut w, topic::BUILD, "softhaptic.BuildRecord");
    let device_ch = add(&mut w, topic::DEVICE, device_schema);
    let header = |channel_id| mcap::records::MessageHeader {
        channel_id,
        sequence: 1,
        log_time: 0,
        publish_time: 0,
    };
    let b = serde_json::to_vec(&build(SESSION_FORMAT_VERSION, PROTOCOL_VERSION)).unwrap();
    w.write_to_known_channel(&header(build_ch), &b).unwrap();
    w.write_to_known_channel(&header(device_ch), device_message)
        .unwrap();
    w.finish().unwrap();
}

#[test]
fn a_channel_with_another_schema_is_refused() {
    let dir = TempDir::new("schema");
    let path = dir.join("robot.mcap");
    write_foreign(&path, "geometry_msgs/Pose", b"{}");
    let e = Recording::open(&path).unwrap_err();
    let text = e.to_string();
    assert!(matches!(e, SessionError::WrongSchema { .. }), "{text}");
    assert!(
        text.contains("robot.mcap")
            && text.contains("/device")
            && text.contains("geometry_msgs/Pose"),
        "{text}"
    );
}

#[test]
fn an_invalid_message_is_refused_naming_topic_and_sequence() {
    let dir = TempDir::new("message");
    let path = dir.join("bad.mcap");
    write_foreign(&path, "softhaptic.DeviceRecord", br#"{"tick":"one"}"#);
    let e = Recording::open(&path).unwrap_err();
    let text = e.to_string();
    assert!(matches!(e, SessionError::BadMessage { .. }), "{text}");
    assert!(
        text.contains("message 1 on /device") && text.contains("bad.mcap"),
        "{text}"
    );
}

#[test]
fn newer_format_or_protocol_versions_are_refused() {
    let dir = TempDir::new("version");
    for (name, b, field) in [
        (
            "format.mcap",
            build(SESSION_FORMAT_VERSION + 1, 1),
            "session_format_version",
        ),
        (
            "protocol.mcap",
            build(1, PROTOCOL_VERSION + 1),
            "protocol_version",
        ),
    ] {
        let path = dir.join(name);
        let w = SessionWriter::create(&path, &b, &scene_record()).unwrap();
        w.finish().unwrap();
        let e = Recording::open(&path).unwrap_err();
        let text = e.to_string();
        assert!(matches!(e, SessionError::NewerVersion { .. }), "{text}");
        assert!(text.contains(field) && text.contains(name), "{text}");
    }
}

#[test]
fn the_writer_refuses_to_overwrite_a_recording() {
    let dir = TempDir::new("overwrite");
    let path = dir.join("a.mcap");
    SessionWriter::create(&path, &build(1, 1), &scene_record())
        .unwrap()
        .finish()
        .unwrap();
    let e = SessionWriter::create(&path, &build(1, 1), &scene_record())
        .err()
        .expect("a second create fails");
    assert!(e.to_string().contains("a.mcap"), "{e}");
    assert!(e.to_string().contains("--replace"), "the fix is named: {e}");
}

#[test]
fn device_errors_are_recorded_and_read_back() {
    let dir = TempDir::new("errors");
    let path = dir.join("e.mcap");
    let mut w = SessionWriter::create(&path, &build(1, 1), &scene_record()).unwrap();
    let state = ContactState {
        flags: ContactFlags::DEVICE_FAULT,
        ..ContactState::IDLE
    };
    let rec: DeviceRecord =
        softhaptic_device::replay::device_record(&Err(DeviceError::Driver(-42)), &state);
    w.write_device(&rec).unwrap();
    w.finish().unwrap();
    let r = Recording::open(&path).unwrap();
    assert_eq!(r.device, vec![rec]);
    assert_eq!(
        softhaptic_device::replay::device_read(&r.device[0]),
        Err(DeviceError::Driver(-42))
    );
}

/// Damaged bytes anywhere (a bad disk, a bad copy) give a recording or an error, never a panic.
#[test]
fn corrupted_bytes_never_panic_the_reader() {
    let path = sessions_dir().join("cone-press.mcap");
    let bytes = std::fs::read(&path).unwrap();
    // Refused, or read as cut short at the damage.
    let mut refused = 0;
    for (i, at) in (8..bytes.len()).step_by(bytes.len() / 60).enumerate() {
        let mut damaged = bytes.clone();
        damaged[at] ^= 0x5a ^ (i as u8);
        match Recording::from_bytes(&path, &damaged) {
            Ok(r) => {
                assert!(r.device.len() <= 3000);
                if !r.is_complete() {
                    refused += 1;
                }
            }
            Err(e) => {
                assert!(e.to_string().contains("cone-press.mcap"), "{e}");
                refused += 1;
            }
        }
    }
    assert!(refused > 0, "some damage must be detected");
}

/// Byte ranges `(record start, body start, body end)` of the file's top-level chunk records.
fn chunks(bytes: &[u8]) -> Vec<(usize, usize, usize)> {
    let mut out = Vec::new();
    let mut pos = 8;
    while pos + 9 <= bytes.len() {
        let op = bytes[pos];
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().unwrap()) as usize;
        let end = pos + 9 + len;
        if op == 0x06 {
            out.push((pos, pos + 9, end));
        }
        if op == 0x0F {
            break;
        }
        pos = end;
    }
    out
}

/// Every recovered record is the original's: damage may drop records, never change one.
fn assert_subset(full: &Recording, r: &Recording) {
    let by_tick: BTreeMap<u64, &DeviceRecord> = full.device.iter().map(|d| (d.tick, d)).collect();
    for d in &r.device {
        assert_eq!(by_tick.get(&d.tick), Some(&d), "tick {} changed", d.tick);
    }
}

#[test]
fn a_damaged_chunk_loses_its_own_second_and_every_later_chunk_is_read() {
    let path = sessions_dir().join("slide.mcap");
    let bytes = std::fs::read(&path).unwrap();
    let full = Recording::from_bytes(&path, &bytes).unwrap();
    let found = chunks(&bytes);
    // The first chunk holds the channels, the build and the scene; the data chunks follow.
    assert!(found.len() >= 4, "{} chunks", found.len());
    let (start, body, end) = found[1];
    let mut damaged = bytes.clone();
    // A bit flipped in the middle of the first data chunk's compressed records.
    damaged[(body + end) / 2] ^= 0x10;
    let r = Recording::from_bytes(&path, &damaged).unwrap();
    assert_eq!(r.lost.len(), 1, "{}", r.recovery());
    let lost = &r.lost[0];
    assert_eq!(lost.first_byte, start as u64);
    let (from_ns, to_ns) = lost.time_ns.expect("the chunk's header names its times");
    // Every tick outside the lost chunk's second is there, unchanged.
    let outside: Vec<&DeviceRecord> = full
        .device
        .iter()
        .filter(|d| d.time_ns < from_ns || d.time_ns > to_ns)
        .collect();
    assert_eq!(r.device.len(), outside.len(), "{}", r.recovery());
    assert!(
        r.device.len() >= full.device.len() - 1_100,
        "{} of {} ticks recovered",
        r.device.len(),
        full.device.len()
    );
    assert_subset(&full, &r);
    assert!(!r.is_complete());
    assert_eq!(r.ending, Ending::Complete, "the file itself was closed");
    let text = r.recovery().to_string();
    assert!(
        text.contains("damaged")
            && text.contains("device time")
            && text.contains("checksum")
            && text.contains(&format!("recovered {} ticks", r.device.len())),
        "{text}"
    );
    // With a later chunk damaged instead, checking stops at the gap and blames the damage, not
    // the recorder.
    let (_, body2, end2) = found[2];
    let mut later = bytes.clone();
    later[(body2 + end2) / 2] ^= 0x10;
    let report = softhaptic_server::session::check::check(
        &Recording::from_bytes(&path, &later).unwrap(),
        softhaptic_server::session::check::CheckOverrides::default(),
    )
    .unwrap();
    assert!(
        matches!(report.stopped_at_gap, Some((_, _, true))),
        "{report}"
    );
    let said = report.to_string();
    assert!(
        said.contains("damaged part of the file") && !said.contains("dropped by the recorder"),
        "{said}"
    );
    // A flipped length: the walk cannot step over the chunk, and finds the next one by itself.
    let mut bad_length = bytes.clone();
    bad_length[start + 6] ^= 0x01;
    let r = Recording::from_bytes(&path, &bad_length).unwrap();
    assert!(
        r.device.len() >= full.device.len() - 1_100,
        "{}",
        r.recovery()
    );
    assert_subset(&full, &r);
}

/// The experiment of a damaged disk: 100 single-bit flips at seeded random places of a shipped
/// recording. Each gives a recording (every recovered record unchanged; a flip in the first
/// chunk, which defines the session, is made good by its copy); none loses more than the chunk
/// it hit and the one around a damaged length.
#[test]
fn a_hundred_random_bit_flips_each_lose_at_most_the_chunk_they_hit() {
    let path = sessions_dir().join("slide.mcap");
    let bytes = std::fs::read(&path).unwrap();
    let full = Recording::from_bytes(&path, &bytes).unwrap();
    let first_data_chunk = chunks(&bytes)[1].0;
    // A small deterministic generator (xorshift): the same 100 places on every run.
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let (mut refused, mut worst, mut total, mut whole) = (0, full.device.len(), 0, 0);
    for _ in 0..100 {
        let at = 8 + (next() as usize) % (bytes.len() - 8);
        let bit = (next() % 8) as u8;
        let mut damaged = bytes.clone();
        damaged[at] ^= 1 << bit;
        match Recording::from_bytes(&path, &damaged) {
            Ok(r) => {
                assert_subset(&full, &r);
                worst = worst.min(r.device.len());
                total += r.device.len();
                whole += usize::from(r.device.len() == full.device.len());
                {
                    assert!(
                        r.device.len() + 2_200 >= full.device.len(),
                        "a flip at byte {at} lost {} of {} ticks: {}",
                        full.device.len() - r.device.len(),
                        full.device.len(),
                        r.recovery()
                    );
                }
            }
            Err(e) => {
                assert!(at < first_data_chunk, "a flip at byte {at} refused: {e}");
                assert!(e.to_string().contains("slide.mcap"), "{e}");
                refused += 1;
            }
        }
    }
    assert_eq!(refused, 0, "flips in the first chunk refused");
    println!(
        "100 flips: {refused} refused (first chunk), worst {worst} of {} ticks recovered, mean {:.0}, \
         {whole} lost no tick",
        full.device.len(),
        total as f64 / (100 - refused).max(1) as f64
    );
}

/// A 10 cm flat grid as an OBJ file, 11 × 11 vertices at y = 0, normals up.
fn grid_obj() -> String {
    let mut text = String::new();
    for k in 0..11 {
        for i in 0..11 {
            text.push_str(&format!(
                "v {} 0 {}\n",
                -0.05 + 0.01 * i as f64,
                -0.05 + 0.01 * k as f64
            ));
        }
    }
    for k in 0..10 {
        for i in 0..10 {
            let v = |i: usize, k: usize| k * 11 + i + 1;
            text.push_str(&format!("f {} {} {}\n", v(i, k), v(i, k + 1), v(i + 1, k)));
            text.push_str(&format!(
                "f {} {} {}\n",
                v(i + 1, k),
                v(i, k + 1),
                v(i + 1, k + 1)
            ));
        }
    }
    text
}

/// Records a press of the simulated hand on `scene`, tick by tick, to `path`.
fn record_press(scene: &Scene, scene_record: &SceneRecord, path: &Path) {
    use softhaptic_device::sim::{SimParams, SimulatedPhantom};
    let mut writer = SessionWriter::create(path, &build(1, 1), scene_record).unwrap();
    let mut world = scene.haptic_world();
    let mut script = scene.hand_script();
    script.repeat = false;
    let mut sim = SimulatedPhantom::with_params(
        script,
        SimParams {
            limits: scene.device_limits,
            ..SimParams::default()
        },
    );
    for _ in 0..2000 {
        let t = world.tick(&mut sim);
        writer
            .write_tick(&TickRecord {
                sample: t.read.ok(),
                device_fault: t.state.flags.contains(ContactFlags::DEVICE_FAULT),
                device_error: t.read.err(),
                command_error: t.command.err(),
                lost_before: 0,
                contact: t.state,
            })
            .unwrap();
    }
    writer.finish().unwrap();
}

#[test]
fn a_recording_keeps_its_meshes_and_checks_without_reading_the_files_its_scene_names() {
    use softhaptic_server::session::check::{CheckOverrides, check};
    let dir = TempDir::new("self-contained");
    std::fs::write(dir.join("grid.obj"), grid_obj()).unwrap();
    let scene_toml = include_str!("../../scenes/default.toml")
        .replace("builtin = \"liver\"", "haptic_mesh = \"grid.obj\"")
        .replace("curvature = true", "curvature = false")
        .replace("calibration/sphere10_50kpa.json", "half_space");
    let scene_path = dir.join("grid.toml");
    std::fs::write(&scene_path, &scene_toml).unwrap();
    let scene = Scene::load(&scene_path).unwrap();
    let meshes = scene.recorded_meshes().expect("meshes from files are kept");
    assert_eq!(meshes.haptic.positions_m.len(), 121);
    assert!(meshes.render.is_none(), "the haptic mesh is drawn");
    let record = SceneRecord {
        message: scene.message(),
        scene_toml: scene_toml.clone(),
        scene_file: Some(scene_path.display().to_string()),
        period_ns: 1_000_000,
        meshes: Some(meshes),
        inclusions: None,
        guide: None,
    };
    let recording_path = dir.join("press.mcap");
    record_press(&scene, &record, &recording_path);
    let r = Recording::open(&recording_path).unwrap();
    assert!(
        r.device.iter().any(|d| d.in_contact),
        "the hand pressed the grid"
    );
    let report = check(&r, CheckOverrides::default()).unwrap();
    assert!(report.passed(), "{report}");

    // The mesh on disk edited, then gone: the check runs on the recording's own copy.
    std::fs::write(
        dir.join("grid.obj"),
        grid_obj().replace("v -0.05 0", "v -0.05 0.003"),
    )
    .unwrap();
    assert!(check(&r, CheckOverrides::default()).unwrap().passed());
    std::fs::remove_file(dir.join("grid.obj")).unwrap();
    assert!(check(&r, CheckOverrides::default()).unwrap().passed());

    // A recording without the meshes (as older ones were) is refused, not read from disk.
    let older_path = dir.join("older.mcap");
    record_press(
        &scene,
        &SceneRecord {
            meshes: None,
            inclusions: None,
            guide: None,
            ..record.clone()
        },
        &older_path,
    );
    let e = check(
        &Recording::open(&older_path).unwrap(),
        CheckOverrides::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("grid.obj") && e.contains("not in the recording"),
        "{e}"
    );

    // A damaged copy (one coordinate changed, its hash not) is refused.
    let mut damaged = record.clone();
    if let Some(m) = damaged.meshes.as_mut() {
        m.haptic.positions_m[5][1] += 1e-3;
    }
    let damaged_path = dir.join("damaged.mcap");
    record_press(&scene, &damaged, &damaged_path);
    let e = check(
        &Recording::open(&damaged_path).unwrap(),
        CheckOverrides::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("does not match its hash"), "{e}");
}

#[test]
fn a_live_recording_keeps_the_scene_text_that_was_loaded_not_the_file_as_it_is_later() {
    use softhaptic_server::session::cli::{LiveRecording, RecordArgs};
    let dir = TempDir::new("scene-text");
    let loaded = include_str!("../../scenes/default.toml")
        .replace("calibration/sphere10_50kpa.json", "half_space");
    let scene_path = dir.join("scene.toml");
    std::fs::write(&scene_path, &loaded).unwrap();
    let scene = Scene::load(&scene_path).unwrap();
    // Edited after the scene was loaded and before the recording starts: the session runs the
    // scene as loaded, so the recording must hold that text for a check to rebuild it.
    std::fs::write(&scene_path, loaded.replace("0.33", "0.45")).unwrap();
    let args = RecordArgs {
        no_record: false,
        record_dir: dir.join("sessions"),
    };
    let recording = LiveRecording::start(&args, &scene, Some(&scene_path))
        .unwrap()
        .expect("recording");
    let (path, _) = recording
        .finish(&softhaptic_device::metrics::TraineeMetrics::default())
        .unwrap();
    let r = Recording::open(&path).unwrap();
    assert_eq!(r.scene.scene_toml, loaded);
    assert_eq!(
        r.scene.scene_file.as_deref(),
        Some(
            std::path::absolute(&scene_path)
                .unwrap()
                .display()
                .to_string()
                .as_str()
        )
    );
}
