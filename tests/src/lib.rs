//! Whole-system tests of the soft-object haptic simulator.
//!
//! # Layout
//! - `tests/server_*.rs`: the real server (library [`start`](softhaptic_server::app::start) on
//!   127.0.0.1:0, the real haptic loop thread and simulated device) spoken to by real WebSocket
//!   and HTTP clients.
//! - this library: the helpers those tests share ([`start_default`], [`Viewer`] with
//!   [`Viewer::connect_with`] for the access tests' Origin, Host and token, [`http_get`] and
//!   [`http_request`], [`scratch_dir`], [`repo_scenes`]).
//! - [`softhaptic_binary`]: the built `softhaptic`, for the tests that run it as a user does
//!   (`tests/spacemouse.rs`'s `softhaptic check`, `tests/openhaptics_cli.rs`).
//! - [`standin`] and `tests/hd_standin.rs`: the HD API stand-in (`standin/hd_standin.c`, built by
//!   `build.rs` into a `libHD.so` the OpenHaptics backend loads in place of the vendor's), its
//!   path and a handle on its test controls; the test file checks the stand-in keeps the HD
//!   API's rules.
//! - [`dhd_standin`] and `tests/dhd_standin.rs`: the same for the Force Dimension SDK
//!   (`standin/dhd_standin.c`, a `libdhd.so`), whose hand is the HD stand-in's
//!   (`standin/standin_hand.h`); `tests/forcedimension_device.rs` checks its rules and drives
//!   the server through it.
//! - [`device_checks`]: the assertions the real-device tests share (the ramp back after a fault,
//!   the contact held when a hand pushes a 1 mm sphere through, the force sent for each reading).
//! - [`standin_cli`]: the `softhaptic` program run against a stand-in until the hand presses,
//!   then signalled, with what the stand-in reported.
//! - [`fuzz`]: a mutation fuzzer of every parser that takes outside input (scene, OBJ,
//!   calibration and limits JSON, recordings, wire messages), run offline by `fuzz-report` and
//!   briefly by `tests/fuzz_seeded.rs`.
//! - [`lab_ca`]: a lab's certificate authority and a server certificate it signed, for the TLS
//!   tests (the server's `tests/tls.rs` includes the file by its path).
//! - [`crafted`]: recordings made to hurt their reader (valid, but padded to decode to far more
//!   than their size), for `tests/recording_limits.rs` and `padded-recording`.

pub mod crafted;
pub mod device_checks;
pub mod dhd_standin;
pub mod fuzz;
pub mod lab_ca;
pub mod nats;
pub mod standin;
pub mod standin_cli;

use std::net::{IpAddr, SocketAddr};
use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use softhaptic_proto::wire::{DecodeError, ServerMessage};
use softhaptic_server::app::{self, RunningServer, ServerOptions};
use softhaptic_server::scene::Scene;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::HeaderValue;

/// The instructor's and the observer's tokens of [`test_tokens`].
pub const INSTRUCTOR_TOKEN: &str = "1f0e2d3c4b5a69788796a5b4c3d2e1f0";
pub const OBSERVER_TOKEN: &str = "00112233445566778899aabbccddeeff";

/// Fixed tokens for the two roles, as a lab that keeps stable links sets them.
pub fn test_tokens() -> std::sync::Arc<softhaptic_server::access::Tokens> {
    use softhaptic_proto::wire::Role;
    use softhaptic_server::access::{Token, TokenSource, Tokens};
    let token =
        |t: &str, role| Token::parse(t, role).unwrap_or_else(|e| panic!("a test token: {e}"));
    std::sync::Arc::new(
        Tokens::new(
            token(INSTRUCTOR_TOKEN, Role::Instructor),
            token(OBSERVER_TOKEN, Role::Observer),
            TokenSource::Environment,
        )
        .unwrap_or_else(|e| panic!("the test tokens: {e}")),
    )
}

/// The server options every test starts from: port 0, no real-time request (tests share the
/// machine), the viewer built into the binary.
pub fn test_options() -> ServerOptions {
    let addr: SocketAddr = ([127, 0, 0, 1], 0).into();
    let mut options = ServerOptions::new(addr);
    options.realtime = false;
    options
}

/// A live server whose session is recorded into a directory, as `softhaptic run` records it.
pub struct RecordedServer {
    pub server: RunningServer,
    pub recording: softhaptic_server::session::cli::LiveRecording,
}

