//! Writing a session to an MCAP file, and the recorder thread that drains the haptic loop's ring.
//!
//! [`SessionWriter`] is the synchronous file writer: one channel per record kind (see
//! `softhaptic_proto::record`), JSON messages, zstd-compressed chunks. Chunks are kept small (one
//! second of device time, [`CHUNK_SPAN_NS`]) and written whole: the writer buffers a chunk in
//! memory and hands it to the file only when it is complete, then flushes the file. A process
//! killed at any moment therefore leaves a file whose every chunk but possibly the last is intact,
//! and [`super::reader`] recovers all of them.
//!
//! [`Recorder`] runs a [`SessionWriter`] on its own thread. The haptic loop pushes one
//! `TickRecord` per tick into a wait-free ring and never waits: when the ring is full the loop's
//! push fails and that tick is lost to the recording. The recorder notices the gap in the tick
//! counter and counts it, so the file says how much is missing. The 50 Hz contact frames reach it
//! through a bounded queue with the same rule (a full queue drops the frame and counts it).
//!
//! # Why one file
//! About 650 lines, kept together because the promise above is one promise across both types:
//! the writer decides where a chunk ends and the recorder decides what reaches the writer, and
//! "a killed process loses at most the last chunk" is checked by reading the two side by side.
//! The rest (the copy of the first chunk, the file name) is used by the writer alone.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError};
use std::thread::JoinHandle;
use std::time::Duration;

use mcap::records::MessageHeader;
use mcap::write::NoSeek;
use softhaptic_device::haptic_loop::TickRecord;
use softhaptic_device::replay::tick_device_record;
use softhaptic_proto::record::{
    self, BuildRecord, DeviceRecord, RecordingStats, SceneRecord, schema,
};

use super::SessionError;

/// Device time covered by one chunk. Small, so that a crash loses at most about this much.
pub const CHUNK_SPAN_NS: u64 = 1_000_000_000;

/// Ticks the loop → recorder ring holds: 4 s at 1 kHz, so the recorder thread may stall that long
/// (a slow disk) before a tick is lost.
pub const TICK_RING_CAPACITY: usize = 4096;

/// Upper bound on one chunk's uncompressed size, whatever its time span.
const CHUNK_SIZE_BYTES: u64 = 1 << 20;

/// How many contact frames may wait for the recorder thread (about 10 s at 50 Hz).
const CONTACT_QUEUE_FRAMES: usize = 512;

/// How long the recorder thread sleeps when the ring is empty. Short compared with the ring's
/// capacity (the loop fills it at one record per millisecond), long enough to cost nothing.
const IDLE_SLEEP: Duration = Duration::from_millis(5);

type McapWriter = mcap::Writer<NoSeek<BufWriter<File>>>;

/// Channel ids of one open recording.
struct Channels {
    build: u16,
    scene: u16,
    device: u16,
    contact: u16,
    stats: u16,
    loop_stats: u16,
    marks: u16,
    metrics: u16,
    exercise: u16,
    alerts: u16,
}

/// Writes one session to one MCAP file. Not thread-safe by itself; see [`Recorder`].
pub struct SessionWriter {
    mcap: McapWriter,
    path: PathBuf,
    channels: Channels,
    /// Reused serialisation buffer, so that a tick costs no allocation once warmed up.
    buf: Vec<u8>,
    /// Per-channel sequence numbers (MCAP's `sequence`), indexed by channel id.
    sequences: [u32; 16],
    stats: RecordingStats,
    /// The tick expected next; a larger tick means the ring dropped the ones between.
    next_tick: Option<u64>,
    /// Device time at which the current chunk began.
    chunk_start_ns: Option<u64>,
    /// Device time of the last record written (log time of stats and of the end).
    last_time_ns: u64,
}

