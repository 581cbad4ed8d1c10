//! The real `softhaptic` binary driving its OpenHaptics device, with the HD API stand-in
//! ([`standin_path`], built by `build.rs`) as the library it loads: the log says which limits the
//! device reported and which are in use, and SIGTERM or SIGINT send zero force, stop the driver's
//! scheduler and close the device before the process exits, with the recording complete.
//!
//! The binary loads the stand-in in its own process, so what the stand-in saw is read from the
//! report it writes there (`HD_STANDIN_REPORT`), not through [`softhaptic_tests::standin`]'s
//! controls; each test runs its own server and they need not take turns.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::process::{Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use softhaptic_tests::standin::standin_path;
use softhaptic_tests::standin_cli::{
    StandinProgram, StandinRun, assert_recording_complete, number, run_until_pressing_then,
};
use softhaptic_tests::{repo_scenes, scratch_dir, softhaptic_binary};

const LIBRARY_ENV: &str = "SOFTHAPTIC_HD_LIBRARY";

/// The program run against the HD stand-in: `scenes/phantom.toml`, its report and its hand.
fn program() -> StandinProgram {
    StandinProgram {
        scene: "phantom.toml",
        library_env: LIBRARY_ENV,
        library: standin_path(),
        report_env: "HD_STANDIN_REPORT",
        // The stand-in's hand presses the liver along the device's −y through its origin (the
        // surface): its target goes from 5 to 25 mm below the surface and back, so the tool is
        // pressed in at every moment a signal may come, and a zero force at the stop is the
        // server's.
        press: ("HD_STANDIN_PRESS", "0,-25,0,0,3"),
    }
}

/// [`run_until_pressing_then`] against the HD stand-in.
fn run_standin_until_pressing_then(name: &str, signal: &str, env: &[(&str, &str)]) -> StandinRun {
    run_until_pressing_then(&program(), name, signal, env)
}

#[test]
fn sigterm_and_sigint_send_zero_force_then_stop_the_scheduler_and_close_the_device() {
    for signal in ["TERM", "INT"] {
        let run =
            run_standin_until_pressing_then(&format!("openhaptics-cli-stop-{signal}"), signal, &[]);
        let log = &run.log;
        assert!(run.status.success(), "SIG{signal}: {}:\n{log}", run.status);
        assert!(
            log.contains(&format!("shutting down signal=\"SIG{signal}\"")),
            "SIG{signal} is logged:\n{log}"
        );
        let events: Vec<&str> = run.report.iter().map(|l| l["event"].as_str()).collect();
        // Loaded once, stopped once and closed once, in that order, and the process ended
        // normally (the library is unloaded only by an orderly exit).
        assert_eq!(
            events,
            ["load", "hdStopScheduler", "hdDisableDevice", "unload"],
            "SIG{signal}: {:?}",
            run.report
        );
        let stop = &run.report[1];
        assert_eq!(
            stop["motor_force_n"], "0,0,0",
            "SIG{signal}: the last force sent before the scheduler stopped: {stop:?}"
        );
        // The hand was pressing until the stop: the last force other than zero was a real one,
        // and went out at most a few frames before the stop (the server's zero frame; a fault
        // tick or two of a loaded machine's late servo thread). The hand never lets go (its
        // target stays 5 mm below the surface), so a stop that left the force to the hand
        // would leave it there.
        assert!(
            number(stop, "last_nonzero_force_n") > 0.5,
            "SIG{signal}: {stop:?}"
        );
        assert!(
            number(stop, "frames") - number(stop, "last_nonzero_frame") <= 50.0,
            "SIG{signal}: the force was already zero long before the stop: {stop:?}"
        );
        assert_eq!(stop["callbacks"], "0", "SIG{signal}: {stop:?}");
        assert_eq!(stop["force_output"], "off", "SIG{signal}: {stop:?}");
        let disable = &run.report[2];
        assert_eq!(
            (disable["scheduler"].as_str(), disable["device"].as_str()),
            ("stopped", "closed"),
            "SIG{signal}: the device is closed after its scheduler stopped: {disable:?}"
        );
        let unload = &run.report[3];
        assert_eq!(unload["motor_force_n"], "0,0,0");
        assert_eq!(
            (unload["scheduler"].as_str(), unload["device"].as_str()),
            ("stopped", "closed"),
            "SIG{signal}: {unload:?}"
        );
        // The recording was closed: `softhaptic info` says so.
        assert_recording_complete(&run, LIBRARY_ENV, "OpenHaptics", signal);
        let _ = std::fs::remove_dir_all(&run.dir);
    }
}

/// The `key=value` fields of the first log line that contains `message`.
fn log_line<'a>(log: &'a str, message: &str) -> &'a str {
    log.lines()
        .find(|l| l.contains(message))
        .unwrap_or_else(|| panic!("no {message:?} in the log:\n{log}"))
}

