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
//!
//! # Layout
//! - this file: the [`StreamHub`] every connection shares (channels, counters, limits, marks,
//!   at most [`MAX_MARKS`]) and the backlogs.
//! - `frame.rs`: [`EncodedFrame`], a frame encoded once with each viewer's `dropped` spliced in.
//! - `tasks.rs`: [`frame_task`] and [`stats_task`] (with the `metrics` and the device's state),
//!   and [`send_final_metrics`], the session's last `metrics`, sent once the loop has stopped.
//! - `exercise.rs`: [`ExerciseFeed`], the `exercise` messages of a station running exercises
//!   and the instructors' `exercise_control` on their way to its scorer.
//! - `inclusions.rs`: [`InclusionsFeed`], where a palpation scene's inclusions are, to the
//!   viewers who may see them (instructors while an attempt runs, everyone after its end).
//! - `viewer.rs`: [`serve_viewer`], one viewer's connection: its role, what it is sent, what it
//!   may ask, and how it is closed.

mod exercise;
mod frame;
mod inclusions;
pub mod summary;
mod tasks;
mod viewer;

use std::sync::Arc;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::time::Duration;

use axum::extract::ws::{Utf8Bytes, WebSocketUpgrade};
use softhaptic_proto::wire::ReplayControl;
use softhaptic_proto::wire::{Hello, MarkMessage, MarkRequest, Role, ServerMessage};
use tokio::sync::{broadcast, watch};

use crate::access::Access;

pub use exercise::{ControlRefusal, EXERCISE_BACKLOG, ExerciseFeed};
pub use frame::EncodedFrame;
pub use inclusions::InclusionsFeed;
pub use summary::SummaryFeed;
pub use tasks::{
    FrameInclusions, device_status, frame_task, metrics_message, send_final_metrics, stats_message,
    stats_task,
};
pub use viewer::{
    REASON_FLOOD, REFUSED_EXERCISE_BUSY, REFUSED_EXERCISE_NONE, REFUSED_EXERCISE_OBSERVER,
    REFUSED_LIVE, REFUSED_MARK_HUB, REFUSED_MARK_OBSERVER, REFUSED_MARK_REPLAY, REFUSED_MARKS_FULL,
    REFUSED_OBSERVER, REFUSED_REARM_NONE, REFUSED_REARM_OBSERVER, ViewerEnd, refuse_connection,
    serve_viewer,
};

/// Frames a viewer may fall behind before it skips to the newest (80 ms at 50 Hz): enough to
/// ride out a scheduling hiccup without loss, short enough that a lagging viewer shows the
/// present.
pub const FRAME_BACKLOG: usize = 4;
/// Stats messages kept for a slow viewer (they are once a second; older ones are worthless).
pub const STATS_BACKLOG: usize = 2;
/// Marks a slow viewer may fall behind by before it loses one (they are rare and small).
pub const MARK_BACKLOG: usize = 64;
/// Marks a session keeps (and sends every viewer as it connects); a further `add_mark` is
/// refused. A thousand notes is far beyond any lesson, and bounds what an instructor's link,
/// within its message rate, can make the server hold and resend to each new viewer (about
/// 400 KiB at the longest notes).
pub const MAX_MARKS: usize = 1000;

