//! How a viewer's connection ended, as the server counts it and its audit line says it: a viewer
//! that just disappears (its TCP connection reset, or ended without WebSocket's close frame) is
//! a lost connection, not a malformed message; an oversized message still is one.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::sync::atomic::Ordering;
use std::time::Duration;

use softhaptic_proto::wire::ServerMessage;
use softhaptic_server::app::RunningServer;
use softhaptic_tests::{Viewer, start_default, test_options, wait_until};

const WAIT: Duration = Duration::from_secs(10);

/// Connected, greeted and streaming.
async fn streaming(server: &RunningServer) -> Viewer {
    let mut viewer = Viewer::connect(server.local_addr()).await;
    assert!(matches!(
        viewer.expect_message(WAIT).await,
        ServerMessage::Hello(_)
    ));
    assert!(matches!(
        viewer.expect_message(WAIT).await,
        ServerMessage::Scene(_)
    ));
    viewer
}

/// Drops the viewer's TCP connection with a reset (SO_LINGER 0), as a killed process's or a
/// dead link's does.
fn reset(viewer: Viewer) {
    match viewer.socket.get_ref() {
        tokio_tungstenite::MaybeTlsStream::Plain(tcp) => {
            #[allow(deprecated)] // the blocking on drop it warns of is what a linger of 0 avoids
            tcp.set_linger(Some(Duration::ZERO)).unwrap();
        }
        _ => panic!("a plain TCP connection"),
    }
    drop(viewer);
}

/// Every admitted connection has ended (its audit line written).
async fn all_ended(server: &RunningServer) {
    wait_until("every connection to end", || {
        server.hub().access.viewers() == 0 && server.counters().viewers.load(Ordering::Relaxed) == 0
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_viewer_that_drops_its_connection_is_lost_not_malformed() {
    let server = start_default(test_options()).await;
    // One ends its TCP connection (FIN) without a close frame, one resets it, one closes
    // properly.
    drop(streaming(&server).await);
    reset(streaming(&server).await);
    let mut clean = streaming(&server).await;
    clean.socket.close(None).await.unwrap();
    all_ended(&server).await;
    assert_eq!(
        server.counters().malformed_closes.load(Ordering::Relaxed),
        0,
        "a viewer that went away sent nothing malformed"
    );

    // An oversized message is still malformed (closed with 1009).
    let mut huge = streaming(&server).await;
    huge.send_text(&format!(
        r#"{{"type":"x","pad":"{}"}}"#,
        "a".repeat(200_000)
    ))
    .await;
    let (close, _) = huge.until_closed(WAIT).await;
    assert_eq!(close.map(|c| c.0), Some(1009));
    all_ended(&server).await;
    assert_eq!(
        server.counters().malformed_closes.load(Ordering::Relaxed),
        1
    );
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_viewer_that_drops_its_connection_before_its_token_is_lost_not_malformed() {
    let mut options = test_options();
    options.access.tokens = Some(softhaptic_tests::test_tokens());
    let server = start_default(options).await;
    let addr = server.local_addr();
    let eof = Viewer::connect(addr).await;
    let reset_before = Viewer::connect(addr).await;
    wait_until("both connections admitted", || {
        server.hub().access.viewers() == 2
    })
    .await;
    drop(eof);
    reset(reset_before);
    all_ended(&server).await;
    let counters = server.counters();
    assert_eq!(counters.malformed_closes.load(Ordering::Relaxed), 0);
    assert_eq!(counters.unauthorized_closes.load(Ordering::Relaxed), 0);
    server.shutdown().await;
}
