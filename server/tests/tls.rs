//! TLS on the viewer's port, through `softhaptic_server::tls` and a small router with an HTTP
//! route and a WebSocket route: a wss client that trusts exactly the self-signed certificate (or
//! pins its printed fingerprint) exchanges messages, https works over HTTP/1.1 and HTTP/2, a kept
//! certificate is reused and replaced when it no longer serves, the lab's own PEM files work, a
//! plain-text or silent client is refused without disturbing the next TLS client, and every bad
//! option or file gets an error that names it.
//!
//! An idle HTTP/2 connection is closed and cleartext HTTP/2 refused.
//!
//! One file because its 16 tests share one router, the clients' TLS setups and a lab CA.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

#[path = "../../tests/src/lab_ca.rs"]
mod lab_ca;
mod support;

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::body::Bytes;
use axum::extract::ConnectInfo;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::routing::get;
use clap::Parser;
use futures_util::{SinkExt, StreamExt};
use http_body_util::{BodyExt, Empty};
use hyper_util::rt::{TokioExecutor, TokioIo};
use lab_ca::LabCa;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, ServerName};
use rustls::{ClientConfig, RootCertStore};
use softhaptic_server::tls::{
    self, SELF_SIGNED_CERT_FILE, SELF_SIGNED_KEY_FILE, TlsArgs, TlsError, TlsSetup,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio::task::JoinHandle;
use tokio_rustls::TlsConnector;
use tokio_rustls::client::TlsStream;
use tokio_tungstenite::tungstenite;

use support::{client_pinning, provider};

const LOOPBACK: IpAddr = IpAddr::V4(Ipv4Addr::LOCALHOST);
/// A guard against a hang, never a measured time: every wait in these tests ends far sooner.
const HANG_GUARD: Duration = Duration::from_secs(20);

/// `GET /hello` answers `hello`; `GET /whoami` the client's address as the server saw it;
/// `/ws` greets with `welcome` (as the stream sends `hello` first) and then echoes text.
fn router() -> Router {
    Router::new()
        .route("/hello", get(|| async { "hello" }))
        .route(
            "/whoami",
            get(|ConnectInfo(client): ConnectInfo<SocketAddr>| async move { client.to_string() }),
        )
        .route(
            "/ws",
            get(|ws: WebSocketUpgrade| async { ws.on_upgrade(echo) }),
        )
}

async fn echo(mut socket: WebSocket) {
    if socket.send(Message::text("welcome")).await.is_err() {
        return;
    }
    while let Some(Ok(message)) = socket.recv().await {
        let Message::Text(text) = message else {
            continue;
        };
        if socket
            .send(Message::text(format!("echo {text}")))
            .await
            .is_err()
        {
            return;
        }
    }
}

/// A server on a free loopback port; TLS when `config` is given.
struct Server {
    addr: SocketAddr,
    shutdown: watch::Sender<bool>,
    task: JoinHandle<()>,
}

impl Server {
    async fn start(config: Option<Arc<rustls::ServerConfig>>) -> Server {
        let caps = tls::ConnectionCaps::for_limits(
            &softhaptic_server::access::ConnectionLimits::default(),
        );
        Server::start_with(config, caps).await
    }

    async fn start_with(
        config: Option<Arc<rustls::ServerConfig>>,
        caps: tls::ConnectionCaps,
    ) -> Server {
        let listener = TcpListener::bind((LOOPBACK, 0)).await.unwrap();
        let addr = listener.local_addr().unwrap();
        let (shutdown, shutdown_rx) = watch::channel(false);
        let task = tls::serve(listener, router(), config, caps, shutdown_rx);
        Server {
            addr,
            shutdown,
            task,
        }
    }

    async fn stop(self) {
        self.shutdown.send(true).unwrap();
        tokio::time::timeout(HANG_GUARD, self.task)
            .await
            .expect("the server did not stop")
            .unwrap();
    }
}

/// Self-signed options with their data directory.
fn self_signed_args(data_dir: &Path, names: &[&str]) -> TlsArgs {
    TlsArgs {
        tls_self_signed: true,
        tls_names: names.iter().map(|n| n.to_string()).collect(),
        data_dir: Some(data_dir.to_owned()),
        ..TlsArgs::default()
    }
}

/// A client that trusts exactly the certificates given (a self-signed certificate, or a CA).
fn client_trusting(anchors: &[CertificateDer<'static>], alpn: &[&[u8]]) -> Arc<ClientConfig> {
    let mut roots = RootCertStore::empty();
    for anchor in anchors {
        roots.add(anchor.clone()).unwrap();
    }
    let mut config = ClientConfig::builder_with_provider(provider())
        .with_safe_default_protocol_versions()
        .unwrap()
        .with_root_certificates(roots)
        .with_no_client_auth();
    config.alpn_protocols = alpn.iter().map(|p| p.to_vec()).collect();
    Arc::new(config)
}

/// The certificate file a lab would copy to its viewers' machines.
fn certificate_of(setup: &TlsSetup) -> CertificateDer<'static> {
    CertificateDer::pem_file_iter(&setup.certificate_path)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
}

async fn tls_connect(
    addr: SocketAddr,
    server_name: &str,
    config: Arc<ClientConfig>,
) -> std::io::Result<TlsStream<TcpStream>> {
    let tcp = TcpStream::connect(addr).await?;
    let name = ServerName::try_from(server_name.to_owned()).unwrap();
    TlsConnector::from(config).connect(name, tcp).await
}

/// Connects with wss, checks the greeting and one echo, closes.
async fn wss_round_trip(addr: SocketAddr, server_name: &str, config: Arc<ClientConfig>) {
    let tls = tls_connect(addr, server_name, config).await.unwrap();
    let url = format!("wss://{server_name}:{}/ws", addr.port());
    let (mut ws, response) = tokio_tungstenite::client_async(url, tls).await.unwrap();
    assert_eq!(response.status(), 101);
    let greeting = tokio::time::timeout(HANG_GUARD, ws.next()).await.unwrap();
    assert_eq!(greeting.unwrap().unwrap().into_text().unwrap(), "welcome");
    ws.send(tungstenite::Message::text("press")).await.unwrap();
    let reply = tokio::time::timeout(HANG_GUARD, ws.next()).await.unwrap();
    assert_eq!(reply.unwrap().unwrap().into_text().unwrap(), "echo press");
    ws.close(None).await.unwrap();
}

/// `GET path` over HTTP/1.1 or HTTP/2 (as ALPN chose) on a TLS connection.
async fn https_get(
    addr: SocketAddr,
    anchor: &CertificateDer<'static>,
    alpn: &[u8],
    path: &str,
) -> String {
    let tls = tls_connect(
        addr,
        "localhost",
        client_trusting(std::slice::from_ref(anchor), &[alpn]),
    )
    .await
    .unwrap();
    assert_eq!(tls.get_ref().1.alpn_protocol(), Some(alpn));
    let io = TokioIo::new(tls);
    let uri = format!("https://localhost:{}{path}", addr.port());
    let request = hyper::Request::get(uri)
        .header(hyper::header::HOST, format!("localhost:{}", addr.port()))
        .body(Empty::<Bytes>::new())
        .unwrap();
    let response = if alpn == b"h2" {
        let (mut sender, connection) =
            hyper::client::conn::http2::handshake(TokioExecutor::new(), io)
                .await
                .unwrap();
        tokio::spawn(connection);
        sender.send_request(request).await.unwrap()
    } else {
        let (mut sender, connection) = hyper::client::conn::http1::handshake(io).await.unwrap();
        tokio::spawn(connection);
        sender.send_request(request).await.unwrap()
    };
    assert_eq!(response.status(), 200);
    let body = response.into_body().collect().await.unwrap().to_bytes();
    String::from_utf8(body.to_vec()).unwrap()
}

#[tokio::test]
async fn a_wss_viewer_that_trusts_the_self_signed_certificate_exchanges_messages() {
    let dir = tempfile::tempdir().unwrap();
    let setup = tls::server_config(&self_signed_args(dir.path(), &[]), LOOPBACK)
        .unwrap()
        .unwrap();
    assert!(setup.generated);
    // Self-signed: never Strict-Transport-Security (a browser would refuse the click-through).
    assert!(!setup.from_a_ca);
    assert_eq!(setup.self_signed_names, ["localhost", "127.0.0.1"]);
    assert_eq!(
        setup.certificate_path,
        dir.path().join(SELF_SIGNED_CERT_FILE)
    );
    let certificate = certificate_of(&setup);
    // The printed fingerprint is the SHA-256 of the certificate the server presents.
    assert_eq!(
        setup.fingerprint_sha256,
        tls::fingerprint_sha256(certificate.as_ref())
    );
    assert_eq!(setup.fingerprint_sha256.len(), 32 * 3 - 1);
    assert!(setup.to_string().contains(&setup.fingerprint_sha256));

    let server = Server::start(Some(setup.config.clone())).await;
    // Both default names verify: a viewer may type either.
    for name in ["localhost", "127.0.0.1"] {
        wss_round_trip(
            server.addr,
            name,
            client_trusting(std::slice::from_ref(&certificate), &[]),
        )
        .await;
    }
    server.stop().await;
}

#[tokio::test]
async fn a_client_that_pins_the_printed_fingerprint_connects_and_one_pinning_another_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let setup = tls::server_config(&self_signed_args(dir.path(), &[]), LOOPBACK)
        .unwrap()
        .unwrap();
    let server = Server::start(Some(setup.config.clone())).await;

    wss_round_trip(
        server.addr,
        "localhost",
        client_pinning(&setup.fingerprint_sha256),
    )
    .await;

    let mut wrong = setup.fingerprint_sha256.clone();
    wrong.replace_range(0..2, if wrong.starts_with("00") { "11" } else { "00" });
    let refused = tls_connect(server.addr, "localhost", client_pinning(&wrong)).await;
    assert!(
        refused.is_err(),
        "a client pinning another fingerprint connected"
    );

    // Nor does a client that trusts some other certificate get in.
    let other = rcgen::generate_simple_self_signed(vec!["localhost".to_owned()]).unwrap();
    let refused = tls_connect(
        server.addr,
        "localhost",
        client_trusting(&[other.cert.der().clone()], &[]),
    )
    .await;
    assert!(
        refused.is_err(),
        "a client trusting another certificate connected"
    );
    // And the server still serves the next client.
    wss_round_trip(
        server.addr,
        "localhost",
        client_trusting(&[certificate_of(&setup)], &[]),
    )
    .await;
    server.stop().await;
}

