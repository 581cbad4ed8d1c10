//! Reading a recorded session back, whole or as much of it as survived.
//!
//! [`Recording::open`] first walks the file's records itself: every chunk is checked (its sizes,
//! its decompression, its checksum, the lengths of the records inside) before the MCAP library
//! parses it, and a damaged chunk is skipped, not trusted: the walk resumes at the next chunk that
//! checks out, so one bad sector loses about a second of a session (the writer closes one chunk per
//! second of device time), never the rest of it. Every other record's fields must end where its
//! length says, and a length that led the walk into damage is not trusted: the search for the next
//! good chunk starts where that record did. The index and summary after the data are not needed,
//! and read only for the channels when the first chunk (which defines them) and its copy are
//! lost, so damage there hides nothing. The first chunk also holds the build and scene records,
//! without which nothing else can be read: when it is damaged, the writer's copy of it (an
//! attachment right after it) takes its place. A file cut short by a crash yields every complete chunk before the cut.
//! [`Recording::recovery`] says what was recovered and what was lost, as device-time ranges. Files
//! that are not recordings, or not ones this build can read (wrong magic, a channel with another
//! schema, a newer format or protocol version, a message that does not parse) are refused with a
//! [`SessionError`] naming the file and the cause.
//!
//! What a reader holds is bounded by the file's size, whoever made the file: its chunks may
//! decompress to at most 64 times its size (and 32 MiB for any file; a recording this build
//! writes decompresses to about 5 times), checked from the chunks' headers before anything is
//! decompressed; every message has a size limit of its channel (a contact frame 64 KiB, a tick
//! 4 KiB, the scene with its meshes a chunk); and the frames are kept as compact text, without
//! whitespace a file may have padded them with. A file past a limit is refused, naming it: a
//! few hundred kilobytes of whitespace-padded frames once made `info` take 2.1 GB.
//!
//! # Layout
//! - this file: [`Recording`] and what it holds, [`Recording::open`], and the account of what
//!   was recovered ([`Recovery`]).
//! - `walk.rs`: the walk over the file's records that checks every chunk and skips damage, and
//!   the bytes it hands the MCAP library.
//! - `decode.rs`: the records the library parses, turned into a [`Recording`]; the schema and
//!   version checks.

mod decode;
mod walk;

use std::fmt;
use std::path::{Path, PathBuf};

use softhaptic_proto::record::{BuildRecord, DeviceRecord, RecordingStats, SceneRecord};

use super::SessionError;
use walk::FileSource;

/// One `/contact` or `/loop_stats` message: its device time and the wire text exactly as it was
/// sent.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedMessage {
    pub time_ns: u64,
    pub json: String,
}

/// How a file ended.
#[derive(Debug, Clone, PartialEq)]
pub enum Ending {
    /// The writer closed the file: final stats, summary and footer are present.
    Complete,
    /// The file stops early (the server was killed, the disk filled): everything before
    /// `reason` was recovered.
    Truncated { reason: String },
}

/// A recording read into memory.
#[derive(Debug, Clone)]
pub struct Recording {
    pub path: PathBuf,
    /// Size of the file in bytes.
    pub file_len: u64,
    pub build: BuildRecord,
    pub scene: SceneRecord,
    /// Every `/device` record, in tick order.
    pub device: Vec<DeviceRecord>,
    /// Every `/contact` frame, in order.
    pub contacts: Vec<RecordedMessage>,
    /// Every `/loop_stats` message, in order.
    pub loop_stats: Vec<RecordedMessage>,
    /// The last `/stats` record (the final one in a complete file).
    pub last_stats: Option<RecordingStats>,
    /// Messages on topics this build does not know (a newer writer's additions), skipped.
    pub unknown_messages: u64,
    pub ending: Ending,
    /// The damaged stretches of the file that were skipped, in file order.
    pub lost: Vec<LostSpan>,
    /// The instructors' marks, in the order made.
    pub marks: Vec<softhaptic_proto::wire::MarkMessage>,
    /// The trainee's `metrics` messages as recorded: the 1 Hz ones viewers were sent, then the
    /// final one over the whole session (absent from a recording cut short, and from recordings
    /// made before the metrics were kept).
    pub metrics: Vec<softhaptic_proto::wire::MetricsMessage>,
    /// A station's `exercise` messages, as recorded when each attempt started and ended.
    pub exercises: Vec<softhaptic_proto::wire::ExerciseMessage>,
    /// The session's alerts, each as it last stood (raised, or acknowledged), in the order
    /// raised; empty for recordings made before alerts existed.
    pub alerts: Vec<softhaptic_proto::wire::Alert>,
}

