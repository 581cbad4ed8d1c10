//! The real `softhaptic doctor` on this machine: its JSON report has every check with a verdict
//! and what was found, its exit status is 0, 1 or 2 and agrees with the report, the timing runs
//! when asked for, and `--root` reads a copy of another machine's files. End to end, a copy of
//! exactly the files the checks read on this machine gives the verdicts the machine itself
//! gives (whatever the machine: the fixtures' predictions are the unit tests'), and the kernel's
//! preemption model is named wherever its build configuration can be read. On a kernel that
//! preempts none or voluntary, the items that do not depend on the machine are judged as the
//! unit tests' `stock` fixture predicts (`server/doctor/src/stock_verdicts.rs`).

// Test code, synchronous: reads what the doctor reads (/proc, /sys, /boot) to check its report,
// and polls the command it started.
#![allow(clippy::disallowed_methods)]
#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::io::Read as _;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

#[path = "../doctor/src/stock_verdicts.rs"]
mod stock_verdicts;
use stock_verdicts::{STOCK_PREEMPTION_NAMES, STOCK_VERDICTS};

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
    let deadline = Instant::now() + Duration::from_secs(240);
    while child.try_wait().unwrap().is_none() {
        if Instant::now() > deadline {
            child.kill().unwrap();
            panic!("softhaptic doctor {args:?} still running after 240 s");
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
    // A check that could not be read ("unknown") is a warning: nothing shows it is good.
    let expected = match worst {
        4 => 2,
        2 | 3 => 1,
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

/// Copies `/rel` of this machine into `root` when it can be read (as bytes: `/proc/config.gz`
/// is gzip); a file the machine does not have stays missing in the copy too.
fn copy_file(root: &Path, rel: &str) {
    let Ok(bytes) = std::fs::read(Path::new("/").join(rel.trim_start_matches('/'))) else {
        return;
    };
    let path = root.join(rel.trim_start_matches('/'));
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, bytes).unwrap();
}

/// The names in `/rel` of this machine.
fn names(rel: &str) -> Vec<String> {
    std::fs::read_dir(rel)
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default()
}

/// A copy of every file the doctor's checks read on this machine, into `root`. The process's
/// own files (`/proc/self/…`) are this test's, whose limits, capabilities, CPUs and cgroup the
/// doctor it starts inherits. Device nodes cannot be copied: `/dev/hidraw*` become symbolic
/// links to this machine's, which open as the nodes do.
fn copy_host_files(root: &Path) {
    for rel in [
        "/proc/version",
        "/proc/sys/kernel/osrelease",
        "/proc/config.gz",
        "/proc/cmdline",
        "/proc/cpuinfo",
        "/proc/stat",
        "/proc/swaps",
        "/proc/interrupts",
        "/proc/self/limits",
        "/proc/self/status",
        "/proc/self/cgroup",
        "/sys/kernel/realtime",
        "/sys/kernel/debug/sched/preempt",
        "/sys/class/dmi/id/sys_vendor",
        "/sys/class/dmi/id/product_name",
        "/sys/devices/system/cpu/online",
        "/sys/devices/system/cpu/isolated",
        "/sys/devices/system/cpu/nohz_full",
        "/sys/fs/cgroup/cpuset.cpus.isolated",
        "/etc/passwd",
    ] {
        copy_file(root, rel);
    }
    if let Ok(release) = std::fs::read_to_string("/proc/sys/kernel/osrelease") {
        copy_file(root, &format!("/boot/config-{}", release.trim()));
    }
    for cpu in names("/sys/devices/system/cpu") {
        if cpu.starts_with("cpu") && cpu[3..].parse::<usize>().is_ok() {
            copy_file(
                root,
                &format!("/sys/devices/system/cpu/{cpu}/cpufreq/scaling_governor"),
            );
        }
    }
    for irq in names("/proc/irq") {
        for file in ["effective_affinity_list", "smp_affinity_list"] {
            copy_file(root, &format!("/proc/irq/{irq}/{file}"));
        }
        copy_file(root, &format!("/sys/kernel/debug/irq/irqs/{irq}"));
    }
    // The process's cgroups: v2's `0::/path`, v1's `n:cpu,cpuacct:/path`.
    let cgroups = std::fs::read_to_string("/proc/self/cgroup").unwrap_or_default();
    for line in cgroups.lines() {
        let mut fields = line.splitn(3, ':');
        let (Some(_), Some(controllers), Some(path)) =
            (fields.next(), fields.next(), fields.next())
        else {
            continue;
        };
        let path = path.trim_end_matches('/');
        let mut dirs = vec![format!("/sys/fs/cgroup{path}")];
        if !controllers.is_empty() {
            dirs.push(format!("/sys/fs/cgroup/{controllers}{path}"));
            dirs.extend(
                controllers
                    .split(',')
                    .map(|c| format!("/sys/fs/cgroup/{c}{path}")),
            );
            dirs.push(format!("/sys/fs/cgroup/cpuacct,cpu{path}"));
        }
        for dir in dirs {
            for file in [
                "cpuset.cpus.effective",
                "cpuset.effective_cpus",
                "cpuset.cpus",
                "cpu.rt_runtime_us",
            ] {
                copy_file(root, &format!("{dir}/{file}"));
            }
        }
    }
    std::fs::create_dir_all(root.join("dev")).unwrap();
    for node in names("/dev") {
        if node.starts_with("hidraw") {
            std::os::unix::fs::symlink(Path::new("/dev").join(&node), root.join("dev").join(&node))
                .unwrap();
        }
    }
}

/// Each check's verdict by its id, with what it found where that holds no count that grows
/// while the machine runs (steal time, interrupts, swap in use).
fn verdicts(report: &serde_json::Value) -> Vec<(String, String, Option<String>)> {
    const STEADY: [&str; 5] = [
        "preemption",
        "sched_fifo",
        "memory_lock",
        "cpu_isolation",
        "cpu_governor",
    ];
    report["checks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            let id = c["id"].as_str().unwrap();
            (
                id.to_owned(),
                c["verdict"].as_str().unwrap().to_owned(),
                STEADY
                    .contains(&id)
                    .then(|| c["found"].as_str().unwrap().to_owned()),
            )
        })
        .collect()
}

/// The check `id` of a report.
fn check<'a>(report: &'a serde_json::Value, id: &str) -> &'a serde_json::Value {
    report["checks"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["id"] == id)
        .unwrap()
}

