//! The real `softhaptic` binary asked for a SpaceMouse that is not there: the start stops before
//! anything listens or records, and the error says what was not found once, then what to do.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Runs the binary; one still running after a generous deadline (it started a server it should
/// not have) is killed and reported.
fn softhaptic(args: &[&str]) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_softhaptic"))
        .args(args)
        .env_remove("RUST_BACKTRACE")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("softhaptic runs");
    let deadline = Instant::now() + Duration::from_secs(60);
    while child.try_wait().unwrap().is_none() {
        if Instant::now() > deadline {
            child.kill().unwrap();
            let out = child.wait_with_output().unwrap();
            panic!(
                "softhaptic {args:?} still running after 60 s: it started instead of refusing\n{}",
                String::from_utf8_lossy(&out.stdout)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

#[test]
fn a_spacemouse_that_is_not_plugged_in_is_named_once_and_nothing_starts() {
    let record_dir =
        std::env::temp_dir().join(format!("softhaptic-spacemouse-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&record_dir);
    // A serial no device has: refused the same way on a desk with a SpaceMouse plugged in.
    let out = softhaptic(&[
        "--device",
        "spacemouse:NO-SUCH-SERIAL-0000",
        "--addr",
        "127.0.0.1:0",
        "--record-dir",
        &record_dir.display().to_string(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(!stdout.contains("viewer:"), "{stdout}");
    assert!(
        !record_dir.exists() || std::fs::read_dir(&record_dir).unwrap().next().is_none(),
        "a recording was started in {}",
        record_dir.display()
    );
    let line = err
        .lines()
        .find(|l| l.starts_with("error: "))
        .unwrap_or_else(|| panic!("no error line in:\n{err}"));
    for once in [
        "no SpaceMouse found",
        "NO-SUCH-SERIAL-0000",
        "plug one in",
        "softhaptic devices",
    ] {
        assert_eq!(line.matches(once).count(), 1, "{once:?} once in:\n{line}");
    }
    let _ = std::fs::remove_dir_all(&record_dir);
}
