//! docs/roles.md against running servers: every route and every message of a live station, a
//! replay server and a lab hub (on a real `nats-server`), tried as an instructor, as an observer
//! and without a valid token. The expected answers are written out here, route by route, not
//! taken from the server's own table. Every answer of these routes says `Cache-Control: no-store`.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::net::SocketAddr;
use std::path::Path;
use std::time::Duration;

use futures_util::StreamExt;
use softhaptic_proto::wire::{Mode, Role, ServerMessage};
use softhaptic_server::access::AccessConfig;
use softhaptic_server::session::reader::Recording;
use softhaptic_server::session::replay;
use softhaptic_server::stream::{
    REFUSED_EXERCISE_NONE, REFUSED_LIVE, REFUSED_MARK_HUB, REFUSED_MARK_OBSERVER,
    REFUSED_MARK_REPLAY, REFUSED_OBSERVER,
};
use softhaptic_tests::nats::{
    NatsServer, archive_sessions, options as nats, start_hub, start_station,
};
use softhaptic_tests::{
    INSTRUCTOR_TOKEN as I, OBSERVER_TOKEN as O, Viewer, http_get_with_token, replay_options,
    start_default, test_options, test_tokens, wait_until,
};
use tokio_tungstenite::tungstenite::Message;

const WAIT: Duration = Duration::from_secs(30);

/// Who a request is made as: a role's token, or a token of no role.
#[derive(Debug, Clone, Copy, PartialEq)]
enum As {
    Instructor,
    Observer,
    Nobody,
}

const EVERYONE: [As; 3] = [As::Instructor, As::Observer, As::Nobody];

impl As {
    fn token(self) -> &'static str {
        match self {
            As::Instructor => I,
            As::Observer => O,
            As::Nobody => "ffffffffffffffff0000000000000000",
        }
    }
}

/// The status of a GET of `path` made as `who`.
async fn get(addr: SocketAddr, path: &str, who: As) -> (u16, String) {
    let response = http_get_with_token(addr, path, who.token()).await;
    // Session data, given or refused, is nobody's to keep (a shared browser's cache, a proxy's);
    // a station's `/api/stations` (no data, no token) is the one route here that is not.
    if path != "/api/stations"
        || response.status == 401
        || response.body.starts_with(b"{\"hub\":true")
    {
        assert_eq!(
            response.header("cache-control"),
            Some("no-store"),
            "{path} as {who:?}"
        );
    }
    let body = if response.body.len() < 512 {
        String::from_utf8_lossy(&response.body).into_owned()
    } else {
        format!("<{} bytes>", response.body.len())
    };
    (response.status, body)
}

/// Checks `path` answers `expected` (instructor, observer, nobody), and an observer's 403 says
/// why; returns the instructor's body.
async fn route(addr: SocketAddr, path: &str, expected: [u16; 3]) {
    for (who, status) in EVERYONE.into_iter().zip(expected) {
        let (got, body) = get(addr, path, who).await;
        assert_eq!(got, status, "{path} as {who:?}: {body}");
        if status == 403 {
            assert!(body.contains("only an instructor"), "{path}: {body}");
        }
    }
}

/// Connects to `ws://ADDR/ws?QUERY` and presents `who`'s token.
async fn connect(addr: SocketAddr, query: &str, who: As) -> Viewer {
    let mut viewer = Viewer::connect_url(&format!("ws://{addr}/ws?{query}")).await;
    viewer.authenticate(who.token()).await;
    viewer
}

/// The next text message as JSON whose `type` is one of `types`, skipping others.
async fn next_of(viewer: &mut Viewer, types: &[&str]) -> serde_json::Value {
    loop {
        let message = tokio::time::timeout(WAIT, viewer.socket.next())
            .await
            .expect("a message within the timeout");
        match message {
            Some(Ok(Message::Text(text))) => {
                let value: serde_json::Value = serde_json::from_str(&text).unwrap();
                if types.contains(&value["type"].as_str().unwrap_or_default()) {
                    return value;
                }
            }
            Some(Ok(_)) => continue,
            other => panic!("the connection ended waiting for {types:?}: {other:?}"),
        }
    }
}

/// A viewer's greeting: its role and mode.
async fn greeted(viewer: &mut Viewer) -> (Role, Mode) {
    match viewer.expect_message(WAIT).await {
        ServerMessage::Hello(h) => (h.role, h.mode),
        other => panic!("expected hello, got {other:?}"),
    }
}

/// Sends `text` and expects a `refused` with `reason`.
async fn refused(viewer: &mut Viewer, text: &str, reason: &str) {
    viewer.send_text(text).await;
    let answer = next_of(viewer, &["refused"]).await;
    assert_eq!(answer["reason"], reason, "{text}");
}

