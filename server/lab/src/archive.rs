//! Finished recordings into the lab's JetStream object store, and back out for the hubs.
//!
//! A station with a recording directory uploads every finished recording there (all but the one
//! being written) when it starts, again while it runs until none is left unarchived
//! ([`mod@schedule`]), and the session's own recording when it stops, each as
//! `STATION/FILE` in the station's own bucket ([`bucket`]: one per station, so that NATS's
//! permissions can let each station's credentials write its bucket and nothing else, and a
//! hub's read them all; see [`crate::permissions`]). An upload goes part by part and resumes: a pass cut
//! short (NATS restarted, the station stopped) leaves the parts it stored in the store, and the
//! next attempt, in the same pass or the next, or at the next start, asks the store how far
//! it got and sends only the rest ([`mod@upload`] explains how the store keeps that count exact).
//! A file is archived once every part is stored, read back with the file's SHA-256, and the
//! object's meta written: only then do hubs list it. They read it for a replay with the object
//! store's ordinary reader, and for a download ([`download`]) a part at a time as the client
//! takes it, the same for objects older stations wrote with a plain `put`. A hub's list says
//! "nothing archived" only when the bucket does not exist; any other failure to ask the store is
//! an error, not an empty list.
//!
//! No recording is ever deleted here: the local file stays where it is (a lab that wants its
//! disks back removes archived files after checking with `/api/archive`), and so does every
//! archived object. What is deleted is parts no object will ever use: an upload that can never
//! finish (its file was removed, or changed, before a pass resumed it) leaves its parts under a
//! chunk id no meta names, and every pass with recordings to archive removes such parts once
//! the last of them is [`ORPHAN_PARTS_AGE`] old ([`sweep_orphan_parts`]), long after any upload
//! still going would have stored its next part.

pub mod schedule;
pub mod upload;

pub use schedule::{ArchiveProgress, RetryOptions, StationArchive};
pub use upload::{UploadEvent, UploadOptions, upload_with};

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::time::Duration;

use async_nats::jetstream::object_store::{self, ObjectStore};
use async_nats::jetstream::{self, stream::Stream};
use base64::Engine;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

/// The start of every station's bucket's name: [`bucket`].
pub const BUCKET_PREFIX: &str = "softhaptic-sessions-";

/// The object store bucket of `station`'s recordings. A station's name is a bucket name's
/// characters (`[A-Za-z0-9_-]`), so each name has its own bucket.
pub fn bucket(station: &str) -> String {
    format!("{BUCKET_PREFIX}{station}")
}

/// The JetStream stream under `station`'s bucket, by the name the object store gives it.
pub fn bucket_stream(station: &str) -> String {
    format!("OBJ_{}", bucket(station))
}

/// What an archiving pass did.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct ArchiveReport {
    /// Uploaded now and verified.
    pub uploaded: Vec<String>,
    /// Already in the store with the same digest.
    pub already: Vec<String>,
    /// Not uploaded (or not verified), with why; they stay for the next pass.
    pub failed: Vec<(String, String)>,
    /// Parts of uploads that can never finish, removed: (chunk id, parts).
    pub orphans_removed: Vec<(String, usize)>,
    /// Why the sweep for such parts did not run to the end (it runs again at the next pass).
    pub sweep_failed: Option<String>,
}

/// How old the last part of an upload no object uses must be before [`sweep_orphan_parts`]
/// removes its parts: a day, so that an upload that is still going (its next part comes within
/// seconds) or a station that was off overnight (it resumes at its next start, and a removed
/// upload only starts again from its first part) is never cut short.
pub const ORPHAN_PARTS_AGE: Duration = Duration::from_secs(24 * 3600);

/// An archived recording as a hub lists it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ArchivedSession {
    pub station: String,
    pub file: String,
    pub bytes: u64,
    /// The store's digest of it (`SHA-256=` and the hash in unpadded base64url).
    pub digest: String,
}

/// The store's name for a station's recording.
pub fn object_name(station: &str, file: &str) -> String {
    format!("{station}/{file}")
}

/// The digest of `path` in the store's form, read a piece at a time.
pub fn digest_of(path: &Path) -> std::io::Result<String> {
    use std::io::Read;
    let mut file = std::fs::File::open(path)?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = file.read(&mut buf)?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    Ok(format!(
        "SHA-256={}",
        base64::engine::general_purpose::URL_SAFE.encode(hasher.finalize())
    ))
}

/// The digests compare equal whatever the padding of their base64.
fn same_digest(a: &str, b: &str) -> bool {
    a.trim_end_matches('=') == b.trim_end_matches('=')
}

