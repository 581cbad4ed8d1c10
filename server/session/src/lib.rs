//! Sessions are recorded and replayed.
//!
//! Every session the server runs is written to one MCAP file (unless `--no-record`): the device
//! reading and commanded force of every 1 kHz tick, the 50 Hz contact frames as they were sent,
//! the scene, the build, and the recorder's own loss accounting. The record types and their JSON
//! schemas are in `softhaptic_proto::record`; Foxglove opens the files as they are.
//!
//! # Layout
//! - [`writer`]: [`SessionWriter`](writer::SessionWriter), the file writer (small whole chunks, so a
//!   killed server leaves a readable file), and [`Recorder`](writer::Recorder), the thread that
//!   drains the haptic loop's ring without ever making the loop wait.
//! - [`reader`]: [`Recording`](reader::Recording), a file read back, with recovery of truncated
//!   files and clear refusals of files it cannot trust.
//! - [`check`]: replays a recording's device readings through a freshly built haptic world and
//!   compares the forces bit for bit (the CI replay check, docs/design.md invariant 5).
//! - [`guide`]: a recording as a guide for a trainee (`run --guide`): its path, checked against
//!   the session's object and tool.
//! - [`tools`]: `info` and `export` (CSV).
//! - [`script`]: scripted sessions with the simulated device, recorded without a wall clock
//!   (the test recordings under `tests/sessions/`).
//! - [`replay`]: streams a recording to viewers exactly as a live session, with pause, play and
//!   seek from the viewer.
//! - [`overhead`]: what recording costs the loop's timing (`recording-overhead`).
//! - `build.rs`: the git commit every recording names ([`git_commit`]).
//!
//! The crate serves replays with `softhaptic-serve` and rebuilds recorded scenes with
//! `softhaptic-scene`, whose modules it imports under their own names (`crate::stream`,
//! `crate::scene`, …). The session subcommands, which also start the live server, are the
//! `softhaptic` binary's (`server/src/session/cli.rs`).

pub mod check;
pub mod guide;
pub mod overhead;
pub mod reader;
pub mod replay;
pub mod script;
pub mod tools;
pub mod writer;

use std::path::PathBuf;

use softhaptic_io::files;
use softhaptic_scene as scene;
use softhaptic_serve::{access, routes, stream, tls, viewer};

/// Why a recording could not be written or read. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// The OS's reason is part of this message rather than a separate cause, so that an error
    /// chain prints it once.
    #[error("{path}: {reason}")]
    Io {
        path: PathBuf,
        reason: std::io::Error,
    },
    /// A recording is never written over by accident.
    #[error("{path} exists already and is kept (record-script --replace writes over a recording)")]
    Exists { path: PathBuf },
    #[error("{path} exists already and is kept (export --replace writes over it)")]
    ExportExists { path: PathBuf },
    #[error("{path}: MCAP error: {source}")]
    Mcap {
        path: PathBuf,
        #[source]
        source: mcap::McapError,
    },
    #[error("{path}: could not encode a record: {what}")]
    Encode { path: PathBuf, what: String },
    #[error(
        "{path}: not an MCAP file (first bytes {found}, expected the MCAP magic 89 4d 43 41 50 30 0d 0a)"
    )]
    NotMcap { path: PathBuf, found: String },
    #[error(
        "{path}: channel {topic} has schema {found}, expected {expected}: not a softhaptic recording, or a different format"
    )]
    WrongSchema {
        path: PathBuf,
        topic: String,
        expected: String,
        found: String,
    },
    #[error(
        "{path}: {field} is {found} but this build reads up to {supported} (written by {writer}); use a newer softhaptic"
    )]
    NewerVersion {
        path: PathBuf,
        field: &'static str,
        found: u32,
        supported: u32,
        writer: String,
    },
    #[error(
        "{path}: message {sequence} on {topic} (device time {log_time_ns} ns) is invalid: {reason}"
    )]
    BadMessage {
        path: PathBuf,
        topic: String,
        sequence: u32,
        log_time_ns: u64,
        reason: String,
    },
    #[error(
        "{path}: message {sequence} on {topic} (device time {log_time_ns} ns) is {bytes} bytes; \
         a {topic} message may be at most {limit} bytes: refused, as damaged or made to fill the \
         reader's memory"
    )]
    MessageTooLarge {
        path: PathBuf,
        topic: String,
        sequence: u32,
        log_time_ns: u64,
        bytes: u64,
        limit: u64,
    },
    #[error("{path}: no /build record before the data: not a softhaptic recording")]
    MissingBuild { path: PathBuf },
    #[error("{path}: no /scene record: not a complete softhaptic recording")]
    MissingScene { path: PathBuf },
    #[error(
        "{path}: the file ends after {file_len} bytes, before its build and scene records ({reason}): nothing to recover"
    )]
    TruncatedBeforeStart {
        path: PathBuf,
        file_len: u64,
        reason: String,
    },
    #[error("{path}: the recorder thread panicked")]
    RecorderPanicked { path: PathBuf },
}

/// The git commit this binary was built from, when the build environment gave it
/// (found by `server/session/build.rs` with git at compile time, or `SOFTHAPTIC_GIT_COMMIT` in the build's
/// environment for a tree without `.git`).
pub fn git_commit() -> Option<String> {
    option_env!("SOFTHAPTIC_GIT_COMMIT")
        .filter(|c| !c.is_empty())
        .map(str::to_owned)
}

/// Wall-clock time, nanoseconds since the Unix epoch (0 if the clock is before it).
pub fn unix_now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}
