//! The real `softhaptic` binary serving TLS: with `--tls-self-signed` it prints the certificate
//! and its fingerprint and an `https://` link; a wss viewer that trusts exactly that certificate
//! presents its token and gets `hello`, `scene` and the contact stream; the page comes with its
//! security headers over https; plain http to the same port gets a short refusal.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, ServerName};
use rustls::{ClientConfig, RootCertStore};
use softhaptic_proto::wire::{Role, ServerMessage};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_rustls::TlsConnector;
use tokio_tungstenite::tungstenite::Message;

/// The server, killed when the test ends however it ends.
struct Server(Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts the binary with a self-signed certificate and tokens; returns it, the port, the
/// instructor's token, the printed fingerprint and the certificate file's path.
fn start(data_dir: &std::path::Path) -> (Server, u16, String, String, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_softhaptic"))
        .args([
            "--addr",
            "127.0.0.1:0",
            "--no-realtime",
            "--no-record",
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
    let (mut certificate, mut fingerprint) = (String::new(), String::new());
    let deadline = Instant::now() + Duration::from_secs(60);
    for line in BufReader::new(stdout).lines() {
        assert!(Instant::now() < deadline, "the server printed no link");
        let line = line.unwrap();
        if let Some(rest) = line.strip_prefix("TLS certificate: ") {
            certificate = rest.split(" (").next().unwrap().to_owned();
        }
        if let Some(rest) = line.strip_prefix("TLS certificate SHA-256 fingerprint: ") {
            fingerprint = rest.to_owned();
        }
        if let Some(link) = line.strip_prefix("viewer: ") {
            let rest = link
                .strip_prefix("https://127.0.0.1:")
                .unwrap_or_else(|| panic!("not an https link: {link}"));
            let (port, token) = rest.split_once("/#token=").unwrap();
            return (
                server,
                port.parse().unwrap(),
                token.to_owned(),
                fingerprint,
                certificate,
            );
        }
    }
    panic!("the server ended without printing its link");
}

fn client_trusting(certificate: &str) -> Arc<ClientConfig> {
    let mut roots = RootCertStore::empty();
    for cert in CertificateDer::pem_file_iter(certificate).unwrap() {
        roots.add(cert.unwrap()).unwrap();
    }
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    Arc::new(
        ClientConfig::builder_with_provider(provider)
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
    let (_server, port, token, fingerprint, certificate) = start(&data_dir);
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
    let mut stream = tls(addr, config).await;
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
    let _ = std::fs::remove_dir_all(&data_dir);
}