const MARK: &str = r#"{"type":"add_mark","note":"roles"}"#;
const SEEK: &str = r#"{"type":"replay_control","action":"seek","time_s":1.5}"#;
const NEXT: &str = r#"{"type":"exercise_control","action":"next"}"#;

/// The WebSocket as nobody: closed with 4401 before anything is sent.
async fn refused_without_a_role(addr: SocketAddr, query: &str) {
    let mut viewer = connect(addr, query, As::Nobody).await;
    let (close, texts) = viewer.until_closed(WAIT).await;
    assert_eq!(close.map(|c| c.0), Some(4401), "{query}");
    assert!(texts.is_empty(), "{query}: {texts:?}");
}

/// The mesh URL of the scene `addr` serves at `scene_path` to an instructor.
async fn first_mesh_url(addr: SocketAddr, scene_path: &str) -> String {
    let response = http_get_with_token(addr, scene_path, I).await;
    assert_eq!(response.status, 200, "{scene_path}");
    let scene: serde_json::Value = serde_json::from_slice(&response.body).unwrap();
    scene["render_meshes"][0]["url"]
        .as_str()
        .unwrap()
        .to_owned()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_station_and_a_replay_server_answer_each_route_and_message_by_role() {
    // A live station.
    let mut options = test_options();
    options.access.tokens = Some(test_tokens());
    let station = start_default(options).await;
    let addr = station.local_addr();
    route(addr, "/api/scene", [200, 200, 401]).await;
    let mesh = first_mesh_url(addr, "/api/scene").await;
    route(addr, &mesh, [200, 200, 401]).await;
    route(addr, "/api/stations", [200, 200, 200]).await;
    refused_without_a_role(addr, "").await;
    for (who, role) in [
        (As::Instructor, Role::Instructor),
        (As::Observer, Role::Observer),
    ] {
        let mut viewer = connect(addr, "", who).await;
        assert_eq!(greeted(&mut viewer).await, (role, Mode::Live));
        refused(&mut viewer, SEEK, REFUSED_LIVE).await;
        // A station started without exercises (one with them: tests/tests/exercises_live.rs).
        refused(&mut viewer, NEXT, REFUSED_EXERCISE_NONE).await;
        if who == As::Observer {
            refused(&mut viewer, MARK, REFUSED_MARK_OBSERVER).await;
        } else {
            viewer.send_text(MARK).await;
            let mark = next_of(&mut viewer, &["mark", "refused"]).await;
            assert_eq!(mark["type"], "mark", "{mark}");
        }
    }
    station.shutdown().await;

    // A replay server: its command line opened the replay, so an observer watches it from the
    // start; only an instructor moves it.
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("sessions/sphere-press.mcap");
    let mut options = replay_options(1.0, true);
    options.access = AccessConfig {
        tokens: Some(test_tokens()),
        ..AccessConfig::default()
    };
    let server = replay::start(Recording::open(&path).unwrap(), options)
        .await
        .unwrap();
    let addr = server.local_addr();
    route(addr, "/api/scene", [200, 200, 401]).await;
    let mesh = first_mesh_url(addr, "/api/scene").await;
    route(addr, &mesh, [200, 200, 401]).await;
    refused_without_a_role(addr, "").await;
    let mut observer = connect(addr, "", As::Observer).await;
    assert_eq!(greeted(&mut observer).await, (Role::Observer, Mode::Replay));
    refused(&mut observer, SEEK, REFUSED_OBSERVER).await;
    refused(&mut observer, MARK, REFUSED_MARK_REPLAY).await;
    refused(&mut observer, NEXT, REFUSED_EXERCISE_NONE).await;
    let mut instructor = connect(addr, "", As::Instructor).await;
    assert_eq!(
        greeted(&mut instructor).await,
        (Role::Instructor, Mode::Replay)
    );
    refused(&mut instructor, MARK, REFUSED_MARK_REPLAY).await;
    refused(&mut instructor, NEXT, REFUSED_EXERCISE_NONE).await;
    instructor.send_text(SEEK).await;
    // The observer sees the instructor's seek.
    loop {
        let status = next_of(&mut observer, &["replay"]).await;
        if status["time_s"] == 1.5 {
            break;
        }
    }
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hub_answers_each_route_and_message_by_role() {
    let server = NatsServer::start("roles");
    let station = start_station("st1", nats(server.url())).await.unwrap();
    archive_sessions(nats(server.url()), "st1", &[("slide.mcap", "slide.mcap")]).await;
    let hub = start_hub(nats(server.url()), true).await;
    wait_until("the station listed", || hub.stations().len() == 1).await;
    let addr = hub.local_addr();

    // A station's live stream: both roles watch; nobody marks through a hub.
    route(addr, "/api/stations", [200, 200, 401]).await;
    route(addr, "/api/scene?station=st1", [200, 200, 401]).await;
    let mesh = first_mesh_url(addr, "/api/scene?station=st1").await;
    route(addr, &mesh, [200, 200, 401]).await;
    refused_without_a_role(addr, "station=st1").await;
    for (who, role) in [
        (As::Instructor, Role::Instructor),
        (As::Observer, Role::Observer),
    ] {
        let mut viewer = connect(addr, "station=st1", who).await;
        assert_eq!(greeted(&mut viewer).await, (role, Mode::Live));
        refused(&mut viewer, MARK, REFUSED_MARK_HUB).await;
        refused(&mut viewer, SEEK, REFUSED_LIVE).await;
        refused(&mut viewer, NEXT, REFUSED_EXERCISE_NONE).await;
    }

    // The archive: listing and downloading are an instructor's.
    route(addr, "/api/archive", [200, 403, 401]).await;
    route(addr, "/api/archive?station=st1", [200, 403, 401]).await;
    route(addr, "/stations/st1/archive/slide.mcap", [200, 403, 401]).await;
    // Refused before the name is looked at: the same for a file that is not there.
    route(addr, "/stations/st1/archive/nosuch.mcap", [404, 403, 401]).await;

    // A replay no instructor has open: an observer cannot open it, by WebSocket or by HTTP, and
    // makes the hub fetch nothing.
    let query = "station=st1&archive=slide.mcap";
    let scene = format!("/api/scene?{query}");
    let archived_mesh = "/stations/st1/archive/slide.mcap/meshes/liver.bin";
    for q in [query, "station=st1&archive=nosuch.mcap"] {
        let mut viewer = connect(addr, q, As::Observer).await;
        let (close, texts) = viewer.until_closed(WAIT).await;
        let (code, reason) = close.unwrap();
        assert_eq!(code, 4403, "{q}: {reason}");
        assert!(reason.contains("instructor has opened it"), "{reason}");
        assert!(texts.is_empty(), "{texts:?}");
    }
    for path in [scene.as_str(), archived_mesh] {
        let (status, body) = get(addr, path, As::Observer).await;
        assert_eq!(status, 403, "{path}: {body}");
    }
    assert!(
        hub.replayed_recordings().is_empty(),
        "fetched for an observer"
    );
    refused_without_a_role(addr, query).await;

    // An instructor opens it: the observer now watches it, and only the instructor moves it.
    let mut instructor = connect(addr, query, As::Instructor).await;
    assert_eq!(
        greeted(&mut instructor).await,
        (Role::Instructor, Mode::Replay)
    );
    let mut observer = connect(addr, query, As::Observer).await;
    assert_eq!(greeted(&mut observer).await, (Role::Observer, Mode::Replay));
    let (status, _) = get(addr, &scene, As::Observer).await;
    assert_eq!(status, 200);
    let mesh = first_mesh_url(addr, &scene).await;
    assert_eq!(mesh, archived_mesh);
    let (status, _) = get(addr, &mesh, As::Observer).await;
    assert_eq!(status, 200);
    refused(&mut observer, SEEK, REFUSED_OBSERVER).await;
    refused(&mut observer, MARK, REFUSED_MARK_REPLAY).await;
    refused(&mut instructor, MARK, REFUSED_MARK_REPLAY).await;
    instructor.send_text(SEEK).await;
    loop {
        let status = next_of(&mut observer, &["replay"]).await;
        if status["time_s"] == 1.5 {
            break;
        }
    }
    // The instructor leaves: the observers still watching keep the replay.
    instructor.socket.close(None).await.unwrap();
    let _ = instructor.until_closed(WAIT).await;
    refused(&mut observer, SEEK, REFUSED_OBSERVER).await;
    assert_eq!(hub.replayed_recordings(), ["st1/slide.mcap"]);
    observer.socket.close(None).await.unwrap();
    drop(observer);
    wait_until("the replay closed with its last viewer", || {
        hub.replayed_recordings().is_empty()
    })
    .await;
    // Closed: an observer is refused again.
    let mut viewer = connect(addr, query, As::Observer).await;
    let (close, _) = viewer.until_closed(WAIT).await;
    assert_eq!(close.map(|c| c.0), Some(4403));

    hub.shutdown().await;
    station.shutdown().await;
}
