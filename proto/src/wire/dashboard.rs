//! The hub's dashboard of every station (proto/WIRE.md, "Dashboard"): what a station says of its
//! trainee and device once a second ([`StationSummary`], in its heartbeat), the alerts it raises
//! until an instructor acknowledges them ([`Alert`]), the hub's `dashboard` message to its
//! dashboard pages, and the instructor's actions on a station (`station_action`, answered by
//! `action_result`).
//!
//! A summary is small on purpose: a hub relays summaries, not frames, to its dashboard pages, so
//! a page costs the same whatever the stations' frame rate; the force comes as the largest in
//! each 100 ms of the last second, and the page keeps the sparkline's history itself.

use serde::{Deserialize, Serialize};

use super::{DeviceStatus, ExerciseAction, ExerciseState};

/// Samples of [`StationSummary::force_n`] a second: the largest force in each 100 ms.
pub const FORCE_SAMPLES_PER_S: usize = 10;
/// Alerts a summary carries at most: every one not yet acknowledged first, then the latest
/// acknowledged.
pub const MAX_SUMMARY_ALERTS: usize = 32;
/// Longest alert detail, characters.
pub const MAX_ALERT_DETAIL_CHARS: usize = 200;

/// What a station says of its trainee, exercise and device once a second (in its heartbeat).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StationSummary {
    /// Who is being assessed (`--trainee`), or `null`.
    pub trainee: Option<String>,
    /// Where the station's exercise stands, or `null` where none run.
    pub exercise: Option<ExerciseSummary>,
    /// Whether the tool touched the object on the latest frame.
    pub in_contact: bool,
    /// The largest force magnitude commanded in each 100 ms of the last second, oldest first
    /// (at most [`FORCE_SAMPLES_PER_S`]; fewer when fewer frames came), N.
    pub force_n: Vec<f32>,
    /// The scene's safe force, N.
    pub safe_force_n: f64,
    /// The session's metrics so far (the latest `metrics` message's).
    pub peak_force_n: f64,
    pub time_above_safe_s: f64,
    pub time_in_contact_s: f64,
    pub pushes: u64,
    pub device: DeviceSummary,
    /// The session's alerts: every one not yet acknowledged, then the latest acknowledged, at
    /// most [`MAX_SUMMARY_ALERTS`], in the order raised.
    pub alerts: Vec<Alert>,
}

/// Where a station's exercise stands (from its latest `exercise` message).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExerciseSummary {
    pub name: String,
    /// Its place in the station's list (from 0) and the list's length.
    pub index: u32,
    pub count: u32,
    /// 1 for the first attempt at it, 2 for a repeat, …
    pub attempt: u32,
    pub state: ExerciseState,
    /// Seconds left before the time limit (0 once ended).
    pub remaining_s: f64,
    /// Once ended: whether every pass mark was met; `null` while it runs.
    pub passed: Option<bool>,
}

/// The device's health, for the tile.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeviceSummary {
    /// Its state on the last tick (`stats.device`).
    pub state: DeviceStatus,
    /// Ticks with the `device_fault` flag, since the session started.
    pub fault_ticks: u64,
    /// Ticks the loop lost (deadlines that passed without one), since the start.
    pub lost_ticks: u64,
    /// The driver reports its motors warm (the latest frame's `motors_warm` flag).
    pub motors_warm: bool,
}

impl DeviceSummary {
    /// Whether the device waits for its operator to calibrate it.
    pub fn needs_calibration(&self) -> bool {
        matches!(
            self.state,
            DeviceStatus::NeedsCalibration
                | DeviceStatus::NeedsCalibrationReset
                | DeviceStatus::CalibrationUpdating
        )
    }
}

/// Something an instructor should look at: conspicuous on the tile until acknowledged.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Alert {
    /// 1, 2, … in the order raised, per session.
    pub id: u32,
    pub kind: AlertKind,
    /// The session's device time when it was raised (the frames' `time_ns`).
    pub time_ns: u64,
    /// Wall-clock time when it was raised, Unix milliseconds.
    pub unix_ms: u64,
    /// What happened, in words (at most [`MAX_ALERT_DETAIL_CHARS`] characters).
    pub detail: String,
    /// Who acknowledged it and when; `null` until someone does.
    pub acknowledged: Option<Acknowledgement>,
}

/// Why an alert was raised.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AlertKind {
    /// The trainee's force went above the scene's safe force.
    AboveSafeForce,
    /// The device faulted (`stats.device` other than `ok`, calibration aside).
    DeviceFault,
    /// The device needs its operator to calibrate it.
    NeedsCalibration,
    /// An exercise attempt ended without meeting its pass marks.
    ExerciseFailed,
}

/// An instructor's acknowledgement of an alert.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Acknowledgement {
    /// Who, in words: the role and where from (`instructor at 10.0.0.7:53122 on a hub`).
    pub by: String,
    pub unix_ms: u64,
}

/// The hub's view of every station, about once a second, to its dashboard pages.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DashboardMessage {
    /// When the hub made it, Unix milliseconds.
    pub time_unix_ms: u64,
    /// Every station the hub lists, by name.
    pub stations: Vec<DashboardStation>,
}

/// One tile.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DashboardStation {
    pub name: String,
    /// The scene in words.
    pub scene: String,
    /// `live`, `idle` or `offline` (as `/api/stations` says).
    pub state: String,
    /// Viewers on the station itself, and on this hub.
    pub viewers: u32,
    pub hub_viewers: u32,
    /// What the station said of itself in its latest heartbeat; `null` from a station that
    /// sends none.
    pub summary: Option<StationSummary>,
}

/// `station_action` (dashboard page → hub): an instructor acts on a station. Instructors only;
/// the hub logs who, and the station logs it and carries it out.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename = "station_action")]
pub struct StationActionRequest {
    /// The station's name.
    pub station: String,
    pub action: StationAction,
}

/// What an instructor asks of a station.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum StationAction {
    /// Acknowledge the alert `alert` (its id).
    Acknowledge { alert: u32 },
    /// Start, repeat or stop the station's exercise (as `exercise_control`).
    Exercise { control: ExerciseAction },
    /// Add a mark to the station's session (as `add_mark`, without a point; the same 1 to 280
    /// characters).
    Mark { note: String },
    /// Re-arm a device whose force output latched off (as `rearm_device`).
    RearmDevice,
}

impl StationAction {
    /// The action's name, as the wire spells it.
    pub fn name(&self) -> &'static str {
        match self {
            StationAction::Acknowledge { .. } => "acknowledge",
            StationAction::Exercise { .. } => "exercise",
            StationAction::Mark { .. } => "mark",
            StationAction::RearmDevice => "rearm_device",
        }
    }
}

/// The station's answer to an action, passed on to the page that asked (`action_result`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActionResult {
    pub station: String,
    /// The action's name ([`StationAction::name`]).
    pub action: String,
    /// Whether the station carried it out.
    pub done: bool,
    /// Why not, in words to show a person; `null` when done.
    pub reason: Option<String>,
}
