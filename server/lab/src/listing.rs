//! The archive's listing a hub serves (`/api/archive`), kept in memory and updated from the
//! object store's own change feed, so that the pages asking for it (each every 2 s) cost NATS
//! nothing.
//!
//! Each station's bucket ([`super::archive::bucket`]) is read once, by one ordered consumer on
//! the subjects of its objects' metas (`$O.BUCKET.M.>`) delivering the last meta of each object
//! and then every new one: an object archived, replaced or deleted reaches the listing as the
//! store writes its meta, with no listing asked again. Buckets appear and go as JetStream's
//! advisories say (`$JS.EVENT.ADVISORY.STREAM.CREATED.*` and `.DELETED.*`, subscribed to before
//! the buckets are listed once, so that one made in between is seen by either); a bucket made
//! later (a new station's first upload) is read from then on. A deleted bucket whose advisory
//! does not come (nats-server 2.9 now and then sends none) goes when its feed's heartbeats stop,
//! within about 10 s: the bucket is looked up again, and not found.
//!
//! What the listing says when it cannot be whole:
//! - NATS not connected: no listing, an error (the hub answers 502, "did not answer"), never
//!   an empty list. On reconnection every bucket is read again from its history (one stream
//!   listing and one consumer per bucket), since what changed while the hub was away (a bucket
//!   made or deleted) came with no advisory to it.
//! - a bucket not read yet, or whose feed failed (it is read again after a wait that doubles
//!   from 1 s to 30 s): a request waits up to the time it is given for it; past that, a listing
//!   of that station alone is an error, and the listing of all names it under `unavailable`
//!   beside the others' recordings.
//!
//! Bounded: at most [`ListingLimits::max_stations`] buckets are read, and at most
//! [`ListingLimits::max_per_station`] recordings of a station and
//! [`ListingLimits::max_total`] in all are listed (with a file name of at most
//! [`MAX_FILE_NAME_BYTES`]). What is beyond is not listed: it is counted in the listing's
//! `omitted` and logged (the first time and at each power of two). A recording deleted from a
//! station that has some omitted makes the hub read that station's bucket again, so that one
//! omitted takes its place.

use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use async_nats::jetstream::{
    self,
    consumer::{DeliverPolicy, push::OrderedConfig},
    object_store::ObjectInfo,
};
use axum::body::Bytes;
use futures_util::StreamExt;
use tokio::sync::watch;
use tokio::task::JoinHandle;

use super::archive::{ArchivedSession, BUCKET_PREFIX, bucket, bucket_stream};

/// How much of the archive a hub lists.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ListingLimits {
    /// Buckets (stations) read at most.
    pub max_stations: usize,
    /// Recordings of one station listed at most.
    pub max_per_station: usize,
    /// Recordings listed at most in all.
    pub max_total: usize,
}

impl Default for ListingLimits {
    /// 512 stations (the hub's station list's own bound), 5 000 recordings a station (years of
    /// a lab's sessions), 50 000 in all: each listed recording takes at most about 400 bytes
    /// (its name, at most [`MAX_FILE_NAME_BYTES`], its digest, the map's node), so the whole
    /// listing at most about 20 MB, and its JSON at most about 18 MB.
    fn default() -> Self {
        ListingLimits {
            max_stations: 512,
            max_per_station: 5_000,
            max_total: 50_000,
        }
    }
}

/// The longest file name listed, bytes (a recording's name is a few tens).
pub const MAX_FILE_NAME_BYTES: usize = 255;
/// The largest object meta read, bytes: a recording's is a few hundred; one far larger (a
/// station's metadata padded) is not a recording's and is skipped.
const MAX_META_BYTES: usize = 64 * 1024;

/// JetStream's advisory of a stream made, and of one deleted (`*`: the stream's name).
pub const STREAM_CREATED: &str = "$JS.EVENT.ADVISORY.STREAM.CREATED.*";
pub const STREAM_DELETED: &str = "$JS.EVENT.ADVISORY.STREAM.DELETED.*";

/// How often the connection is looked at (a local read, no request).
const CONNECTION_CHECK: Duration = Duration::from_millis(250);
/// The longest wait between two attempts to read a bucket, or to follow the archive.
const MAX_RETRY: Duration = Duration::from_secs(30);

