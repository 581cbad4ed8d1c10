//! A lab hub's `/ws` against clients it should tell nothing: a page of another site gets its 403
//! before anything is looked up (no station relayed, no recording fetched, no word of what
//! exists); a client without a valid token is refused the same way whether the station it names
//! exists or not, and makes the hub relay or fetch nothing; an authenticated viewer of something
//! that is not there gets one answer, with none of the hub's internal errors; an archived
//! recording's replay is dropped when its last viewer leaves. With a real `nats-server`.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::net::SocketAddr;
use std::time::Duration;

use softhaptic_proto::wire::{Mode, ServerMessage};
use softhaptic_server::app::RunningServer;
use softhaptic_server::lab::NatsOptions;
use softhaptic_server::lab::hub::RunningHub;
use softhaptic_tests::nats::{
    NatsServer, archive_sessions, options as nats, start_hub, start_station,
};
use softhaptic_tests::{Viewer, http_get_with_token, wait_until};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::HeaderValue;

const I: &str = softhaptic_tests::INSTRUCTOR_TOKEN;
const WAIT: Duration = Duration::from_secs(30);
/// What the hub's internal errors look like (NATS's, JetStream's, the station list's).
const INTERNAL: [&str; 5] = [
    "jetstream",
    "stream not found",
    "object store",
    "heard from",
    "nosuch",
];

/// Connects to the hub's `/ws?QUERY` as a page of `origin` would (no `Origin` when `None`),
/// naming it `host` (its address when `None`). `Err` is a refused upgrade's status and body.
async fn connect(
    addr: SocketAddr,
    query: &str,
    origin: Option<&str>,
    host: Option<&str>,
) -> Result<Viewer, (u16, String)> {
    let mut request = format!("ws://{addr}/ws?{query}")
        .into_client_request()
        .unwrap();
    if let Some(origin) = origin {
        request
            .headers_mut()
            .insert("origin", HeaderValue::from_str(origin).unwrap());
    }
    if let Some(host) = host {
        request
            .headers_mut()
            .insert("host", HeaderValue::from_str(host).unwrap());
    }
    let tcp = tokio::net::TcpStream::connect(addr).await.unwrap();
    match tokio_tungstenite::client_async(request, tokio_tungstenite::MaybeTlsStream::Plain(tcp))
        .await
    {
        Ok((socket, _)) => Ok(Viewer { socket }),
        Err(tokio_tungstenite::tungstenite::Error::Http(response)) => Err((
            response.status().as_u16(),
            String::from_utf8_lossy(response.body().as_deref().unwrap_or_default()).into_owned(),
        )),
        Err(e) => panic!("WebSocket handshake failed: {e}"),
    }
}