/// Whether this machine's build configuration can be read and chooses a preemption model:
/// `/sys/kernel/realtime`, `/proc/config.gz` or `/boot/config-<release>`.
fn build_configuration_readable() -> bool {
    let names_a_model = |config: &str| {
        config.lines().any(|l| {
            [
                "CONFIG_PREEMPT_NONE=y",
                "CONFIG_PREEMPT_VOLUNTARY=y",
                "CONFIG_PREEMPT=y",
                "CONFIG_PREEMPT_LAZY=y",
                "CONFIG_PREEMPT_RT=y",
            ]
            .contains(&l.trim())
        })
    };
    let proc_config = std::fs::File::open("/proc/config.gz").ok().and_then(|f| {
        let mut text = String::new();
        flate2::read::GzDecoder::new(f)
            .read_to_string(&mut text)
            .ok()
            .map(|_| text)
    });
    let boot_config = std::fs::read_to_string("/proc/sys/kernel/osrelease")
        .ok()
        .and_then(|r| std::fs::read_to_string(format!("/boot/config-{}", r.trim())).ok());
    std::fs::read_to_string("/sys/kernel/realtime").is_ok_and(|t| t.trim() == "1")
        || proc_config.as_deref().is_some_and(names_a_model)
        || boot_config.as_deref().is_some_and(names_a_model)
}

