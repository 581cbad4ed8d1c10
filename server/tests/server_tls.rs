//! The real `softhaptic` binary serving TLS: with `--tls-self-signed` it prints the certificate
//! and its fingerprint and an `https://` link; a wss viewer that trusts exactly that certificate
//! presents its token and gets `hello`, `scene` and the contact stream; the page comes with its
//! security headers over https; plain http, and a plain ws:// upgrade, to the same port get a
//! short refusal and the server goes on serving TLS. `softhaptic replay` serves a recording the
//! same way: a wss viewer pinning the printed fingerprint gets `hello` in replay mode with its
//! token's role, and an upgrade from a foreign Origin gets 403.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

mod support;

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, ServerName};
use rustls::{ClientConfig, RootCertStore};
use softhaptic_proto::wire::{Mode, Role, ServerMessage};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_rustls::TlsConnector;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

use support::{client_pinning, provider};

/// The server, killed when the test ends however it ends.
struct Server(Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// What a started server printed: its port, the instructor's and the observer's tokens, the
/// certificate's fingerprint and the path of its PEM file.
struct Printed {
    port: u16,
    instructor: String,
    observer: String,
    fingerprint: String,
    certificate: String,
}

/// Starts the binary with `command` (nothing for a live session, `replay FILE` for a replay), a
/// self-signed certificate kept in `data_dir` and tokens; returns it and what it printed once
/// it has printed both links (the instructor's after `link_label`, then the observer's).
fn start(command: &[&str], link_label: &str, data_dir: &std::path::Path) -> (Server, Printed) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_softhaptic"))
        .args(command)
        .args([
            "--addr",
            "127.0.0.1:0",
            "--tokens",
            "--tls-self-signed",
            "--data-dir",
        ])
        .arg(data_dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    let server = Server(child);
    let mut lines = BufReader::new(stdout).lines();
    let (mut certificate, mut fingerprint) = (String::new(), String::new());
    let mut instructor: Option<(u16, String)> = None;
    let deadline = Instant::now() + Duration::from_secs(60);
    while let Some(line) = lines.next() {
        assert!(Instant::now() < deadline, "the server printed no link");
        let line = line.unwrap();
        if let Some(rest) = line.strip_prefix("TLS certificate: ") {
            certificate = rest.split(" (").next().unwrap().to_owned();
        }
        if let Some(rest) = line.strip_prefix("TLS certificate SHA-256 fingerprint: ") {
            fingerprint = rest.to_owned();
        }
        if let Some(link) = line.strip_prefix(link_label) {
            instructor = Some(port_and_token(link, "instructor"));
        }
        if let Some(link) = line.strip_prefix("observer: ") {
            let (port, instructor) = instructor.expect("the instructor's link comes first");
            let (observer_port, observer) = port_and_token(link, "observer");
            assert_eq!(port, observer_port);
            // Keep reading, so that a later line never finds the pipe closed.
            std::thread::spawn(move || lines.for_each(drop));
            let printed = Printed {
                port,
                instructor,
                observer,
                fingerprint,
                certificate,
            };
            return (server, printed);
        }
    }
    panic!("the server ended without printing its links");
}

/// `https://127.0.0.1:PORT/#token=T&role=R` → (PORT, T); checks that the link names `role`.
fn port_and_token(link: &str, role: &str) -> (u16, String) {
    let rest = link
        .strip_prefix("https://127.0.0.1:")
        .unwrap_or_else(|| panic!("not an https link: {link}"));
    let (port, fragment) = rest.split_once("/#").unwrap();
    let (token, hint) = fragment
        .strip_prefix("token=")
        .and_then(|pairs| pairs.split_once("&role="))
        .unwrap_or_else(|| panic!("not token=…&role=… in {link}"));
    assert_eq!(hint, role, "the role hint of {link}");
    (port.parse().unwrap(), token.to_owned())
}

fn client_trusting(certificate: &str) -> Arc<ClientConfig> {
    let mut roots = RootCertStore::empty();
    for cert in CertificateDer::pem_file_iter(certificate).unwrap() {
        roots.add(cert.unwrap()).unwrap();
    }
    Arc::new(
        ClientConfig::builder_with_provider(provider())
            .with_safe_default_protocol_versions()
            .unwrap()
            .with_root_certificates(roots)
            .with_no_client_auth(),
    )
}

async fn tls(
    addr: SocketAddr,
    config: Arc<ClientConfig>,
) -> tokio_rustls::client::TlsStream<TcpStream> {
    let tcp = TcpStream::connect(addr).await.unwrap();
    let name = ServerName::try_from("127.0.0.1").unwrap();
    TlsConnector::from(config).connect(name, tcp).await.unwrap()
}

#[tokio::test]
async fn a_wss_viewer_trusting_the_self_signed_certificate_gets_the_stream() {
    let data_dir = std::env::temp_dir().join(format!("softhaptic-tls-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&data_dir);
    let (_server, printed) = start(&["--no-realtime", "--no-record"], "viewer: ", &data_dir);
    let Printed {
        port,
        instructor: token,
        fingerprint,
        certificate,
        ..
    } = printed;
    assert_eq!(fingerprint.split(':').count(), 32, "{fingerprint}");
    assert!(
        certificate.starts_with(&data_dir.display().to_string()),
        "{certificate}"
    );
    let addr: SocketAddr = ([127, 0, 0, 1], port).into();
    let config = client_trusting(&certificate);

    // The viewer's WebSocket over TLS: token first, then hello, scene and contact frames.
    let stream = tls(addr, Arc::clone(&config)).await;
    let url = format!("wss://127.0.0.1:{port}/ws");
    let (mut ws, _) = tokio_tungstenite::client_async(url, stream).await.unwrap();
    let auth = format!(r#"{{"type":"auth","token":"{token}"}}"#);
    ws.send(Message::text(auth)).await.unwrap();
    let mut seen = (false, false, 0);
    let deadline = Instant::now() + Duration::from_secs(30);
    while seen.2 < 5 {
        assert!(Instant::now() < deadline, "stream incomplete: {seen:?}");
        let next = tokio::time::timeout(Duration::from_secs(10), ws.next()).await;
        let text = match next.unwrap().unwrap().unwrap() {
            Message::Text(text) => text,
            Message::Close(frame) => panic!("the server closed the stream: {frame:?} ({seen:?})"),
            // Pings and pongs are the WebSocket layer's.
            _ => continue,
        };
        match ServerMessage::decode(&text).unwrap() {
            ServerMessage::Hello(h) => {
                assert_eq!(h.role, Role::Instructor);
                seen.0 = true;
            }
            ServerMessage::Scene(_) => seen.1 = true,
            ServerMessage::Contact(_) => seen.2 += 1,
            _ => {}
        }
    }
    assert!(seen.0 && seen.1, "{seen:?}");

    // The page over https, with its security headers.
    let mut stream = tls(addr, Arc::clone(&config)).await;
    stream
        .write_all(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
        .await
        .unwrap();
    let mut response = Vec::new();
    let _ = stream.read_to_end(&mut response).await;
    let response = String::from_utf8_lossy(&response).to_lowercase();
    assert!(response.starts_with("http/1.1 200"), "{response:.200}");
    assert!(
        response.contains("content-security-policy:"),
        "{response:.600}"
    );

    // Plain http to the TLS port: a short refusal, and the server keeps serving.
    let mut plain = TcpStream::connect(addr).await.unwrap();
    plain
        .write_all(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        .await
        .unwrap();
    let mut answer = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(10), plain.read_to_end(&mut answer)).await;
    let answer = String::from_utf8_lossy(&answer);
    assert!(answer.starts_with("HTTP/1.1 400"), "{answer}");
    assert!(answer.contains("https://"), "{answer}");

    // A plain ws:// upgrade to the TLS port: the same refusal, read by the WebSocket client as
    // an HTTP answer (not a hang, not a reset), and nothing upgraded.
    let plain = TcpStream::connect(addr).await.unwrap();
    let refused = tokio::time::timeout(
        Duration::from_secs(10),
        tokio_tungstenite::client_async(format!("ws://127.0.0.1:{port}/ws"), plain),
    )
    .await
    .expect("the plain upgrade is answered within 10 s");
    match refused {
        Err(tokio_tungstenite::tungstenite::Error::Http(response)) => {
            assert_eq!(response.status(), 400);
            let body = String::from_utf8_lossy(response.body().as_deref().unwrap_or_default());
            assert!(body.contains("https://"), "{body}");
        }
        Err(other) => panic!("a plain upgrade to the TLS port ended with {other}, not a 400"),
        Ok(_) => panic!("a plain ws:// upgrade to the TLS port was accepted"),
    }

    // The refusals cost the TLS side nothing: a new wss viewer is greeted as before.
    let stream = tls(addr, config).await;
    let url = format!("wss://127.0.0.1:{port}/ws");
    let (mut ws, _) = tokio_tungstenite::client_async(url, stream).await.unwrap();
    let auth = format!(r#"{{"type":"auth","token":"{token}"}}"#);
    ws.send(Message::text(auth)).await.unwrap();
    assert_eq!(first_hello(&mut ws).await.role, Role::Instructor);
    let _ = std::fs::remove_dir_all(&data_dir);
}

/// The first text message of a connection, which must be a `hello`.
async fn first_hello<S>(
    ws: &mut tokio_tungstenite::WebSocketStream<S>,
) -> softhaptic_proto::wire::Hello
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin,
{
    loop {
        let next = tokio::time::timeout(Duration::from_secs(10), ws.next())
            .await
            .expect("an answer within 10 s");
        match next.unwrap().unwrap() {
            Message::Text(text) => match ServerMessage::decode(&text) {
                Ok(ServerMessage::Hello(hello)) => return hello,
                other => panic!("the first message is not a hello: {other:?}"),
            },
            Message::Close(frame) => panic!("the server closed the connection: {frame:?}"),
            // Pings and pongs are the WebSocket layer's.
            _ => continue,
        }
    }
}

#[tokio::test]
async fn a_replay_served_over_tls_greets_each_token_with_its_role_and_refuses_a_foreign_origin() {
    let data_dir =
        std::env::temp_dir().join(format!("softhaptic-tls-replay-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&data_dir);
    let recording = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/sessions/sphere-press.mcap")
        .display()
        .to_string();
    let (_server, printed) = start(&["replay", &recording, "--paused"], "replay: ", &data_dir);
    assert_eq!(printed.fingerprint.split(':').count(), 32);
    let port = printed.port;
    let addr: SocketAddr = ([127, 0, 0, 1], port).into();
    // Trusted by the printed fingerprint alone, as a lab without a CA compares it.
    let config = client_pinning(&printed.fingerprint);
    let own_origin = format!("https://127.0.0.1:{port}");

    for (token, role) in [
        (&printed.instructor, Role::Instructor),
        (&printed.observer, Role::Observer),
    ] {
        let mut request = format!("wss://127.0.0.1:{port}/ws")
            .into_client_request()
            .unwrap();
        request
            .headers_mut()
            .insert("Origin", own_origin.parse().unwrap());
        let stream = tls(addr, Arc::clone(&config)).await;
        let (mut ws, _) = tokio_tungstenite::client_async(request, stream)
            .await
            .unwrap();
        let auth = format!(r#"{{"type":"auth","token":"{token}"}}"#);
        ws.send(Message::text(auth)).await.unwrap();
        let hello = first_hello(&mut ws).await;
        assert_eq!((hello.role, hello.mode), (role, Mode::Replay));
    }

    // A page on another site (or the same host over plain http) cannot open the replay's socket.
    for foreign in [
        "https://evil.example".to_owned(),
        format!("http://127.0.0.1:{port}"),
    ] {
        let mut request = format!("wss://127.0.0.1:{port}/ws")
            .into_client_request()
            .unwrap();
        request
            .headers_mut()
            .insert("Origin", foreign.parse().unwrap());
        let stream = tls(addr, Arc::clone(&config)).await;
        match tokio_tungstenite::client_async(request, stream).await {
            Err(tokio_tungstenite::tungstenite::Error::Http(response)) => {
                assert_eq!(response.status(), 403, "{foreign}");
            }
            Err(other) => panic!("{foreign}: the upgrade ended with {other}, not a 403"),
            Ok(_) => panic!("{foreign}: the upgrade was accepted"),
        }
    }

    // A certificate the client was not told about is not trusted: the pin is what secures it.
    let stranger = client_pinning(&["00"; 32].join(":"));
    let tcp = TcpStream::connect(addr).await.unwrap();
    let name = ServerName::try_from("127.0.0.1").unwrap();
    assert!(
        TlsConnector::from(stranger)
            .connect(name, tcp)
            .await
            .is_err()
    );
    let _ = std::fs::remove_dir_all(&data_dir);
}
