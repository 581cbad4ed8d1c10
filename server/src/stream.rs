//! The 50 Hz contact stream and the 1 Hz stats, from the haptic loop to every WebSocket viewer.
//!
//! One task ([`frame_task`]) reads the loop's latest contact 50 times a second, adds R_d from
//! the calibration table, encodes the frame once and broadcasts it; one task ([`stats_task`])
//! does the same for the loop's timing once a second. Each viewer's connection task
//! ([`serve_viewer`]) forwards what it receives to its socket.
//!
//! Why a slow viewer cannot delay anyone: the broadcast channel is bounded and never waits for a
//! receiver; a receiver that falls [`FRAME_BACKLOG`] frames behind is told how many it lost,
//! jumps to the newest frame, and its `dropped` count (reported in its next contact frame) grows.
//! A viewer that stops reading altogether blocks only its own task in a socket send; its losses
//! are counted when that send completes, and a send that waits longer than the send timeout
//! closes the connection (`stalled_closes`).
//! The haptic loop is never touched by any of this: the frame task only reads its wait-free
//! publication.
//!
//! Each connection first gets its role ([`crate::access`]): with tokens, its first message must
//! be an `auth` with a valid token within the auth timeout, before anything is sent to it; without
//! tokens it is an instructor at once. A request its role may not make gets a `refused` reply and
//! the connection stays open; a connection that sends more than its message rate allows is
//! closed. Both are decided by the connection's own task, so a misbehaving client delays no one.

use std::fmt;
use std::sync::Arc;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use axum::extract::ws::{CloseFrame, Message, Utf8Bytes, WebSocket, close_code};
use softhaptic_device::device::DeviceError;
use softhaptic_device::haptic_loop::HapticLoop;
use softhaptic_device::metrics::TraineeMetrics;
use softhaptic_device::stats::LoopStats;
use softhaptic_proto::CalibrationTable;
use softhaptic_proto::wire::ReplayControl;
use softhaptic_proto::wire::{
    Auth, ComputeUs, ContactFrame, DeviceStatus, Hello, MarkMessage, MarkRequest, MetricsMessage,
    PeriodErrorUs, Refused, Role, ServerMessage, StatsMessage, message_type,
};
use tokio::sync::{broadcast, watch};

use crate::access::{
    Access, CLOSE_UNAUTHORIZED, Connection, LimitRefusal, MessageRate, REASON_BAD_TOKEN,
    REASON_NO_TOKEN, Tokens,
};

/// Frames a viewer may fall behind before it skips to the newest (80 ms at 50 Hz): enough to
/// ride out a scheduling hiccup without loss, short enough that a lagging viewer shows the
/// present.
pub const FRAME_BACKLOG: usize = 4;
/// Stats messages kept for a slow viewer (they are once a second; older ones are worthless).
pub const STATS_BACKLOG: usize = 2;

/// A contact frame encoded once for every viewer.
///
/// Every viewer with no lost frames gets `with_no_drops` (shared bytes, no copy). A viewer that
/// lost frames needs its own `dropped` value, the frame's last field: it gets `prefix` (the JSON
/// up to and including `"dropped":`) followed by its count and `}`.
#[derive(Debug)]
pub struct EncodedFrame {
    pub seq: u64,
    with_no_drops: Utf8Bytes,
    prefix_len: usize,
}

/// The tail every encoded contact frame ends with when `dropped` is 0.
const NO_DROPS_TAIL: &str = "\"dropped\":0}";

impl EncodedFrame {
    /// Encodes `frame` (its `dropped` is ignored and written as 0).
    pub fn new(frame: &ContactFrame) -> Result<Self, serde_json::Error> {
        let frame = ContactFrame {
            dropped: 0,
            ..*frame
        };
        let text = ServerMessage::Contact(frame).encode()?;
        // `dropped` is the last field of `ContactFrame`, and serde writes fields in declaration
        // order, so the text always ends with the tail (checked by a test); if a future field
        // order broke that, fail loudly rather than send wrong counts.
        if !text.ends_with(NO_DROPS_TAIL) {
            return Err(serde::ser::Error::custom(
                "contact frame does not end with its dropped field",
            ));
        }
        let prefix_len = text.len() - 2;
        Ok(Self {
            seq: frame.seq,
            with_no_drops: Utf8Bytes::from(text),
            prefix_len,
        })
    }

    /// A frame received as text (a station's, relayed by a hub): it must be a contact message
    /// of the wire protocol whose `dropped` is 0; its bytes are kept as they are, so a hub's
    /// viewers get exactly what the station's get.
    pub fn from_text(text: String) -> Result<Self, String> {
        let seq = match ServerMessage::decode(&text) {
            Ok(ServerMessage::Contact(frame)) => frame.seq,
            Ok(other) => {
                return Err(format!(
                    "a {} message, not a contact frame",
                    other.type_name()
                ));
            }
            Err(e) => return Err(e.to_string()),
        };
        if !text.ends_with(NO_DROPS_TAIL) {
            return Err("a contact frame that does not end with \"dropped\":0".into());
        }
        let prefix_len = text.len() - 2;
        Ok(Self {
            seq,
            with_no_drops: Utf8Bytes::from(text),
            prefix_len,
        })
    }