/// A listed recording.
#[derive(Debug, Clone)]
struct Listed {
    bytes: u64,
    digest: String,
}

/// A station's bucket as read so far.
struct Station {
    /// Caught up with its bucket's history: its list is whole.
    ready: bool,
    files: BTreeMap<String, Listed>,
    /// Recordings not listed, beyond the caps.
    omitted: u64,
    /// Which reading of the bucket this is: what an earlier one (aborted) would still say is
    /// ignored.
    epoch: u64,
    task: Option<JoinHandle<()>>,
}

impl Drop for Station {
    fn drop(&mut self) {
        if let Some(task) = self.task.take() {
            task.abort();
        }
    }
}

/// Whether the archive can be listed.
#[derive(Debug, Clone, PartialEq)]
enum Availability {
    /// The buckets are being listed (at start, after a reconnection).
    Building,
    /// The buckets are known and each is read (or being read).
    Following,
    /// Not now, and why.
    Unavailable(String),
}

struct State {
    availability: Availability,
    stations: BTreeMap<String, Station>,
    /// Recordings listed in all.
    total: usize,
    /// Buckets not read, beyond [`ListingLimits::max_stations`].
    omitted_stations: u64,
    generation: u64,
    /// Answers made at `generation`, by station asked for (none: all).
    answers: HashMap<Option<String>, Bytes>,
    next_epoch: u64,
}

/// The archive's listing, kept by one task per bucket and one following the buckets.
pub struct ArchiveListing {
    state: Mutex<State>,
    /// The state's generation, for requests waiting for a bucket to be read.
    changed: watch::Sender<u64>,
    /// Consumers made on the buckets since the start.
    consumers: AtomicU64,
    /// Times the buckets were listed since the start.
    bucket_listings: AtomicU64,
    limits: ListingLimits,
}

fn lock(m: &Mutex<State>) -> std::sync::MutexGuard<'_, State> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Whether to log the `n`th event of a kind: the first, then at each power of two.
fn log_nth(n: u64) -> bool {
    n == 1 || n.is_power_of_two()
}

impl ArchiveListing {
    /// A listing of no station yet, in `availability`.
    fn empty(limits: ListingLimits, availability: Availability) -> ArchiveListing {
        ArchiveListing {
            state: Mutex::new(State {
                availability,
                stations: BTreeMap::new(),
                total: 0,
                omitted_stations: 0,
                generation: 0,
                answers: HashMap::new(),
                next_epoch: 0,
            }),
            changed: watch::channel(0).0,
            consumers: AtomicU64::new(0),
            bucket_listings: AtomicU64::new(0),
            limits,
        }
    }

    /// Starts following the archive through `client`; the task runs until aborted.
    pub fn start(
        client: async_nats::Client,
        limits: ListingLimits,
    ) -> (Arc<ArchiveListing>, JoinHandle<()>) {
        let listing = Arc::new(ArchiveListing::empty(limits, Availability::Building));
        let task = tokio::spawn(Arc::clone(&listing).follow_archive(client));
        (listing, task)
    }

    /// JetStream consumers made on the buckets since the start: one per bucket, and one more
    /// per bucket each time it is read again (a reconnection, a failed feed).
    pub fn consumers_made(&self) -> u64 {
        self.consumers.load(Ordering::Relaxed)
    }

    /// Times the buckets were listed since the start (at start, and once per reconnection).
    pub fn bucket_listings(&self) -> u64 {
        self.bucket_listings.load(Ordering::Relaxed)
    }

    /// The listing as `/api/archive` answers it (`{"archive": [...]}`, with `unavailable` and
    /// `omitted` when there are any), of `station` or of all; waits up to `wait` for buckets
    /// still being read. An error when NATS is not connected, or when `station`'s bucket is
    /// not read by then.
    pub async fn answer(&self, station: Option<&str>, wait: Duration) -> Result<Bytes, String> {
        let mut changes = self.changed.subscribe();
        let deadline = tokio::time::Instant::now() + wait;
        loop {
            {
                let mut state = lock(&self.state);
                match &state.availability {
                    Availability::Unavailable(why) => return Err(why.clone()),
                    Availability::Following if whole(&state, station) => {
                        return self.render(&mut state, station);
                    }
                    _ => {}
                }
            }
            if tokio::time::timeout_at(deadline, changes.changed())
                .await
                .is_err()
            {
                break;
            }
        }
        let mut state = lock(&self.state);
        match &state.availability {
            Availability::Unavailable(why) => Err(why.clone()),
            Availability::Building => Err("the archive's buckets are being listed".to_owned()),
            Availability::Following => match station {
                Some(name) if !whole(&state, station) => {
                    Err(format!("the bucket of station {name:?} is being read"))
                }
                _ => self.render(&mut state, station),
            },
        }
    }

