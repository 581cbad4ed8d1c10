//! Streaming a recording to viewers exactly as a live session (`softhaptic replay FILE`).
//!
//! One file because the player, its controls and its routes are one state machine; the last 70
//! lines are its tests.
//!
//! The replay serves the same routes with the same code as the live server
//! ([`crate::routes::viewer_router`], [`crate::stream::serve_viewer`]); only the source of the
//! frames differs: instead of the haptic loop, a player task walks the recorded `/contact` frames
//! and `/loop_stats` messages on the recording's device-time axis, at `speed` times real time.
//! Viewers send `replay_control` messages (pause, play, seek, speed) and receive `replay` status
//! messages (duration, position, paused, speed) after each control and once a second, so a viewer
//! that connects learns the replay's state within a second; their `hello` says mode `replay`.
//! The access rules are the live server's ([`crate::access`]): the timeline is shared, so only an
//! instructor moves it; an observer's `replay_control` is answered with `refused`, and the
//! observer sees the timeline move with everyone else's.
//!
//! Frames keep their recorded content; only `seq` is renumbered (+1 per frame sent, across
//! seeks), so a viewer's loss detection works as live, and `dropped` is the viewer's own count.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use axum::body::Bytes;
use axum::extract::ws::Utf8Bytes;
use softhaptic_device::metrics::{MetricsAccumulator, TickInput};
use softhaptic_proto::exercise::Task;
use softhaptic_proto::record::DeviceRecord;
use softhaptic_proto::wire::{
    ExerciseState, GapCause, Hello, InclusionView, InclusionsMessage, Mode, PROTOCOL_VERSION,
    ReplayAction, ReplayControl, ReplayGap, ReplayMark, ReplaySpan, ReplayStatus, Role,
    ServerMessage,
};
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;
use tokio::time::Instant;

use super::check::recorded_scene;
use super::reader::{RecordedMessage, Recording};
use crate::access::{Access, AccessConfig, AccessError};
use crate::routes::{SERVER_NAME, serve_http, viewer_router};
use crate::stream::{EncodedFrame, FRAME_BACKLOG, StreamHub, ViewerLimits};

/// How often the player sends a `replay` status while playing.
const STATUS_PERIOD: Duration = Duration::from_secs(1);
/// Controls that may wait for the player (a viewer cannot click faster than this matters).
const CONTROL_QUEUE: usize = 32;

/// How to serve a replay.
#[derive(Debug, Clone)]
pub struct ReplayOptions {
    pub addr: SocketAddr,
    /// The viewer's files (built in, or `--web-dir`).
    pub viewer: crate::viewer::Viewer,
    /// Playback speed, 1.0 = real time.
    pub speed: f64,
    /// Start paused at the beginning (a viewer presses play).
    pub start_paused: bool,
    pub viewer_limits: ViewerLimits,
    /// Who may connect, as for a live server; [`start`] refuses an address beyond loopback
    /// without tokens.
    pub access: AccessConfig,
    /// Serve https and wss with this configuration; plain http when `None`.
    pub tls: Option<Arc<rustls::ServerConfig>>,
}