    /// The text for a viewer that has lost `dropped` frames so far.
    pub fn text_for(&self, dropped: u64) -> Utf8Bytes {
        if dropped == 0 {
            return self.with_no_drops.clone();
        }
        let prefix = &self.with_no_drops.as_str()[..self.prefix_len];
        let mut text = String::with_capacity(self.prefix_len + 21);
        text.push_str(prefix);
        text.push_str(&dropped.to_string());
        text.push('}');
        Utf8Bytes::from(text)
    }
}

/// Limits of one viewer connection.
#[derive(Debug, Clone, Copy)]
pub struct ViewerLimits {
    /// Largest incoming message; a bigger one closes the connection (the viewer sends nothing
    /// large: this only bounds what a broken or hostile client can make the server buffer).
    pub max_incoming_bytes: usize,
    /// A send that does not complete in this time closes the connection: the peer stopped
    /// reading, and holding its socket open serves nobody.
    pub send_timeout: Duration,
}

impl Default for ViewerLimits {
    fn default() -> Self {
        Self {
            max_incoming_bytes: 64 * 1024,
            send_timeout: Duration::from_secs(10),
        }
    }
}

/// Counters shared by the stream tasks and reported in `stats`.
#[derive(Debug, Default)]
pub struct StreamCounters {
    pub viewers: AtomicU32,
    /// Frames lost by all viewers together.
    pub dropped_frames: AtomicU64,
    /// Incoming messages of a type the server does not know (ignored).
    pub unknown_messages: AtomicU64,
    /// Connections closed because a message was malformed or too large.
    pub malformed_closes: AtomicU64,
    /// Contact frames produced.
    pub frames_sent: AtomicU64,
    /// Connections closed because a send did not complete within the send timeout (the viewer
    /// stopped reading).
    pub stalled_closes: AtomicU64,
    /// Connections closed for presenting no token, or a wrong one (4401).
    pub unauthorized_closes: AtomicU64,
    /// Connections closed for sending more messages than their rate allows (1008).
    pub flood_closes: AtomicU64,
    /// Connections refused by a limit on connections (4429).
    pub limit_refusals: AtomicU64,
    /// Requests answered with `refused` (the connection stayed open).
    pub refused_requests: AtomicU64,
}

/// What every viewer connection needs.
pub struct StreamHub {
    /// `hello` for an instructor and for an observer, encoded once.
    hello_instructor: Utf8Bytes,
    hello_observer: Utf8Bytes,
    pub scene: Utf8Bytes,
    pub frames: broadcast::Sender<Arc<EncodedFrame>>,
    pub stats: broadcast::Sender<Utf8Bytes>,
    pub counters: StreamCounters,
    pub limits: ViewerLimits,
    pub shutdown: watch::Receiver<bool>,
    /// Where viewers' `replay_control` messages go when the source is a recording (see
    /// `session::replay`); `None` on a live session, where they are unknown messages.
    pub replay_control: Option<tokio::sync::mpsc::Sender<ReplayControl>>,
    /// Who may connect: tokens, Origin and Host rules, connection limits.
    pub access: Arc<Access>,
    /// Instructors' marks as they are made (to every viewer, and to the recorder).
    pub marks: broadcast::Sender<Utf8Bytes>,
    /// Every mark so far, encoded, for a viewer that connects later.
    made_marks: std::sync::Mutex<Vec<Utf8Bytes>>,
    /// Device time of the latest contact frame: a mark's time.
    pub latest_time_ns: AtomicU64,
    /// The frame a replay shows now, sent to a viewer as it connects so that a paused replay
    /// draws the tool where the recording has it rather than nowhere; `None` on a live session,
    /// whose next frame is 20 ms away. A lock held only to swap or clone an `Arc`.
    held_frame: std::sync::Mutex<Option<Arc<EncodedFrame>>>,
}

impl StreamHub {
    /// A hub with empty frame and stats channels of the standard backlogs, for a live session
    /// (`replay_control` `None`) or a replay (the player's control queue). `hello` gives the
    /// session id and mode; its role is set per connection.
    pub fn new(
        hello: &Hello,
        scene: Utf8Bytes,
        limits: ViewerLimits,
        shutdown: watch::Receiver<bool>,
        replay_control: Option<tokio::sync::mpsc::Sender<ReplayControl>>,
        access: Arc<Access>,
    ) -> Result<Self, serde_json::Error> {
        let hello_for = |role| {
            ServerMessage::Hello(Hello {
                role,
                ..hello.clone()
            })
            .encode()
            .map(Utf8Bytes::from)
        };
        Ok(Self {
            hello_instructor: hello_for(Role::Instructor)?,
            hello_observer: hello_for(Role::Observer)?,
            scene,
            frames: broadcast::channel(FRAME_BACKLOG).0,
            stats: broadcast::channel(STATS_BACKLOG).0,
            counters: StreamCounters::default(),
            limits,
            shutdown,
            replay_control,
            access,
            marks: broadcast::channel(MARK_BACKLOG).0,
            made_marks: std::sync::Mutex::new(Vec::new()),
            latest_time_ns: AtomicU64::new(0),
            held_frame: std::sync::Mutex::new(None),
        })
    }

