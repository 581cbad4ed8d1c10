//! Reading a recorded session back, whole or as much of it as survived.
//!
//! [`Recording::open`] first walks the file's records itself: every chunk is checked (its sizes,
//! its decompression, its checksum, the lengths of the records inside) before the MCAP library
//! parses it, and a damaged chunk is skipped, not trusted: the walk resumes at the next chunk
//! that checks out, so one bad sector loses about a second of a session (the writer closes one
//! chunk per second of device time), never the rest of it. The index and summary after the data
//! are not needed and not read, so damage there hides nothing. A file cut short by a crash
//! yields every complete chunk before the cut. [`Recording::recovery`] says what was recovered
//! and what was lost, as device-time ranges. Files that are not recordings, or not ones this build can read
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
    /// The damaged stretches of the file that were skipped, in file order.
    pub lost: Vec<LostSpan>,
    /// The instructors' marks, in the order made.
    pub marks: Vec<softhaptic_proto::wire::MarkMessage>,
    /// The trainee's `metrics` messages as recorded: the 1 Hz ones viewers were sent, then the
    /// final one over the whole session (absent from a recording cut short, and from recordings
    /// made before the metrics were kept).
    pub metrics: Vec<softhaptic_proto::wire::MetricsMessage>,
}

/// A stretch of a recording that could not be read and was skipped.
#[derive(Debug, Clone, PartialEq)]
pub struct LostSpan {
    /// Where it starts in the file, and how long it is, bytes.
    pub first_byte: u64,
    pub bytes: u64,
    /// The device times its chunk said it held (first and last message), when it said so.
    pub time_ns: Option<(u64, u64)>,
    pub reason: String,
}

impl fmt::Display for LostSpan {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.time_ns {
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

/// Which record kind a channel id carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Build,
    Scene,
    Device,
    Contact,
    Stats,
    LoopStats,
    Marks,
    Metrics,
    Unknown,
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