    /// The JSON of what is listed now, made once per change.
    fn render(&self, state: &mut State, station: Option<&str>) -> Result<Bytes, String> {
        let key = station.map(str::to_owned);
        if let Some(json) = state.answers.get(&key) {
            return Ok(json.clone());
        }
        let mut archive = Vec::new();
        let mut unavailable = Vec::new();
        let mut omitted = 0;
        for (name, s) in &state.stations {
            if station.is_some_and(|wanted| wanted != name) {
                continue;
            }
            if !s.ready {
                unavailable.push(name.clone());
                continue;
            }
            omitted += s.omitted;
            archive.extend(s.files.iter().map(|(file, listed)| ArchivedSession {
                station: name.clone(),
                file: file.clone(),
                bytes: listed.bytes,
                digest: listed.digest.clone(),
            }));
        }
        if station.is_none() {
            omitted += state.omitted_stations;
        }
        let body = Answer {
            archive,
            unavailable,
            omitted,
        };
        let json = Bytes::from(serde_json::to_vec(&body).map_err(|e| e.to_string())?);
        // Any name may be asked for: the answers kept are bounded.
        if state.answers.len() >= 64 {
            state.answers.clear();
        }
        state.answers.insert(key, json.clone());
        Ok(json)
    }

    /// Marks a change: the answers made are dropped, and waiting requests look again.
    fn changed(&self, state: &mut State) {
        state.generation += 1;
        state.answers.clear();
        self.changed.send_replace(state.generation);
    }

    fn set_availability(&self, availability: Availability) {
        let mut state = lock(&self.state);
        if state.availability != availability {
            state.availability = availability;
            self.changed(&mut state);
        }
    }

    /// Forgets every bucket (their readers stop) and says whether the archive is listed.
    fn reset(&self, availability: Availability) {
        let mut state = lock(&self.state);
        state.stations.clear();
        state.total = 0;
        state.omitted_stations = 0;
        state.availability = availability;
        self.changed(&mut state);
    }

    /// Follows the archive: lists the buckets, reads each, and follows the advisories of
    /// buckets made and deleted; starts again on reconnection.
    async fn follow_archive(self: Arc<Self>, client: async_nats::Client) {
        let mut retry = Duration::from_secs(1);
        let mut failures = 0u64;
        loop {
            while !super::is_connected(&client) {
                self.set_availability(Availability::Unavailable(
                    "NATS is not connected".to_owned(),
                ));
                tokio::time::sleep(CONNECTION_CHECK).await;
            }
            self.set_availability(Availability::Building);
            match Arc::clone(&self)
                .follow_connected(&client, &mut retry)
                .await
            {
                // Reconnected: read again at once, requests waiting meanwhile.
                Ok(_) if super::is_connected(&client) => {
                    self.reset(Availability::Building);
                    // However it ended, never a busy loop.
                    tokio::time::sleep(CONNECTION_CHECK).await;
                }
                Ok(why) => self.reset(Availability::Unavailable(why)),
                Err(e) => {
                    failures += 1;
                    if log_nth(failures) {
                        tracing::warn!(
                            "the archive's listing could not be made ({failures} times so far; again in {retry:?}): {e}"
                        );
                    }
                    self.reset(Availability::Unavailable(e));
                    tokio::time::sleep(retry).await;
                    retry = (retry * 2).min(MAX_RETRY);
                }
            }
        }
    }

    /// Stops reading the buckets (the hub stops).
    pub fn stop(&self) {
        self.reset(Availability::Unavailable("the hub is stopping".to_owned()));
    }