    /// Every mark so far, encoded.
    pub fn made_marks(&self) -> Vec<Utf8Bytes> {
        self.made_marks
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Adds a mark: numbered, stamped with the session's device time, kept for later viewers
    /// and sent to everyone now. `Err` when it cannot be encoded.
    pub fn add_mark(&self, request: MarkRequest) -> Result<MarkMessage, serde_json::Error> {
        let mut made = self.made_marks.lock().unwrap_or_else(|p| p.into_inner());
        let mark = MarkMessage {
            id: made.len() as u64 + 1,
            time_ns: self.latest_time_ns.load(Ordering::Relaxed),
            note: request.note.trim().to_owned(),
            point_m: request.point_m,
        };
        let text = Utf8Bytes::from(ServerMessage::Mark(mark.clone()).encode()?);
        made.push(text.clone());
        let _ = self.marks.send(text);
        Ok(mark)
    }

    /// Marks a replayed recording holds, shown to its viewers as they connect.
    pub fn preload_marks(&self, marks: &[MarkMessage]) {
        let mut made = self.made_marks.lock().unwrap_or_else(|p| p.into_inner());
        for m in marks {
            if let Ok(text) = ServerMessage::Mark(m.clone()).encode() {
                made.push(Utf8Bytes::from(text));
            }
        }
    }

    /// The `hello` of a connection with `role`.
    pub fn hello(&self, role: Role) -> &Utf8Bytes {
        match role {
            Role::Instructor => &self.hello_instructor,
            Role::Observer => &self.hello_observer,
        }
    }

    /// Sets the frame a viewer gets as it connects ([`StreamHub::held_frame`]).
    pub fn hold_frame(&self, frame: Arc<EncodedFrame>) {
        *self.held_frame.lock().unwrap_or_else(|p| p.into_inner()) = Some(frame);
    }

    /// The frame a viewer gets as it connects, if any.
    pub fn held_frame(&self) -> Option<Arc<EncodedFrame>> {
        self.held_frame
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }
}

/// Counts a viewer for as long as its connection task lives.
struct ViewerGuard<'a>(&'a StreamCounters);

impl<'a> ViewerGuard<'a> {
    fn new(counters: &'a StreamCounters) -> Self {
        counters.viewers.fetch_add(1, Ordering::Relaxed);
        Self(counters)
    }
}

impl Drop for ViewerGuard<'_> {
    fn drop(&mut self) {
        self.0.viewers.fetch_sub(1, Ordering::Relaxed);
    }
}

/// Reads the loop's latest contact every `period` and broadcasts it, until shutdown.
pub async fn frame_task(
    haptic_loop: Arc<HapticLoop>,
    calibration: CalibrationTable,
    hub: Arc<StreamHub>,
    period: Duration,
) {
    let mut shutdown = hub.shutdown.clone();
    let mut interval = tokio::time::interval(period);
    // After a stall, continue at the normal rate rather than bursting the missed frames.
    interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut seq: u64 = 0;
    loop {
        tokio::select! {
            _ = interval.tick() => {}
            _ = shutdown.changed() => break,
        }
        let state = haptic_loop.latest_contact();
        let deformed_radius_m = if state.in_contact {
            calibration.deformed_radius_m(state.depth_m)
        } else {
            0.0
        };
        hub.latest_time_ns.store(state.time_ns, Ordering::Relaxed);
        let frame = ContactFrame::from_state(&state, seq, deformed_radius_m, 0);
        match EncodedFrame::new(&frame) {
            Ok(encoded) => {
                // No receivers is not an error: frames are simply not needed.
                let _ = hub.frames.send(Arc::new(encoded));
                hub.counters.frames_sent.fetch_add(1, Ordering::Relaxed);
            }
            Err(e) => tracing::error!(error = %e, seq, "could not encode a contact frame"),
        }
        seq += 1;
    }
}