/// Why a replay could not start.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error(transparent)]
    Viewer(#[from] crate::viewer::ViewerError),
    #[error("{path}: nothing to replay: the recording has no contact frames")]
    Empty { path: PathBuf },
    #[error("--speed must be finite and in [0.01, 100], got {0}")]
    Speed(f64),
    #[error(transparent)]
    Check(#[from] super::check::CheckError),
    #[error(transparent)]
    Access(#[from] AccessError),
    #[error("could not listen on {addr}: {source}")]
    Bind {
        addr: SocketAddr,
        #[source]
        source: std::io::Error,
    },
    #[error("could not encode the {what} message: {source}")]
    Encode {
        what: &'static str,
        #[source]
        source: serde_json::Error,
    },
}

/// A replay being served.
pub struct RunningReplay {
    local_addr: SocketAddr,
    shutdown_tx: watch::Sender<bool>,
    http: JoinHandle<()>,
    player: JoinHandle<()>,
    hub: Arc<StreamHub>,
    /// Served over TLS: the viewer's URL is https.
    tls: bool,
}

impl RunningReplay {
    /// The address actually bound.
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// The viewer's URL.
    pub fn viewer_url(&self) -> String {
        let scheme = if self.tls { "https" } else { "http" };
        format!("{scheme}://{}/", self.local_addr)
    }

    /// The stream's counters.
    pub fn counters(&self) -> &crate::stream::StreamCounters {
        &self.hub.counters
    }

    /// Closes every viewer and stops serving.
    pub async fn shutdown(self) {
        let _ = self.shutdown_tx.send(true);
        let _ = self.player.await;
        let _ = tokio::time::timeout(
            crate::routes::VIEWERS_CLOSE_WAIT,
            self.hub.access.until_no_connections(),
        )
        .await;
        let _ = tokio::time::timeout(Duration::from_secs(5), self.http).await;
    }
}

/// Starts serving `recording` to viewers.
pub async fn start(
    recording: Recording,
    mut options: ReplayOptions,
) -> Result<RunningReplay, ReplayError> {
    options.access.check_bind(options.addr)?;
    options.viewer.check()?;
    let page_html = options.viewer.page_html()?;
    let speed = options.speed;
    if !(speed.is_finite()
        && (ReplayControl::SPEED_RANGE.0..=ReplayControl::SPEED_RANGE.1).contains(&speed))
    {
        return Err(ReplayError::Speed(speed));
    }
    if recording.contacts.is_empty() {
        return Err(ReplayError::Empty {
            path: recording.path.clone(),
        });
    }
    let listener = tokio::net::TcpListener::bind(options.addr)
        .await
        .map_err(|source| ReplayError::Bind {
            addr: options.addr,
            source,
        })?;
    let local_addr = listener.local_addr().map_err(|source| ReplayError::Bind {
        addr: options.addr,
        source,
    })?;
    let (shutdown_tx, shutdown_rx) = watch::channel(false);
    // The page's own origin is https when the replay serves TLS.
    options.access.secure_transport = options.tls.is_some();
    let caps = crate::tls::ConnectionCaps::for_limits(&options.access.limits);
    let access = Arc::new(Access::new(options.access, &page_html));
    let ReplayFeed {
        hub,
        scene_text,
        meshes,
        player,
    } = replay_feed(
        &recording,
        speed,
        options.start_paused,
        options.viewer_limits,
        access,
        shutdown_rx.clone(),
        None,
    )?;

    let app = viewer_router(
        &options.viewer,
        // The same text as the WebSocket `scene` message, as a live server serves it.
        Bytes::from(scene_text),
        meshes,
        Arc::clone(&hub),
    );
    let tls = options.tls.is_some();
    let http = serve_http(listener, app, options.tls, caps, shutdown_rx);
    Ok(RunningReplay {
        local_addr,
        shutdown_tx,
        http,
        player,
        hub,
        tls,
    })
}

/// A recording's replay as a stream hub, for a replay server or a lab hub: the hub (its
/// viewers' controls move the replay), the `scene` text and render meshes, and the player task
/// feeding it until `shutdown` turns true.
pub struct ReplayFeed {
    pub hub: Arc<StreamHub>,
    pub scene_text: String,
    pub meshes: HashMap<String, Bytes>,
    pub player: JoinHandle<()>,
}

/// Starts replaying `recording` into a stream hub of its own (see [`ReplayFeed`]).
pub fn replay_feed(
    recording: &Recording,
    speed: f64,
    start_paused: bool,
    limits: crate::stream::ViewerLimits,
    access: Arc<Access>,
    shutdown: watch::Receiver<bool>,
    mesh_url_prefix: Option<&str>,
) -> Result<ReplayFeed, ReplayError> {
    if recording.contacts.is_empty() {
        return Err(ReplayError::Empty {
            path: recording.path.clone(),
        });
    }
    // The render mesh comes from the recorded scene file (the message only names its URL).
    let scene = recorded_scene(recording)?;
    let mut meshes = HashMap::new();
    meshes.insert(
        scene.object_name.clone(),
        Bytes::from(scene.render_surface.to_shm1()),
    );
    let mut message = recording.scene.message.clone();
    // Served under another path (a lab hub's): the meshes' URLs say where.
    if let Some(prefix) = mesh_url_prefix {
        for m in &mut message.render_meshes {
            m.url = format!("{prefix}/{}.bin", m.name);
        }
    }
    let encode = |what: &'static str, m: ServerMessage| {
        m.encode()
            .map_err(|source| ReplayError::Encode { what, source })
    };
    let scene_text = encode("scene", ServerMessage::Scene(Box::new(message.clone())))?;
    let hello = Hello {
        protocol_version: PROTOCOL_VERSION,
        session_id: recording.build.session_id.clone(),
        // Set per connection by the stream hub.
        role: Role::Instructor,
        mode: Mode::Replay,
        server: SERVER_NAME.into(),
        // As the recorded session's device was: a SpaceMouse session renders no force.
        force_feedback: message.device.force_feedback,
        accepts_marks: true,
    };

    let (control_tx, control_rx) = mpsc::channel(CONTROL_QUEUE);
    let hub = Arc::new(
        StreamHub::new(
            &hello,
            Utf8Bytes::from(scene_text.clone()),
            limits,
            shutdown,
            Some(control_tx),
            access,
        )
        .map_err(|source| ReplayError::Encode {
            what: "hello",
            source,
        })?,
    );
    // The recording's marks, for every viewer as it connects (with their 3-D points).
    hub.preload_marks(&recording.marks);
    let player = Player::new(recording, speed, start_paused);
    let player = tokio::spawn(player.run(Arc::clone(&hub), control_rx));

    Ok(ReplayFeed {
        hub,
        scene_text,
        meshes,
        player,
    })
}

/// Most gaps a status lists (the longest, in time order): hours of a machine that loses a tick
/// every few seconds would otherwise make every status long.
const MAX_GAPS: usize = 200;
/// The loop's period: a lost tick is this much device time.
const PERIOD_S: f64 = 1e-3;

/// The stretches of `device` (in tick order) without ticks, in seconds from `start_ns`: ticks
/// the loop lost (`lost_before`), and ticks missing from the file (numbers skipped: a damaged
/// stretch the reader left out).
fn gaps(device: &[DeviceRecord], start_ns: u64) -> Vec<ReplayGap> {
    let seconds = |t: u64| t.saturating_sub(start_ns) as f64 * 1e-9;
    let mut out: Vec<ReplayGap> = device
        .windows(2)
        .filter_map(|pair| {
            let (a, b) = (&pair[0], &pair[1]);
            let start_s = seconds(a.time_ns);
            let missing = b.tick.saturating_sub(a.tick.saturating_add(1));
            if missing > 0 {
                Some(ReplayGap {
                    start_s,
                    end_s: seconds(b.time_ns).max(start_s),
                    ticks: missing,
                    cause: GapCause::Damaged,
                })
            } else if b.lost_before > 0 {
                // A device counting fixed steps does not advance its time over lost ticks; one
                // on the wall clock does: the gap is the longer of the two.
                let lost_s = b.lost_before as f64 * PERIOD_S;
                Some(ReplayGap {
                    start_s,
                    end_s: seconds(b.time_ns).max(start_s + lost_s),
                    ticks: b.lost_before,
                    cause: GapCause::LostTicks,
                })
            } else {
                None
            }
        })
        .collect();
    if out.len() > MAX_GAPS {
        out.sort_by(|x, y| (y.end_s - y.start_s).total_cmp(&(x.end_s - x.start_s)));
        out.truncate(MAX_GAPS);
        out.sort_by(|x, y| x.start_s.total_cmp(&y.start_s));
    }
    out
}

/// The stretches of `device` with the force above `safe_force_n`, in seconds from `start_ns`
/// (at most [`MAX_GAPS`], the longest, in time order).
fn above_safe(device: &[DeviceRecord], start_ns: u64, safe_force_n: f64) -> Vec<ReplaySpan> {
    let seconds = |t: u64| t.saturating_sub(start_ns) as f64 * 1e-9;
    let mut out: Vec<ReplaySpan> = Vec::new();
    let mut open: Option<(u64, u64)> = None;
    for d in device {
        let above = glam::DVec3::from_array(d.force_n).length() > safe_force_n;
        open = match (open, above) {
            (None, true) => Some((d.time_ns, d.time_ns)),
            (Some((first, _)), true) => Some((first, d.time_ns)),
            (Some((first, last)), false) => {
                out.push(ReplaySpan {
                    start_s: seconds(first),
                    end_s: seconds(last),
                });
                None
            }
            (None, false) => None,
        };
    }
    if let Some((first, last)) = open {
        out.push(ReplaySpan {
            start_s: seconds(first),
            end_s: seconds(last),
        });
    }
    if out.len() > MAX_GAPS {
        out.sort_by(|x, y| (y.end_s - y.start_s).total_cmp(&(x.end_s - x.start_s)));
        out.truncate(MAX_GAPS);
        out.sort_by(|x, y| x.start_s.total_cmp(&y.start_s));
    }
    out
}

/// Device time between two replayed `metrics` messages, as the live server sends them.
const METRICS_PERIOD_NS: u64 = 1_000_000_000;

/// The trainee's `metrics` messages a replay sends, on the recording's device-time axis: one
/// each second of ticks and the final one at the last tick, computed from the recorded ticks
/// as `info` and `export` compute them (the live loop's own, when the file holds every tick).
/// After a seek the replay sends the last of them at or before the new position (the metrics
/// before any tick, all zero, when there is none).
pub fn metrics_timeline(recording: &Recording) -> Vec<RecordedMessage> {
    let mut acc = MetricsAccumulator::new(super::tools::recorded_safe_force_n(recording));
    let mut out = Vec::new();
    let Some(first) = recording.device.first() else {
        return out;
    };
    let mut next_ns = first.time_ns.saturating_add(METRICS_PERIOD_NS);
    let mut push = |time_ns: u64, acc: &MetricsAccumulator, is_final: bool| {
        let message = crate::stream::metrics_message(&acc.metrics(), is_final);
        match ServerMessage::Metrics(message).encode() {
            Ok(json) => out.push(RecordedMessage { time_ns, json }),
            Err(e) => tracing::error!(error = %e, "could not encode replayed metrics"),
        }
    };
    for d in &recording.device {
        acc.update(&TickInput::from_record(d));
        if d.time_ns >= next_ns {
            push(d.time_ns, &acc, false);
            next_ns = d.time_ns.saturating_add(METRICS_PERIOD_NS);
        }
    }
    let last_ns = recording.device.last().map_or(first.time_ns, |d| d.time_ns);
    push(last_ns, &acc, true);
    out
}

/// The `inclusions` messages the live station sent, from the recording: at its first frame the
/// answer for instructors, and with each recorded attempt's start (for instructors) and each
/// palpation attempt's end (for everyone, `true`), at their device times (at most `end_ns`).
/// Empty for a scene without inclusions.
fn inclusions_timeline(recording: &Recording, end_ns: u64) -> Vec<(u64, bool, Utf8Bytes)> {
    let Some(recorded) = &recording.scene.inclusions else {
        return Vec::new();
    };
    // The object's pose: the scene message's meshes are the object's.
    let Some(mesh) = recording.scene.message.render_meshes.first() else {
        return Vec::new();
    };
    let views = InclusionView::placed(&recorded.placed, &mesh.object_in_world);
    let start_ns = recording.contacts.first().map_or(0, |c| c.time_ns);
    let message = |revealed, exercise_index, attempt| {
        ServerMessage::Inclusions(InclusionsMessage {
            revealed,
            exercise_index,
            attempt,
            inclusions: views.clone(),
        })
        .encode()
        .ok()
        .map(Utf8Bytes::from)
    };
    let mut out: Vec<(u64, bool, Utf8Bytes)> = message(false, None, None)
        .map(|text| (start_ns, false, text))
        .into_iter()
        .collect();
    for m in &recording.exercises {
        let revealed = match m.state {
            ExerciseState::Running => false,
            ExerciseState::Ended if matches!(m.exercise.task, Task::Palpation(_)) => true,
            ExerciseState::Ended => continue,
        };
        if let Some(text) = message(revealed, Some(m.index), Some(m.attempt)) {
            out.push((
                m.time_ns.clamp(start_ns, end_ns.max(start_ns)),
                revealed,
                text,
            ));
        }
    }
    // Stable: an attempt's end and the next one's start at the same time keep their order.
    out.sort_by_key(|(time_ns, _, _)| *time_ns);
    out
}

/// The replay clock and cursor.
struct Player {
    contacts: Vec<RecordedMessage>,
    /// The recorded `stats` and `exercise` messages and the replay's `metrics` ones, in
    /// device-time order.
    loop_stats: Vec<RecordedMessage>,
    /// The `metrics` messages alone, in device-time order, and those before any tick (all
    /// zero): what a seek sends for the new position.
    metrics: Vec<RecordedMessage>,
    no_metrics_yet: Option<Utf8Bytes>,
    /// Set by a seek (or a play that starts over): the metrics of the new position are due.
    metrics_stale: bool,
    /// Device time of the recording's first frame: replay time 0.
    start_ns: u64,
    duration_ns: u64,
    file: String,
    /// The stretches without ticks, for the timeline.
    gaps: Vec<ReplayGap>,
    /// The stretches above the safe force, for the timeline.
    above_safe: Vec<ReplaySpan>,
    /// The recording's marks, for the timeline.
    marks: Vec<ReplayMark>,
    speed: f64,
    paused: bool,
    /// Replay position (ns from `start_ns`) at `anchor`.
    anchor_pos_ns: u64,
    anchor: Instant,
    /// Next contact and stats message to send.
    next_contact: usize,
    next_stats: usize,
    /// Where the recorded scene's inclusions were told, as the live station told them
    /// ([`inclusions_timeline`]), and the next one to tell. A seek starts them over, so the
    /// answer stands as it stood at the new position for the viewers who connect after it.
    inclusions: Vec<(u64, bool, Utf8Bytes)>,
    next_inclusions: usize,
    /// `seq` of the next frame sent.
    seq: u64,
}

impl Player {
    fn new(recording: &Recording, speed: f64, paused: bool) -> Self {
        let start_ns = recording.contacts.first().map_or(0, |c| c.time_ns);
        let end_ns = recording.contacts.last().map_or(0, |c| c.time_ns);
        let mut loop_stats = recording.loop_stats.clone();
        // The final metrics come with the last frame, where the replay ends, even when the
        // ticks went on a little after it.
        let metrics: Vec<RecordedMessage> = metrics_timeline(recording)
            .into_iter()
            .map(|mut m| {
                m.time_ns = m.time_ns.min(end_ns);
                m
            })
            .collect();
        loop_stats.extend(metrics.iter().cloned());
        // The station's exercises as its viewers saw them start and end (without the files,
        // which were never sent to a viewer).
        loop_stats.extend(recording.exercises.iter().filter_map(|m| {
            let mut m = m.clone();
            m.exercise_file = None;
            m.exercise_toml = None;
            let time_ns = m.time_ns.min(end_ns);
            let json = ServerMessage::Exercise(Box::new(m)).encode().ok()?;
            Some(RecordedMessage { time_ns, json })
        }));
        // Stable: a stats and a metrics message at the same time keep that order.
        loop_stats.sort_by_key(|m| m.time_ns);
        let safe_force_n = super::tools::recorded_safe_force_n(recording);
        let no_metrics_yet = ServerMessage::Metrics(crate::stream::metrics_message(
            &MetricsAccumulator::new(safe_force_n).metrics(),
            false,
        ))
        .encode()
        .map(Utf8Bytes::from)
        .ok();
        Self {
            contacts: recording.contacts.clone(),
            loop_stats,
            metrics,
            no_metrics_yet,
            metrics_stale: false,
            start_ns,
            duration_ns: end_ns.saturating_sub(start_ns),
            file: recording.file_name(),
            gaps: gaps(&recording.device, start_ns),
            marks: recording
                .marks
                .iter()
                .map(|m| ReplayMark {
                    id: m.id,
                    time_s: m.time_ns.saturating_sub(start_ns) as f64 * 1e-9,
                    note: m.note.clone(),
                })
                .collect(),
            above_safe: above_safe(&recording.device, start_ns, safe_force_n),
            speed,
            paused,
            anchor_pos_ns: 0,
            anchor: Instant::now(),
            next_contact: 0,
            next_stats: 0,
            inclusions: inclusions_timeline(recording, end_ns),
            next_inclusions: 0,
            seq: 0,
        }
    }

    /// Replay position now.
    fn position_ns(&self, now: Instant) -> u64 {
        if self.paused {
            return self.anchor_pos_ns;
        }
        let elapsed_ns = now.saturating_duration_since(self.anchor).as_nanos() as f64;
        let pos = self.anchor_pos_ns as f64 + elapsed_ns * self.speed;
        (pos as u64).min(self.duration_ns)
    }

    fn status(&self, now: Instant) -> ReplayStatus {
        ReplayStatus {
            duration_s: self.duration_ns as f64 * 1e-9,
            time_s: self.position_ns(now) as f64 * 1e-9,
            paused: self.paused,
            speed: self.speed,
            file: self.file.clone(),
            gaps: self.gaps.clone(),
            above_safe: self.above_safe.clone(),
            marks: self.marks.clone(),
        }
    }

    fn apply(&mut self, control: ReplayControl, now: Instant) {
        let pos = self.position_ns(now);
        if let Some(speed) = control.speed {
            self.speed = speed;
        }
        match control.action {
            ReplayAction::Pause => {
                self.anchor_pos_ns = pos;
                self.paused = true;
            }
            ReplayAction::Play => {
                // Play at the end starts over.
                self.anchor_pos_ns = if pos >= self.duration_ns { 0 } else { pos };
                if self.anchor_pos_ns == 0 {
                    self.rewind_to(0);
                }
                self.paused = false;
            }
            ReplayAction::Seek => {
                let target_ns = control
                    .time_s
                    .map_or(pos, |t| ((t * 1e9) as u64).min(self.duration_ns));
                self.anchor_pos_ns = target_ns;
                self.rewind_to(target_ns);
            }
        }
        self.anchor = now;
    }

    /// Puts the cursors just before `pos_ns`, so that the frame at the new position is sent next.
    fn rewind_to(&mut self, pos_ns: u64) {
        let t = self.start_ns + pos_ns;
        // The frame in effect at `t` (the last one at or before it) is sent at once.
        self.next_contact = self
            .contacts
            .partition_point(|c| c.time_ns <= t)
            .saturating_sub(1);
        self.next_stats = self.loop_stats.partition_point(|s| s.time_ns < t);
        self.next_inclusions = 0;
        self.metrics_stale = true;
    }

    /// The `metrics` in effect at `pos_ns`: the last sent at or before it, or those before any
    /// tick.
    fn metrics_at(&self, pos_ns: u64) -> Option<Utf8Bytes> {
        let t = self.start_ns + pos_ns;
        match self.metrics.partition_point(|m| m.time_ns <= t) {
            0 => self.no_metrics_yet.clone(),
            n => Some(Utf8Bytes::from(self.metrics[n - 1].json.as_str())),
        }
    }

    /// After a seek, sends the metrics of the new position, so that a viewer does not go on
    /// showing those of where the replay was (a paused replay sends nothing else until played).
    fn send_metrics_if_stale(&mut self, hub: &StreamHub, now: Instant) {
        if !std::mem::take(&mut self.metrics_stale) {
            return;
        }
        if let Some(text) = self.metrics_at(self.position_ns(now)) {
            let _ = hub.stats.send(text);
        }
    }

    /// Sends everything due at `pos_ns`, in order; when the player fell more than a viewer's
    /// backlog behind (a stall, a high speed), only the newest [`FRAME_BACKLOG`] frames.
    fn send_due(&mut self, hub: &StreamHub, pos_ns: u64) {
        let t = self.start_ns + pos_ns;
        let due_end = self.contacts.partition_point(|c| c.time_ns <= t);
        let from = self.next_contact.max(due_end.saturating_sub(FRAME_BACKLOG));
        for i in from..due_end {
            let frame = self.contacts[i].clone();
            self.send_frame(hub, &frame);
        }
        self.next_contact = self.next_contact.max(due_end);
        while let Some(s) = self.loop_stats.get(self.next_stats) {
            if s.time_ns > t {
                break;
            }
            self.send_stats(hub, s);
            self.next_stats += 1;
        }
        self.send_inclusions_due(hub, t);
    }

    /// Tells the inclusions as the live station had told them by device time `t`.
    fn send_inclusions_due(&mut self, hub: &StreamHub, t: u64) {
        while let Some((time_ns, revealed, text)) = self.inclusions.get(self.next_inclusions) {
            if *time_ns > t {
                break;
            }
            if *revealed {
                hub.inclusions.reveal(text.clone());
            } else {
                hub.inclusions.show_instructors(text.clone());
            }
            self.next_inclusions += 1;
        }
    }

    fn send_frame(&mut self, hub: &StreamHub, recorded: &RecordedMessage) {
        // The reader checked every recorded frame decodes.
        let Ok(ServerMessage::Contact(mut frame)) = ServerMessage::decode(&recorded.json) else {
            return;
        };
        frame.seq = self.seq;
        self.seq += 1;
        match EncodedFrame::new(&frame) {
            Ok(encoded) => {
                let encoded = Arc::new(encoded);
                // A viewer that connects now (a paused replay sends nothing more) starts here.
                hub.hold_frame(Arc::clone(&encoded));
                let _ = hub.frames.send(encoded);
                hub.counters.frames_sent.fetch_add(1, Ordering::Relaxed);
            }
            Err(e) => tracing::error!(error = %e, "could not encode a replayed frame"),
        }
    }

    fn send_stats(&self, hub: &StreamHub, recorded: &RecordedMessage) {
        let mut stats = match ServerMessage::decode(&recorded.json) {
            Ok(ServerMessage::Stats(stats)) => stats,
            Ok(ServerMessage::Metrics(_)) => {
                let _ = hub.stats.send(Utf8Bytes::from(recorded.json.as_str()));
                return;
            }
            // On the exercise feed, which keeps the latest for a viewer that connects later.
            Ok(ServerMessage::Exercise(_)) => {
                hub.exercise
                    .publish(Utf8Bytes::from(recorded.json.as_str()));
                return;
            }
            _ => return,
        };
        // Viewer counts are the replay's own.
        stats.viewers = hub.counters.viewers.load(Ordering::Relaxed);
        stats.dropped_frames = hub.counters.dropped_frames.load(Ordering::Relaxed);
        if let Ok(text) = ServerMessage::Stats(stats).encode() {
            let _ = hub.stats.send(Utf8Bytes::from(text));
        }
    }

    fn send_status(&self, hub: &StreamHub, now: Instant) {
        match ServerMessage::Replay(self.status(now)).encode() {
            // The stats channel carries every low-rate message to every viewer.
            Ok(text) => {
                let _ = hub.stats.send(Utf8Bytes::from(text));
            }
            Err(e) => tracing::error!(error = %e, "could not encode the replay status"),
        }
    }

    /// The next instant something is due: the next frame or stats message, at the current speed.
    fn next_due(&self, now: Instant) -> Option<Instant> {
        if self.paused {
            return None;
        }
        let pos = self.position_ns(now);
        let next_t = [
            self.contacts.get(self.next_contact).map(|c| c.time_ns),
            self.loop_stats.get(self.next_stats).map(|s| s.time_ns),
        ]
        .into_iter()
        .flatten()
        .min()?;
        let ahead_ns = next_t.saturating_sub(self.start_ns).saturating_sub(pos) as f64 / self.speed;
        Some(now + Duration::from_nanos(ahead_ns as u64))
    }

    async fn run(mut self, hub: Arc<StreamHub>, mut controls: mpsc::Receiver<ReplayControl>) {
        let mut shutdown = hub.shutdown.clone();
        let mut status_tick = tokio::time::interval(STATUS_PERIOD);
        status_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        self.anchor = Instant::now();
        // The recording's first frame, so that a replay started paused shows the tool where the
        // session began (no viewer is connected yet: it is held for the viewers to come).
        if self.paused
            && let Some(first) = self.contacts.first().cloned()
        {
            self.send_frame(&hub, &first);
            self.next_contact = 1;
            self.send_inclusions_due(&hub, self.start_ns);
        }
        loop {
            let now = Instant::now();
            if !self.paused {
                let pos = self.position_ns(now);
                self.send_due(&hub, pos);
                if pos >= self.duration_ns && self.next_contact >= self.contacts.len() {
                    // The end: hold the last frame, paused, and say so.
                    self.anchor_pos_ns = self.duration_ns;
                    self.paused = true;
                    self.send_status(&hub, now);
                }
            }
            let wake = self.next_due(now).unwrap_or(now + STATUS_PERIOD);
            tokio::select! {
                _ = shutdown.changed() => return,
                _ = tokio::time::sleep_until(wake) => {}
                _ = status_tick.tick() => {
                    // Also while paused: a viewer that just connected learns the replay's state
                    // within a second.
                    self.send_status(&hub, Instant::now());
                }
                control = controls.recv() => {
                    let Some(control) = control else { return };
                    let now = Instant::now();
                    self.apply(control, now);
                    self.send_metrics_if_stale(&hub, now);
                    if control.action == ReplayAction::Seek {
                        // Show the frame at the new position even when paused.
                        let pos = self.position_ns(now);
                        let t = self.start_ns + pos;
                        let at = self.contacts.partition_point(|c| c.time_ns <= t);
                        if let Some(frame) = at.checked_sub(1).map(|i| self.contacts[i].clone()) {
                            self.send_frame(&hub, &frame);
                            self.next_contact = at;
                        }
                        self.send_inclusions_due(&hub, t);
                    }
                    self.send_status(&hub, now);
                }
            }
        }
    }
}

#[cfg(test)]
mod gap_tests {
    use super::*;

    fn record(tick: u64, time_ns: u64, lost_before: u64) -> DeviceRecord {
        DeviceRecord {
            tick,
            time_ns,
            sample: None,
            device_fault: false,
            device_error: None,
            command_error: None,
            lost_before,
            in_contact: false,
            depth_m: 0.0,
            force_n: [0.0; 3],
            flags: 0,
            guide: None,
        }
    }

    #[test]
    fn lost_ticks_and_missing_records_are_gaps_in_seconds_from_the_start() {
        let ms = 1_000_000;
        let device = vec![
            record(0, 10 * ms, 0),
            record(1, 11 * ms, 0),
            // 5 ticks lost on a fixed-step clock: the time does not jump.
            record(2, 12 * ms, 5),
            record(3, 13 * ms, 0),
            // Ticks 4..=999 are not in the file.
            record(1000, 1010 * ms, 0),
        ];
        let g = gaps(&device, 10 * ms);
        assert_eq!(g.len(), 2, "{g:?}");
        assert_eq!(g[0].cause, GapCause::LostTicks);
        assert_eq!(g[0].ticks, 5);
        assert!((g[0].start_s - 0.001).abs() < 1e-12 && (g[0].end_s - 0.006).abs() < 1e-12);
        assert_eq!(g[1].cause, GapCause::Damaged);
        assert_eq!(g[1].ticks, 996);
        assert!((g[1].start_s - 0.003).abs() < 1e-12 && (g[1].end_s - 1.0).abs() < 1e-12);
        assert!(gaps(&device[..2], 10 * ms).is_empty());
    }

    #[test]
    fn stretches_above_the_safe_force_are_marked() {
        let ms = 1_000_000;
        let mut device: Vec<DeviceRecord> =
            (0..10u64).map(|i| record(i, (10 + i) * ms, 0)).collect();
        for (i, f) in [(2usize, 2.5), (3, 3.0), (4, 1.0), (8, 2.1), (9, 2.2)] {
            device[i].force_n = [0.0, f, 0.0];
        }
        let spans = above_safe(&device, 10 * ms, 2.0);
        assert_eq!(spans.len(), 2, "{spans:?}");
        assert!((spans[0].start_s - 0.002).abs() < 1e-12 && (spans[0].end_s - 0.003).abs() < 1e-12);
        // Still above at the end: closed at the last tick.
        assert!((spans[1].start_s - 0.008).abs() < 1e-12 && (spans[1].end_s - 0.009).abs() < 1e-12);
        assert!(above_safe(&device, 10 * ms, 5.0).is_empty());
    }

    #[test]
    fn many_gaps_keep_the_longest_in_time_order() {
        let device: Vec<DeviceRecord> = (0..1000u64)
            .map(|i| record(i, i * 1_000_000, if i % 2 == 1 { i % 7 + 1 } else { 0 }))
            .collect();
        let g = gaps(&device, 0);
        assert_eq!(g.len(), MAX_GAPS);
        assert!(g.windows(2).all(|w| w[0].start_s <= w[1].start_s));
        assert!(g.iter().all(|x| x.ticks >= 5), "the shortest were dropped");
    }
}