/// A stretch of a recording that could not be read and was skipped.
#[derive(Debug, Clone, PartialEq)]
pub struct LostSpan {
    /// Where it starts in the file, and how long it is, bytes.
    pub first_byte: u64,
    pub bytes: u64,
    /// The device time it covers: from the last message of the chunk kept before it (or the
    /// first its own chunk header claims, when that lies later) to the first message of the
    /// chunk kept after it (or the last its own header claims, when none is), where known.
    pub time_ns: Option<(u64, u64)>,
    pub reason: String,
}

impl fmt::Display for LostSpan {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.time_ns {
            // One instant (between kept chunks that meet, or a chunk of one instant's records,
            // such as the build and scene): its bytes say more than its time.
            Some((a, b)) if a == b => write!(
                f,
                "{} bytes at byte {} around device time {:.3} s ({})",
                self.bytes,
                self.first_byte,
                a as f64 * 1e-9,
                self.reason
            ),
            Some((a, b)) => write!(
                f,
                "device time {:.3} s to {:.3} s ({})",
                a as f64 * 1e-9,
                b as f64 * 1e-9,
                self.reason
            ),
            None => write!(
                f,
                "{} bytes at byte {} ({})",
                self.bytes, self.first_byte, self.reason
            ),
        }
    }
}

impl Recording {
    /// Reads `path`. Refuses files it cannot trust; recovers what it can from truncated ones.
    /// The file is read as a stream, a record at a time: what stays in memory is what was
    /// decoded, never the file.
    pub fn open(path: &Path) -> Result<Recording, SessionError> {
        let io = |e: crate::files::ReadError| SessionError::Io {
            path: path.to_path_buf(),
            reason: e.into(),
        };
        let (file, len) =
            crate::files::open(path, crate::files::FileKind::Recording).map_err(io)?;
        Self::from_source(path, &FileSource { file, len })
    }

    /// Reads a recording held in memory; `path` names it in messages.
    pub fn from_bytes(path: &Path, bytes: &[u8]) -> Result<Recording, SessionError> {
        Self::from_source(path, bytes)
    }

    /// The session's final metrics as the live loop computed them over every tick, when the
    /// recording holds them (it closed normally, and was made by a build that keeps them).
    pub fn final_metrics(&self) -> Option<&softhaptic_proto::wire::MetricsMessage> {
        self.metrics.iter().rev().find(|m| m.is_final)
    }

    /// The results of the attempts at exercises the session ran, in the order they ended.
    pub fn attempts(&self) -> impl Iterator<Item = &softhaptic_proto::exercise::AttemptResult> {
        self.exercises.iter().filter_map(|m| m.result.as_ref())
    }

    /// The text of the exercise file an attempt at `exercise` (its name) started with.
    pub fn exercise_toml(&self, exercise: &str) -> Option<(&str, &str)> {
        self.exercises
            .iter()
            .filter(|m| m.exercise.name == exercise)
            .find_map(|m| Some((m.exercise_file.as_deref()?, m.exercise_toml.as_deref()?)))
    }