/// The `stats` message for the loop's current summary and the stream's counters.
pub fn stats_message(
    loop_stats: &LoopStats,
    counters: &StreamCounters,
    device: DeviceStatus,
) -> StatsMessage {
    let us = |ns: u64| ns as f64 * 1e-3;
    StatsMessage {
        loop_rate_hz: loop_stats.loop_rate_hz,
        period_error_us: PeriodErrorUs {
            p50: us(loop_stats.period_error_p50_ns),
            p99: us(loop_stats.period_error_p99_ns),
            p999: us(loop_stats.period_error_p999_ns),
            max: us(loop_stats.period_error_max_ns),
        },
        overruns: loop_stats.overruns,
        standby_ticks: loop_stats.standby_ticks,
        compute_us: ComputeUs {
            p50: us(loop_stats.compute_p50_ns),
            p99: us(loop_stats.compute_p99_ns),
            max: us(loop_stats.compute_max_ns),
        },
        viewers: counters.viewers.load(Ordering::Relaxed),
        dropped_frames: counters.dropped_frames.load(Ordering::Relaxed),
        device,
    }
}

/// The device's state for viewers, from its error on the last tick.
pub fn device_status(error: Option<DeviceError>) -> DeviceStatus {
    match error {
        None => DeviceStatus::Ok,
        Some(DeviceError::Disconnected) => DeviceStatus::Disconnected,
        Some(DeviceError::Timeout) => DeviceStatus::NotAnswering,
        Some(DeviceError::ForceDisabled) => DeviceStatus::ForceDisabled,
        Some(DeviceError::NeedsCalibration) => DeviceStatus::NeedsCalibration,
        Some(DeviceError::Overrun) => DeviceStatus::Overrun,
        Some(DeviceError::Driver(_)) => DeviceStatus::DriverError,
    }
}

/// How often the stats task looks at the device's state: a change is logged and sent to the
/// viewers at once rather than with the next second's stats.
const DEVICE_STATUS_POLL: Duration = Duration::from_millis(50);

/// Broadcasts `stats` every `period`, until shutdown.
pub async fn stats_task(haptic_loop: Arc<HapticLoop>, hub: Arc<StreamHub>, period: Duration) {
    let mut shutdown = hub.shutdown.clone();
    let mut interval = tokio::time::interval(period);
    interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    // The first tick fires at once; the loop has no statistics yet then.
    interval.tick().await;
    let mut poll = tokio::time::interval(DEVICE_STATUS_POLL.min(period));
    poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut device = DeviceStatus::Ok;
    loop {
        tokio::select! {
            _ = interval.tick() => {}
            _ = poll.tick() => {
                let error = haptic_loop.device_error();
                let now = device_status(error);
                if now == device {
                    continue;
                }
                // One line per change of state, never per tick; the text a person reads.
                match error {
                    Some(e) => tracing::warn!(error = %e, "haptic device: {}", now.message()),
                    None => tracing::info!("haptic device: back, force ramps in again"),
                }
                device = now;
            }
            _ = shutdown.changed() => {
                // The session's end: its metrics as they stand, marked final.
                send_metrics(&hub, &haptic_loop.metrics(), true);
                break;
            }
        }
        let message = stats_message(&haptic_loop.stats(), &hub.counters, device);
        match ServerMessage::Stats(message).encode() {
            Ok(text) => {
                let _ = hub.stats.send(Utf8Bytes::from(text));
            }
            Err(e) => tracing::error!(error = %e, "could not encode stats"),
        }
        send_metrics(&hub, &haptic_loop.metrics(), false);
    }
}

/// The `metrics` message of the trainee's metrics.
pub fn metrics_message(m: &TraineeMetrics, is_final: bool) -> MetricsMessage {
    let flags_raised = m
        .flag_onsets
        .iter()
        .enumerate()
        .filter(|(_, n)| **n > 0)
        .filter_map(|(bit, n)| {
            let flag = softhaptic_proto::ContactFlags::from_bits_retain(1 << bit);
            softhaptic_proto::wire::flag_name(flag).map(|name| (name.to_owned(), *n))
        })
        .collect();
    MetricsMessage {
        peak_force_n: m.peak_force_n,
        peak_force_time_s: m.peak_force_time_s,
        safe_force_n: m.safe_force_n,
        time_above_safe_s: m.time_above_safe_s,
        time_in_contact_s: m.time_in_contact_s,
        path_length_in_contact_m: m.path_length_in_contact_m,
        mean_squared_jerk_m2_s6: m.mean_squared_jerk_m2_s6,
        pushes: m.pushes,
        device_fault_ticks: m.device_fault_ticks,
        flags_raised,
        ticks: m.ticks,
        is_final,
    }
}

fn send_metrics(hub: &StreamHub, m: &TraineeMetrics, is_final: bool) {
    match ServerMessage::Metrics(metrics_message(m, is_final)).encode() {
        Ok(text) => {
            let _ = hub.stats.send(Utf8Bytes::from(text));
        }
        Err(e) => tracing::error!(error = %e, "could not encode the metrics"),
    }
}

/// Why a viewer connection ended (in its audit line; counted where it matters).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ViewerEnd {
    Closed,
    Malformed,
    SendFailed,
    Shutdown,
    /// No `auth` with a token within the auth timeout, or a first message that was not one
    /// (4401).
    NoToken,
    /// A token that is neither role's (4401).
    BadToken,
    /// More messages than the connection's rate allows (1008).
    Flooded,
    /// Refused at the upgrade by a limit on connections (4429).
    Limit(LimitRefusal),
}