#[tokio::test]
async fn https_get_works_over_http1_and_http2_and_requests_carry_the_client_address() {
    let dir = tempfile::tempdir().unwrap();
    let setup = tls::server_config(&self_signed_args(dir.path(), &[]), LOOPBACK)
        .unwrap()
        .unwrap();
    let server = Server::start(Some(setup.config.clone())).await;
    let certificate = certificate_of(&setup);
    assert_eq!(
        https_get(server.addr, &certificate, b"http/1.1", "/hello").await,
        "hello"
    );
    assert_eq!(
        https_get(server.addr, &certificate, b"h2", "/hello").await,
        "hello"
    );
    let client: SocketAddr = https_get(server.addr, &certificate, b"http/1.1", "/whoami")
        .await
        .parse()
        .unwrap();
    assert_eq!(client.ip(), LOOPBACK);
    server.stop().await;
}

#[tokio::test]
async fn an_idle_http2_connection_is_closed_and_a_quiet_websocket_is_not() {
    let dir = tempfile::tempdir().unwrap();
    let setup = tls::server_config(&self_signed_args(dir.path(), &[]), LOOPBACK)
        .unwrap()
        .unwrap();
    // The idle time made short for the test (30 s in service): what is tested is that the
    // connection ends at all, within a generous deadline, not when.
    let caps = tls::ConnectionCaps {
        http2_idle_timeout: Duration::from_millis(300),
        ..tls::ConnectionCaps::for_limits(&softhaptic_server::access::ConnectionLimits::default())
    };
    let server = Server::start_with(Some(setup.config.clone()), caps).await;
    let certificate = certificate_of(&setup);

    let tls = tls_connect(
        server.addr,
        "localhost",
        client_trusting(std::slice::from_ref(&certificate), &[b"h2"]),
    )
    .await
    .unwrap();
    let (mut sender, connection) =
        hyper::client::conn::http2::handshake(TokioExecutor::new(), TokioIo::new(tls))
            .await
            .unwrap();
    let connection = tokio::spawn(connection);
    let request = hyper::Request::get(format!("https://localhost:{}/hello", server.addr.port()))
        .body(Empty::<Bytes>::new())
        .unwrap();
    let response = sender.send_request(request).await.unwrap();
    assert_eq!(response.status(), 200);
    drop(response);
    // Then nothing: the server ends the connection (the client's connection task returns).
    let ended = tokio::time::timeout(HANG_GUARD, connection).await;
    assert!(ended.is_ok(), "the idle HTTP/2 connection is still open");

    // A WebSocket (HTTP/1.1) quiet for longer than that is still served: a paused replay's
    // viewer sends nothing for minutes.
    let tls = tls_connect(
        server.addr,
        "localhost",
        client_trusting(std::slice::from_ref(&certificate), &[]),
    )
    .await
    .unwrap();
    let url = format!("wss://localhost:{}/ws", server.addr.port());
    let (mut ws, _) = tokio_tungstenite::client_async(url, tls).await.unwrap();
    let greeting = tokio::time::timeout(HANG_GUARD, ws.next()).await.unwrap();
    assert_eq!(greeting.unwrap().unwrap().into_text().unwrap(), "welcome");
    tokio::time::sleep(caps.http2_idle_timeout * 3).await;
    ws.send(tungstenite::Message::text("still here"))
        .await
        .unwrap();
    let reply = tokio::time::timeout(HANG_GUARD, ws.next()).await.unwrap();
    assert_eq!(
        reply.unwrap().unwrap().into_text().unwrap(),
        "echo still here"
    );
    server.stop().await;
}

