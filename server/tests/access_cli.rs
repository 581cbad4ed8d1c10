//! The real `softhaptic` binary's access rules: serving beyond loopback without tokens stops the
//! start with what to do (`run` and `replay`), unless `--insecure-no-tokens`; tokens from
//! `--tokens` or the environment are printed in the links on stdout and nowhere else: not in
//! its log (stderr, at debug level), not in the recording (its bytes, and every message
//! decompressed), not in an error; a wrong token source stops the start naming the file, the
//! line and the problem, without the token; every refusal of a running server (a foreign
//! Origin, a wrong Host, a connection over its cap, a missing or wrong token, a flood) leaves
//! its log line, and every viewer connection its audit line, with no token in any of them.

// Test code, synchronous: polls the servers it started and reads the recording one wrote.
#![allow(clippy::disallowed_methods)]
#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

mod support;

use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use softhaptic_server::access::{INSTRUCTOR_TOKEN_ENV, OBSERVER_TOKEN_ENV};

const DEADLINE: Duration = Duration::from_secs(60);

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("softhaptic-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn repo(path: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(path)
        .display()
        .to_string()
}

/// The binary with `args`, with none of the token variables unless `env` sets them.
fn command(args: &[&str], env: &[(&str, &str)]) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_softhaptic"));
    command
        .args(args)
        .env_remove("RUST_BACKTRACE")
        .env_remove(INSTRUCTOR_TOKEN_ENV)
        .env_remove(OBSERVER_TOKEN_ENV)
        .envs(env.iter().copied())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    command
}

