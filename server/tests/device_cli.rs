//! The real `softhaptic` binary on a machine without OpenHaptics: asking for the device stops
//! the start with where the library was looked for and how to install it, before anything
//! listens or records; a SpaceMouse that is not there is refused the same way, its cause said
//! once; `softhaptic devices` still lists what there is and exits 0; a bad `--device` is refused
//! by the command line. The binary driving a device through the HD API stand-in is tested in
//! `tests/tests/openhaptics_cli.rs`, the crate that builds the stand-in.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

const LIBRARY_ENV: &str = "SOFTHAPTIC_HD_LIBRARY";

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("softhaptic-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// Runs the binary; one that is still running after a generous deadline (it started a server
/// it should not have) is killed and reported.
fn softhaptic(args: &[&str], library: Option<&Path>) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_softhaptic"));
    command
        .args(args)
        .env_remove("RUST_BACKTRACE")
        .env_remove(LIBRARY_ENV)
        .env_remove("SOFTHAPTIC_DHD_LIBRARY")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    if let Some(path) = library {
        command.env(LIBRARY_ENV, path);
    }
    let mut child = command.spawn().expect("softhaptic runs");
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
        #[allow(clippy::disallowed_methods)] // test code: polls a child on the test's own thread
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

fn repo(path: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(path)
        .display()
        .to_string()
}

/// Asserts that the run refused to start: exit 1, no viewer URL, no recording.
fn assert_nothing_started(out: &Output, record_dir: &Path) {
    assert_eq!(
        out.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(!stdout.contains("viewer:"), "{stdout}");
    assert!(!stdout.contains("recording:"), "{stdout}");
    assert!(
        !record_dir.exists() || std::fs::read_dir(record_dir).unwrap().next().is_none(),
        "a recording was started in {}",
        record_dir.display()
    );
}

#[test]
fn an_openhaptics_library_that_is_not_there_stops_the_start_and_says_where_it_looked() {
    let record_dir = scratch("device-missing");
    let record = record_dir.display().to_string();
    let missing = Path::new("/nonexistent/OpenHaptics/libHD.so");
    let out = softhaptic(
        &[
            "--device",
            "openhaptics",
            "--addr",
            "127.0.0.1:0",
            "--record-dir",
            &record,
        ],
        Some(missing),
    );
    assert_nothing_started(&out, &record_dir);
    let err = String::from_utf8_lossy(&out.stderr);
    for expected in [
        "/nonexistent/OpenHaptics/libHD.so",
        LIBRARY_ENV,
        "could not load the OpenHaptics HD library",
    ] {
        assert!(err.contains(expected), "{expected:?} missing from:\n{err}");
    }
}

#[test]
fn without_the_override_the_search_is_listed_with_how_to_install() {
    let installed = [
        "/usr/lib64",
        "/usr/lib",
        "/usr/lib/x86_64-linux-gnu",
        "/usr/local/lib",
    ]
    .iter()
    .any(|d| Path::new(d).join("libHD.so").exists());
    if installed {
        // A machine with OpenHaptics installed finds it; the override test covers the refusal.
        return;
    }
    let record_dir = scratch("device-search");
    let record = record_dir.display().to_string();
    // The phantom scene asks for the device itself, and its file loads without it.
    let out = softhaptic(
        &[
            "--scene",
            &repo("scenes/phantom.toml"),
            "--addr",
            "127.0.0.1:0",
            "--record-dir",
            &record,
        ],
        None,
    );
    assert_nothing_started(&out, &record_dir);
    let err = String::from_utf8_lossy(&out.stderr);
    for expected in [
        "the OpenHaptics HD library (libHD.so) was not found",
        "LD_LIBRARY_PATH",
        "/usr/lib64/libHD.so",
        "SOFTHAPTIC_HD_LIBRARY: not set",
        "install the Touch device driver and OpenHaptics for Linux",
    ] {
        assert!(err.contains(expected), "{expected:?} missing from:\n{err}");
    }
}

#[test]
fn a_file_that_is_not_a_library_is_refused_with_the_loader_s_reason() {
    let dir = scratch("device-wrong");
    std::fs::create_dir_all(&dir).unwrap();
    let fake = dir.join("libHD.so");
    std::fs::write(&fake, "#!/bin/sh\necho not a library\n").unwrap();
    let record_dir = dir.join("sessions");
    let out = softhaptic(
        &[
            "--device",
            "openhaptics:Left Arm",
            "--addr",
            "127.0.0.1:0",
            "--record-dir",
            &record_dir.display().to_string(),
        ],
        Some(&fake),
    );
    assert_nothing_started(&out, &record_dir);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(&fake.display().to_string()) && err.contains("could not load"),
        "{err}"
    );
}

#[test]
fn the_device_listing_exits_0_on_a_machine_without_hardware() {
    let out = softhaptic(
        &["devices"],
        Some(Path::new("/nonexistent/OpenHaptics/libHD.so")),
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    for expected in [
        "OpenHaptics (PHANTOM, Touch): not available",
        "/nonexistent/OpenHaptics/libHD.so",
        "Force Dimension (omega, delta, sigma, Falcon): not available",
        "SOFTHAPTIC_DHD_LIBRARY: not set",
        "simulated: always available",
    ] {
        assert!(
            text.contains(expected),
            "{expected:?} missing from:\n{text}"
        );
    }
}

#[test]
fn an_unknown_device_kind_is_refused_by_the_command_line() {
    let out = softhaptic(&["--device", "falcon"], None);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("unknown device kind \"falcon\"") && err.contains("openhaptics"),
        "{err}"
    );
}

#[test]
fn a_spacemouse_that_is_not_plugged_in_is_named_once_and_nothing_starts() {
    let record_dir = scratch("spacemouse-cli");
    // A serial no device has: refused the same way on a desk with a SpaceMouse plugged in.
    let out = softhaptic(
        &[
            "--device",
            "spacemouse:NO-SUCH-SERIAL-0000",
            "--addr",
            "127.0.0.1:0",
            "--record-dir",
            &record_dir.display().to_string(),
        ],
        None,
    );
    assert_nothing_started(&out, &record_dir);
    let err = String::from_utf8_lossy(&out.stderr);
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
