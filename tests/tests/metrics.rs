//! The trainee's metrics end to end: a viewer gets them once a second, and last before the
//! server closes it the loop's final ones, which are recorded, and are what the recording gives
//! when computed again from its ticks (`info`, `export`), what the replay check's world computes
//! replaying them, and what a replay sends (after a seek, those of the new position). A scene's
//! safe force is read from a recording whether written `1` or `1.0`, and a replay marks on its
//! timeline exactly the stretches of recorded ticks that pushed harder than it.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::time::{Duration, Instant};

use softhaptic_proto::wire::ServerMessage;
use softhaptic_server::scene::Scene;
use softhaptic_server::session::check::{CheckOverrides, check};
use softhaptic_server::session::reader::Recording;
use softhaptic_server::session::replay;
use softhaptic_server::session::tools::{Info, export, recorded_safe_force_n, recording_metrics};
use softhaptic_server::stream::metrics_message;
use softhaptic_tests::{Viewer, scratch_dir, start_recorded, test_options};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn live_recorded_exported_and_replayed_metrics_are_the_same() {
    let scene = Scene::builtin_default().unwrap();
    let dir = scratch_dir("metrics");
    let session = start_recorded(scene, &dir, test_options()).await;
    let server = &session.server;

    // A viewer gets the metrics; once the simulated hand has pressed, they show it.
    let mut viewer = Viewer::connect(server.local_addr()).await;
    let deadline = Instant::now() + Duration::from_secs(60);
    let live = loop {
        assert!(Instant::now() < deadline, "no metrics with a press");
        if let Some(Ok(ServerMessage::Metrics(m))) = viewer.next(Duration::from_secs(10)).await
            && m.pushes >= 1
            && m.time_in_contact_s > 0.2
        {
            break m;
        }
    };
    assert!(!live.is_final);
    assert!(live.peak_force_n > 0.1 && live.ticks > 500, "{live:?}");
    assert_eq!(live.safe_force_n, 2.0);

    let (loop_stats, final_live, path, stats) = session.finish().await;
    let r = Recording::open(&path).unwrap();
    let recorded = recording_metrics(&r);

    // The recording keeps the 1 Hz messages viewers were sent and, last, the loop's final ones.
    assert!(r.metrics.iter().any(|m| !m.is_final), "{:?}", r.metrics);
    assert_eq!(r.metrics.iter().filter(|m| m.is_final).count(), 1);
    assert_eq!(r.final_metrics(), Some(&metrics_message(&final_live, true)));

    // The replaying world computes them from the recorded ticks as the live one did.
    let report = check(&r, CheckOverrides::default()).unwrap();
    assert!(report.passed(), "{report}");
    assert_eq!(report.metrics, recorded);
    // Every tick the loop ran is in the recording or counted as dropped by the loop itself (the
    // ring to the recorder had no room): the loop's count covers a loss at the end too, which
    // the writer, seeing no later tick, cannot count.
    let dropped = loop_stats.dropped_tick_records;
    assert_eq!(
        recorded.ticks + dropped,
        final_live.ticks,
        "recorded {} ticks, the loop ran {} and dropped {dropped}",
        recorded.ticks,
        final_live.ticks
    );
    // The writer counts the gaps it saw in the tick counter, which are the file's gaps.
    assert_eq!(stats.ticks_dropped, r.missing_ticks());
    assert!(
        stats.ticks_dropped <= dropped,
        "the writer counted {} dropped, the loop {dropped}",
        stats.ticks_dropped
    );
    // The live loop's, to the bit, whenever the recording holds every tick it ran. A loaded
    // machine may make the ring overflow; then the recording's metrics are of a subset of the
    // ticks, and only what a subset cannot exceed is held against the live ones.
    if dropped == 0 {
        assert_eq!(recorded, final_live);
        assert!(matches!(Info::of(&r).recorded_metrics, Some((_, true))));
        assert!(report.metrics_compared);
        assert!(
            report.to_string().contains("metrics are the ones recorded"),
            "{report}"
        );
        // `check` holds the replay's metrics against the recorded ones, to the bit.
        let mut tampered = r.clone();
        let last = tampered.metrics.len() - 1;
        tampered.metrics[last].path_length_in_contact_m += 1e-12;
        let report = check(&tampered, CheckOverrides::default()).unwrap();
        assert!(!report.passed());
        assert!(report.first_difference.is_none());
        assert!(report.to_string().contains("metrics differ"), "{report}");
        assert!(matches!(
            Info::of(&tampered).recorded_metrics,
            Some((_, false))
        ));
    } else {
        assert!(recorded.peak_force_n <= final_live.peak_force_n);
        assert!(recorded.device_fault_ticks <= final_live.device_fault_ticks);
        assert_eq!(recorded.safe_force_n, final_live.safe_force_n);
    }
    assert!(final_live.ticks >= live.ticks);

    // `info` and `export` give the same.
    assert_eq!(Info::of(&r).metrics, recorded);
    let out = dir.join("export");
    let json = export(&r, &out, false).unwrap().metrics;
    // A second export into the same directory keeps the first, unless told to replace it.
    let e = export(&r, &out, false).unwrap_err().to_string();
    assert!(e.contains("device.csv") && e.contains("--replace"), "{e}");
    export(&r, &out, true).unwrap();
    let exported: softhaptic_proto::wire::MetricsMessage =
        serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap();
    assert_eq!(exported, metrics_message(&recorded, true));

    // The replay sends them on the recording's timeline: once a second, then the final ones.
    let replay = replay::start(r.clone(), softhaptic_tests::replay_options(8.0, false))
        .await
        .unwrap();
    let mut watcher = Viewer::connect(replay.local_addr()).await;
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut seen = Vec::new();
    let replayed_final = loop {
        assert!(
            Instant::now() < deadline,
            "no final metrics in the replay: {seen:?}"
        );
        if let Some(Ok(ServerMessage::Metrics(m))) = watcher.next(Duration::from_secs(10)).await {
            if m.is_final {
                break m;
            }
            seen.push(m);
        }
    };
    assert_eq!(replayed_final, metrics_message(&recorded, true));
    // Non-decreasing as the replay plays on.
    assert!(
        seen.windows(2)
            .all(|w| w[0].ticks <= w[1].ticks && w[0].pushes <= w[1].pushes)
    );
    replay.shutdown().await;
    let _ = std::fs::remove_dir_all(&dir);
}

