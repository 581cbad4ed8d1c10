//! The server program run against a device stand-in (`tests/openhaptics_cli.rs`,
//! `tests/forcedimension_cli.rs`): it loads the stand-in in its own process, so what the
//! stand-in saw is read from the report lines it appends to a file, not through the controls.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::collections::HashMap;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use softhaptic_server::session::reader::Recording;

use crate::{repo_scenes, scratch_dir, softhaptic_binary};

/// What one run of the server against the stand-in left behind.
pub struct StandinRun {
    pub status: ExitStatus,
    /// The server's log (stderr, `RUST_LOG=info`).
    pub log: String,
    /// The stand-in's report lines, each as its `key=value` fields.
    pub report: Vec<HashMap<String, String>>,
    pub recording: PathBuf,
    /// The run's scratch directory (log, report, recordings), removed by a test that passes.
    pub dir: PathBuf,
}

/// A device stand-in as the server program loads it: the scene, the library and the variables
/// that name it, its report file and its hand's press.
pub struct StandinProgram {
    /// A scene of the repository's scenes/.
    pub scene: &'static str,
    pub library_env: &'static str,
    pub library: &'static Path,
    /// The variable naming the file the stand-in appends its report lines to.
    pub report_env: &'static str,
    /// The variable and value of the stand-in's hand's press.
    pub press: (&'static str, &'static str),
}

/// Runs `softhaptic --scene scenes/<program.scene>` with the stand-in as its device library
/// (and `env` for the stand-in), waits until it serves viewers and has recorded the hand
/// pressing the liver with more than 1 N, then sends it `signal` and waits for it to exit.
pub fn run_until_pressing_then(
    program: &StandinProgram,
    name: &str,
    signal: &str,
    env: &[(&str, &str)],
) -> StandinRun {
    let dir = scratch_dir(name);
    let report_path = dir.join("standin-report.txt");
    let log_path = dir.join("server.log");
    let mut command = Command::new(softhaptic_binary());
    command
        .arg("--scene")
        .arg(repo_scenes().join(program.scene))
        .args(["--addr", "127.0.0.1:0"])
        .arg("--record-dir")
        .arg(dir.join("sessions"))
        .env_remove("RUST_BACKTRACE")
        .env(program.library_env, program.library)
        .env(program.report_env, &report_path)
        .env(program.press.0, program.press.1)
        .env("RUST_LOG", "info")
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(&log_path).unwrap());
    for (key, value) in env {
        command.env(key, value);
    }
    let mut child = command.spawn().expect("softhaptic runs");
    let log = || std::fs::read_to_string(&log_path).unwrap_or_default();
    let mut recording = None;
    for line in BufReader::new(child.stdout.take().unwrap()).lines() {
        let line = line.unwrap();
        if let Some(p) = line.strip_prefix("recording: ") {
            recording = Some(PathBuf::from(p));
        }
        if line.starts_with("viewer: ") {
            break;
        }
    }
    let Some(recording) = recording else {
        let _ = child.kill();
        panic!("the server did not start recording:\n{}", log());
    };
    // Serving and ticking: the recording holds ticks of the hand pressing in.
    let give_up = Instant::now() + Duration::from_secs(60);
    loop {
        let pressing = Recording::open(&recording).is_ok_and(|r| {
            r.device.iter().any(|d| {
                let [x, y, z] = d.force_n;
                (x * x + y * y + z * z).sqrt() > 1.0
            })
        });
        if pressing {
            break;
        }
        if Instant::now() > give_up {
            let _ = child.kill();
            panic!("no press above 1 N recorded within 60 s:\n{}", log());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let sent = Command::new("kill")
        .args([format!("-{signal}"), child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    let give_up = Instant::now() + Duration::from_secs(60);
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if Instant::now() > give_up {
            let _ = child.kill();
            panic!("SIG{signal} did not stop the server:\n{}", log());
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let report = std::fs::read_to_string(&report_path)
        .unwrap_or_default()
        .lines()
        .map(|line| {
            line.split_whitespace()
                .filter_map(|field| field.split_once('='))
                .map(|(k, v)| (k.to_owned(), v.to_owned()))
                .collect()
        })
        .collect();
    StandinRun {
        status,
        log: log(),
        report,
        recording,
        dir,
    }
}

/// A report field as a number.
pub fn number(line: &HashMap<String, String>, key: &str) -> f64 {
    line[key]
        .parse()
        .unwrap_or_else(|e| panic!("{key}={}: {e}", line[key]))
}

/// `softhaptic info` on the run's recording (without the stand-in's library in its
/// environment) says it is complete and names the device by `device_word`.
pub fn assert_recording_complete(
    run: &StandinRun,
    library_env: &str,
    device_word: &str,
    signal: &str,
) {
    let info = Command::new(softhaptic_binary())
        .arg("info")
        .arg(&run.recording)
        .env_remove("RUST_BACKTRACE")
        .env_remove(library_env)
        .output()
        .expect("softhaptic info runs");
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(
        info.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&info.stderr)
    );
    for expected in ["status:            complete", device_word] {
        assert!(
            text.contains(expected),
            "SIG{signal}: {expected:?} missing from:\n{text}"
        );
    }
}
