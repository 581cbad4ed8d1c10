//! The session subcommands of the real `softhaptic` binary on the test recordings: `check` passes
//! and fails with the right exit code and report, `info` and `export` describe and convert, and a
//! bad file gets a clear error and a non-zero exit, not a panic.

// Test code, synchronous: reads the files the commands wrote and the source tree's recordings.
#![allow(clippy::disallowed_methods)]
#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn recording(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join("tests")
        .join("sessions")
        .join(name)
}

fn softhaptic(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_softhaptic"))
        .args(args)
        .env_remove("RUST_BACKTRACE")
        .env_remove("RUST_LIB_BACKTRACE")
        .output()
        .expect("softhaptic runs")
}

#[test]
fn check_passes_on_a_recording_and_fails_naming_the_tick_when_damping_changes() {
    let file = recording("cone-press.mcap");
    let ok = softhaptic(&["check".as_ref(), file.as_os_str()]);
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    assert!(String::from_utf8_lossy(&ok.stdout).contains("every force identical bit for bit"));

    let changed = softhaptic(&[
        "check".as_ref(),
        file.as_os_str(),
        "--damping".as_ref(),
        "4.5".as_ref(),
    ]);
    assert_eq!(changed.status.code(), Some(1));
    let err = String::from_utf8_lossy(&changed.stderr);
    assert!(
        err.contains("replay check failed")
            && err.contains("forces differ at tick")
            && err.contains("recorded force_n")
            && err.contains("replayed force_n"),
        "{err}"
    );
}

#[test]
fn info_describes_the_fault_recording() {
    let out = softhaptic(&[
        "info".as_ref(),
        recording("fault-mid-press.mcap").as_os_str(),
    ]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for expected in [
        "ticks:             3000 recorded, 0 missing",
        "device faults:     200 ticks in 1 gap of zero force, the longest 200 ticks at tick 1400",
        "gap at 1.399 s (tick 1400): 200 ticks, device disconnected",
        "device:            simulated PHANTOM Desktop",
        "device_fault (200 ticks)",
        "status:            complete",
        "peak force:",
    ] {
        assert!(
            text.contains(expected),
            "{expected:?} missing from:\n{text}"
        );
    }
}

#[test]
fn export_writes_one_csv_row_per_tick_and_per_frame() {
    let out_dir = std::env::temp_dir().join(format!("softhaptic-export-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out_dir);
    let out = softhaptic(&[
        "export".as_ref(),
        recording("slide.mcap").as_os_str(),
        "--out".as_ref(),
        out_dir.as_os_str(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let device = std::fs::read_to_string(out_dir.join("device.csv")).unwrap();
    let contact = std::fs::read_to_string(out_dir.join("contact.csv")).unwrap();
    let _ = std::fs::remove_dir_all(&out_dir);
    let header: Vec<&str> = device.lines().next().unwrap().split(',').collect();
    assert_eq!(device.lines().count(), 4001);
    for line in device.lines().skip(1) {
        assert_eq!(line.split(',').count(), header.len(), "{line}");
    }
    let fy = header.iter().position(|h| *h == "force_y_n").unwrap();
    let max_fy = device
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(fy).unwrap().parse::<f64>().unwrap())
        .fold(0.0, f64::max);
    assert!(max_fy > 0.5, "the slide pushes back: {max_fy} N");
    assert_eq!(contact.lines().count(), 201);
    assert!(contact.starts_with("log_time_ns,seq,tick,time_ns"));
}

#[test]
fn a_bad_file_gets_a_clear_error_and_a_non_zero_exit() {
    let dir = std::env::temp_dir().join(format!("softhaptic-badcli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let truncated = dir.join("cut.mcap");
    let bytes = std::fs::read(recording("sphere-press.mcap")).unwrap();
    std::fs::write(&truncated, &bytes[..30]).unwrap();
    let text_file = dir.join("text.mcap");
    std::fs::write(&text_file, "not a recording").unwrap();
    for (file, expected) in [
        (&truncated, "before its build and scene records"),
        (&text_file, "not an MCAP file"),
    ] {
        for cmd in ["info", "check"] {
            let out = softhaptic(&[cmd.as_ref(), file.as_os_str()]);
            let err = String::from_utf8_lossy(&out.stderr);
            assert_eq!(out.status.code(), Some(1), "{cmd}: {err}");
            assert!(
                err.contains(expected) && !err.contains("panicked"),
                "{cmd}: {err}"
            );
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn record_script_writes_the_same_bytes_twice() {
    let dir = std::env::temp_dir().join(format!("softhaptic-script-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut files = Vec::new();
    for run in ["a.mcap", "b.mcap"] {
        let file = dir.join(run);
        let out = softhaptic(&[
            "record-script".as_ref(),
            "--script".as_ref(),
            "fault-mid-press".as_ref(),
            "--out".as_ref(),
            file.as_os_str(),
        ]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        files.push(std::fs::read(&file).unwrap());
    }
    // Refuses to overwrite without --replace.
    let again = softhaptic(&[
        "record-script".as_ref(),
        "--script".as_ref(),
        "slide".as_ref(),
        "--out".as_ref(),
        dir.join("a.mcap").as_os_str(),
    ]);
    let _ = std::fs::remove_dir_all(&dir);
    assert!(files[0] == files[1], "two runs of a script differ");
    assert!(files[0].len() > 100_000 && files[0].len() < 1_000_000);
    assert_eq!(again.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&again.stderr).contains("a.mcap"));
}

#[test]
fn a_reader_that_closes_early_ends_the_report_quietly() {
    // `softhaptic info FILE | head`: the pipe's reader is gone before anything is written.
    for args in [
        vec!["info".into(), recording("slide.mcap").into_os_string()],
        vec![
            "check".into(),
            recording("cone-press.mcap").into_os_string(),
        ],
        vec!["devices".into()],
    ] {
        let (reader, writer) = std::io::pipe().unwrap();
        drop(reader);
        let out = Command::new(env!("CARGO_BIN_EXE_softhaptic"))
            .args(&args)
            .env("SOFTHAPTIC_HD_LIBRARY", "/nonexistent/libHD.so")
            .stdout(writer)
            .stderr(std::process::Stdio::piped())
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{args:?}: {:?} {err}", out.status);
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
}

#[test]
fn an_os_error_is_printed_once() {
    let out = softhaptic(&["info".as_ref(), "/nonexistent/session.mcap".as_ref()]);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.matches("No such file or directory").count(), 1, "{err}");
}

#[test]
fn a_negative_damping_is_refused_with_the_reason() {
    let out = softhaptic(&[
        "check".as_ref(),
        recording("slide.mcap").as_os_str(),
        "--damping".as_ref(),
        "-5".as_ref(),
    ]);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--damping must be finite and >= 0, got -5"),
        "{err}"
    );
}
