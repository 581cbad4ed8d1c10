//! Instructor marks: an instructor's note (and point on the organ) reaches every viewer at once
//! and every later one as it connects; an observer's, one sent to a replay, one sent through a
//! lab hub, or one past the session's cap is refused; the marks are recorded, `info` prints them and `export` writes them,
//! and a replay of the recording shows them and puts them on its timeline.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::time::Duration;

use softhaptic_proto::wire::ReplayStatus;
use softhaptic_proto::wire::{MarkMessage, ServerMessage};
use softhaptic_server::scene::Scene;
use softhaptic_server::session::reader::Recording;
use softhaptic_server::session::replay;
use softhaptic_server::session::tools::{Info, export};
use softhaptic_server::stream::{
    MAX_MARKS, REFUSED_MARK_HUB, REFUSED_MARK_OBSERVER, REFUSED_MARK_REPLAY, REFUSED_MARKS_FULL,
};
use softhaptic_tests::{Viewer, scratch_dir, start_recorded, test_options};

const I: &str = softhaptic_tests::INSTRUCTOR_TOKEN;
const O: &str = softhaptic_tests::OBSERVER_TOKEN;

async fn viewer(addr: std::net::SocketAddr, token: &str) -> Viewer {
    let mut v = Viewer::connect(addr).await;
    v.authenticate(token).await;
    v
}

