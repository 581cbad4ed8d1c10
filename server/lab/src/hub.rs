//! `softhaptic hub`: the lab's page for instructors, relaying any station from NATS.
//!
//! One file because the station list, the per-station feeds and the routes that serve them share
//! one lifecycle: a feed lives as long as its station's session and its viewers with it.
//!
//! The hub keeps the stations' last heartbeats (a station not heard from for
//! [`super::OFFLINE_AFTER`] is offline) and, for each station a viewer opens, one
//! `Feed`: the station's session fetched once (its `hello` and `scene`), a
//! [`StreamHub`] of the hub's own fed by one NATS subscription to the station's frames and
//! stats. Viewers then connect to that stream hub exactly as they would to the station's, with
//! the hub's access rules (tokens, Origin, Host, TLS): the same wire, the same roles, but no
//! marks: their `hello` says `accepts_marks: false` and an `add_mark` is refused, since a mark
//! made here would be stamped with no station time and recorded nowhere. A feed
//! lives as long as its station's session; a station that restarts (a new session id) gets a
//! new feed, and the old one's viewers are closed, so they reconnect to the new session. An
//! archived recording's replay (`&archive=FILE`) is opened for its first viewer and closed when
//! its last viewer leaves; its decoded recording is kept by [`super::replays`] (bounded in
//! bytes, expired when unused), and HTTP serves a replay's scene and meshes only while it is
//! open, so no request loads one without a viewer. Only an instructor opens one, lists the archive or downloads a file
//! from it; an observer watches the replays an instructor has open ([`crate::access::roles`],
//! docs/roles.md), and is refused before anything is looked up.
//!
//! What a client without a valid token learns: nothing. `/ws` checks the `Origin` (and the guard
//! every request passes, the `Host`) before anything else, and looks the station or the
//! recording up only once the viewer has its role, so a page of another site or a client
//! without a token makes the hub relay or fetch nothing and is refused alike whether what it
//! names exists or not. A station or a recording that is not there is one answer (404 over
//! HTTP, close 4404 over WebSocket), and no refusal carries the hub's internal errors (NATS's,
//! the recording reader's): those are logged.
//!
//! The archive's list (`/api/archive`, instructors only) is answered from memory:
//! [`super::listing`] keeps it from the object store's change feed, so the pages asking for it
//! make no request to NATS.
//!
//! Routes: the viewer's files; `/api/stations` (the station list), `/api/scene?station=NAME`,
//! `/stations/NAME/meshes/FILE` (the station's render meshes, fetched over NATS once) and
//! `/ws?station=NAME`. The session data needs a token when the hub has tokens, as on a station.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::Extension;
use axum::Router;
use axum::body::Bytes;
use axum::extract::ws::{Utf8Bytes, WebSocketUpgrade};
use axum::extract::{ConnectInfo, Path as UrlPath, Query, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use futures_util::StreamExt;
use serde::{Deserialize, Serialize};
use softhaptic_proto::wire::{
    DashboardMessage, DashboardStation, Hello, Mode, PROTOCOL_VERSION, Role, ServerMessage,
};
use tokio::sync::watch;
use tokio::task::JoinHandle;

use super::dashboard::{DASHBOARD_PERIOD, DashboardCounters, DashboardHub};
use super::{
    LabError, MeshRequest, NatsOptions, OFFLINE_AFTER, STATUS_SUBJECTS, StationSession,
    StationState, StationStatus, Subjects,
};
use crate::access::roles::{Action, may};
use crate::access::{self, Access, AccessConfig, Connection};
use crate::routes::SERVER_NAME;
use crate::stream::{EncodedFrame, StreamCounters, StreamHub, ViewerEnd, ViewerLimits};

/// How to run a hub.
pub struct HubOptions {
    pub nats: NatsOptions,
    pub addr: SocketAddr,
    /// The viewer's files (built in, or `--web-dir`).
    pub viewer: crate::viewer::Viewer,
    pub access: AccessConfig,
    pub tls: Option<Arc<rustls::ServerConfig>>,
    pub viewer_limits: ViewerLimits,
    /// How much of the archive the hub keeps decoded for replays.
    pub replay_cache: super::replays::ReplayCacheLimits,
    /// How much of the archive the hub lists.
    pub archive_listing: super::listing::ListingLimits,
}

/// Why a hub did not start.
#[derive(Debug, thiserror::Error)]
pub enum HubError {
    #[error(transparent)]
    Lab(#[from] LabError),
    #[error(transparent)]
    Access(#[from] access::AccessError),
    #[error(transparent)]
    Viewer(#[from] crate::viewer::ViewerError),
    #[error("could not listen on {addr}: {source}")]
    Bind {
        addr: SocketAddr,
        #[source]
        source: std::io::Error,
    },
}

/// A running hub.
pub struct RunningHub {
    local_addr: SocketAddr,
    shutdown_tx: watch::Sender<bool>,
    http: JoinHandle<()>,
    tasks: Vec<JoinHandle<()>>,
    lab: Arc<Lab>,
    tls: bool,
}

impl RunningHub {
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// The page's URL.
    pub fn viewer_url(&self) -> String {
        let scheme = if self.tls { "https" } else { "http" };
        format!("{scheme}://{}/", self.local_addr)
    }

    /// The stations as the hub lists them now.
    pub fn stations(&self) -> Vec<StationListing> {
        self.lab.listing()
    }

    /// The stations the hub relays now (a station is relayed from its first authenticated
    /// viewer, or its first request with a token, on).
    pub fn relayed_stations(&self) -> Vec<String> {
        let mut names: Vec<String> = lock(&self.lab.stations)
            .iter()
            .filter(|(_, e)| e.feed.is_some())
            .map(|(name, _)| name.clone())
            .collect();
        names.sort();
        names
    }

    /// The archived recordings being replayed now (`STATION/FILE`): one is fetched for its
    /// first viewer and dropped when its last viewer leaves.
    pub fn replayed_recordings(&self) -> Vec<String> {
        let mut keys: Vec<String> = lock(&self.lab.archives).keys().cloned().collect();
        keys.sort();
        keys
    }

    /// The archived recordings decoded and kept for replays now (open or not, until they
    /// expire), by `STATION/FILE`, with the bytes each is counted for.
    pub fn cached_recordings(&self) -> Vec<(String, u64)> {
        self.lab.replays.cached()
    }

    /// JetStream consumers the hub made to list the archive since the start: one per station's
    /// bucket, read once and then followed ([`super::listing`]), however many pages ask.
    pub fn archive_consumers(&self) -> u64 {
        self.lab.archive.consumers_made()
    }

    /// Times the hub listed the archive's buckets since the start (once, and once per
    /// reconnection to NATS).
    pub fn archive_bucket_listings(&self) -> u64 {
        self.lab.archive.bucket_listings()
    }

    /// Archived recordings fetched and decoded since the start.
    pub fn recording_loads(&self) -> u64 {
        self.lab.replays.loads()
    }

    /// What happened to the connections that had no stream yet: refused for their token, by a
    /// limit, or for a message (the counters of each stream count the rest).
    /// What the dashboard pages cost (pages open, messages made, bytes sent, actions).
    pub fn dashboard_counters(&self) -> &DashboardCounters {
        &self.lab.dashboard.counters
    }

    pub fn gate_counters(&self) -> &StreamCounters {
        &self.lab.gate
    }

    /// Closes every viewer and stops.
    pub async fn shutdown(self) {
        let _ = self.shutdown_tx.send(true);
        self.lab.close_feeds();
        self.lab.archive.stop();
        let _ = self.http.await;
        for t in self.tasks {
            t.abort();
        }
    }
}

/// A station as `/api/stations` lists it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StationListing {
    pub name: String,
    pub session_id: String,
    pub scene: String,
    /// `live`, `idle` or `offline`.
    pub state: String,
    /// Since when: Unix milliseconds (for `offline`, its last heartbeat).
    pub since_unix_ms: u64,
    pub viewers: u32,
    pub unpublished_frames: u64,
    /// The hub's own viewers of it.
    pub hub_viewers: u32,
}

/// `/api/stations`: `hub` true, and the stations. A station answers it too, with `hub` false
/// and no stations, so the page learns which it is talking to.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StationList {
    pub hub: bool,
    pub stations: Vec<StationListing>,
}

struct Entry {
    status: StationStatus,
    seen: Instant,
    seen_unix_ms: u64,
    feed: Option<Arc<Feed>>,
}

/// One station relayed: its session and the stream hub its viewers here connect to.
struct Feed {
    session_id: String,
    hub: Arc<StreamHub>,
    scene_json: Bytes,
    meshes: tokio::sync::Mutex<HashMap<String, Bytes>>,
    stop: watch::Sender<bool>,
    relay: JoinHandle<()>,
}

impl Drop for Feed {
    fn drop(&mut self) {
        let _ = self.stop.send(true);
        self.relay.abort();
    }
}

/// An archived recording replayed for the hub's viewers (one replay per recording, shared by
/// its viewers as on a replay server: the instructor's controls move it for everyone).
struct ArchiveFeed {
    /// Its recording, held from the replays' cache: while the replay is open it is not evicted.
    _recording: Arc<crate::session::reader::Recording>,
    hub: Arc<StreamHub>,
    scene_json: Bytes,
    meshes: HashMap<String, Bytes>,
    stop: watch::Sender<bool>,
    player: JoinHandle<()>,
    /// The WebSocket viewers using it (changed with the archives' lock held).
    viewers: std::sync::atomic::AtomicUsize,
}

/// A WebSocket viewer's use of an archived recording's replay: the replay is dropped (its
/// recording's memory given back) when the last one ends.
struct ArchiveViewer {
    lab: Arc<Lab>,
    key: String,
    feed: Arc<ArchiveFeed>,
}

impl Drop for ArchiveViewer {
    fn drop(&mut self) {
        use std::sync::atomic::Ordering;
        let mut archives = lock(&self.lab.archives);
        if self.feed.viewers.fetch_sub(1, Ordering::Relaxed) == 1
            && archives
                .get(&self.key)
                .is_some_and(|f| Arc::ptr_eq(f, &self.feed))
        {
            archives.remove(&self.key);
            // Its recording stays in the cache until it expires or another needs the room.
            self.lab.replays.touch(&self.key);
            tracing::info!(recording = %self.key, "its last viewer left: the replay is closed");
        }
    }
}

impl Drop for ArchiveFeed {
    fn drop(&mut self) {
        let _ = self.stop.send(true);
        self.player.abort();
    }
}

/// The hub's shared state.
struct Lab {
    client: async_nats::Client,
    stations: Mutex<HashMap<String, Entry>>,
    /// Archived recordings being replayed, by `STATION/FILE`.
    archives: Mutex<HashMap<String, Arc<ArchiveFeed>>>,
    /// Held while a feed is made, so two first viewers make one.
    making: tokio::sync::Mutex<()>,
    /// The archived recordings decoded for replays (bounded in bytes, expired when unused).
    replays: super::replays::ReplayCache,
    /// The archive's listing, kept from the object store's change feed: what every page asks
    /// for every 2 s, answered from memory.
    archive: Arc<super::listing::ArchiveListing>,
    access: Arc<Access>,
    limits: ViewerLimits,
    /// The hub's shutdown, for the connections that have no stream yet.
    shutdown: watch::Receiver<bool>,
    /// The refusals of connections that have no stream yet.
    gate: StreamCounters,
    /// The dashboard pages' shared message, and the actions they send to stations.
    dashboard: Arc<DashboardHub>,
}

/// A refusal: its status and why, in detail. The detail is for the hub's log only (it can hold
/// NATS's and the recording reader's errors): a client gets [`public_reason`].
type Refusal = (StatusCode, String);

/// What a client is told of a refusal: one answer for every station or recording that is not
/// there (whatever the reason, so none tells what exists), none of the hub's internal errors.
fn public_reason(status: StatusCode) -> &'static str {
    match status {
        StatusCode::NOT_FOUND => NOT_FOUND,
        StatusCode::SERVICE_UNAVAILABLE => "the station is offline",
        StatusCode::BAD_GATEWAY => "the station or the archive did not answer",
        StatusCode::UNPROCESSABLE_ENTITY => "the recording could not be replayed",
        StatusCode::FORBIDDEN => Action::OpenReplay.observer_refusal(),
        StatusCode::TOO_MANY_REQUESTS => REPLAYS_FULL,
        _ => "internal error",
    }
}

/// The answer to a replay the hub has no room for (its replays' memory is full of open ones).
pub const REPLAYS_FULL: &str =
    "the hub has as many replays open as it can hold: try again when one closes";
/// The answer to every station, recording or mesh that is not there.
const NOT_FOUND: &str = "no such station or recording";
/// Close code of a hub viewer's connection whose station or recording is not there (4000–4999
/// are the application's; 4404 echoes HTTP's 404).
pub const CLOSE_NOT_FOUND: u16 = 4404;
/// Close code of a hub viewer's connection whose station is offline or did not answer (1013:
/// try again later).
const CLOSE_TRY_LATER: u16 = 1013;

/// The HTTP answer to a refusal; its detail is logged.
fn refused(what: &str, (status, detail): Refusal) -> Response {
    tracing::info!(%what, %status, "refused: {detail}");
    access::json_error(status, public_reason(status))
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Lab {
    fn listing(&self) -> Vec<StationListing> {
        let stations = lock(&self.stations);
        let mut out: Vec<StationListing> = stations
            .values()
            .map(|e| {
                let offline = e.seen.elapsed() > OFFLINE_AFTER;
                StationListing {
                    name: e.status.name.clone(),
                    session_id: e.status.session_id.clone(),
                    scene: e.status.scene.clone(),
                    state: if offline {
                        "offline".into()
                    } else {
                        match e.status.state {
                            StationState::Live => "live".into(),
                            StationState::Idle => "idle".into(),
                        }
                    },
                    since_unix_ms: if offline {
                        e.seen_unix_ms
                    } else {
                        e.status.since_unix_ms
                    },
                    viewers: e.status.viewers,
                    unpublished_frames: e.status.unpublished_frames,
                    hub_viewers: e.feed.as_ref().map_or(0, |f| {
                        f.hub
                            .counters
                            .viewers
                            .load(std::sync::atomic::Ordering::Relaxed)
                    }),
                }
            })
            .collect();
        out.sort_by(|a, b| a.name.cmp(&b.name));
        out
    }

    /// Every station's tile, in the list's order: the listing with each station's latest
    /// summary (none once it is offline: an old summary would show a trainee who has left).
    fn dashboard_message(&self) -> DashboardMessage {
        let listing = self.listing();
        let stations = lock(&self.stations);
        let stations = listing
            .into_iter()
            .map(|l| {
                let summary = (l.state != "offline")
                    .then(|| stations.get(&l.name).and_then(|e| e.status.summary.clone()))
                    .flatten();
                DashboardStation {
                    name: l.name,
                    scene: l.scene,
                    state: l.state,
                    viewers: l.viewers,
                    hub_viewers: l.hub_viewers,
                    summary,
                }
            })
            .collect();
        DashboardMessage {
            time_unix_ms: super::unix_ms(),
            stations,
        }
    }

    fn close_feeds(&self) {
        for e in lock(&self.stations).values_mut() {
            e.feed = None;
        }
        // A replay's viewers hold it too (to drop it after the last): stop it for them.
        for feed in lock(&self.archives).drain().map(|(_, feed)| feed) {
            let _ = feed.stop.send(true);
        }
    }

    /// The replay of an archived recording that a viewer has open now: what an observer may
    /// watch, and what the replay's scene and meshes are served from over HTTP (which never
    /// loads one: replays are loaded for connected viewers only). Refused before anything is
    /// looked up beyond what is open: an observer with 403 whether the recording exists or not,
    /// an instructor with the 404 of anything not there.
    fn open_replay(
        &self,
        station: &str,
        file: &str,
        role: Role,
    ) -> Result<Arc<ArchiveFeed>, Refusal> {
        let key = super::archive::object_name(station, file);
        let open = lock(&self.archives)
            .get(&key)
            .filter(|f| f.viewers.load(std::sync::atomic::Ordering::Relaxed) > 0)
            .cloned();
        open.ok_or_else(|| {
            if may(role, Action::OpenReplay) {
                (
                    StatusCode::NOT_FOUND,
                    format!("{key}: no viewer has its replay open"),
                )
            } else {
                (
                    StatusCode::FORBIDDEN,
                    format!("{key}: not open, and an observer may not open a replay"),
                )
            }
        })
    }

    /// The replay of an archived recording for an instructor's viewer, opened (paused) if it is
    /// not open: its recording from the replays' cache, loaded when it is not there (one load
    /// for all who ask at once).
    async fn archive_feed(&self, station: &str, file: &str) -> Result<Arc<ArchiveFeed>, Refusal> {
        super::check_station_name(station).map_err(|e| (StatusCode::NOT_FOUND, e))?;
        if file.contains('/') || !file.ends_with(".mcap") {
            return Err((
                StatusCode::NOT_FOUND,
                format!("no archived recording {file:?}"),
            ));
        }
        let key = super::archive::object_name(station, file);
        if let Some(feed) = lock(&self.archives).get(&key) {
            return Ok(Arc::clone(feed));
        }
        let client = &self.client;
        let max_file_bytes = self.replays.limits().max_bytes;
        let recording = self
            .replays
            .get_or_load(&key, || async {
                let bytes = super::archive::fetch(client, station, file, max_file_bytes)
                    .await
                    .map_err(|e| {
                        (
                            StatusCode::NOT_FOUND,
                            format!("archived recording {key}: {e}"),
                        )
                    })?;
                crate::session::reader::Recording::from_bytes(std::path::Path::new(&key), &bytes)
                    .map_err(|e| (StatusCode::UNPROCESSABLE_ENTITY, e.to_string()))
            })
            .await?;
        let (stop, stop_rx) = watch::channel(false);
        let prefix = format!("/stations/{station}/archive/{file}/meshes");
        let feed = crate::session::replay::replay_feed(
            &recording,
            1.0,
            true,
            self.limits,
            Arc::clone(&self.access),
            stop_rx,
            Some(&prefix),
        )
        .map_err(|e| (StatusCode::UNPROCESSABLE_ENTITY, e.to_string()))?;
        let archive = Arc::new(ArchiveFeed {
            _recording: recording,
            hub: feed.hub,
            scene_json: Bytes::from(feed.scene_text),
            meshes: feed.meshes,
            stop,
            player: feed.player,
            viewers: std::sync::atomic::AtomicUsize::new(0),
        });
        // Another viewer may have opened it meanwhile: theirs is the replay (this one's player
        // stops as it is dropped).
        let mut archives = lock(&self.archives);
        let open = archives.entry(key.clone()).or_insert_with(|| {
            tracing::info!(recording = %key, "replaying an archived recording");
            Arc::clone(&archive)
        });
        Ok(Arc::clone(open))
    }

    /// The stream a viewer names (a station's, or its archived recording's replay), looked up
    /// (and made) for a viewer that has its role; with the viewer's use of a replay, held for as
    /// long as the viewer is served.
    async fn viewer_stream(
        self: &Arc<Self>,
        station: &str,
        archive: Option<&str>,
        role: Role,
    ) -> Result<(Arc<StreamHub>, Option<ArchiveViewer>), Refusal> {
        let Some(file) = archive else {
            return Ok((Arc::clone(&self.feed(station).await?.hub), None));
        };
        loop {
            // An observer joins a replay an instructor has open, and makes the hub fetch nothing.
            let feed = if may(role, Action::OpenReplay) {
                self.archive_feed(station, file).await?
            } else {
                self.open_replay(station, file, role)?
            };
            let key = super::archive::object_name(station, file);
            let archives = lock(&self.archives);
            // Dropped meanwhile by its last viewer's leaving: fetch it again.
            if !archives.get(&key).is_some_and(|f| Arc::ptr_eq(f, &feed)) {
                continue;
            }
            feed.viewers
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            drop(archives);
            let hub = Arc::clone(&feed.hub);
            let viewer = ArchiveViewer {
                lab: Arc::clone(self),
                key,
                feed,
            };
            return Ok((hub, Some(viewer)));
        }
    }

    /// The station's feed, made on first use (or again for a new session of the station).
    async fn feed(self: &Arc<Self>, name: &str) -> Result<Arc<Feed>, (StatusCode, String)> {
        let current = || -> Result<(StationStatus, Option<Arc<Feed>>), Refusal> {
            let stations = lock(&self.stations);
            let e = stations.get(name).ok_or_else(|| {
                (
                    StatusCode::NOT_FOUND,
                    format!("no station {name:?} has been heard from"),
                )
            })?;
            if e.seen.elapsed() > OFFLINE_AFTER {
                return Err((
                    StatusCode::SERVICE_UNAVAILABLE,
                    format!("station {name:?} is offline"),
                ));
            }
            let feed = e
                .feed
                .as_ref()
                .filter(|f| f.session_id == e.status.session_id)
                .cloned();
            Ok((e.status.clone(), feed))
        };
        if let (_, Some(feed)) = current()? {
            return Ok(feed);
        }
        let _making = self.making.lock().await;
        let (status, feed) = current()?;
        if let Some(feed) = feed {
            return Ok(feed);
        }
        let feed = Arc::new(self.make_feed(name, &status).await?);
        if let Some(e) = lock(&self.stations).get_mut(name) {
            // The old session's viewers are closed (the feed's drop): they reconnect to this one.
            e.feed = Some(Arc::clone(&feed));
        }
        Ok(feed)
    }

    async fn make_feed(
        &self,
        name: &str,
        status: &StationStatus,
    ) -> Result<Feed, (StatusCode, String)> {
        let subjects = Subjects::of(name);
        let unavailable = |what: String| (StatusCode::BAD_GATEWAY, what);
        // Subscribed before asking where things stand, so that nothing said meanwhile is missed
        // (what is told twice is told the same).
        let subscribe = |subject: &String| {
            let subject = subject.clone();
            async {
                self.client
                    .subscribe(subject)
                    .await
                    .map_err(|e| unavailable(e.to_string()))
            }
        };
        let events = StationEvents {
            exercise: subscribe(&subjects.exercise).await?,
            marks: subscribe(&subjects.marks).await?,
            inclusions: subscribe(&subjects.inclusions).await?,
        };
        let reply = tokio::time::timeout(
            Duration::from_secs(5),
            self.client.request(subjects.session.clone(), Bytes::new()),
        )
        .await
        .map_err(|_| unavailable(format!("station {name:?} did not answer")))?
        .map_err(|e| unavailable(format!("station {name:?}: {e}")))?;
        let session: StationSession = serde_json::from_slice(&reply.payload)
            .map_err(|e| unavailable(format!("station {name:?} answered nonsense: {e}")))?;
        let scene_text = rewrite_mesh_urls(&session.scene, &format!("/stations/{name}/meshes"))
            .map_err(|e| {
                unavailable(format!(
                    "station {name:?} sent a scene that is not one: {e}"
                ))
            })?;
        let hello = Hello {
            protocol_version: PROTOCOL_VERSION,
            session_id: session.session_id.clone(),
            role: Role::Instructor,
            mode: Mode::Live,
            server: SERVER_NAME.into(),
            force_feedback: session.force_feedback,
            // The hub relays a station's frames: it knows neither the station's device time (a
            // mark's stamp) nor its recording (where a mark is kept), so it takes no marks, and
            // the viewer hides its control; an `add_mark` is refused.
            accepts_marks: false,
        };
        let (stop, stop_rx) = watch::channel(false);
        let hub = Arc::new(
            StreamHub::new(
                &hello,
                Utf8Bytes::from(scene_text.clone()),
                self.limits,
                stop_rx.clone(),
                None,
                Arc::clone(&self.access),
            )
            .map_err(|e| unavailable(e.to_string()))?,
        );
        let contact = subscribe(&subjects.contact).await?;
        let stats = subscribe(&subjects.stats).await?;
        // Where the exercise, marks and inclusions stand, as the station's viewers are told.
        if let Some(text) = &session.exercise {
            relay_event(name, &hub, EventKind::Exercise, text.as_bytes());
        }
        for text in &session.marks {
            relay_event(name, &hub, EventKind::Mark, text.as_bytes());
        }
        if let Ok(json) = serde_json::to_vec(&session.inclusions) {
            relay_event(name, &hub, EventKind::Inclusions, &json);
        }
        let relay = tokio::spawn(relay(
            name.to_owned(),
            contact,
            stats,
            events,
            Arc::clone(&hub),
            stop_rx,
        ));
        tracing::info!(
            station = name,
            session = %status.session_id,
            "relaying the station"
        );
        Ok(Feed {
            session_id: session.session_id,
            hub,
            scene_json: Bytes::from(scene_text),
            meshes: tokio::sync::Mutex::new(HashMap::new()),
            stop,
            relay,
        })
    }

    /// A render mesh of the station, fetched over NATS piece by piece once, then kept.
    async fn mesh(
        &self,
        name: &str,
        feed: &Feed,
        mesh: &str,
    ) -> Result<Bytes, (StatusCode, String)> {
        let mut cache = feed.meshes.lock().await;
        if let Some(bytes) = cache.get(mesh) {
            return Ok(bytes.clone());
        }
        let subjects = Subjects::of(name);
        let mut out: Vec<u8> = Vec::new();
        loop {
            let request = serde_json::to_vec(&MeshRequest {
                name: mesh.to_owned(),
                offset: out.len() as u64,
            })
            .map_err(|e| (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
            let reply = tokio::time::timeout(
                Duration::from_secs(10),
                self.client
                    .request(subjects.mesh.clone(), Bytes::from(request)),
            )
            .await
            .map_err(|_| {
                (
                    StatusCode::BAD_GATEWAY,
                    format!("station {name:?} did not send the mesh"),
                )
            })?
            .map_err(|e| (StatusCode::BAD_GATEWAY, e.to_string()))?;
            let p = &reply.payload;
            if p.len() < 8 {
                return Err((StatusCode::NOT_FOUND, format!("no render mesh {mesh:?}")));
            }
            let total = u64::from_le_bytes(p[..8].try_into().unwrap_or([0; 8]));
            if total > crate::files::FileKind::Mesh.max_bytes() {
                return Err((StatusCode::BAD_GATEWAY, format!("a mesh of {total} bytes")));
            }
            out.extend_from_slice(&p[8..]);
            if out.len() as u64 >= total || p.len() == 8 {
                break;
            }
        }
        let bytes = Bytes::from(out);
        cache.insert(mesh.to_owned(), bytes.clone());
        Ok(bytes)
    }
}

/// A station's scene with its meshes' URLs under `prefix` on this hub. What comes from NATS is
/// outside input: it must decode as a `scene` message of the wire (proto/WIRE.md) before it is
/// touched or passed on to a viewer.
fn rewrite_mesh_urls(scene: &str, prefix: &str) -> Result<String, String> {
    match ServerMessage::decode(scene) {
        Ok(ServerMessage::Scene(_)) => {}
        Ok(other) => return Err(format!("a {} message, not a scene", other.type_name())),
        Err(e) => return Err(e.to_string()),
    }
    let mut value: serde_json::Value = serde_json::from_str(scene).map_err(|e| e.to_string())?;
    if let Some(meshes) = value
        .get_mut("render_meshes")
        .and_then(|m| m.as_array_mut())
    {
        for m in meshes {
            let Some(mesh) = m.as_object_mut() else {
                return Err("a render mesh that is not an object".to_owned());
            };
            let name = mesh
                .get("name")
                .and_then(|n| n.as_str())
                .unwrap_or_default()
                .to_owned();
            mesh.insert(
                "url".to_owned(),
                serde_json::Value::String(format!("{prefix}/{name}.bin")),
            );
        }
    }
    serde_json::to_string(&value).map_err(|e| e.to_string())
}

/// What of a message from a station's stats subject goes to viewers: the 1 Hz messages a
/// station sends there (`stats`, `metrics`), decoded as the wire's and encoded again (nothing a
/// station padded them with is passed on); anything else, however it got onto the subject,
/// would make every viewer drop its connection as malformed.
fn relayable_stats(text: &str) -> Result<String, String> {
    match ServerMessage::decode(text) {
        Ok(m @ (ServerMessage::Stats(_) | ServerMessage::Metrics(_))) => {
            m.encode().map_err(|e| e.to_string())
        }
        Ok(other) => Err(format!("a {} message", other.type_name())),
        Err(e) => Err(e.to_string()),
    }
}

/// A station's subscriptions besides its frames and stats: its exercise, marks and inclusions.
struct StationEvents {
    exercise: async_nats::Subscriber,
    marks: async_nats::Subscriber,
    inclusions: async_nats::Subscriber,
}

#[derive(Debug, Clone, Copy)]
enum EventKind {
    Exercise,
    Mark,
    Inclusions,
}

/// The largest exercise, mark or inclusions message taken from a station, bytes (an exercise
/// with a long traced path is a few tens of kilobytes).
const MAX_EVENT_BYTES: usize = 256 << 10;
/// Exercise, mark and inclusions messages a second relayed from one station at most (it sends
/// about one, and a mark when an instructor makes one).
const MAX_EVENTS_PER_S: f64 = 20.0;

/// One of a station's exercise, mark or inclusions messages into the feed's stream hub: decoded
/// as the wire's and encoded again; an `inclusions` message only where the station would put it
/// (an answer before the end never among the public ones). Refusals are logged.
fn relay_event(station: &str, hub: &StreamHub, kind: EventKind, payload: &[u8]) -> bool {
    match checked_event(hub, kind, payload) {
        Ok(()) => true,
        Err(e) => {
            tracing::warn!(station, "a {kind:?} message that is not one: {e}");
            false
        }
    }
}

fn checked_event(hub: &StreamHub, kind: EventKind, payload: &[u8]) -> Result<(), String> {
    if payload.len() > MAX_EVENT_BYTES {
        return Err(format!("{} bytes, over {MAX_EVENT_BYTES}", payload.len()));
    }
    let text = std::str::from_utf8(payload).map_err(|e| e.to_string())?;
    match kind {
        EventKind::Exercise => match ServerMessage::decode(text).map_err(|e| e.to_string())? {
            m @ ServerMessage::Exercise(_) => {
                hub.exercise
                    .publish(Utf8Bytes::from(m.encode().map_err(|e| e.to_string())?));
                Ok(())
            }
            other => Err(format!("a {} message", other.type_name())),
        },
        EventKind::Mark => match ServerMessage::decode(text).map_err(|e| e.to_string())? {
            ServerMessage::Mark(mark) => {
                hub.relay_mark(&mark).map(|_| ()).map_err(|e| e.to_string())
            }
            other => Err(format!("a {} message", other.type_name())),
        },
        EventKind::Inclusions => {
            let state: super::InclusionsState =
                serde_json::from_str(text).map_err(|e| e.to_string())?;
            let hidden = checked_inclusions(state.hidden.as_deref(), false)?;
            let public = checked_inclusions(state.public.as_deref(), true)?;
            hub.inclusions.mirror(hidden, public);
            Ok(())
        }
    }
}

/// An `inclusions` message re-encoded, refused unless its `revealed` is `revealed`.
fn checked_inclusions(text: Option<&str>, revealed: bool) -> Result<Option<Utf8Bytes>, String> {
    let Some(text) = text else { return Ok(None) };
    match ServerMessage::decode(text).map_err(|e| e.to_string())? {
        ServerMessage::Inclusions(m) if m.revealed == revealed => {
            let m = ServerMessage::Inclusions(m);
            Ok(Some(Utf8Bytes::from(
                m.encode().map_err(|e| e.to_string())?,
            )))
        }
        ServerMessage::Inclusions(_) => Err(format!(
            "an answer with revealed: {} where only revealed: {revealed} goes",
            !revealed
        )),
        other => Err(format!("a {} message", other.type_name())),
    }
}

/// Frames a second relayed from one station at most (it sends 50).
const MAX_FRAMES_PER_S: f64 = 100.0;
/// Stats and metrics messages a second relayed from one station at most (it sends 2).
const MAX_STATS_PER_S: f64 = 10.0;

/// The station's frames and stats from NATS into the feed's stream hub: each decoded and
/// encoded again (nothing a station padded them with is passed on), at most
/// [`MAX_FRAMES_PER_S`] and [`MAX_STATS_PER_S`].
async fn relay(
    name: String,
    mut contact: async_nats::Subscriber,
    mut stats: async_nats::Subscriber,
    mut events: StationEvents,
    hub: Arc<StreamHub>,
    mut stop: watch::Receiver<bool>,
) {
    let mut refused = 0u64;
    // A station sends 50 frames and 2 stats or metrics messages a second; one sending far more
    // (a broken or rogue publisher) is cut to this for the hub's viewers.
    let cap = |per_s: f64| {
        access::MessageRate::new(
            &access::ConnectionLimits {
                messages_per_s: per_s,
                message_burst: per_s,
                ..access::ConnectionLimits::default()
            },
            std::time::Instant::now(),
        )
    };
    let (mut frame_rate, mut stats_rate) = (cap(MAX_FRAMES_PER_S), cap(MAX_STATS_PER_S));
    let mut event_rate = cap(MAX_EVENTS_PER_S);
    loop {
        let event = tokio::select! {
            _ = stop.changed() => break,
            m = events.exercise.next() => match m { Some(m) => Some((EventKind::Exercise, m)), None => break },
            m = events.marks.next() => match m { Some(m) => Some((EventKind::Mark, m)), None => break },
            m = events.inclusions.next() => match m { Some(m) => Some((EventKind::Inclusions, m)), None => break },
            m = contact.next() => {
                let Some(m) = m else { break };
                if !frame_rate.allow(std::time::Instant::now()) {
                    refused += 1;
                    if refused == 1 || refused.is_power_of_two() {
                        tracing::warn!(station = %name, "frames faster than {MAX_FRAMES_PER_S} a second are not relayed ({refused} refused so far)");
                    }
                    continue;
                }
                match String::from_utf8(m.payload.to_vec()).map_err(|e| e.to_string()).and_then(EncodedFrame::from_text) {
                    Ok(frame) => {
                        let _ = hub.frames.send(Arc::new(frame));
                        hub.counters.frames_sent.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    }
                    Err(e) => {
                        refused += 1;
                        if refused == 1 || refused.is_power_of_two() {
                            tracing::warn!(station = %name, "a frame that is not one ({refused} so far): {e}");
                        }
                    }
                }
                None
            }
            m = stats.next() => {
                let Some(m) = m else { break };
                if !stats_rate.allow(std::time::Instant::now()) {
                    refused += 1;
                    continue;
                }
                let checked = String::from_utf8(m.payload.to_vec())
                    .map_err(|e| e.to_string())
                    .and_then(|text| relayable_stats(&text));
                match checked {
                    Ok(text) => {
                        let _ = hub.stats.send(Utf8Bytes::from(text));
                    }
                    Err(e) => {
                        refused += 1;
                        if refused == 1 || refused.is_power_of_two() {
                            tracing::warn!(station = %name, "a stats message that is not one ({refused} so far): {e}");
                        }
                    }
                }
                None
            }
        };
        let Some((kind, m)) = event else { continue };
        if !event_rate.allow(std::time::Instant::now())
            || !relay_event(&name, &hub, kind, &m.payload)
        {
            refused += 1;
        }
    }
}

/// The stations' heartbeats into the list.
async fn follow_stations(lab: Arc<Lab>, mut status: async_nats::Subscriber) {
    let mut turned_away = 0u64;
    while let Some(m) = status.next().await {
        // A station's heartbeat is a few hundred bytes; what is far larger is not one, and would
        // be kept and served by every hub.
        if m.payload.len() > MAX_HEARTBEAT_BYTES {
            continue;
        }
        let Ok(s) = serde_json::from_slice::<StationStatus>(&m.payload) else {
            continue;
        };
        // A station speaks for itself only.
        if m.subject.as_str() != Subjects::of(&s.name).status
            || super::check_station_name(&s.name).is_err()
        {
            continue;
        }
        let mut stations = lock(&lab.stations);
        let name = s.name.clone();
        match stations.get_mut(&name) {
            Some(e) => {
                e.status = s;
                e.seen = Instant::now();
                e.seen_unix_ms = super::unix_ms();
            }
            None => {
                if stations.len() >= MAX_STATIONS && !forget_longest_silent(&mut stations) {
                    // Every name held is watched or still heard from: a flood of names (or a lab
                    // larger than any served here) does not grow the hub without bound.
                    turned_away += 1;
                    if turned_away == 1 || turned_away.is_power_of_two() {
                        tracing::warn!(station = %name, "the station list is full ({MAX_STATIONS}); a new station is not listed ({turned_away} so far)");
                    }
                    continue;
                }
                tracing::info!(station = %name, "a station appeared");
                stations.insert(
                    name,
                    Entry {
                        status: s,
                        seen: Instant::now(),
                        seen_unix_ms: super::unix_ms(),
                        feed: None,
                    },
                );
            }
        }
    }
}

/// How long a request for the archive's list waits for a bucket being read (at the hub's
/// start, a new station's bucket, after a reconnection).
const LISTING_WAIT: Duration = Duration::from_secs(5);

/// The stations a hub lists at most (a lab has tens).
const MAX_STATIONS: usize = 512;
/// The largest heartbeat taken as one, bytes: a summary with its most alerts, each detail at its
/// longest, is about 12 KiB.
const MAX_HEARTBEAT_BYTES: usize = 32 << 10;

/// Makes room in a full station list: forgets the station heard from longest ago that no viewer
/// of this hub watches. False when every station is watched.
fn forget_longest_silent(stations: &mut HashMap<String, Entry>) -> bool {
    let oldest = stations
        .iter()
        .filter(|(_, e)| e.feed.is_none())
        .min_by_key(|(_, e)| e.seen)
        .map(|(name, _)| name.clone());
    match oldest {
        Some(name) => {
            stations.remove(&name);
            tracing::info!(station = %name, "forgot a silent station to make room in the list");
            true
        }
        None => false,
    }
}

#[derive(Deserialize)]
struct StationQuery {
    station: Option<String>,
    /// `/ws?dashboard`: the dashboard page's connection, not a station's viewer.
    dashboard: Option<String>,
    /// An archived recording of the station, to replay instead of its live stream.
    archive: Option<String>,
}

fn no_station() -> Response {
    (
        StatusCode::NOT_FOUND,
        "this is a lab hub: name a station (?station=NAME); /api/stations lists them",
    )
        .into_response()
}

async fn api_stations(State(lab): State<Arc<Lab>>) -> Response {
    let list = StationList {
        hub: true,
        stations: lab.listing(),
    };
    match serde_json::to_vec(&list) {
        Ok(json) => ([(header::CONTENT_TYPE, "application/json")], json).into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response(),
    }
}

/// `/api/archive?station=NAME`: the archived recordings (of one station, or all).
async fn api_archive(
    State(lab): State<Arc<Lab>>,
    Extension(role): Extension<Role>,
    connect_info: Option<Extension<ConnectInfo<SocketAddr>>>,
    Query(q): Query<StationQuery>,
) -> Response {
    if let Some(refusal) = access::refusal(
        role,
        Action::ListArchive,
        client_of(connect_info),
        "/api/archive",
    ) {
        return refusal;
    }
    match lab.archive.answer(q.station.as_deref(), LISTING_WAIT).await {
        Ok(json) => ([(header::CONTENT_TYPE, "application/json")], json).into_response(),
        Err(e) => refused("the archive's list", (StatusCode::BAD_GATEWAY, e)),
    }
}

/// An archived recording's file, for `softhaptic replay` on an instructor's machine.
async fn archived_file(
    State(lab): State<Arc<Lab>>,
    Extension(role): Extension<Role>,
    connect_info: Option<Extension<ConnectInfo<SocketAddr>>>,
    UrlPath((station, file)): UrlPath<(String, String)>,
) -> Response {
    // Before the name is even looked at: an observer learns nothing of what is archived.
    if let Some(refusal) = access::refusal(
        role,
        Action::DownloadArchive,
        client_of(connect_info),
        "an archived file",
    ) {
        return refusal;
    }
    if super::check_station_name(&station).is_err() || !file.ends_with(".mcap") {
        return refused(
            "an archived file",
            (
                StatusCode::NOT_FOUND,
                format!("{station:?}/{file:?}: not a recording's name"),
            ),
        );
    }
    // Streamed from the store as the client takes it: a download holds a piece of the
    // recording at a time, not the whole file, however many run at once.
    match super::archive::download(&lab.client, &station, &file).await {
        Ok(download) => (
            [
                (header::CONTENT_TYPE, "application/octet-stream".to_owned()),
                (header::CONTENT_LENGTH, download.bytes.to_string()),
                (
                    header::CONTENT_DISPOSITION,
                    format!("attachment; filename=\"{station}-{file}\""),
                ),
            ],
            axum::body::Body::from_stream(download.body),
        )
            .into_response(),
        Err(e) => refused(
            "an archived file",
            (StatusCode::NOT_FOUND, format!("{station}/{file}: {e}")),
        ),
    }
}

/// A render mesh of a replayed archived recording.
async fn archived_mesh(
    State(lab): State<Arc<Lab>>,
    Extension(role): Extension<Role>,
    UrlPath((station, file, mesh)): UrlPath<(String, String, String)>,
) -> Response {
    let feed = match lab.open_replay(&station, &file, role) {
        Ok(f) => f,
        Err(e) => return refused("an archived recording's mesh", e),
    };
    match mesh.strip_suffix(".bin").and_then(|m| feed.meshes.get(m)) {
        Some(bytes) => (
            [(header::CONTENT_TYPE, "application/octet-stream")],
            bytes.clone(),
        )
            .into_response(),
        None => refused(
            "an archived recording's mesh",
            (StatusCode::NOT_FOUND, format!("no render mesh {mesh:?}")),
        ),
    }
}

async fn api_scene(
    State(lab): State<Arc<Lab>>,
    Extension(role): Extension<Role>,
    Query(q): Query<StationQuery>,
) -> Response {
    let Some(name) = q.station else {
        return no_station();
    };
    if let Some(file) = q.archive {
        return match lab.open_replay(&name, &file, role) {
            Ok(feed) => (
                [(header::CONTENT_TYPE, "application/json")],
                feed.scene_json.clone(),
            )
                .into_response(),
            Err(e) => refused("a scene", e),
        };
    }
    match lab.feed(&name).await {
        Ok(feed) => (
            [(header::CONTENT_TYPE, "application/json")],
            feed.scene_json.clone(),
        )
            .into_response(),
        Err(e) => refused("a scene", e),
    }
}

async fn mesh(
    State(lab): State<Arc<Lab>>,
    UrlPath((station, file)): UrlPath<(String, String)>,
) -> Response {
    let Some(mesh_name) = file.strip_suffix(".bin") else {
        return refused(
            "a mesh",
            (StatusCode::NOT_FOUND, format!("no render mesh {file:?}")),
        );
    };
    let feed = match lab.feed(&station).await {
        Ok(f) => f,
        Err(e) => return refused("a mesh", e),
    };
    match lab.mesh(&station, &feed, mesh_name).await {
        Ok(bytes) => ([(header::CONTENT_TYPE, "application/octet-stream")], bytes).into_response(),
        Err(e) => refused("a mesh", e),
    }
}

/// `/ws?station=NAME[&archive=FILE]`. The Origin is checked first (the Host was, by the guard
/// every request passes), and a page of another site gets its 403 before anything is looked up;
/// then the connection is upgraded and, once the viewer has its role (its token, when the hub has
/// tokens), the station or the recording is looked up: a client without a valid token learns
/// nothing of what exists and makes the hub fetch nothing. One that is not there is closed with
/// [`CLOSE_NOT_FOUND`], whatever the reason.
async fn ws(
    State(lab): State<Arc<Lab>>,
    Query(q): Query<StationQuery>,
    connect_info: Option<Extension<ConnectInfo<SocketAddr>>>,
    headers: HeaderMap,
    upgrade: WebSocketUpgrade,
) -> Response {
    let peer = connect_info.map(|info| info.0.0);
    let client = peer.map_or_else(|| "unknown".to_owned(), |p| p.to_string());
    let origin = match lab.access.check_origin(&headers) {
        Ok(origin) => origin,
        Err(reason) => {
            if lab.access.log_refusal("403 (Origin)") {
                tracing::warn!(%client, "WebSocket upgrade refused (403): {reason}");
            }
            return access::json_error(StatusCode::FORBIDDEN, "origin not allowed");
        }
    };
    if q.dashboard.is_some() {
        return dashboard_ws(lab, peer, origin, upgrade);
    }
    let Some(station) = q.station else {
        return no_station();
    };
    let archive = q.archive;
    admitted(
        lab,
        peer,
        origin,
        upgrade,
        move |lab, socket, mut connection| async move {
            let limits = lab.limits;
            // The viewer's use of a replay, given back when it ends.
            let mut replay_use = None;
            let used = &mut replay_use;
            let (hub_lab, client) = (&lab, &client);
            let (station, archive) = (station.as_str(), archive.as_deref());
            let find = move |role| async move {
                match hub_lab.viewer_stream(station, archive, role).await {
                    // Made after the hub's feeds were closed: nobody would close it.
                    Ok(_) if *hub_lab.shutdown.borrow() => {
                        Err((axum::extract::ws::close_code::AWAY, "server shutting down"))
                    }
                    Ok((hub, archive_use)) => {
                        *used = archive_use;
                        Ok(hub)
                    }
                    Err((status, detail)) => {
                        tracing::info!(%client, %status, "viewer refused: {detail}");
                        let reason = public_reason(status);
                        Err(match status {
                            StatusCode::NOT_FOUND => (CLOSE_NOT_FOUND, reason),
                            StatusCode::FORBIDDEN => (access::CLOSE_FORBIDDEN, reason),
                            StatusCode::SERVICE_UNAVAILABLE
                            | StatusCode::BAD_GATEWAY
                            | StatusCode::TOO_MANY_REQUESTS => (CLOSE_TRY_LATER, reason),
                            _ => (axum::extract::ws::close_code::ERROR, reason),
                        })
                    }
                }
            };
            let end = lab
                .access
                .serve_viewer_found_after_auth(
                    socket,
                    limits,
                    &lab.shutdown,
                    &lab.gate,
                    &mut connection,
                    find,
                )
                .await;
            drop(replay_use);
            (connection, end)
        },
    )
}

/// Upgrades to a WebSocket behind the hub's limits on connections (refused with 4429 past
/// them), then `serve`s it with its connection, finished (the audit line) with how it ended.
fn admitted<F, Fut>(
    lab: Arc<Lab>,
    peer: Option<SocketAddr>,
    origin: Option<String>,
    upgrade: WebSocketUpgrade,
    serve: F,
) -> Response
where
    F: FnOnce(Arc<Lab>, axum::extract::ws::WebSocket, Connection) -> Fut + Send + 'static,
    Fut: std::future::Future<Output = (Connection, ViewerEnd)> + Send,
{
    let admission = lab.access.admit(peer.map(|p| p.ip()));
    let limits = lab.limits;
    limits.bound(upgrade).on_upgrade(move |socket| async move {
        let admission = match admission {
            Ok(admission) => admission,
            Err(refusal) => {
                lab.access
                    .refuse_viewer(socket, refusal, limits, &lab.gate)
                    .await;
                Connection::new(&lab.access, peer, origin, None).finish(&ViewerEnd::Limit(refusal));
                return;
            }
        };
        let connection = Connection::new(&lab.access, peer, origin, Some(admission));
        let (connection, end) = serve(lab, socket, connection).await;
        connection.finish(&end);
    })
}

/// `/ws?dashboard`: a dashboard page, behind the same limits and token exchange as a viewer.
fn dashboard_ws(
    lab: Arc<Lab>,
    peer: Option<SocketAddr>,
    origin: Option<String>,
    upgrade: WebSocketUpgrade,
) -> Response {
    admitted(
        lab,
        peer,
        origin,
        upgrade,
        move |lab, socket, mut connection| async move {
            let limits = lab.limits;
            let who = peer.map_or_else(|| "unknown".to_owned(), |p| p.to_string());
            let (dashboard, shutdown) = (Arc::clone(&lab.dashboard), lab.shutdown.clone());
            let end = lab
                .access
                .serve_after_auth(
                    socket,
                    limits,
                    &lab.shutdown,
                    &lab.gate,
                    &mut connection,
                    move |socket, role, rate| {
                        super::dashboard::serve_page(
                            socket, dashboard, role, rate, limits, shutdown, who,
                        )
                    },
                )
                .await;
            (connection, end)
        },
    )
}

/// The dashboard's message to its pages, once a [`DASHBOARD_PERIOD`] while a page is open.
async fn publish_dashboard(lab: Arc<Lab>) {
    let mut ticks = tokio::time::interval(DASHBOARD_PERIOD);
    ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut shutdown = lab.shutdown.clone();
    loop {
        tokio::select! {
            _ = shutdown.changed() => break,
            _ = ticks.tick() => {}
        }
        if lab.dashboard.watched() {
            lab.dashboard.publish(lab.dashboard_message());
        }
    }
}

/// Drops the decoded recordings no replay has used for their expiry, a few times per expiry.
async fn expire_replays(lab: Arc<Lab>) {
    let every = (lab.replays.limits().idle_expiry / 4).max(Duration::from_millis(100));
    let mut ticks = tokio::time::interval(every);
    loop {
        ticks.tick().await;
        lab.replays.expire();
    }
}

/// The client's address of a request served with connection info.
fn client_of(connect_info: Option<Extension<ConnectInfo<SocketAddr>>>) -> Option<SocketAddr> {
    connect_info.map(|info| info.0.0)
}

/// Connects to NATS, follows the stations and serves the page.
pub async fn start(options: HubOptions) -> Result<RunningHub, HubError> {
    let mut access_config = options.access;
    access_config.check_bind(options.addr)?;
    options.viewer.check()?;
    let client = super::connect(&options.nats, "softhaptic hub".into(), super::Party::Hub).await?;
    let status = client
        .subscribe(STATUS_SUBJECTS)
        .await
        .map_err(|e| LabError::Connect {
            url: options.nats.url.clone(),
            reason: e.to_string(),
        })?;
    access_config.secure_transport = options.tls.is_some();
    let caps = crate::tls::ConnectionCaps::for_limits(&access_config.limits);
    let access = Arc::new(Access::new(access_config, &options.viewer.page_html()?));
    let (shutdown_tx, shutdown_rx) = watch::channel(false);
    let (archive, follow_archive) =
        super::listing::ArchiveListing::start(client.clone(), options.archive_listing);
    let dashboard = Arc::new(DashboardHub::new(client.clone()));
    let lab = Arc::new(Lab {
        client,
        stations: Mutex::new(HashMap::new()),
        archives: Mutex::new(HashMap::new()),
        making: tokio::sync::Mutex::new(()),
        replays: super::replays::ReplayCache::new(options.replay_cache),
        archive,
        access: Arc::clone(&access),
        limits: options.viewer_limits,
        shutdown: shutdown_rx.clone(),
        gate: StreamCounters::default(),
        dashboard,
    });
    let tasks = vec![
        tokio::spawn(follow_stations(Arc::clone(&lab), status)),
        tokio::spawn(publish_dashboard(Arc::clone(&lab))),
        tokio::spawn(expire_replays(Arc::clone(&lab))),
        follow_archive,
    ];

    let session_data = Router::new()
        .route("/api/stations", get(api_stations))
        .route("/api/scene", get(api_scene))
        .route("/stations/{station}/meshes/{file}", get(mesh))
        .route("/api/archive", get(api_archive))
        .route("/stations/{station}/archive/{file}", get(archived_file))
        .route(
            "/stations/{station}/archive/{file}/meshes/{mesh}",
            get(archived_mesh),
        )
        .route_layer(axum::middleware::from_fn_with_state(
            Arc::clone(&access),
            access::require_token,
        ));
    let routes = options
        .viewer
        .routes()
        .merge(options.viewer.dashboard_routes())
        .merge(session_data)
        .route("/ws", get(ws))
        .with_state(Arc::clone(&lab))
        .layer(axum::middleware::from_fn_with_state(
            Arc::clone(&access),
            access::guard_host,
        ));
    let app =
        access::with_security_headers(routes, access.csp().clone(), access.config.strict_transport);

    let listener = tokio::net::TcpListener::bind(options.addr)
        .await
        .map_err(|source| HubError::Bind {
            addr: options.addr,
            source,
        })?;
    let local_addr = listener.local_addr().map_err(|source| HubError::Bind {
        addr: options.addr,
        source,
    })?;
    let tls = options.tls.is_some();
    let http = crate::routes::serve_http(listener, app, options.tls, caps, shutdown_rx);
    Ok(RunningHub {
        local_addr,
        shutdown_tx,
        http,
        tasks,
        lab,
        tls,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use softhaptic_proto::wire::{MessageVector, message_vectors};

    /// The shared test vector of a message of `kind`, as text.
    fn vector(kind: &str) -> String {
        message_vectors()
            .unwrap()
            .into_iter()
            .find_map(|v| match v {
                MessageVector::Valid { json, .. } if json["type"] == kind => Some(json.to_string()),
                _ => None,
            })
            .unwrap()
    }

    #[test]
    fn an_answer_is_taken_only_where_the_station_would_put_it() {
        let inclusions = vector("inclusions");
        let m: serde_json::Value = serde_json::from_str(&inclusions).unwrap();
        let revealed = m["revealed"].as_bool().unwrap();
        // Where it belongs it is taken, re-encoded; on the other channel it is refused.
        assert!(
            checked_inclusions(Some(&inclusions), revealed)
                .unwrap()
                .is_some()
        );
        let refused = checked_inclusions(Some(&inclusions), !revealed).unwrap_err();
        assert!(refused.contains("revealed"), "{refused}");
        assert!(checked_inclusions(Some(&vector("stats")), false).is_err());
        assert!(checked_inclusions(None, true).unwrap().is_none());
    }

    #[test]
    fn a_station_scene_that_is_not_a_scene_is_refused_not_a_panic() {
        let scene = vector("scene");
        let rewritten = rewrite_mesh_urls(&scene, "/stations/desk-1/meshes").unwrap();
        assert!(matches!(
            ServerMessage::decode(&rewritten),
            Ok(ServerMessage::Scene(_))
        ));
        // What a rogue publisher on NATS sent: a render mesh that is a number panicked the hub.
        for bad in [
            r#"{"render_meshes":[1]}"#.to_owned(),
            scene.replacen(r#""render_meshes":["#, r#""render_meshes":[1,"#, 1),
            vector("stats"),
            "not json".to_owned(),
        ] {
            assert!(rewrite_mesh_urls(&bad, "/x").is_err(), "{bad}");
        }
    }

    #[test]
    fn a_full_station_list_forgets_the_longest_silent_unwatched_station() {
        let entry = |name: &str, seen: Instant| Entry {
            status: StationStatus {
                name: name.to_owned(),
                session_id: "s".to_owned(),
                scene: "liver".to_owned(),
                state: super::super::StationState::Idle,
                since_unix_ms: 0,
                viewers: 0,
                unpublished_frames: 0,
                summary: None,
            },
            seen,
            seen_unix_ms: 0,
            feed: None,
        };
        let now = Instant::now();
        let mut stations = HashMap::new();
        stations.insert("recent".to_owned(), entry("recent", now));
        stations.insert(
            "silent".to_owned(),
            entry("silent", now - Duration::from_secs(600)),
        );
        stations.insert(
            "older".to_owned(),
            entry("older", now - Duration::from_secs(60)),
        );
        assert!(forget_longest_silent(&mut stations));
        assert!(!stations.contains_key("silent"));
        assert_eq!(stations.len(), 2);
        assert!(forget_longest_silent(&mut stations));
        assert!(!stations.contains_key("older"));
    }

    #[test]
    fn only_stats_and_metrics_are_relayed_from_a_stations_stats_subject() {
        relayable_stats(&vector("stats")).unwrap();
        relayable_stats(&vector("metrics")).unwrap();
        // Padded: what is relayed is the message alone.
        let stats = vector("stats");
        let padded = stats.replacen('{', &format!("{{{}", " ".repeat(10_000)), 1);
        assert_eq!(
            relayable_stats(&padded).unwrap(),
            relayable_stats(&stats).unwrap()
        );
        assert!(relayable_stats(&padded).unwrap().len() < 2000);
        for bad in [
            "<script>not json".to_owned(),
            vector("hello"),
            vector("contact"),
            r#"{"type":"stats"}"#.to_owned(),
        ] {
            assert!(relayable_stats(&bad).is_err(), "{bad}");
        }
    }
}