impl SessionWriter {
    /// Creates `path` (refusing to overwrite) and writes the header, the build and scene records.
    pub fn create(
        path: &Path,
        build: &BuildRecord,
        scene: &SceneRecord,
    ) -> Result<Self, SessionError> {
        let io_err = |reason| SessionError::Io {
            path: path.to_path_buf(),
            reason,
        };
        let file = File::options()
            .write(true)
            .create_new(true)
            .open(path)
            .map_err(|e| match e.kind() {
                std::io::ErrorKind::AlreadyExists => SessionError::Exists {
                    path: path.to_path_buf(),
                },
                _ => io_err(e),
            })?;
        let options = mcap::WriteOptions::new()
            .profile(record::MCAP_PROFILE)
            .library(concat!("softhaptic ", env!("CARGO_PKG_VERSION")))
            .compression(Some(mcap::Compression::Zstd))
            .chunk_size(Some(CHUNK_SIZE_BYTES))
            // Buffer each chunk and write it whole (see the module doc).
            .disable_seeking(true)
            // Compress on this thread: the machine's other core belongs to the haptic loop.
            .compression_threads(0);
        let mcap_err = |e: mcap::McapError| SessionError::Mcap {
            path: path.to_path_buf(),
            source: e,
        };
        let mut mcap = options
            .create(NoSeek::new(BufWriter::new(file)))
            .map_err(mcap_err)?;
        let ids = add_channels(&mut mcap).map_err(mcap_err)?;
        let [
            build_id,
            scene_id,
            device_id,
            contact_id,
            stats_id,
            loop_stats_id,
            marks_id,
            metrics_id,
            exercise_id,
            alerts_id,
        ] = ids;
        let mut w = SessionWriter {
            mcap,
            path: path.to_path_buf(),
            channels: Channels {
                build: build_id,
                scene: scene_id,
                device: device_id,
                contact: contact_id,
                stats: stats_id,
                loop_stats: loop_stats_id,
                marks: marks_id,
                metrics: metrics_id,
                exercise: exercise_id,
                alerts: alerts_id,
            },
            buf: Vec::with_capacity(1024),
            sequences: [0; 16],
            stats: RecordingStats::default(),
            next_tick: None,
            chunk_start_ns: None,
            last_time_ns: 0,
        };
        let encode = |e: serde_json::Error| SessionError::Encode {
            path: path.to_path_buf(),
            what: e.to_string(),
        };
        let build_json = serde_json::to_vec(build).map_err(encode)?;
        let scene_json = serde_json::to_vec(scene).map_err(encode)?;
        w.write_raw(w.channels.build, 0, &build_json)?;
        w.write_raw(w.channels.scene, 0, &scene_json)?;
        // The build and scene records go to disk at once: a file cut short keeps them.
        w.flush_chunk()?;
        // And once more, apart from the first chunk: without them nothing after it can be read,
        // so one damaged chunk there would cost the whole recording.
        let copy = start_copy(path, ids, &build_json, &scene_json)?;
        w.mcap
            .attach(&mcap::Attachment {
                log_time: 0,
                create_time: 0,
                name: record::START_COPY_ATTACHMENT.into(),
                media_type: record::START_COPY_MEDIA_TYPE.into(),
                data: std::borrow::Cow::Owned(copy),
            })
            .map_err(mcap_err)?;
        w.flush_chunk()?;
        Ok(w)
    }

    /// The file being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// What has been written and lost so far.
    pub fn stats(&self) -> RecordingStats {
        self.stats
    }

    /// Writes one tick from the haptic loop.
    pub fn write_tick(&mut self, tick: &TickRecord) -> Result<(), SessionError> {
        self.write_device(&tick_device_record(tick))
    }

    /// Writes one device record; counts a gap in the tick counter as dropped ticks.
    pub fn write_device(&mut self, rec: &DeviceRecord) -> Result<(), SessionError> {
        if let Some(expected) = self.next_tick
            && rec.tick > expected
        {
            self.stats.ticks_dropped += rec.tick - expected;
        }
        self.next_tick = Some(rec.tick + 1);
        self.write_json(self.channels.device, rec.time_ns, rec)?;
        self.stats.ticks_recorded += 1;
        self.after_record(rec.time_ns)
    }

    /// Writes one contact frame exactly as it was sent (`json` is the wire text).
    pub fn write_contact(&mut self, time_ns: u64, json: &str) -> Result<(), SessionError> {
        self.write_raw(self.channels.contact, time_ns, json.as_bytes())?;
        self.stats.contact_frames_recorded += 1;
        self.after_record(time_ns)
    }

    /// Writes one `mark` wire message exactly as it was sent, at the latest device time.
    pub fn write_mark(&mut self, json: &str) -> Result<(), SessionError> {
        self.write_raw(self.channels.marks, self.last_time_ns, json.as_bytes())
    }

