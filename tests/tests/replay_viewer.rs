//! A recording replayed to a real WebSocket client: the same hello and scene as live, then the
//! recorded contact frames in order; pause, seek and play from the viewer; invalid controls close
//! only that connection.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::net::SocketAddr;
use std::path::Path;
use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use softhaptic_proto::wire::ReplayStatus;
use softhaptic_proto::wire::{ContactFrame, ServerMessage};
use softhaptic_server::session::reader::Recording;
use softhaptic_server::session::replay::{self, ReplayOptions};
use softhaptic_server::stream::ViewerLimits;
use tokio_tungstenite::tungstenite::Message;

const WAIT: Duration = Duration::from_secs(10);

type Socket =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// What the replay sends: a wire message, or the replay's own status.
#[derive(Debug)]
enum Received {
    Wire(ServerMessage),
    Status(ReplayStatus),
    Closed,
}

async fn receive(socket: &mut Socket) -> Received {
    loop {
        let m = tokio::time::timeout(WAIT, socket.next())
            .await
            .expect("a message within the timeout");
        match m {
            Some(Ok(Message::Text(text))) => {
                if text.contains(r#""type":"replay""#) {
                    return Received::Status(serde_json::from_str(&text).expect("replay status"));
                }
                return Received::Wire(ServerMessage::decode(&text).expect("a wire message"));
            }
            Some(Ok(Message::Close(_))) | None | Some(Err(_)) => return Received::Closed,
            Some(Ok(_)) => continue,
        }
    }
}

async fn next_frame(socket: &mut Socket) -> ContactFrame {
    loop {
        match receive(socket).await {
            Received::Wire(ServerMessage::Contact(f)) => return f,
            Received::Closed => panic!("closed while waiting for a frame"),
            _ => continue,
        }
    }
}

async fn next_status(socket: &mut Socket) -> ReplayStatus {
    loop {
        match receive(socket).await {
            Received::Status(s) => return s,
            Received::Closed => panic!("closed while waiting for a status"),
            _ => continue,
        }
    }
}

fn recording() -> Recording {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("sessions")
        .join("sphere-press.mcap");
    Recording::open(&path).expect("the test recording reads")
}

/// Every field but the renumbered `seq` and the per-viewer `dropped`.
fn same_content(a: &ContactFrame, b: &ContactFrame) -> bool {
    ContactFrame {
        seq: 0,
        dropped: 0,
        ..*a
    } == ContactFrame {
        seq: 0,
        dropped: 0,
        ..*b
    }
}

fn recorded_frames(r: &Recording) -> Vec<ContactFrame> {
    r.contacts
        .iter()
        .map(|c| match ServerMessage::decode(&c.json).unwrap() {
            ServerMessage::Contact(f) => f,
            other => panic!("{other:?}"),
        })
        .collect()
}

async fn start(speed: f64, paused: bool) -> (replay::RunningReplay, SocketAddr) {
    let addr: SocketAddr = ([127, 0, 0, 1], 0).into();
    let replay = replay::start(
        recording(),
        ReplayOptions {
            addr,
            viewer: Default::default(),
            speed,
            start_paused: paused,
            viewer_limits: ViewerLimits::default(),
            access: Default::default(),
            tls: None,
        },
    )
    .await
    .expect("the replay starts");
    let addr = replay.local_addr();
    (replay, addr)
}

