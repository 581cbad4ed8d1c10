//! What a live session says of itself on a lab's dashboard: a [`StationSummary`] of its trainee,
//! exercise, force and device, kept from what the viewers are sent, and the [`Alert`]s it raises
//! until an instructor acknowledges them.
//!
//! [`track`] reads the stream hub's broadcasts as a viewer does (so the loop never waits for
//! it): each contact frame (the force's largest in each 100 ms, contact, warm motors), each
//! `stats` (the device's state, lost ticks), each `metrics` (the session's key figures, computed
//! from every 1 kHz tick) and each `exercise` message. Alerts are raised on the edge of what
//! they report:
//!
//! - **above the safe force**: a frame's force going above the scene's safe force (not again
//!   while it stays above), or the metrics' time above it growing while no frame showed it (a
//!   spike between two frames);
//! - **device fault** and **needs calibration**: `stats.device` turning to a fault, or to a
//!   state that waits for the operator to calibrate;
//! - **exercise failed**: an attempt ending without meeting its pass marks.
//!
//! While an alert of a kind is not acknowledged, no other of that kind is raised: one trainee
//! pressing too hard for a minute is one alert, not sixty. Every alert, as it is raised and as
//! it is acknowledged, goes to [`SummaryFeed::alerts`] (the recording keeps them).

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::{SystemTime, UNIX_EPOCH};

use axum::extract::ws::Utf8Bytes;
use softhaptic_proto::contact::ContactFlags;
use softhaptic_proto::exercise::AttemptEnd;
use softhaptic_proto::wire::{
    Acknowledgement, Alert, AlertKind, ContactFrame, DeviceStatus, DeviceSummary, ExerciseMessage,
    ExerciseState, ExerciseSummary, FORCE_SAMPLES_PER_S, MAX_ALERT_DETAIL_CHARS,
    MAX_SUMMARY_ALERTS, MetricsMessage, ServerMessage, StationSummary, StatsMessage,
};
use tokio::sync::broadcast;

use super::StreamHub;

/// The force samples' window, ns (the dashboard's 100 ms).
const WINDOW_NS: u64 = 1_000_000_000 / FORCE_SAMPLES_PER_S as u64;
/// Alerts a session keeps at most (the oldest acknowledged go first).
const MAX_ALERTS: usize = 1000;
/// Alert events a slow recorder may fall behind by.
const ALERT_BACKLOG: usize = 64;

/// A live session's summary and alerts.
pub struct SummaryFeed {
    tracker: Mutex<Tracker>,
    /// Each alert as it is raised and as it is acknowledged, its JSON, for the recording.
    pub alerts: broadcast::Sender<Utf8Bytes>,
}

/// Why an acknowledgement was not taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AcknowledgeRefusal {
    /// No alert has that id in this session.
    NoSuchAlert,
    /// Someone acknowledged it already.
    AlreadyAcknowledged,
}

impl AcknowledgeRefusal {
    pub fn reason(self) -> &'static str {
        match self {
            AcknowledgeRefusal::NoSuchAlert => "this session has no alert with that id",
            AcknowledgeRefusal::AlreadyAcknowledged => "that alert is already acknowledged",
        }
    }
}

#[derive(Default)]
struct Tracker {
    trainee: Option<String>,
    exercise: Option<ExerciseSummary>,
    in_contact: bool,
    motors_warm: bool,
    /// Completed 100 ms windows `(start, largest force)`, oldest first, and the current one.
    windows: VecDeque<(u64, f32)>,
    current: Option<(u64, f32)>,
    safe_force_n: f64,
    peak_force_n: f64,
    time_above_safe_s: f64,
    time_in_contact_s: f64,
    pushes: u64,
    fault_ticks: u64,
    lost_ticks: u64,
    device: DeviceStatus,
    /// Device time of the latest frame.
    time_ns: u64,
    /// The latest frame's force was above the safe force: an alert is raised as the force goes
    /// above, not again while it stays there (the instructor acknowledged that press).
    above: bool,
    /// A frame above the safe force came since the last `metrics` message (which then says
    /// nothing new).
    above_since_metrics: bool,
    alerts: Vec<Alert>,
}