    /// Writes one `exercise` message (wire text, with the exercise file on an attempt's
    /// first), at the latest device time.
    pub fn write_exercise(&mut self, json: &str) -> Result<(), SessionError> {
        self.write_raw(self.channels.exercise, self.last_time_ns, json.as_bytes())
    }

    /// Writes one alert (`wire::Alert` JSON) as it was raised or acknowledged, at the latest
    /// device time.
    pub fn write_alert(&mut self, json: &str) -> Result<(), SessionError> {
        self.write_raw(self.channels.alerts, self.last_time_ns, json.as_bytes())
    }

    /// Writes one `metrics` wire message exactly as it was sent, at the latest device time.
    pub fn write_metrics(&mut self, json: &str) -> Result<(), SessionError> {
        self.write_raw(self.channels.metrics, self.last_time_ns, json.as_bytes())
    }

    /// Writes one `stats` wire message exactly as it was sent, at the latest device time.
    pub fn write_loop_stats(&mut self, json: &str) -> Result<(), SessionError> {
        self.write_raw(self.channels.loop_stats, self.last_time_ns, json.as_bytes())
    }

    /// Adds contact frames that never reached the writer to the loss count.
    pub fn count_dropped_contacts(&mut self, n: u64) {
        self.stats.contact_frames_dropped += n;
    }

    /// Writes the final stats record, the summary and the footer, and closes the file.
    pub fn finish(mut self) -> Result<RecordingStats, SessionError> {
        self.stats.is_final = true;
        let stats = self.stats;
        self.write_json(self.channels.stats, self.last_time_ns, &stats)?;
        let path = self.path.clone();
        self.mcap.finish().map_err(|source| SessionError::Mcap {
            path: path.clone(),
            source,
        })?;
        self.mcap
            .into_inner()
            .into_inner()
            .flush()
            .map_err(|reason| SessionError::Io { path, reason })?;
        Ok(stats)
    }

    /// Closes the current chunk once it spans [`CHUNK_SPAN_NS`], with a stats record in it.
    fn after_record(&mut self, time_ns: u64) -> Result<(), SessionError> {
        self.last_time_ns = self.last_time_ns.max(time_ns);
        let start = *self.chunk_start_ns.get_or_insert(time_ns);
        if time_ns.saturating_sub(start) >= CHUNK_SPAN_NS {
            self.end_chunk()?;
        }
        Ok(())
    }

    /// Whether records were written since the last chunk was closed.
    pub fn has_open_chunk(&self) -> bool {
        self.chunk_start_ns.is_some()
    }

    /// Writes a stats record and closes the current chunk, so that everything written so far
    /// survives a crash. The recorder also calls it on a wall-clock period, in case the loop's
    /// device time advances slower than real time.
    pub fn end_chunk(&mut self) -> Result<(), SessionError> {
        let stats = self.stats;
        self.write_json(self.channels.stats, self.last_time_ns, &stats)?;
        self.flush_chunk()?;
        self.chunk_start_ns = None;
        Ok(())
    }

    /// Ends the current chunk and pushes it to the operating system.
    pub fn flush_chunk(&mut self) -> Result<(), SessionError> {
        self.mcap.flush().map_err(|source| SessionError::Mcap {
            path: self.path.clone(),
            source,
        })
    }

    fn write_json<T: serde::Serialize>(
        &mut self,
        channel: u16,
        time_ns: u64,
        value: &T,
    ) -> Result<(), SessionError> {
        let mut buf = std::mem::take(&mut self.buf);
        buf.clear();
        let result = serde_json::to_writer(&mut buf, value)
            .map_err(|e| SessionError::Encode {
                path: self.path.clone(),
                what: e.to_string(),
            })
            .and_then(|()| self.write_raw(channel, time_ns, &buf));
        self.buf = buf;
        result
    }

    fn write_raw(&mut self, channel: u16, time_ns: u64, data: &[u8]) -> Result<(), SessionError> {
        // Channel ids are small (MCAP numbers them from 0 or 1 in the order added).
        let slot = &mut self.sequences[usize::from(channel) % 16];
        *slot = slot.wrapping_add(1);
        let header = MessageHeader {
            channel_id: channel,
            sequence: *slot,
            log_time: time_ns,
            publish_time: time_ns,
        };
        self.mcap
            .write_to_known_channel(&header, data)
            .map_err(|source| SessionError::Mcap {
                path: self.path.clone(),
                source,
            })
    }
}

