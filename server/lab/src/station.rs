//! A station's side of the lab: its stream published to NATS beside its own viewers.
//!
//! The task reads the stream hub's frame and stats broadcasts exactly as a viewer does, so the
//! haptic loop and the local viewers never wait for NATS: a publish that cannot go out at once
//! (NATS down, or slower than the frames) loses that frame, counted in the heartbeat's
//! `unpublished_frames` and logged, with the outage's length, when NATS is back. While the
//! client is disconnected nothing is handed to it, so a reconnection never flushes a backlog of
//! stale frames to the hubs.

use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use axum::body::Bytes;
use futures_util::StreamExt;
use tokio::sync::{broadcast, watch};
use tokio::task::JoinHandle;

use softhaptic_proto::wire::{ActionResult, DeviceStatus, MarkRequest, StationAction};

use super::{
    ActionCall, InclusionsState, LabError, MESH_PIECE_BYTES, MeshRequest, NatsOptions,
    STATUS_PERIOD, StationSession, StationState, StationStatus, Subjects, unix_ms,
};
use crate::stream::{
    ControlRefusal, REFUSED_EXERCISE_BUSY, REFUSED_EXERCISE_NONE, REFUSED_REARM_NONE, StreamHub,
};

/// A station's lab settings (`--nats`, `--station`, `--nats-credentials`).
#[derive(Debug, Clone)]
pub struct StationOptions {
    pub nats: NatsOptions,
    pub name: String,
}

/// What the station serves the hubs.
pub struct StationData {
    pub session: StationSession,
    /// The scene in words, for the station list.
    pub scene_label: String,
    /// The render meshes by name, SHM1 bytes.
    pub meshes: Arc<HashMap<String, Bytes>>,
}

/// How long after the last contact a station still counts as live.
const LIVE_FOR: Duration = Duration::from_secs(60);

/// Connects the station to NATS: a refusal of the credentials is an error, an unreachable
/// server is not (the client keeps trying; the station serves its own viewers meanwhile).
pub async fn connect(options: &StationOptions) -> Result<async_nats::Client, LabError> {
    super::check_station_name(&options.name).map_err(LabError::Name)?;
    super::connect(
        &options.nats,
        format!("softhaptic station {}", options.name),
        super::Party::Station(&options.name),
    )
    .await
}

/// Starts publishing `hub`'s stream through `client` until `shutdown`.
pub fn spawn(
    client: async_nats::Client,
    options: &StationOptions,
    hub: Arc<StreamHub>,
    data: StationData,
    shutdown: watch::Receiver<bool>,
) -> Vec<JoinHandle<()>> {
    let subjects = Subjects::of(&options.name);
    let data = Arc::new(data);
    let published = Arc::new(Published::default());
    let tasks = vec![
        tokio::spawn(publish_frames(
            client.clone(),
            subjects.clone(),
            hub.frames.subscribe(),
            hub.stats.subscribe(),
            Arc::clone(&published),
            shutdown.clone(),
        )),
        tokio::spawn(heartbeat(
            client.clone(),
            options.name.clone(),
            subjects.clone(),
            Arc::clone(&hub),
            Arc::clone(&data),
            Arc::clone(&published),
            shutdown.clone(),
        )),
        tokio::spawn(publish_events(
            client.clone(),
            subjects.clone(),
            Arc::clone(&hub),
            shutdown.clone(),
        )),
        tokio::spawn(answer_requests(client, subjects, hub, data, shutdown)),
    ];
    tracing::info!(
        "station {:?} publishes to NATS at {}",
        options.name,
        options.nats.url
    );
    tasks
}

#[derive(Default)]
struct Published {
    /// Frames not published (NATS down, or the publisher behind).
    unpublished_frames: std::sync::atomic::AtomicU64,
    /// Unix ms of the last frame in contact (0: never).
    last_contact_ms: std::sync::atomic::AtomicU64,
}