/// A station's recording store: its object store, and the stream under it that resumable
/// uploads write their parts to.
#[derive(Clone)]
pub struct Store {
    client: async_nats::Client,
    js: jetstream::Context,
    station: String,
    bucket: String,
    objects: ObjectStore,
    stream: Stream,
}

impl Store {
    /// The object store itself, read as any NATS client reads it.
    pub fn objects(&self) -> &ObjectStore {
        &self.objects
    }

    /// The station whose store it is.
    pub fn station(&self) -> &str {
        &self.station
    }

    /// The subject of the parts stored under chunk id `id`.
    pub(crate) fn chunk_subject(&self, id: &str) -> String {
        upload::chunk_subject(&self.bucket, id)
    }
}

/// `station`'s recording store, made on first use.
pub async fn store(client: &async_nats::Client, station: &str) -> Result<Store, String> {
    let js = jetstream::new(client.clone());
    let bucket = bucket(station);
    let objects = match js.get_object_store(&bucket).await {
        Ok(store) => store,
        Err(_) => js
            .create_object_store(object_store::Config {
                bucket: bucket.clone(),
                description: Some(format!(
                    "softhaptic session recordings of station {station}, {station}/FILE"
                )),
                ..Default::default()
            })
            .await
            .map_err(|e| format!("the object store {bucket:?}: {e}"))?,
    };
    let stream = js
        .get_stream(bucket_stream(station))
        .await
        .map_err(|e| format!("the object store {bucket:?}'s stream: {e}"))?;
    Ok(Store {
        client: client.clone(),
        js,
        station: station.to_owned(),
        bucket,
        objects,
        stream,
    })
}

/// Uploads `path` as `STATION/FILE` unless the store already has it, resuming an earlier
/// attempt, with the default [`UploadOptions`]; verified before it counts. `Ok(true)` archived
/// now, `Ok(false)` already there.
pub async fn upload(store: &Store, station: &str, path: &Path) -> Result<bool, String> {
    upload_with(store, station, path, &UploadOptions::default()).await
}

/// Uploads every finished recording (`*.mcap`) of `dir` but `skip` (the one being written).
pub async fn upload_finished(
    client: &async_nats::Client,
    station: &str,
    dir: &Path,
    skip: Option<&Path>,
) -> ArchiveReport {
    let mut report = ArchiveReport::default();
    let files = match recordings(dir, skip) {
        Ok(f) => f,
        Err(e) => {
            report.failed.push((dir.display().to_string(), e));
            return report;
        }
    };
    if files.is_empty() {
        return report;
    }
    let store = match store(client, station).await {
        Ok(s) => s,
        Err(e) => {
            for f in files {
                report.failed.push((f.display().to_string(), e.clone()));
            }
            return report;
        }
    };
    for path in files {
        let shown = path.display().to_string();
        match upload(&store, station, &path).await {
            Ok(true) => report.uploaded.push(shown),
            Ok(false) => report.already.push(shown),
            Err(e) => report.failed.push((shown, e)),
        }
    }
    match sweep_orphan_parts(&store, ORPHAN_PARTS_AGE).await {
        Ok(removed) => report.orphans_removed = removed,
        Err(e) => report.sweep_failed = Some(e),
    }
    report
}

/// Removes the parts stored under every chunk id that no object's meta names, when the last of
/// them is at least `older_than` old; returns the ids removed with their part counts. Objects,
/// and parts an object uses, are never touched; nor is an upload whose last part is younger.
pub async fn sweep_orphan_parts(
    store: &Store,
    older_than: Duration,
) -> Result<Vec<(String, usize)>, String> {
    use futures_util::StreamExt;
    // Every id an object uses, read before the chunk subjects: an upload that writes its meta
    // in between has just stored its last part, too young to be removed.
    let mut used = HashSet::new();
    let mut objects = store
        .objects
        .list()
        .await
        .map_err(|e| format!("listing the archived objects: {e}"))?;
    while let Some(info) = objects.next().await {
        used.insert(
            info.map_err(|e| format!("listing the archived objects: {e}"))?
                .nuid,
        );
    }
    let now = time::OffsetDateTime::now_utc();
    let mut removed = Vec::new();
    for (id, parts) in stored_parts(store).await? {
        if used.contains(&id) {
            continue;
        }
        let subject = store.chunk_subject(&id);
        let last = store
            .stream
            .get_last_raw_message_by_subject(&subject)
            .await
            .map_err(|e| format!("reading the last part of {id}: {e}"))?;
        // A clock behind the server's makes the age negative: too young, kept.
        let age = now - last.time;
        if age < time::Duration::try_from(older_than).unwrap_or(time::Duration::MAX) {
            continue;
        }
        store
            .stream
            .purge()
            .filter(&subject)
            .await
            .map_err(|e| format!("removing the parts of {id}: {e}"))?;
        removed.push((id, parts));
    }
    Ok(removed)
}