/// Adds every channel of a recording (with its schema) to `mcap`, in the order of
/// [`schema::ALL`], and returns their ids in that order.
fn add_channels<W: Write + std::io::Seek>(
    mcap: &mut mcap::Writer<W>,
) -> Result<[u16; 10], mcap::McapError> {
    let mut ids = [0u16; 10];
    for (slot, (topic, name, schema)) in ids.iter_mut().zip(schema::ALL) {
        let schema_id = mcap.add_schema(name, record::SCHEMA_ENCODING, schema.as_bytes())?;
        *slot = mcap.add_channel(
            schema_id,
            topic,
            record::MESSAGE_ENCODING,
            &Default::default(),
        )?;
    }
    Ok(ids)
}

/// The data of the [`record::START_COPY_ATTACHMENT`] of the recording at `path`: one chunk
/// record holding the schemas and channels (`ids`, as the file numbers them) and the build and
/// scene records, as the first chunk holds them. Written by the MCAP library into a file in
/// memory, whose first chunk it is.
fn start_copy(
    path: &Path,
    ids: [u16; 10],
    build: &[u8],
    scene: &[u8],
) -> Result<Vec<u8>, SessionError> {
    let mcap_err = |source| SessionError::Mcap {
        path: path.to_path_buf(),
        source,
    };
    let unlike = |what: &str| SessionError::Encode {
        path: path.to_path_buf(),
        what: format!("the copy of the first chunk: {what}"),
    };
    let mut mcap = mcap::WriteOptions::new()
        .profile(record::MCAP_PROFILE)
        .compression(Some(mcap::Compression::Zstd))
        .compression_threads(0)
        .create(std::io::Cursor::new(Vec::new()))
        .map_err(mcap_err)?;
    // Both writers number channels in the order added, from the same start.
    if add_channels(&mut mcap).map_err(mcap_err)? != ids {
        return Err(unlike("its channels are numbered differently"));
    }
    let [build_id, scene_id, ..] = ids;
    for (channel_id, data) in [(build_id, build), (scene_id, scene)] {
        let header = MessageHeader {
            channel_id,
            sequence: 1,
            log_time: 0,
            publish_time: 0,
        };
        mcap.write_to_known_channel(&header, data)
            .map_err(mcap_err)?;
    }
    mcap.finish().map_err(mcap_err)?;
    let bytes = mcap.into_inner().into_inner();
    // The records after the magic: the header, then the chunk.
    let record_end = |at: usize| -> Option<usize> {
        let len = u64::from_le_bytes(bytes.get(at + 1..at + 9)?.try_into().ok()?);
        at.checked_add(9)?
            .checked_add(usize::try_from(len).ok()?)
            .filter(|&end| end <= bytes.len())
    };
    let chunk = record_end(mcap::MAGIC.len())
        .and_then(|at| Some(at..record_end(at)?))
        .filter(|r| bytes.get(r.start) == Some(&OP_CHUNK))
        .ok_or_else(|| unlike("no chunk follows the header"))?;
    Ok(bytes[chunk].to_vec())
}

/// MCAP opcode of a chunk record.
const OP_CHUNK: u8 = 0x06;

/// The file name of a new recording: UTC start time, then the session id.
pub fn recording_file_name(started_unix_ns: u64, session_id: &str) -> String {
    let secs = started_unix_ns / 1_000_000_000;
    let (y, mo, d) = civil_from_days((secs / 86_400) as i64);
    let rem = secs % 86_400;
    let safe_id: String = session_id
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    format!(
        "{y:04}{mo:02}{d:02}T{:02}{:02}{:02}Z-{safe_id}.mcap",
        rem / 3600,
        rem / 60 % 60,
        rem % 60
    )
}

/// Days since 1970-01-01 to a proleptic Gregorian date (Howard Hinnant's `civil_from_days`).
fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let y = yoe + era * 400;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (if m <= 2 { y + 1 } else { y }, m, d)
}

