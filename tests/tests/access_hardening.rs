//! The access rules' smaller guards, against a real server: wrong tokens from one address are
//! answered ever more slowly (HTTP and WebSocket alike), while a right token is not refused.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::time::{Duration, Instant};

use softhaptic_tests::{
    INSTRUCTOR_TOKEN as I, Viewer, http_get_with_token, start_default, test_options, test_tokens,
};

const WRONG: &str = "ffffffffffffffff0000000000000000";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn wrong_tokens_from_one_address_are_answered_ever_more_slowly() {
    let mut options = test_options();
    options.access.tokens = Some(test_tokens());
    let server = start_default(options).await;
    let addr = server.local_addr();
    // The first five (a mistyped or expired link, tried again) are answered at once; the sixth
    // waits 250 ms, the seventh 500, the eighth a second. Only lower bounds are checked: a slow
    // machine answers later, never sooner.
    let mut waits = Vec::new();
    for _ in 0..8 {
        let started = Instant::now();
        let response = http_get_with_token(addr, "/api/scene", WRONG).await;
        assert_eq!(response.status, 401);
        waits.push(started.elapsed());
    }
    assert!(waits[5] >= Duration::from_millis(250), "{waits:?}");
    assert!(waits[6] >= Duration::from_millis(500), "{waits:?}");
    assert!(waits[7] >= Duration::from_millis(1000), "{waits:?}");
    // The ninth, over WebSocket: two seconds before its 4401.
    let started = Instant::now();
    let mut viewer = Viewer::connect_with(addr, None, None, Some(WRONG))
        .await
        .unwrap();
    let (close, _) = viewer.until_closed(Duration::from_secs(30)).await;
    assert_eq!(close.map(|c| c.0), Some(4401));
    assert!(
        started.elapsed() >= Duration::from_secs(2),
        "{:?}",
        started.elapsed()
    );
    // The right token from the same address is served.
    let response = http_get_with_token(addr, "/api/scene", I).await;
    assert_eq!(response.status, 200);
    server.shutdown().await;
}