#[test]
fn doctor_gives_this_machines_verdicts_from_a_copy_of_the_files_it_reads() {
    // Interrupt counts grow between the copy and the runs: an interrupt first handled on the
    // loop's CPU in between changes that one verdict. Such a race passes on a second copy; a
    // check that reads the copy differently from the machine fails every time.
    let mut attempts = Vec::new();
    for _ in 0..3 {
        let root = tempfile::tempdir().unwrap();
        copy_host_files(root.path());
        let here = assert_report(&doctor(&["--json", "--no-timing"]));
        let copy = assert_report(&doctor(&[
            "--json",
            "--no-timing",
            "--root",
            root.path().to_str().unwrap(),
        ]));
        let (here, copy) = (verdicts(&here), verdicts(&copy));
        assert_eq!(here.len(), 11, "{here:?}");
        if here == copy {
            attempts.clear();
            break;
        }
        attempts.push((here, copy));
    }
    assert!(
        attempts.is_empty(),
        "this machine's verdicts, then the copy's: {attempts:#?}"
    );

    // The preemption model is named wherever the kernel's build configuration says it, and
    // judged as the fixtures judge it: good when preemptible, a warning when not.
    let report = assert_report(&doctor(&["--json", "--no-timing"]));
    let preemption = check(&report, "preemption");
    let found = preemption["found"].as_str().unwrap();
    if build_configuration_readable() {
        assert!(
            !found.contains("unknown") && !found.contains("none or voluntary"),
            "the build configuration is readable, and the model is not named: {preemption:#}"
        );
        let preemptible = ["PREEMPT_RT", "full (", "lazy ("]
            .iter()
            .any(|m| found.contains(m));
        assert_eq!(
            preemption["verdict"],
            if preemptible { "good" } else { "warn" },
            "{preemption:#}"
        );
    } else {
        eprintln!("no build configuration readable here: {found}");
    }
}

#[test]
fn on_a_stock_kernel_this_machine_is_judged_as_the_stock_fixture_predicts() {
    let report = assert_report(&doctor(&["--json", "--no-timing"]));
    let found = check(&report, "preemption")["found"].as_str().unwrap();
    // Each row beside this machine's verdict, for whoever reads the output.
    for row in &STOCK_VERDICTS {
        eprintln!(
            "{:<15} stock fixture {:<5} here {:<5} {}",
            row.id,
            row.verdict,
            check(&report, row.id)["verdict"].as_str().unwrap(),
            row.depends_on.unwrap_or("(the same on any stock host)")
        );
    }
    if !STOCK_PREEMPTION_NAMES
        .iter()
        .any(|name| found.contains(name))
    {
        eprintln!("not a kernel that preempts none or voluntary: {found}");
        return;
    }
    let independent: Vec<&str> = STOCK_VERDICTS
        .iter()
        .filter(|row| row.depends_on.is_none())
        .map(|row| row.id)
        .collect();
    assert_eq!(independent, ["preemption", "cpu_isolation"]);
    for row in STOCK_VERDICTS.iter().filter(|row| row.depends_on.is_none()) {
        let c = check(&report, row.id);
        assert_eq!(c["verdict"], row.verdict, "{c:#}");
    }
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
            // The run lasted what was asked and the loop ticked in it; how many ticks a loaded
            // machine manages in a second is the measurement, not something to assert.
            let ticks = run["ticks"].as_u64().unwrap();
            assert!(ticks > 0, "{run:#}");
            assert!(run["seconds"].as_f64().unwrap() >= 1.0, "{run:#}");
            assert!(
                run["ticks_by_standby"].as_u64().unwrap() <= ticks,
                "{run:#}"
            );
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

#[test]
fn a_doctor_that_cannot_run_exits_2_with_the_reason_and_no_report() {
    let missing = tempfile::tempdir().unwrap().path().join("sessions");
    let out = doctor(&[
        "--json",
        "--seconds",
        "0.2",
        "--record-dir",
        missing.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(out.stdout.is_empty(), "no report");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("no such directory") && stderr.contains(missing.to_str().unwrap()),
        "{stderr}"
    );
}

#[test]
fn the_help_gives_each_exit_status() {
    let out = doctor(&["--help"]);
    assert_eq!(out.status.code(), Some(0));
    let help = String::from_utf8_lossy(&out.stdout);
    for status in ["0  ready", "1  warnings", "2  cannot run"] {
        assert!(help.contains(status), "{help}");
    }
}