#[test]
fn the_log_says_which_limits_the_device_reported_and_which_are_in_use() {
    // A device that reports less force than the scene's PHANTOM Desktop preset (7.9 N) and more
    // stiffness (1.86 N/mm against the preset's 1000 N/m): each limit in use is the tighter.
    let run = run_standin_until_pressing_then(
        "openhaptics-cli-limits",
        "TERM",
        &[("HD_STANDIN_MAX_FORCE_N", "5.5")],
    );
    assert!(run.status.success(), "{}:\n{}", run.status, run.log);
    let library = standin_path().display().to_string();
    let reported = log_line(&run.log, "haptic device opened");
    for expected in [
        "device=Default Device",
        "model=PHANTOM Desktop",
        "serial=STANDIN-0001",
        &format!("library={library}"),
        "max_force_n=5.5",
        "continuous_force_n=1.75",
        "max_stiffness_n_per_m=1860.0",
        "max_damping_n_s_per_m=5.0",
        "usable_workspace_mm=[DVec3(-80.0, -60.0, -60.0), DVec3(80.0, 60.0, 60.0)]",
    ] {
        assert!(
            reported.contains(expected),
            "{expected:?} missing from:\n{reported}"
        );
    }
    let in_use = log_line(&run.log, "haptic device limits in use");
    for expected in [
        "the tighter of the device's and the preset's",
        "peak_force_n=5.5",
        "continuous_force_n=1.75",
        "max_stiffness_n_per_m=1000.0",
        "damping_n_s_per_m=5.0",
        "preset=\"PHANTOM Desktop\"",
    ] {
        assert!(
            in_use.contains(expected),
            "{expected:?} missing from:\n{in_use}"
        );
    }
    let _ = std::fs::remove_dir_all(&run.dir);
}

/// Runs the binary with `args`, the stand-in as its library and `env` for it, and waits for it
/// at most `deadline` (a hang is killed and fails the test): its status, stdout and stderr.
fn run_bounded(
    args: &[&str],
    env: &[(&str, &str)],
    deadline: Duration,
) -> (ExitStatus, String, String, Duration) {
    let mut command = Command::new(softhaptic_binary());
    command
        .args(args)
        .env(LIBRARY_ENV, standin_path())
        .env_remove("RUST_BACKTRACE")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    for (k, v) in env {
        command.env(k, v);
    }
    let started = Instant::now();
    let mut child = command.spawn().unwrap();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let took = started.elapsed();
            let output = child.wait_with_output().unwrap();
            return (
                status,
                String::from_utf8_lossy(&output.stdout).into_owned(),
                String::from_utf8_lossy(&output.stderr).into_owned(),
                took,
            );
        }
        if started.elapsed() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("softhaptic {args:?} hangs: still running after {deadline:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn devices_loads_the_library_once_and_never_unloads_it_while_running() {
    let dir = scratch_dir("openhaptics-cli-devices-once");
    let report = dir.join("standin-report.txt");
    let report_text = report.display().to_string();
    let (status, stdout, stderr, _) = run_bounded(
        &["devices"],
        &[("HD_STANDIN_REPORT", &report_text)],
        Duration::from_secs(60),
    );
    assert!(status.success(), "{status}: {stdout}{stderr}");
    let events: Vec<String> = std::fs::read_to_string(&report)
        .unwrap()
        .lines()
        .filter_map(|l| l.split_whitespace().next().map(str::to_owned))
        .collect();
    let loads = events.iter().filter(|e| *e == "event=load").count();
    let unloads = events.iter().filter(|e| *e == "event=unload").count();
    assert_eq!(loads, 1, "{events:?}");
    // At most the process' own exit, last.
    assert!(
        unloads <= 1 && (unloads == 0 || events.last().unwrap() == "event=unload"),
        "{events:?}"
    );
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn a_scheduler_that_does_not_start_ends_run_and_devices_at_once_with_the_cause() {
    let scene = repo_scenes().join("phantom.toml");
    let scene = scene.display().to_string();
    let dir = scratch_dir("openhaptics-cli-timer");
    let record = dir.join("sessions").display().to_string();
    for args in [
        vec![
            "--scene",
            &scene,
            "--addr",
            "127.0.0.1:0",
            "--record-dir",
            &record,
        ],
        vec!["devices"],
    ] {
        let (status, stdout, stderr, took) = run_bounded(
            &args,
            &[("HD_STANDIN_FAIL_START", "1000")],
            Duration::from_secs(60),
        );
        let said = format!("{stdout}{stderr}");
        assert!(said.contains("HD_TIMER_ERROR"), "{args:?}: {said}");
        assert!(said.contains("real-time"), "{args:?}: what to do: {said}");
        assert!(
            !said.contains("disconnected"),
            "{args:?}: not the cause: {said}"
        );
        if args[0] != "devices" {
            assert!(!status.success(), "{args:?}: {status}");
        }
        println!("softhaptic {}: the driver's error after {took:?}", args[0]);
    }
    let _ = std::fs::remove_dir_all(dir);
}
