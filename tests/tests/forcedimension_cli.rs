//! The real `softhaptic` binary driving a Force Dimension device, with the SDK stand-in
//! ([`dhd_standin_path`], built by `build.rs`) as the library it loads, on
//! `scenes/forcedimension.toml`: the log says which limits are in use, and SIGTERM or SIGINT
//! send zero force, put the brakes on and close the device before the process exits, with the
//! recording complete.
//!
//! The binary loads the stand-in in its own process, so what the stand-in saw is read from the
//! report it writes there (`DHD_STANDIN_REPORT`); each test runs its own server.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use softhaptic_device::forcedimension::LIBRARY_ENV;
use softhaptic_tests::dhd_standin::dhd_standin_path;
use softhaptic_tests::standin_cli::{
    StandinProgram, assert_recording_complete, number, run_until_pressing_then,
};

fn program() -> StandinProgram {
    StandinProgram {
        scene: "forcedimension.toml",
        library_env: LIBRARY_ENV,
        library: dhd_standin_path(),
        report_env: "DHD_STANDIN_REPORT",
        // The stand-in's hand presses along the SDK's −z (down, as the scene turns it) through
        // the device's origin on the liver's surface, its target from 5 to 25 mm below it and
        // back: the tool is pressed in whenever the signal comes, so a zero force at the stop is
        // the server's.
        press: ("DHD_STANDIN_PRESS", "0,0,-25,0,3"),
    }
}

#[test]
fn sigterm_and_sigint_send_zero_force_put_the_brakes_on_and_close_the_device() {
    for signal in ["TERM", "INT"] {
        let run = run_until_pressing_then(
            &program(),
            &format!("forcedimension-cli-stop-{signal}"),
            signal,
            &[],
        );
        let log = &run.log;
        assert!(run.status.success(), "SIG{signal}: {}:\n{log}", run.status);
        assert!(
            log.contains(&format!("shutting down signal=\"SIG{signal}\"")),
            "SIG{signal} is logged:\n{log}"
        );
        assert!(
            log.contains("haptic device limits in use") && log.contains("omega.3"),
            "{log}"
        );
        let events: Vec<&str> = run.report.iter().map(|l| l["event"].as_str()).collect();
        // The brakes put on once and the device closed once, in that order, at the stop.
        assert_eq!(events, ["brakes", "close"], "SIG{signal}: {:?}", run.report);
        let brakes = &run.report[0];
        assert_eq!(
            brakes["motor_force_n"], "0,0,0",
            "SIG{signal}: the motors when the brakes went on: {brakes:?}"
        );
        // The hand was pressing until the stop: the last force other than zero was a real one,
        // sent at most a few ticks before the stop's zero.
        assert!(
            number(brakes, "last_nonzero_force_n") > 0.5,
            "SIG{signal}: {brakes:?}"
        );
        assert!(
            number(brakes, "commands") - number(brakes, "last_nonzero_command") <= 50.0,
            "SIG{signal}: the force was already zero long before the stop: {brakes:?}"
        );
        assert_eq!(brakes["watchdog_units"], "80", "{brakes:?}");
        let close = &run.report[1];
        assert_eq!(
            (
                close["device"].as_str(),
                close["force"].as_str(),
                close["brakes"].as_str(),
                close["motor_force_n"].as_str()
            ),
            ("closed", "off", "on", "0,0,0"),
            "SIG{signal}: {close:?}"
        );
        // The recording was closed: `softhaptic info` says so.
        assert_recording_complete(&run, LIBRARY_ENV, "Force Dimension", signal);
        let _ = std::fs::remove_dir_all(&run.dir);
    }
}
