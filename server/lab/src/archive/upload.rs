//! One recording into the object store, part by part, so that an upload cut short resumes where
//! the server says it stopped.
//!
//! One file because the parts, the resume and the read-back are one exchange with the store, whose
//! ordering rule (each part expects its predecessor's sequence) every step relies on.
//!
//! The object store keeps an object as chunk messages on `$O.BUCKET.C.ID` and, last, one meta
//! message on `$O.BUCKET.M.NAME` (size, chunk count, SHA-256, and the `ID`). Its own `put`
//! draws a fresh random `ID` each time, so chunks a failed put left behind cannot be found again
//! and the next put starts at byte 0. This module writes the same layout itself:
//!
//! - `ID` is derived from the object's name, the file's SHA-256 and the part size ([`chunk_id`]),
//!   so any later attempt (in this call, or after the station restarted) finds the parts an
//!   earlier one stored. Each part carries its index and its own SHA-256 in headers.
//! - Part k is published with `Nats-Expected-Last-Subject-Sequence` set to the stream sequence of
//!   part k − 1 (0 for the first): the server stores a part only right after its predecessor, so
//!   the subject holds parts 0..n in order, never a gap or a duplicate, whatever was re-sent after
//!   a lost acknowledgement. Resuming therefore costs one request: the subject's last message
//!   says how many parts are there (its index + 1), its digest that they are this file's, and its
//!   sequence what the next part must expect.
//! - After the last part the parts are read back and the whole file's SHA-256 is checked; only
//!   then is the meta written (with the `Nats-Rollup` the object store uses), so a hub never lists
//!   a recording that is not all there, and reads it with the object store's ordinary reader,
//!   as it reads those that stations wrote with `put` before.
//!
//! Rejected: `Nats-Msg-Id` deduplication. The stream remembers ids only for its duplicate window
//! (two minutes by default), and after parts are purged (a digest that does not match) it would
//! drop the re-sent ones as duplicates of parts no longer there; the expected sequence is checked
//! against what the stream holds now.
//!
//! Nothing here deletes the local file: it stays the copy until the meta is written and read
//! back, and after that too (see the parent module).
//!
//! One file because the chain (each part's expected sequence), the resume (the last part's index,
//! digest and sequence) and the read-back are one protocol whose promise is read in one place;
//! the last 40 lines are its tests.

use std::path::Path;
use std::time::{Duration, Instant};

use async_nats::jetstream::consumer::push::OrderedConfig;
use async_nats::jetstream::message::PublishMessage;
use async_nats::jetstream::object_store::{ObjectInfo, ObjectOptions};
use async_nats::jetstream::stream::LastRawMessageErrorKind;
use base64::Engine;
use futures_util::StreamExt;
use sha2::{Digest, Sha256};
use tokio::io::{AsyncReadExt, AsyncSeekExt};
use tokio::sync::mpsc;

use super::{Store, object_name, same_digest};

/// The header with a part's index (0-based, decimal).
pub const PART_HEADER: &str = "Softhaptic-Part";
/// The header with a part's SHA-256 (lower-case hex).
pub const PART_DIGEST_HEADER: &str = "Softhaptic-Part-Sha256";
/// The object store's own part size; a recording of tens of MB is a few hundred parts.
pub const DEFAULT_PART_BYTES: usize = 128 << 10;
/// Largest part: well under NATS's default 1 MiB payload limit, headers included.
pub const MAX_PART_BYTES: usize = 512 << 10;
/// How long the read-back waits for the next part before it calls the upload unverified.
const READ_BACK_IDLE: Duration = Duration::from_secs(30);

/// How an upload runs.
#[derive(Debug, Clone)]
pub struct UploadOptions {
    /// The size of each part but the last, 1 to [`MAX_PART_BYTES`]. Part of the chunk id: an
    /// upload resumed with another part size starts again.
    pub part_bytes: usize,
    /// How long an upload that stopped making progress (NATS gone, JetStream not ready) keeps
    /// trying within this call before it gives up; the next call resumes it then. Zero: give up
    /// at the first failure.
    pub resume_within: Duration,
    /// Where to report each step. The upload waits for the receiver to take each event (a
    /// bounded channel), so a receiver that holds off pauses the upload between parts.
    pub progress: Option<mpsc::Sender<UploadEvent>>,
}

