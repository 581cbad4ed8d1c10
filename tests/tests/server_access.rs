//! Who may connect, against the real server (the library's `start` on 127.0.0.1:0 with the real
//! loop and simulated device, or a recording's replay) and real WebSocket and HTTP clients:
//! tokens and roles, refusals on an open connection, the Origin and Host rules, the connection
//! limits and the message rate, the security headers; and a well-behaved viewer that keeps its
//! 50 Hz through a flood and through a storm of every refusal at once. The real binary's
//! refusals (no tokens beyond loopback, token sources), their log lines, and the absence of
//! tokens from its logs and recordings are in `server/tests/access_cli.rs`.
//!
//! Long because each of its 12 tests starts a real server; they share its token and viewer helpers.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::net::{IpAddr, SocketAddr};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use base64::Engine;
use futures_util::{SinkExt, StreamExt};
use sha2::{Digest, Sha256};
use softhaptic_proto::wire::ReplayStatus;
use softhaptic_proto::wire::{Hello, Mode, Refused, Role, ServerMessage};
use softhaptic_server::access::{AccessConfig, Origin, Token, TokenSource, Tokens};
use softhaptic_server::app::ServerOptions;
use softhaptic_server::session::reader::Recording;
use softhaptic_server::session::replay::{self, ReplayOptions};
use softhaptic_server::stream::{REFUSED_LIVE, REFUSED_OBSERVER, ViewerLimits};
use softhaptic_tests::{Viewer, http_request, start_default, test_options};
use tokio_tungstenite::tungstenite::Message;

const WAIT: Duration = Duration::from_secs(10);
/// The instructor's and the observer's tokens of these tests.
const I: &str = "1f0e2d3c4b5a69788796a5b4c3d2e1f0";
const O: &str = "00112233445566778899aabbccddeeff";

fn tokens() -> Arc<Tokens> {
    Arc::new(
        Tokens::new(
            Token::parse(I, Role::Instructor).unwrap(),
            Token::parse(O, Role::Observer).unwrap(),
            TokenSource::Environment,
        )
        .unwrap(),
    )
}

/// The test server's options with the tokens above.
fn with_tokens() -> ServerOptions {
    let mut options = test_options();
    options.access.tokens = Some(tokens());
    options
}

/// The `hello` and `scene` a viewer gets first; the `hello`'s fields.
async fn greeting(viewer: &mut Viewer) -> Hello {
    let ServerMessage::Hello(hello) = viewer.expect_message(WAIT).await else {
        panic!("hello first")
    };
    assert!(matches!(
        viewer.expect_message(WAIT).await,
        ServerMessage::Scene(_)
    ));
    hello
}

/// The next contact frame's `seq`, past stats.
async fn next_seq(viewer: &mut Viewer) -> u64 {
    loop {
        match viewer.expect_message(WAIT).await {
            ServerMessage::Contact(f) => return f.seq,
            ServerMessage::Stats(_) | ServerMessage::Metrics(_) => continue,
            other => panic!("expected a contact frame, got {other:?}"),
        }
    }
}