/// Every chunk id the store holds parts under, with how many, by id: archived objects' and
/// unfinished uploads' alike.
pub async fn stored_parts(store: &Store) -> Result<Vec<(String, usize)>, String> {
    use futures_util::TryStreamExt;
    let prefix = store.chunk_subject("");
    let mut listing = store
        .stream
        .info_with_subjects(format!("{prefix}>"))
        .await
        .map_err(|e| format!("listing the stored parts: {e}"))?;
    let mut out = Vec::new();
    while let Some((subject, parts)) = listing
        .try_next()
        .await
        .map_err(|e| format!("listing the stored parts: {e}"))?
    {
        if let Some(id) = subject.strip_prefix(&prefix) {
            out.push((id.to_owned(), parts));
        }
    }
    out.sort();
    Ok(out)
}

fn recordings(dir: &Path, skip: Option<&Path>) -> Result<Vec<PathBuf>, String> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(e.to_string()),
    };
    let skip = skip.and_then(|s| s.file_name().map(|f| f.to_owned()));
    let mut files: Vec<PathBuf> = entries
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "mcap") && p.is_file())
        .filter(|p| p.file_name().map(|f| f.to_owned()) != skip)
        .collect();
    files.sort();
    Ok(files)
}

/// The archived recordings of `station` (all stations when `None`), each from its station's
/// own bucket: an object in a station's bucket is that station's, whatever name it was given
/// (one named for another station is not listed: only its own station could have put it there).
pub async fn list(
    client: &async_nats::Client,
    station: Option<&str>,
) -> Result<Vec<ArchivedSession>, String> {
    use futures_util::StreamExt;
    // Not connected: the request would only time out (and "nothing archived" would be a lie).
    if !crate::is_connected(client) {
        return Err("NATS is not connected".to_owned());
    }
    let js = async_nats::jetstream::new(client.clone());
    let stations = match station {
        Some(s) => vec![s.to_owned()],
        None => {
            let mut names = js.stream_names();
            let mut stations = Vec::new();
            while let Some(name) = names.next().await {
                let name = name.map_err(|e| format!("listing the stations' buckets: {e}"))?;
                if let Some(s) = name.strip_prefix(&format!("OBJ_{BUCKET_PREFIX}"))
                    && crate::check_station_name(s).is_ok()
                {
                    stations.push(s.to_owned());
                }
            }
            stations
        }
    };
    let mut out = Vec::new();
    for station in stations {
        let bucket = bucket(&station);
        let store = match js.get_object_store(&bucket).await {
            Ok(store) => store,
            // Nothing archived by this station: no bucket yet.
            Err(e) if is_no_bucket(&e) => continue,
            Err(e) => return Err(format!("the object store {bucket:?}: {e}")),
        };
        let mut objects = store.list().await.map_err(|e| e.to_string())?;
        while let Some(info) = objects.next().await {
            let info = info.map_err(|e| e.to_string())?;
            let Some((s, file)) = info.name.split_once('/') else {
                continue;
            };
            if s != station {
                continue;
            }
            out.push(ArchivedSession {
                station: station.clone(),
                file: file.to_owned(),
                bytes: info.size as u64,
                digest: info.digest.clone().unwrap_or_default(),
            });
        }
    }
    out.sort_by(|a, b| (&a.station, &a.file).cmp(&(&b.station, &b.file)));
    Ok(out)
}

/// Whether `error` says that the bucket does not exist (its stream is not found), rather than
/// that the store could not be asked.
fn is_no_bucket(error: &jetstream::context::ObjectStoreError) -> bool {
    use async_nats::jetstream::ErrorCode;
    use async_nats::jetstream::context::{GetStreamError, GetStreamErrorKind};
    std::error::Error::source(error)
        .and_then(|source| source.downcast_ref::<GetStreamError>())
        .is_some_and(|e| {
            matches!(e.kind(), GetStreamErrorKind::JetStream(j) if j.error_code() == ErrorCode::STREAM_NOT_FOUND)
        })
}