impl Default for UploadOptions {
    fn default() -> Self {
        Self {
            part_bytes: DEFAULT_PART_BYTES,
            resume_within: Duration::from_secs(30),
            progress: None,
        }
    }
}

/// A step of an upload, for [`UploadOptions::progress`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum UploadEvent {
    /// The store was asked what it holds: `held` of the `total` parts; the others are sent now.
    /// Comes first, and again after each failure once the store answers.
    Resuming { held: usize, total: usize },
    /// Part `index` (of `total`) is stored.
    Stored { index: usize, total: usize },
    /// The parts read back have the file's SHA-256 and the meta is written: the file is archived.
    Verified { total: usize, bytes: u64 },
}

/// What is known of the file before anything is sent.
struct Plan {
    bytes: u64,
    part_bytes: usize,
    /// The whole file's SHA-256 in the store's form (`SHA-256=` and padded base64url).
    digest: String,
    /// Each part's SHA-256.
    parts: Vec<[u8; 32]>,
}

impl Plan {
    /// Reads `path` once: its size, its digest and each part's.
    fn of(path: &Path, part_bytes: usize) -> std::io::Result<Plan> {
        let mut file = std::fs::File::open(path)?;
        let mut whole = Sha256::new();
        let mut parts = Vec::new();
        let mut buf = vec![0u8; part_bytes];
        let mut bytes = 0u64;
        loop {
            let n = read_full(&mut file, &mut buf)?;
            if n == 0 {
                break;
            }
            whole.update(&buf[..n]);
            parts.push(Sha256::digest(&buf[..n]).into());
            bytes += n as u64;
            if n < part_bytes {
                break;
            }
        }
        Ok(Plan {
            bytes,
            part_bytes,
            digest: format!(
                "SHA-256={}",
                base64::engine::general_purpose::URL_SAFE.encode(whole.finalize())
            ),
            parts,
        })
    }

    fn total(&self) -> usize {
        self.parts.len()
    }
}

