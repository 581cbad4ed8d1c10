//! A lab hub's memory for archived recordings' replays, with a real `nats-server`: asking for a
//! replay's scene or meshes over HTTP loads nothing (replays load for connected viewers only);
//! viewers asking for one file at once share one load; the decoded recordings live in a cache
//! bounded in bytes (a replay that does not fit beside the open ones is refused until one
//! closes, and a closed one makes room) and expire once unused. (The archive's list, which every
//! hub page asks for every 2 s, is answered from memory: `lab_permissions.rs`.)

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::net::SocketAddr;
use std::path::Path;
use std::time::Duration;

use futures_util::StreamExt;
use softhaptic_proto::wire::{Mode, ServerMessage};
use softhaptic_server::lab::hub::{self, REPLAYS_FULL, RunningHub};
use softhaptic_server::lab::replays::{ReplayCacheLimits, replay_bytes};
use softhaptic_server::session::reader::Recording;
use softhaptic_tests::nats::{NatsServer, archive_sessions, options as nats};
use softhaptic_tests::{INSTRUCTOR_TOKEN as I, Viewer, http_get_with_token, wait_until};
use tokio_tungstenite::tungstenite::Message;

const WAIT: Duration = Duration::from_secs(30);

fn session(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("sessions")
        .join(name)
}

async fn start(url: String, replay_cache: ReplayCacheLimits) -> RunningHub {
    hub::start(hub::HubOptions {
        nats: nats(url),
        addr: ([127, 0, 0, 1], 0).into(),
        viewer: Default::default(),
        access: softhaptic_server::access::AccessConfig {
            tokens: Some(softhaptic_tests::test_tokens()),
            ..Default::default()
        },
        tls: None,
        viewer_limits: Default::default(),
        replay_cache,
        archive_listing: Default::default(),
    })
    .await
    .unwrap()
}

/// An instructor's viewer of `file`'s replay: greeted, or `Err` with its close code and reason.
async fn open(addr: SocketAddr, file: &str) -> Result<Viewer, (u16, String)> {
    let mut viewer =
        Viewer::connect_url(&format!("ws://{addr}/ws?station=st1&archive={file}")).await;
    viewer.authenticate(I).await;
    let first = tokio::time::timeout(WAIT, viewer.socket.next())
        .await
        .expect("an answer within the timeout");
    match first {
        Some(Ok(Message::Text(text))) => match ServerMessage::decode(&text) {
            Ok(ServerMessage::Hello(h)) => {
                assert_eq!(h.mode, Mode::Replay);
                Ok(viewer)
            }
            other => panic!("{file}: {other:?}"),
        },
        Some(Ok(Message::Close(Some(frame)))) => {
            Err((u16::from(frame.code), frame.reason.to_string()))
        }
        other => panic!("{file}: {other:?}"),
    }
}

/// Closes a viewer and waits for the hub to see it go.
async fn close(hub: &RunningHub, mut viewer: Viewer) {
    viewer.socket.close(None).await.unwrap();
    let _ = viewer.until_closed(WAIT).await;
    wait_until("the replay closed", || hub.replayed_recordings().is_empty()).await;
}