/// One archived recording's bytes (at most `max_bytes`, and a recording's size limit).
pub async fn fetch(
    client: &async_nats::Client,
    station: &str,
    file: &str,
    max_bytes: u64,
) -> Result<Vec<u8>, String> {
    use tokio::io::AsyncReadExt;
    let js = async_nats::jetstream::new(client.clone());
    let store = js
        .get_object_store(bucket(station))
        .await
        .map_err(|e| e.to_string())?;
    let mut object = store
        .get(object_name(station, file))
        .await
        .map_err(|e| e.to_string())?;
    let limit = crate::files::FileKind::Recording.max_bytes().min(max_bytes);
    let mut bytes = Vec::new();
    (&mut object)
        .take(limit + 1)
        .read_to_end(&mut bytes)
        .await
        .map_err(|e| e.to_string())?;
    if bytes.len() as u64 > limit {
        return Err(format!("larger than the {limit} bytes a recording may be"));
    }
    Ok(bytes)
}

/// An archived recording opened for a download: its size, and its bytes a part at a time as
/// the client takes them (each part is asked of the store when the one before has gone, so a
/// download holds one part, never the whole file, however slow its client). The whole file's
/// SHA-256 is checked before its last part goes: a body that ends with an error was not the
/// recording (and is shorter than its `Content-Length`).
pub struct Download {
    pub bytes: u64,
    pub body: futures_util::stream::BoxStream<'static, std::io::Result<axum::body::Bytes>>,
}

/// Opens one archived recording for a download (at most a recording's size limit).
pub async fn download(
    client: &async_nats::Client,
    station: &str,
    file: &str,
) -> Result<Download, String> {
    use futures_util::StreamExt;
    let js = async_nats::jetstream::new(client.clone());
    let objects = js
        .get_object_store(bucket(station))
        .await
        .map_err(|e| e.to_string())?;
    let info = objects
        .info(object_name(station, file))
        .await
        .map_err(|e| e.to_string())?;
    if info.deleted {
        return Err("deleted".to_owned());
    }
    if info.options.as_ref().is_some_and(|o| o.link.is_some()) {
        return Err("a link, not a recording".to_owned());
    }
    let limit = crate::files::FileKind::Recording.max_bytes();
    let bytes = info.size as u64;
    if bytes > limit {
        return Err(format!(
            "{bytes} bytes, larger than the {limit} bytes a recording may be"
        ));
    }
    if info.chunks == 0 && bytes != 0 {
        return Err(format!("{bytes} bytes in no part"));
    }
    let stream = js
        .get_stream(bucket_stream(station))
        .await
        .map_err(|e| e.to_string())?;
    let reading = Reading {
        stream,
        subject: upload::chunk_subject(&bucket(station), &info.nuid),
        chunks: info.chunks,
        digest: info.digest.clone(),
        bytes,
        next_chunk: 0,
        next_sequence: 1,
        sent: 0,
        hasher: Sha256::new(),
    };
    let body = futures_util::stream::unfold(Some(reading), |state| async move {
        let mut reading = state?;
        match reading.next_part().await {
            Ok(Some(part)) => Some((Ok(part), Some(reading))),
            Ok(None) => None,
            Err(e) => Some((Err(std::io::Error::other(e)), None)),
        }
    })
    .boxed();
    Ok(Download { bytes, body })
}

/// Where a download is in the object's parts.
struct Reading {
    stream: Stream,
    subject: String,
    chunks: usize,
    digest: Option<String>,
    bytes: u64,
    next_chunk: usize,
    /// The stream sequence to look for the next part from.
    next_sequence: u64,
    sent: u64,
    hasher: Sha256,
}

impl Reading {
    /// The next part, checked; `None` after the last.
    async fn next_part(&mut self) -> Result<Option<axum::body::Bytes>, String> {
        if self.next_chunk == self.chunks {
            return Ok(None);
        }
        let message = self
            .stream
            .raw_message_builder()
            .next_by_subject(self.subject.clone())
            .sequence(self.next_sequence)
            .send()
            .await
            .map_err(|e| format!("part {} of {}: {e}", self.next_chunk + 1, self.chunks))?;
        self.next_sequence = message.sequence + 1;
        self.next_chunk += 1;
        self.sent += message.payload.len() as u64;
        if self.sent > self.bytes {
            return Err(format!(
                "the object holds more than its {} bytes",
                self.bytes
            ));
        }
        self.hasher.update(&message.payload);
        if self.next_chunk == self.chunks {
            if self.sent != self.bytes {
                return Err(format!(
                    "the object holds {} of its {} bytes",
                    self.sent, self.bytes
                ));
            }
            let digest = format!(
                "SHA-256={}",
                base64::engine::general_purpose::URL_SAFE
                    .encode(std::mem::take(&mut self.hasher).finalize())
            );
            if let Some(want) = &self.digest
                && !same_digest(want, &digest)
            {
                return Err(format!("its parts' digest is {digest}, not {want}"));
            }
        }
        Ok(Some(message.payload))
    }
}