/// Why [`StreamHub::add_mark`] made no mark.
#[derive(Debug, thiserror::Error)]
pub enum AddMarkError {
    #[error("the session already has its {MAX_MARKS} marks")]
    Full,
    #[error("could not encode the mark: {0}")]
    Encode(#[from] serde_json::Error),
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

impl ViewerLimits {
    /// `upgrade` bounded as every viewer's WebSocket is, a station's, a replay's or a hub's:
    /// incoming messages and frames no larger than [`ViewerLimits::max_incoming_bytes`], and
    /// at most 1 MiB buffered for a viewer that stopped reading (a frame or two).
    pub fn bound(&self, upgrade: WebSocketUpgrade) -> WebSocketUpgrade {
        upgrade
            .max_message_size(self.max_incoming_bytes)
            .max_frame_size(self.max_incoming_bytes)
            .write_buffer_size(0)
            .max_write_buffer_size(1 << 20)
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
    /// Every mark so far (at most [`MAX_MARKS`]), encoded, for a viewer that connects later.
    made_marks: std::sync::Mutex<Vec<Utf8Bytes>>,
    /// The newest relayed mark's id ([`StreamHub::relay_mark`]), changed under `made_marks`'s
    /// lock.
    relayed_mark_id: AtomicU64,
    /// Whether an instructor's `add_mark` is taken (`hello.accepts_marks`): not on a lab hub's
    /// relay, which knows neither the station's device time nor its recording.
    pub accepts_marks: bool,
    /// Device time of the latest contact frame: a mark's time.
    pub latest_time_ns: AtomicU64,
    /// The frame a replay shows now, sent to a viewer as it connects so that a paused replay
    /// draws the tool where the recording has it rather than nowhere; `None` on a live session,
    /// whose next frame is 20 ms away. A lock held only to swap or clone an `Arc`.
    held_frame: std::sync::Mutex<Option<Arc<EncodedFrame>>>,
    /// Where an instructor's `rearm_device` goes: the live device's handle, `None` on a replay,
    /// a lab hub's relay, and a device whose force output cannot latch off.
    rearm: Option<softhaptic_device::device::RearmHandle>,
    /// The exercise the station runs, if it runs any ([`StreamHub::with_exercises`]).
    pub exercise: Arc<ExerciseFeed>,
    /// Where the scene's inclusions are, for the viewers who may see them
    /// ([`StreamHub::with_inclusions`]; empty without inclusions).
    pub inclusions: Arc<InclusionsFeed>,
    /// What the session says of itself on a lab's dashboard, and its alerts
    /// ([`summary::track`] keeps it on a live session).
    pub summary: Arc<SummaryFeed>,
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
            relayed_mark_id: AtomicU64::new(0),
            accepts_marks: hello.accepts_marks,
            latest_time_ns: AtomicU64::new(0),
            held_frame: std::sync::Mutex::new(None),
            rearm: None,
            exercise: Arc::new(ExerciseFeed::none()),
            inclusions: Arc::new(InclusionsFeed::none()),
            summary: Arc::new(SummaryFeed::new(0.0)),
        })
    }

    /// The hub of a live session whose device an instructor may re-arm through `handle`.
    pub fn with_rearm(mut self, handle: Option<softhaptic_device::device::RearmHandle>) -> Self {
        self.rearm = handle;
        self
    }

    /// The hub of a live station running exercises, whose scorer publishes to `feed` (`None`:
    /// none run here).
    pub fn with_exercises(mut self, feed: Option<Arc<ExerciseFeed>>) -> Self {
        if let Some(feed) = feed {
            self.exercise = feed;
        }
        self
    }

    /// The hub of a stream whose scene has inclusions, published to `feed` (by the station's
    /// exercises, or once for a session without them, or by a replay).
    pub fn with_inclusions(mut self, feed: Option<Arc<InclusionsFeed>>) -> Self {
        if let Some(feed) = feed {
            self.inclusions = feed;
        }
        self
    }

    /// The hub of a live session whose scene's safe force is `safe_force_n` (its summary's
    /// alerts compare the force with it).
    pub fn with_safe_force(mut self, safe_force_n: f64) -> Self {
        self.summary = Arc::new(SummaryFeed::new(safe_force_n));
        self
    }

    /// Whether this stream has a device whose force output can be re-armed.
    pub fn rearm_device_possible(&self) -> bool {
        self.rearm.is_some()
    }

    /// Re-arms the device's force output; false when this stream has no device to re-arm.
    pub fn rearm_device(&self) -> bool {
        match &self.rearm {
            Some(handle) => {
                handle.request();
                true
            }
            None => false,
        }
    }

