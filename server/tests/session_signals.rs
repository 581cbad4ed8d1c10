//! Every way a person or a machine stops the server closes its recording: SIGINT (Ctrl-C),
//! SIGTERM (a service manager), SIGHUP (the terminal or SSH session closed) and SIGQUIT each
//! make the real `softhaptic` binary exit 0 with a complete recording.

// Test code, synchronous: polls the server it started and its recording.
#![allow(clippy::disallowed_methods)]
#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

mod support;

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use softhaptic_server::session::reader::Recording;

#[test]
fn every_stop_signal_closes_the_recording() {
    for signal in ["INT", "TERM", "HUP", "QUIT"] {
        let dir =
            std::env::temp_dir().join(format!("softhaptic-signal-{signal}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut child = Command::new(env!("CARGO_BIN_EXE_softhaptic"))
            .args(["--addr", "127.0.0.1:0", "--no-realtime", "--record-dir"])
            .arg(&dir)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let stdout = child.stdout.take().unwrap();
        let mut recording: Option<PathBuf> = None;
        for line in BufReader::new(stdout).lines() {
            let line = line.unwrap();
            if let Some(p) = line.strip_prefix("recording: ") {
                recording = Some(PathBuf::from(p));
            }
            if line.starts_with("viewer: ") {
                break;
            }
        }
        let path = recording.expect("the server names its recording");
        // Some ticks in the file before the signal.
        let give_up = Instant::now() + Duration::from_secs(60);
        while Recording::open(&path).map_or(0, |r| r.device.len()) < 100 {
            assert!(Instant::now() < give_up, "SIG{signal}: nothing recorded");
            std::thread::sleep(Duration::from_millis(20));
        }
        let status = support::stop_with_signal(&mut child, signal);
        assert!(status.success(), "SIG{signal}: {status}");
        let r = Recording::open(&path).unwrap();
        assert!(r.is_complete(), "SIG{signal}: {}", r.recovery());
        assert!(r.device.len() >= 100);
        let _ = std::fs::remove_dir_all(&dir);
    }
}

#[test]
fn a_server_that_cannot_start_leaves_no_recording_and_says_what_to_do() {
    // Another listener holds the port.
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap().to_string();
    let dir = std::env::temp_dir().join(format!("softhaptic-busy-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = Command::new(env!("CARGO_BIN_EXE_softhaptic"))
        .args(["--addr", &addr, "--no-realtime", "--record-dir"])
        .arg(&dir)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(&format!("could not listen on {addr}")) && err.contains("--addr 127.0.0.1:0"),
        "{err}"
    );
    assert_eq!(err.matches("Address already in use").count(), 1, "{err}");
    let left: Vec<_> = std::fs::read_dir(&dir)
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    assert!(left.is_empty(), "a recording was left: {left:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_stop_during_the_start_still_ends_cleanly_with_a_complete_recording() {
    // The signal arrives while the server is still starting (the scene is loaded; the device,
    // the recording and the listener come next): it is caught, and the start runs on into an
    // orderly stop instead of dying with the recording open.
    let dir = std::env::temp_dir().join(format!("softhaptic-early-stop-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut child = Command::new(env!("CARGO_BIN_EXE_softhaptic"))
        .args(["--addr", "127.0.0.1:0", "--no-realtime", "--record-dir"])
        .arg(&dir)
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = child.stderr.take().unwrap();
    let mut lines = BufReader::new(stderr).lines();
    let mut log = String::new();
    for line in lines.by_ref() {
        let line = line.unwrap();
        log.push_str(&line);
        log.push('\n');
        if line.contains("scene loaded") {
            break;
        }
    }
    assert!(
        log.contains("scene loaded"),
        "the server never loaded its scene:\n{log}"
    );
    let sent = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    for line in lines {
        log.push_str(&line.unwrap());
        log.push('\n');
    }
    let status = child.wait().unwrap();
    assert!(status.success(), "{status}:\n{log}");
    assert!(log.contains("SIGTERM"), "the stop is logged:\n{log}");
    for entry in std::fs::read_dir(&dir).unwrap().flatten() {
        let r = Recording::open(&entry.path()).unwrap();
        assert!(
            r.is_complete(),
            "{}: {}",
            entry.path().display(),
            r.recovery()
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