#[tokio::test]
async fn cleartext_http2_is_refused_on_a_plain_port() {
    let server = Server::start(None).await;
    // Prior knowledge (RFC 9113 §3.3): the preface, then an empty SETTINGS frame.
    let mut h2c = TcpStream::connect(server.addr).await.unwrap();
    h2c.write_all(b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n\0\0\0\x04\0\0\0\0\0")
        .await
        .unwrap();
    let mut answer = Vec::new();
    // Closed, or reset (the server drops it with the client's frame unread).
    let _closed_or_reset = tokio::time::timeout(HANG_GUARD, h2c.read_to_end(&mut answer))
        .await
        .expect("the h2c connection was not closed");
    // No HTTP/2 frame (a server's first is SETTINGS, type 4 in its fourth byte): at most an
    // HTTP/1.1 error.
    assert!(
        answer.is_empty() || answer.starts_with(b"HTTP/1.1 4") || answer.starts_with(b"HTTP/1.1 5"),
        "{:?}",
        String::from_utf8_lossy(&answer)
    );
    // HTTP/1.1 on the same port is served as before.
    let mut http = TcpStream::connect(server.addr).await.unwrap();
    http.write_all(b"GET /hello HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n")
        .await
        .unwrap();
    let mut answer = String::new();
    http.read_to_string(&mut answer).await.unwrap();
    assert!(answer.starts_with("HTTP/1.1 200 OK\r\n"), "{answer}");
    server.stop().await;
}

#[tokio::test]
async fn a_second_start_reuses_the_kept_certificate_and_keeps_its_key_private() {
    let dir = tempfile::tempdir().unwrap();
    // A data directory that does not exist yet, two levels down.
    let data_dir = dir.path().join("share").join("softhaptic");
    let first = tls::server_config(&self_signed_args(&data_dir, &[]), LOOPBACK)
        .unwrap()
        .unwrap();
    assert!(first.generated);
    let mode = |path: &Path| std::fs::metadata(path).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode(&data_dir), 0o700);
    assert_eq!(mode(&data_dir.join(SELF_SIGNED_KEY_FILE)), 0o600);

    let second = tls::server_config(&self_signed_args(&data_dir, &[]), LOOPBACK)
        .unwrap()
        .unwrap();
    assert!(!second.generated && !second.from_a_ca);
    assert_eq!(second.fingerprint_sha256, first.fingerprint_sha256);
    assert!(second.to_string().contains("kept from an earlier start"));

    // The reused certificate and key really serve: a client that trusted the first start's
    // certificate connects to the second start.
    let server = Server::start(Some(second.config.clone())).await;
    wss_round_trip(
        server.addr,
        "localhost",
        client_trusting(&[certificate_of(&first)], &[]),
    )
    .await;
    server.stop().await;
}

