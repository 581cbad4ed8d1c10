//! The WebSocket messages between the server and the viewer (proto/WIRE.md).
//!
//! Long because every message of the contract is declared here, in the order proto/WIRE.md gives
//! them; the last 340 lines are its tests.
//!
//! These are transport types: they exist to be encoded as JSON text frames, and they are built
//! from the application types ([`ContactState`], [`CalibrationTable`], [`Material`],
//! [`ToolShape`]) at the edge, never used inside the haptic loop. Every message is a JSON object
//! whose `"type"` names it; vectors are `[x, y, z]` arrays and quaternions `[x, y, z, w]`, as glam
//! serialises them.
//!
//! Decoding distinguishes three failures ([`DecodeError`]): text that is not a JSON object with a
//! string `type` (malformed: the receiver closes that connection), a `type` it does not know
//! (ignored and counted: a newer peer may send it), and a known type with wrong fields.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::calibration::CalibrationTable;
use crate::contact::{ContactFlags, ContactState, Pose};
use crate::deformation::RenderProfile;
use crate::material::Material;
use crate::model::{ModelSpec, ValidityLimits};
use crate::tool::ToolShape;

mod dashboard;
mod exercise;
mod inclusions;
mod replay;
pub mod shm1;
mod vectors;
pub use dashboard::{
    Acknowledgement, ActionResult, Alert, AlertKind, DashboardMessage, DashboardStation,
    DeviceSummary, ExerciseSummary, FORCE_SAMPLES_PER_S, MAX_ALERT_DETAIL_CHARS,
    MAX_SUMMARY_ALERTS, StationAction, StationActionRequest, StationSummary,
};
pub use exercise::{ExerciseAction, ExerciseControl, ExerciseMessage, ExerciseState};
pub use inclusions::{InclusionView, InclusionsMessage};
pub use replay::{
    GapCause, ReplayAction, ReplayControl, ReplayControlError, ReplayGap, ReplayMark, ReplaySpan,
    ReplayStatus,
};
pub use vectors::{MessageVector, message_vectors, vector_files};

/// The protocol version carried by `hello` and `scene`.
pub const PROTOCOL_VERSION: u32 = 1;

/// The `type` names of every server → viewer message, in the order of [`ServerMessage`].
pub const SERVER_MESSAGE_TYPES: [&str; 12] = [
    "hello",
    "scene",
    "contact",
    "stats",
    "metrics",
    "mark",
    "refused",
    "replay",
    "exercise",
    "inclusions",
    "dashboard",
    "action_result",
];

/// The `type` names of every viewer → server message: [`Auth`], [`ReplayControl`] and
/// [`MarkRequest`], [`RearmRequest`], [`ExerciseControl`] and, on a hub's dashboard,
/// [`StationActionRequest`].
pub const CLIENT_MESSAGE_TYPES: [&str; 6] = [
    "auth",
    "replay_control",
    "add_mark",
    "rearm_device",
    "exercise_control",
    "station_action",
];

/// A message from the server to a viewer.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ServerMessage {
    /// First message on every connection.
    Hello(Hello),
    /// Second message on every connection: what is being simulated (large, hence boxed).
    Scene(Box<SceneMessage>),
    /// 50 Hz: the latest contact state.
    Contact(ContactFrame),
    /// 1 Hz: loop timing and stream health.
    Stats(StatsMessage),
    /// 1 Hz, and once more as the session ends: the trainee's metrics.
    Metrics(MetricsMessage),
    /// An instructor's mark, as it is made, and every earlier one as a viewer connects.
    Mark(MarkMessage),
    /// The answer to a request the connection's role (or the server) does not allow; the
    /// connection stays open.
    Refused(Refused),
    /// Where a replay stands: once a second and after every control (replays only).
    Replay(ReplayStatus),
    /// The exercise a station runs and where its attempt stands (stations with exercises).
    Exercise(Box<ExerciseMessage>),
    /// Where a palpation scene's inclusions are: to instructors while an attempt runs, to
    /// everyone once it has ended (never to anyone else: they are the trainee's answer).
    Inclusions(InclusionsMessage),
    /// A hub's dashboard pages only, about once a second: every station's tile.
    Dashboard(Box<DashboardMessage>),
    /// A hub's dashboard pages only: a station's answer to an instructor's `station_action`.
    ActionResult(ActionResult),
}

/// What a connection may do, decided by the token it presented (proto/WIRE.md, "Roles and
/// tokens").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// Everything an observer may, and also control a replay (play, pause, seek, speed).
    Instructor,
    /// Read-only: receives the scene, the frames, the stats and the replay's status.
    Observer,
}

impl Role {
    /// The role's name on the wire.
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Instructor => "instructor",
            Role::Observer => "observer",
        }
    }
}

/// What the server streams: a live session, or a recording (`softhaptic replay`), which also
/// sends `replay` status messages and accepts `replay_control` from an instructor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    Live,
    Replay,
}