fn assert_no_internal_text(text: &str) {
    let lower = text.to_ascii_lowercase();
    for internal in INTERNAL {
        assert!(!lower.contains(internal), "{internal:?} in {text:?}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_foreign_origin_or_a_missing_token_learns_nothing_and_makes_the_hub_fetch_nothing() {
    let server = NatsServer::start("lab-access");
    let st1 = station("st1", nats(server.url())).await;
    archive_sessions(nats(server.url()), "st1", &[("slide.mcap", "slide.mcap")]).await;
    let hub = tokened_hub(nats(server.url())).await;
    wait_until("the station listed", || hub.stations().len() == 1).await;
    let addr = hub.local_addr();
    let queries = [
        "station=st1",
        "station=nosuch",
        "station=st1&archive=x.mcap",
        "station=st1&archive=slide.mcap",
    ];

    // A page of another site: 403 for all alike, nothing looked up.
    for query in queries {
        let (status, body) = connect(addr, query, Some("http://evil.example"), None)
            .await
            .err()
            .unwrap_or_else(|| panic!("{query}: a foreign Origin was upgraded"));
        assert_eq!(status, 403, "{query}: {body}");
        assert_no_internal_text(&body);
    }
    // A page that names the hub by another site's name (DNS rebinding): refused by the Host.
    for query in queries {
        let (status, _) = connect(
            addr,
            query,
            Some("http://evil.example"),
            Some("evil.example"),
        )
        .await
        .err()
        .unwrap();
        assert_eq!(status, 421, "{query}");
    }
    assert!(
        hub.relayed_stations().is_empty(),
        "relayed for a foreign page"
    );
    assert!(
        hub.replayed_recordings().is_empty(),
        "fetched for a foreign page"
    );

    // Not a browser, no token or a wrong one: each refused with 4401 as the others, whether what
    // it names exists or not.
    for query in queries {
        for token in [None, Some("not-a-token-of-this-hub-at-all-0000")] {
            let mut viewer = connect(addr, query, None, None)
                .await
                .unwrap_or_else(|(status, body)| panic!("{query}: {status} {body}"));
            if let Some(token) = token {
                viewer.authenticate(token).await;
            } else {
                viewer.send_text(r#"{"type":"hello"}"#).await;
            }
            let (close, texts) = viewer.until_closed(WAIT).await;
            let (code, reason) = close.unwrap_or_else(|| panic!("{query}: no close frame"));
            assert_eq!(code, 4401, "{query}: {reason}");
            assert!(texts.is_empty(), "{query}: sent {texts:?} before a token");
            assert_no_internal_text(&reason);
        }
    }
    assert_eq!(
        hub.gate_counters()
            .unauthorized_closes
            .load(std::sync::atomic::Ordering::Relaxed),
        8
    );
    assert!(
        hub.relayed_stations().is_empty(),
        "relayed for a client without a token"
    );
    assert!(
        hub.replayed_recordings().is_empty(),
        "fetched for a client without a token"
    );

    // With a token: a station or a recording that is not there is one answer, over WebSocket
    // (4404) and over HTTP (404), without the hub's internal errors.
    let mut closes = Vec::new();
    for query in [
        "station=nosuch",
        "station=st1&archive=x.mcap",
        "station=nosuch&archive=x.mcap",
        "station=..&archive=x.mcap",
    ] {
        let mut viewer = connect(addr, query, None, None).await.unwrap();
        viewer.authenticate(I).await;
        let (close, texts) = viewer.until_closed(WAIT).await;
        let (code, reason) = close.unwrap_or_else(|| panic!("{query}: no close frame"));
        assert_eq!(code, 4404, "{query}: {reason}");
        assert!(texts.is_empty(), "{query}: {texts:?}");
        assert_no_internal_text(&reason);
        closes.push(reason);
    }
    closes.dedup();
    assert_eq!(closes.len(), 1, "{closes:?}");
    let mut bodies = Vec::new();
    for path in [
        "/api/scene?station=nosuch",
        "/api/scene?station=st1&archive=x.mcap",
        "/api/scene?station=nosuch&archive=x.mcap",
        "/stations/nosuch/meshes/liver.bin",
        "/stations/st1/archive/x.mcap",
        "/stations/st1/archive/x.mcap/meshes/liver.bin",
    ] {
        let response = http_get_with_token(addr, path, I).await;
        let body = String::from_utf8_lossy(&response.body).into_owned();
        assert_eq!(response.status, 404, "{path}: {body}");
        assert_no_internal_text(&body);
        bodies.push(body);
    }
    bodies.dedup();
    assert_eq!(bodies.len(), 1, "{bodies:?}");

    // The station itself, for an authenticated viewer: relayed from then on.
    let mut viewer = connect(addr, "station=st1", None, None).await.unwrap();
    viewer.authenticate(I).await;
    assert!(matches!(
        viewer.expect_message(WAIT).await,
        ServerMessage::Hello(_)
    ));
    assert_eq!(hub.relayed_stations(), ["st1"]);
    hub.shutdown().await;
    st1.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_archived_replay_is_fetched_for_an_authenticated_viewer_and_dropped_after_the_last() {
    let server = NatsServer::start("lab-access-replay");
    archive_sessions(
        nats(server.url()),
        "desk-r",
        &[("slide.mcap", "slide.mcap")],
    )
    .await;
    let hub = tokened_hub(nats(server.url())).await;
    let addr = hub.local_addr();
    let query = "station=desk-r&archive=slide.mcap";

    async fn replay_viewer(addr: SocketAddr, query: &str) -> Viewer {
        let mut viewer = connect(addr, query, None, None).await.unwrap();
        viewer.authenticate(I).await;
        match viewer.expect_message(WAIT).await {
            ServerMessage::Hello(h) => assert_eq!(h.mode, Mode::Replay),
            other => panic!("expected hello, got {other:?}"),
        }
        viewer
    }
    let first = replay_viewer(addr, query).await;
    let second = replay_viewer(addr, query).await;
    assert_eq!(hub.replayed_recordings(), ["desk-r/slide.mcap"]);
    // One leaves (without a close frame): the other's replay stays.
    drop(first);
    let mut second = second;
    assert!(matches!(
        second.expect_message(WAIT).await,
        ServerMessage::Scene(_)
    ));
    assert_eq!(hub.replayed_recordings(), ["desk-r/slide.mcap"]);
    // The last leaves: the replay and its recording are dropped.
    second.socket.close(None).await.unwrap();
    drop(second);
    wait_until("the replay dropped", || {
        hub.replayed_recordings().is_empty()
    })
    .await;
    // And fetched again for the next viewer, who is closed when the hub stops.
    let mut third = replay_viewer(addr, query).await;
    assert_eq!(hub.replayed_recordings(), ["desk-r/slide.mcap"]);
    hub.shutdown().await;
    let (close, _) = third.until_closed(WAIT).await;
    assert_eq!(close.map(|c| c.0), Some(1001));
}

async fn station(name: &str, options: NatsOptions) -> RunningServer {
    start_station(name, options).await.unwrap()
}

async fn tokened_hub(options: NatsOptions) -> RunningHub {
    start_hub(options, true).await
}