#[tokio::test]
async fn a_kept_certificate_that_does_not_name_a_requested_host_is_replaced() {
    let dir = tempfile::tempdir().unwrap();
    let first = tls::server_config(&self_signed_args(dir.path(), &[]), LOOPBACK)
        .unwrap()
        .unwrap();
    // Now the server listens on the lab's address and names the machine.
    let lab_names = ["lab-pc.local", "localhost"];
    let bind: IpAddr = "127.0.0.2".parse().unwrap();
    let second = tls::server_config(&self_signed_args(dir.path(), &lab_names), bind)
        .unwrap()
        .unwrap();
    assert!(second.generated);
    assert_ne!(second.fingerprint_sha256, first.fingerprint_sha256);
    assert_eq!(
        second.self_signed_names,
        ["lab-pc.local", "localhost", "127.0.0.2"]
    );

    // The new certificate names the machine: a viewer connecting by that name verifies it.
    let server = Server::start(Some(second.config.clone())).await;
    wss_round_trip(
        server.addr,
        "lab-pc.local",
        client_trusting(&[certificate_of(&second)], &[]),
    )
    .await;
    server.stop().await;

    // A start asking for some of the kept certificate's names keeps it (and its fingerprint).
    let subset = tls::server_config(&self_signed_args(dir.path(), &["localhost"]), bind)
        .unwrap()
        .unwrap();
    assert!(!subset.generated);
    assert_eq!(subset.fingerprint_sha256, second.fingerprint_sha256);
}