impl fmt::Display for ViewerEnd {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ViewerEnd::Closed => f.write_str("closed by the viewer"),
            ViewerEnd::Malformed => f.write_str("closed: malformed or oversized message"),
            ViewerEnd::SendFailed => {
                f.write_str("closed: the viewer stopped reading or the link failed")
            }
            ViewerEnd::Shutdown => f.write_str("closed: server shutting down (1001)"),
            ViewerEnd::NoToken => write!(f, "refused: {REASON_NO_TOKEN} ({CLOSE_UNAUTHORIZED})"),
            ViewerEnd::BadToken => write!(f, "refused: {REASON_BAD_TOKEN} ({CLOSE_UNAUTHORIZED})"),
            ViewerEnd::Flooded => write!(f, "closed: {REASON_FLOOD} (1008)"),
            ViewerEnd::Limit(refusal) => {
                write!(
                    f,
                    "refused: {} ({})",
                    refusal.reason(),
                    crate::access::CLOSE_TOO_MANY
                )
            }
        }
    }
}

/// The close reason of a connection that sent more messages than its rate allows.
pub const REASON_FLOOD: &str = "too many messages";
/// The `refused` reason of a `replay_control` from an observer.
pub const REFUSED_OBSERVER: &str =
    "an observer cannot control the replay: only an instructor's link can";
/// The `refused` reason of an `add_mark` from an observer.
pub const REFUSED_MARK_OBSERVER: &str = "only an instructor marks the session";
/// The `refused` reason of an `add_mark` sent to a replay.
pub const REFUSED_MARK_REPLAY: &str = "a replay's marks are the recording's: mark a live session";
/// Marks a slow viewer may fall behind by before it loses one (they are rare and small).
pub const MARK_BACKLOG: usize = 64;
/// The `refused` reason of a `replay_control` sent to a live session.
pub const REFUSED_LIVE: &str = "this is a live session: there is no replay to control";

/// Serves one viewer: its role (see the module doc), `hello` and `scene`, then every contact
/// frame and stats message, until the viewer leaves, misbehaves, stops reading, or the server
/// shuts down. `connection` learns the role, for the audit line its owner logs.
pub async fn serve_viewer(
    mut socket: WebSocket,
    hub: Arc<StreamHub>,
    connection: &mut Connection,
) -> ViewerEnd {
    let timeout = hub.limits.send_timeout;
    let mut rate = MessageRate::new(&hub.access.config.limits, Instant::now());
    let role = match hub.access.tokens() {
        None => Role::Instructor,
        Some(tokens) => match authenticate(&mut socket, &hub, tokens, &mut rate).await {
            Ok(role) => role,
            Err(end) => return end,
        },
    };
    connection.authenticated(role);
    let _guard = ViewerGuard::new(&hub.counters);
    // Subscribe before sending the greeting, so no frame produced meanwhile is missed.
    let mut frames = hub.frames.subscribe();
    let mut stats = hub.stats.subscribe();
    let mut marks = hub.marks.subscribe();
    let mut shutdown = hub.shutdown.clone();

    for greeting in [hub.hello(role), &hub.scene] {
        if !send(
            &mut socket,
            Message::Text(greeting.clone()),
            timeout,
            &hub.counters,
        )
        .await
        {
            return ViewerEnd::SendFailed;
        }
    }
    // The marks made before this viewer came (a mark made meanwhile is also queued: sent twice,
    // which its id makes harmless).
    for mark in hub.made_marks() {
        if !send(&mut socket, Message::Text(mark), timeout, &hub.counters).await {
            return ViewerEnd::SendFailed;
        }
    }
    // A replay's current frame, unless a newer one is already queued for this viewer.
    if frames.is_empty()
        && let Some(held) = hub.held_frame()
        && !send(
            &mut socket,
            Message::Text(held.text_for(0)),
            timeout,
            &hub.counters,
        )
        .await
    {
        return ViewerEnd::SendFailed;
    }

    let mut dropped: u64 = 0;
    loop {
        if *shutdown.borrow() {
            close(
                &mut socket,
                close_code::AWAY,
                "server shutting down",
                timeout,
            )
            .await;
            return ViewerEnd::Shutdown;
        }
        tokio::select! {
            changed = shutdown.changed() => {
                // An error means the server was dropped without an orderly shutdown: leave too.
                if changed.is_err() {
                    close(&mut socket, close_code::AWAY, "server shutting down", timeout).await;
                    return ViewerEnd::Shutdown;
                }
            }
            incoming = socket.recv() => {
                if let Some(end) =
                    handle_incoming(&mut socket, &hub, connection, role, &mut rate, incoming).await
                {
                    return end;
                }
            }
            frame = frames.recv() => {
                let frame = match frame {
                    Ok(frame) => frame,
                    Err(broadcast::error::RecvError::Lagged(lost)) => {
                        // Fell FRAME_BACKLOG behind: skip to the newest frame.
                        let mut lost = lost;
                        let mut newest = None;
                        loop {
                            match frames.try_recv() {
                                Ok(f) => {
                                    if newest.replace(f).is_some() {
                                        lost += 1;
                                    }
                                }
                                Err(broadcast::error::TryRecvError::Lagged(n)) => lost += n,
                                Err(_) => break,
                            }
                        }
                        dropped += lost;
                        hub.counters.dropped_frames.fetch_add(lost, Ordering::Relaxed);
                        match newest {
                            Some(f) => f,
                            None => continue,
                        }
                    }
                    Err(broadcast::error::RecvError::Closed) => return ViewerEnd::Shutdown,
                };
                if !send(&mut socket, Message::Text(frame.text_for(dropped)), timeout, &hub.counters).await {
                    return ViewerEnd::SendFailed;
                }
            },
            text = stats.recv() => {
                if let Ok(text) = text
                    && !send(&mut socket, Message::Text(text), timeout, &hub.counters).await
                {
                    return ViewerEnd::SendFailed;
                }
            },
            mark = marks.recv() => {
                if let Ok(text) = mark
                    && !send(&mut socket, Message::Text(text), timeout, &hub.counters).await
                {
                    return ViewerEnd::SendFailed;
                }
            },
        }
    }
}

