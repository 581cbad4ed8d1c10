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

/// A measurement, not a test (it prints its figures and asserts none): the log lines a station
/// (the `softhaptic` binary, as an operator runs it) writes a second during a storm of requests
/// with a wrong token, each from an address of its own (so that no address is slowed: the
/// storm the per-address waits do not hold back). The closing note's figure:
/// `cargo test -p softhaptic-tests --test access_hardening -- --ignored --nocapture refusal_storm`
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "a measurement: run it by name with --ignored --nocapture"]
async fn refusal_storm_log_lines_a_second() {
    use std::io::BufRead;
    use std::sync::atomic::{AtomicU64, Ordering};
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    // Longer than the refusal log's interval (10 s), so that its summary line is in it.
    const RUN: Duration = Duration::from_secs(21);
    const CLIENTS: u32 = 64;
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let mut child = std::process::Command::new(softhaptic_tests::softhaptic_binary())
        .args(["run", "--no-record", "--addr", &format!("127.0.0.1:{port}")])
        .env("SOFTHAPTIC_INSTRUCTOR_TOKEN", I)
        .env(
            "SOFTHAPTIC_OBSERVER_TOKEN",
            softhaptic_tests::OBSERVER_TOKEN,
        )
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Each line the server writes, with when it came.
    let stderr = child.stderr.take().unwrap();
    let lines = std::thread::spawn(move || {
        std::io::BufReader::new(stderr)
            .lines()
            .map_while(Result::ok)
            .map(|line| (Instant::now(), line))
            .collect::<Vec<_>>()
    });
    let addr: std::net::SocketAddr = ([127, 0, 0, 1], port).into();
    let until = Instant::now() + Duration::from_secs(60);
    while tokio::net::TcpStream::connect(addr).await.is_err() {
        assert!(Instant::now() < until, "the server did not listen");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let (sent, next_address) = (AtomicU64::new(0), AtomicU64::new(0));
    let started = Instant::now();
    futures_util::future::join_all((0..CLIENTS).map(|_| async {
        while started.elapsed() < RUN {
            // 127.1.0.0 and on: an address of its own for each request.
            let n = next_address.fetch_add(1, Ordering::Relaxed) as u32;
            let source = std::net::Ipv4Addr::from(0x7f01_0000 + n);
            let socket = tokio::net::TcpSocket::new_v4().unwrap();
            socket.bind((source, 0).into()).unwrap();
            let Ok(mut stream) = socket.connect(addr).await else {
                continue;
            };
            let request = format!(
                "GET /api/scene HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {WRONG}\r\nConnection: close\r\n\r\n"
            );
            if stream.write_all(request.as_bytes()).await.is_ok() {
                let mut answer = Vec::new();
                let _ = stream.read_to_end(&mut answer).await;
                if answer.starts_with(b"HTTP/1.1 401") {
                    sent.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    }))
    .await;
    let seconds = started.elapsed().as_secs_f64();
    // Stopped as an operator stops it (SIGTERM): its last summary line is written at its end.
    // SAFETY: `kill` of this test's own child, by its pid.
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
    let _ = child.wait();
    let lines = lines.join().unwrap();
    let during: Vec<&(Instant, String)> = lines
        .iter()
        .filter(|(at, _)| *at >= started && at.duration_since(started).as_secs_f64() < seconds)
        .collect();
    let mut per_second = vec![0u32; seconds.ceil() as usize];
    for (at, _) in &during {
        per_second[at.duration_since(started).as_secs() as usize] += 1;
    }
    let sent = sent.into_inner();
    println!(
        "{sent} wrong-token requests in {seconds:.1} s = {:.0} a second, from {sent} addresses; \
         the server wrote {} log lines meanwhile = {:.2} a second (most in one second: {}); \
         lines a second: {per_second:?}",
        sent as f64 / seconds,
        during.len(),
        during.len() as f64 / seconds,
        per_second.iter().max().unwrap_or(&0)
    );
    for (_, line) in during.iter().filter(|(_, l)| l.contains("not logged")) {
        println!("summary: {line}");
    }
}