/// Writes a self-signed certificate for `localhost` and `127.0.0.1` valid until `not_after` into
/// the data directory, as an earlier start would have.
fn keep_certificate_until(dir: &Path, not_after: time::OffsetDateTime) -> String {
    let key = rcgen::KeyPair::generate().unwrap();
    let mut params =
        rcgen::CertificateParams::new(vec!["localhost".to_owned(), "127.0.0.1".to_owned()])
            .unwrap();
    params.not_before = not_after - time::Duration::days(365);
    params.not_after = not_after;
    let cert = params.self_signed(&key).unwrap();
    std::fs::write(dir.join(SELF_SIGNED_CERT_FILE), cert.pem()).unwrap();
    std::fs::write(dir.join(SELF_SIGNED_KEY_FILE), key.serialize_pem()).unwrap();
    tls::fingerprint_sha256(cert.der().as_ref())
}

#[test]
fn an_expired_or_expiring_kept_certificate_is_replaced_and_a_lasting_one_is_kept() {
    let now = time::OffsetDateTime::now_utc();
    let cases = [
        (now - time::Duration::days(1), true),
        (now + time::Duration::days(10), true),
        (now + time::Duration::days(200), false),
    ];
    for (not_after, replaced) in cases {
        let dir = tempfile::tempdir().unwrap();
        let kept = keep_certificate_until(dir.path(), not_after);
        let setup = tls::server_config(&self_signed_args(dir.path(), &[]), LOOPBACK)
            .unwrap()
            .unwrap();
        assert_eq!(setup.generated, replaced, "expiring {not_after}");
        assert_eq!(
            setup.fingerprint_sha256 != kept,
            replaced,
            "expiring {not_after}"
        );
    }
}

#[test]
fn damaged_or_mismatched_kept_files_are_replaced_not_fatal() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join(SELF_SIGNED_CERT_FILE), "not a certificate").unwrap();
    let first = tls::server_config(&self_signed_args(dir.path(), &[]), LOOPBACK)
        .unwrap()
        .unwrap();
    assert!(first.generated);

    // A key from elsewhere beside the kept certificate (a start that died between its writes).
    let stray = rcgen::KeyPair::generate().unwrap();
    std::fs::write(dir.path().join(SELF_SIGNED_KEY_FILE), stray.serialize_pem()).unwrap();
    let second = tls::server_config(&self_signed_args(dir.path(), &[]), LOOPBACK)
        .unwrap()
        .unwrap();
    assert!(second.generated);
    assert_ne!(second.fingerprint_sha256, first.fingerprint_sha256);
}