fn mark_of(text: &str) -> MarkMessage {
    match ServerMessage::decode(text).unwrap() {
        ServerMessage::Mark(m) => m,
        other => panic!("{other:?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_mark_reaches_every_viewer_is_recorded_and_replayed() {
    let scene = Scene::builtin_default().unwrap();
    let dir = scratch_dir("marks");
    let mut options = test_options();
    options.access.tokens = Some(softhaptic_tests::test_tokens());
    let live = start_recorded(scene, &dir, options).await;
    let server = &live.server;

    let mut instructor = viewer(server.local_addr(), I).await;
    let mut observer = viewer(server.local_addr(), O).await;
    // Both see frames first (the session runs), then the instructor marks it.
    observer.next_of("contact").await;
    instructor.next_of("contact").await;
    instructor
        .send_text(r#"{"type":"add_mark","note":"  too fast on the approach ","point_m":[0.01,0.02,0.03]}"#)
        .await;
    let seen = mark_of(&observer.next_of("mark").await);
    assert_eq!(seen.id, 1);
    assert_eq!(seen.note, "too fast on the approach");
    assert_eq!(seen.point_m, Some([0.01, 0.02, 0.03]));
    assert!(seen.time_ns > 0);
    assert_eq!(mark_of(&instructor.next_of("mark").await), seen);

    // An observer may not mark; nor may anyone with an empty note.
    observer
        .send_text(r#"{"type":"add_mark","note":"me too"}"#)
        .await;
    let refused = observer.next_of("refused").await;
    assert!(refused.contains(REFUSED_MARK_OBSERVER), "{refused}");
    instructor
        .send_text(r#"{"type":"add_mark","note":"   "}"#)
        .await;
    let refused = instructor.next_of("refused").await;
    assert!(refused.contains("needs a note"), "{refused}");

    // A viewer that comes later gets the mark as it connects.
    let mut late = viewer(server.local_addr(), O).await;
    assert_eq!(mark_of(&late.next_of("mark").await), seen);

    let (_, _, path, _) = live.finish().await;
    let r = Recording::open(&path).unwrap();
    assert_eq!(r.marks, vec![seen.clone()]);

    // `info` prints it (time from the first tick, point, note); `export` writes marks.json.
    let info = Info::of(&r).to_string();
    assert!(info.contains("\nmarks:             1\n"), "{info}");
    let time_s = (seen.time_ns - r.device[0].time_ns) as f64 * 1e-9;
    assert!(
        info.contains(&format!(
            "  #1 at {time_s:.3} s at (10.0, 20.0, 30.0) mm: too fast on the approach\n"
        )),
        "{info}"
    );
    let written = export(&r, &dir.join("export"), false).unwrap();
    let exported: Vec<MarkMessage> =
        serde_json::from_str(&std::fs::read_to_string(&written.marks).unwrap()).unwrap();
    assert_eq!(exported, vec![seen.clone()]);
    assert_eq!(written.marks.parent(), written.metrics.parent());

    // The replay shows it to its viewers and on its timeline; it takes no new marks.
    let replay = replay::start(r, softhaptic_tests::replay_options(1.0, true))
        .await
        .unwrap();
    let mut watcher = Viewer::connect(replay.local_addr()).await;
    assert_eq!(mark_of(&watcher.next_of("mark").await), seen);
    let status: ReplayStatus = serde_json::from_str(&watcher.next_of("replay").await).unwrap();
    assert_eq!(status.marks.len(), 1);
    assert_eq!(status.marks[0].note, seen.note);
    assert!(status.marks[0].time_s >= 0.0 && status.marks[0].time_s <= status.duration_s + 1.0);
    watcher
        .send_text(r#"{"type":"add_mark","note":"later"}"#)
        .await;
    let refused = watcher.next_of("refused").await;
    assert!(refused.contains(REFUSED_MARK_REPLAY), "{refused}");
    replay.shutdown().await;
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lab_hub_says_it_takes_no_marks_and_refuses_an_instructors() {
    use softhaptic_tests::nats::{NatsServer, options, start_hub, start_station};
    let nats = NatsServer::start("hub-marks");
    let station = start_station("desk-m", options(nats.url())).await.unwrap();
    let hub = start_hub(options(nats.url()), true).await;
    softhaptic_tests::wait_until("the station listed", || {
        hub.stations()
            .iter()
            .any(|s| s.name == "desk-m" && s.state != "offline")
    })
    .await;
    let mut relayed =
        Viewer::connect_url(&format!("ws://{}/ws?station=desk-m", hub.local_addr())).await;
    relayed.authenticate(I).await;
    match relayed.expect_message(Duration::from_secs(10)).await {
        ServerMessage::Hello(h) => {
            assert_eq!(h.role, softhaptic_proto::wire::Role::Instructor);
            assert!(!h.accepts_marks, "{h:?}");
        }
        other => panic!("expected hello, got {other:?}"),
    }
    // The station's own viewers are told it takes marks.
    let own = ServerMessage::decode(
        station
            .hub()
            .hello(softhaptic_proto::wire::Role::Instructor)
            .as_str(),
    )
    .unwrap();
    assert!(matches!(own, ServerMessage::Hello(h) if h.accepts_marks));

    relayed.next_of("contact").await;
    relayed
        .send_text(r#"{"type":"add_mark","note":"through the hub"}"#)
        .await;
    let refused = relayed.next_of("refused").await;
    assert!(refused.contains(REFUSED_MARK_HUB), "{refused}");
    // The connection stays open, and no mark was made anywhere.
    relayed.next_of("contact").await;
    assert!(station.hub().made_marks().is_empty());
    hub.shutdown().await;
    station.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_mark_past_the_sessions_cap_is_refused_and_not_kept() {
    let mut options = test_options();
    // A rate that lets one link send every mark at once.
    options.access.limits.messages_per_s = 1e6;
    options.access.limits.message_burst = 1e6;
    let server = softhaptic_tests::start_default(options).await;
    let mut instructor = Viewer::connect(server.local_addr()).await;
    instructor.next_of("contact").await;
    for n in 1..=MAX_MARKS + 1 {
        instructor
            .send_text(&format!(r#"{{"type":"add_mark","note":"mark {n}"}}"#))
            .await;
    }
    let refused = instructor.next_of("refused").await;
    assert!(refused.contains(REFUSED_MARKS_FULL), "{refused}");
    let kept = server.hub().made_marks();
    assert_eq!(kept.len(), MAX_MARKS);
    assert_eq!(
        mark_of(&kept[MAX_MARKS - 1]).note,
        format!("mark {MAX_MARKS}")
    );
    server.shutdown().await;
}