async fn publish_frames(
    client: async_nats::Client,
    subjects: Subjects,
    mut frames: broadcast::Receiver<Arc<crate::stream::EncodedFrame>>,
    mut stats: broadcast::Receiver<axum::extract::ws::Utf8Bytes>,
    published: Arc<Published>,
    mut shutdown: watch::Receiver<bool>,
) {
    // When NATS went away, and how many frames were not published since.
    let mut outage: Option<(Instant, u64)> = None;
    loop {
        let (subject, payload, in_contact) = tokio::select! {
            _ = shutdown.changed() => break,
            frame = frames.recv() => match frame {
                Ok(frame) => {
                    let text = frame.text_for(0);
                    let in_contact = text.as_str().contains("\"in_contact\":true");
                    (subjects.contact.clone(), Bytes::from(text.as_str().to_owned()), in_contact)
                }
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    published.unpublished_frames.fetch_add(n, Ordering::Relaxed);
                    continue;
                }
                Err(broadcast::error::RecvError::Closed) => break,
            },
            s = stats.recv() => match s {
                Ok(text) => (subjects.stats.clone(), Bytes::from(text.as_str().to_owned()), false),
                Err(broadcast::error::RecvError::Lagged(_)) => continue,
                Err(broadcast::error::RecvError::Closed) => break,
            },
        };
        if in_contact {
            published
                .last_contact_ms
                .store(unix_ms(), Ordering::Relaxed);
        }
        let is_frame = subject == subjects.contact;
        let connected = client.connection_state() == async_nats::connection::State::Connected;
        if !connected {
            if is_frame {
                published.unpublished_frames.fetch_add(1, Ordering::Relaxed);
                let (_, lost) = outage.get_or_insert((Instant::now(), 0));
                *lost += 1;
                if *lost == 1 {
                    // The log line carries the wall-clock time; the Instant kept is for the
                    // outage's length only.
                    tracing::warn!(
                        "NATS connection lost: frames are not published until it is back (this station's own viewers are not affected)"
                    );
                }
            }
            continue;
        }
        if let Some((since, lost)) = outage.take() {
            tracing::warn!(
                "NATS is back after {:.1} s: {lost} frames were not published",
                since.elapsed().as_secs_f64()
            );
        }
        // Bounded: a publish that cannot be queued within a frame period is dropped.
        let sent =
            tokio::time::timeout(Duration::from_millis(20), client.publish(subject, payload)).await;
        if !matches!(sent, Ok(Ok(()))) && is_frame {
            published.unpublished_frames.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// Where the inclusions stand now, as a viewer connecting to the station would be told.
fn inclusions_state(hub: &StreamHub) -> InclusionsState {
    let text = |r: tokio::sync::watch::Receiver<Option<axum::extract::ws::Utf8Bytes>>| {
        r.borrow().as_ref().map(|t| t.as_str().to_owned())
    };
    InclusionsState {
        hidden: text(hub.inclusions.hidden()),
        public: text(hub.inclusions.public()),
    }
}

/// The exercise, marks and inclusions messages, as they are made, to the hubs. Rare (about one
/// a second at most), so each is published as it comes, in order; one that cannot go out (NATS
/// down) is not queued: a hub that starts relaying asks for where things stand.
async fn publish_events(
    client: async_nats::Client,
    subjects: Subjects,
    hub: Arc<StreamHub>,
    mut shutdown: watch::Receiver<bool>,
) {
    let mut exercise = hub.exercise.messages.subscribe();
    let mut marks = hub.marks.subscribe();
    let mut hidden = hub.inclusions.hidden();
    let mut public = hub.inclusions.public();
    loop {
        let (subject, payload) = tokio::select! {
            _ = shutdown.changed() => break,
            m = exercise.recv() => match m {
                Ok(text) => (subjects.exercise.clone(), Bytes::from(text.as_str().to_owned())),
                // A newer message says all a lost one did.
                Err(broadcast::error::RecvError::Lagged(_)) => continue,
                Err(broadcast::error::RecvError::Closed) => break,
            },
            m = marks.recv() => match m {
                Ok(text) => (subjects.marks.clone(), Bytes::from(text.as_str().to_owned())),
                Err(broadcast::error::RecvError::Lagged(_)) => continue,
                Err(broadcast::error::RecvError::Closed) => break,
            },
            changed = hidden.changed() => {
                if changed.is_err() {
                    break;
                }
                hidden.borrow_and_update();
                inclusions_payload(&subjects, &hub)
            }
            changed = public.changed() => {
                if changed.is_err() {
                    break;
                }
                public.borrow_and_update();
                inclusions_payload(&subjects, &hub)
            }
        };
        if client.connection_state() != async_nats::connection::State::Connected {
            continue;
        }
        let _ = tokio::time::timeout(STATUS_PERIOD, client.publish(subject, payload)).await;
    }
}

fn inclusions_payload(subjects: &Subjects, hub: &StreamHub) -> (String, Bytes) {
    let json = serde_json::to_vec(&inclusions_state(hub)).unwrap_or_default();
    (subjects.inclusions.clone(), Bytes::from(json))
}

async fn heartbeat(
    client: async_nats::Client,
    name: String,
    subjects: Subjects,
    hub: Arc<StreamHub>,
    data: Arc<StationData>,
    published: Arc<Published>,
    mut shutdown: watch::Receiver<bool>,
) {
    let mut interval = tokio::time::interval(STATUS_PERIOD);
    interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut state = (StationState::Idle, unix_ms());
    loop {
        tokio::select! {
            _ = shutdown.changed() => break,
            _ = interval.tick() => {}
        }
        let now = unix_ms();
        let last = published.last_contact_ms.load(Ordering::Relaxed);
        let live = last != 0 && now.saturating_sub(last) < LIVE_FOR.as_millis() as u64;
        let current = if live {
            StationState::Live
        } else {
            StationState::Idle
        };
        if current != state.0 {
            state = (current, now);
        }
        let status = StationStatus {
            name: name.clone(),
            session_id: data.session.session_id.clone(),
            scene: data.scene_label.clone(),
            state: state.0,
            since_unix_ms: state.1,
            viewers: hub.counters.viewers.load(Ordering::Relaxed),
            unpublished_frames: published.unpublished_frames.load(Ordering::Relaxed),
            summary: Some(hub.summary.summary()),
        };
        if client.connection_state() != async_nats::connection::State::Connected {
            continue;
        }
        if let Ok(json) = serde_json::to_vec(&status) {
            let _ = tokio::time::timeout(
                STATUS_PERIOD,
                client.publish(subjects.status.clone(), Bytes::from(json)),
            )
            .await;
        }
    }
}

async fn answer_requests(
    client: async_nats::Client,
    subjects: Subjects,
    hub: Arc<StreamHub>,
    data: Arc<StationData>,
    mut shutdown: watch::Receiver<bool>,
) {
    // Subscribed as soon as NATS is there (the client may still be connecting).
    let (mut session, mut mesh, mut action) = loop {
        let subscribed = async {
            Ok::<_, async_nats::SubscribeError>((
                client.subscribe(subjects.session.clone()).await?,
                client.subscribe(subjects.mesh.clone()).await?,
                client.subscribe(subjects.action.clone()).await?,
            ))
        };
        tokio::select! {
            _ = shutdown.changed() => return,
            s = subscribed => match s {
                Ok(pair) => break pair,
                Err(e) => {
                    tracing::warn!("cannot subscribe to the hubs' requests yet: {e}");
                    tokio::time::sleep(Duration::from_secs(1)).await;
                }
            }
        }
    };
    loop {
        let (request, reply) = tokio::select! {
            _ = shutdown.changed() => break,
            m = session.next() => match m {
                Some(m) => (m, session_reply(&hub, &data)),
                None => break,
            },
            m = mesh.next() => match m {
                Some(m) => {
                    let reply = mesh_piece(&data, &m.payload);
                    (m, reply)
                }
                None => break,
            },
            m = action.next() => match m {
                Some(m) => {
                    let result = carry_out(&hub, &m.payload);
                    (m, Bytes::from(serde_json::to_vec(&result).unwrap_or_default()))
                }
                None => break,
            },
        };
        if let Some(to) = request.reply {
            let _ = client.publish(to, reply).await;
        }
    }
}

/// The answer to a dashboard's re-arm of a device that has not latched off.
pub const REFUSED_REARM_NOT_LATCHED: &str = "the device's force output is not latched off";

/// The largest action request taken, bytes (a mark's note is at most 280 characters).
const MAX_ACTION_BYTES: usize = 4096;

/// Carries out an instructor's action sent by a hub (the hub checked the instructor's role; the
/// NATS permissions let only hubs send it), logged with who asked.
fn carry_out(hub: &StreamHub, payload: &[u8]) -> ActionResult {
    let call = (payload.len() <= MAX_ACTION_BYTES)
        .then(|| serde_json::from_slice::<ActionCall>(payload).ok())
        .flatten();
    let Some(ActionCall { action, by }) = call else {
        return ActionResult {
            station: String::new(),
            action: "unknown".into(),
            done: false,
            reason: Some("the station could not read the request".into()),
        };
    };
    let by: String = by.chars().take(200).collect();
    let outcome: Result<(), String> = match &action {
        StationAction::Acknowledge { alert } => hub
            .summary
            .acknowledge(*alert, &by)
            .map_err(|r| r.reason().to_owned()),
        StationAction::Exercise { control } => {
            hub.exercise.control(*control).map_err(|r| match r {
                ControlRefusal::NoExercises => REFUSED_EXERCISE_NONE.to_owned(),
                ControlRefusal::Busy => REFUSED_EXERCISE_BUSY.to_owned(),
            })
        }
        StationAction::Mark { note } => {
            let request = MarkRequest {
                note: note.clone(),
                point_m: None,
            };
            match request.problem() {
                Some(problem) => Err(problem.to_owned()),
                None => hub.add_mark(request).map(|_| ()).map_err(|e| e.to_string()),
            }
        }
        // From a dashboard, only a device that latched off: a re-arm is the instructor's
        // decision to let force back after repeated trips, not something to send blind.
        StationAction::RearmDevice => match hub.summary.device_state() {
            DeviceStatus::ForceLatched if hub.rearm_device() => Ok(()),
            _ if !hub.rearm_device_possible() => Err(REFUSED_REARM_NONE.to_owned()),
            _ => Err(REFUSED_REARM_NOT_LATCHED.to_owned()),
        },
    };
    match &outcome {
        Ok(()) => {
            tracing::info!(by = %by, action = ?action, "an instructor's action from a lab hub, carried out")
        }
        Err(reason) => {
            tracing::info!(by = %by, action = ?action, "an instructor's action from a lab hub, not carried out: {reason}")
        }
    }
    ActionResult {
        station: String::new(),
        action: action.name().to_owned(),
        done: outcome.is_ok(),
        reason: outcome.err(),
    }
}

/// The session as a hub that starts relaying the station needs it: the scene, and where the
/// exercise, marks and inclusions stand now.
fn session_reply(hub: &StreamHub, data: &StationData) -> Bytes {
    let session = StationSession {
        exercise: hub.exercise.latest().map(|t| t.as_str().to_owned()),
        marks: hub
            .made_marks()
            .iter()
            .map(|t| t.as_str().to_owned())
            .collect(),
        inclusions: inclusions_state(hub),
        ..data.session.clone()
    };
    match serde_json::to_vec(&session) {
        Ok(json) => Bytes::from(json),
        Err(e) => {
            tracing::error!("cannot encode the station's session for the hubs: {e}");
            Bytes::new()
        }
    }
}

/// The piece of a mesh a request asks for: its total length (u64, little-endian) then up to
/// [`MESH_PIECE_BYTES`] from the offset; an empty reply for a mesh or offset that is not there.
fn mesh_piece(data: &StationData, request: &[u8]) -> Bytes {
    let Ok(MeshRequest { name, offset }) = serde_json::from_slice(request) else {
        return Bytes::new();
    };
    let Some(mesh) = data.meshes.get(&name) else {
        return Bytes::new();
    };
    let Ok(start) = usize::try_from(offset) else {
        return Bytes::new();
    };
    if start > mesh.len() {
        return Bytes::new();
    }
    let end = (start + MESH_PIECE_BYTES).min(mesh.len());
    let mut out = Vec::with_capacity(8 + end - start);
    out.extend_from_slice(&(mesh.len() as u64).to_le_bytes());
    out.extend_from_slice(&mesh[start..end]);
    Bytes::from(out)
}