#[tokio::test]
async fn plain_http_and_plain_ws_to_the_tls_port_are_refused_and_the_next_tls_client_is_served() {
    let dir = tempfile::tempdir().unwrap();
    let setup = tls::server_config(&self_signed_args(dir.path(), &[]), LOOPBACK)
        .unwrap()
        .unwrap();
    let server = Server::start(Some(setup.config.clone())).await;
    let trusting = client_trusting(&[certificate_of(&setup)], &[]);

    // A client that connects and says nothing holds only its own socket meanwhile.
    let silent = TcpStream::connect(server.addr).await.unwrap();

    // A browser pointed at http:// is told to use https:// and closed.
    let mut plain = TcpStream::connect(server.addr).await.unwrap();
    plain
        .write_all(b"GET / HTTP/1.1\r\nHost: localhost\r\n\r\n")
        .await
        .unwrap();
    let mut answer = String::new();
    tokio::time::timeout(HANG_GUARD, plain.read_to_string(&mut answer))
        .await
        .unwrap()
        .unwrap();
    assert!(
        answer.starts_with("HTTP/1.1 400 Bad Request\r\n"),
        "{answer}"
    );
    let (head, body) = answer.split_once("\r\n\r\n").unwrap();
    assert!(body.contains("https://"), "{answer}");
    assert!(
        head.contains(&format!("Content-Length: {}\r\n", body.len())),
        "{answer}"
    );

    // A ws:// viewer gets an error, not a stream.
    let url = format!("ws://localhost:{}/ws", server.addr.port());
    match tokio::time::timeout(HANG_GUARD, tokio_tungstenite::connect_async(url))
        .await
        .unwrap()
    {
        Err(tungstenite::Error::Http(response)) => assert_eq!(response.status(), 400),
        Err(other) => panic!("expected a 400 refusal, got {other}"),
        Ok(_) => panic!("a plain ws:// viewer was streamed to on the TLS port"),
    }

    // Bytes that are not TLS at all end in a closed connection too.
    let mut garbage = TcpStream::connect(server.addr).await.unwrap();
    garbage.write_all(&[0xff; 64]).await.unwrap();
    let mut rest = Vec::new();
    let _ = tokio::time::timeout(HANG_GUARD, garbage.read_to_end(&mut rest))
        .await
        .unwrap();

    // The next TLS client is served while the silent one still waits.
    wss_round_trip(server.addr, "localhost", trusting).await;
    drop(silent);
    server.stop().await;
}

#[tokio::test(start_paused = true)]
async fn a_client_that_never_starts_the_handshake_is_closed_after_the_handshake_timeout() {
    let dir = tempfile::tempdir().unwrap();
    let setup = tls::server_config(&self_signed_args(dir.path(), &[]), LOOPBACK)
        .unwrap()
        .unwrap();
    let server = Server::start(Some(setup.config.clone())).await;
    let mut silent = TcpStream::connect(server.addr).await.unwrap();
    let started = tokio::time::Instant::now();
    let mut buffer = [0_u8; 16];
    // The clock is paused: it moves only when every task waits, straight to the next timer.
    let read = silent.read(&mut buffer).await;
    assert!(matches!(read, Ok(0) | Err(_)), "{read:?}");
    assert!(started.elapsed() >= tls::HANDSHAKE_TIMEOUT);
    server.stop().await;
}

#[tokio::test]
async fn shutdown_ends_the_serve_task_and_stops_accepting() {
    let dir = tempfile::tempdir().unwrap();
    let setup = tls::server_config(&self_signed_args(dir.path(), &[]), LOOPBACK)
        .unwrap()
        .unwrap();
    let server = Server::start(Some(setup.config.clone())).await;
    let addr = server.addr;
    // Neither an idle connection nor an open WebSocket holds the shutdown up (a WebSocket is the
    // router's to close: the real server's viewer tasks close theirs on the same signal).
    let certificate = certificate_of(&setup);
    let trusting = client_trusting(std::slice::from_ref(&certificate), &[]);
    let idle = tls_connect(addr, "localhost", trusting.clone())
        .await
        .unwrap();
    let tls = tls_connect(addr, "localhost", trusting).await.unwrap();
    let url = format!("wss://localhost:{}/ws", addr.port());
    let (mut ws, _) = tokio_tungstenite::client_async(url, tls).await.unwrap();
    assert_eq!(
        ws.next().await.unwrap().unwrap().into_text().unwrap(),
        "welcome"
    );
    server.stop().await;
    drop(idle);
    assert!(TcpStream::connect(addr).await.is_err());
}