async fn connect(addr: SocketAddr) -> Socket {
    tokio_tungstenite::connect_async(format!("ws://{addr}/ws"))
        .await
        .expect("WebSocket connects")
        .0
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replay_sends_hello_scene_and_the_recorded_frames_in_order() {
    let r = recording();
    let recorded = recorded_frames(&r);
    let (replay, addr) = start(2.0, false).await;
    let mut socket = connect(addr).await;

    let Received::Wire(ServerMessage::Hello(hello)) = receive(&mut socket).await else {
        panic!("hello first")
    };
    assert_eq!(hello.session_id, r.build.session_id);
    assert_eq!(hello.role, softhaptic_proto::wire::Role::Instructor);
    assert_eq!(hello.mode, softhaptic_proto::wire::Mode::Replay);
    let Received::Wire(ServerMessage::Scene(scene)) = receive(&mut socket).await else {
        panic!("scene second")
    };
    assert_eq!(*scene, r.scene.message);

    // 40 frames, each identical to a recorded one, in the recorded order, numbered +1 each. (A
    // player that stalls skips to the newest frames, as the live stream does, so the recorded
    // indices increase but may jump.)
    let first = next_frame(&mut socket).await;
    let mut index = recorded
        .iter()
        .position(|f| same_content(f, &first))
        .expect("the first frame is a recorded one");
    let mut previous_seq = first.seq;
    for _ in 0..40 {
        let f = next_frame(&mut socket).await;
        let at = recorded[index + 1..]
            .iter()
            .position(|x| same_content(x, &f))
            .map(|k| index + 1 + k)
            .unwrap_or_else(|| panic!("frame {f:?} is not a recorded frame after {index}"));
        index = at;
        assert_eq!(f.seq, previous_seq + 1);
        previous_seq = f.seq;
    }
    let status = next_status(&mut socket).await;
    // Playing, unless a player stalled by a loaded machine skipped to the end, where it pauses.
    assert!(
        !status.paused || status.time_s >= status.duration_s - 0.05,
        "{status:?}"
    );
    assert_eq!(status.speed, 2.0);
    // The same HTTP routes as live: the scene and the render mesh it names.
    let (code, body) = softhaptic_tests::http_get(addr, "/api/scene").await;
    assert_eq!(code, 200);
    // The very text of the WebSocket `scene` message, as a live server serves it.
    let ServerMessage::Scene(served) =
        ServerMessage::decode(std::str::from_utf8(&body).unwrap()).unwrap()
    else {
        panic!("/api/scene is a scene message")
    };
    assert_eq!(*served, r.scene.message);
    let (code, mesh) = softhaptic_tests::http_get(addr, &served.render_meshes[0].url).await;
    assert_eq!(code, 200);
    assert_eq!(&mesh[..4], b"SHM1");
    let vertex_count = u32::from_le_bytes(mesh[4..8].try_into().unwrap());
    assert_eq!(vertex_count, served.render_meshes[0].vertex_count);
    assert_eq!(status.file, "sphere-press.mcap");
    assert!((status.duration_s - 2.98).abs() < 0.05, "{status:?}");
    replay.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn viewer_pauses_seeks_and_plays() {
    let r = recording();
    let recorded = recorded_frames(&r);
    let (replay, addr) = start(1.0, true).await;
    let mut socket = connect(addr).await;

    // Paused from the start: the status says so, at time 0.
    let status = next_status(&mut socket).await;
    assert!(status.paused && status.time_s == 0.0, "{status:?}");

    // Seek to 1.5 s: the frame in effect there comes at once, and the status follows.
    socket
        .send(Message::text(
            r#"{"type":"replay_control","action":"seek","time_s":1.5}"#,
        ))
        .await
        .unwrap();
    let f = next_frame(&mut socket).await;
    let at = recorded.iter().position(|x| same_content(x, &f)).unwrap();
    let t0 = recorded[0].time_ns;
    assert!(recorded[at].time_ns - t0 <= 1_500_000_000);
    assert!(recorded[at + 1].time_ns - t0 > 1_500_000_000);
    let status = next_status(&mut socket).await;
    assert!(
        status.paused && (status.time_s - 1.5).abs() < 1e-9,
        "{status:?}"
    );

    // Play at 4×: frames continue from there.
    socket
        .send(Message::text(
            r#"{"type":"replay_control","action":"play","speed":4.0}"#,
        ))
        .await
        .unwrap();
    let status = next_status(&mut socket).await;
    assert!(!status.paused && status.speed == 4.0, "{status:?}");
    let next = next_frame(&mut socket).await;
    let next_at = recorded
        .iter()
        .position(|x| same_content(x, &next))
        .unwrap();
    assert!(
        next_at > at,
        "playing continues after the seek: {next_at} <= {at}"
    );

    // Pause: the status stops the clock.
    socket
        .send(Message::text(
            r#"{"type":"replay_control","action":"pause"}"#,
        ))
        .await
        .unwrap();
    let status = loop {
        let s = next_status(&mut socket).await;
        if s.paused {
            break s;
        }
    };
    assert!(status.time_s > 1.5, "{status:?}");

    // A seek without a time is invalid: this connection is closed, the replay goes on.
    socket
        .send(Message::text(
            r#"{"type":"replay_control","action":"seek"}"#,
        ))
        .await
        .unwrap();
    loop {
        if let Received::Closed = receive(&mut socket).await {
            break;
        }
    }
    let mut other = connect(addr).await;
    assert!(matches!(
        receive(&mut other).await,
        Received::Wire(ServerMessage::Hello(_))
    ));
    assert_eq!(
        replay
            .counters()
            .malformed_closes
            .load(std::sync::atomic::Ordering::Relaxed),
        1
    );
    replay.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_viewer_of_a_paused_replay_is_shown_the_recording_s_first_frame() {
    let r = recording();
    let frames = recorded_frames(&r);
    let (replay, addr) = start(1.0, true).await;
    let mut viewer = connect(addr).await;
    // Right after hello and scene: the tool where the session began, not at the origin.
    let shown = next_frame(&mut viewer).await;
    assert!(same_content(&shown, &frames[0]), "{shown:?}");
    // Paused, nothing else comes but statuses.
    let status = next_status(&mut viewer).await;
    assert!(status.paused && status.time_s == 0.0, "{status:?}");
    replay.shutdown().await;
}
