//! The records the MCAP library parses out of the kept part of a file, turned into a
//! [`Recording`]: each channel classified by topic and schema, each message checked against the
//! wire protocol, and the recording refused when its writer's format or protocol is newer than
//! this build's.

use std::collections::BTreeMap;
use std::path::Path;

use softhaptic_proto::record::{
    self, BuildRecord, DeviceRecord, RecordingStats, SESSION_FORMAT_VERSION, SceneRecord,
    schema_name, topic,
};
use softhaptic_proto::wire::{PROTOCOL_VERSION, ServerMessage};

use super::walk::{Feed, MAX_RECORD_BYTES, Source, scan};
use super::{Ending, RecordedMessage, Recording, SessionError};

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
    Exercise,
    Alerts,
    Unknown,
}

/// Most bytes of `exercise` messages a recording's reader keeps: a station writes one when an
/// attempt starts or ends (a few kilobytes, the exercise file with the first), so a day of
/// exercises is far below it; a file made to hold many large ones costs no more than this.
const MAX_EXERCISE_BYTES: usize = 64 << 20;

impl Kind {
    /// The largest message of this kind read, bytes: a few times the largest this build writes
    /// (a tick's record is about 300 bytes, a contact frame about 600, a stats or metrics
    /// message a few hundred); the scene, which holds the object's meshes, as large as a chunk.
    /// A larger one is refused before it is parsed or kept: a frame padded with whitespace is
    /// valid JSON, and a few thousand of them would fill the memory of whoever reads the file.
    const fn max_message_bytes(self) -> u64 {
        match self {
            Kind::Scene => super::walk::MAX_CHUNK_UNCOMPRESSED_BYTES,
            Kind::Build | Kind::Contact | Kind::LoopStats | Kind::Metrics => 64 << 10,
            Kind::Device | Kind::Stats => 4 << 10,
            Kind::Marks | Kind::Alerts => 8 << 10,
            // A traced path of up to a thousand points, and the exercise file on an attempt's
            // first message.
            Kind::Exercise => 1 << 20,
            // Not parsed and not kept: bounded by its chunk.
            Kind::Unknown => u64::MAX,
        }
    }
}