/// The next `metrics` message; panics when none comes within 30 s (the other messages, a
/// paused replay's status among them, go on coming), saying what came instead.
async fn next_metrics(viewer: &mut Viewer, after: &str) -> softhaptic_proto::wire::MetricsMessage {
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut seen: Vec<String> = Vec::new();
    loop {
        assert!(
            Instant::now() < deadline,
            "no metrics message after {after}; came instead: {seen:?}"
        );
        match viewer.next(Duration::from_secs(10)).await {
            Some(Ok(ServerMessage::Metrics(m))) => return m,
            Some(Ok(other)) => seen.push(other.type_name().to_owned()),
            Some(Err(e)) => seen.push(format!("undecodable: {e}")),
            None => {
                panic!("the connection closed waiting for metrics after {after}; came: {seen:?}")
            }
        }
    }
}

/// A shipped recording of `tests/sessions/`.
fn shipped(name: &str) -> Recording {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("sessions")
        .join(name);
    Recording::open(&path).unwrap()
}

/// Makes the recording's scene say `[haptics] safe_force_n = <value>` (TOML text, as written),
/// which is where `info`, `export` and `replay` read the safe force from.
fn set_recorded_safe_force(r: &mut Recording, value: &str) {
    let others: Vec<&str> = r
        .scene
        .scene_toml
        .lines()
        .filter(|l| !l.trim_start().starts_with("safe_force_n"))
        .collect();
    let mut text = others.join("\n");
    let line = format!("safe_force_n = {value}");
    if text.contains("[haptics]") {
        text = text.replacen("[haptics]", &format!("[haptics]\n{line}"), 1);
    } else {
        text.push_str(&format!("\n[haptics]\n{line}\n"));
    }
    r.scene.scene_toml = text;
}