    fn from_source<S: Source + ?Sized>(path: &Path, src: &S) -> Result<Recording, SessionError> {
        let path_buf = path.to_path_buf();
        let io = |e: std::io::Error| SessionError::Io {
            path: path.to_path_buf(),
            reason: e,
        };
        let mut start = [0u8; 8];
        let head = (src.len() as usize).min(start.len());
        src.read_at(0, &mut start[..head]).map_err(io)?;
        let bytes = &start[..head];
        if bytes.len() < mcap::MAGIC.len() || bytes[..mcap::MAGIC.len()] != mcap::MAGIC[..] {
            let found = bytes
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
        // Damaged chunks are skipped before the MCAP library sees them (it would trust a damaged
        // length and allocate what it claims); the library reads the rest, checking every
        // chunk's checksum again.
        let scanned = scan(src).map_err(io)?;
        let options = mcap::sans_io::LinearReaderOptions::default()
            .with_validate_chunk_crcs(true)
            .with_record_length_limit(MAX_RECORD_BYTES as usize);
        let mut reader = mcap::sans_io::MessageReader::new_with_options(options);
        let mut feed = Feed::new(src, &scanned.keep);
        let mut read_error = None;
        let mut next_message = || loop {
            match reader.next_event()? {
                Ok(mcap::sans_io::MessageReadEvent::ReadRequest(n)) => {
                    let buf = reader.insert(n);
                    match feed.fill(buf) {
                        Ok(written) => reader.notify_read(written),
                        Err(e) => {
                            read_error = Some(e);
                            return None;
                        }
                    }
                }
                Ok(mcap::sans_io::MessageReadEvent::Message(m)) => return Some(Ok(m)),
                Err(e) => return Some(Err(e)),
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
        let mut marks = Vec::new();
        let mut metrics = Vec::new();
        let mut ending = match &scanned.tail {
            Some(reason) => Ending::Truncated {
                reason: reason.clone(),
            },
            None => Ending::Complete,
        };
        let file_len = src.len();

        while let Some(item) = next_message() {
            let message = match item {
                Ok(m) => m,
                Err(e) => {
                    // The walk passed only records that check out, so this is damage the checks
                    // cannot see; keep what was read before it.
                    ending = Ending::Truncated {
                        reason: e.to_string(),
                    };
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
                Kind::Marks => {
                    let json = String::from_utf8_lossy(&message.data);
                    match ServerMessage::decode(&json) {
                        Ok(ServerMessage::Mark(m)) => marks.push(m),
                        _ => {
                            return Err(SessionError::BadMessage {
                                path: path_buf.clone(),
                                topic: channel.topic.clone(),
                                sequence: message.sequence,
                                log_time_ns: message.log_time,
                                reason: "not a mark message of the wire protocol".into(),
                            });
                        }
                    }
                }
                Kind::Metrics => {
                    let json = String::from_utf8_lossy(&message.data);
                    match ServerMessage::decode(&json) {
                        Ok(ServerMessage::Metrics(m)) => metrics.push(m),
                        // Derived data, computed again from the ticks when needed: one that
                        // does not read costs nothing else of the file.
                        _ => unknown_messages += 1,
                    }
                }
                Kind::Unknown => unknown_messages += 1,
            }
        }

        if let Some(e) = read_error {
            return Err(io(e));
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
            lost: scanned.lost,
            marks,
            metrics,
        })
    }

    /// The session's final metrics as the live loop computed them over every tick, when the
    /// recording holds them (it closed normally, and was made by a build that keeps them).
    pub fn final_metrics(&self) -> Option<&softhaptic_proto::wire::MetricsMessage> {
        self.metrics.iter().rev().find(|m| m.is_final)
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

/// Which record a channel carries; refuses known topics with another schema or encoding.
fn classify(path: &Path, channel: &mcap::Channel<'_>) -> Result<Kind, SessionError> {
    let (kind, expected) = match channel.topic.as_str() {
        topic::BUILD => (Kind::Build, schema_name::BUILD),
        topic::SCENE => (Kind::Scene, schema_name::SCENE),
        topic::DEVICE => (Kind::Device, schema_name::DEVICE),
        topic::CONTACT => (Kind::Contact, schema_name::CONTACT),
        topic::STATS => (Kind::Stats, schema_name::STATS),
        topic::LOOP_STATS => (Kind::LoopStats, schema_name::LOOP_STATS),
        topic::MARKS => (Kind::Marks, schema_name::MARKS),
        topic::METRICS => (Kind::Metrics, schema_name::METRICS),
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

/// MCAP opcodes the walk tells apart.
const OP_HEADER: u8 = 0x01;
const OP_FOOTER: u8 = 0x02;
const OP_SCHEMA: u8 = 0x03;
const OP_CHANNEL: u8 = 0x04;
const OP_MESSAGE: u8 = 0x05;
const OP_MESSAGE_INDEX: u8 = 0x07;
const OP_ATTACHMENT: u8 = 0x09;
const OP_METADATA: u8 = 0x0C;
const OP_DATA_END: u8 = 0x0F;

/// Random access to a recording's bytes: the file itself (read a record at a time, never whole)
/// or bytes already in memory.
pub(crate) trait Source {
    fn len(&self) -> u64;
    /// Fills `buf` from `pos`; the range lies within [`Source::len`].
    fn read_at(&self, pos: u64, buf: &mut [u8]) -> std::io::Result<()>;
}

impl Source for [u8] {
    fn len(&self) -> u64 {
        <[u8]>::len(self) as u64
    }
    fn read_at(&self, pos: u64, buf: &mut [u8]) -> std::io::Result<()> {
        let start = usize::try_from(pos).map_err(std::io::Error::other)?;
        let src = start
            .checked_add(buf.len())
            .and_then(|end| self.get(start..end))
            .ok_or_else(|| std::io::Error::from(std::io::ErrorKind::UnexpectedEof))?;
        buf.copy_from_slice(src);
        Ok(())
    }
}

/// A recording file, of the length it had when it was opened (a live recording read while it
/// is written is read as far as it went then).
struct FileSource {
    file: std::fs::File,
    len: u64,
}

impl Source for FileSource {
    fn len(&self) -> u64 {
        self.len
    }
    fn read_at(&self, pos: u64, buf: &mut [u8]) -> std::io::Result<()> {
        use std::os::unix::fs::FileExt;
        self.file.read_exact_at(buf, pos)
    }
}

/// Largest top-level record read: a chunk the writer closes at about 1 MiB (compressed, less),
/// or the scene record with its meshes. A length beyond it is damage, never allocated.
const MAX_RECORD_BYTES: u64 = 256 << 20;
/// The window the search for a resumption point reads at a time.
const RESUME_WINDOW_BYTES: usize = 64 << 10;

/// What the walk kept of a file: the byte ranges of the records to parse (in file order), the
/// stretches skipped, and why the file ended early, if it did.
struct Scanned {
    keep: Vec<std::ops::Range<u64>>,
    lost: Vec<LostSpan>,
    tail: Option<String>,
}

/// The record at `pos`: its opcode and body range, when its header is there and its body ends
/// within the file.
fn record_at<S: Source + ?Sized>(src: &S, pos: u64) -> std::io::Result<Option<(u8, u64, u64)>> {
    let mut header = [0u8; 9];
    if pos.checked_add(9).is_none_or(|end| end > src.len()) {
        return Ok(None);
    }
    src.read_at(pos, &mut header)?;
    Ok(header_fits(src.len(), pos, &header))
}

/// The record whose 9-byte header (opcode, u64 length) is `header`, at `pos` of a file `len`
/// bytes long: its opcode and body range, when its body ends within the file.
fn header_fits(len: u64, pos: u64, header: &[u8; 9]) -> Option<(u8, u64, u64)> {
    let body_len = read_u64(header, 1)?;
    let body_start = pos + 9;
    let body_end = body_start.checked_add(body_len)?;
    (body_end <= len).then_some((header[0], body_start, body_end))
}

/// Why the chunk whose body is `start..end` cannot be trusted (reading it into `scratch`), if
/// it cannot.
fn chunk_damage_at<S: Source + ?Sized>(
    src: &S,
    start: u64,
    end: u64,
    scratch: &mut Vec<u8>,
) -> std::io::Result<Option<String>> {
    let len = end - start;
    if len > MAX_RECORD_BYTES {
        return Ok(Some(format!("it claims {len} bytes")));
    }
    scratch.clear();
    scratch.resize(len as usize, 0);
    src.read_at(start, scratch)?;
    Ok(chunk_damage(scratch))
}

/// The device times the chunk whose body starts at `start` says it holds.
fn chunk_times_at<S: Source + ?Sized>(src: &S, start: u64) -> Option<(u64, u64)> {
    let mut times = [0u8; 16];
    src.read_at(start, &mut times).ok()?;
    Some((read_u64(&times, 0)?, read_u64(&times, 8)?))
}

/// Where reading can resume after damage at `from`: the next chunk that checks out in full, or
/// the data section's end record, whichever comes first. Damage may have hit a length, so the
/// walk cannot step over it; a chunk is only trusted once its checksum matches. Reads the file
/// a window at a time and looks closer only where a byte could start such a record.
fn resume_after<S: Source + ?Sized>(
    src: &S,
    from: u64,
    scratch: &mut Vec<u8>,
) -> std::io::Result<Option<u64>> {
    let len = src.len();
    let mut window = vec![0u8; RESUME_WINDOW_BYTES + 8];
    let mut base = from;
    while base < len {
        // The window overlaps the next by a header's length, so a header across the seam is seen.
        let n = ((len - base) as usize).min(window.len());
        src.read_at(base, &mut window[..n])?;
        let candidates = n.min(RESUME_WINDOW_BYTES);
        for i in 0..candidates {
            let op = window[i];
            if op != OP_CHUNK && op != OP_DATA_END {
                continue;
            }
            let pos = base + i as u64;
            let header: Option<[u8; 9]> = window.get(i..i + 9).and_then(|h| h.try_into().ok());
            let Some(header) = header else {
                continue;
            };
            match header_fits(len, pos, &header) {
                Some((OP_DATA_END, start, end)) if end - start == 4 => return Ok(Some(pos)),
                Some((OP_CHUNK, start, end))
                    if chunk_damage_at(src, start, end, scratch)?.is_none() =>
                {
                    return Ok(Some(pos));
                }
                _ => {}
            }
        }
        base += candidates as u64;
    }
    Ok(None)
}

/// Walks the file's top-level records: keeps the header, the schemas, channels and messages
/// outside chunks, and every chunk that checks out ([`chunk_damage`]); skips a damaged chunk or
/// record and resumes at the next good chunk ([`resume_after`]); stops at the data section's end
/// (the summary and index after it are only for seeking). Holds one record at a time.
fn scan<S: Source + ?Sized>(src: &S) -> std::io::Result<Scanned> {
    let len = src.len();
    let mut keep = Vec::new();
    let mut lost = Vec::new();
    let mut tail = None;
    let mut scratch = Vec::new();
    let mut pos = mcap::MAGIC.len() as u64;
    let skip = |lost: &mut Vec<LostSpan>,
                scratch: &mut Vec<u8>,
                pos: u64,
                time_ns,
                reason: String|
     -> std::io::Result<Option<u64>> {
        let next = resume_after(src, pos + 1, scratch)?;
        let end = next.unwrap_or(len);
        lost.push(LostSpan {
            first_byte: pos,
            bytes: end - pos,
            time_ns,
            reason,
        });
        Ok(next)
    };
    loop {
        if pos >= len {
            tail = Some("the file ends without its data section's end and footer".to_owned());
            break;
        }
        let Some((op, start, end)) = record_at(src, pos)? else {
            // The chunk being written when the file was cut (a crash), or a damaged length:
            // a good chunk further on tells the two apart.
            match resume_after(src, pos + 1, &mut scratch)? {
                Some(next) => {
                    lost.push(LostSpan {
                        first_byte: pos,
                        bytes: next - pos,
                        time_ns: None,
                        reason: format!(
                            "the record at byte {pos} claims a length past the file's end"
                        ),
                    });
                    pos = next;
                    continue;
                }
                None => {
                    tail = Some(format!(
                        "the record at byte {pos} runs past the end of the file"
                    ));
                    break;
                }
            }
        };
        match op {
            OP_CHUNK => match chunk_damage_at(src, start, end, &mut scratch)? {
                None => {
                    keep.push(pos..end);
                    pos = end;
                }
                Some(why) => {
                    let times = chunk_times_at(src, start);
                    let reason = format!("the chunk at byte {pos} is damaged: {why}");
                    match skip(&mut lost, &mut scratch, pos, times, reason)? {
                        Some(next) => pos = next,
                        None => {
                            tail = Some("damage reaches the end of the data".to_owned());
                            break;
                        }
                    }
                }
            },
            OP_HEADER | OP_SCHEMA | OP_CHANNEL | OP_MESSAGE if end - start <= MAX_RECORD_BYTES => {
                keep.push(pos..end);
                pos = end;
            }
            // Needed only for seeking, or not written by this project.
            OP_MESSAGE_INDEX | OP_ATTACHMENT | OP_METADATA => pos = end,
            OP_DATA_END if end - start == 4 => {
                // The writer closes a file with its summary, a footer and the magic; the data is
                // whole either way, but a file without them was not closed.
                let magic_len = mcap::MAGIC.len() as u64;
                let mut end_magic = [0u8; 8];
                let ends_with_magic = len >= end + magic_len
                    && src.read_at(len - magic_len, &mut end_magic).is_ok()
                    && end_magic[..] == mcap::MAGIC[..];
                let footer_at = len.checked_sub(magic_len + 29);
                let closed = ends_with_magic
                    && match footer_at {
                        Some(at) if at >= end => {
                            record_at(src, at)? == Some((OP_FOOTER, at + 9, at + 29))
                        }
                        _ => false,
                    };
                if !closed {
                    tail = Some(
                        "the file's footer is missing or damaged (the data before it is whole)"
                            .to_owned(),
                    );
                }
                break;
            }
            // A record of a kind the data section does not hold (a damaged opcode), or one far
            // larger than any the writer makes (a damaged length).
            other => {
                let reason = format!("a record of kind {other:#04x} at byte {pos} (damaged)");
                match skip(&mut lost, &mut scratch, pos, None, reason)? {
                    Some(next) => pos = next,
                    None => {
                        tail = Some("damage reaches the end of the data".to_owned());
                        break;
                    }
                }
            }
        }
    }
    Ok(Scanned { keep, lost, tail })
}

/// The bytes the MCAP library reads: the magic, the kept records read from the source as it
/// asks for them, and a closing data end (checksum 0: not computed), a footer pointing at no
/// summary and the magic, so that it reads them as a whole file.
struct Feed<'a, S: ?Sized> {
    src: &'a S,
    parts: Vec<FeedPart>,
    part: usize,
    offset: u64,
}

enum FeedPart {
    Bytes(Vec<u8>),
    Range(std::ops::Range<u64>),
}

impl<'a, S: Source + ?Sized> Feed<'a, S> {
    fn new(src: &'a S, keep: &[std::ops::Range<u64>]) -> Self {
        let mut closing = Vec::new();
        let mut record = |op: u8, body: &[u8]| {
            closing.push(op);
            closing.extend_from_slice(&(body.len() as u64).to_le_bytes());
            closing.extend_from_slice(body);
        };
        record(OP_DATA_END, &[0; 4]);
        record(OP_FOOTER, &[0; 20]);
        closing.extend_from_slice(mcap::MAGIC);
        let mut parts = vec![FeedPart::Bytes(mcap::MAGIC.to_vec())];
        parts.extend(keep.iter().cloned().map(FeedPart::Range));
        parts.push(FeedPart::Bytes(closing));
        Self {
            src,
            parts,
            part: 0,
            offset: 0,
        }
    }

    /// Fills as much of `buf` as the next part allows; 0 at the end.
    fn fill(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        while let Some(part) = self.parts.get(self.part) {
            let part_len = match part {
                FeedPart::Bytes(b) => b.len() as u64,
                FeedPart::Range(r) => r.end - r.start,
            };
            if self.offset >= part_len {
                self.part += 1;
                self.offset = 0;
                continue;
            }
            let n = ((part_len - self.offset) as usize).min(buf.len());
            match part {
                FeedPart::Bytes(b) => {
                    let at = self.offset as usize;
                    buf[..n].copy_from_slice(&b[at..at + n]);
                }
                FeedPart::Range(r) => self.src.read_at(r.start + self.offset, &mut buf[..n])?,
            }
            self.offset += n as u64;
            return Ok(n);
        }
        Ok(0)
    }
}