#[tokio::test]
async fn without_tls_options_the_server_is_plain_http_and_ws() {
    assert!(
        tls::server_config(&TlsArgs::default(), LOOPBACK)
            .unwrap()
            .is_none()
    );
    let server = Server::start(None).await;

    let mut http = TcpStream::connect(server.addr).await.unwrap();
    http.write_all(b"GET /whoami HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n")
        .await
        .unwrap();
    let mut answer = String::new();
    http.read_to_string(&mut answer).await.unwrap();
    assert!(answer.starts_with("HTTP/1.1 200 OK\r\n"), "{answer}");
    let client = http.local_addr().unwrap();
    assert!(answer.ends_with(&client.to_string()), "{answer}");

    let url = format!("ws://localhost:{}/ws", server.addr.port());
    let (mut ws, _) = tokio_tungstenite::connect_async(url).await.unwrap();
    let greeting = ws.next().await.unwrap().unwrap();
    assert_eq!(greeting.into_text().unwrap(), "welcome");
    ws.close(None).await.unwrap();
    server.stop().await;
}

#[tokio::test]
async fn a_certificate_and_key_from_pem_files_serve_wss_to_a_client_that_trusts_the_ca() {
    let dir = tempfile::tempdir().unwrap();
    let ca = LabCa::new(&["lab-pc.local", "localhost"]);
    let cert_path = dir.path().join("lab-pc.crt");
    let key_path = dir.path().join("lab-pc.key");
    // The server's certificate, then the chain, as a CA delivers it.
    std::fs::write(&cert_path, format!("{}{}", ca.server_pem, ca.ca_pem)).unwrap();
    std::fs::write(&key_path, &ca.server_key_pem).unwrap();
    let args = TlsArgs {
        tls_cert: Some(cert_path.clone()),
        tls_key: Some(key_path),
        ..TlsArgs::default()
    };
    let setup = tls::server_config(&args, LOOPBACK).unwrap().unwrap();
    assert!(!setup.generated);
    assert!(setup.self_signed_names.is_empty());
    // A CA's certificate: browsers may be told to use https only (Strict-Transport-Security).
    assert!(setup.from_a_ca);
    assert_eq!(setup.certificate_path, cert_path);
    assert_eq!(
        setup.fingerprint_sha256,
        tls::fingerprint_sha256(&ca.server_der)
    );

    let server = Server::start(Some(setup.config.clone())).await;
    wss_round_trip(
        server.addr,
        "lab-pc.local",
        client_trusting(&[CertificateDer::from(ca.ca_der.clone())], &[]),
    )
    .await;
    server.stop().await;
}

/// The error of `server_config` for `args`, and its message.
fn error_of(args: &TlsArgs) -> (TlsError, String) {
    let error = tls::server_config(args, LOOPBACK).unwrap_err();
    let message = error.to_string();
    (error, message)
}

fn given(cert: &Path, key: &Path) -> TlsArgs {
    TlsArgs {
        tls_cert: Some(cert.to_owned()),
        tls_key: Some(key.to_owned()),
        ..TlsArgs::default()
    }
}

fn write(dir: &Path, name: &str, contents: impl AsRef<[u8]>) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, contents).unwrap();
    path
}

