//! The server's log written to a file (or a pipe) holds no ANSI colour codes, which only a
//! person at a terminal gets: pinned on the real binary, with the terminal's colours as the
//! control.

// Test code, synchronous: polls the server it started and reads the log file it wrote.
#![allow(clippy::disallowed_methods)]
#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

mod support;

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};

/// The escape that starts every ANSI colour or style code.
const ESC: char = '\u{1b}';

/// A scratch directory of this test process, emptied first.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("softhaptic-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn the_log_written_to_a_file_has_no_colour_codes() {
    let dir = scratch("plain-log");
    let log_path = dir.join("server.log");
    // A whole run, start to stop, with every level the server writes: the loop's, the
    // recorder's and the stop's lines, not only the start's.
    let mut child = Command::new(env!("CARGO_BIN_EXE_softhaptic"))
        .args(["--addr", "127.0.0.1:0", "--no-realtime", "--record-dir"])
        .arg(dir.join("sessions"))
        .env("RUST_LOG", "trace")
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(&log_path).unwrap())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    let started = BufReader::new(stdout)
        .lines()
        .map_while(Result::ok)
        .any(|line| line.starts_with("viewer: "));
    assert!(started, "the server never printed its URL");
    let status = support::stop_with_signal(&mut child, "TERM");
    assert!(status.success(), "{status}");

    let log = std::fs::read_to_string(&log_path).unwrap();
    // The log is there (a silent server would pass the next assertion for nothing).
    for expected in [" INFO ", "scene loaded", "haptic thread started", "SIGTERM"] {
        assert!(log.contains(expected), "no {expected:?} in the log:\n{log}");
    }
    if let Some((n, line)) = log.lines().enumerate().find(|(_, l)| l.contains(ESC)) {
        panic!("line {} of the log holds an escape code: {line:?}", n + 1);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_log_at_a_terminal_is_coloured() {
    // The other side of the rule, so that the test above cannot pass by a log that is never
    // coloured: under a pseudo-terminal (util-linux `script`), the same start is. The server
    // stops at once, its port taken, after the lines of its start.
    let Ok(script) = which("script") else {
        eprintln!("no `script` here to give the server a terminal: not checked");
        return;
    };
    let dir = scratch("tty-log");
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let command = format!(
        "{} --addr {} --no-realtime --record-dir {}",
        env!("CARGO_BIN_EXE_softhaptic"),
        taken.local_addr().unwrap(),
        dir.display()
    );
    let out = Command::new(script)
        .args(["-qec", &command, "/dev/null"])
        .env("RUST_LOG", "info")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("scene loaded"), "{text}");
    assert!(
        text.contains(&format!("{ESC}[32m INFO{ESC}[0m")),
        "the level is not coloured at a terminal: {text:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// `name` on the `PATH`.
fn which(name: &str) -> Result<PathBuf, ()> {
    std::env::var_os("PATH")
        .and_then(|paths| {
            std::env::split_paths(&paths)
                .map(|dir| dir.join(name))
                .find(|p| p.is_file())
        })
        .ok_or(())
}