/// Starts `scene` with `options`, recording the session into `record_dir`.
pub async fn start_recorded(
    scene: Scene,
    record_dir: &std::path::Path,
    options: ServerOptions,
) -> RecordedServer {
    start_recorded_observed(scene, record_dir, options, None).await
}

/// [`start_recorded`], with every recorded tick shown to `observer` (a station's exercises).
pub async fn start_recorded_observed(
    scene: Scene,
    record_dir: &std::path::Path,
    mut options: ServerOptions,
    observer: Option<Box<dyn softhaptic_server::session::writer::TickObserver>>,
) -> RecordedServer {
    let args = softhaptic_server::session::cli::RecordArgs {
        no_record: false,
        record_dir: record_dir.to_path_buf(),
    };
    let mut recording = softhaptic_server::session::cli::LiveRecording::start_observed(
        &args, &scene, None, observer,
    )
    .expect("the recording starts")
    .expect("recording is on");
    options.tick_sink = recording.take_tick_sink();
    options.session_id = Some(recording.session_id().to_owned());
    let server = app::start(scene, options).await.expect("the server starts");
    recording.attach(&server);
    RecordedServer { server, recording }
}

impl RecordedServer {
    /// Stops the server, closes the recording with the loop's final metrics, and returns the
    /// loop's statistics, those metrics and the recording's path.
    pub async fn finish(
        self,
    ) -> (
        softhaptic_device::stats::LoopStats,
        softhaptic_device::metrics::TraineeMetrics,
        std::path::PathBuf,
        softhaptic_proto::record::RecordingStats,
    ) {
        let (stats, metrics) = self.server.shutdown_with_metrics().await;
        let (path, recorded) = self
            .recording
            .finish(&metrics)
            .expect("the recording closes");
        (stats, metrics, path, recorded)
    }
}

/// A replay's options: a free loopback port, the built-in viewer, no tokens, at `speed`,
/// paused or playing from the start.
pub fn replay_options(
    speed: f64,
    start_paused: bool,
) -> softhaptic_server::session::replay::ReplayOptions {
    softhaptic_server::session::replay::ReplayOptions {
        addr: ([127, 0, 0, 1], 0).into(),
        viewer: Default::default(),
        speed,
        start_paused,
        viewer_limits: softhaptic_server::stream::ViewerLimits::default(),
        access: softhaptic_server::access::AccessConfig::default(),
        tls: None,
    }
}

/// Starts the built-in default scene with `options`.
pub async fn start_default(options: ServerOptions) -> RunningServer {
    let scene = Scene::builtin_default().expect("the built-in scene loads");
    app::start(scene, options).await.expect("the server starts")
}

type Socket =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// A WebSocket viewer connected to a running server.
pub struct Viewer {
    pub socket: Socket,
}

impl Viewer {
    /// Connects to a WebSocket `url` (a hub's `ws://…/ws?station=NAME`, say).
    pub async fn connect_url(url: &str) -> Viewer {
        let (socket, _) = tokio_tungstenite::connect_async(url)
            .await
            .expect("WebSocket connects");
        Viewer { socket }
    }

    pub async fn connect(addr: SocketAddr) -> Viewer {
        let (socket, _) = tokio_tungstenite::connect_async(format!("ws://{addr}/ws"))
            .await
            .expect("WebSocket connects");
        Viewer { socket }
    }

    /// Connects over a socket whose receive buffer is `recv_buffer_bytes`, so that a viewer that
    /// reads slowly fills it quickly.
    pub async fn connect_with_small_buffer(addr: SocketAddr, recv_buffer_bytes: u32) -> Viewer {
        let tcp = tokio::net::TcpSocket::new_v4().expect("socket");
        tcp.set_recv_buffer_size(recv_buffer_bytes)
            .expect("receive buffer size");
        let stream = tcp.connect(addr).await.expect("TCP connects");
        let (socket, _) = tokio_tungstenite::client_async(
            format!("ws://{addr}/ws"),
            tokio_tungstenite::MaybeTlsStream::Plain(stream),
        )
        .await
        .expect("WebSocket handshake");
        Viewer { socket }
    }

