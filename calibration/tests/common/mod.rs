//! What the calibration's command-line tests share.

use std::path::Path;
use std::process::Command;

/// Runs `softhaptic-calibrate --quick --out <out> <command>` and fails the test unless it
/// exits successfully.
pub fn run_quick(out: &Path, command: &str) {
    let status = Command::new(env!("CARGO_BIN_EXE_softhaptic-calibrate"))
        .args(["--quick", "--out"])
        .arg(out)
        .arg(command)
        .env("RUST_LOG", "warn")
        .status()
        .unwrap();
    assert!(
        status.success(),
        "softhaptic-calibrate {command} exited with {status}"
    );
}