    /// One connection's following: `Ok` with why it ended (the connection lost or made again),
    /// `Err` when the buckets could not be listed.
    async fn follow_connected(
        self: Arc<Self>,
        client: &async_nats::Client,
        retry: &mut Duration,
    ) -> Result<String, String> {
        let connects = client.statistics().connects.load(Ordering::Relaxed);
        let subscribe = |subject: &'static str| async move {
            client
                .subscribe(subject)
                .await
                .map_err(|e| format!("subscribing to {subject}: {e}"))
        };
        let mut created = subscribe(STREAM_CREATED).await?;
        let mut deleted = subscribe(STREAM_DELETED).await?;
        // The subscriptions are in place before the buckets are listed: one made in between is
        // in the list or in an advisory (or both: reading it twice is harmless).
        client
            .flush()
            .await
            .map_err(|e| format!("flushing the subscriptions: {e}"))?;
        let js = jetstream::new(client.clone());
        let mut names = js.stream_names();
        let mut stations = Vec::new();
        while let Some(name) = names.next().await {
            let name = name.map_err(|e| format!("listing the stations' buckets: {e}"))?;
            if let Some(station) = station_of_stream(&name) {
                stations.push(station.to_owned());
            }
        }
        self.bucket_listings.fetch_add(1, Ordering::Relaxed);
        for station in stations {
            Arc::clone(&self).read_bucket(&js, &station);
        }
        self.set_availability(Availability::Following);
        *retry = Duration::from_secs(1);
        let mut check = tokio::time::interval(CONNECTION_CHECK);
        loop {
            tokio::select! {
                m = created.next() => {
                    let Some(m) = m else { return Ok("the advisories ended".to_owned()) };
                    if let Some(station) = m.subject.rsplit('.').next().and_then(station_of_stream) {
                        tracing::info!(station, "a station's archive bucket was made");
                        Arc::clone(&self).read_bucket(&js, station);
                    }
                }
                m = deleted.next() => {
                    let Some(m) = m else { return Ok("the advisories ended".to_owned()) };
                    if let Some(station) = m.subject.rsplit('.').next().and_then(station_of_stream) {
                        tracing::info!(station, "a station's archive bucket was deleted");
                        self.forget(station);
                    }
                }
                _ = check.tick() => {
                    if !super::is_connected(client) {
                        return Ok("NATS is not connected".to_owned());
                    }
                    if client.statistics().connects.load(Ordering::Relaxed) != connects {
                        return Ok("NATS reconnected: the archive is read again".to_owned());
                    }
                }
            }
        }
    }

    /// Starts reading `station`'s bucket, unless it is read already (or there are as many
    /// buckets read as the hub reads).
    fn read_bucket(self: Arc<Self>, js: &jetstream::Context, station: &str) {
        let mut state = lock(&self.state);
        if state.stations.contains_key(station) {
            return;
        }
        if state.stations.len() >= self.limits.max_stations {
            state.omitted_stations += 1;
            if log_nth(state.omitted_stations) {
                tracing::warn!(
                    station,
                    "the archive's listing reads {} stations' buckets at most: this one is not listed ({} so far)",
                    self.limits.max_stations,
                    state.omitted_stations
                );
            }
            self.changed(&mut state);
            return;
        }
        state.next_epoch += 1;
        let epoch = state.next_epoch;
        let task =
            tokio::spawn(Arc::clone(&self).follow_bucket(js.clone(), station.to_owned(), epoch));
        state.stations.insert(
            station.to_owned(),
            Station {
                ready: false,
                files: BTreeMap::new(),
                omitted: 0,
                epoch,
                task: Some(task),
            },
        );
        self.changed(&mut state);
    }

    /// Forgets a deleted bucket (its reader stops).
    fn forget(&self, station: &str) {
        let mut state = lock(&self.state);
        if let Some(s) = state.stations.remove(station) {
            state.total -= s.files.len();
            self.changed(&mut state);
        }
    }

    /// Reads `station`'s bucket for as long as it is listed, again after each failure: at once
    /// after a feed that ran (its bucket may be gone), then after a wait that doubles.
    async fn follow_bucket(self: Arc<Self>, js: jetstream::Context, station: String, epoch: u64) {
        let mut retry = Duration::ZERO;
        let mut failures = 0u64;
        loop {
            let started = tokio::time::Instant::now();
            let ended = self.read_feed(&js, &station, epoch).await;
            // Unlisted until read again: the listing says so rather than show a part.
            self.begin(&station, epoch, false);
            match ended {
                FeedEnd::ReadAgain => continue,
                FeedEnd::Gone => {
                    // Its advisory is the usual way a deleted bucket goes; this is for one that
                    // did not come (seen with nats-server 2.9): the feed's heartbeats stop.
                    tracing::info!(station, "a station's archive bucket is gone");
                    self.forget_reading(&station, epoch);
                    return;
                }
                FeedEnd::Failed(e) => {
                    failures += 1;
                    if log_nth(failures) {
                        tracing::warn!(
                            station,
                            "the archive bucket's change feed failed ({failures} times so far; read again in {retry:?}): {e}"
                        );
                    }
                }
            }
            // A feed that ran a while starts the waits again from none.
            if started.elapsed() > MAX_RETRY {
                retry = Duration::ZERO;
            }
            tokio::time::sleep(retry).await;
            retry = (retry * 2).clamp(Duration::from_secs(1), MAX_RETRY);
        }
    }

    /// Forgets `station`'s bucket if this reading (`epoch`) is still its own.
    fn forget_reading(&self, station: &str, epoch: u64) {
        let mut state = lock(&self.state);
        if state
            .stations
            .get(station)
            .is_some_and(|s| s.epoch == epoch)
            && let Some(mut s) = state.stations.remove(station)
        {
            state.total -= s.files.len();
            // The task ending is this one: it returns rather than be aborted.
            s.task = None;
            self.changed(&mut state);
        }
    }

    /// One reading of the bucket's change feed: from the last meta of each object on, until it
    /// ends.
    async fn read_feed(&self, js: &jetstream::Context, station: &str, epoch: u64) -> FeedEnd {
        let bucket = bucket(station);
        let stream = match js.get_stream(bucket_stream(station)).await {
            Ok(stream) => stream,
            Err(e) if is_stream_not_found(&e) => return FeedEnd::Gone,
            Err(e) => return FeedEnd::Failed(format!("the bucket {bucket:?}: {e}")),
        };
        let consumer = match stream
            .create_consumer(OrderedConfig {
                deliver_subject: js.client().new_inbox(),
                deliver_policy: DeliverPolicy::LastPerSubject,
                filter_subject: format!("$O.{bucket}.M.>"),
                description: Some("softhaptic hub: the archive's listing".to_owned()),
                ..Default::default()
            })
            .await
        {
            Ok(consumer) => consumer,
            Err(e) => return FeedEnd::Failed(format!("following the bucket {bucket:?}: {e}")),
        };
        self.consumers.fetch_add(1, Ordering::Relaxed);
        // Nothing to read back: the listing of this bucket is whole (empty) now.
        self.begin(station, epoch, consumer.cached_info().num_pending == 0);
        let mut feed = match consumer.messages().await {
            Ok(feed) => feed,
            Err(e) => return FeedEnd::Failed(format!("following the bucket {bucket:?}: {e}")),
        };
        let mut skipped = 0u64;
        while let Some(message) = feed.next().await {
            let message = match message {
                Ok(message) => message,
                Err(e) => return FeedEnd::Failed(format!("the bucket {bucket:?}'s feed: {e}")),
            };
            let caught_up = match message.info() {
                Ok(info) => info.pending == 0,
                Err(e) => return FeedEnd::Failed(format!("the bucket {bucket:?}'s feed: {e}")),
            };
            let info = if message.payload.len() > MAX_META_BYTES {
                Err(format!("a meta of {} bytes", message.payload.len()))
            } else {
                serde_json::from_slice::<ObjectInfo>(&message.payload).map_err(|e| e.to_string())
            };
            let info = match info {
                Ok(info) => Some(info),
                Err(e) => {
                    skipped += 1;
                    if log_nth(skipped) {
                        tracing::warn!(
                            station,
                            "not an object's meta in the bucket ({skipped} so far): {e}"
                        );
                    }
                    None
                }
            };
            if self.apply(station, epoch, info.as_ref(), caught_up) {
                return FeedEnd::ReadAgain;
            }
        }
        FeedEnd::Failed(format!("the bucket {bucket:?}'s feed ended"))
    }

    /// A reading of `station`'s bucket starts (or failed): nothing listed of it until it is
    /// caught up (`ready` now when there is nothing to read).
    fn begin(&self, station: &str, epoch: u64, ready: bool) {
        let mut state = lock(&self.state);
        let state = &mut *state;
        let Some(s) = state.stations.get_mut(station).filter(|s| s.epoch == epoch) else {
            return;
        };
        state.total -= s.files.len();
        s.files.clear();
        s.omitted = 0;
        s.ready = ready;
        self.changed(state);
    }

    /// One object's meta from `station`'s feed (`None`: a message that was not one). True when
    /// the bucket must be read again from its history: a recording was deleted where some
    /// were omitted, one of which may be listed now.
    fn apply(&self, station: &str, epoch: u64, info: Option<&ObjectInfo>, caught_up: bool) -> bool {
        let mut guard = lock(&self.state);
        let state = &mut *guard;
        let Some(s) = state.stations.get_mut(station).filter(|s| s.epoch == epoch) else {
            return false;
        };
        let mut changed = false;
        // An object in a station's bucket is that station's whatever name it was given; one
        // named for another station is not listed (only its own station could have put it
        // there), nor is a link (it is not a recording a download could serve).
        let named = info.and_then(|info| {
            let (owner, file) = info.name.split_once('/')?;
            let link = info.options.as_ref().is_some_and(|o| o.link.is_some());
            (owner == station && !file.is_empty() && file.len() <= MAX_FILE_NAME_BYTES && !link)
                .then_some((info, file))
        });
        if let Some((info, file)) = named {
            if info.deleted {
                if s.files.remove(file).is_some() {
                    state.total -= 1;
                    changed = true;
                }
                // Live (not the history read back): one omitted may take its place.
                if s.ready && s.omitted > 0 {
                    return true;
                }
            } else if let Some(listed) = s.files.get_mut(file) {
                listed.bytes = info.size as u64;
                listed.digest = info.digest.clone().unwrap_or_default();
                changed = true;
            } else if s.files.len() >= self.limits.max_per_station
                || state.total >= self.limits.max_total
            {
                s.omitted += 1;
                if log_nth(s.omitted) {
                    tracing::warn!(
                        station,
                        "the archive's listing holds {} recordings a station and {} in all: {file:?} is not listed ({} of the station's so far)",
                        self.limits.max_per_station,
                        self.limits.max_total,
                        s.omitted
                    );
                }
                changed = true;
            } else {
                s.files.insert(
                    file.to_owned(),
                    Listed {
                        bytes: info.size as u64,
                        digest: info.digest.clone().unwrap_or_default(),
                    },
                );
                state.total += 1;
                changed = true;
            }
        }
        if caught_up && !s.ready {
            s.ready = true;
            changed = true;
        }
        if changed {
            self.changed(state);
        }
        false
    }
}