    /// Connects as a browser page of `origin` would (no `Origin` header when `None`), naming
    /// the server `host` in the `Host` header (its address when `None`), and presents `token`
    /// in an `auth` message first when given. `Err` is the HTTP status of a refused upgrade.
    pub async fn connect_with(
        addr: SocketAddr,
        origin: Option<&str>,
        host: Option<&str>,
        token: Option<&str>,
    ) -> Result<Viewer, u16> {
        Self::connect_from(addr, None, origin, host, token).await
    }

    /// [`Viewer::connect_with`] from the local address `from` (another loopback address, such
    /// as 127.0.0.2, is another client address to the server).
    pub async fn connect_from(
        addr: SocketAddr,
        from: Option<IpAddr>,
        origin: Option<&str>,
        host: Option<&str>,
        token: Option<&str>,
    ) -> Result<Viewer, u16> {
        let mut request = format!("ws://{addr}/ws")
            .into_client_request()
            .expect("a WebSocket request");
        let headers = request.headers_mut();
        if let Some(origin) = origin {
            headers.insert(
                "origin",
                HeaderValue::from_str(origin).expect("an Origin value"),
            );
        }
        if let Some(host) = host {
            headers.insert("host", HeaderValue::from_str(host).expect("a Host value"));
        }
        let tcp = match from {
            Some(ip) => {
                let socket = tokio::net::TcpSocket::new_v4().expect("socket");
                socket
                    .bind(SocketAddr::new(ip, 0))
                    .expect("bind the client address");
                socket.connect(addr).await.expect("TCP connects")
            }
            None => tokio::net::TcpStream::connect(addr)
                .await
                .expect("TCP connects"),
        };
        let result =
            tokio_tungstenite::client_async(request, tokio_tungstenite::MaybeTlsStream::Plain(tcp))
                .await;
        let socket = match result {
            Ok((socket, _)) => socket,
            Err(tokio_tungstenite::tungstenite::Error::Http(response)) => {
                return Err(response.status().as_u16());
            }
            Err(e) => panic!("WebSocket handshake failed: {e}"),
        };
        let mut viewer = Viewer { socket };
        if let Some(token) = token {
            viewer.authenticate(token).await;
        }
        Ok(viewer)
    }

    /// Sends `{"type":"auth","token":...}`.
    pub async fn authenticate(&mut self, token: &str) {
        let auth = serde_json::json!({"type": "auth", "token": token}).to_string();
        self.send_text(&auth).await;
    }

    /// Reads until the server closes the connection: its close code and reason (`None` for a
    /// connection that ended without a close frame), and the text messages received before.
    /// Panics after `timeout` without the end.
    pub async fn until_closed(
        &mut self,
        timeout: Duration,
    ) -> (Option<(u16, String)>, Vec<String>) {
        let mut texts = Vec::new();
        let deadline = tokio::time::Instant::now() + timeout;
        loop {
            let message = tokio::time::timeout_at(deadline, self.socket.next())
                .await
                .expect("the connection ends within the timeout");
            match message {
                Some(Ok(Message::Text(text))) => texts.push(text.to_string()),
                Some(Ok(Message::Close(frame))) => {
                    let close = frame.map(|f| (u16::from(f.code), f.reason.to_string()));
                    return (close, texts);
                }
                None | Some(Err(_)) => return (None, texts),
                Some(Ok(_)) => continue,
            }
        }
    }

    /// The next text message decoded, `None` when the connection ended (close or error).
    /// Panics after `timeout` without a message.
    pub async fn next(&mut self, timeout: Duration) -> Option<Result<ServerMessage, DecodeError>> {
        loop {
            let message = tokio::time::timeout(timeout, self.socket.next())
                .await
                .expect("a message within the timeout");
            match message {
                Some(Ok(Message::Text(text))) => return Some(ServerMessage::decode(&text)),
                Some(Ok(Message::Close(_))) | None | Some(Err(_)) => return None,
                Some(Ok(_)) => continue,
            }
        }
    }

    /// The next message, which must decode.
    pub async fn expect_message(&mut self, timeout: Duration) -> ServerMessage {
        self.next(timeout)
            .await
            .expect("connection open")
            .expect("message decodes")
    }

    pub async fn send_text(&mut self, text: &str) {
        self.socket
            .send(Message::text(text))
            .await
            .expect("send succeeds");
    }

