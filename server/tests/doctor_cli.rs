//! The real `softhaptic doctor` on this machine: its JSON report has every check with a verdict
//! and what was found, its exit status is 0, 1 or 2 and agrees with the report, the timing runs
//! when asked for, and `--root` reads a copy of another machine's files.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Runs the binary with `args`, killing it if it is still running after a generous deadline.
fn doctor(args: &[&str]) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_softhaptic"))
        .arg("doctor")
        .args(args)
        .env_remove("RUST_BACKTRACE")
        .env_remove("SOFTHAPTIC_HD_LIBRARY")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("softhaptic runs");
    let deadline = Instant::now() + Duration::from_secs(120);
    while child.try_wait().unwrap().is_none() {
        if Instant::now() > deadline {
            child.kill().unwrap();
            panic!("softhaptic doctor {args:?} still running after 120 s");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

fn json(out: &Output) -> serde_json::Value {
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "stdout is not JSON ({e}):\n{}\nstderr:\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        )
    })
}

const VERDICTS: [&str; 5] = ["good", "info", "unknown", "warn", "fail"];

/// The report's shape, and its exit status beside the process's.
fn assert_report(out: &Output) -> serde_json::Value {
    let report = json(out);
    let code = out.status.code().unwrap();
    assert!((0..=2).contains(&code), "exit status {code}");
    assert_eq!(report["exit_code"], code, "{report:#}");
    let status = report["status"].as_str().unwrap();
    assert_eq!(
        status,
        ["ready", "warnings", "cannot_run"][code as usize],
        "{report:#}"
    );
    let checks = report["checks"].as_array().unwrap();
    let ids: Vec<&str> = checks.iter().map(|c| c["id"].as_str().unwrap()).collect();
    for id in [
        "preemption",
        "virtualisation",
        "sched_fifo",
        "memory_lock",
        "swap",
        "cpu_isolation",
        "irq_affinity",
        "cpu_governor",
        "haptic_device",
        "hidraw",
    ] {
        assert!(ids.contains(&id), "no {id} in {ids:?}");
    }
    for c in checks {
        assert!(VERDICTS.contains(&c["verdict"].as_str().unwrap()), "{c:#}");
        assert!(!c["found"].as_str().unwrap().is_empty(), "{c:#}");
        assert!(!c["title"].as_str().unwrap().is_empty(), "{c:#}");
        assert!(c["fix"].is_null() || c["fix"].is_string(), "{c:#}");
        // Every warning or failure says what to do about it.
        if matches!(c["verdict"].as_str(), Some("warn" | "fail")) {
            assert!(
                c["fix"].is_string(),
                "a {} without a fix: {c:#}",
                c["verdict"]
            );
        }
    }
    let worst = checks
        .iter()
        .map(|c| c["verdict"].as_str().unwrap())
        .chain(report["timing"]["verdict"].as_str())
        .map(|v| VERDICTS.iter().position(|x| *x == v).unwrap())
        .max()
        .unwrap();
    let expected = match worst {
        4 => 2,
        3 => 1,
        _ => 0,
    };
    assert_eq!(
        code, expected,
        "the exit status is the worst verdict: {report:#}"
    );
    report
}

#[test]
fn doctor_without_timing_reports_every_check_as_json() {
    let out = doctor(&["--json", "--no-timing"]);
    let report = assert_report(&out);
    assert!(report["timing"].is_null(), "{report:#}");
    // The kernel's preemption model is named.
    let preemption = report["checks"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["id"] == "preemption")
        .unwrap();
    assert!(
        preemption["found"].as_str().unwrap().contains("kernel"),
        "{preemption:#}"
    );
}

