//! Instructor marks: an instructor's note (and point on the organ) reaches every viewer at once
//! and every later one as it connects; an observer's, or one sent to a replay, is refused; the
//! marks are recorded, and a replay of the recording shows them and puts them on its timeline.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::time::{Duration, Instant};

use futures_util::StreamExt;
use softhaptic_proto::wire::ReplayStatus;
use softhaptic_proto::wire::{MarkMessage, ServerMessage};
use softhaptic_server::access::AccessConfig;
use softhaptic_server::app::default_web_dir;
use softhaptic_server::scene::Scene;
use softhaptic_server::session::reader::Recording;
use softhaptic_server::session::replay::{self, ReplayOptions};
use softhaptic_server::stream::{REFUSED_MARK_OBSERVER, REFUSED_MARK_REPLAY, ViewerLimits};
use softhaptic_tests::{Viewer, scratch_dir, start_recorded, test_options};
use tokio_tungstenite::tungstenite::Message;

const I: &str = softhaptic_tests::INSTRUCTOR_TOKEN;
const O: &str = softhaptic_tests::OBSERVER_TOKEN;

/// The next message of `kind` (raw text), skipping frames and stats.
async fn next_of(viewer: &mut Viewer, kind: &str) -> String {
    let prefix = format!(r#"{{"type":"{kind}""#);
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        assert!(Instant::now() < deadline, "no {kind} message");
        let next = tokio::time::timeout(Duration::from_secs(10), viewer.socket.next()).await;
        if let Ok(Some(Ok(Message::Text(t)))) = next
            && t.starts_with(&prefix)
        {
            return t.to_string();
        }
    }
}

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
    next_of(&mut observer, "contact").await;
    next_of(&mut instructor, "contact").await;
    instructor
        .send_text(r#"{"type":"add_mark","note":"  too fast on the approach ","point_m":[0.01,0.02,0.03]}"#)
        .await;
    let seen = mark_of(&next_of(&mut observer, "mark").await);
    assert_eq!(seen.id, 1);
    assert_eq!(seen.note, "too fast on the approach");
    assert_eq!(seen.point_m, Some([0.01, 0.02, 0.03]));
    assert!(seen.time_ns > 0);
    assert_eq!(mark_of(&next_of(&mut instructor, "mark").await), seen);

    // An observer may not mark; nor may anyone with an empty note.
    observer
        .send_text(r#"{"type":"add_mark","note":"me too"}"#)
        .await;
    let refused = next_of(&mut observer, "refused").await;
    assert!(refused.contains(REFUSED_MARK_OBSERVER), "{refused}");
    instructor
        .send_text(r#"{"type":"add_mark","note":"   "}"#)
        .await;
    let refused = next_of(&mut instructor, "refused").await;
    assert!(refused.contains("needs a note"), "{refused}");

    // A viewer that comes later gets the mark as it connects.
    let mut late = viewer(server.local_addr(), O).await;
    assert_eq!(mark_of(&next_of(&mut late, "mark").await), seen);

    let (_, _, path, _) = live.finish().await;
    let r = Recording::open(&path).unwrap();
    assert_eq!(r.marks, vec![seen.clone()]);

    // The replay shows it to its viewers and on its timeline; it takes no new marks.
    let replay = replay::start(
        r,
        ReplayOptions {
            addr: ([127, 0, 0, 1], 0).into(),
            web_dir: default_web_dir(),
            speed: 1.0,
            start_paused: true,
            viewer_limits: ViewerLimits::default(),
            access: AccessConfig::default(),
            tls: None,
        },
    )
    .await
    .unwrap();
    let mut watcher = Viewer::connect(replay.local_addr()).await;
    assert_eq!(mark_of(&next_of(&mut watcher, "mark").await), seen);
    let status: ReplayStatus =
        serde_json::from_str(&next_of(&mut watcher, "replay").await).unwrap();
    assert_eq!(status.marks.len(), 1);
    assert_eq!(status.marks[0].note, seen.note);
    assert!(status.marks[0].time_s >= 0.0 && status.marks[0].time_s <= status.duration_s + 1.0);
    watcher
        .send_text(r#"{"type":"add_mark","note":"later"}"#)
        .await;
    let refused = next_of(&mut watcher, "refused").await;
    assert!(refused.contains(REFUSED_MARK_REPLAY), "{refused}");
    replay.shutdown().await;
    let _ = std::fs::remove_dir_all(&dir);
}