/// Waits for the connection's `auth` (nothing is sent before it): the role of its token, or
/// the connection closed with 4401 (no valid `auth` first, or none within the auth timeout).
async fn authenticate(
    socket: &mut WebSocket,
    hub: &StreamHub,
    tokens: &Tokens,
    rate: &mut MessageRate,
) -> Result<Role, ViewerEnd> {
    let timeout = hub.limits.send_timeout;
    let deadline = tokio::time::Instant::now() + hub.access.config.limits.auth_timeout;
    let mut shutdown = hub.shutdown.clone();
    loop {
        if *shutdown.borrow() {
            close(socket, close_code::AWAY, "server shutting down", timeout).await;
            return Err(ViewerEnd::Shutdown);
        }
        let incoming = tokio::select! {
            _ = shutdown.changed() => continue,
            incoming = tokio::time::timeout_at(deadline, socket.recv()) => incoming,
        };
        let message = match incoming {
            Err(_) => {
                hub.counters
                    .unauthorized_closes
                    .fetch_add(1, Ordering::Relaxed);
                close(socket, CLOSE_UNAUTHORIZED, REASON_NO_TOKEN, timeout).await;
                return Err(ViewerEnd::NoToken);
            }
            Ok(None | Some(Ok(Message::Close(_)))) => return Err(ViewerEnd::Closed),
            Ok(Some(Err(e))) => {
                tracing::debug!(error = %e, "viewer connection failed before presenting a token");
                return Err(malformed(socket, hub, close_code::SIZE, INVALID_REFUSED).await);
            }
            Ok(Some(Ok(message))) => message,
        };
        if !rate.allow(Instant::now()) {
            return Err(flooded(socket, hub).await);
        }
        match message {
            Message::Ping(_) | Message::Pong(_) => continue,
            Message::Binary(_) => {
                return Err(malformed(socket, hub, close_code::UNSUPPORTED, BINARY_REFUSED).await);
            }
            Message::Close(_) => return Err(ViewerEnd::Closed),
            Message::Text(text) => {
                // Anything but an `auth` with a string token is no token presented.
                let role = serde_json::from_str::<Auth>(&text)
                    .ok()
                    .map(|auth| tokens.role_of(&auth.token));
                let (reason, end) = match role {
                    Some(Some(role)) => return Ok(role),
                    Some(None) => (REASON_BAD_TOKEN, ViewerEnd::BadToken),
                    None => (REASON_NO_TOKEN, ViewerEnd::NoToken),
                };
                hub.counters
                    .unauthorized_closes
                    .fetch_add(1, Ordering::Relaxed);
                close(socket, CLOSE_UNAUTHORIZED, reason, timeout).await;
                return Err(end);
            }
        }
    }
}

/// Close reason of a connection that sent a binary message.
const BINARY_REFUSED: &str = "binary messages are not accepted";
/// Close reason of a connection whose message broke the WebSocket protocol or its size limit.
const INVALID_REFUSED: &str = "invalid or oversized message";

/// Closes a connection that sent what the protocol does not accept (a binary message, a message
/// that breaks WebSocket's rules or the size limit), with `code` and `reason`.
async fn malformed(
    socket: &mut WebSocket,
    hub: &StreamHub,
    code: u16,
    reason: &'static str,
) -> ViewerEnd {
    hub.counters
        .malformed_closes
        .fetch_add(1, Ordering::Relaxed);
    close(socket, code, reason, hub.limits.send_timeout).await;
    ViewerEnd::Malformed
}