/// A message for the recorder's viewer-stream queue: the wire text as sent.
enum StreamMessage {
    /// A contact frame and its device time.
    Contact { time_ns: u64, json: String },
    /// A `stats` message.
    LoopStats { json: String },
    /// A `mark` message.
    Mark { json: String },
    /// A `metrics` message.
    Metrics { json: String },
    /// An alert, raised or acknowledged.
    Alert { json: String },
}

/// The handle the server keeps to hand what it sends viewers to the recorder thread.
#[derive(Clone)]
pub struct StreamTap {
    tx: SyncSender<StreamMessage>,
    dropped: Arc<AtomicU64>,
}

impl StreamTap {
    /// Queues one contact frame for the file; never waits. A full queue drops it (counted).
    pub fn record_contact(&self, time_ns: u64, json: String) {
        self.send(StreamMessage::Contact { time_ns, json }, true);
    }

    /// Counts contact frames lost before they reached the tap.
    pub fn count_lost_contacts(&self, n: u64) {
        self.dropped.fetch_add(n, Ordering::Relaxed);
    }

    /// Queues one `mark` message for the file; never waits (a full queue drops it, counted).
    pub fn record_mark(&self, json: String) {
        self.send(StreamMessage::Mark { json }, true);
    }

    /// Queues one alert for the file; never waits (a full queue drops it, counted).
    pub fn record_alert(&self, json: String) {
        self.send(StreamMessage::Alert { json }, true);
    }

    /// Queues one 1 Hz `metrics` message for the file; never waits (a full queue drops it: the
    /// final one, written by [`Recorder::finish_with_metrics`], covers the whole session).
    pub fn record_metrics(&self, json: String) {
        self.send(StreamMessage::Metrics { json }, false);
    }

    /// Queues one `stats` message for the file; never waits (a full queue drops it).
    pub fn record_loop_stats(&self, json: String) {
        self.send(StreamMessage::LoopStats { json }, false);
    }

    fn send(&self, m: StreamMessage, count: bool) {
        match self.tx.try_send(m) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                if count {
                    self.dropped.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    }
}

/// Shown every tick the recorder writes, in order, on the recorder's thread, with what it
/// returns written on the exercise channel: a station's exercises are scored here, from exactly
/// the ticks its recording holds, off the haptic loop and off the async runtime.
pub trait TickObserver: Send {
    /// One tick, as recorded; the `exercise` records (JSON) to write after it, if any.
    fn tick(&mut self, record: &DeviceRecord) -> Vec<String>;
    /// The session ends after the last tick: what to write last.
    fn finish(&mut self) -> Vec<String>;
}

/// A recording in progress on its own thread.
pub struct Recorder {
    path: PathBuf,
    tap: StreamTap,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<RecordingStats, SessionError>>>,
}

impl Recorder {
    /// Opens `path` and starts the recorder thread draining `ticks`.
    pub fn start(
        path: &Path,
        build: &BuildRecord,
        scene: &SceneRecord,
        ticks: rtrb::Consumer<TickRecord>,
    ) -> Result<Self, SessionError> {
        Self::start_observed(path, build, scene, ticks, None)
    }

    /// [`Recorder::start`], showing every tick to `observer` and recording what it says.
    pub fn start_observed(
        path: &Path,
        build: &BuildRecord,
        scene: &SceneRecord,
        ticks: rtrb::Consumer<TickRecord>,
        observer: Option<Box<dyn TickObserver>>,
    ) -> Result<Self, SessionError> {
        let writer = SessionWriter::create(path, build, scene)?;
        let (tx, rx) = std::sync::mpsc::sync_channel(CONTACT_QUEUE_FRAMES);
        let dropped = Arc::new(AtomicU64::new(0));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = std::thread::Builder::new()
            .name("session-recorder".into())
            .spawn({
                let stop = stop.clone();
                let dropped = dropped.clone();
                move || {
                    let result = run_recorder(writer, ticks, rx, dropped, stop, observer);
                    // Said at once: the session goes on unrecorded (the loop drops its ticks
                    // into a full ring) until the server stops and reports it again.
                    if let Err(e) = &result {
                        tracing::error!("session recording stopped: {e}");
                    }
                    result
                }
            })
            .map_err(|reason| SessionError::Io {
                path: path.to_path_buf(),
                reason,
            })?;
        Ok(Recorder {
            path: path.to_path_buf(),
            tap: StreamTap { tx, dropped },
            stop,
            thread: Some(thread),
        })
    }

