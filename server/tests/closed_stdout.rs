//! A server whose stdout is closed (a supervisor that stopped reading, `softhaptic | head -1`)
//! keeps running: printing its links must not stop the loop and the recording with it.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

#[test]
fn a_server_whose_stdout_is_closed_serves_on_and_stops_cleanly() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_softhaptic"))
        .args([
            "--addr",
            "127.0.0.1:0",
            "--tokens",
            "--no-record",
            "--no-realtime",
        ])
        .env("RUST_LOG", "info")
        .env_remove("SOFTHAPTIC_INSTRUCTOR_TOKEN")
        .env_remove("SOFTHAPTIC_OBSERVER_TOKEN")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Nobody will read the links.
    drop(child.stdout.take());
    let stderr = child.stderr.take().unwrap();
    let (tx, lines) = mpsc::sync_channel(1024);
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    // Logged after the links were printed (into the closed pipe).
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut log = String::new();
    loop {
        assert!(Instant::now() < deadline, "never served:\n{log}");
        match lines.recv_timeout(Duration::from_secs(1)) {
            Ok(line) => {
                log.push_str(&line);
                log.push('\n');
                if line.contains("serving viewers") {
                    break;
                }
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(mpsc::RecvTimeoutError::Disconnected) => panic!("the server ended:\n{log}"),
        }
    }
    assert!(child.try_wait().unwrap().is_none(), "{log}");
    // SIGTERM: an orderly stop, exit status 0.
    let sent = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    let status = child.wait().unwrap();
    while let Ok(line) = lines.recv_timeout(Duration::from_secs(5)) {
        log.push_str(&line);
        log.push('\n');
    }
    assert!(status.success(), "{status}:\n{log}");
    assert!(!log.contains("panicked"), "{log}");
}