    /// Every mark so far, encoded.
    pub fn made_marks(&self) -> Vec<Utf8Bytes> {
        self.made_marks
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Adds a mark: numbered, stamped with the session's device time, kept for later viewers
    /// and sent to everyone now. `Err` when the session has [`MAX_MARKS`] already, or when it
    /// cannot be encoded.
    pub fn add_mark(&self, request: MarkRequest) -> Result<MarkMessage, AddMarkError> {
        let mut made = self.made_marks.lock().unwrap_or_else(|p| p.into_inner());
        if made.len() >= MAX_MARKS {
            return Err(AddMarkError::Full);
        }
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

    /// A mark another server made (a lab hub relays a station's), sent to everyone now and kept
    /// for later viewers: ignored when its `id` is not past every mark held (told twice, once in
    /// the station's session and once on its subject) or the session holds [`MAX_MARKS`].
    pub fn relay_mark(&self, mark: &MarkMessage) -> Result<bool, serde_json::Error> {
        let mut made = self.made_marks.lock().unwrap_or_else(|p| p.into_inner());
        let last_id = self.relayed_mark_id.load(Ordering::Relaxed);
        if mark.id <= last_id || made.len() >= MAX_MARKS {
            return Ok(false);
        }
        let text = Utf8Bytes::from(ServerMessage::Mark(mark.clone()).encode()?);
        self.relayed_mark_id.store(mark.id, Ordering::Relaxed);
        made.push(text.clone());
        let _ = self.marks.send(text);
        Ok(true)
    }

    /// Marks a replayed recording holds, shown to its viewers as they connect (the first
    /// [`MAX_MARKS`]: a live session keeps no more).
    pub fn preload_marks(&self, marks: &[MarkMessage]) {
        let mut made = self.made_marks.lock().unwrap_or_else(|p| p.into_inner());
        let room = MAX_MARKS.saturating_sub(made.len());
        for m in marks.iter().take(room) {
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

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use softhaptic_proto::wire::{Mode, PROTOCOL_VERSION};

    fn hub() -> StreamHub {
        let hello = Hello {
            protocol_version: PROTOCOL_VERSION,
            session_id: "s".into(),
            role: Role::Instructor,
            mode: Mode::Live,
            server: "test".into(),
            force_feedback: true,
            accepts_marks: true,
        };
        let access = Arc::new(Access::new(crate::access::AccessConfig::default(), ""));
        StreamHub::new(
            &hello,
            Utf8Bytes::from_static("{}"),
            ViewerLimits::default(),
            watch::channel(false).1,
            None,
            access,
        )
        .unwrap()
    }

    fn note(n: usize) -> MarkRequest {
        serde_json::from_str(&format!(r#"{{"type":"add_mark","note":"mark {n}"}}"#)).unwrap()
    }

    #[test]
    fn the_marks_kept_for_later_viewers_stop_at_the_cap_and_a_further_one_is_refused() {
        let live = hub();
        for n in 1..=MAX_MARKS {
            assert_eq!(live.add_mark(note(n)).unwrap().id, n as u64);
        }
        let mut receiver = live.marks.subscribe();
        assert!(matches!(
            live.add_mark(note(MAX_MARKS + 1)),
            Err(AddMarkError::Full)
        ));
        assert!(REFUSED_MARKS_FULL.contains(&MAX_MARKS.to_string()));
        let kept = live.made_marks();
        assert_eq!(kept.len(), MAX_MARKS);
        assert!(
            kept[MAX_MARKS - 1]
                .as_str()
                .contains(&format!("\"mark {MAX_MARKS}\""))
        );
        // The refused one reached no viewer either.
        assert!(matches!(
            receiver.try_recv(),
            Err(broadcast::error::TryRecvError::Empty)
        ));
        // A replay's recording with more marks is cut at the same cap.
        let replay = hub();
        let marks: Vec<MarkMessage> = (1..=MAX_MARKS as u64 + 5)
            .map(|id| MarkMessage {
                id,
                time_ns: id,
                note: "n".into(),
                point_m: None,
            })
            .collect();
        replay.preload_marks(&marks);
        assert_eq!(replay.made_marks().len(), MAX_MARKS);
    }
}