#[test]
fn bad_files_give_errors_that_name_the_file_and_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let ca = LabCa::new(&["lab-pc.local", "localhost"]);
    let cert = write(dir.path(), "server.crt", &ca.server_pem);
    let key = write(dir.path(), "server.key", &ca.server_key_pem);
    let missing = dir.path().join("missing.crt");
    let der = write(dir.path(), "server.der", &ca.server_der);
    let other_key = write(
        dir.path(),
        "other.key",
        rcgen::KeyPair::generate().unwrap().serialize_pem(),
    );
    let encrypted = write(
        dir.path(),
        "encrypted.key",
        "-----BEGIN ENCRYPTED PRIVATE KEY-----\nAAAA\n-----END ENCRYPTED PRIVATE KEY-----\n",
    );
    let truncated = write(
        dir.path(),
        "truncated.crt",
        &ca.server_pem[..ca.server_pem.len() / 2],
    );
    let shown = |path: &Path| path.display().to_string();

    let (error, message) = error_of(&given(&missing, &key));
    assert!(matches!(error, TlsError::Read { .. }), "{message}");
    assert!(message.contains(&shown(&missing)), "{message}");

    let (error, message) = error_of(&given(&der, &key));
    assert!(matches!(error, TlsError::NotPem { .. }), "{message}");
    assert!(
        message.contains(&shown(&der)) && message.contains("not a PEM file"),
        "{message}"
    );

    // The two files swapped: each says what it holds instead.
    let (error, message) = error_of(&given(&key, &cert));
    assert!(matches!(error, TlsError::NoCertificate { .. }), "{message}");
    assert!(
        message.contains(&shown(&key)) && message.contains("PRIVATE KEY"),
        "{message}"
    );
    let (error, message) = error_of(&given(&cert, &cert));
    assert!(matches!(error, TlsError::NoPrivateKey { .. }), "{message}");
    assert!(
        message.contains("holds no private key") && message.contains("CERTIFICATE"),
        "{message}"
    );

    let (error, message) = error_of(&given(&cert, &encrypted));
    assert!(matches!(error, TlsError::EncryptedKey { .. }), "{message}");
    assert!(message.contains(&shown(&encrypted)), "{message}");

    let (error, message) = error_of(&given(&cert, &other_key));
    assert!(matches!(error, TlsError::KeyMismatch { .. }), "{message}");
    assert!(
        message.contains(&shown(&other_key)) && message.contains(&shown(&cert)),
        "{message}"
    );

    let (error, message) = error_of(&given(&truncated, &key));
    assert!(matches!(error, TlsError::BadPem { .. }), "{message}");
    assert!(message.contains(&shown(&truncated)), "{message}");

    // A data directory that cannot be made.
    let (error, message) = error_of(&self_signed_args(&cert.join("sub"), &[]));
    assert!(matches!(error, TlsError::DataDir { .. }), "{message}");
    assert!(message.contains(&shown(&cert.join("sub"))), "{message}");
}

#[test]
fn options_that_do_not_go_together_are_refused_by_server_config_and_by_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    let cert = dir.path().join("server.crt");
    let key = dir.path().join("server.key");

    let both = TlsArgs {
        tls_self_signed: true,
        ..given(&cert, &key)
    };
    assert!(matches!(error_of(&both).0, TlsError::CertAndSelfSigned));
    let cert_only = TlsArgs {
        tls_cert: Some(cert.clone()),
        ..TlsArgs::default()
    };
    let (error, message) = error_of(&cert_only);
    assert!(
        matches!(error, TlsError::CertWithoutKey { .. }),
        "{message}"
    );
    assert!(message.contains("--tls-key"), "{message}");
    let key_only = TlsArgs {
        tls_key: Some(key.clone()),
        ..TlsArgs::default()
    };
    assert!(matches!(
        error_of(&key_only).0,
        TlsError::KeyWithoutCert { .. }
    ));
    let names_only = TlsArgs {
        tls_names: vec!["lab-pc.local".into()],
        ..TlsArgs::default()
    };
    assert!(matches!(
        error_of(&names_only).0,
        TlsError::NamesWithoutSelfSigned
    ));
    let (error, message) = error_of(&self_signed_args(dir.path(), &["*.lab.local"]));
    assert!(matches!(error, TlsError::InvalidName { .. }), "{message}");
    assert!(message.contains("*.lab.local"), "{message}");

    // The command line refuses the same combinations before anything runs.
    #[derive(Parser, Debug)]
    struct Cli {
        #[command(flatten)]
        tls: TlsArgs,
    }
    let parse = |args: &[&str]| {
        Cli::try_parse_from(std::iter::once("softhaptic").chain(args.iter().copied()))
    };
    assert!(parse(&["--tls-cert", "a.crt"]).is_err());
    assert!(parse(&["--tls-key", "a.key"]).is_err());
    assert!(
        parse(&[
            "--tls-cert",
            "a.crt",
            "--tls-key",
            "a.key",
            "--tls-self-signed"
        ])
        .is_err()
    );
    assert!(parse(&["--tls-name", "lab-pc.local"]).is_err());
    let cli = parse(&[
        "--tls-self-signed",
        "--tls-name",
        "lab-pc.local",
        "--tls-name",
        "10.1.2.3",
        "--data-dir",
        "/srv/softhaptic",
    ])
    .unwrap();
    assert_eq!(cli.tls.tls_names, ["lab-pc.local", "10.1.2.3"]);
    assert_eq!(cli.tls.data_dir, Some(PathBuf::from("/srv/softhaptic")));
    assert_eq!(parse(&[]).unwrap().tls, TlsArgs::default());
}