#[test]
fn a_whole_number_safe_force_in_a_recorded_scene_is_the_one_counted_against() {
    let mut r = shipped("sphere-press.mcap");
    let default = recording_metrics(&r);
    assert_eq!(default.safe_force_n, 2.0);
    // The recorded scene says `safe_force_n = 1`, as a person writes it: a TOML integer.
    set_recorded_safe_force(&mut r, "1");
    assert_eq!(recorded_safe_force_n(&r), 1.0);
    let m = recording_metrics(&r);
    assert_eq!(m.safe_force_n, 1.0);
    // The press goes above 1 N for longer than above 2 N.
    assert!(
        m.time_above_safe_s > default.time_above_safe_s,
        "{} vs {}",
        m.time_above_safe_s,
        default.time_above_safe_s
    );
    let info = Info::of(&r);
    assert_eq!(info.metrics.safe_force_n, 1.0);
    assert!(info.to_string().contains("above the safe 1.00 N"), "{info}");
    let dir = scratch_dir("whole-safe-force");
    let json = export(&r, &dir, true).unwrap().metrics;
    let exported: softhaptic_proto::wire::MetricsMessage =
        serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap();
    assert_eq!(exported.safe_force_n, 1.0);
    assert_eq!(exported, metrics_message(&m, true));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn info_prints_the_fault_ticks_and_flags_raised_of_a_press_held_through_a_fault_as_one_push() {
    let r = shipped("fault-mid-press.mcap");
    let m = recording_metrics(&r);
    assert_eq!(m.pushes, 1, "{m:?}");
    let text = Info::of(&r).to_string();
    let line = text
        .lines()
        .find(|l| l.starts_with("trainee metrics:"))
        .unwrap();
    assert!(line.contains("; 1 push;"), "{line}");
    assert!(
        line.contains(&format!("; {} device fault ticks;", m.device_fault_ticks))
            && m.device_fault_ticks > 0,
        "{line}"
    );
    assert!(line.contains("flags raised: device_fault ×1"), "{line}");
    assert!(text.contains("\nmarks:             none\n"), "{text}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_last_metrics_a_viewer_gets_before_the_close_are_the_final_ones_recorded() {
    let scene = Scene::builtin_default().unwrap();
    let dir = scratch_dir("final-metrics");
    let session = start_recorded(scene, &dir, test_options()).await;
    let mut viewer = Viewer::connect(session.server.local_addr()).await;
    // The viewer is served: it has had the 1 Hz metrics once.
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        assert!(Instant::now() < deadline, "no metrics");
        if let Some(Ok(ServerMessage::Metrics(_))) = viewer.next(Duration::from_secs(10)).await {
            break;
        }
    }
    // The server stops while the viewer reads on, to the close.
    let finish = tokio::spawn(session.finish());
    let (close, texts) = viewer.until_closed(Duration::from_secs(60)).await;
    assert_eq!(close.map(|c| c.0), Some(1001), "{texts:?}");
    let (_, final_live, path, _) = finish.await.unwrap();
    let last = texts
        .iter()
        .rev()
        .find_map(|t| match ServerMessage::decode(t) {
            Ok(ServerMessage::Metrics(m)) => Some(m),
            _ => None,
        })
        .expect("metrics before the close");
    assert!(last.is_final, "{last:?}");
    assert_eq!(last, metrics_message(&final_live, true));
    let r = Recording::open(&path).unwrap();
    assert_eq!(r.final_metrics(), Some(&last));
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_seek_sends_the_metrics_of_the_new_position() {
    let r = shipped("slide.mcap");
    let timeline: Vec<(u64, softhaptic_proto::wire::MetricsMessage)> = replay::metrics_timeline(&r)
        .into_iter()
        .map(|m| match ServerMessage::decode(&m.json).unwrap() {
            ServerMessage::Metrics(metrics) => (m.time_ns, metrics),
            other => panic!("{other:?}"),
        })
        .collect();
    assert!(timeline.len() >= 3, "{timeline:?}");
    let start_ns = r.contacts[0].time_ns;
    let replay = replay::start(r.clone(), softhaptic_tests::replay_options(1.0, true))
        .await
        .unwrap();
    let mut watcher = Viewer::connect(replay.local_addr()).await;
    assert!(matches!(
        watcher.expect_message(Duration::from_secs(10)).await,
        ServerMessage::Hello(_)
    ));
    // Paused, a seek sends the metrics at or before the new position, and nothing plays on.
    let seek = |time_s: f64| {
        serde_json::json!({"type": "replay_control", "action": "seek", "time_s": time_s})
            .to_string()
    };
    for time_s in [2.5, 0.2, 1.5] {
        watcher.send_text(&seek(time_s)).await;
        let got = next_metrics(&mut watcher, &format!("a seek to {time_s} s")).await;
        let t = start_ns + (time_s * 1e9) as u64;
        match timeline.iter().rev().find(|(at, _)| *at <= t) {
            Some((_, expected)) => assert_eq!(&got, expected, "at {time_s} s"),
            // Before the first second's: none yet, all zero.
            None => {
                assert_eq!(
                    (got.ticks, got.pushes, got.is_final),
                    (0, 0, false),
                    "{got:?}"
                );
                assert_eq!(got.peak_force_n, 0.0);
            }
        }
    }
    replay.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_replay_marks_where_the_recorded_ticks_pushed_harder_than_the_safe_force() {
    // A 1 N safe force, which the recorded press exceeds for most of its hold.
    let mut r = shipped("sphere-press.mcap");
    set_recorded_safe_force(&mut r, "1.0");
    let safe_force_n = 1.0;
    assert_eq!(recorded_safe_force_n(&r), safe_force_n);

    // The stretches from the recorded 1 kHz ticks: each run of consecutive records with
    // |F| > 1 N, from its first tick to its last, in seconds from the first contact frame
    // (replay time 0).
    let start_ns = r.contacts[0].time_ns;
    let seconds = |t: u64| t.saturating_sub(start_ns) as f64 * 1e-9;
    let mut expected: Vec<(f64, f64)> = Vec::new();
    // And the time above the safe force the metrics count over those runs: each tick above it
    // counts the device time since the tick before.
    let mut time_above_s = 0.0;
    let mut run: Option<(u64, u64)> = None;
    for (i, d) in r.device.iter().enumerate() {
        let above = glam::DVec3::from_array(d.force_n).length() > safe_force_n;
        if above {
            run = Some((run.map_or(d.time_ns, |(first, _)| first), d.time_ns));
            if i > 0 {
                time_above_s += (d.time_ns - r.device[i - 1].time_ns) as f64 * 1e-9;
            }
        } else if let Some((first, last)) = run.take() {
            expected.push((seconds(first), seconds(last)));
        }
    }
    if let Some((first, last)) = run {
        expected.push((seconds(first), seconds(last)));
    }
    // The press holds above 1 N for more than a second (and crosses it twice on the way up,
    // a one-tick stretch first: a single tick is marked too).
    assert!(
        expected.iter().any(|(a, b)| b - a > 1.0),
        "the recording should push above 1 N for more than a second: {expected:?}"
    );
    let metrics = recording_metrics(&r);
    assert!(
        (metrics.time_above_safe_s - time_above_s).abs() < 1e-9,
        "the metrics count {} s above the safe force, the ticks {time_above_s} s",
        metrics.time_above_safe_s
    );

    // What a viewer of the replay is told to mark on its timeline.
    let replay = replay::start(r.clone(), softhaptic_tests::replay_options(1.0, true))
        .await
        .unwrap();
    let mut watcher = Viewer::connect(replay.local_addr()).await;
    let deadline = Instant::now() + Duration::from_secs(30);
    let status = loop {
        assert!(Instant::now() < deadline, "no replay status");
        if let Some(Ok(ServerMessage::Replay(s))) = watcher.next(Duration::from_secs(10)).await {
            break s;
        }
    };
    replay.shutdown().await;
    let marked: Vec<(f64, f64)> = status
        .above_safe
        .iter()
        .map(|s| (s.start_s, s.end_s))
        .collect();
    // To the nanosecond (the ticks are a millisecond apart; the JSON number may round).
    assert_eq!(
        marked.len(),
        expected.len(),
        "marked {marked:?}, ticks {expected:?}"
    );
    for (m, e) in marked.iter().zip(&expected) {
        assert!(
            (m.0 - e.0).abs() < 1e-9 && (m.1 - e.1).abs() < 1e-9,
            "marked {marked:?}, ticks {expected:?}"
        );
    }
    // Within the recording's timeline.
    assert!(
        marked
            .iter()
            .all(|(a, b)| 0.0 <= *a && a <= b && *b <= status.duration_s + 1e-9)
    );
}