impl SummaryFeed {
    /// The feed of a session whose scene's safe force is `safe_force_n`.
    pub fn new(safe_force_n: f64) -> Self {
        Self {
            tracker: Mutex::new(Tracker {
                safe_force_n,
                ..Tracker::default()
            }),
            alerts: broadcast::channel(ALERT_BACKLOG).0,
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Tracker> {
        self.tracker.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The summary as things stand.
    pub fn summary(&self) -> StationSummary {
        let t = self.lock();
        let since = t.time_ns.saturating_sub(1_000_000_000);
        let force_n = t
            .windows
            .iter()
            .chain(t.current.iter())
            .filter(|(start, _)| *start >= since)
            .map(|(_, f)| *f)
            .collect::<Vec<f32>>();
        let force_n = force_n[force_n.len().saturating_sub(FORCE_SAMPLES_PER_S)..].to_vec();
        // Every alert not acknowledged, then the latest acknowledged, in the order raised.
        let open = t.alerts.iter().filter(|a| a.acknowledged.is_none()).count();
        let room_for_acknowledged = MAX_SUMMARY_ALERTS.saturating_sub(open);
        let acknowledged_total = t.alerts.len() - open;
        let mut skip_acknowledged = acknowledged_total.saturating_sub(room_for_acknowledged);
        let alerts = t
            .alerts
            .iter()
            .filter(|a| {
                if a.acknowledged.is_none() {
                    return true;
                }
                if skip_acknowledged > 0 {
                    skip_acknowledged -= 1;
                    return false;
                }
                true
            })
            .take(MAX_SUMMARY_ALERTS)
            .cloned()
            .collect();
        StationSummary {
            trainee: t.trainee.clone(),
            exercise: t.exercise.clone(),
            in_contact: t.in_contact,
            force_n,
            safe_force_n: t.safe_force_n,
            peak_force_n: t.peak_force_n,
            time_above_safe_s: t.time_above_safe_s,
            time_in_contact_s: t.time_in_contact_s,
            pushes: t.pushes,
            device: DeviceSummary {
                state: t.device,
                fault_ticks: t.fault_ticks,
                lost_ticks: t.lost_ticks,
                motors_warm: t.motors_warm,
            },
            alerts,
        }
    }

    /// The device's state on the last `stats`.
    pub fn device_state(&self) -> DeviceStatus {
        self.lock().device
    }

    /// Every alert of the session so far.
    pub fn all_alerts(&self) -> Vec<Alert> {
        self.lock().alerts.clone()
    }

    /// An instructor (`by`, in words) acknowledges alert `id`.
    pub fn acknowledge(&self, id: u32, by: &str) -> Result<(), AcknowledgeRefusal> {
        let mut t = self.lock();
        let alert = t
            .alerts
            .iter_mut()
            .find(|a| a.id == id)
            .ok_or(AcknowledgeRefusal::NoSuchAlert)?;
        if alert.acknowledged.is_some() {
            return Err(AcknowledgeRefusal::AlreadyAcknowledged);
        }
        alert.acknowledged = Some(Acknowledgement {
            by: clip(by),
            unix_ms: unix_ms(),
        });
        let alert = alert.clone();
        drop(t);
        self.publish(&alert);
        Ok(())
    }

    fn publish(&self, alert: &Alert) {
        if let Ok(json) = serde_json::to_string(alert) {
            // No recorder listening is not an error.
            let _ = self.alerts.send(Utf8Bytes::from(json));
        }
    }

    /// Raises an alert of `kind` unless one of that kind waits for an acknowledgement.
    fn raise(&self, t: &mut Tracker, kind: AlertKind, detail: String) {
        if t.alerts
            .iter()
            .any(|a| a.kind == kind && a.acknowledged.is_none())
        {
            return;
        }
        if t.alerts.len() >= MAX_ALERTS {
            match t.alerts.iter().position(|a| a.acknowledged.is_some()) {
                Some(i) => {
                    t.alerts.remove(i);
                }
                None => return,
            }
        }
        let id = t.alerts.last().map_or(1, |a| a.id + 1);
        let alert = Alert {
            id,
            kind,
            time_ns: t.time_ns,
            unix_ms: unix_ms(),
            detail: clip(&detail),
            acknowledged: None,
        };
        tracing::info!(alert = id, kind = ?kind, "alert: {}", alert.detail);
        self.publish(&alert);
        t.alerts.push(alert);
    }

    /// A contact frame, as the viewers get it.
    pub fn on_frame(&self, frame: &ContactFrame) {
        let mut t = self.lock();
        t.time_ns = frame.time_ns;
        t.in_contact = frame.in_contact;
        t.motors_warm = frame.flags.contains(ContactFlags::MOTORS_WARM);
        let force = frame.force_n.length();
        let force = if force.is_finite() { force } else { 0.0 };
        let start = frame.time_ns - frame.time_ns % WINDOW_NS;
        match &mut t.current {
            Some((s, peak)) if *s == start => *peak = peak.max(force as f32),
            _ => {
                if let Some(done) = t.current.take() {
                    t.windows.push_back(done);
                    while t.windows.len() > FORCE_SAMPLES_PER_S {
                        t.windows.pop_front();
                    }
                }
                t.current = Some((start, force as f32));
            }
        }
        let above = t.safe_force_n > 0.0 && force > t.safe_force_n;
        if above && !t.above {
            let detail = format!("{force:.2} N, above the safe {:.2} N", t.safe_force_n);
            self.raise(&mut t, AlertKind::AboveSafeForce, detail);
        }
        t.above = above;
        t.above_since_metrics |= above;
    }

    /// A `stats` message.
    pub fn on_stats(&self, stats: &StatsMessage) {
        let mut t = self.lock();
        t.lost_ticks = stats.overruns;
        let before = std::mem::replace(&mut t.device, stats.device);
        if before == stats.device {
            return;
        }
        let calibration = matches!(
            stats.device,
            DeviceStatus::NeedsCalibration
                | DeviceStatus::NeedsCalibrationReset
                | DeviceStatus::CalibrationUpdating
        );
        match stats.device {
            DeviceStatus::Ok => {}
            _ if calibration => self.raise(
                &mut t,
                AlertKind::NeedsCalibration,
                stats.device.message().to_owned(),
            ),
            _ => self.raise(
                &mut t,
                AlertKind::DeviceFault,
                stats.device.message().to_owned(),
            ),
        }
    }

    /// A `metrics` message.
    pub fn on_metrics(&self, m: &MetricsMessage) {
        let mut t = self.lock();
        // Time above the safe force that no frame showed: a spike between two frames.
        let grew = m.time_above_safe_s > t.time_above_safe_s
            && !std::mem::take(&mut t.above_since_metrics);
        t.safe_force_n = m.safe_force_n;
        t.peak_force_n = m.peak_force_n;
        t.time_above_safe_s = m.time_above_safe_s;
        t.time_in_contact_s = m.time_in_contact_s;
        t.pushes = m.pushes;
        t.fault_ticks = m.device_fault_ticks;
        if grew {
            let detail = format!(
                "force above the safe {:.2} N for {:.3} s so far (peak {:.2} N)",
                m.safe_force_n, m.time_above_safe_s, m.peak_force_n
            );
            self.raise(&mut t, AlertKind::AboveSafeForce, detail);
        }
    }

    /// An `exercise` message.
    pub fn on_exercise(&self, m: &ExerciseMessage) {
        let mut t = self.lock();
        t.trainee = Some(m.trainee.clone());
        let passed = m.result.as_ref().map(|r| r.passed);
        let was_ended = t
            .exercise
            .as_ref()
            .is_some_and(|e| e.index == m.index && e.attempt == m.attempt && e.passed.is_some());
        t.exercise = Some(ExerciseSummary {
            name: m.exercise.name.clone(),
            index: m.index,
            count: m.count,
            attempt: m.attempt,
            state: m.state,
            remaining_s: m.remaining_s,
            passed: if m.state == ExerciseState::Ended {
                passed
            } else {
                None
            },
        });
        if m.state == ExerciseState::Ended && passed == Some(false) && !was_ended {
            let how = match m.result.as_ref().map(|r| r.ended) {
                Some(AttemptEnd::TimeLimit) => "the time limit ran out",
                Some(AttemptEnd::Completed) => "completed without meeting the pass marks",
                Some(AttemptEnd::Stopped) => "stopped",
                None => "ended",
            };
            let detail = format!("{}: attempt {} failed ({how})", m.exercise.name, m.attempt);
            self.raise(&mut t, AlertKind::ExerciseFailed, detail);
        }
    }
}

/// Keeps `hub`'s summary from its broadcasts until the session ends.
pub async fn track(hub: Arc<StreamHub>) {
    let feed = Arc::clone(&hub.summary);
    let mut frames = hub.frames.subscribe();
    let mut stats = hub.stats.subscribe();
    let mut exercise = hub.exercise.messages.subscribe();
    let mut shutdown = hub.shutdown.clone();
    loop {
        tokio::select! {
            _ = shutdown.changed() => break,
            frame = frames.recv() => match frame {
                Ok(frame) => {
                    if let Ok(ServerMessage::Contact(f)) =
                        ServerMessage::decode(frame.text_for(0).as_str())
                    {
                        feed.on_frame(&f);
                    }
                }
                // A frame missed costs one sample of a sparkline; the metrics catch any force.
                Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(broadcast::error::RecvError::Closed) => break,
            },
            text = stats.recv() => match text {
                Ok(text) => match ServerMessage::decode(text.as_str()) {
                    Ok(ServerMessage::Stats(s)) => feed.on_stats(&s),
                    Ok(ServerMessage::Metrics(m)) => feed.on_metrics(&m),
                    _ => {}
                },
                Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(broadcast::error::RecvError::Closed) => break,
            },
            text = exercise.recv() => match text {
                Ok(text) => {
                    if let Ok(ServerMessage::Exercise(m)) = ServerMessage::decode(text.as_str()) {
                        feed.on_exercise(&m);
                    }
                }
                Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(broadcast::error::RecvError::Closed) => break,
            },
        }
    }
}

fn clip(text: &str) -> String {
    text.chars().take(MAX_ALERT_DETAIL_CHARS).collect()
}

fn unix_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use softhaptic_proto::wire::{MessageVector, message_vectors};

    fn vector(name: &str) -> ServerMessage {
        message_vectors()
            .unwrap()
            .into_iter()
            .find_map(|v| match v {
                MessageVector::Valid { name: n, json } if n == name => {
                    Some(ServerMessage::decode(&json.to_string()).unwrap())
                }
                _ => None,
            })
            .unwrap_or_else(|| panic!("no vector {name}"))
    }

    fn stats(device: DeviceStatus) -> StatsMessage {
        let ServerMessage::Stats(mut s) = vector("stats") else {
            panic!()
        };
        s.device = device;
        s
    }

    fn kinds(feed: &SummaryFeed) -> Vec<(AlertKind, bool)> {
        feed.all_alerts()
            .iter()
            .map(|a| (a.kind, a.acknowledged.is_some()))
            .collect()
    }

    #[test]
    fn a_fault_is_one_alert_until_acknowledged_then_a_new_one_can_come() {
        let feed = SummaryFeed::new(2.0);
        let mut recorded = feed.alerts.subscribe();
        feed.on_stats(&stats(DeviceStatus::Ok));
        assert!(feed.all_alerts().is_empty());
        feed.on_stats(&stats(DeviceStatus::Disconnected));
        feed.on_stats(&stats(DeviceStatus::Ok));
        feed.on_stats(&stats(DeviceStatus::Disconnected));
        assert_eq!(kinds(&feed), [(AlertKind::DeviceFault, false)]);
        feed.acknowledge(1, "instructor at 10.0.0.7:1 on a hub")
            .unwrap();
        assert_eq!(
            feed.acknowledge(1, "x"),
            Err(AcknowledgeRefusal::AlreadyAcknowledged)
        );
        assert_eq!(
            feed.acknowledge(9, "x"),
            Err(AcknowledgeRefusal::NoSuchAlert)
        );
        feed.on_stats(&stats(DeviceStatus::NeedsCalibration));
        feed.on_stats(&stats(DeviceStatus::ForceLatched));
        assert_eq!(
            kinds(&feed),
            [
                (AlertKind::DeviceFault, true),
                (AlertKind::NeedsCalibration, false),
                (AlertKind::DeviceFault, false)
            ]
        );
        let summary = feed.summary();
        assert_eq!(summary.device.state, DeviceStatus::ForceLatched);
        assert_eq!(summary.alerts.len(), 3);
        // Each raise and the acknowledgement went to the recording, in order.
        let mut events = Vec::new();
        while let Ok(text) = recorded.try_recv() {
            events.push(serde_json::from_str::<Alert>(text.as_str()).unwrap());
        }
        let seen: Vec<(u32, bool)> = events
            .iter()
            .map(|a| (a.id, a.acknowledged.is_some()))
            .collect();
        assert_eq!(seen, [(1, false), (1, true), (2, false), (3, false)]);
    }

    #[test]
    fn the_force_comes_as_the_largest_in_each_100_ms_of_the_last_second() {
        let feed = SummaryFeed::new(2.0);
        let ServerMessage::Contact(mut frame) = vector("contact_pressing") else {
            panic!()
        };
        // 3 s of frames at 50 Hz, the force rising 0.01 N a frame.
        for i in 0..150u64 {
            frame.time_ns = i * 20_000_000;
            frame.force_n =
                serde_json::from_value(serde_json::json!([0.0, 0.01 * i as f64, 0.0])).unwrap();
            feed.on_frame(&frame);
        }
        let s = feed.summary();
        assert_eq!(s.force_n.len(), FORCE_SAMPLES_PER_S);
        // The last window holds frames 145..149; the one before, 140..144.
        assert!((s.force_n[9] - 1.49).abs() < 1e-5, "{:?}", s.force_n);
        assert!((s.force_n[8] - 1.44).abs() < 1e-5, "{:?}", s.force_n);
        assert!(feed.all_alerts().is_empty(), "below the safe 2 N");
        frame.force_n = serde_json::from_value(serde_json::json!([0.0, 2.5, 0.0])).unwrap();
        frame.time_ns += 20_000_000;
        feed.on_frame(&frame);
        assert_eq!(kinds(&feed), [(AlertKind::AboveSafeForce, false)]);
        // Acknowledged, the press that goes on above is not raised again; the next one is.
        feed.acknowledge(1, "instructor").unwrap();
        for _ in 0..3 {
            frame.time_ns += 20_000_000;
            feed.on_frame(&frame);
        }
        assert_eq!(kinds(&feed), [(AlertKind::AboveSafeForce, true)]);
        let below = frame.force_n * 0.1;
        let above = frame.force_n;
        for force in [below, above] {
            frame.force_n = force;
            frame.time_ns += 20_000_000;
            feed.on_frame(&frame);
        }
        assert_eq!(
            kinds(&feed),
            [
                (AlertKind::AboveSafeForce, true),
                (AlertKind::AboveSafeForce, false)
            ]
        );
    }

    #[test]
    fn a_failed_attempt_is_an_alert_once() {
        let feed = SummaryFeed::new(2.0);
        let ServerMessage::Exercise(mut ended) = vector("exercise_ended") else {
            panic!()
        };
        if let Some(r) = ended.result.as_mut() {
            r.passed = false;
        }
        feed.on_exercise(&ended);
        feed.on_exercise(&ended);
        assert_eq!(kinds(&feed), [(AlertKind::ExerciseFailed, false)]);
        let detail = &feed.all_alerts()[0].detail;
        assert!(
            detail.ends_with("failed (the time limit ran out)")
                || detail.ends_with("failed (stopped)")
                || detail.ends_with("failed (completed without meeting the pass marks)"),
            "{detail}"
        );
        let s = feed.summary();
        assert_eq!(s.trainee.as_deref(), Some("ana"));
        assert_eq!(s.exercise.unwrap().passed, Some(false));
    }
}