    /// The raw text of the next message of `kind` (its `type`), skipping the others (frames,
    /// stats); fails the test after 30 s without one.
    pub async fn next_of(&mut self, kind: &str) -> String {
        let prefix = format!(r#"{{"type":"{kind}""#);
        let deadline = std::time::Instant::now() + Duration::from_secs(30);
        loop {
            assert!(std::time::Instant::now() < deadline, "no {kind} message");
            let next = tokio::time::timeout(Duration::from_secs(10), self.socket.next()).await;
            if let Ok(Some(Ok(Message::Text(t)))) = next
                && t.starts_with(&prefix)
            {
                return t.to_string();
            }
        }
    }
}

/// A plain HTTP/1.1 GET over a real TCP connection: status code and body.
pub async fn http_get(addr: SocketAddr, path: &str) -> (u16, Vec<u8>) {
    let response = http_request(addr, path, &[]).await;
    (response.status, response.body)
}

/// An HTTP response: status, headers (names in lower case) and body.
#[derive(Debug)]
pub struct HttpResponse {
    pub status: u16,
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl HttpResponse {
    /// The value of header `name` (lower case), if present.
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_str())
    }
}

/// A GET of `path` with extra request `headers` (a `Host` among them replaces the default, the
/// server's address): status, headers and body.
pub async fn http_request(addr: SocketAddr, path: &str, headers: &[(&str, &str)]) -> HttpResponse {
    let mut stream = tokio::net::TcpStream::connect(addr)
        .await
        .expect("TCP connects");
    let host = headers
        .iter()
        .find(|(n, _)| n.eq_ignore_ascii_case("host"))
        .map_or_else(|| addr.to_string(), |(_, v)| (*v).to_owned());
    let mut request = format!("GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n");
    for (name, value) in headers
        .iter()
        .filter(|(n, _)| !n.eq_ignore_ascii_case("host"))
    {
        request.push_str(&format!("{name}: {value}\r\n"));
    }
    request.push_str("\r\n");
    stream
        .write_all(request.as_bytes())
        .await
        .expect("request sent");
    let mut response = Vec::new();
    tokio::time::timeout(Duration::from_secs(20), stream.read_to_end(&mut response))
        .await
        .expect("response within 20 s")
        .expect("response read");
    let header_end = response
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("a header block");
    let head = String::from_utf8_lossy(&response[..header_end]).to_string();
    let status: u16 = head
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .expect("a status code");
    let body = response[header_end + 4..].to_vec();
    let headers: Vec<(String, String)> = head
        .lines()
        .skip(1)
        .filter_map(|line| line.split_once(':'))
        .map(|(n, v)| (n.trim().to_ascii_lowercase(), v.trim().to_owned()))
        .collect();
    let chunked = headers
        .iter()
        .any(|(n, v)| n == "transfer-encoding" && v.eq_ignore_ascii_case("chunked"));
    HttpResponse {
        status,
        headers,
        body: if chunked { dechunk(&body) } else { body },
    }
}

/// A GET of `path` presenting `token` in `Authorization: Bearer`, as the viewer's own fetches
/// of session data do.
pub async fn http_get_with_token(addr: SocketAddr, path: &str, token: &str) -> HttpResponse {
    let bearer = format!("Bearer {token}");
    http_request(addr, path, &[("Authorization", &bearer)]).await
}

/// Decodes a chunked HTTP body.
fn dechunk(mut body: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let Some(line_end) = body.windows(2).position(|w| w == b"\r\n") else {
            return out;
        };
        let size = usize::from_str_radix(
            String::from_utf8_lossy(&body[..line_end])
                .split(';')
                .next()
                .unwrap_or("0")
                .trim(),
            16,
        )
        .unwrap_or(0);
        if size == 0 {
            return out;
        }
        let start = line_end + 2;
        out.extend_from_slice(&body[start..start + size]);
        body = &body[start + size + 2..];
    }
}

