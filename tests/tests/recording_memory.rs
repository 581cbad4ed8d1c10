//! `softhaptic info`, `check`, `export` and `replay` run as a user runs them on a recording made
//! to fill their memory (`padded-recording`: valid in every respect, four contact frames padded
//! with 50 MiB of whitespace each, 140 KB on disk): each refuses it naming the limit, and its peak
//! resident memory, read from the kernel when it is waited for, stays under a bound. Before the
//! limits `softhaptic info` held the 200 MiB of frames (2.1 GB for forty of them).
//!
//! Alone in its file, and the file made by a child process: a child's peak memory as the kernel
//! counts it starts from its parent's at the `exec`, so this test's own process must stay small.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::process::{Command, Stdio};

use softhaptic_tests::{scratch_dir, softhaptic_binary};

/// Runs `softhaptic ARGS`: its exit code, its stderr, and its peak resident memory in bytes
/// (the kernel's account of the child, from `wait4`).
// Waited for with `wait4`, not `Child::wait`: only `wait4` gives the child's resource usage.
#[allow(clippy::zombie_processes)]
fn run_measured(args: &[&std::ffi::OsStr]) -> (i32, String, u64) {
    let child = Command::new(softhaptic_binary())
        .args(args)
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id() as libc::pid_t;
    let mut stderr = child.stderr.unwrap();
    let reader = std::thread::spawn(move || {
        let mut text = String::new();
        std::io::Read::read_to_string(&mut stderr, &mut text).unwrap();
        text
    });
    let mut status = 0;
    // SAFETY: an all-zero rusage is a valid value of the plain C struct.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: `pid` is this process's child, not yet waited for (`child` was consumed above
    // without a wait); `status` and `usage` are valid for writes.
    let waited = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    assert_eq!(waited, pid, "{}", std::io::Error::last_os_error());
    let stderr = reader.join().unwrap();
    let code = if libc::WIFEXITED(status) {
        libc::WEXITSTATUS(status)
    } else {
        -libc::WTERMSIG(status)
    };
    // Linux gives ru_maxrss in KiB.
    (code, stderr, usage.ru_maxrss as u64 * 1024)
}

#[test]
fn every_reader_refuses_the_padded_file_within_a_memory_bound() {
    let dir = scratch_dir("limits-cli");
    let path = dir.join("padded.mcap");
    // 200 MiB of frames from a file of a few KiB more than its ticks: what the reader held
    // before the limits (it kept every frame's text, padding and all).
    let made = Command::new(env!("CARGO_BIN_EXE_padded-recording"))
        .arg(&path)
        .args(["4", "51200"])
        .output()
        .unwrap();
    assert!(made.status.success(), "{made:?}");
    let out = dir.join("export");
    let file = path.as_os_str();
    let commands: [Vec<&std::ffi::OsStr>; 4] = [
        vec!["info".as_ref(), file],
        vec!["check".as_ref(), file],
        vec!["export".as_ref(), file, "--out".as_ref(), out.as_os_str()],
        vec![
            "replay".as_ref(),
            file,
            "--addr".as_ref(),
            "127.0.0.1:0".as_ref(),
        ],
    ];
    for args in commands {
        let (code, stderr, peak) = run_measured(&args);
        assert_eq!(code, 1, "{args:?}: {stderr}");
        assert!(
            stderr.contains("more than the limit of"),
            "{args:?}: {stderr}"
        );
        assert!(
            peak < 64 << 20,
            "{args:?}: peak resident memory {} MiB",
            peak >> 20
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