    /// The file being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// A handle to queue the contact frames and stats messages sent to viewers.
    pub fn stream_tap(&self) -> StreamTap {
        self.tap.clone()
    }

    /// Drains what is left, writes the final stats and closes the file. Call after the haptic
    /// loop has stopped, so that every tick it produced is in the ring.
    pub fn finish(self) -> Result<RecordingStats, SessionError> {
        self.finish_with_metrics(None)
    }

    /// [`Recorder::finish`], writing the session's final `metrics` message (wire text) after
    /// every tick: the trainee's metrics over the whole session, as the loop computed them.
    pub fn finish_with_metrics(
        mut self,
        final_metrics: Option<String>,
    ) -> Result<RecordingStats, SessionError> {
        if let Some(json) = final_metrics {
            // Waits for room if it must: the thread drains the queue until it sees the stop
            // flag, which is set only after this message is in, so it is always written.
            let _ = self.tap.tx.send(StreamMessage::Metrics { json });
        }
        self.stop.store(true, Ordering::Release);
        match self.thread.take() {
            Some(t) => t.join().map_err(|_| SessionError::RecorderPanicked {
                path: self.path.clone(),
            })?,
            None => Err(SessionError::RecorderPanicked {
                path: self.path.clone(),
            }),
        }
    }
}

impl Drop for Recorder {
    /// A recorder dropped without [`Recorder::finish`] still closes its file properly.
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            match t.join() {
                Ok(Ok(_)) => {}
                Ok(Err(e)) => tracing::error!("recording {}: {e}", self.path.display()),
                Err(_) => tracing::error!("recorder thread of {} panicked", self.path.display()),
            }
        }
    }
}

fn run_recorder(
    mut writer: SessionWriter,
    mut ticks: rtrb::Consumer<TickRecord>,
    contacts: Receiver<StreamMessage>,
    contacts_dropped: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    mut observer: Option<Box<dyn TickObserver>>,
) -> Result<RecordingStats, SessionError> {
    let wall_chunk = Duration::from_nanos(CHUNK_SPAN_NS);
    let mut last_chunk_end = std::time::Instant::now();
    loop {
        // Read the flag before draining, so the last drain after a stop sees everything
        // pushed before it.
        let stopping = stop.load(Ordering::Acquire);
        let mut idle = true;
        while let Ok(tick) = ticks.pop() {
            let record = tick_device_record(&tick);
            writer.write_device(&record)?;
            if let Some(o) = observer.as_mut() {
                for json in o.tick(&record) {
                    writer.write_exercise(&json)?;
                }
            }
            idle = false;
        }
        while let Ok(message) = contacts.try_recv() {
            match message {
                StreamMessage::Contact { time_ns, json } => writer.write_contact(time_ns, &json)?,
                StreamMessage::LoopStats { json } => writer.write_loop_stats(&json)?,
                StreamMessage::Mark { json } => writer.write_mark(&json)?,
                StreamMessage::Metrics { json } => writer.write_metrics(&json)?,
                StreamMessage::Alert { json } => writer.write_alert(&json)?,
            }
            idle = false;
        }
        let lost = contacts_dropped.swap(0, Ordering::Relaxed);
        writer.count_dropped_contacts(lost);
        if stopping {
            if let Some(o) = observer.as_mut() {
                for json in o.finish() {
                    writer.write_exercise(&json)?;
                }
            }
            return writer.finish();
        }
        if !writer.has_open_chunk() {
            last_chunk_end = std::time::Instant::now();
        } else if last_chunk_end.elapsed() >= wall_chunk {
            writer.end_chunk()?;
            last_chunk_end = std::time::Instant::now();
        }
        if idle {
            // The recorder's own thread, not a runtime worker: sleeping holds up no one.
            #[allow(clippy::disallowed_methods)]
            std::thread::sleep(IDLE_SLEEP);
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn file_names_carry_utc_time_and_a_safe_session_id() {
        // 2026-11-23T19:10:28Z
        let ns = 1_795_461_028u64 * 1_000_000_000;
        assert_eq!(
            recording_file_name(ns, "ab/c d"),
            "20261123T191028Z-ab_c_d.mcap"
        );
        assert_eq!(recording_file_name(0, "x"), "19700101T000000Z-x.mcap");
    }
}