/// The next `refused`, past frames and stats.
async fn next_refused(viewer: &mut Viewer) -> Refused {
    loop {
        match viewer.expect_message(WAIT).await {
            ServerMessage::Refused(r) => return r,
            ServerMessage::Contact(_) | ServerMessage::Stats(_) | ServerMessage::Metrics(_) => {
                continue;
            }
            other => panic!("expected refused, got {other:?}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_viewer_that_presents_no_token_is_sent_nothing_and_closed_with_4401() {
    let mut options = with_tokens();
    options.access.limits.auth_timeout = Duration::from_millis(500);
    let server = start_default(options).await;
    let addr = server.local_addr();

    // Silent: after the auth timeout, closed; nothing was streamed to it.
    let mut silent = Viewer::connect_with(addr, None, None, None).await.unwrap();
    let (close, texts) = silent.until_closed(WAIT).await;
    assert_eq!(close, Some((4401, "no token presented".to_owned())));
    assert!(texts.is_empty(), "sent before a token: {texts:?}");

    // A first message that is not an `auth` with a token: the same, at once.
    for first in [
        r#"{"type":"replay_control","action":"pause"}"#,
        r#"{"type":"auth","token":42}"#,
        r#"{"type":"auth"}"#,
        "not json",
    ] {
        let mut eager = Viewer::connect_with(addr, None, None, None).await.unwrap();
        eager.send_text(first).await;
        let (close, texts) = eager.until_closed(WAIT).await;
        assert_eq!(
            close,
            Some((4401, "no token presented".to_owned())),
            "{first}"
        );
        assert!(texts.is_empty(), "{first}: {texts:?}");
    }
    let counters = server.counters();
    assert_eq!(counters.unauthorized_closes.load(Ordering::Relaxed), 5);
    assert_eq!(counters.viewers.load(Ordering::Relaxed), 0);
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_wrong_token_is_closed_with_4401_token_not_valid_for_this_server() {
    let server = start_default(with_tokens()).await;
    let addr = server.local_addr();
    let reversed: String = I.chars().rev().collect();
    for wrong in [reversed.as_str(), &I[..31], "", "instructor"] {
        let mut viewer = Viewer::connect_with(addr, None, None, Some(wrong))
            .await
            .unwrap();
        let (close, texts) = viewer.until_closed(WAIT).await;
        assert_eq!(
            close,
            Some((4401, "token not valid for this server".to_owned())),
            "{wrong:?}"
        );
        assert!(texts.is_empty(), "{texts:?}");
    }
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn each_token_gets_its_role_in_hello_then_the_scene_and_the_stream() {
    let server = start_default(with_tokens()).await;
    let addr = server.local_addr();
    let own_origin = format!("http://{addr}");
    for (token, role, other) in [(I, Role::Instructor, O), (O, Role::Observer, I)] {
        let mut viewer = Viewer::connect_with(addr, Some(&own_origin), None, Some(token))
            .await
            .unwrap();
        let hello = greeting(&mut viewer).await;
        assert_eq!((hello.role, hello.mode), (role, Mode::Live));
        let first = next_seq(&mut viewer).await;
        // A later `auth` changes nothing: ignored, the stream goes on, the role stays.
        viewer.authenticate(other).await;
        let mut seq = first;
        for _ in 0..10 {
            let next = next_seq(&mut viewer).await;
            assert!(next > seq);
            seq = next;
        }
    }
    let counters = server.counters();
    assert_eq!(counters.unknown_messages.load(Ordering::Relaxed), 0);
    assert_eq!(counters.refused_requests.load(Ordering::Relaxed), 0);
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replay_control_sent_to_a_live_server_is_refused_and_the_connection_stays_open() {
    let server = start_default(with_tokens()).await;
    let addr = server.local_addr();
    for token in [I, O] {
        let mut viewer = Viewer::connect_with(addr, None, None, Some(token))
            .await
            .unwrap();
        greeting(&mut viewer).await;
        viewer
            .send_text(r#"{"type":"replay_control","action":"pause"}"#)
            .await;
        let refused = next_refused(&mut viewer).await;
        assert_eq!(refused.request, "replay_control");
        assert_eq!(refused.reason, REFUSED_LIVE);
        let a = next_seq(&mut viewer).await;
        let b = next_seq(&mut viewer).await;
        assert!(b > a, "the stream goes on after the refusal");
    }
    assert_eq!(
        server.counters().refused_requests.load(Ordering::Relaxed),
        2
    );
    server.shutdown().await;
}

/// A replay server's text: a wire message, or the replay's status.
enum ReplayText {
    Wire(ServerMessage),
    Status(ReplayStatus),
}

async fn next_replay_text(viewer: &mut Viewer) -> ReplayText {
    loop {
        let message = tokio::time::timeout(WAIT, viewer.socket.next())
            .await
            .expect("a message within the timeout");
        match message {
            Some(Ok(Message::Text(text))) => {
                if text.contains(r#""type":"replay""#) {
                    return ReplayText::Status(serde_json::from_str(&text).unwrap());
                }
                return ReplayText::Wire(ServerMessage::decode(&text).unwrap());
            }
            Some(Ok(_)) => continue,
            other => panic!("the replay connection ended: {other:?}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn on_a_replay_an_observer_is_refused_and_sees_the_timeline_the_instructor_moves() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("sessions")
        .join("sphere-press.mcap");
    let replay = replay::start(
        Recording::open(&path).unwrap(),
        ReplayOptions {
            addr: ([127, 0, 0, 1], 0).into(),
            viewer: Default::default(),
            speed: 1.0,
            start_paused: true,
            viewer_limits: ViewerLimits::default(),
            access: AccessConfig {
                tokens: Some(tokens()),
                ..AccessConfig::default()
            },
            tls: None,
        },
    )
    .await
    .unwrap();
    let addr = replay.local_addr();
    let mut observer = Viewer::connect_with(addr, None, None, Some(O))
        .await
        .unwrap();
    let mut instructor = Viewer::connect_with(addr, None, None, Some(I))
        .await
        .unwrap();
    for (viewer, role) in [
        (&mut observer, Role::Observer),
        (&mut instructor, Role::Instructor),
    ] {
        let hello = greeting(viewer).await;
        assert_eq!((hello.role, hello.mode), (role, Mode::Replay));
    }

    // The observer's seek is refused, and the timeline does not move.
    observer
        .send_text(r#"{"type":"replay_control","action":"seek","time_s":2.5}"#)
        .await;
    loop {
        match next_replay_text(&mut observer).await {
            ReplayText::Wire(ServerMessage::Refused(r)) => {
                assert_eq!(r.request, "replay_control");
                assert_eq!(r.reason, REFUSED_OBSERVER);
                break;
            }
            ReplayText::Status(s) => assert_eq!(s.time_s, 0.0, "{s:?}"),
            ReplayText::Wire(_) => {}
        }
    }
    // The instructor's seek moves the shared timeline: the observer sees it (and never the
    // position it asked for).
    instructor
        .send_text(r#"{"type":"replay_control","action":"seek","time_s":1.5}"#)
        .await;
    loop {
        match next_replay_text(&mut observer).await {
            ReplayText::Status(s) if (s.time_s - 1.5).abs() < 1e-9 => {
                assert!(s.paused, "{s:?}");
                break;
            }
            ReplayText::Status(s) => assert_eq!(s.time_s, 0.0, "{s:?}"),
            ReplayText::Wire(ServerMessage::Refused(r)) => panic!("a second refusal: {r:?}"),
            ReplayText::Wire(_) => {}
        }
    }
    instructor
        .send_text(r#"{"type":"replay_control","action":"play"}"#)
        .await;
    loop {
        if let ReplayText::Status(s) = next_replay_text(&mut observer).await
            && !s.paused
        {
            assert!(s.time_s >= 1.5, "{s:?}");
            break;
        }
    }
    let counters = replay.counters();
    assert_eq!(counters.refused_requests.load(Ordering::Relaxed), 1);
    assert_eq!(counters.malformed_closes.load(Ordering::Relaxed), 0);
    replay.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_upgrade_from_a_foreign_origin_is_refused_with_403_and_the_own_or_an_allowed_one_is_served()
 {
    // The loopback quick start (no tokens) checks origins all the same.
    let mut options = test_options();
    options.access.allowed_origins = vec![Origin::parse("https://portal.example").unwrap()];
    let server = start_default(options).await;
    let addr = server.local_addr();
    let port = addr.port();
    for foreign in [
        "http://evil.example".to_owned(),
        format!("http://evil.example:{port}"),
        "http://127.0.0.1:1".to_owned(),
        format!("https://{addr}"),
        "null".to_owned(),
        "not an origin".to_owned(),
    ] {
        let refused = Viewer::connect_with(addr, Some(&foreign), None, None).await;
        assert_eq!(refused.err(), Some(403), "{foreign}");
    }
    let localhost = format!("localhost:{port}");
    for (origin, host) in [
        (Some(format!("http://{addr}")), None),
        (
            Some(format!("http://localhost:{port}")),
            Some(localhost.as_str()),
        ),
        (Some("https://portal.example".to_owned()), None),
        // Not a browser: the Origin rule does not apply (tokens guard such clients).
        (None, None),
    ] {
        let mut viewer = Viewer::connect_with(addr, origin.as_deref(), host, None)
            .await
            .unwrap_or_else(|status| panic!("{origin:?} refused with {status}"));
        let hello = greeting(&mut viewer).await;
        assert_eq!(hello.role, Role::Instructor);
    }
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_request_naming_another_host_is_refused_with_421_pages_api_and_websocket_alike() {
    let mut options = test_options();
    options.access.host_names = vec!["lab.example".into()];
    let server = start_default(options).await;
    let addr = server.local_addr();
    let port = addr.port();
    let evil = format!("evil.example:{port}");
    for path in ["/", "/src/main.js", "/api/scene", "/ws"] {
        let response = http_request(addr, path, &[("Host", &evil)]).await;
        assert_eq!(response.status, 421, "{path}");
    }
    assert_eq!(
        Viewer::connect_with(addr, None, Some(&evil), None)
            .await
            .err(),
        Some(421)
    );
    // Rebinding with the page's own origin is refused by the Host rule all the same.
    let origin = format!("http://{evil}");
    assert_eq!(
        Viewer::connect_with(addr, Some(&origin), Some(&evil), None)
            .await
            .err(),
        Some(421)
    );
    let lab = format!("lab.example:{port}");
    for host in [
        lab.as_str(),
        &format!("localhost:{port}"),
        &format!("127.0.0.1:{port}"),
    ] {
        let response = http_request(addr, "/api/scene", &[("Host", host)]).await;
        assert_eq!(response.status, 200, "{host}");
        let mut viewer = Viewer::connect_with(addr, None, Some(host), None)
            .await
            .unwrap();
        greeting(&mut viewer).await;
    }
    server.shutdown().await;
}

/// Connects from `from` and returns the close code and reason of a refused connection, or
/// `None` when it was admitted (it got its `hello`), with the viewer.
async fn try_admit(
    addr: SocketAddr,
    from: [u8; 4],
    token: Option<&str>,
) -> (Option<(u16, String)>, Viewer) {
    let mut viewer = Viewer::connect_from(addr, Some(IpAddr::from(from)), None, None, token)
        .await
        .unwrap();
    let message = tokio::time::timeout(WAIT, viewer.socket.next())
        .await
        .expect("an answer within the timeout");
    match message {
        Some(Ok(Message::Text(text))) => {
            assert!(text.starts_with(r#"{"type":"hello""#), "{text}");
            (None, viewer)
        }
        Some(Ok(Message::Close(Some(frame)))) => (
            Some((u16::from(frame.code), frame.reason.to_string())),
            viewer,
        ),
        other => panic!("neither hello nor a close: {other:?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn viewers_beyond_the_caps_are_closed_with_4429_and_told_which_cap() {
    let mut options = test_options();
    options.access.limits.max_viewers = 3;
    options.access.limits.max_per_address = 2;
    let server = start_default(options).await;
    let addr = server.local_addr();

    let (refused, a1) = try_admit(addr, [127, 0, 0, 1], None).await;
    assert_eq!(refused, None);
    let (refused, _a2) = try_admit(addr, [127, 0, 0, 1], None).await;
    assert_eq!(refused, None);
    let (refused, _) = try_admit(addr, [127, 0, 0, 1], None).await;
    assert_eq!(
        refused,
        Some((4429, "too many viewers from this address".to_owned()))
    );
    // Another address is still admitted, up to the overall cap.
    let (refused, _b1) = try_admit(addr, [127, 0, 0, 2], None).await;
    assert_eq!(refused, None);
    let (refused, _) = try_admit(addr, [127, 0, 0, 3], None).await;
    assert_eq!(refused, Some((4429, "too many viewers".to_owned())));

    // A viewer leaves: its place is given back (once the server has seen it go).
    drop(a1);
    let deadline = tokio::time::Instant::now() + WAIT;
    loop {
        let (refused, _c) = try_admit(addr, [127, 0, 0, 3], None).await;
        if refused.is_none() {
            break;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "the place was never given back"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(server.counters().limit_refusals.load(Ordering::Relaxed) >= 2);
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connections_waiting_to_present_a_token_beyond_the_cap_are_closed_with_4429() {
    let mut options = with_tokens();
    options.access.limits.max_pending = 2;
    let server = start_default(options).await;
    let addr = server.local_addr();
    let mut p1 = Viewer::connect_with(addr, None, None, None).await.unwrap();
    let _p2 = Viewer::connect_with(addr, None, None, None).await.unwrap();
    let mut p3 = Viewer::connect_with(addr, None, None, None).await.unwrap();
    let (close, texts) = p3.until_closed(WAIT).await;
    assert_eq!(
        close,
        Some((
            4429,
            "too many connections waiting to authenticate".to_owned()
        ))
    );
    assert!(texts.is_empty());
    // Once one presents its token it no longer waits, and a new connection may.
    p1.authenticate(O).await;
    assert_eq!(greeting(&mut p1).await.role, Role::Observer);
    let mut p4 = Viewer::connect_with(addr, None, None, Some(I))
        .await
        .unwrap();
    assert_eq!(greeting(&mut p4).await.role, Role::Instructor);
    server.shutdown().await;
}

/// Sends up to `count` messages of `text` as fast as the socket takes them (a send fails once
/// the server has closed), then reads to the close: its code and reason.
async fn flood(mut viewer: Viewer, message: Message, count: usize) -> Option<(u16, String)> {
    for _ in 0..count {
        if viewer.socket.feed(message.clone()).await.is_err() {
            break;
        }
    }
    let _ = viewer.socket.flush().await;
    viewer.until_closed(WAIT * 3).await.0
}

/// A well-behaved viewer reading every frame in a task of its own while others misbehave: it
/// keeps each contact frame's `seq` and device time, and [`FrameWatch::check_window`] says
/// whether it kept up, by those alone (no wall-clock rate).
struct FrameWatch {
    frames: Arc<Mutex<Vec<(u64, u64)>>>,
    stop: Arc<AtomicBool>,
    reader: tokio::task::JoinHandle<()>,
}

impl FrameWatch {
    /// Connects as an observer with `token` and returns once it has received 10 frames.
    async fn start(addr: SocketAddr, token: &str) -> FrameWatch {
        let mut watcher = Viewer::connect_with(addr, None, None, Some(token))
            .await
            .unwrap();
        greeting(&mut watcher).await;
        let frames: Arc<Mutex<Vec<(u64, u64)>>> = Arc::default();
        let stop = Arc::new(AtomicBool::new(false));
        let reader = {
            let frames = Arc::clone(&frames);
            let stop = Arc::clone(&stop);
            tokio::spawn(async move {
                while !stop.load(Ordering::Relaxed) {
                    if let ServerMessage::Contact(f) = watcher.expect_message(WAIT).await {
                        frames.lock().unwrap().push((f.seq, f.time_ns));
                    }
                }
            })
        };
        let watch = FrameWatch {
            frames,
            stop,
            reader,
        };
        let deadline = tokio::time::Instant::now() + WAIT;
        while watch.seen() < 10 {
            assert!(tokio::time::Instant::now() < deadline, "no frames");
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        watch
    }

    /// How many frames it has received so far: the index of the next one, where a window of
    /// [`FrameWatch::check_window`] starts.
    fn seen(&self) -> usize {
        self.frames.lock().unwrap().len()
    }

    /// Waits for the frame made 100 frames (2 s of device time) after the window's first, stops
    /// watching, and checks the window: frames were still made every 20 ms of device time
    /// (10–30 ms allowed), and this viewer received at least 80 % of those made (it may skip
    /// ahead when it falls behind, never stall). Prints the figures with `what`.
    async fn check_window(self, window_start: usize, what: &str) {
        let first_seq = {
            let frames = self.frames.lock().unwrap();
            assert!(frames.len() > window_start, "no frame {what}");
            frames[window_start].0
        };
        let deadline = tokio::time::Instant::now() + WAIT * 2;
        while self.frames.lock().unwrap().last().unwrap().0 < first_seq + 100 {
            assert!(tokio::time::Instant::now() < deadline, "frames stopped");
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        self.stop.store(true, Ordering::Relaxed);
        self.reader.await.unwrap();
        let frames = std::mem::take(&mut *self.frames.lock().unwrap());
        let window = &frames[window_start..];
        let (s0, t0) = window[0];
        let (s1, t1) = window[window.len() - 1];
        let produced = s1 - s0 + 1;
        let received = window.len() as u64;
        // Produced at 50 Hz: the device clock advanced about 20 ms per frame the server made...
        let period_ms = (t1 - t0) as f64 * 1e-6 / (s1 - s0) as f64;
        eprintln!(
            "{what}: received {received} of {produced} frames, one per {period_ms:.1} ms of device time"
        );
        assert!(
            (10.0..=30.0).contains(&period_ms),
            "{what}: frames were made every {period_ms} ms of device time"
        );
        // ...and the well-behaved viewer got at least 80 % of them.
        assert!(
            received * 5 >= produced * 4,
            "{what}: received {received} of {produced} frames"
        );
    }
}

/// An authenticated connection's flood: refused controls padded to 8 KiB (each would be
/// answered), as fast as the socket takes them.
fn padded_control() -> Message {
    Message::text(format!(
        r#"{{"type":"replay_control","action":"pause","pad":"{}"}}"#,
        "x".repeat(8 * 1024)
    ))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_flooding_connection_is_closed_with_1008_while_a_well_behaved_viewer_keeps_50_hz() {
    let server = start_default(with_tokens()).await;
    let addr = server.local_addr();
    let watch = FrameWatch::start(addr, O).await;

    // The flood: authenticated connections sending refused controls, and connections sending
    // pings before presenting any token.
    let window_start = watch.seen();
    let mut flooders = Vec::new();
    for _ in 0..6 {
        let mut viewer = Viewer::connect_with(addr, None, None, Some(O))
            .await
            .unwrap();
        greeting(&mut viewer).await;
        flooders.push(tokio::spawn(flood(viewer, padded_control(), 2_000)));
    }
    for _ in 0..2 {
        let viewer = Viewer::connect_with(addr, None, None, None).await.unwrap();
        flooders.push(tokio::spawn(flood(
            viewer,
            Message::Ping(vec![0; 64].into()),
            2_000,
        )));
    }
    for flooder in flooders {
        assert_eq!(
            flooder.await.unwrap(),
            Some((1008, "too many messages".to_owned()))
        );
    }
    assert_eq!(server.counters().flood_closes.load(Ordering::Relaxed), 8);
    watch.check_window(window_start, "during the flood").await;
    server.shutdown().await;
}

/// How many times each kind of refusal is tried in the storm below.
const STORM_ROUNDS: usize = 20;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_storm_of_every_refusal_at_once_leaves_a_well_behaved_viewer_its_50_hz() {
    let mut options = with_tokens();
    options.access.limits.max_per_address = 2;
    let server = start_default(options).await;
    let addr = server.local_addr();
    // The watcher is 127.0.0.1's; the storm comes from other client addresses.
    let watch = FrameWatch::start(addr, O).await;
    let window_start = watch.seen();

    // 127.0.0.9's two places, taken and held through the storm.
    let mut held = Vec::new();
    for _ in 0..2 {
        let (refused, mut viewer) = try_admit(addr, [127, 0, 0, 9], Some(I)).await;
        assert_eq!(refused, None);
        // Its `hello` was read; the scene comes next.
        let scene = viewer.expect_message(WAIT).await;
        assert!(
            matches!(scene, ServerMessage::Scene(_)),
            "the scene after hello"
        );
        held.push(viewer);
    }
    let evil_host = format!("evil.example:{}", addr.port());
    let wrong_token: String = I.chars().rev().collect();
    let mut storm: Vec<tokio::task::JoinHandle<&'static str>> = Vec::new();
    for round in 0..STORM_ROUNDS {
        let evil_host = evil_host.clone();
        storm.push(tokio::spawn(async move {
            let refused = Viewer::connect_with(addr, Some("http://evil.example"), None, Some(I))
                .await
                .err();
            assert_eq!(refused, Some(403), "a foreign Origin");
            "403"
        }));
        storm.push(tokio::spawn(async move {
            let refused = Viewer::connect_with(addr, None, Some(&evil_host), Some(I))
                .await
                .err();
            assert_eq!(refused, Some(421), "a wrong Host");
            let page = http_request(addr, "/api/scene", &[("Host", &evil_host)]).await;
            assert_eq!(page.status, 421, "a wrong Host over HTTP");
            "421"
        }));
        let wrong_token = wrong_token.clone();
        storm.push(tokio::spawn(async move {
            // Each from an address of its own: the per-address cap is another refusal.
            let from = IpAddr::from([127, 0, 2, u8::try_from(round).unwrap()]);
            let mut viewer = Viewer::connect_from(addr, Some(from), None, None, Some(&wrong_token))
                .await
                .unwrap();
            let (close, texts) = viewer.until_closed(WAIT).await;
            assert_eq!(
                close,
                Some((4401, "token not valid for this server".to_owned()))
            );
            assert!(texts.is_empty(), "{texts:?}");
            let api = http_request(addr, "/api/scene", &[]).await;
            assert_eq!(api.status, 401, "session data without a token");
            "4401"
        }));
        storm.push(tokio::spawn(async move {
            let (refused, _) = try_admit(addr, [127, 0, 0, 9], None).await;
            assert_eq!(
                refused,
                Some((4429, "too many viewers from this address".to_owned()))
            );
            "4429"
        }));
        if round % 5 == 0 {
            // A flood from an address of its own, so that its place is not the cap's.
            let from = IpAddr::from([127, 0, 1, u8::try_from(round).unwrap()]);
            storm.push(tokio::spawn(async move {
                let mut viewer = Viewer::connect_from(addr, Some(from), None, None, Some(O))
                    .await
                    .unwrap();
                greeting(&mut viewer).await;
                let close = flood(viewer, padded_control(), 2_000).await;
                assert_eq!(close, Some((1008, "too many messages".to_owned())));
                "1008"
            }));
        }
    }
    let mut answered = std::collections::BTreeMap::new();
    for refusal in storm {
        *answered.entry(refusal.await.unwrap()).or_insert(0) += 1;
    }
    eprintln!("refusals answered during the storm: {answered:?}");
    let counters = server.counters();
    assert_eq!(
        counters.unauthorized_closes.load(Ordering::Relaxed),
        STORM_ROUNDS as u64
    );
    assert_eq!(
        counters.limit_refusals.load(Ordering::Relaxed),
        STORM_ROUNDS as u64
    );
    assert_eq!(
        counters.flood_closes.load(Ordering::Relaxed),
        STORM_ROUNDS.div_ceil(5) as u64
    );
    // The held viewers were never disturbed: each still reads its stream.
    for viewer in &mut held {
        next_seq(viewer).await;
    }
    watch
        .check_window(window_start, "during the refusal storm")
        .await;
    server.shutdown().await;
}

/// The CSP the server must send for the source tree's page (the one built into the binary),
/// computed here from the page: the SHA-256 of each inline script (the import map).
fn expected_csp() -> String {
    let page =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../web/index.html"))
            .unwrap();
    let mut hashes = String::new();
    let mut rest = page.as_str();
    while let Some(start) = rest.find("<script") {
        let after = &rest[start..];
        let tag_end = after.find('>').unwrap();
        let body_end = after.find("</script>").unwrap();
        if !after[..tag_end].contains("src=") {
            let body = &after[tag_end + 1..body_end];
            let hash = base64::engine::general_purpose::STANDARD.encode(Sha256::digest(body));
            hashes.push_str(&format!(" 'sha256-{hash}'"));
        }
        rest = &after[body_end..];
    }
    assert!(!hashes.is_empty(), "the page has its import map inline");
    format!(
        "default-src 'self'; script-src 'self'{hashes}; style-src 'self'; connect-src 'self'; \
         img-src 'self' data:; object-src 'none'; base-uri 'none'; form-action 'none'; \
         frame-ancestors 'none'"
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_response_carries_the_security_headers_and_session_data_needs_a_bearer_token() {
    let server = start_default(with_tokens()).await;
    let addr = server.local_addr();
    let csp = expected_csp();
    let bearer = |t: &str| format!("Bearer {t}");
    let (bearer_i, bearer_o) = (bearer(I), bearer(O));
    let wrong = bearer(&I.chars().rev().collect::<String>());
    let evil = format!("evil.example:{}", addr.port());
    let mesh = server.scene_message().render_meshes[0].url.clone();
    type Case<'a> = (&'a str, Vec<(&'a str, &'a str)>, u16);
    let cases: [Case; 11] = [
        ("/", vec![], 200),
        ("/src/main.js", vec![], 200),
        ("/api/scene", vec![("Authorization", &bearer_i)], 200),
        ("/api/scene", vec![("Authorization", &bearer_o)], 200),
        (&mesh, vec![("Authorization", &bearer_o)], 200),
        ("/src/no-such-file.js", vec![], 404),
        ("/api/scene", vec![], 401),
        ("/api/scene", vec![("Authorization", &wrong)], 401),
        ("/api/scene", vec![("Authorization", O)], 401),
        (&mesh, vec![], 401),
        ("/", vec![("Host", &evil)], 421),
    ];
    for (path, headers, status) in cases {
        let response = http_request(addr, path, &headers).await;
        assert_eq!(response.status, status, "{path} {headers:?}");
        let has = |name: &str, value: &str| response.header(name) == Some(value);
        assert!(
            has("content-security-policy", &csp),
            "{path} {status}: {:?}\nexpected {csp}",
            response.header("content-security-policy")
        );
        assert!(has("x-content-type-options", "nosniff"), "{path} {status}");
        assert!(has("referrer-policy", "no-referrer"), "{path} {status}");
        assert!(has("x-frame-options", "DENY"), "{path} {status}");
        match (path, status) {
            ("/api/scene", 200) => {
                assert!(has("content-type", "application/json"));
                let text = std::str::from_utf8(&response.body).unwrap();
                assert!(matches!(
                    ServerMessage::decode(text),
                    Ok(ServerMessage::Scene(_))
                ));
            }
            (_, 401) => {
                assert!(has("content-type", "application/json"));
                let www = response.header("www-authenticate").unwrap();
                assert!(www.starts_with("Bearer"), "{www}");
                let body: serde_json::Value = serde_json::from_slice(&response.body).unwrap();
                let reason = body["error"].as_str().unwrap();
                assert!(
                    ["no token presented", "token not valid for this server"].contains(&reason),
                    "{reason}"
                );
            }
            (_, 421) => assert!(has("content-type", "application/json")),
            _ => {}
        }
    }
    server.shutdown().await;
}