/// Fills `buf` unless the file ends first; the bytes read.
fn read_full(file: &mut impl std::io::Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match file.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

fn hex(bytes: &[u8]) -> String {
    use std::fmt::Write;
    bytes.iter().fold(String::new(), |mut s, b| {
        let _ = write!(s, "{b:02x}");
        s
    })
}

/// The chunk subject's id of `name` with this content and part size: 32 hex digits (a subject
/// token), the same for every attempt at the same file.
pub fn chunk_id(name: &str, digest: &str, part_bytes: usize) -> String {
    let mut h = Sha256::new();
    h.update(name.as_bytes());
    h.update([0]);
    h.update(digest.trim_end_matches('=').as_bytes());
    h.update([0]);
    h.update((part_bytes as u64).to_be_bytes());
    hex(&h.finalize()[..16])
}

pub(super) fn chunk_subject(bucket: &str, id: &str) -> String {
    format!("$O.{bucket}.C.{id}")
}

/// Uploads `path` as `STATION/FILE` unless the store already has it, resuming whatever part of
/// it an earlier attempt stored; verified before it counts. `Ok(true)` archived now, `Ok(false)`
/// already there.
pub async fn upload_with(
    store: &Store,
    station: &str,
    path: &Path,
    options: &UploadOptions,
) -> Result<bool, String> {
    let file = path
        .file_name()
        .and_then(|f| f.to_str())
        .ok_or_else(|| format!("{}: not a file name", path.display()))?
        .to_owned();
    if !(1..=MAX_PART_BYTES).contains(&options.part_bytes) {
        return Err(format!(
            "part_bytes {}: use 1 to {MAX_PART_BYTES}",
            options.part_bytes
        ));
    }
    // A station's store takes only its own recordings (and NATS lets its credentials write
    // no other).
    if station != store.station {
        return Err(format!(
            "{}: station {station}'s recording cannot go into station {}'s store",
            path.display(),
            store.station
        ));
    }
    let name = object_name(station, &file);
    let plan = {
        let (owned, part_bytes) = (path.to_owned(), options.part_bytes);
        tokio::task::spawn_blocking(move || Plan::of(&owned, part_bytes))
            .await
            .map_err(|e| e.to_string())?
            .map_err(|e| format!("{}: {e}", path.display()))?
    };
    let existing = store.objects.info(&name).await.ok();
    if let Some(info) = &existing
        && info
            .digest
            .as_deref()
            .is_some_and(|d| same_digest(d, &plan.digest))
    {
        return Ok(false);
    }
    let id = chunk_id(&name, &plan.digest, plan.part_bytes);
    let mut upload = Upload {
        store,
        name: &name,
        path,
        plan: &plan,
        subject: store.chunk_subject(&id),
        options,
    };
    upload.send_all().await?;
    upload.read_back().await?;
    upload.write_meta(station, &id).await?;
    upload
        .emit(UploadEvent::Verified {
            total: plan.total(),
            bytes: plan.bytes,
        })
        .await;
    tracing::info!(
        object = %name,
        parts = plan.total(),
        bytes = plan.bytes,
        "recording archived: every part stored and the whole read back with the file's SHA-256"
    );
    // The chunks of an earlier object of that name (another content) are no one's now.
    if let Some(old) = existing
        && old.nuid != id
        && !old.nuid.is_empty()
        && let Err(e) = store
            .stream
            .purge()
            .filter(store.chunk_subject(&old.nuid))
            .await
    {
        tracing::warn!(object = %name, "the replaced object's chunks stay in the store: {e}");
    }
    Ok(true)
}

/// One upload in progress.
struct Upload<'a> {
    store: &'a Store,
    name: &'a str,
    path: &'a Path,
    plan: &'a Plan,
    subject: String,
    options: &'a UploadOptions,
}