/// `hello`: the protocol version, this connection's id, role and mode, and the server's name.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Hello {
    pub protocol_version: u32,
    pub session_id: String,
    pub role: Role,
    pub mode: Mode,
    /// `"softhaptic <version>"`.
    pub server: String,
    /// Whether the trainee feels the force: false for an input-only device (a SpaceMouse), whose
    /// force is computed, streamed and recorded but rendered by nothing. Absent from servers
    /// that predate it: `true` (they drove force-rendering devices only).
    #[serde(default = "renders_force")]
    pub force_feedback: bool,
    /// Whether an instructor may mark this stream (`add_mark`): false where a mark could be
    /// neither stamped with the session's time nor recorded (a lab hub's relay of a station),
    /// and the viewer hides its mark control. Sent only when false; absent means `true` (a
    /// live server; a replay takes no marks either, which its `mode` already says).
    #[serde(default = "accepts", skip_serializing_if = "is_true")]
    pub accepts_marks: bool,
}

fn renders_force() -> bool {
    true
}

fn accepts() -> bool {
    true
}

fn is_true(value: &bool) -> bool {
    *value
}

/// `refused`: a request the server did not carry out, and why, in words a person reads.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Refused {
    /// The `type` of the refused message, e.g. `"replay_control"`.
    pub request: String,
    pub reason: String,
}

/// `auth` (viewer → server): the token of the viewer's link, the first message on a
/// connection to a server that has tokens.
///
/// `Debug` never shows the token, so a logged or panicking value cannot leak it.
#[derive(Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "type", rename = "auth")]
pub struct Auth {
    pub token: String,
}

impl std::fmt::Debug for Auth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Auth")
            .field("token", &"<redacted>")
            .finish()
    }
}

/// The contact model the loop runs and its validity bounds (beyond them the contact frame's
/// flags say so).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelInfo {
    /// `"hertz"`, `"sneddon_cone"`, ...
    pub name: String,
    /// Depth beyond which the model is known to be inaccurate.
    pub valid_depth_m: f64,
    /// Tool inclination beyond which the model is known to be inaccurate.
    pub valid_inclination_rad: f64,
}

impl ModelInfo {
    /// The model the loop runs for `tool`, with its validity bounds.
    pub fn new(tool: &ToolShape, valid_depth_m: f64, valid_inclination_rad: f64) -> Self {
        ModelInfo {
            name: Self::law_name(tool).into(),
            valid_depth_m,
            valid_inclination_rad,
        }
    }

    /// The paper's contact law for `tool`, as the wire names it.
    pub fn law_name(tool: &ToolShape) -> &'static str {
        match tool {
            ToolShape::Sphere { .. } => "hertz",
            ToolShape::Cone { .. } => "sneddon_cone",
        }
    }
}

/// The contact model the loop runs: the paper's law and the corrections the scene turned on,
/// and the limits the validity flags use with where they come from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactModelInfo {
    /// [`ModelSpec::label`], e.g. `"Hertz + exact sphere + curvature + neo-Hookean fit"`.
    pub label: String,
    /// [`ModelSpec::corrections`]: the scene-file names of the corrections that are on.
    pub corrections: Vec<String>,
    /// The scene's model, field by field.
    pub spec: ModelSpec,
    /// Depth beyond which contact frames carry `beyond_valid_depth`.
    pub valid_depth_m: f64,
    /// Angle between tool axis and contact normal beyond which contact frames carry
    /// `beyond_valid_inclination`.
    pub valid_inclination_rad: f64,
    /// The measured limit's reference, or `"paper"` for the paper's limits.
    pub limits_source: String,
}

impl ContactModelInfo {
    /// The description of `spec` for `tool` running with `limits`.
    pub fn new(tool: &ToolShape, spec: &ModelSpec, limits: &ValidityLimits) -> Self {
        Self {
            label: spec.label(tool),
            corrections: spec.corrections().into_iter().map(str::to_owned).collect(),
            spec: *spec,
            valid_depth_m: limits.valid_depth_m,
            valid_inclination_rad: limits.valid_inclination_rad,
            limits_source: limits.source.clone(),
        }
    }

    /// The paper's law with the paper's limits: what every server ran before the scene message
    /// named its model.
    pub fn paper(tool: &ToolShape) -> Self {
        Self::new(tool, &ModelSpec::PAPER, &ValidityLimits::paper(tool))
    }

    /// The limits as the renderer takes them.
    pub fn validity(&self) -> ValidityLimits {
        ValidityLimits {
            valid_depth_m: self.valid_depth_m,
            valid_inclination_rad: self.valid_inclination_rad,
            source: self.limits_source.clone(),
        }
    }
}

/// A render mesh the viewer fetches from `url` (binary layout "SHM1", proto/WIRE.md).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RenderMeshInfo {
    pub name: String,
    pub url: String,
    pub vertex_count: u32,
    pub object_in_world: Pose,
}

/// The haptic device's limits, for the viewer's gauges.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DeviceInfo {
    pub name: String,
    /// Whether the device renders the force (false for a SpaceMouse). Absent in recordings made
    /// before it existed: `true`.
    #[serde(default = "renders_force")]
    pub force_feedback: bool,
    pub peak_force_n: f64,
    pub continuous_force_n: f64,
    pub max_stiffness_n_per_m: f64,
    pub damping_n_s_per_m: f64,
    pub workspace_radius_m: f64,
}