impl Recording {
    pub(super) fn from_source<S: Source + ?Sized>(
        path: &Path,
        src: &S,
    ) -> Result<Recording, SessionError> {
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
        let mut exercises = Vec::new();
        let mut exercise_bytes = 0usize;
        let mut alerts: Vec<softhaptic_proto::wire::Alert> = Vec::new();
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
            let limit = kind.max_message_bytes();
            if message.data.len() as u64 > limit {
                return Err(SessionError::MessageTooLarge {
                    path: path_buf,
                    topic: channel.topic.clone(),
                    sequence: message.sequence,
                    log_time_ns: message.log_time,
                    bytes: message.data.len() as u64,
                    limit,
                });
            }
            // This message refused, for `reason`, naming the file, channel and place.
            let refuse = |reason: String| SessionError::BadMessage {
                path: path_buf.clone(),
                topic: channel.topic.clone(),
                sequence: message.sequence,
                log_time_ns: message.log_time,
                reason,
            };
            let bad = |e: serde_json::Error| refuse(e.to_string());
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
                        .map_err(|e| refuse(e.to_string()))?
                        .to_owned();
                    // The frame must be a contact message of the wire protocol.
                    match ServerMessage::decode(&json) {
                        Ok(ServerMessage::Contact(_)) => {}
                        Ok(other) => {
                            return Err(refuse(format!(
                                "a {} message on the contact channel",
                                other.type_name()
                            )));
                        }
                        Err(e) => {
                            return Err(refuse(e.to_string()));
                        }
                    }
                    contacts.push(RecordedMessage {
                        time_ns: message.log_time,
                        json: compact_json(json),
                    });
                }
                Kind::LoopStats => {
                    let json = String::from_utf8_lossy(&message.data).into_owned();
                    match ServerMessage::decode(&json) {
                        Ok(ServerMessage::Stats(_)) => loop_stats.push(RecordedMessage {
                            time_ns: message.log_time,
                            json: compact_json(json),
                        }),
                        _ => {
                            return Err(refuse("not a stats message of the wire protocol".into()));
                        }
                    }
                }
                Kind::Stats => {
                    last_stats = Some(serde_json::from_slice(&message.data).map_err(bad)?);
                }
                Kind::Alerts => {
                    let alert: softhaptic_proto::wire::Alert =
                        serde_json::from_slice(&message.data).map_err(bad)?;
                    // An acknowledgement is the alert written again: it replaces the raised one.
                    match alerts.iter().position(|a| a.id == alert.id) {
                        Some(i) => alerts[i] = alert,
                        // A session keeps at most 1000 (the station's bound).
                        None if alerts.len() < 1000 => alerts.push(alert),
                        None => {}
                    }
                }
                Kind::Marks => {
                    let json = String::from_utf8_lossy(&message.data);
                    match ServerMessage::decode(&json) {
                        Ok(ServerMessage::Mark(m)) => marks.push(m),
                        _ => {
                            return Err(refuse("not a mark message of the wire protocol".into()));
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
                Kind::Exercise if exercise_bytes + message.data.len() > MAX_EXERCISE_BYTES => {
                    unknown_messages += 1;
                }
                Kind::Exercise => {
                    exercise_bytes += message.data.len();
                    let json = String::from_utf8_lossy(&message.data);
                    match ServerMessage::decode(&json) {
                        Ok(ServerMessage::Exercise(m)) => exercises.push(*m),
                        _ => {
                            return Err(refuse(
                                "not an exercise message of the wire protocol".into(),
                            ));
                        }
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
        if (build.is_none() || scene.is_none())
            && let Some(first) = scanned.lost.first()
        {
            return Err(damaged_before_start(
                path,
                first,
                scanned.definitions_from_summary,
                &device,
            ));
        }
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
        // Kept for as long as the recording is replayed or checked: no spare capacity.
        device.shrink_to_fit();
        contacts.shrink_to_fit();
        loop_stats.shrink_to_fit();
        marks.shrink_to_fit();
        metrics.shrink_to_fit();
        exercises.shrink_to_fit();
        alerts.sort_by_key(|a| a.id);
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
            exercises,
            alerts,
        })
    }
}

/// `json` (valid JSON) without the whitespace between its tokens, and without spare capacity: a
/// frame is kept as the text viewers are sent, and the text a recording holds may have been
/// padded. Strings are kept as they are, escapes and all.
fn compact_json(json: String) -> String {
    let mut in_string = false;
    let mut escaped = false;
    let padded = json.bytes().any(|b| {
        let space = !in_string && matches!(b, b' ' | b'\t' | b'\n' | b'\r');
        if in_string {
            match (escaped, b) {
                (true, _) => escaped = false,
                (false, b'\\') => escaped = true,
                (false, b'"') => in_string = false,
                _ => {}
            }
        } else if b == b'"' {
            in_string = true;
        }
        space
    });
    if !padded {
        let mut json = json;
        json.shrink_to_fit();
        return json;
    }
    let mut out = String::with_capacity(json.len());
    let (mut in_string, mut escaped) = (false, false);
    for c in json.chars() {
        if in_string {
            out.push(c);
            match (escaped, c) {
                (true, _) => escaped = false,
                (false, '\\') => escaped = true,
                (false, '"') => in_string = false,
                _ => {}
            }
        } else if !matches!(c, ' ' | '\t' | '\n' | '\r') {
            in_string = c == '"';
            out.push(c);
        }
    }
    out.shrink_to_fit();
    out
}

/// The refusal of a recording whose build and scene records were in a damaged part of the file
/// (`first`, the first part skipped): the writer keeps them in the first chunk and in a copy
/// right after it (recordings made before the copy have none), and a recording cannot be
/// replayed, checked or even described without them, however much of the rest is intact
/// (`device`: the ticks read from it).
fn damaged_before_start(
    path: &Path,
    first: &super::LostSpan,
    definitions_from_summary: bool,
    device: &[DeviceRecord],
) -> SessionError {
    let intact = match (
        device.iter().map(|d| d.time_ns).min(),
        device.iter().map(|d| d.time_ns).max(),
    ) {
        (Some(a), Some(b)) => format!(
            "; the {} ticks after it ({:.3} s to {:.3} s{}) are intact, but cannot be used without \
             the build and scene records, which were in the first chunk and its copy (or it has \
             none)",
            device.len(),
            a as f64 * 1e-9,
            b as f64 * 1e-9,
            if definitions_from_summary {
                ", read with the channels of the file's summary"
            } else {
                ""
            }
        ),
        _ => String::new(),
    };
    SessionError::Io {
        path: path.to_path_buf(),
        reason: std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "the part of the file holding its build and scene records is damaged: lost {first}\
                 {intact}: nothing to recover"
            ),
        ),
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
        topic::EXERCISE => (Kind::Exercise, schema_name::EXERCISE),
        topic::ALERTS => (Kind::Alerts, schema_name::ALERTS),
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