/// Runs a command that must stop by itself; one still running after the deadline started a
/// server it should not have.
fn run_to_end(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut child = command(args, env).spawn().expect("softhaptic runs");
    let started = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if started.elapsed() > DEADLINE {
            child.kill().unwrap();
            let out = child.wait_with_output().unwrap();
            panic!(
                "softhaptic {args:?} still running after {DEADLINE:?}: it started instead of refusing\n{}",
                String::from_utf8_lossy(&out.stdout)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// A server started from the binary: its stdout lines as they come, its stderr collected.
struct Server {
    child: Child,
    lines: mpsc::Receiver<String>,
    stdout: Vec<String>,
    stderr: std::thread::JoinHandle<String>,
}

impl Server {
    fn start(args: &[&str], env: &[(&str, &str)]) -> Server {
        let mut child = command(args, env).spawn().expect("softhaptic runs");
        let out = child.stdout.take().unwrap();
        let mut err = child.stderr.take().unwrap();
        // The links and a few status lines: far fewer than the queue holds.
        let (tx, lines) = mpsc::sync_channel(1024);
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines() {
                let Ok(line) = line else { break };
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        let stderr = std::thread::spawn(move || {
            let mut text = String::new();
            let _ = err.read_to_string(&mut text);
            text
        });
        Server {
            child,
            lines,
            stdout: Vec::new(),
            stderr,
        }
    }

    /// The rest of the first stdout line starting with `prefix`.
    fn line(&mut self, prefix: &str) -> String {
        loop {
            let line = self
                .lines
                .recv_timeout(DEADLINE)
                .unwrap_or_else(|_| panic!("no {prefix:?} line on stdout: {:?}", self.stdout));
            self.stdout.push(line.clone());
            if let Some(rest) = line.strip_prefix(prefix) {
                return rest.to_owned();
            }
        }
    }

    /// Stops the server with SIGTERM (an orderly shutdown: the recording is closed) and returns
    /// its whole stdout and stderr.
    fn stop(mut self) -> (Vec<String>, String) {
        support::stop_with_signal(&mut self.child, "TERM");
        while let Ok(line) = self.lines.recv_timeout(Duration::from_secs(5)) {
            self.stdout.push(line);
        }
        (self.stdout, self.stderr.join().unwrap())
    }
}

/// `http://HOST:PORT/#token=T&role=R` → (`HOST:PORT`, `T`); checks that the link names `role`.
fn split_link(link: &str, role: &str) -> (String, String) {
    let rest = link.strip_prefix("http://").expect("an http link");
    let (addr, fragment) = rest.split_once("/#").expect("a fragment");
    let (token, hint) = fragment
        .strip_prefix("token=")
        .and_then(|pairs| pairs.split_once("&role="))
        .unwrap_or_else(|| panic!("not token=…&role=… in the fragment: {fragment}"));
    assert_eq!(hint, role, "the link's role hint");
    (addr.to_owned(), token.to_owned())
}

fn is_generated_token(token: &str) -> bool {
    token.len() == 32
        && token
            .bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// A WebSocket to `addr`; presents `token` when given.
fn connect(
    addr: &str,
    token: Option<&str>,
) -> tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<std::net::TcpStream>> {
    let (mut socket, _) = tungstenite::connect(format!("ws://{addr}/ws")).expect("connects");
    if let Some(token) = token {
        let auth = serde_json::json!({"type": "auth", "token": token}).to_string();
        socket.send(tungstenite::Message::text(auth)).unwrap();
    }
    socket
}

/// A WebSocket upgrade to `addr` with `Origin: origin`; the HTTP status of a refused one.
fn connect_from_origin(
    addr: &str,
    origin: &str,
) -> Result<tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<std::net::TcpStream>>, u16> {
    use tungstenite::client::IntoClientRequest;
    let mut request = format!("ws://{addr}/ws").into_client_request().unwrap();
    request
        .headers_mut()
        .insert("Origin", origin.parse().unwrap());
    match tungstenite::connect(request) {
        Ok((socket, _)) => Ok(socket),
        Err(tungstenite::Error::Http(response)) => Err(response.status().as_u16()),
        Err(e) => panic!("the upgrade from {origin} failed without an answer: {e}"),
    }
}

/// The client side's address of `socket`: the `client` its log lines name.
fn local_addr(
    socket: &tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<std::net::TcpStream>>,
) -> std::net::SocketAddr {
    match socket.get_ref() {
        tungstenite::stream::MaybeTlsStream::Plain(tcp) => tcp.local_addr().unwrap(),
        _ => unreachable!("a ws:// connection is plain TCP"),
    }
}

/// The next text message as JSON; `None` at the close (with its code in the second place).
fn next_json(
    socket: &mut tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<std::net::TcpStream>>,
) -> Result<serde_json::Value, Option<u16>> {
    loop {
        match socket.read() {
            Ok(tungstenite::Message::Text(text)) => return Ok(serde_json::from_str(&text).unwrap()),
            Ok(tungstenite::Message::Close(frame)) => return Err(frame.map(|f| u16::from(f.code))),
            Ok(_) => continue,
            Err(_) => return Err(None),
        }
    }
}

/// A GET with an optional bearer token over a plain TCP connection: the whole response.
fn http_get(addr: &str, path: &str, token: Option<&str>) -> String {
    http_get_naming(addr, addr, path, token)
}

/// [`http_get`] with `Host: host`.
fn http_get_naming(addr: &str, host: &str, path: &str, token: Option<&str>) -> String {
    let mut stream = std::net::TcpStream::connect(addr).unwrap();
    stream.set_read_timeout(Some(DEADLINE)).unwrap();
    let auth = token.map_or_else(String::new, |t| format!("Authorization: Bearer {t}\r\n"));
    write!(
        stream,
        "GET {path} HTTP/1.1\r\nHost: {host}\r\n{auth}Connection: close\r\n\r\n"
    )
    .unwrap();
    let mut response = Vec::new();
    stream.read_to_end(&mut response).unwrap();
    String::from_utf8_lossy(&response).into_owned()
}

#[test]
fn serving_every_address_without_tokens_refuses_to_start_and_says_what_to_do() {
    let record_dir = scratch("access-refused");
    let record = record_dir.display().to_string();
    let recording = repo("tests/sessions/sphere-press.mcap");
    let runs: [Vec<&str>; 3] = [
        vec![
            "--addr",
            "0.0.0.0:0",
            "--no-realtime",
            "--record-dir",
            &record,
        ],
        vec![
            "run",
            "--addr",
            "[::]:0",
            "--no-realtime",
            "--record-dir",
            &record,
        ],
        vec!["replay", &recording, "--addr", "0.0.0.0:0"],
    ];
    for args in runs {
        let out = run_to_end(&args, &[]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
        for says in [
            "without tokens",
            "--tokens",
            "--token-file",
            INSTRUCTOR_TOKEN_ENV,
            OBSERVER_TOKEN_ENV,
            "--insecure-no-tokens",
        ] {
            assert!(stderr.contains(says), "{args:?}: {says:?} not in: {stderr}");
        }
        assert!(
            !stdout.contains("viewer:") && !stdout.contains("replay:"),
            "{stdout}"
        );
        assert!(!stdout.contains("recording:"), "{stdout}");
        assert!(!record_dir.exists(), "a recording was started in {record}");
    }
}

#[test]
fn with_insecure_no_tokens_it_serves_every_address_and_warns_loudly() {
    let mut server = Server::start(
        &[
            "--addr",
            "0.0.0.0:0",
            "--insecure-no-tokens",
            "--no-record",
            "--no-realtime",
        ],
        &[],
    );
    let url = server.line("viewer: ");
    assert!(!url.contains("#token="), "{url}");
    let port = url
        .trim_end_matches('/')
        .rsplit(':')
        .next()
        .unwrap()
        .to_owned();
    let mut socket = connect(&format!("127.0.0.1:{port}"), None);
    let hello = next_json(&mut socket).unwrap();
    assert_eq!(hello["type"], "hello");
    assert_eq!(hello["role"], "instructor");
    drop(socket);
    let (_, stderr) = server.stop();
    assert!(
        stderr.contains("INSECURE") && stderr.contains("WITHOUT TOKENS"),
        "{stderr}"
    );
}

#[test]
fn tokens_appear_only_in_the_printed_links_never_in_the_log_the_recording_or_an_error() {
    let record_dir = scratch("access-tokens");
    let record = record_dir.display().to_string();
    let mut server = Server::start(
        &[
            "--tokens",
            "--addr",
            "127.0.0.1:0",
            "--no-realtime",
            "--record-dir",
            &record,
        ],
        // Trace level: every line the server and its libraries could log about a connection
        // (the WebSocket and NATS libraries print what a connection carries at this level).
        &[("RUST_LOG", "trace")],
    );
    let recording = PathBuf::from(server.line("recording: "));
    let (addr, instructor) = split_link(&server.line("viewer: "), "instructor");
    let (observer_addr, observer) = split_link(&server.line("observer: "), "observer");
    assert_eq!(addr, observer_addr);
    assert!(is_generated_token(&instructor) && is_generated_token(&observer));
    assert_ne!(instructor, observer);

    // Every way a token travels to the server: WebSocket auth (right, wrong, twice) and HTTP.
    for (token, role) in [(&instructor, "instructor"), (&observer, "observer")] {
        let mut socket = connect(&addr, Some(token));
        let hello = next_json(&mut socket).unwrap();
        assert_eq!(
            (hello["type"].as_str(), hello["role"].as_str()),
            (Some("hello"), Some(role))
        );
        let auth = serde_json::json!({"type": "auth", "token": token}).to_string();
        socket.send(tungstenite::Message::text(auth)).unwrap();
        let control = r#"{"type":"replay_control","action":"pause"}"#;
        socket.send(tungstenite::Message::text(control)).unwrap();
        loop {
            let m = next_json(&mut socket).unwrap();
            if m["type"] == "refused" {
                assert!(!m.to_string().contains(token.as_str()));
                break;
            }
        }
        socket.close(None).unwrap();
        while socket.read().is_ok() {}
    }
    let wrong: String = instructor.chars().rev().collect();
    let mut socket = connect(&addr, Some(&wrong));
    assert_eq!(next_json(&mut socket), Err(Some(4401)));
    drop(socket);
    for token in [Some(instructor.as_str()), Some(observer.as_str())] {
        let response = http_get(&addr, "/api/scene", token);
        assert!(response.starts_with("HTTP/1.1 200"), "{response}");
        assert!(!response.contains(&instructor) && !response.contains(&observer));
    }
    for token in [None, Some(wrong.as_str())] {
        let response = http_get(&addr, "/api/scene", token);
        assert!(response.starts_with("HTTP/1.1 401"), "{response}");
        assert!(!response.contains(&instructor) && !response.contains(&observer));
    }
    let (stdout, stderr) = server.stop();

    for token in [&instructor, &observer] {
        assert!(
            !stderr.contains(token.as_str()),
            "a token is in the log:\n{stderr}"
        );
        let lines: Vec<_> = stdout
            .iter()
            .filter(|l| l.contains(token.as_str()))
            .collect();
        assert_eq!(
            lines.len(),
            1,
            "the token is printed once, in its link: {stdout:?}"
        );
    }
    // The log has the audit line of each connection and the refusals (without the tokens).
    for expected in [
        "viewer connection ended",
        "role=\"instructor\"",
        "role=\"observer\"",
        "token not valid for this server",
        "request refused",
        "request refused (401)",
    ] {
        assert!(
            stderr.contains(expected),
            "{expected:?} not in the log:\n{stderr}"
        );
    }

    let bytes = std::fs::read(&recording).unwrap();
    let mut messages = 0;
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let message = message.unwrap();
        let mut texts = vec![
            message.data.to_vec(),
            message.channel.topic.as_bytes().to_vec(),
        ];
        if let Some(schema) = &message.channel.schema {
            texts.push(schema.data.to_vec());
        }
        for text in texts {
            for token in [&instructor, &observer] {
                assert!(
                    !contains(&text, token.as_bytes()),
                    "a token is in the recording's {} channel",
                    message.channel.topic
                );
            }
        }
        messages += 1;
    }
    assert!(
        messages >= 10,
        "the recording holds the session: {messages} messages"
    );
    for token in [&instructor, &observer] {
        assert!(
            !contains(&bytes, token.as_bytes()),
            "a token is in the recording's bytes"
        );
    }
    let _ = std::fs::remove_dir_all(&record_dir);
}

fn contains(haystack: &[u8], needle: &[u8]) -> bool {
    haystack.windows(needle.len()).any(|w| w == needle)
}

#[test]
fn stable_tokens_from_the_environment_are_the_ones_in_the_links_and_not_in_the_log() {
    let instructor = "lab-instructor-39dda56eb9b68204cac0";
    let observer = "lab-observer-184cdd91c08d039d51a380";
    let mut server = Server::start(
        &["--addr", "127.0.0.1:0", "--no-record", "--no-realtime"],
        &[
            (INSTRUCTOR_TOKEN_ENV, instructor),
            (OBSERVER_TOKEN_ENV, observer),
            ("RUST_LOG", "debug"),
        ],
    );
    let (addr, from_link) = split_link(&server.line("viewer: "), "instructor");
    assert_eq!(from_link, instructor);
    assert_eq!(
        split_link(&server.line("observer: "), "observer").1,
        observer
    );
    let mut socket = connect(&addr, Some(observer));
    assert_eq!(next_json(&mut socket).unwrap()["role"], "observer");
    drop(socket);
    let (_, stderr) = server.stop();
    assert!(
        !stderr.contains(instructor) && !stderr.contains(observer),
        "{stderr}"
    );
}

#[test]
fn a_wrong_token_source_stops_the_start_naming_the_problem_without_the_token() {
    let dir = scratch("access-token-file");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("tokens.txt");
    let short = "abcdef0123456789";
    std::fs::write(
        &file,
        format!("# lab links\ninstructor = {short}\nobserver = 00112233445566778899aabbccddeeff\n"),
    )
    .unwrap();
    let path = file.display().to_string();
    let out = run_to_end(
        &["--token-file", &path, "--no-record", "--no-realtime"],
        &[],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains(&format!(
            "{path}:2: the instructor token is 16 characters long"
        )),
        "{stderr}"
    );
    assert!(!stderr.contains(short), "{stderr}");
    assert!(!String::from_utf8_lossy(&out.stdout).contains("viewer:"));

    let out = run_to_end(
        &[
            "--token-file",
            &dir.join("missing.txt").display().to_string(),
        ],
        &[],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("could not read the token file") && stderr.contains("missing.txt"));

    let only = "00112233445566778899aabbccddeeff";
    let out = run_to_end(&["--no-record"], &[(INSTRUCTOR_TOKEN_ENV, only)]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("SOFTHAPTIC_INSTRUCTOR_TOKEN is set but SOFTHAPTIC_OBSERVER_TOKEN is not"),
        "{stderr}"
    );
    assert!(!stderr.contains(only), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The one line of `log` that holds every one of `needles`; the log's refusal and audit lines
/// when there is none.
fn log_line<'a>(log: &'a str, needles: &[&str]) -> &'a str {
    let found: Vec<&str> = log
        .lines()
        .filter(|line| needles.iter().all(|n| line.contains(n)))
        .collect();
    if found.len() == 1 {
        return found[0];
    }
    let relevant: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("refused") || l.contains("viewer connection ended"))
        .collect();
    panic!(
        "{} lines hold all of {needles:?}; the refusal and audit lines:\n{}",
        found.len(),
        relevant.join("\n")
    );
}

/// Connects with `token` once the server has given back the one place this address has (a
/// viewer that just left is still counted until the server has seen it go): the socket and
/// the `hello`, or the close code when the token is refused.
fn connect_when_admitted(
    addr: &str,
    origin: &str,
    token: &str,
) -> (
    tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<std::net::TcpStream>>,
    Result<serde_json::Value, Option<u16>>,
) {
    let auth = serde_json::json!({"type": "auth", "token": token}).to_string();
    send_first_when_admitted(addr, origin, &auth)
}

/// [`connect_when_admitted`] sending `first` as the first message.
fn send_first_when_admitted(
    addr: &str,
    origin: &str,
    first: &str,
) -> (
    tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<std::net::TcpStream>>,
    Result<serde_json::Value, Option<u16>>,
) {
    let started = Instant::now();
    loop {
        let mut socket = connect_from_origin(addr, origin).expect("the own origin is served");
        socket.send(tungstenite::Message::text(first)).unwrap();
        let answer = next_json(&mut socket);
        if answer != Err(Some(4429)) {
            return (socket, answer);
        }
        assert!(
            started.elapsed() < DEADLINE,
            "the address's place was never given back"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn every_refusal_leaves_a_log_line_and_every_connection_an_audit_line_without_a_token() {
    let mut server = Server::start(
        &[
            "--tokens",
            "--addr",
            "127.0.0.1:0",
            "--max-viewers-per-address",
            "1",
            "--no-record",
            "--no-realtime",
        ],
        &[("RUST_LOG", "trace")],
    );
    let (addr, instructor) = split_link(&server.line("viewer: "), "instructor");
    let (_, observer) = split_link(&server.line("observer: "), "observer");
    let port = addr.rsplit(':').next().unwrap().to_owned();
    let own_origin = format!("http://{addr}");

    // A page on another site: 403, nothing streamed.
    assert_eq!(
        connect_from_origin(&addr, "http://evil.example").err(),
        Some(403)
    );
    // A page that rebound its own name to this address: 421.
    let rebound = format!("evil.example:{port}");
    let response = http_get_naming(&addr, &rebound, "/api/scene", Some(&observer));
    assert!(response.starts_with("HTTP/1.1 421"), "{response}");

    // The address's one place taken by an observer; a second viewer is closed with 4429.
    let (mut first, hello) = connect_when_admitted(&addr, &own_origin, &observer);
    assert_eq!(hello.unwrap()["role"], "observer");
    let first_client = local_addr(&first).to_string();
    let mut second = connect(&addr, Some(&instructor));
    let second_client = local_addr(&second).to_string();
    assert_eq!(next_json(&mut second), Err(Some(4429)));
    drop(second);
    first.close(None).unwrap();
    while first.read().is_ok() {}

    // A wrong token, no token (a first message that is not an `auth`), and a flood, each once the place is free again.
    let wrong: String = instructor.chars().rev().collect();
    let (_, answer) = connect_when_admitted(&addr, &own_origin, &wrong);
    assert_eq!(answer, Err(Some(4401)));
    let (_, answer) = send_first_when_admitted(&addr, &own_origin, "not an auth");
    assert_eq!(answer, Err(Some(4401)));
    let (mut flooder, hello) = connect_when_admitted(&addr, &own_origin, &instructor);
    assert_eq!(hello.unwrap()["role"], "instructor");
    let flooder_client = local_addr(&flooder).to_string();
    for _ in 0..1_000 {
        if flooder
            .send(tungstenite::Message::Ping(vec![0; 8].into()))
            .is_err()
        {
            break;
        }
    }
    let mut flood_close = None;
    loop {
        match next_json(&mut flooder) {
            Ok(_) => continue,
            Err(code) => {
                flood_close = flood_close.or(code);
                break;
            }
        }
    }
    assert_eq!(flood_close, Some(1008));
    drop(flooder);
    let (stdout, log) = server.stop();

    let origin_refusal = log_line(&log, &["WebSocket upgrade refused (403)", "evil.example"]);
    assert!(origin_refusal.contains("WARN"), "{origin_refusal}");
    assert!(
        origin_refusal.contains("client=127.0.0.1:"),
        "{origin_refusal}"
    );
    let host_refusal = log_line(&log, &["request refused (421)", "/api/scene"]);
    assert!(host_refusal.contains("WARN"), "{host_refusal}");
    assert!(
        host_refusal.contains(&format!("host=\"{rebound}\"")),
        "{host_refusal}"
    );
    // The audit lines: client, role, Origin as sent, how it ended, how long it lasted.
    let audit = |client: &str| {
        log_line(
            &log,
            &["viewer connection ended", &format!("client={client} ")],
        )
    };
    let over_cap = audit(&second_client);
    for field in [
        "role=\"none\"",
        "origin=\"none\"",
        "ended=refused: too many viewers from this address (4429)",
        "duration_s=",
    ] {
        assert!(over_cap.contains(field), "{field} not in {over_cap}");
    }
    let observed = audit(&first_client);
    for field in [
        "role=\"observer\"",
        &format!("origin=\"{own_origin}\""),
        "ended=closed by the viewer",
        "duration_s=",
    ] {
        assert!(observed.contains(field), "{field} not in {observed}");
    }
    let flooded = audit(&flooder_client);
    for field in [
        "role=\"instructor\"",
        "ended=closed: too many messages (1008)",
    ] {
        assert!(flooded.contains(field), "{field} not in {flooded}");
    }
    log_line(
        &log,
        &[
            "viewer connection ended",
            "role=\"none\"",
            "ended=refused: token not valid for this server (4401)",
        ],
    );
    log_line(
        &log,
        &[
            "viewer connection ended",
            "role=\"none\"",
            "ended=refused: no token presented (4401)",
        ],
    );

    for token in [&instructor, &observer] {
        assert!(!log.contains(token.as_str()), "a token is in the log");
        let printed = stdout.iter().filter(|l| l.contains(token.as_str())).count();
        assert_eq!(printed, 1, "the token is printed once, in its link");
    }
}

/// A storm of refusals of every kind a client without a token can cause (a wrong Host, no
/// token, a foreign Origin, a WebSocket whose first message is not an `auth`): at most 20 are
/// logged one by one per 10 s, and a summary line counts the rest, so that every refusal is
/// accounted for and the log grows by lines per interval, not per refusal. (One line per
/// refusal before: 400 lines for these 400.)
#[test]
fn a_refusal_storm_is_logged_in_lines_per_interval_with_a_summary_of_the_rest() {
    let mut server = Server::start(
        &[
            "--tokens",
            "--addr",
            "127.0.0.1:0",
            "--no-record",
            "--no-realtime",
        ],
        &[("RUST_LOG", "info")],
    );
    let (addr, _) = split_link(&server.line("viewer: "), "instructor");
    let port = addr.rsplit(':').next().unwrap().to_owned();
    let rebound = format!("evil.example:{port}");
    const STORM: u64 = 400;
    let started = Instant::now();
    for i in 0..STORM {
        match i % 4 {
            0 => {
                let response = http_get_naming(&addr, &rebound, "/api/scene", None);
                assert!(response.starts_with("HTTP/1.1 421"), "{response}");
            }
            1 => {
                let response = http_get(&addr, "/api/scene", None);
                assert!(response.starts_with("HTTP/1.1 401"), "{response}");
            }
            2 => assert_eq!(
                connect_from_origin(&addr, "http://evil.example").err(),
                Some(403)
            ),
            _ => {
                let mut socket = connect(&addr, None);
                socket
                    .send(tungstenite::Message::text("not an auth"))
                    .unwrap();
                assert_eq!(next_json(&mut socket), Err(Some(4401)));
            }
        }
    }
    let storm = started.elapsed();
    let (_, log) = server.stop();
    let refusal_lines = log
        .lines()
        .filter(|l| {
            l.contains("request refused")
                || l.contains("upgrade refused")
                || (l.contains("viewer connection ended") && l.contains("refused"))
        })
        .count() as u64;
    let not_logged: u64 = log
        .lines()
        .filter(|l| l.contains("refusals not logged one by one"))
        .map(|l| {
            let n = l
                .split("not_logged=")
                .nth(1)
                .unwrap_or_else(|| panic!("{l}"));
            n.split(|c: char| !c.is_ascii_digit())
                .next()
                .unwrap()
                .parse::<u64>()
                .unwrap()
        })
        .sum();
    eprintln!(
        "{STORM} refusals in {:.2} s: {refusal_lines} refusal lines ({:.0} per second), {not_logged} in summaries",
        storm.as_secs_f64(),
        refusal_lines as f64 / storm.as_secs_f64().max(1e-3)
    );
    let intervals = storm.as_secs() / 10 + 1;
    assert!(
        refusal_lines <= 20 * intervals,
        "{refusal_lines} refusal lines in {intervals} intervals of 10 s"
    );
    assert_eq!(
        refusal_lines + not_logged,
        STORM,
        "every refusal accounted for"
    );
}

/// Standard output that keeps what it is given (a file here; the journal under systemd) gets
/// no token: the links go to `links.txt`, mode 0600, in the data directory, and the log names
/// that file. (A terminal or a pipe, which every other test here reads, gets them as before.)
#[test]
fn links_with_tokens_go_to_a_private_file_when_stdout_would_keep_them() {
    use std::os::unix::fs::PermissionsExt;
    let dir = scratch("links-file");
    std::fs::create_dir_all(&dir).unwrap();
    let stdout_path = dir.join("stdout.log");
    let data_dir = dir.join("data");
    let mut child = command(
        &[
            "--tokens",
            "--addr",
            "127.0.0.1:0",
            "--no-record",
            "--no-realtime",
            "--data-dir",
            data_dir.to_str().unwrap(),
        ],
        &[("RUST_LOG", "info")],
    )
    .stdout(std::fs::File::create(&stdout_path).unwrap())
    .spawn()
    .unwrap();
    let links = data_dir.join("links.txt");
    let started = Instant::now();
    while !std::fs::read_to_string(&links).is_ok_and(|t| t.contains("observer: ")) {
        assert!(started.elapsed() < DEADLINE, "no {}", links.display());
        std::thread::sleep(Duration::from_millis(20));
    }
    support::stop_with_signal(&mut child, "TERM");
    let mut stderr = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    let text = std::fs::read_to_string(&links).unwrap();
    let (_, instructor) = split_link(
        text.lines()
            .find_map(|l| l.strip_prefix("viewer: "))
            .unwrap(),
        "instructor",
    );
    assert!(is_generated_token(&instructor), "{text}");
    assert_eq!(
        std::fs::metadata(&links).unwrap().permissions().mode() & 0o777,
        0o600
    );
    let stdout = std::fs::read_to_string(&stdout_path).unwrap();
    assert!(!stdout.contains("#token="), "{stdout}");
    assert!(!stdout.contains(&instructor) && !stderr.contains(&instructor));
    let named = log_line(&stderr, &["links to open are in this file"]);
    assert!(named.contains(&links.display().to_string()), "{named}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Standard output a socket: the journal's (systemd names it in `JOURNAL_STREAM`, as
/// `device:inode`) gets no token, the links go to the 0600 file; any other socket (a program
/// reading the links, as node's pipes are) gets them printed.
#[test]
fn links_go_to_the_file_under_the_journal_and_to_any_other_socket_as_printed() {
    use std::os::fd::OwnedFd;
    use std::os::unix::fs::MetadataExt;
    use std::os::unix::net::UnixStream;
    for journal in [true, false] {
        let dir = scratch(&format!("links-journal-{journal}"));
        std::fs::create_dir_all(&dir).unwrap();
        let data_dir = dir.join("data");
        let (ours, theirs) = UnixStream::pair().unwrap();
        let meta = std::fs::metadata(format!(
            "/proc/self/fd/{}",
            std::os::fd::AsRawFd::as_raw_fd(&theirs)
        ))
        .unwrap();
        let stream = format!("{}:{}", meta.dev(), meta.ino());
        let env: Vec<(&str, &str)> = if journal {
            vec![("RUST_LOG", "info"), ("JOURNAL_STREAM", &stream)]
        } else {
            vec![("RUST_LOG", "info")]
        };
        let mut child = command(
            &[
                "--tokens",
                "--addr",
                "127.0.0.1:0",
                "--no-record",
                "--no-realtime",
                "--data-dir",
                data_dir.to_str().unwrap(),
            ],
            &env,
        )
        .stdout(std::process::Stdio::from(OwnedFd::from(theirs)))
        .spawn()
        .unwrap();
        let mut stderr = child.stderr.take().unwrap();
        let stderr = std::thread::spawn(move || {
            let mut text = String::new();
            let _ = stderr.read_to_string(&mut text);
            text
        });
        let links = data_dir.join("links.txt");
        // What the socket gets, line by line.
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(ours).lines() {
                let Ok(line) = line else { break };
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        let mut printed = String::new();
        if journal {
            let started = Instant::now();
            while !std::fs::read_to_string(&links).is_ok_and(|t| t.contains("observer: ")) {
                assert!(started.elapsed() < DEADLINE, "no {}", links.display());
                std::thread::sleep(Duration::from_millis(20));
            }
        } else {
            while !printed.contains("observer: ") {
                let line = lines
                    .recv_timeout(DEADLINE)
                    .unwrap_or_else(|_| panic!("no links on the socket: {printed}"));
                printed.push_str(&line);
                printed.push('\n');
            }
        }
        support::stop_with_signal(&mut child, "TERM");
        while let Ok(line) = lines.recv_timeout(Duration::from_secs(5)) {
            printed.push_str(&line);
            printed.push('\n');
        }
        let log = stderr.join().unwrap();
        if journal {
            assert!(!printed.contains("#token="), "{printed}");
            assert!(std::fs::read_to_string(&links).unwrap().contains("#token="));
            log_line(&log, &["links to open are in this file"]);
        } else {
            assert!(printed.contains("viewer: http://"), "{printed}\n{log}");
            assert!(!links.exists());
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