async fn status(addr: SocketAddr, path: &str) -> u16 {
    http_get_with_token(addr, path, I).await.status
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn http_loads_no_replay_and_viewers_of_one_file_share_one_load() {
    let server = NatsServer::start("lab-replays-http");
    archive_sessions(nats(server.url()), "st1", &[("slide.mcap", "slide.mcap")]).await;
    let hub = start(server.url(), ReplayCacheLimits::default()).await;
    let addr = hub.local_addr();
    let scene = "/api/scene?station=st1&archive=slide.mcap";
    let mesh = "/stations/st1/archive/slide.mcap/meshes/liver.bin";

    // An instructor's HTTP requests for a replay nobody watches: nothing is fetched or kept
    // (they were answered by loading the whole recording, kept with no viewer ever after).
    for path in [scene, mesh, scene, mesh] {
        assert_eq!(status(addr, path).await, 404, "{path}");
    }
    assert_eq!(hub.recording_loads(), 0);
    assert!(hub.cached_recordings().is_empty());
    assert!(hub.replayed_recordings().is_empty());

    // Six viewers at once: one load, one replay.
    let viewers = futures_util::future::join_all((0..6).map(|_| open(addr, "slide.mcap"))).await;
    let viewers: Vec<Viewer> = viewers.into_iter().map(Result::unwrap).collect();
    assert_eq!(hub.recording_loads(), 1);
    assert_eq!(hub.replayed_recordings(), ["st1/slide.mcap"]);
    // Open now: its scene and meshes are served.
    assert_eq!(status(addr, scene).await, 200);
    assert_eq!(status(addr, mesh).await, 200);
    drop(viewers);
    wait_until("the replay closed", || hub.replayed_recordings().is_empty()).await;
    // Closed, its recording kept for a while: a viewer coming back loads nothing.
    let again = open(addr, "slide.mcap").await.unwrap();
    assert_eq!(hub.recording_loads(), 1);
    close(&hub, again).await;
    hub.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replays_live_in_a_cache_bounded_in_bytes_that_expires() {
    let server = NatsServer::start("lab-replays-cache");
    archive_sessions(
        nats(server.url()),
        "st1",
        &[("a.mcap", "slide.mcap"), ("b.mcap", "sphere-press.mcap")],
    )
    .await;
    let bytes = |name| replay_bytes(&Recording::open(&session(name)).unwrap());
    let (a, b) = (bytes("slide.mcap"), bytes("sphere-press.mcap"));
    // Room for either, not both.
    let hub = start(
        server.url(),
        ReplayCacheLimits {
            max_bytes: a.max(b) + a.min(b) / 2,
            idle_expiry: Duration::from_secs(3600),
        },
    )
    .await;
    let addr = hub.local_addr();
    let first = open(addr, "a.mcap").await.unwrap();
    assert_eq!(hub.cached_recordings(), [("st1/a.mcap".to_owned(), a)]);
    // `a` is open: `b` does not fit beside it, and is refused until it closes.
    let (code, reason) = open(addr, "b.mcap").await.err().unwrap();
    assert_eq!((code, reason.as_str()), (1013, REPLAYS_FULL));
    assert_eq!(hub.cached_recordings(), [("st1/a.mcap".to_owned(), a)]);
    // Closed, `a` makes room.
    close(&hub, first).await;
    let second = open(addr, "b.mcap").await.unwrap();
    assert_eq!(hub.cached_recordings(), [("st1/b.mcap".to_owned(), b)]);
    close(&hub, second).await;
    hub.shutdown().await;

    // A closed replay's recording goes once unused for the expiry.
    let hub = start(
        server.url(),
        ReplayCacheLimits {
            max_bytes: 1 << 30,
            idle_expiry: Duration::from_millis(500),
        },
    )
    .await;
    let viewer = open(hub.local_addr(), "a.mcap").await.unwrap();
    assert_eq!(hub.cached_recordings().len(), 1);
    close(&hub, viewer).await;
    wait_until("the recording expired", || {
        hub.cached_recordings().is_empty()
    })
    .await;
    hub.shutdown().await;
}

/// A measurement, not a test (it prints its figures and asserts none): the archive's listings a
/// hub serves a second with 1 000 pages asking at once, each asking again as soon as it is
/// answered (a page asks every 2 s, so 1 000 pages want 500 a second), and the JetStream API
/// requests the hub makes meanwhile (the server's own count). The closing note's figure:
/// `cargo test -p softhaptic-tests --test lab_replays -- --ignored --nocapture listings_per_second`
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "a measurement: run it by name with --ignored --nocapture"]
async fn listings_per_second_with_1000_pages_asking() {
    use std::sync::atomic::{AtomicU64, Ordering};
    const PAGES: usize = 1000;
    const RUN: Duration = Duration::from_secs(5);
    let server = NatsServer::start("lab-listing-rate");
    for station in ["st1", "st2"] {
        archive_sessions(
            nats(server.url()),
            station,
            &[
                ("slide.mcap", "slide.mcap"),
                ("press.mcap", "sphere-press.mcap"),
            ],
        )
        .await;
    }
    let hub = start(server.url(), ReplayCacheLimits::default()).await;
    let addr = hub.local_addr();
    let client = async_nats::connect(server.url()).await.unwrap();
    let api_requests = || async {
        let answer = client.request("$JS.API.INFO", "".into()).await.unwrap();
        let info: serde_json::Value = serde_json::from_slice(&answer.payload).unwrap();
        info["api"]["total"].as_u64().unwrap()
    };
    // The first listing (the hub's start) is not counted.
    assert_eq!(status(addr, "/api/archive").await, 200);
    let (served, other) = (AtomicU64::new(0), AtomicU64::new(0));
    let before = api_requests().await;
    let started = std::time::Instant::now();
    futures_util::future::join_all((0..PAGES).map(|_| async {
        while started.elapsed() < RUN {
            match http_get_with_token(addr, "/api/archive", I).await.status {
                200 => served.fetch_add(1, Ordering::Relaxed),
                _ => other.fetch_add(1, Ordering::Relaxed),
            };
        }
    }))
    .await;
    let seconds = started.elapsed().as_secs_f64();
    // Its own request counts once.
    let jetstream = api_requests().await - before - 1;
    let served = served.into_inner();
    println!(
        "{PAGES} pages: {served} listings in {seconds:.1} s = {:.0} a second ({} not 200); \
         JetStream API requests meanwhile: {jetstream} = {:.1} a second",
        served as f64 / seconds,
        other.into_inner(),
        jetstream as f64 / seconds
    );
    hub.shutdown().await;
}