impl Upload<'_> {
    async fn emit(&self, event: UploadEvent) {
        if let Some(tx) = &self.options.progress {
            // A receiver that went away wants no more events; the upload goes on.
            let _ = tx.send(event).await;
        }
    }

    /// Sends every part the store does not hold, asking it again after each failure, until all
    /// are stored or no part could be stored for `resume_within`.
    async fn send_all(&mut self) -> Result<(), String> {
        let total = self.plan.total();
        let mut file = tokio::fs::File::open(self.path)
            .await
            .map_err(|e| format!("{}: {e}", self.path.display()))?;
        let mut buf = vec![0u8; self.plan.part_bytes];
        // Since when no part could be stored (None while parts go through).
        let mut stalled_since: Option<Instant> = None;
        let mut failures = 0u32;
        // The parts known to be stored, for the log when the store cannot be asked.
        let mut known = 0;
        loop {
            let (held, mut last_seq) = match self.held().await {
                Ok(h) => h,
                Err(e) => {
                    self.wait_to_resume(&mut stalled_since, &mut failures, known, &e)
                        .await?;
                    continue;
                }
            };
            if held == 0 {
                tracing::info!(object = %self.name, parts = total, bytes = self.plan.bytes, "archiving a recording");
            } else {
                tracing::info!(
                    object = %self.name,
                    held,
                    missing = total - held,
                    parts = total,
                    "resuming an upload: the store holds the first parts, the rest follow"
                );
            }
            self.emit(UploadEvent::Resuming { held, total }).await;
            let mut index = held;
            known = held;
            let result = loop {
                if index == total {
                    break Ok(());
                }
                match self.send_part(&mut file, &mut buf, index, last_seq).await {
                    Ok(seq) => {
                        last_seq = seq;
                        stalled_since = None;
                        failures = 0;
                        tracing::debug!(object = %self.name, part = index, parts = total, "part stored");
                        if (index + 1) * 4 / total.max(1) > index * 4 / total.max(1) {
                            tracing::info!(object = %self.name, stored = index + 1, parts = total, "archiving");
                        }
                        self.emit(UploadEvent::Stored { index, total }).await;
                        index += 1;
                        known = index;
                    }
                    Err(e) => break Err(e),
                }
            };
            match result {
                Ok(()) => return Ok(()),
                Err(PartError::Local(e)) => return Err(e),
                Err(PartError::Store(e)) => {
                    self.wait_to_resume(&mut stalled_since, &mut failures, index, &e)
                        .await?
                }
            }
        }
    }

    /// After a failure: logs the gap, then waits for NATS (and a short backoff) or gives up.
    async fn wait_to_resume(
        &self,
        stalled_since: &mut Option<Instant>,
        failures: &mut u32,
        stored: usize,
        why: &str,
    ) -> Result<(), String> {
        let total = self.plan.total();
        let since = *stalled_since.get_or_insert_with(Instant::now);
        let deadline = since + self.options.resume_within;
        let gave_up = || {
            format!(
                "{}: {stored} of {total} parts stored ({why}); the next attempt resumes from there",
                self.name
            )
        };
        if Instant::now() >= deadline {
            return Err(gave_up());
        }
        tracing::warn!(
            object = %self.name,
            stored,
            missing = total - stored.min(total),
            parts = total,
            "archive upload interrupted ({why}); resuming when the store answers"
        );
        *failures += 1;
        let backoff = Duration::from_millis(100 << (*failures).min(5));
        while !crate::is_connected(&self.store.client) {
            if Instant::now() >= deadline {
                return Err(gave_up());
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        tokio::time::sleep(backoff.min(deadline.saturating_duration_since(Instant::now()))).await;
        Ok(())
    }

    /// How many parts the store holds (0..held, in order, by the expected-sequence chain) and the
    /// stream sequence of the last. Parts that are not this file's are purged first.
    async fn held(&self) -> Result<(usize, u64), String> {
        let last = match self
            .store
            .stream
            .get_last_raw_message_by_subject(&self.subject)
            .await
        {
            Ok(m) => m,
            Err(e) if e.kind() == LastRawMessageErrorKind::NoMessageFound => return Ok((0, 0)),
            Err(e) => return Err(format!("asking for the stored parts: {e}")),
        };
        let index = last
            .headers
            .get(PART_HEADER)
            .and_then(|v| v.as_str().parse::<usize>().ok());
        let digest = last.headers.get(PART_DIGEST_HEADER).map(|v| v.as_str());
        match index {
            Some(i)
                if i < self.plan.total()
                    && digest.is_some_and(|d| d == hex(&self.plan.parts[i])) =>
            {
                Ok((i + 1, last.sequence))
            }
            _ => {
                tracing::warn!(
                    object = %self.name,
                    part = ?index,
                    "the stored parts are not this file's; sending it again from the first part"
                );
                self.purge_parts().await?;
                Ok((0, 0))
            }
        }
    }

    async fn purge_parts(&self) -> Result<(), String> {
        self.store
            .stream
            .purge()
            .filter(&self.subject)
            .await
            .map(|_| ())
            .map_err(|e| format!("purging the stored parts: {e}"))
    }

    /// Reads part `index` and stores it right after the part at sequence `after`; its sequence.
    async fn send_part(
        &self,
        file: &mut tokio::fs::File,
        buf: &mut [u8],
        index: usize,
        after: u64,
    ) -> Result<u64, PartError> {
        let offset = index as u64 * self.plan.part_bytes as u64;
        let len = (self.plan.bytes - offset).min(self.plan.part_bytes as u64) as usize;
        let local = |e: std::io::Error| {
            PartError::Local(format!("{} at byte {offset}: {e}", self.path.display()))
        };
        file.seek(std::io::SeekFrom::Start(offset))
            .await
            .map_err(local)?;
        file.read_exact(&mut buf[..len]).await.map_err(local)?;
        let digest: [u8; 32] = Sha256::digest(&buf[..len]).into();
        if digest != self.plan.parts[index] {
            return Err(PartError::Local(format!(
                "{}: changed while being archived (part {index} at byte {offset})",
                self.path.display()
            )));
        }
        let message = PublishMessage::build()
            .payload(buf[..len].to_vec().into())
            .header(PART_HEADER, index.to_string())
            .header(PART_DIGEST_HEADER, hex(&digest))
            .expected_last_subject_sequence(after);
        let ack = self
            .store
            .js
            .send_publish(self.subject.clone(), message)
            .await
            .map_err(|e| PartError::Store(format!("publishing part {index}: {e}")))?
            .await
            .map_err(|e| PartError::Store(format!("storing part {index}: {e}")))?;
        Ok(ack.sequence)
    }

    /// Reads every part back in order and checks each part's and the whole file's SHA-256. Parts
    /// that read back wrong are purged, so that the next attempt sends them again rather than
    /// failing on them for ever.
    async fn read_back(&self) -> Result<(), String> {
        match self.read_back_parts().await {
            Ok(()) => Ok(()),
            Err(ReadBack::Unavailable(e)) => Err(e),
            Err(ReadBack::Wrong(e)) => {
                tracing::warn!(object = %self.name, "{e}; its parts are purged and sent again at the next attempt");
                if let Err(p) = self.purge_parts().await {
                    tracing::warn!(object = %self.name, "{p}");
                }
                Err(e)
            }
        }
    }

    async fn read_back_parts(&self) -> Result<(), ReadBack> {
        let total = self.plan.total();
        if total == 0 {
            return Ok(());
        }
        let unverified =
            |why: String| ReadBack::Unavailable(format!("{}: not verified: {why}", self.name));
        let wrong = |why: String| ReadBack::Wrong(format!("{}: not verified: {why}", self.name));
        let consumer = self
            .store
            .stream
            .create_consumer(OrderedConfig {
                deliver_subject: self.store.client.new_inbox(),
                filter_subject: self.subject.clone(),
                ..Default::default()
            })
            .await
            .map_err(|e| unverified(format!("reading the parts back: {e}")))?;
        let mut messages = consumer
            .messages()
            .await
            .map_err(|e| unverified(format!("reading the parts back: {e}")))?;
        let mut whole = Sha256::new();
        let mut bytes = 0u64;
        for index in 0..total {
            let message = match tokio::time::timeout(READ_BACK_IDLE, messages.next()).await {
                Ok(Some(Ok(m))) => m,
                Ok(Some(Err(e))) => return Err(unverified(format!("part {index}: {e}"))),
                Ok(None) => return Err(unverified(format!("the parts ended before part {index}"))),
                Err(_) => {
                    return Err(unverified(format!(
                        "part {index} did not come back within {} s",
                        READ_BACK_IDLE.as_secs()
                    )));
                }
            };
            let stored_index = message
                .headers
                .as_ref()
                .and_then(|h| h.get(PART_HEADER))
                .map(|v| v.as_str().to_owned());
            if stored_index.as_deref() != Some(index.to_string().as_str()) {
                return Err(wrong(format!(
                    "part {index} read back as part {stored_index:?}"
                )));
            }
            let digest: [u8; 32] = Sha256::digest(&message.payload).into();
            if digest != self.plan.parts[index] {
                return Err(wrong(format!(
                    "part {index} read back with another SHA-256"
                )));
            }
            whole.update(&message.payload);
            bytes += message.payload.len() as u64;
            let pending = message.info().map(|i| i.pending).unwrap_or(0);
            if (pending == 0) != (index + 1 == total) {
                return Err(wrong(format!(
                    "after part {index} of {total} the store has {pending} more"
                )));
            }
        }
        let digest = format!(
            "SHA-256={}",
            base64::engine::general_purpose::URL_SAFE.encode(whole.finalize())
        );
        if bytes != self.plan.bytes || !same_digest(&digest, &self.plan.digest) {
            return Err(wrong(format!(
                "read back {bytes} bytes with {digest}, the file has {} bytes with {}",
                self.plan.bytes, self.plan.digest
            )));
        }
        Ok(())
    }

    /// Writes the object's meta, as the object store's `put` does last, and checks that the store
    /// answers with it.
    async fn write_meta(&self, station: &str, id: &str) -> Result<(), String> {
        let info = ObjectInfo {
            name: self.name.to_owned(),
            description: Some(format!("recording of station {station}")),
            metadata: Default::default(),
            headers: None,
            options: Some(ObjectOptions {
                link: None,
                max_chunk_size: Some(self.plan.part_bytes),
            }),
            bucket: self.store.bucket.clone(),
            nuid: id.to_owned(),
            size: self.plan.bytes as usize,
            chunks: self.plan.total(),
            modified: Some(time::OffsetDateTime::now_utc()),
            digest: Some(self.plan.digest.clone()),
            deleted: false,
        };
        let payload = serde_json::to_vec(&info).map_err(|e| format!("{}: {e}", self.name))?;
        let subject = format!(
            "$O.{}.M.{}",
            self.store.bucket,
            base64::engine::general_purpose::URL_SAFE.encode(self.name)
        );
        let mut headers = async_nats::HeaderMap::new();
        // One meta message per object: the new one replaces any earlier one of that name.
        headers.insert("Nats-Rollup", "sub");
        self.store
            .js
            .publish_with_headers(subject, headers, payload.into())
            .await
            .map_err(|e| format!("{}: writing its meta: {e}", self.name))?
            .await
            .map_err(|e| format!("{}: writing its meta: {e}", self.name))?;
        let stored = self
            .store
            .objects
            .info(self.name)
            .await
            .map_err(|e| format!("{}: reading its meta back: {e}", self.name))?;
        if stored.nuid != id || stored.digest.as_deref() != Some(self.plan.digest.as_str()) {
            return Err(format!(
                "{}: the store's meta names chunks {} with digest {:?}, not {id} with {}",
                self.name, stored.nuid, stored.digest, self.plan.digest
            ));
        }
        Ok(())
    }
}

/// Why the parts did not read back as the file: the store could not be read (try again), or
/// they are not the file's (send them again).
enum ReadBack {
    Unavailable(String),
    Wrong(String),
}

/// Why a part was not stored: the file (no point retrying) or the store (resume).
enum PartError {
    Local(String),
    Store(String),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_is_planned_as_full_parts_and_a_short_last_one_with_the_stores_digest() {
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let path = dir.path().join("a.mcap");
        let data: Vec<u8> = (0..10_000u32).map(|i| (i * 7 % 251) as u8).collect();
        std::fs::write(&path, &data).unwrap_or_else(|e| panic!("{e}"));
        let plan = Plan::of(&path, 4096).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((plan.bytes, plan.total()), (10_000, 3));
        assert_eq!(
            plan.parts[2],
            <[u8; 32]>::from(Sha256::digest(&data[8192..]))
        );
        assert_eq!(
            plan.digest,
            super::super::digest_of(&path).unwrap_or_else(|e| panic!("{e}"))
        );
        // Exactly two parts: no empty third.
        std::fs::write(&path, &data[..8192]).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(Plan::of(&path, 4096).map(|p| p.total()).ok(), Some(2));
        std::fs::write(&path, b"").unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(Plan::of(&path, 4096).map(|p| p.total()).ok(), Some(0));
    }

    #[test]
    fn the_chunk_id_is_a_subject_token_fixed_by_name_content_and_part_size() {
        let a = chunk_id("desk-1/s.mcap", "SHA-256=abc=", 4096);
        assert_eq!(a, chunk_id("desk-1/s.mcap", "SHA-256=abc", 4096));
        assert_eq!(a.len(), 32);
        assert!(a.chars().all(|c| c.is_ascii_hexdigit()));
        assert_ne!(a, chunk_id("desk-2/s.mcap", "SHA-256=abc", 4096));
        assert_ne!(a, chunk_id("desk-1/s.mcap", "SHA-256=abd", 4096));
        assert_ne!(a, chunk_id("desk-1/s.mcap", "SHA-256=abc", 8192));
    }
}
