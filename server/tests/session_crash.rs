//! A server killed without warning leaves a recording that reads back: the real `softhaptic`
//! binary records to a temporary directory, is SIGKILLed once its file holds closed chunks, and the
//! file is read, its recovery described, and its recovered ticks replayed bit for bit. The
//! viewers of that session were told the same session id as the file records.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use softhaptic_server::session::check::{CheckOverrides, check};
use softhaptic_server::session::reader::{Ending, Recording};

#[test]
fn a_sigkilled_server_leaves_a_recording_that_recovers_its_ticks() {
    let dir = std::env::temp_dir().join(format!("softhaptic-crash-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut child = Command::new(env!("CARGO_BIN_EXE_softhaptic"))
        .args(["--addr", "127.0.0.1:0", "--no-realtime", "--record-dir"])
        .arg(&dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("the server starts");
    let stdout = child.stdout.take().expect("stdout is piped");
    let mut lines = BufReader::new(stdout).lines();
    let mut recording: Option<PathBuf> = None;
    let mut viewer_url = String::new();
    let started = Instant::now();
    // The server prints the recording's path, then the viewer's URL once it serves.
    for line in lines.by_ref() {
        let line = line.expect("stdout reads");
        if let Some(p) = line.strip_prefix("recording: ") {
            recording = Some(PathBuf::from(p));
        }
        if let Some(url) = line.strip_prefix("viewer: ") {
            viewer_url = url.to_owned();
            break;
        }
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "server did not start"
        );
    }
    let path = recording.expect("the server names its recording");
    let hello_session_id = hello_session_id(&viewer_url);
    // Killed once the file holds some closed chunks (however slowly a loaded machine gets there).
    let give_up = Instant::now() + Duration::from_secs(60);
    let written_before_kill = loop {
        let ticks = Recording::open(&path).map_or(0, |r| r.device.len());
        if ticks >= 500 {
            break ticks;
        }
        assert!(Instant::now() < give_up, "no chunk written: {ticks} ticks");
        #[allow(clippy::disallowed_methods)] // test code: polls a file on the test's own thread
        std::thread::sleep(Duration::from_millis(20));
    };
    child.kill().expect("SIGKILL delivered");
    let _ = child.wait();

    let r = Recording::open(&path).expect("a killed server's recording still opens");
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(r.build.session_id, hello_session_id);
    assert!(
        matches!(r.ending, Ending::Truncated { .. }),
        "a killed server cannot have closed its file: {}",
        r.recovery()
    );
    assert!(r.device.len() >= written_before_kill, "{}", r.recovery());
    assert_eq!(r.device[0].tick, 0);
    assert_eq!(r.missing_ticks(), 0);
    let text = r.recovery().to_string();
    assert!(
        text.contains("truncated") && text.contains(&format!("recovered {} ticks", r.device.len())),
        "{text}"
    );
    // What was recovered is exact: the same build replays it to the same forces.
    let report = check(&r, CheckOverrides::default()).expect("the check runs");
    assert!(report.passed(), "{report}");
    assert_eq!(report.ticks_compared, r.device.len() as u64);
}

/// The session id of the `hello` a viewer of `viewer_url` (http://host:port/) receives.
fn hello_session_id(viewer_url: &str) -> String {
    let ws_url = format!("{}ws", viewer_url.replacen("http://", "ws://", 1));
    let (mut socket, _) = tungstenite::connect(ws_url.as_str()).expect("the viewer connects");
    let first = socket.read().expect("the server sends hello first");
    let hello: serde_json::Value =
        serde_json::from_str(first.to_text().expect("hello is text")).expect("hello is JSON");
    assert_eq!(hello["type"], "hello", "{hello}");
    hello["session_id"]
        .as_str()
        .expect("hello names its session")
        .to_owned()
}