/// Closes a connection that sent more than its rate allows.
async fn flooded(socket: &mut WebSocket, hub: &StreamHub) -> ViewerEnd {
    hub.counters.flood_closes.fetch_add(1, Ordering::Relaxed);
    close(
        socket,
        close_code::POLICY,
        REASON_FLOOD,
        hub.limits.send_timeout,
    )
    .await;
    ViewerEnd::Flooded
}

/// Handles one incoming message of a connection that has its `role`; `Some` when the
/// connection ends.
async fn handle_incoming(
    socket: &mut WebSocket,
    hub: &StreamHub,
    connection: &Connection,
    role: Role,
    rate: &mut MessageRate,
    incoming: Option<Result<Message, axum::Error>>,
) -> Option<ViewerEnd> {
    let timeout = hub.limits.send_timeout;
    let message = match incoming {
        None | Some(Ok(Message::Close(_))) => return Some(ViewerEnd::Closed),
        Some(Err(e)) => {
            // Protocol violations and oversized messages end up here.
            tracing::debug!(error = %e, "viewer connection failed");
            return Some(malformed(socket, hub, close_code::SIZE, INVALID_REFUSED).await);
        }
        Some(Ok(message)) => message,
    };
    if !rate.allow(Instant::now()) {
        return Some(flooded(socket, hub).await);
    }
    let text = match message {
        Message::Text(text) => text,
        Message::Binary(_) => {
            return Some(malformed(socket, hub, close_code::UNSUPPORTED, BINARY_REFUSED).await);
        }
        // Pings are answered by the WebSocket layer.
        Message::Ping(_) | Message::Pong(_) | Message::Close(_) => return None,
    };
    match message_type(&text) {
        Ok(kind) if kind == "replay_control" => {
            let tx = match (&hub.replay_control, role) {
                (Some(tx), Role::Instructor) => tx,
                (None, _) => return refuse(socket, hub, connection, &kind, REFUSED_LIVE).await,
                (Some(_), Role::Observer) => {
                    return refuse(socket, hub, connection, &kind, REFUSED_OBSERVER).await;
                }
            };
            let control = serde_json::from_str::<ReplayControl>(&text)
                .map_err(|e| e.to_string())
                .and_then(|c| c.validate().map(|()| c).map_err(|e| e.to_string()));
            match control {
                // A full queue means controls arrive faster than they matter.
                Ok(c) => {
                    let _ = tx.try_send(c);
                }
                Err(reason) => {
                    tracing::debug!(reason, "invalid replay_control message");
                    hub.counters
                        .malformed_closes
                        .fetch_add(1, Ordering::Relaxed);
                    close(
                        socket,
                        close_code::INVALID,
                        "invalid replay_control message",
                        timeout,
                    )
                    .await;
                    return Some(ViewerEnd::Malformed);
                }
            }
        }
        Ok(kind) if kind == "add_mark" => {
            if hub.replay_control.is_some() {
                return refuse(socket, hub, connection, &kind, REFUSED_MARK_REPLAY).await;
            }
            if role == Role::Observer {
                return refuse(socket, hub, connection, &kind, REFUSED_MARK_OBSERVER).await;
            }
            let request = serde_json::from_str::<MarkRequest>(&text).map_err(|e| e.to_string());
            match request.and_then(|r| r.problem().map_or(Ok(r), Err)) {
                Ok(r) => match hub.add_mark(r) {
                    Ok(m) => tracing::info!(id = m.id, time_ns = m.time_ns, "instructor mark"),
                    Err(e) => tracing::error!(error = %e, "could not encode a mark"),
                },
                Err(reason) => return refuse(socket, hub, connection, &kind, &reason).await,
            }
        }
        // The connection has its role already (or the server has no tokens): a later `auth`
        // changes nothing and is ignored.
        Ok(kind) if kind == "auth" => {}
        Ok(kind) => {
            let n = hub
                .counters
                .unknown_messages
                .fetch_add(1, Ordering::Relaxed);
            if n == 0 {
                tracing::warn!(kind, "ignoring a viewer message of unknown type");
            } else {
                tracing::debug!(kind, "ignoring a viewer message of unknown type");
            }
        }
        Err(e) => {
            tracing::debug!(error = %e, "malformed viewer message");
            hub.counters
                .malformed_closes
                .fetch_add(1, Ordering::Relaxed);
            close(socket, close_code::INVALID, "malformed message", timeout).await;
            return Some(ViewerEnd::Malformed);
        }
    }
    None
}