#[test]
fn doctor_measures_the_loop_idle_and_loaded() {
    let disk = tempfile::tempdir().unwrap();
    let disk_dir = disk.path().to_str().unwrap();
    let out = doctor(&["--json", "--seconds", "1", "--record-dir", disk_dir]);
    let report = assert_report(&out);
    let timing = &report["timing"];
    assert!(timing.is_object(), "{report:#}");
    assert_eq!(timing["goal"]["period_error_p99_us"], 100.0);
    assert!(VERDICTS.contains(&timing["verdict"].as_str().unwrap()));
    if timing["error"].is_null() {
        let runs = timing["runs"].as_array().unwrap();
        assert_eq!(runs.len(), 3, "{timing:#}");
        assert!(runs[0]["neighbour"].as_str().unwrap().starts_with("none"));
        assert!(runs[1]["neighbour"].as_str().unwrap().contains("burning"));
        assert!(runs[2]["neighbour"].as_str().unwrap().starts_with("disk"));
        assert!(runs[2]["neighbour"].as_str().unwrap().contains(disk_dir));
        // The disk writer's scratch file is gone.
        assert_eq!(std::fs::read_dir(disk.path()).unwrap().count(), 0);
        for run in runs {
            // About a thousand ticks in one second, whatever the machine.
            let ticks = run["ticks"].as_u64().unwrap();
            assert!((500..=1500).contains(&ticks), "{run:#}");
            assert!(run["lost_ticks"].as_u64().is_some(), "{run:#}");
            assert!(run["period_error_p99_us"].as_f64().unwrap() >= 0.0);
            assert!(
                run["period_error_max_us"].as_f64().unwrap()
                    >= run["period_error_p99_us"].as_f64().unwrap()
            );
        }
    } else {
        assert_eq!(timing["verdict"], "fail", "{timing:#}");
        assert_eq!(out.status.code(), Some(2));
    }
}

#[test]
fn doctor_reads_a_copy_of_another_machines_files_and_prints_for_a_person() {
    let root = tempfile::tempdir().unwrap();
    let write = |rel: &str, text: &str| {
        let path = root.path().join(rel);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, text).unwrap();
    };
    write(
        "proc/version",
        "Linux version 6.1.0-25-amd64 (debian-kernel@lists.debian.org) #1 SMP PREEMPT_DYNAMIC Debian 6.1.106-3\n",
    );
    write("proc/cmdline", "ro quiet\n");
    write(
        "proc/self/limits",
        "Max locked memory         65536                65536                bytes\n\
         Max realtime priority     0                    0\n",
    );
    write(
        "proc/self/status",
        "Uid:\t1000\t1000\t1000\t1000\nCapEff:\t0000000000000000\nCpus_allowed_list:\t0-3\n",
    );
    write("sys/devices/system/cpu/online", "0-3\n");

    let out = doctor(&[
        "--json",
        "--no-timing",
        "--root",
        root.path().to_str().unwrap(),
    ]);
    let report = assert_report(&out);
    assert_eq!(
        out.status.code(),
        Some(2),
        "rtprio 0 without CAP_SYS_NICE: {report:#}"
    );
    let fifo = report["checks"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["id"] == "sched_fifo")
        .unwrap();
    assert_eq!(fifo["verdict"], "fail");
    assert!(
        fifo["fix"].as_str().unwrap().contains("rtprio 95"),
        "{fifo:#}"
    );

    // The same as text: each item tagged, found and fixed, and the verdict with its status.
    let out = doctor(&["--no-timing", "--root", root.path().to_str().unwrap()]);
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains("[FAIL] Real-time scheduling (SCHED_FIFO)"),
        "{text}"
    );
    assert!(
        text.contains("found: ") && text.contains("fix:   "),
        "{text}"
    );
    assert!(text.contains("(exit 2)"), "{text}");
    assert_eq!(out.status.code(), Some(2));

    // --no-realtime: the loop is not asked to be real-time, so nothing fails.
    let out = doctor(&[
        "--json",
        "--no-timing",
        "--no-realtime",
        "--root",
        root.path().to_str().unwrap(),
    ]);
    assert_report(&out);
    assert_ne!(out.status.code(), Some(2));
}

#[test]
fn doctor_refuses_a_run_length_out_of_range() {
    let out = doctor(&["--seconds", "0"]);
    assert_eq!(out.status.code(), Some(2), "clap's usage error");
    assert!(String::from_utf8_lossy(&out.stderr).contains("outside 0.2 to 600 s"));
}