/// Polls `condition` until it holds, failing the test after a minute: the tests wait for what
/// they check, never for a time.
pub async fn wait_until(what: &str, mut condition: impl FnMut() -> bool) {
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    while !condition() {
        assert!(
            std::time::Instant::now() < deadline,
            "timed out waiting for {what}"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

/// A fresh, empty directory for one test's files: `<tmp>/softhaptic-<name>-<pid>`.
///
/// The same test's directories left by earlier runs whose process is gone (a failed or killed
/// test does not clean up after itself) are removed first, so a machine that runs the suite
/// again and again keeps at most one per test.
pub fn scratch_dir(name: &str) -> std::path::PathBuf {
    let tmp = std::env::temp_dir();
    let prefix = format!("softhaptic-{name}-");
    if let Ok(entries) = std::fs::read_dir(&tmp) {
        for entry in entries.flatten() {
            let file_name = entry.file_name();
            let Some(pid) = file_name
                .to_str()
                .and_then(|n| n.strip_prefix(&prefix))
                .and_then(|rest| rest.parse::<u32>().ok())
            else {
                continue;
            };
            if pid != std::process::id() && !std::path::Path::new(&format!("/proc/{pid}")).exists()
            {
                let _ = std::fs::remove_dir_all(entry.path());
            }
        }
    }
    let dir = tmp.join(format!("{prefix}{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    if let Err(e) = std::fs::create_dir_all(&dir) {
        panic!("could not create {}: {e}", dir.display());
    }
    dir
}

/// The `softhaptic` binary of this build, for the tests that run it as a user does (its signals,
/// its exit status, its log); `SOFTHAPTIC_BIN` names another build.
///
/// It is looked for beside the test executable's own directory: a test runs as
/// `target/<profile>/deps/<test>-<hash>`, and cargo puts the workspace's binaries in
/// `target/<profile>/`, so the binary found there is the one built with the tests' profile (by
/// `cargo test --workspace`, before any test runs). Cargo cannot be asked for it instead:
/// `CARGO_BIN_EXE_*` names only the binaries of the test's own package, and `softhaptic` is the
/// server's.
pub fn softhaptic_binary() -> std::path::PathBuf {
    if let Some(bin) = std::env::var_os("SOFTHAPTIC_BIN") {
        return std::path::PathBuf::from(bin);
    }
    let exe = std::env::current_exe()
        .unwrap_or_else(|e| panic!("could not find the running test's executable: {e}"));
    // target/<profile>/deps/<test>-<hash> → target/<profile>
    let Some(profile_dir) = exe.parent().and_then(std::path::Path::parent) else {
        panic!(
            "the test executable {} is not in target/<profile>/deps/: set SOFTHAPTIC_BIN",
            exe.display()
        );
    };
    let bin = profile_dir.join("softhaptic");
    assert!(
        bin.is_file(),
        "{} is not built: run `cargo build -p softhaptic-server --bin softhaptic` (with the same \
         profile as the tests), or set SOFTHAPTIC_BIN",
        bin.display()
    );
    bin
}

/// The repository's `scenes/` directory.
pub fn repo_scenes() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join("scenes")
}

/// Writes `text` as `scene.toml` in `dir` and loads it as the server would.
pub fn load_scene_text(
    dir: &std::path::Path,
    text: &str,
) -> Result<Scene, softhaptic_server::scene::SceneError> {
    let path = dir.join("scene.toml");
    if let Err(e) = std::fs::write(&path, text) {
        panic!("could not write {}: {e}", path.display());
    }
    Scene::load(&path)
}

/// Asserts that `text` is refused as a scene with an error naming the file and containing each
/// of `expected` (the field, the value, the reason).
pub fn assert_scene_refused(dir: &std::path::Path, text: &str, expected: &[&str]) {
    let err = match load_scene_text(dir, text) {
        Ok(_) => panic!("the scene is refused:\n{text}"),
        Err(e) => e.to_string(),
    };
    let path = dir.join("scene.toml");
    assert!(
        err.contains(&path.display().to_string()),
        "error names the file: {err}"
    );
    for e in expected {
        assert!(err.contains(e), "expected {e:?} in: {err}");
    }
}

/// Every coordinate of every lump's centre in `scene`, as JSON writes it, in the world frame and
/// the object's (zeros left out): what no message a trainee's viewer gets may contain before the
/// answer is public.
pub fn inclusion_coordinates(scene: &softhaptic_server::scene::Scene) -> Vec<String> {
    scene
        .inclusions
        .iter()
        .flat_map(|i| {
            let world = scene
                .object_in_world
                .transform_point(glam::DVec3::from_array(i.centre_in_object_m));
            i.centre_in_object_m
                .into_iter()
                .chain(world.to_array())
                .filter(|v| v.abs() > 1e-6)
                .filter_map(|v| serde_json::to_string(&v).ok())
                .collect::<Vec<_>>()
        })
        .collect()
}
