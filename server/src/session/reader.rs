//! Reading a recorded session back, whole or as much of it as survived.
//!
//! [`Recording::open`] reads the file's messages in order and stops at the first damaged record:
//! a file cut short by a crash (the writer writes one chunk per second of device time, whole)
//! yields every complete chunk before the cut, and [`Recording::recovery`] says what was
//! recovered and what was lost. Files that are not recordings, or not ones this build can read
//! (wrong magic, a channel with another schema, a newer format or protocol version, a message
//! that does not parse) are refused with a [`SessionError`] naming the file and the cause.

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

use softhaptic_proto::record::{
    self, BuildRecord, DeviceRecord, RecordingStats, SESSION_FORMAT_VERSION, SceneRecord,
    schema_name, topic,
};
use softhaptic_proto::wire::{PROTOCOL_VERSION, ServerMessage};

use super::SessionError;

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
}

/// Which record kind a channel id carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Build,
    Scene,
    Device,
    Contact,
    Stats,
    LoopStats,
    Unknown,
}

impl Recording {
    /// Reads `path`. Refuses files it cannot trust; recovers what it can from truncated ones.
    pub fn open(path: &Path) -> Result<Recording, SessionError> {
        let bytes = std::fs::read(path).map_err(|source| SessionError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_bytes(path, &bytes)
    }

    /// Reads a recording held in memory; `path` names it in messages.
    pub fn from_bytes(path: &Path, bytes: &[u8]) -> Result<Recording, SessionError> {
        let path_buf = path.to_path_buf();
        if bytes.len() < mcap::MAGIC.len() || &bytes[..mcap::MAGIC.len()] != mcap::MAGIC {
            let found = bytes[..bytes.len().min(8)]
                .iter()
                .map(|b| format!("{b:02x}"))
                .collect::<Vec<_>>()
                .join(" ");
            return Err(SessionError::NotMcap {
                path: path_buf,
                found: if found.is_empty() {
                    "none (empty file)".into()
                } else {
                    found
                },
            });
        }
        // Damage that would make the MCAP library allocate what a length field claims is cut
        // off first; the stream then ends there like a truncated file.
        let (bytes, damage) = cut_at_damaged_chunk(bytes);
        let options = mcap::read::Options::ValidateChunkCrcs.into();
        let stream = match mcap::MessageStream::new_with_options(bytes, options) {
            Ok(s) => s,
            Err(e) => {
                return Err(SessionError::Mcap {
                    path: path_buf,
                    source: e,
                });
            }
        };

        let mut kinds: BTreeMap<u16, Kind> = BTreeMap::new();
        let mut build: Option<BuildRecord> = None;
        let mut scene: Option<SceneRecord> = None;
        let mut device = Vec::new();
        let mut contacts = Vec::new();
        let mut loop_stats = Vec::new();
        let mut last_stats = None;
        let mut unknown_messages = 0;
        let mut ending = Ending::Complete;
        let file_len = bytes.len() as u64 + damage.as_ref().map_or(0, |(cut, _)| *cut);

        for item in stream {
            let message = match item {
                Ok(m) => m,
                Err(e) => {
                    let reason = match &damage {
                        Some((_, why)) => why.clone(),
                        None => e.to_string(),
                    };
                    ending = Ending::Truncated { reason };
                    break;
                }
            };
            let channel = &message.channel;
            let kind = match kinds.get(&channel.id) {
                Some(k) => *k,
                None => {
                    let k = classify(path, channel)?;
                    kinds.insert(channel.id, k);
                    k
                }
            };
            let bad = |e: serde_json::Error| SessionError::BadMessage {
                path: path_buf.clone(),
                topic: channel.topic.clone(),
                sequence: message.sequence,
                log_time_ns: message.log_time,
                reason: e.to_string(),
            };
            match kind {
                Kind::Build => {
                    let b: BuildRecord = serde_json::from_slice(&message.data).map_err(bad)?;
                    check_versions(path, &b)?;
                    build = Some(b);
                }
                Kind::Scene => {
                    if build.is_none() {
                        return Err(SessionError::MissingBuild { path: path_buf });
                    }
                    scene = Some(serde_json::from_slice(&message.data).map_err(bad)?);
                }
                Kind::Device => {
                    device.push(serde_json::from_slice::<DeviceRecord>(&message.data).map_err(bad)?)
                }
                Kind::Contact => {
                    let json = std::str::from_utf8(&message.data)
                        .map_err(|e| SessionError::BadMessage {
                            path: path_buf.clone(),
                            topic: channel.topic.clone(),
                            sequence: message.sequence,
                            log_time_ns: message.log_time,
                            reason: e.to_string(),
                        })?
                        .to_owned();
                    // The frame must be a contact message of the wire protocol.
                    match ServerMessage::decode(&json) {
                        Ok(ServerMessage::Contact(_)) => {}
                        Ok(other) => {
                            return Err(SessionError::BadMessage {
                                path: path_buf.clone(),
                                topic: channel.topic.clone(),
                                sequence: message.sequence,
                                log_time_ns: message.log_time,
                                reason: format!(
                                    "a {} message on the contact channel",
                                    other.type_name()
                                ),
                            });
                        }
                        Err(e) => {
                            return Err(SessionError::BadMessage {
                                path: path_buf.clone(),
                                topic: channel.topic.clone(),
                                sequence: message.sequence,
                                log_time_ns: message.log_time,
                                reason: e.to_string(),
                            });
                        }
                    }
                    contacts.push(RecordedMessage {
                        time_ns: message.log_time,
                        json,
                    });
                }
                Kind::LoopStats => {
                    let json = String::from_utf8_lossy(&message.data).into_owned();
                    match ServerMessage::decode(&json) {
                        Ok(ServerMessage::Stats(_)) => loop_stats.push(RecordedMessage {
                            time_ns: message.log_time,
                            json,
                        }),
                        _ => {
                            return Err(SessionError::BadMessage {
                                path: path_buf.clone(),
                                topic: channel.topic.clone(),
                                sequence: message.sequence,
                                log_time_ns: message.log_time,
                                reason: "not a stats message of the wire protocol".into(),
                            });
                        }
                    }
                }
                Kind::Stats => {
                    last_stats = Some(serde_json::from_slice(&message.data).map_err(bad)?);
                }
                Kind::Unknown => unknown_messages += 1,
            }
        }

        let cut_short = |reason: &str| SessionError::TruncatedBeforeStart {
            path: path_buf.clone(),
            file_len,
            reason: reason.to_owned(),
        };
        let Some(build) = build else {
            return Err(match &ending {
                Ending::Truncated { reason } => cut_short(reason),
                Ending::Complete => SessionError::MissingBuild { path: path_buf },
            });
        };
        let Some(scene) = scene else {
            return Err(match &ending {
                Ending::Truncated { reason } => cut_short(reason),
                Ending::Complete => SessionError::MissingScene { path: path_buf },
            });
        };
        if ending == Ending::Complete && !last_stats.is_some_and(|s: RecordingStats| s.is_final) {
            ending = Ending::Truncated {
                reason: "the file ends without the recorder's final stats record".into(),
            };
        }
        device.sort_by_key(|r: &DeviceRecord| r.tick);
        Ok(Recording {
            path: path_buf,
            file_len,
            build,
            scene,
            device,
            contacts,
            loop_stats,
            last_stats,
            unknown_messages,
            ending,
        })
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

    /// Whether the file was closed by its writer.
    pub fn is_complete(&self) -> bool {
        self.ending == Ending::Complete
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
        match &r.ending {
            Ending::Complete => write!(
                f,
                "{}: complete; {} ticks ({span}), {} contact frames",
                r.path.display(),
                r.device.len(),
                r.contacts.len()
            ),
            Ending::Truncated { reason } => {
                write!(
                    f,
                    "{}: truncated ({reason}); recovered {} ticks ({span}) and {} contact frames \
                     from {} bytes; lost: whatever was recorded after {} (the chunk being written \
                     when the file was cut: up to about a second)",
                    r.path.display(),
                    r.device.len(),
                    r.contacts.len(),
                    r.file_len,
                    r.time_span_ns()
                        .map(|(_, b)| format!("{:.3} s", b as f64 * 1e-9))
                        .unwrap_or_else(|| "the scene".into()),
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

/// Which record a channel carries; refuses known topics with another schema or encoding.
fn classify(path: &Path, channel: &mcap::Channel<'_>) -> Result<Kind, SessionError> {
    let (kind, expected) = match channel.topic.as_str() {
        topic::BUILD => (Kind::Build, schema_name::BUILD),
        topic::SCENE => (Kind::Scene, schema_name::SCENE),
        topic::DEVICE => (Kind::Device, schema_name::DEVICE),
        topic::CONTACT => (Kind::Contact, schema_name::CONTACT),
        topic::STATS => (Kind::Stats, schema_name::STATS),
        topic::LOOP_STATS => (Kind::LoopStats, schema_name::LOOP_STATS),
        _ => return Ok(Kind::Unknown),
    };
    let found_schema = channel
        .schema
        .as_ref()
        .map(|s| format!("{} ({})", s.name, s.encoding))
        .unwrap_or_else(|| "no schema".into());
    let schema_ok = channel
        .schema
        .as_ref()
        .is_some_and(|s| s.name == expected && s.encoding == record::SCHEMA_ENCODING);
    if !schema_ok || channel.message_encoding != record::MESSAGE_ENCODING {
        return Err(SessionError::WrongSchema {
            path: path.to_path_buf(),
            topic: channel.topic.clone(),
            expected: format!(
                "{expected} ({}), messages {}",
                record::SCHEMA_ENCODING,
                record::MESSAGE_ENCODING
            ),
            found: format!("{found_schema}, messages {}", channel.message_encoding),
        });
    }
    Ok(kind)
}

fn check_versions(path: &Path, b: &BuildRecord) -> Result<(), SessionError> {
    if b.session_format_version > SESSION_FORMAT_VERSION {
        return Err(SessionError::NewerVersion {
            path: path.to_path_buf(),
            field: "session_format_version",
            found: b.session_format_version,
            supported: SESSION_FORMAT_VERSION,
            writer: b.writer.clone(),
        });
    }
    if b.protocol_version > PROTOCOL_VERSION {
        return Err(SessionError::NewerVersion {
            path: path.to_path_buf(),
            field: "protocol_version",
            found: b.protocol_version,
            supported: PROTOCOL_VERSION,
            writer: b.writer.clone(),
        });
    }
    Ok(())
}

/// Largest uncompressed chunk accepted. The writer closes chunks at about 1 MiB; anything far
/// beyond is a damaged length field, which the MCAP library would try to allocate.
const MAX_CHUNK_UNCOMPRESSED_BYTES: u64 = 64 << 20;

/// MCAP opcode of a chunk record.
const OP_CHUNK: u8 = 0x06;

/// Little-endian reads that fail instead of panicking on short input.
fn read_u32(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(
        b.get(at..at.checked_add(4)?)?.try_into().ok()?,
    ))
}

fn read_u64(b: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(
        b.get(at..at.checked_add(8)?)?.try_into().ok()?,
    ))
}

/// The records of `b` (opcode, u64 length, body) all fit exactly.
fn records_fit(b: &[u8]) -> bool {
    let mut pos = 0;
    while pos < b.len() {
        let Some(len) = read_u64(b, pos + 1) else {
            return false;
        };
        match usize::try_from(len)
            .ok()
            .and_then(|l| (pos + 9).checked_add(l))
        {
            Some(end) if end <= b.len() => pos = end,
            _ => return false,
        }
    }
    true
}

/// Why a chunk record's body cannot be trusted, if it cannot: a size beyond reason, a compression
/// this build does not write, data that does not decompress to its declared size and checksum,
/// or inner records whose lengths overrun the chunk.
fn chunk_damage(body: &[u8]) -> Option<String> {
    let fields = || {
        let uncompressed_size = read_u64(body, 16)?;
        let crc = read_u32(body, 24)?;
        let name_len = read_u32(body, 28)? as usize;
        let name_end = 32usize.checked_add(name_len)?;
        let compression = body.get(32..name_end)?;
        let records_len = usize::try_from(read_u64(body, name_end)?).ok()?;
        let records_start = name_end + 8;
        let records = body.get(records_start..records_start.checked_add(records_len)?)?;
        Some((uncompressed_size, crc, compression, records))
    };
    let Some((uncompressed_size, crc, compression, records)) = fields() else {
        return Some("its fields overrun it".into());
    };
    if uncompressed_size > MAX_CHUNK_UNCOMPRESSED_BYTES {
        return Some(format!("it claims {uncompressed_size} bytes uncompressed"));
    }
    let data = match compression {
        b"" => records.to_vec(),
        b"zstd" => match zstd::bulk::decompress(records, uncompressed_size as usize) {
            Ok(d) => d,
            Err(e) => return Some(format!("it does not decompress: {e}")),
        },
        other => {
            return Some(format!(
                "its compression {:?} is not one this build reads",
                String::from_utf8_lossy(other)
            ));
        }
    };
    if data.len() as u64 != uncompressed_size {
        return Some(format!(
            "it decompresses to {} bytes instead of {uncompressed_size}",
            data.len()
        ));
    }
    if crc != 0 && crc32fast::hash(&data) != crc {
        return Some("its checksum does not match".into());
    }
    if !records_fit(&data) {
        return Some("its records overrun it".into());
    }
    None
}

/// Walks the file's top-level records and returns the bytes up to the first damaged chunk (see
/// [`chunk_damage`]), with `(bytes cut, reason)`. A record whose header or body runs past the end
/// is left to the MCAP reader, which reports the truncation.
fn cut_at_damaged_chunk(bytes: &[u8]) -> (&[u8], Option<(u64, String)>) {
    let mut pos = mcap::MAGIC.len();
    while let (Some(&op), Some(len)) = (bytes.get(pos), read_u64(bytes, pos + 1)) {
        let body_start = pos + 9;
        let Some(body_end) = usize::try_from(len)
            .ok()
            .and_then(|l| body_start.checked_add(l))
            .filter(|end| *end <= bytes.len())
        else {
            break;
        };
        if op == OP_CHUNK {
            let body = &bytes[body_start..body_end];
            if let Some(why) = chunk_damage(body) {
                let reason = format!("the chunk at byte {pos} is damaged: {why}");
                return (&bytes[..pos], Some(((bytes.len() - pos) as u64, reason)));
            }
        }
        pos = body_end;
    }
    (bytes, None)
}