/// Answers a request the connection may not make with `refused`, logs it, and keeps the
/// connection open (`Some` only when the reply cannot be sent).
async fn refuse(
    socket: &mut WebSocket,
    hub: &StreamHub,
    connection: &Connection,
    request: &str,
    reason: &str,
) -> Option<ViewerEnd> {
    hub.counters
        .refused_requests
        .fetch_add(1, Ordering::Relaxed);
    tracing::info!(
        client = %connection.peer.map_or_else(|| "unknown".to_owned(), |p| p.to_string()),
        role = connection.role.map_or("none", Role::as_str),
        request,
        "request refused: {reason}"
    );
    let reply = ServerMessage::Refused(Refused {
        request: request.to_owned(),
        reason: reason.to_owned(),
    });
    match reply.encode() {
        Ok(text) => {
            let message = Message::Text(Utf8Bytes::from(text));
            if !send(socket, message, hub.limits.send_timeout, &hub.counters).await {
                return Some(ViewerEnd::SendFailed);
            }
        }
        Err(e) => tracing::error!(error = %e, "could not encode a refused message"),
    }
    None
}

/// Closes a connection refused by a limit on connections, with 4429 and the limit's reason.
pub async fn refuse_connection(mut socket: WebSocket, hub: &StreamHub, refusal: LimitRefusal) {
    hub.counters.limit_refusals.fetch_add(1, Ordering::Relaxed);
    close(
        &mut socket,
        crate::access::CLOSE_TOO_MANY,
        refusal.reason(),
        hub.limits.send_timeout,
    )
    .await;
}

/// Sends with a deadline; false when the connection is unusable. A send that times out is
/// counted in `stalled_closes`.
async fn send(
    socket: &mut WebSocket,
    message: Message,
    timeout: Duration,
    counters: &StreamCounters,
) -> bool {
    match tokio::time::timeout(timeout, socket.send(message)).await {
        Ok(Ok(())) => true,
        Ok(Err(_)) => false,
        Err(_) => {
            counters.stalled_closes.fetch_add(1, Ordering::Relaxed);
            tracing::debug!("closing a viewer that stopped reading");
            false
        }
    }
}

/// How long a closing connection's remaining messages are read and discarded, waiting for the
/// peer's close frame.
const CLOSE_DRAIN: Duration = Duration::from_secs(1);

/// Sends a close frame, then reads (and discards) what the peer still sends until its own close
/// frame, for at most [`CLOSE_DRAIN`]. Dropping a socket with unread data makes the kernel
/// reset the connection, and a reset can reach the peer before it has read our close frame:
/// a flooding client would then never learn its close code.
async fn close(socket: &mut WebSocket, code: u16, reason: &'static str, timeout: Duration) {
    let frame = CloseFrame {
        code,
        reason: Utf8Bytes::from_static(reason),
    };
    // The peer may already be gone; nothing more to do either way.
    if !matches!(
        tokio::time::timeout(timeout, socket.send(Message::Close(Some(frame)))).await,
        Ok(Ok(()))
    ) {
        return;
    }
    let _ = tokio::time::timeout(CLOSE_DRAIN, async {
        while let Some(Ok(message)) = socket.recv().await {
            if matches!(message, Message::Close(_)) {
                break;
            }
        }
    })
    .await;
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use softhaptic_proto::{ContactFlags, ContactState};

    #[test]
    fn per_viewer_dropped_counts_are_spliced_into_the_shared_text() {
        let state = ContactState {
            in_contact: true,
            depth_m: 0.003,
            flags: ContactFlags::SATURATED,
            ..ContactState::IDLE
        };
        let encoded = EncodedFrame::new(&ContactFrame::from_state(&state, 42, 0.02, 0)).unwrap();
        for dropped in [0, 1, 17, u64::MAX] {
            let text = encoded.text_for(dropped);
            match ServerMessage::decode(&text).unwrap() {
                ServerMessage::Contact(f) => {
                    assert_eq!(f.dropped, dropped);
                    assert_eq!(f.seq, 42);
                    assert_eq!(f.flags, ContactFlags::SATURATED);
                }
                other => panic!("{other:?}"),
            }
        }
    }

    #[test]
    fn stats_convert_nanoseconds_to_microseconds() {
        let stats = LoopStats {
            loop_rate_hz: 999.5,
            period_error_p50_ns: 2_500,
            period_error_p99_ns: 20_000,
            period_error_p999_ns: 48_000,
            period_error_max_ns: 130_000,
            overruns: 3,
            standby_ticks: 11,
            compute_p50_ns: 12_000,
            compute_p99_ns: 40_000,
            compute_max_ns: 95_000,
            ..LoopStats::default()
        };
        let counters = StreamCounters::default();
        counters.viewers.store(2, Ordering::Relaxed);
        counters.dropped_frames.store(7, Ordering::Relaxed);
        let m = stats_message(&stats, &counters, DeviceStatus::Disconnected);
        assert_eq!(m.device, DeviceStatus::Disconnected);
        assert_eq!(m.period_error_us.p50, 2.5);
        assert_eq!(m.period_error_us.max, 130.0);
        assert_eq!(m.compute_us.p99, 40.0);
        assert_eq!((m.viewers, m.dropped_frames, m.overruns), (2, 7, 3));
        assert_eq!(m.standby_ticks, 11);
    }
}