/// `scene`: the tool, the material, the model, the calibration table, the render meshes and the
/// device. Also served as JSON at `GET /api/scene`.
///
/// A message without `contact_model` (from a server that predates it, or a recording it wrote)
/// decodes with [`ContactModelInfo::paper`]: those servers ran the paper's law. One without
/// `render_profile` decodes as [`RenderProfile::Paper`]: their viewers drew the paper's profile.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(from = "SceneMessageFields")]
pub struct SceneMessage {
    pub protocol_version: u32,
    pub tool: ToolShape,
    pub material: Material,
    /// The law's name and its validity bounds (the same bounds as `contact_model`'s), for
    /// viewers that predate `contact_model`.
    pub model: ModelInfo,
    /// The active contact model, its corrections and where its limits come from.
    pub contact_model: ContactModelInfo,
    pub calibration: CalibrationTable,
    /// The deformation profile the viewer draws (proto/WIRE.md, "Deformation profile").
    pub render_profile: RenderProfile,
    pub render_meshes: Vec<RenderMeshInfo>,
    pub device: DeviceInfo,
    /// The expert's path the trainee is guided along, when the session has a guide.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub guide: Option<crate::guide::GuidePathInfo>,
}

/// [`SceneMessage`] as decoded, `contact_model` and `render_profile` optional.
#[derive(Deserialize)]
struct SceneMessageFields {
    protocol_version: u32,
    tool: ToolShape,
    material: Material,
    model: ModelInfo,
    #[serde(default)]
    contact_model: Option<ContactModelInfo>,
    calibration: CalibrationTable,
    #[serde(default)]
    render_profile: RenderProfile,
    render_meshes: Vec<RenderMeshInfo>,
    device: DeviceInfo,
    #[serde(default)]
    guide: Option<crate::guide::GuidePathInfo>,
}

impl From<SceneMessageFields> for SceneMessage {
    fn from(m: SceneMessageFields) -> Self {
        SceneMessage {
            contact_model: m
                .contact_model
                .unwrap_or_else(|| ContactModelInfo::paper(&m.tool)),
            protocol_version: m.protocol_version,
            tool: m.tool,
            material: m.material,
            model: m.model,
            calibration: m.calibration,
            render_profile: m.render_profile,
            render_meshes: m.render_meshes,
            device: m.device,
            guide: m.guide,
        }
    }
}

/// `contact`: one 50 Hz frame, everything the viewer needs to draw the deformation and the force.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ContactFrame {
    /// +1 per frame the server produced; a gap tells the viewer it lost frames.
    pub seq: u64,
    /// The haptic tick the state comes from.
    pub tick: u64,
    /// Device time of that tick, nanoseconds since the loop started.
    pub time_ns: u64,
    pub tip_in_world: Pose,
    pub in_contact: bool,
    pub depth_m: f64,
    /// Unit, world frame, pointing out of the object.
    pub normal: DVec3,
    pub contact_point_m: DVec3,
    pub contact_radius_m: f64,
    /// R_d from the scene's calibration table at `depth_m` (0 out of contact).
    pub deformed_radius_m: f64,
    pub force_n: DVec3,
    /// Encoded as a list of snake_case names (see [`flag_name`]).
    #[serde(with = "flag_list")]
    pub flags: ContactFlags,
    /// The device's button bits at that tick (bit 0 the stylus' first button). Absent in
    /// recordings made before it existed: 0.
    #[serde(default)]
    pub buttons: u32,
    /// The guidance's pull at that tick, in a session with a guide (absent otherwise).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub guide: Option<crate::GuideState>,
    /// On an object with stiffer inclusions: the force the contact model gives here over what
    /// the homogeneous tissue would give (the FEM's force ratio the loop's force used, 1 away
    /// from every inclusion). The viewer dents the drawn surface less by it. Absent without
    /// inclusions, and in recordings made before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inclusion_force_ratio: Option<f64>,
    /// Frames this viewer lost so far because it read too slowly. Last, so the server can
    /// splice each viewer's count into one shared encoding.
    pub dropped: u64,
}

/// Zero for anything non-finite, so that a frame always encodes to valid JSON numbers (serde_json
/// would write NaN as `null`, which no decoder accepts as a number).
#[inline]
fn finite_or_zero(x: f64) -> f64 {
    if x.is_finite() { x } else { 0.0 }
}

#[inline]
fn finite_vec_or_zero(v: DVec3) -> DVec3 {
    DVec3::new(
        finite_or_zero(v.x),
        finite_or_zero(v.y),
        finite_or_zero(v.z),
    )
}

impl ContactFrame {
    /// The frame for one haptic state. `deformed_radius_m` comes from the calibration table; it
    /// and the contact radius are sent as 0 out of contact. Non-finite numbers are sent as 0
    /// (the loop never publishes them, but the wire must stay valid JSON whatever happens).
    pub fn from_state(
        state: &ContactState,
        seq: u64,
        deformed_radius_m: f64,
        dropped: u64,
    ) -> Self {
        let orientation = if state.tip_in_world.orientation.is_finite() {
            state.tip_in_world.orientation
        } else {
            glam::DQuat::IDENTITY
        };
        let in_contact = state.in_contact;
        ContactFrame {
            seq,
            tick: state.tick,
            time_ns: state.time_ns,
            tip_in_world: Pose {
                position_m: finite_vec_or_zero(state.tip_in_world.position_m),
                orientation,
            },
            in_contact,
            depth_m: if in_contact {
                finite_or_zero(state.depth_m)
            } else {
                0.0
            },
            normal: finite_vec_or_zero(state.normal),
            contact_point_m: finite_vec_or_zero(state.contact_point_m),
            contact_radius_m: if in_contact {
                finite_or_zero(state.contact_radius_m)
            } else {
                0.0
            },
            deformed_radius_m: if in_contact {
                finite_or_zero(deformed_radius_m)
            } else {
                0.0
            },
            force_n: finite_vec_or_zero(state.force_n),
            flags: state.flags,
            buttons: state.buttons,
            guide: state.guide.map(crate::GuideState::finite),
            inclusion_force_ratio: None,
            dropped,
        }
    }
}