/// `/api/archive`'s answer.
#[derive(serde::Serialize)]
struct Answer {
    archive: Vec<ArchivedSession>,
    /// Stations whose bucket is not read (yet, or again).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    unavailable: Vec<String>,
    /// Recordings (and buckets) not listed, beyond the caps.
    #[serde(skip_serializing_if = "is_zero")]
    omitted: u64,
}

fn is_zero(n: &u64) -> bool {
    *n == 0
}

/// How a reading of a bucket's feed ended.
enum FeedEnd {
    /// To be read again from its history at once: a recording was deleted where some were
    /// omitted.
    ReadAgain,
    /// The bucket is not there (deleted).
    Gone,
    /// The feed failed, and why.
    Failed(String),
}

/// Whether `error` says that the stream does not exist, rather than that it could not be asked.
fn is_stream_not_found(error: &jetstream::context::GetStreamError) -> bool {
    use async_nats::jetstream::ErrorCode;
    use async_nats::jetstream::context::GetStreamErrorKind;
    matches!(error.kind(), GetStreamErrorKind::JetStream(j) if j.error_code() == ErrorCode::STREAM_NOT_FOUND)
}

/// Whether what is asked for is read whole: every bucket (or `station`'s, if it has one).
fn whole(state: &State, station: Option<&str>) -> bool {
    match station {
        Some(name) => state.stations.get(name).is_none_or(|s| s.ready),
        None => state.stations.values().all(|s| s.ready),
    }
}

