//! The systemd unit for a device host in `docs/operating.md`: its command line is one this build
//! accepts, its limits let the loop get what it asks for, its state directory is where the
//! recordings go, it names the host for viewers that reach it by name, and (where `systemd-analyze`
//! is installed) systemd itself accepts the unit; that page's doctor command measures the disk the
//! unit records to.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
#![allow(clippy::disallowed_methods)] // test code: reads the source tree's docs

use std::path::Path;
use std::process::Command;

const UNIT_HEADER: &str = "# /etc/systemd/system/softhaptic.service";
/// The binary's path in the documented unit.
const UNIT_BINARY: &str = "/opt/softhaptic/softhaptic";

/// The unit as `docs/operating.md` gives it, from its header comment to the end of the code block.
fn documented_unit() -> String {
    let page = operating_page();
    let start = page
        .find(UNIT_HEADER)
        .expect("docs/operating.md gives the device host's systemd unit");
    let body = &page[start + UNIT_HEADER.len()..];
    let end = body.find("\n```").expect("the unit's code block ends");
    body[..end].trim_start_matches('\n').to_owned()
}

/// The page that documents operating a station.
fn operating_page() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/operating.md"))
        .unwrap()
}

/// Each `key=value` of the unit, continuation lines joined, comments dropped.
fn directives(unit: &str) -> Vec<(String, String)> {
    let joined = unit.replace("\\\n", " ");
    joined
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#') && !l.starts_with('['))
        .filter_map(|l| l.split_once('='))
        .map(|(k, v)| (k.trim().to_owned(), v.trim().to_owned()))
        .collect()
}

fn value<'a>(directives: &'a [(String, String)], key: &str) -> &'a str {
    directives
        .iter()
        .find(|(k, _)| k == key)
        .map(|(_, v)| v.as_str())
        .unwrap_or_else(|| panic!("the unit sets no {key}"))
}

#[test]
fn the_documented_unit_runs_this_build_with_the_limits_the_loop_needs() {
    let unit = documented_unit();
    let d = directives(&unit);

    // The command line: the binary, then arguments this build's `run` accepts (clap reads them
    // in order and stops at `--help`, so an unknown option or a bad value fails first).
    let exec: Vec<&str> = value(&d, "ExecStart").split_whitespace().collect();
    assert_eq!(exec[0], UNIT_BINARY);
    let out = Command::new(env!("CARGO_BIN_EXE_softhaptic"))
        .args(&exec[1..])
        .arg("--help")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{exec:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(exec[1], "run");

    // The loop asks for SCHED_FIFO priority 80 and locked memory.
    let rtprio: u32 = value(&d, "LimitRTPRIO").parse().unwrap();
    assert!(rtprio >= 80, "LimitRTPRIO={rtprio}");
    assert_eq!(value(&d, "LimitMEMLOCK"), "infinity");
    // The recordings go to the state directory systemd makes for the service's user.
    let state = value(&d, "StateDirectory");
    let record_dir = exec
        .windows(2)
        .find(|w| w[0] == "--record-dir")
        .map(|w| w[1])
        .expect("the unit names the recordings' directory");
    assert!(
        record_dir.starts_with(&format!("/var/lib/{state}/")),
        "{record_dir} is not under StateDirectory={state}"
    );
    // Restarted after a crash; given the time to close the recording on a stop.
    assert_eq!(value(&d, "Restart"), "on-failure");
    let stop_s: u32 = value(&d, "TimeoutStopSec").parse().unwrap();
    assert!(stop_s >= 10);
    // Beyond loopback the server refuses to start without tokens: the unit gives them.
    assert!(exec.contains(&"--token-file"), "{exec:?}");
    // A viewer's request naming a host other than an address, localhost or a --host-name is
    // refused: the unit names the host as viewers type it.
    assert!(
        exec.windows(2)
            .any(|w| w[0] == "--host-name" && w[1].contains('.')),
        "{exec:?}"
    );

    // The page's doctor command, run as the service runs, writes its disk run where the
    // service records.
    let page = operating_page();
    let confirm = page
        .split("```")
        .find(|block| block.contains("systemd-run") && block.contains("doctor"))
        .expect("docs/operating.md confirms the host with the doctor under systemd-run");
    let confirm = confirm.replace("\\\n", " ");
    let confirm: Vec<&str> = confirm.split_whitespace().collect();
    let doctor_record_dir = confirm
        .windows(2)
        .find(|w| w[0] == "--record-dir")
        .map(|w| w[1]);
    assert_eq!(doctor_record_dir, Some(record_dir), "{confirm:?}");
}

#[test]
fn systemd_accepts_the_documented_unit() {
    let Ok(version) = Command::new("systemd-analyze").arg("--version").output() else {
        eprintln!("systemd-analyze is not installed: the unit's syntax is not checked here");
        return;
    };
    assert!(version.status.success());
    let dir = tempfile::tempdir().unwrap();
    // The unit as installed, with this build's binary where the page puts its own.
    let unit = documented_unit().replace(UNIT_BINARY, env!("CARGO_BIN_EXE_softhaptic"));
    let path = dir.path().join("softhaptic.service");
    std::fs::write(&path, unit).unwrap();
    let out = Command::new("systemd-analyze")
        .arg("verify")
        .arg(&path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "systemd-analyze verify: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}