/// Percentiles of a timing distribution, microseconds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PeriodErrorUs {
    pub p50: f64,
    pub p99: f64,
    pub p999: f64,
    pub max: f64,
}

/// Percentiles of the per-tick compute time, microseconds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ComputeUs {
    pub p50: f64,
    pub p99: f64,
    pub max: f64,
}

/// `metrics`: the trainee's metrics over the session so far, computed by the server from every
/// 1 kHz tick (`softhaptic_device::metrics` defines each), once a second and once more, `final`,
/// as the session ends.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetricsMessage {
    pub peak_force_n: f64,
    /// Device time of the peak, s.
    pub peak_force_time_s: f64,
    /// The scene's safe force, N.
    pub safe_force_n: f64,
    pub time_above_safe_s: f64,
    pub time_in_contact_s: f64,
    pub path_length_in_contact_m: f64,
    /// Mean squared jerk of the tip in contact, m²/s⁶ (lower is smoother).
    pub mean_squared_jerk_m2_s6: f64,
    pub pushes: u64,
    pub device_fault_ticks: u64,
    /// How many times each contact flag turned on, by its wire name (only flags raised).
    pub flags_raised: std::collections::BTreeMap<String, u64>,
    /// Ticks the metrics cover.
    pub ticks: u64,
    /// The session's last metrics (it ended).
    #[serde(rename = "final", default)]
    pub is_final: bool,
}

/// `add_mark` (viewer → server): an instructor's note on the session now, optionally at a point
/// of the object (world frame, m). Instructors only; on a replay, refused.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename = "add_mark")]
pub struct MarkRequest {
    pub note: String,
    #[serde(default)]
    pub point_m: Option<[f64; 3]>,
}

/// `rearm_device` (viewer → server): an instructor re-arms a device whose force output latched
/// off after repeated force trips (`stats.device` `force_latched`). Instructors only, on a live
/// session; logged with the instructor's address.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "type", rename = "rearm_device")]
pub struct RearmRequest {}

/// Longest note of a mark, characters.
pub const MARK_NOTE_MAX_CHARS: usize = 280;

impl MarkRequest {
    /// Why the mark is refused, if it is: an empty or overlong note, a non-finite point.
    pub fn problem(&self) -> Option<String> {
        let n = self.note.trim().chars().count();
        if n == 0 {
            return Some("a mark needs a note".into());
        }
        if n > MARK_NOTE_MAX_CHARS {
            return Some(format!(
                "a note of {n} characters; at most {MARK_NOTE_MAX_CHARS}"
            ));
        }
        if self
            .point_m
            .is_some_and(|p| !p.iter().all(|v| v.is_finite()))
        {
            return Some("a mark's point must be finite".into());
        }
        None
    }
}

/// `mark` (server → viewer): an instructor's mark on the session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MarkMessage {
    /// 1, 2, … in the order the marks were made.
    pub id: u64,
    /// Device time of the session when it was made, ns (the contact frames' `time_ns`).
    pub time_ns: u64,
    pub note: String,
    /// Where on the object, world frame; `null` for a note on the moment only.
    pub point_m: Option<[f64; 3]>,
}

/// `stats`: the loop's timing and the stream's health, once a second.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StatsMessage {
    pub loop_rate_hz: f64,
    /// |actual − nominal| tick period.
    pub period_error_us: PeriodErrorUs,
    /// Deadlines whose tick did not start before the next deadline (ticks lost), since the start.
    pub overruns: u64,
    /// Ticks run by the loop's standby thread because the loop thread had not started them a
    /// quarter period after their deadline, since the start. Absent in recordings made before
    /// the standby existed: 0.
    #[serde(default)]
    pub standby_ticks: u64,
    pub compute_us: ComputeUs,
    pub viewers: u32,
    /// Frames lost by all viewers together since the server started.
    pub dropped_frames: u64,
    /// The haptic device's state on the last tick. Absent in recordings made before it
    /// existed: `ok`.
    #[serde(default)]
    pub device: DeviceStatus,
}

/// The haptic device's state, as the viewer tells it to people ([`DeviceStatus::message`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DeviceStatus {
    /// Read and commanded on the last tick without an error.
    #[default]
    Ok,
    /// The device is gone (cable, power, driver): force is zero while it is reconnected.
    Disconnected,
    /// The device did not answer within its servo period.
    NotAnswering,
    /// The driver stopped the force output (e.g. a force beyond its maximum, hot motors).
    ForceDisabled,
    /// The device must be calibrated before it renders force.
    NeedsCalibration,
    /// A tick ran past its servo period; zero force was sent instead of a late one.
    Overrun,
    /// Another error of the device's driver.
    DriverError,
    /// The driver's force cut-out tripped more often than it is re-armed automatically: no force
    /// until an instructor re-arms it (`rearm_device`) or the server restarts.
    ForceLatched,
    /// The backend's servo tick failed: no force until the server restarts.
    Failed,
    /// The device's encoders must be reset at the stylus' reset position.
    NeedsCalibrationReset,
    /// The driver is updating the device's calibration by itself.
    CalibrationUpdating,
}