/// The station whose bucket `stream` is, if it is one.
fn station_of_stream(stream: &str) -> Option<&str> {
    stream
        .strip_prefix("OBJ_")
        .and_then(|b| b.strip_prefix(BUCKET_PREFIX))
        .filter(|s| super::check_station_name(s).is_ok())
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    fn listing(limits: ListingLimits) -> ArchiveListing {
        ArchiveListing::empty(limits, Availability::Following)
    }

    /// A station's bucket being read (reading `epoch`), with nothing listed yet.
    fn add(listing: &ArchiveListing, station: &str, epoch: u64) {
        lock(&listing.state).stations.insert(
            station.to_owned(),
            Station {
                ready: false,
                files: BTreeMap::new(),
                omitted: 0,
                epoch,
                task: None,
            },
        );
    }

    fn meta(name: &str, deleted: bool) -> ObjectInfo {
        serde_json::from_value(serde_json::json!({
            "name": name, "bucket": "b", "nuid": "n", "size": 10, "chunks": 1,
            "digest": "SHA-256=x", "deleted": deleted,
        }))
        .unwrap()
    }

    fn shown(listing: &ArchiveListing, station: Option<&str>) -> serde_json::Value {
        let json = listing.render(&mut lock(&listing.state), station).unwrap();
        serde_json::from_slice(&json).unwrap()
    }

    fn files(value: &serde_json::Value) -> Vec<String> {
        value["archive"]
            .as_array()
            .unwrap()
            .iter()
            .map(|a| {
                format!(
                    "{}/{}",
                    a["station"].as_str().unwrap(),
                    a["file"].as_str().unwrap()
                )
            })
            .collect()
    }

    #[test]
    fn beyond_the_caps_recordings_are_counted_not_listed_and_a_deletion_reads_again() {
        let l = listing(ListingLimits {
            max_stations: 8,
            max_per_station: 2,
            max_total: 3,
        });
        add(&l, "a", 1);
        add(&l, "b", 2);
        // Named for another station, with no file name, not a meta at all: skipped.
        for m in [meta("b/x.mcap", false), meta("a/", false)] {
            assert!(!l.apply("a", 1, Some(&m), false));
        }
        assert!(!l.apply("a", 1, None, false));
        for f in ["a/1.mcap", "a/2.mcap", "a/3.mcap"] {
            assert!(!l.apply("a", 1, Some(&meta(f, false)), false));
        }
        // Read back to its end: "a" is whole, "b" is not yet, and says so.
        assert!(!l.apply("a", 1, Some(&meta("a/1.mcap", false)), true));
        let all = shown(&l, None);
        assert_eq!(files(&all), ["a/1.mcap", "a/2.mcap"]);
        assert_eq!(all["omitted"], 1);
        assert_eq!(all["unavailable"], serde_json::json!(["b"]));
        assert!(whole(&lock(&l.state), Some("a")) && !whole(&lock(&l.state), None));
        // The total cap: "b" lists one of its two.
        assert!(!l.apply("b", 2, Some(&meta("b/1.mcap", false)), false));
        assert!(!l.apply("b", 2, Some(&meta("b/2.mcap", false)), true));
        assert_eq!(files(&shown(&l, Some("b"))), ["b/1.mcap"]);
        assert_eq!(shown(&l, None)["omitted"], 2);
        // What an earlier reading of a bucket says is ignored.
        assert!(!l.apply("b", 1, Some(&meta("b/9.mcap", true)), true));
        // Deleted live where some were omitted: gone, and the bucket is read again.
        assert!(l.apply("a", 1, Some(&meta("a/2.mcap", true)), true));
        assert_eq!(files(&shown(&l, Some("a"))), ["a/1.mcap"]);
        l.begin("a", 1, false);
        assert_eq!(lock(&l.state).total, 1);
        assert_eq!(shown(&l, None)["unavailable"], serde_json::json!(["a"]));
    }
}