    /// File name without directories, for messages and the replay status.
    pub fn file_name(&self) -> String {
        self.path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| self.path.display().to_string())
    }

    /// Device time of the first and last recorded tick.
    pub fn time_span_ns(&self) -> Option<(u64, u64)> {
        let first = self.device.first()?.time_ns;
        let last = self.device.last()?.time_ns;
        Some((first, last))
    }

    /// Length of the recording in device time (first to last tick, or contact frame when it has
    /// no ticks).
    pub fn duration_ns(&self) -> u64 {
        let ticks = self.time_span_ns().map(|(a, b)| b - a);
        let contacts = match (self.contacts.first(), self.contacts.last()) {
            (Some(a), Some(b)) => Some(b.time_ns.saturating_sub(a.time_ns)),
            _ => None,
        };
        ticks.or(contacts).unwrap_or(0)
    }

    /// Ticks missing from the device channel: gaps in the tick counter (the ring was full).
    pub fn missing_ticks(&self) -> u64 {
        self.device
            .windows(2)
            .map(|w| w[1].tick.saturating_sub(w[0].tick + 1))
            .sum()
    }

    /// About how much memory the recording holds, bytes: its vectors and the texts they keep
    /// (a lab hub's cache of replays is bounded by this).
    pub fn memory_bytes(&self) -> u64 {
        use std::mem::size_of;
        let texts = |v: &[RecordedMessage]| -> usize {
            v.iter().map(|m| m.json.capacity()).sum::<usize>() + std::mem::size_of_val(v)
        };
        let meshes = self.scene.meshes.as_ref().map_or(0, |m| {
            [Some(&m.haptic), m.render.as_ref()]
                .into_iter()
                .flatten()
                .map(|mesh| {
                    mesh.positions_m.len() * size_of::<[f64; 3]>()
                        + mesh.triangles.len() * size_of::<[u32; 3]>()
                })
                .sum::<usize>()
        });
        let bytes = size_of::<Recording>()
            + self.device.capacity() * size_of::<DeviceRecord>()
            + texts(&self.contacts)
            + texts(&self.loop_stats)
            + self.marks.len() * (size_of::<softhaptic_proto::wire::MarkMessage>() + 1024)
            + self.metrics.len() * size_of::<softhaptic_proto::wire::MetricsMessage>()
            + self
                .exercises
                .iter()
                .map(|m| {
                    let path = match &m.exercise.task {
                        softhaptic_proto::exercise::Task::Trace(t) => t.path_m.len() * 24,
                        // A follow's expert path is not in the message (#[serde(skip)]).
                        softhaptic_proto::exercise::Task::Press(_)
                        | softhaptic_proto::exercise::Task::Palpation(_)
                        | softhaptic_proto::exercise::Task::Follow(_) => 0,
                    };
                    size_of::<softhaptic_proto::wire::ExerciseMessage>()
                        + m.exercise_toml.as_ref().map_or(0, String::len)
                        + m.exercise.instructions.len()
                        + path
                        + 1024
                })
                .sum::<usize>()
            + self.scene.scene_toml.len()
            + meshes;
        bytes as u64
    }

    /// Whether the file was closed by its writer and nothing in it was damaged.
    pub fn is_complete(&self) -> bool {
        self.ending == Ending::Complete && self.lost.is_empty()
    }

    /// What was recovered and what was lost, in a sentence or two.
    pub fn recovery(&self) -> Recovery<'_> {
        Recovery(self)
    }
}

/// Display of [`Recording::recovery`].
pub struct Recovery<'a>(&'a Recording);

impl fmt::Display for Recovery<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let r = self.0;
        let span = match r.time_span_ns() {
            Some((a, b)) => format!("{:.3} s to {:.3} s", a as f64 * 1e-9, b as f64 * 1e-9),
            None => "no device time".into(),
        };
        let damaged = match r.lost.len() {
            0 => String::new(),
            1 => "1 damaged stretch skipped; ".to_owned(),
            n => format!("{n} damaged stretches skipped; "),
        };
        let lost: Vec<String> = r.lost.iter().map(LostSpan::to_string).collect();
        match &r.ending {
            Ending::Complete if r.lost.is_empty() => write!(
                f,
                "{}: complete; {} ticks ({span}), {} contact frames",
                r.path.display(),
                r.device.len(),
                r.contacts.len()
            ),
            Ending::Complete => write!(
                f,
                "{}: damaged, closed by its writer; {damaged}recovered {} ticks ({span}) and {} \
                 contact frames from {} bytes; lost: {}",
                r.path.display(),
                r.device.len(),
                r.contacts.len(),
                r.file_len,
                lost.join("; ")
            ),
            Ending::Truncated { reason } => {
                let mut lost = lost;
                lost.push(format!(
                    "whatever was recorded after {} (the chunk being written when the file was \
                     cut: up to about a second)",
                    r.time_span_ns()
                        .map(|(_, b)| format!("{:.3} s", b as f64 * 1e-9))
                        .unwrap_or_else(|| "the scene".into()),
                ));
                write!(
                    f,
                    "{}: truncated ({reason}); {damaged}recovered {} ticks ({span}) and {} \
                     contact frames from {} bytes; lost: {}",
                    r.path.display(),
                    r.device.len(),
                    r.contacts.len(),
                    r.file_len,
                    lost.join("; ")
                )?;
                if let Some(s) = r.last_stats {
                    write!(
                        f,
                        " (the last stats record before the cut counted {} ticks, {} dropped)",
                        s.ticks_recorded, s.ticks_dropped
                    )?;
                }
                Ok(())
            }
        }
    }
}