impl DeviceStatus {
    /// What the viewer shows, in words a trainee understands.
    pub fn message(self) -> &'static str {
        match self {
            DeviceStatus::Ok => "device ok",
            DeviceStatus::Disconnected => "device disconnected",
            DeviceStatus::NotAnswering => "device not answering",
            DeviceStatus::ForceDisabled => "device force output disabled",
            DeviceStatus::NeedsCalibration => {
                "device needs calibration: put the stylus in its inkwell"
            }
            DeviceStatus::Overrun => "device tick overran: force skipped",
            DeviceStatus::DriverError => "device driver error",
            DeviceStatus::ForceLatched => {
                "device force output latched off after repeated force trips: an instructor must \
                 re-arm it (or restart the server)"
            }
            DeviceStatus::Failed => "device servo tick failed: no force until the server restarts",
            DeviceStatus::NeedsCalibrationReset => {
                "device needs calibration: hold the stylus at its reset position and press its \
                 button"
            }
            DeviceStatus::CalibrationUpdating => {
                "device updating its calibration: force resumes when it is done"
            }
        }
    }
}

/// The wire name of one flag bit, or `None` for a bit this protocol version does not name.
pub fn flag_name(flag: ContactFlags) -> Option<&'static str> {
    FLAG_NAMES
        .iter()
        .find(|(f, _)| *f == flag)
        .map(|(_, name)| *name)
}

/// Every flag with its wire name, in the order proto/WIRE.md lists them.
pub const FLAG_NAMES: [(ContactFlags, &str); 13] = [
    (ContactFlags::SATURATED, "saturated"),
    (ContactFlags::STIFFNESS_CAPPED, "stiffness_capped"),
    (ContactFlags::BEYOND_VALID_DEPTH, "beyond_valid_depth"),
    (
        ContactFlags::BEYOND_VALID_INCLINATION,
        "beyond_valid_inclination",
    ),
    (ContactFlags::DEVICE_FAULT, "device_fault"),
    (ContactFlags::RAMPING, "ramping"),
    (ContactFlags::PASSIVITY_DAMPING, "passivity_damping"),
    (ContactFlags::DEGENERATE_NORMAL, "degenerate_normal"),
    (
        ContactFlags::CONTINUOUS_FORCE_LIMITED,
        "continuous_force_limited",
    ),
    (ContactFlags::PUSHED_THROUGH, "pushed_through"),
    (ContactFlags::MOTORS_WARM, "motors_warm"),
    (ContactFlags::OUTSIDE_WORKSPACE, "outside_workspace"),
    (ContactFlags::LATE_TICK_LIMITED, "late_tick_limited"),
];

/// The snake_case names of the set flags, in [`FLAG_NAMES`] order.
pub fn flag_names(flags: ContactFlags) -> impl Iterator<Item = &'static str> {
    FLAG_NAMES
        .iter()
        .filter(move |(f, _)| flags.contains(*f))
        .map(|(_, name)| *name)
}

/// `ContactFlags` as a JSON list of names. An unknown name is a decoding error: flags change
/// what the viewer shows, so a silent drop would hide a warning.
mod flag_list {
    use super::{ContactFlags, FLAG_NAMES, flag_names};
    use serde::de::{Error, SeqAccess, Visitor};
    use serde::ser::SerializeSeq;
    use serde::{Deserializer, Serializer};

    pub fn serialize<S: Serializer>(flags: &ContactFlags, s: S) -> Result<S::Ok, S::Error> {
        let mut seq = s.serialize_seq(Some(flags.iter().count()))?;
        for name in flag_names(*flags) {
            seq.serialize_element(name)?;
        }
        seq.end()
    }

    struct FlagVisitor;

    impl<'de> Visitor<'de> for FlagVisitor {
        type Value = ContactFlags;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("a list of flag names")
        }
        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<ContactFlags, A::Error> {
            let mut flags = ContactFlags::empty();
            while let Some(name) = seq.next_element::<std::borrow::Cow<'de, str>>()? {
                match FLAG_NAMES.iter().find(|(_, n)| *n == name) {
                    Some((flag, _)) => flags |= *flag,
                    None => {
                        return Err(A::Error::custom(format_args!(
                            "flags: unknown flag name {name:?}"
                        )));
                    }
                }
            }
            Ok(flags)
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<ContactFlags, D::Error> {
        d.deserialize_seq(FlagVisitor)
    }
}

/// Why a text frame could not be decoded.
#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    /// Not JSON, not an object, or no string `"type"`: the sender is broken; close the link.
    #[error("malformed message: {0}")]
    Malformed(String),
    /// A well-formed message of a type this side does not know: ignore it and count it.
    #[error("unknown message type {0:?}")]
    UnknownType(String),
    /// A known type whose fields are wrong.
    #[error("invalid {message_type} message: {reason}")]
    Invalid {
        message_type: String,
        reason: String,
    },
}

impl DecodeError {
    /// True for [`DecodeError::UnknownType`], the one failure a receiver tolerates.
    pub fn is_unknown_type(&self) -> bool {
        matches!(self, DecodeError::UnknownType(_))
    }
}

/// Just the `type` field; every other field is skipped without being stored.
#[derive(Deserialize)]
struct TypeProbe {
    #[serde(rename = "type")]
    message_type: String,
}

/// The `type` of a text frame, checking only that it is a JSON object with a string `type`.
pub fn message_type(text: &str) -> Result<String, DecodeError> {
    serde_json::from_str::<TypeProbe>(text)
        .map(|p| p.message_type)
        .map_err(|e| DecodeError::Malformed(e.to_string()))
}

impl ServerMessage {
    /// The message's `type` name.
    pub fn type_name(&self) -> &'static str {
        match self {
            ServerMessage::Hello(_) => "hello",
            ServerMessage::Scene(_) => "scene",
            ServerMessage::Contact(_) => "contact",
            ServerMessage::Stats(_) => "stats",
            ServerMessage::Metrics(_) => "metrics",
            ServerMessage::Mark(_) => "mark",
            ServerMessage::Refused(_) => "refused",
            ServerMessage::Replay(_) => "replay",
            ServerMessage::Exercise(_) => "exercise",
            ServerMessage::Inclusions(_) => "inclusions",
            ServerMessage::Dashboard(_) => "dashboard",
            ServerMessage::ActionResult(_) => "action_result",
        }
    }

    /// Encodes as one JSON text frame.
    pub fn encode(&self) -> Result<String, serde_json::Error> {
        serde_json::to_string(self)
    }

    /// Decodes one JSON text frame; see [`DecodeError`] for the three ways it can fail.
    pub fn decode(text: &str) -> Result<ServerMessage, DecodeError> {
        let message_type = message_type(text)?;
        if !SERVER_MESSAGE_TYPES.contains(&message_type.as_str()) {
            return Err(DecodeError::UnknownType(message_type));
        }
        serde_json::from_str(text).map_err(|e| DecodeError::Invalid {
            message_type,
            reason: e.to_string(),
        })
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    fn round_trip(message: &ServerMessage) {
        let text = message.encode().unwrap();
        let back = ServerMessage::decode(&text).unwrap();
        assert_eq!(&back, message, "{text}");
        assert_eq!(message_type(&text).unwrap(), message.type_name());
    }

    #[test]
    fn every_vector_message_round_trips() {
        let mut decoded = std::collections::HashSet::new();
        for v in message_vectors().unwrap() {
            match v {
                MessageVector::Valid { name, json } => {
                    let text = json.to_string();
                    match ServerMessage::decode(&text) {
                        Ok(m) => {
                            round_trip(&m);
                            let mut json = json;
                            if name == "scene_before_contact_model" {
                                // Read as the paper's law with the paper's limits; re-encoded
                                // with the field.
                                let ServerMessage::Scene(scene) = &m else {
                                    panic!("{name} is a scene")
                                };
                                assert_eq!(
                                    scene.contact_model,
                                    ContactModelInfo::paper(&scene.tool)
                                );
                                json["contact_model"] =
                                    serde_json::to_value(&scene.contact_model).unwrap();
                                assert_eq!(scene.render_profile, RenderProfile::Paper);
                                json["render_profile"] = "paper".into();
                            }
                            // Re-encoding gives the same JSON value (no field lost or added).
                            assert_eq!(serde_json::to_value(&m).unwrap(), json, "{name}");
                            decoded.insert(m.type_name());
                        }
                        Err(e) => {
                            assert!(e.is_unknown_type(), "{e}");
                            // The replay messages travel beside the server messages; each
                            // decodes as its own type and re-encodes to the same JSON.
                            let text = json.to_string();
                            if name.starts_with("replay_status") {
                                let status: ReplayStatus = serde_json::from_str(&text).unwrap();
                                assert_eq!(serde_json::to_value(&status).unwrap(), json);
                            } else if name == "auth" {
                                let auth: Auth = serde_json::from_str(&text).unwrap();
                                assert_eq!(serde_json::to_value(&auth).unwrap(), json);
                                assert!(CLIENT_MESSAGE_TYPES.contains(&"auth"));
                            } else if name == "add_mark" {
                                let mark: MarkRequest = serde_json::from_str(&text).unwrap();
                                assert_eq!(mark.problem(), None);
                                assert_eq!(serde_json::to_value(&mark).unwrap(), json);
                            } else if name == "exercise_control" {
                                let control: ExerciseControl = serde_json::from_str(&text).unwrap();
                                assert_eq!(serde_json::to_value(control).unwrap(), json);
                            } else if name.starts_with("station_action") {
                                let request: StationActionRequest =
                                    serde_json::from_str(&text).unwrap();
                                assert_eq!(serde_json::to_value(&request).unwrap(), json);
                            } else if name.starts_with("replay_control") {
                                let control: ReplayControl = serde_json::from_str(&text).unwrap();
                                control.validate().unwrap();
                                assert_eq!(serde_json::to_value(control).unwrap(), json);
                            } else {
                                assert_eq!(name, "unknown_type");
                            }
                        }
                    }
                }
                MessageVector::Invalid { name, raw, valid } => {
                    assert!(!valid);
                    let err = ServerMessage::decode(&raw).unwrap_err();
                    assert!(!err.is_unknown_type(), "{name}: {err}");
                }
            }
        }
        assert_eq!(decoded.len(), SERVER_MESSAGE_TYPES.len());
    }

    #[test]
    fn hello_has_the_wire_layout() {
        let text = ServerMessage::Hello(Hello {
            protocol_version: PROTOCOL_VERSION,
            session_id: "s1".into(),
            role: Role::Observer,
            mode: Mode::Replay,
            server: "softhaptic 0.1.0".into(),
            force_feedback: false,
            accepts_marks: true,
        })
        .encode()
        .unwrap();
        assert_eq!(
            text,
            r#"{"type":"hello","protocol_version":1,"session_id":"s1","role":"observer","mode":"replay","server":"softhaptic 0.1.0","force_feedback":false}"#
        );
        // From a server that predates the field: a force-rendering device.
        let old = r#"{"type":"hello","protocol_version":1,"session_id":"s1","role":"observer","mode":"replay","server":"softhaptic 0.1.0"}"#;
        match ServerMessage::decode(old).unwrap() {
            ServerMessage::Hello(h) => assert!(h.force_feedback && h.accepts_marks),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_hello_that_takes_no_marks_says_so_and_one_that_does_is_unchanged() {
        let hello = Hello {
            protocol_version: PROTOCOL_VERSION,
            session_id: "s1".into(),
            role: Role::Instructor,
            mode: Mode::Live,
            server: "softhaptic 0.1.0".into(),
            force_feedback: true,
            accepts_marks: false,
        };
        let text = ServerMessage::Hello(hello.clone()).encode().unwrap();
        assert!(
            text.ends_with(r#""force_feedback":true,"accepts_marks":false}"#),
            "{text}"
        );
        assert_eq!(
            ServerMessage::decode(&text).unwrap(),
            ServerMessage::Hello(hello.clone())
        );
        let taking = ServerMessage::Hello(Hello {
            accepts_marks: true,
            ..hello
        })
        .encode()
        .unwrap();
        assert!(!taking.contains("accepts_marks"), "{taking}");
    }

    #[test]
    fn refused_and_auth_have_the_wire_layout_and_auth_hides_its_token_from_debug() {
        let text = ServerMessage::Refused(Refused {
            request: "replay_control".into(),
            reason: "no".into(),
        })
        .encode()
        .unwrap();
        assert_eq!(
            text,
            r#"{"type":"refused","request":"replay_control","reason":"no"}"#
        );
        let auth = Auth {
            token: "0123456789abcdef0123456789abcdef".into(),
        };
        assert_eq!(
            serde_json::to_string(&auth).unwrap(),
            r#"{"type":"auth","token":"0123456789abcdef0123456789abcdef"}"#
        );
        let shown = format!("{auth:?}");
        assert!(!shown.contains("0123456789abcdef"), "{shown}");
        for role in [Role::Instructor, Role::Observer] {
            assert_eq!(
                serde_json::to_value(role).unwrap(),
                serde_json::Value::from(role.as_str())
            );
        }
    }

    #[test]
    fn contact_frame_has_the_wire_fields() {
        let state = ContactState {
            in_contact: true,
            depth_m: 0.002,
            contact_radius_m: 0.004,
            flags: ContactFlags::SATURATED | ContactFlags::DEGENERATE_NORMAL,
            ..ContactState::IDLE
        };
        let frame = ContactFrame::from_state(&state, 5, 0.02, 9);
        let json = serde_json::to_value(ServerMessage::Contact(frame)).unwrap();
        let keys: Vec<&str> = json
            .as_object()
            .unwrap()
            .keys()
            .map(|k| k.as_str())
            .collect();
        for k in [
            "type",
            "seq",
            "tick",
            "time_ns",
            "tip_in_world",
            "in_contact",
            "depth_m",
            "normal",
            "contact_point_m",
            "contact_radius_m",
            "deformed_radius_m",
            "force_n",
            "flags",
            "dropped",
            "buttons",
        ] {
            assert!(keys.contains(&k), "missing {k}");
        }
        assert_eq!(keys.len(), 15);
        assert_eq!(
            json["flags"],
            serde_json::json!(["saturated", "degenerate_normal"])
        );
        assert_eq!(
            json["tip_in_world"]["orientation"],
            serde_json::json!([0.0, 0.0, 0.0, 1.0])
        );
        assert_eq!(json["normal"], serde_json::json!([0.0, 1.0, 0.0]));
        assert_eq!(json["dropped"], 9);
        assert_eq!(json["deformed_radius_m"], 0.02);
    }

    #[test]
    fn pushed_through_is_bit_nine_and_travels_by_its_name() {
        // The session log's device channel stores the bits, the wire the names.
        assert_eq!(ContactFlags::PUSHED_THROUGH.bits(), 1 << 9);
        let state = ContactState {
            in_contact: true,
            depth_m: 0.025,
            flags: ContactFlags::PUSHED_THROUGH | ContactFlags::SATURATED,
            ..ContactState::IDLE
        };
        let message = ServerMessage::Contact(ContactFrame::from_state(&state, 1, 0.0, 0));
        let json = serde_json::to_value(&message).unwrap();
        assert_eq!(
            json["flags"],
            serde_json::json!(["saturated", "pushed_through"])
        );
        let back: ServerMessage = serde_json::from_value(json).unwrap();
        assert_eq!(back, message);
    }

    #[test]
    fn every_flag_has_a_distinct_name() {
        let mut all = ContactFlags::empty();
        for (flag, name) in FLAG_NAMES {
            assert_eq!(flag.bits().count_ones(), 1);
            assert_eq!(flag_name(flag), Some(name));
            all |= flag;
        }
        assert_eq!(all, ContactFlags::all(), "a flag has no wire name");
        assert_eq!(flag_names(ContactFlags::all()).count(), FLAG_NAMES.len());
    }

    #[test]
    fn out_of_contact_and_non_finite_values_are_sent_as_zero() {
        let state = ContactState {
            in_contact: false,
            depth_m: 0.01,
            contact_radius_m: 0.01,
            force_n: DVec3::new(f64::NAN, 1.0, f64::INFINITY),
            ..ContactState::IDLE
        };
        let frame = ContactFrame::from_state(&state, 1, 0.05, 0);
        assert_eq!(frame.depth_m, 0.0);
        assert_eq!(frame.contact_radius_m, 0.0);
        assert_eq!(frame.deformed_radius_m, 0.0);
        assert_eq!(frame.force_n, DVec3::new(0.0, 1.0, 0.0));
        let text = ServerMessage::Contact(frame).encode().unwrap();
        assert!(!text.contains("null"));
        assert!(ServerMessage::decode(&text).is_ok());
    }

    #[test]
    fn stats_recorded_before_the_standby_existed_still_decode() {
        // A `stats` message as recordings made before `standby_ticks` hold it.
        let old = r#"{"type":"stats","loop_rate_hz":1000.0,
            "period_error_us":{"p50":1.0,"p99":2.0,"p999":3.0,"max":4.0},"overruns":1,
            "compute_us":{"p50":1.0,"p99":2.0,"max":3.0},"viewers":0,"dropped_frames":0}"#;
        let Ok(ServerMessage::Stats(stats)) = ServerMessage::decode(old) else {
            panic!("an old stats message is refused");
        };
        assert_eq!((stats.overruns, stats.standby_ticks), (1, 0));
        // Sent on again (a replay), it carries the field the viewer requires.
        let text = ServerMessage::Stats(stats).encode().unwrap();
        assert!(text.contains(r#""standby_ticks":0"#), "{text}");
    }

    #[test]
    fn decode_failures_are_distinguishable() {
        assert!(matches!(
            ServerMessage::decode(r#"{"type":"futuristic","x":1}"#),
            Err(DecodeError::UnknownType(t)) if t == "futuristic"
        ));
        assert!(matches!(
            ServerMessage::decode("{"),
            Err(DecodeError::Malformed(_))
        ));
        assert!(matches!(
            ServerMessage::decode(r#"{"type":["contact"]}"#),
            Err(DecodeError::Malformed(_))
        ));
        let err = ServerMessage::decode(r#"{"type":"stats","loop_rate_hz":1000}"#).unwrap_err();
        assert!(
            matches!(&err, DecodeError::Invalid { message_type, .. } if message_type == "stats")
        );
        assert!(err.to_string().contains("period_error_us"), "{err}");
    }

    #[test]
    fn vector_files_on_disk_match_the_code() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("vectors");
        for (name, contents) in vector_files().unwrap() {
            let path = dir.join(name);
            let on_disk = std::fs::read_to_string(&path).unwrap_or_else(|e| {
                panic!("{}: {e}; run `softhaptic vectors write`", path.display())
            });
            assert!(
                on_disk == contents,
                "{} differs from the code; run `softhaptic vectors write`",
                path.display()
            );
        }
    }

    #[test]
    fn scene_carries_the_active_contact_model() {
        let v = message_vectors().unwrap();
        let MessageVector::Valid { json, .. } = &v[1] else {
            panic!("second vector is the sphere scene")
        };
        let model = &json["contact_model"];
        assert_eq!(
            model["label"],
            "Hertz + exact sphere + curvature + neo-Hookean fit"
        );
        assert_eq!(
            model["corrections"],
            serde_json::json!(["exact_sphere", "curvature", "hyperelastic"])
        );
        assert_eq!(model["spec"]["exact_sphere"], true);
        assert_eq!(model["spec"]["thickness"], serde_json::Value::Null);
        assert_eq!(model["valid_depth_m"], 0.0058);
        assert!(model["limits_source"].as_str().unwrap().contains("FEM"));
        // The legacy summary carries the same bounds.
        assert_eq!(json["model"]["valid_depth_m"], 0.0058);
        // An unknown field in the model is refused (a typo must not pass for a correction).
        let mut bad = json.clone();
        bad["contact_model"]["spec"]["curvatur"] = true.into();
        let err = ServerMessage::decode(&bad.to_string()).unwrap_err();
        assert!(err.to_string().contains("curvatur"), "{err}");
        // A layer round-trips with its thickness.
        let layer = v
            .iter()
            .find_map(|v| match v {
                MessageVector::Valid { name, json } if name == "scene_paper_layer" => Some(json),
                _ => None,
            })
            .unwrap();
        let ServerMessage::Scene(scene) = ServerMessage::decode(&layer.to_string()).unwrap() else {
            panic!("a scene")
        };
        assert_eq!(scene.contact_model.corrections, vec!["thickness_bonded"]);
        assert_eq!(
            scene.contact_model.spec.thickness.map(|l| l.thickness_m),
            Some(0.03)
        );
        assert_eq!(scene.contact_model.limits_source, "paper");
    }

    #[test]
    fn scene_with_invalid_calibration_is_refused() {
        let v = message_vectors().unwrap();
        let MessageVector::Valid { json, .. } = &v[1] else {
            panic!("second vector is the sphere scene")
        };
        let mut json = json.clone();
        json["calibration"]["rows"][1]["depth_m"] = 0.0001.into();
        let err = ServerMessage::decode(&json.to_string()).unwrap_err();
        assert!(err.to_string().contains("rows[1].depth_m"), "{err}");
    }
}
