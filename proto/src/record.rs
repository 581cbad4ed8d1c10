//! The session log: what a recording holds, channel by channel.
//!
//! Long because every channel's record type lives here, so that the table below is complete in one
//! file; the last 270 lines are its tests.
//!
//! A session is recorded to one MCAP file with JSON-encoded messages and a JSON schema per channel,
//! so that generic tools (Foxglove, `mcap cat`) can open it without this project's code:
//!
//! | topic | schema | when |
//! |---|---|---|
//! | [`topic::BUILD`] | [`BuildRecord`] | once, first: who wrote the file and in which format |
//! | [`topic::SCENE`] | [`SceneRecord`] | once: the `scene` wire message and the scene definition |
//! | [`topic::DEVICE`] | [`DeviceRecord`] | every haptic tick (1 kHz) |
//! | [`topic::CONTACT`] | the `contact` wire message, verbatim | each 50 Hz frame as it was sent |
//! | [`topic::STATS`] | [`RecordingStats`] | about once a second, and a final one at the end |
//! | [`topic::LOOP_STATS`] | the `stats` wire message, verbatim | each 1 Hz stats message as sent |
//! | [`topic::MARKS`] | the `mark` wire message, verbatim | each instructor's mark as sent |
//! | [`topic::METRICS`] | the `metrics` wire message, verbatim | each 1 Hz message as sent, and the final one at the end |
//! | [`topic::EXERCISE`] | the `exercise` wire message, with the exercise file on an attempt's first | each as sent to viewers (stations running exercises) |
//!
//! The build and scene records are written once more right after the first chunk, in an
//! attachment named [`START_COPY_ATTACHMENT`]: its data is a chunk record of its own holding the
//! first chunk's schemas, channels, build and scene again, so that a reader that finds the first
//! chunk damaged still knows what the rest of the file is.
//!
//! Every message's log time is the device time in nanoseconds since the loop started, so a
//! recording's timeline is the device's and replay can pace itself on it.
//!
//! Floating-point fields that may be non-finite (a faulty device can report NaN) are written as
//! JSON numbers when finite and as the strings `"NaN"`, `"inf"`, `"-inf"` otherwise, because JSON
//! has no literal for them and a silent `null` would lose the fault. Finite numbers are written
//! with the shortest representation that parses back to the same bits, which is what makes replay
//! checks exact (the reader must parse with full precision, as serde_json's `float_roundtrip` does).

use serde::{Deserialize, Serialize};

use crate::wire::SceneMessage;

/// Version of the session-log layout described here. A reader refuses files whose version is
/// newer than its own, because it cannot know what a newer writer changed.
pub const SESSION_FORMAT_VERSION: u32 = 1;

/// The MCAP profile string written in the file header.
pub const MCAP_PROFILE: &str = "softhaptic";

/// Name of the attachment that repeats the first chunk: its data is one MCAP chunk record holding
/// every schema and channel, the build record and the scene record.
pub const START_COPY_ATTACHMENT: &str = "softhaptic/start";

/// Media type of the [`START_COPY_ATTACHMENT`].
pub const START_COPY_MEDIA_TYPE: &str = "application/x-mcap-chunk";

/// Schema encoding and message encoding of every channel.
pub const SCHEMA_ENCODING: &str = "jsonschema";
/// Message encoding of every channel.
pub const MESSAGE_ENCODING: &str = "json";

/// The channel topics of a recording.
pub mod topic {
    /// One [`super::DeviceRecord`] per haptic tick.
    pub const DEVICE: &str = "/device";
    /// The 50 Hz `contact` wire messages, as sent to viewers.
    pub const CONTACT: &str = "/contact";
    /// The [`super::SceneRecord`].
    pub const SCENE: &str = "/scene";
    /// The [`super::BuildRecord`].
    pub const BUILD: &str = "/build";
    /// Periodic and final [`super::RecordingStats`].
    pub const STATS: &str = "/stats";
    /// The 1 Hz `stats` wire messages (loop timing), as sent to viewers.
    pub const LOOP_STATS: &str = "/loop_stats";
    /// The instructors' `mark` wire messages, as sent to viewers.
    pub const MARKS: &str = "/marks";
    /// The trainee's `metrics` wire messages: the 1 Hz ones as sent to viewers, and the final
    /// one over every tick of the session, written when it ends.
    pub const METRICS: &str = "/metrics";
    /// The `exercise` wire messages of a station running exercises, as sent to viewers; the
    /// one that starts an attempt carries the exercise file's name and text as well.
    pub const EXERCISE: &str = "/exercise";
    /// The session's alerts (`wire::Alert`), each as it was raised and again as it was
    /// acknowledged; absent from recordings made before alerts existed.
    pub const ALERTS: &str = "/alerts";
}

/// The schema name of each channel (the MCAP schema record's `name`).
pub mod schema_name {
    pub const DEVICE: &str = "softhaptic.DeviceRecord";
    pub const CONTACT: &str = "softhaptic.ContactMessage";
    pub const SCENE: &str = "softhaptic.SceneRecord";
    pub const BUILD: &str = "softhaptic.BuildRecord";
    pub const STATS: &str = "softhaptic.RecordingStats";
    pub const LOOP_STATS: &str = "softhaptic.StatsMessage";
    pub const MARKS: &str = "softhaptic.MarkMessage";
    pub const METRICS: &str = "softhaptic.MetricsMessage";
    pub const EXERCISE: &str = "softhaptic.ExerciseMessage";
    pub const ALERTS: &str = "softhaptic.Alert";
}

/// One device sample as recorded (mirrors the device crate's sample; kept here so the file format
/// does not change when the device crate's in-memory type does).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SampleRecord {
    /// Device time of the sample, nanoseconds since the loop started.
    pub time_ns: u64,
    /// Tool-tip position in the world frame.
    #[serde(with = "lossless_f64")]
    pub tip_position_m: [f64; 3],
    /// Tool-tip orientation in the world frame, quaternion `[x, y, z, w]`.
    #[serde(with = "lossless_f64")]
    pub tip_orientation: [f64; 4],
    /// Tool-tip linear velocity in the world frame.
    #[serde(with = "lossless_f64")]
    pub tip_velocity_m_s: [f64; 3],
    /// Device button bits.
    pub buttons: u32,
    /// `ContactFlags` bits the device reported with the sample (`motors_warm`,
    /// `outside_workspace`); absent when none, and in recordings made before they existed.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub flags: u32,
}

fn is_zero_u32(n: &u32) -> bool {
    *n == 0
}

/// One haptic tick: what the device reported and what the loop commanded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeviceRecord {
    /// Tick counter since the loop started; a gap means ticks the recorder had to drop.
    pub tick: u64,
    /// Device time of the tick, nanoseconds since the loop started.
    pub time_ns: u64,
    /// The sample the device returned, or `None` when reading it failed.
    pub sample: Option<SampleRecord>,
    /// The loop flagged a device fault this tick (the read failed, or the sample was not finite).
    pub device_fault: bool,
    /// The device's error when the read failed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub device_error: Option<DeviceErrorRecord>,
    /// The device's error when it refused the force command (it output zero; the tick's
    /// `force_n` is then zero and `device_fault` set).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command_error: Option<DeviceErrorRecord>,
    /// Ticks the loop lost right before this one (deadlines, or periods of the device's servo
    /// clock, that passed with no tick): the device held the previous force meanwhile. Absent
    /// when none, and in recordings made before it existed.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub lost_before: u64,
    /// Whether the tool touched the object.
    pub in_contact: bool,
    /// Indentation depth along the contact normal.
    #[serde(with = "lossless_f64::scalar")]
    pub depth_m: f64,
    /// Force commanded to the device, world frame, after every safety limit.
    #[serde(with = "lossless_f64")]
    pub force_n: [f64; 3],
    /// `ContactFlags` bits (see `proto::contact::ContactFlags`).
    pub flags: u32,
    /// The guidance's pull this tick (its force is part of `force_n`); absent without a guide.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub guide: Option<crate::GuideState>,
}

fn is_zero(n: &u64) -> bool {
    *n == 0
}

/// Why a device read failed, as recorded (mirrors the device crate's `DeviceError`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum DeviceErrorRecord {
    Disconnected,
    Timeout,
    ForceDisabled,
    Driver { code: i32 },
    NeedsCalibration,
    Overrun,
    ForceLatched,
    Fatal,
    NeedsCalibrationReset,
    CalibrationUpdating,
}

/// The scene of the session: the `scene` wire message the viewers got, and the scene definition
/// the haptic world was built from (so a replay check can rebuild the same world).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneRecord {
    /// The `scene` wire message, exactly as sent to viewers.
    pub message: SceneMessage,
    /// The scene file's text (TOML), as the server loaded it: a replay check rebuilds the
    /// haptic world from it.
    pub scene_toml: String,
    /// Where the scene file was (absolute), for files it names relative to itself; `None` for a
    /// built-in scene.
    pub scene_file: Option<String>,
    /// Haptic loop period the session ran at.
    pub period_ns: u64,
    /// The object's meshes as the session loaded them from the files its scene names, so that a
    /// check or a replay uses these and never reads a path a recording names. Absent for a
    /// built-in object (its meshes are the build's) and from recordings made before they were
    /// kept.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub meshes: Option<RecordedMeshes>,
    /// The scene's inclusions as placed (values drawn from a seed included) and the FEM table
    /// the force used, so a check rebuilds the same force without reading a file. Absent for a
    /// scene without inclusions. Kept out of `message`, which every viewer gets: a replay sends
    /// them only in `inclusions` messages, by role, as the live station did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inclusions: Option<RecordedInclusions>,
    /// The expert's path the session guided along and the pull's settings, exactly as it ran,
    /// so a check rebuilds the same pull without the expert's file. Absent without a guide.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub guide: Option<crate::guide::RecordedGuide>,
}

/// A session's inclusions and their table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordedInclusions {
    pub placed: Vec<crate::Inclusion>,
    pub table: crate::InclusionTable,
}

/// The meshes of a session's object.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordedMeshes {
    /// The coarse haptic mesh the collision used.
    pub haptic: MeshRecord,
    /// The fine render mesh the viewers drew, or `None` when they drew the haptic mesh.
    pub render: Option<MeshRecord>,
}

/// A triangle mesh, object frame, with the hash of its content.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshRecord {
    pub positions_m: Vec<[f64; 3]>,
    pub triangles: Vec<[u32; 3]>,
    /// SHA-256 (hex) of the positions' little-endian f64 bytes followed by the indices'
    /// little-endian u32 bytes: a reader refuses a mesh that does not match it.
    pub sha256: String,
}

/// Who wrote a recording and in which formats.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BuildRecord {
    /// [`SESSION_FORMAT_VERSION`] of the writer.
    pub session_format_version: u32,
    /// The wire protocol version of the messages on `/contact` and `/scene`.
    pub protocol_version: u32,
    /// Name and version of the program that wrote the file, e.g. `softhaptic 0.1.0`.
    pub writer: String,
    /// Git commit the writer was built from, when known at build time.
    pub git_commit: Option<String>,
    /// Session id, as in the `hello` message.
    pub session_id: String,
    /// Wall-clock start of the recording, nanoseconds since the Unix epoch.
    pub started_unix_ns: u64,
}

/// The recorder's own accounting: how much was written and how much was lost.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordingStats {
    /// Device ticks written so far.
    pub ticks_recorded: u64,
    /// Ticks the recorder never saw because its ring was full (gaps in the tick counter).
    pub ticks_dropped: u64,
    /// Contact frames written so far.
    pub contact_frames_recorded: u64,
    /// Contact frames dropped because the recorder's queue was full.
    pub contact_frames_dropped: u64,
    /// True on the last stats message, written when the recording was closed cleanly.
    #[serde(rename = "final")]
    pub is_final: bool,
}

/// Serde helpers for f64 fields that must survive JSON bit for bit, including NaN and infinities.
pub mod lossless_f64 {
    use serde::de::{self, SeqAccess, Visitor};
    use serde::ser::SerializeTuple;
    use serde::{Deserializer, Serializer};
    use std::fmt;

    fn write_one<S: SerializeTuple>(seq: &mut S, v: f64) -> Result<(), S::Error> {
        if v.is_finite() {
            seq.serialize_element(&v)
        } else {
            seq.serialize_element(non_finite_name(v))
        }
    }

    fn non_finite_name(v: f64) -> &'static str {
        if v.is_nan() {
            "NaN"
        } else if v > 0.0 {
            "inf"
        } else {
            "-inf"
        }
    }

    /// Serialises a fixed-size array of f64.
    pub fn serialize<S: Serializer, const N: usize>(
        v: &[f64; N],
        serializer: S,
    ) -> Result<S::Ok, S::Error> {
        let mut seq = serializer.serialize_tuple(N)?;
        for x in v {
            write_one(&mut seq, *x)?;
        }
        seq.end()
    }

    /// Deserialises a fixed-size array of f64 written by [`serialize`].
    pub fn deserialize<'de, D: Deserializer<'de>, const N: usize>(
        deserializer: D,
    ) -> Result<[f64; N], D::Error> {
        struct ArrayVisitor<const N: usize>;
        impl<'de, const N: usize> Visitor<'de> for ArrayVisitor<N> {
            type Value = [f64; N];
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                write!(f, "an array of {N} numbers (or \"NaN\"/\"inf\"/\"-inf\")")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                let mut out = [0.0; N];
                for (i, slot) in out.iter_mut().enumerate() {
                    *slot = seq
                        .next_element::<Lossless>()?
                        .ok_or_else(|| de::Error::invalid_length(i, &self))?
                        .0;
                }
                if seq.next_element::<de::IgnoredAny>()?.is_some() {
                    return Err(de::Error::invalid_length(N + 1, &self));
                }
                Ok(out)
            }
        }
        deserializer.deserialize_seq(ArrayVisitor::<N>)
    }

    /// One f64, finite as a number, non-finite as a string.
    struct Lossless(f64);

    impl<'de> serde::Deserialize<'de> for Lossless {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            d.deserialize_any(OneVisitor).map(Lossless)
        }
    }

    struct OneVisitor;
    impl Visitor<'_> for OneVisitor {
        type Value = f64;
        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            f.write_str("a number or one of \"NaN\", \"inf\", \"-inf\"")
        }
        fn visit_f64<E: de::Error>(self, v: f64) -> Result<f64, E> {
            Ok(v)
        }
        fn visit_u64<E: de::Error>(self, v: u64) -> Result<f64, E> {
            Ok(v as f64)
        }
        fn visit_i64<E: de::Error>(self, v: i64) -> Result<f64, E> {
            Ok(v as f64)
        }
        fn visit_str<E: de::Error>(self, v: &str) -> Result<f64, E> {
            match v {
                "NaN" => Ok(f64::NAN),
                "inf" => Ok(f64::INFINITY),
                "-inf" => Ok(f64::NEG_INFINITY),
                other => Err(E::invalid_value(de::Unexpected::Str(other), &self)),
            }
        }
    }

    /// The same for a single f64 field.
    pub mod scalar {
        use super::*;

        pub fn serialize<S: Serializer>(v: &f64, serializer: S) -> Result<S::Ok, S::Error> {
            if v.is_finite() {
                serializer.serialize_f64(*v)
            } else {
                serializer.serialize_str(non_finite_name(*v))
            }
        }

        pub fn deserialize<'de, D: Deserializer<'de>>(deserializer: D) -> Result<f64, D::Error> {
            deserializer.deserialize_any(OneVisitor)
        }
    }
}

/// JSON schemas (draft 2020-12) of every channel, for the MCAP schema records. Hand-written so that
/// they carry descriptions and units, and kept flat (no `$ref`, no `oneOf`) so that viewers with
/// partial JSON-schema support (Foxglove) read them; a test checks each against a serialised
/// record.
pub mod schema {
    /// Schema of [`super::DeviceRecord`].
    pub const DEVICE: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "softhaptic.DeviceRecord",
  "description": "One 1 kHz haptic tick: the device sample and the force commanded. Non-finite numbers are the strings NaN, inf, -inf.",
  "type": "object",
  "properties": {
    "tick": {"type": "integer", "minimum": 0, "description": "tick counter since the loop started"},
    "time_ns": {"type": "integer", "minimum": 0, "description": "device time, ns since the loop started"},
    "sample": {
      "type": ["object", "null"],
      "description": "the device sample, null when the read failed",
      "properties": {
        "time_ns": {"type": "integer", "minimum": 0},
        "tip_position_m": {"type": "array", "items": {"type": ["number", "string"]}, "minItems": 3, "maxItems": 3, "description": "world frame, metres"},
        "tip_orientation": {"type": "array", "items": {"type": ["number", "string"]}, "minItems": 4, "maxItems": 4, "description": "quaternion [x,y,z,w], world frame"},
        "tip_velocity_m_s": {"type": "array", "items": {"type": ["number", "string"]}, "minItems": 3, "maxItems": 3, "description": "world frame, m/s"},
        "buttons": {"type": "integer", "minimum": 0},
        "flags": {"type": "integer", "minimum": 0, "description": "contact flags the device reported with the sample (1024 motors_warm, 2048 outside_workspace); absent when none"}
      },
      "required": ["time_ns", "tip_position_m", "tip_orientation", "tip_velocity_m_s", "buttons"]
    },
    "device_fault": {"type": "boolean"},
    "device_error": {"type": "object", "description": "why the read failed", "properties": {
      "kind": {"type": "string", "enum": ["disconnected", "timeout", "force_disabled", "driver", "needs_calibration", "overrun", "force_latched", "fatal", "needs_calibration_reset", "calibration_updating"]},
      "code": {"type": "integer"}}, "required": ["kind"]},
    "lost_before": {"type": "integer", "minimum": 0, "description": "ticks the loop lost right before this one (absent: none)"},
    "command_error": {"type": "object", "description": "why the device refused the force command (it output zero)", "properties": {
      "kind": {"type": "string", "enum": ["disconnected", "timeout", "force_disabled", "driver", "needs_calibration", "overrun", "force_latched", "fatal", "needs_calibration_reset", "calibration_updating"]},
      "code": {"type": "integer"}}, "required": ["kind"]},
    "in_contact": {"type": "boolean"},
    "depth_m": {"type": ["number", "string"], "description": "indentation depth, metres"},
    "force_n": {"type": "array", "items": {"type": ["number", "string"]}, "minItems": 3, "maxItems": 3, "description": "commanded force, world frame, newtons"},
    "flags": {"type": "integer", "minimum": 0, "description": "ContactFlags bits: 1 beyond_valid_depth, 2 beyond_valid_inclination, 4 saturated, 8 stiffness_capped, 16 device_fault, 32 ramping, 64 passivity_damping, 128 degenerate_normal, 256 continuous_force_limited, 512 pushed_through, 1024 motors_warm, 2048 outside_workspace, 4096 late_tick_limited"},
    "guide": {"type": "object", "description": "the guidance's pull this tick (absent without a guide)", "properties": {
      "force_n": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3, "description": "guiding force, world frame, newtons (part of force_n)"},
      "target_m": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3, "description": "the target on the expert's path, world frame"},
      "progress": {"type": "number", "description": "arc length of the target over the path's, 0 to 1"},
      "gain": {"type": "number", "description": "the fading gain, 0 to 1"},
      "effective_gain": {"type": "number", "description": "the fading gain times the engage/release ramp"},
      "engaged": {"type": "boolean"},
      "pass": {"type": "integer", "minimum": 0, "description": "passes along the path completed before this one"}}, "required": ["force_n", "target_m", "progress", "gain", "effective_gain", "engaged"]}
  },
  "required": ["tick", "time_ns", "sample", "device_fault", "in_contact", "depth_m", "force_n", "flags"]
}"##;

    /// Schema of the `contact` wire message on `/contact`.
    pub const CONTACT: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "softhaptic.ContactMessage",
  "description": "The 50 Hz contact frame exactly as sent to viewers (protocol version 1).",
  "type": "object",
  "properties": {
    "type": {"type": "string", "const": "contact"},
    "seq": {"type": "integer", "minimum": 0},
    "tick": {"type": "integer", "minimum": 0},
    "time_ns": {"type": "integer", "minimum": 0},
    "tip_in_world": {"type": "object", "properties": {
      "position_m": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3},
      "orientation": {"type": "array", "items": {"type": "number"}, "minItems": 4, "maxItems": 4}}},
    "in_contact": {"type": "boolean"},
    "depth_m": {"type": "number"},
    "normal": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3},
    "contact_point_m": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3},
    "contact_radius_m": {"type": "number"},
    "deformed_radius_m": {"type": "number"},
    "force_n": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3},
    "flags": {"type": "array", "items": {"type": "string"}},
    "dropped": {"type": "integer", "minimum": 0},
    "buttons": {"type": "integer", "minimum": 0, "description": "device button bits, bit 0 the stylus' first button"},
    "inclusion_force_ratio": {"type": "number", "description": "on an object with inclusions, in contact: the force over the homogeneous tissue's there (absent otherwise)"},
    "guide": {"type": "object", "description": "the guidance's pull this tick (absent without a guide)", "properties": {
      "force_n": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3, "description": "guiding force, world frame, newtons (part of force_n)"},
      "target_m": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3, "description": "the target on the expert's path, world frame"},
      "progress": {"type": "number", "description": "arc length of the target over the path's, 0 to 1"},
      "gain": {"type": "number", "description": "the fading gain, 0 to 1"},
      "effective_gain": {"type": "number", "description": "the fading gain times the engage/release ramp"},
      "engaged": {"type": "boolean"},
      "pass": {"type": "integer", "minimum": 0, "description": "passes along the path completed before this one"}}, "required": ["force_n", "target_m", "progress", "gain", "effective_gain", "engaged"]}
  },
  "required": ["type", "seq", "tick", "time_ns", "tip_in_world", "in_contact", "depth_m", "normal", "contact_point_m", "contact_radius_m", "deformed_radius_m", "force_n", "flags", "dropped"]
}"##;

    /// Schema of [`super::SceneRecord`].
    pub const SCENE: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "softhaptic.SceneRecord",
  "description": "The scene wire message sent to viewers, and the scene file the haptic world was built from.",
  "type": "object",
  "properties": {
    "message": {"type": "object", "description": "the scene wire message"},
    "scene_toml": {"type": "string", "description": "the scene file's text"},
    "scene_file": {"type": ["string", "null"], "description": "absolute path of the scene file, null for a built-in scene"},
    "period_ns": {"type": "integer", "minimum": 1, "description": "haptic loop period"},
    "meshes": {"type": "object", "description": "the object's meshes as the session loaded them from files (absent for a built-in object)", "properties": {
      "haptic": {"type": "object", "properties": {"positions_m": {"type": "array"}, "triangles": {"type": "array"}, "sha256": {"type": "string"}}, "required": ["positions_m", "triangles", "sha256"]},
      "render": {"type": ["object", "null"]}}, "required": ["haptic", "render"]},
    "inclusions": {"type": "object", "description": "the inclusions as placed and their FEM force-ratio table (absent without inclusions)", "properties": {
      "placed": {"type": "array"}, "table": {"type": "object"}}, "required": ["placed", "table"]},
    "guide": {"type": "object", "description": "the expert's path the session guided along, resampled, and the pull's settings (absent without a guide)", "properties": {
      "source": {"type": "string"}, "source_scene": {"type": "string"}, "points_m": {"type": "array"}, "depths_m": {"type": "array"}, "forces_n": {"type": "array"}, "spacing_m": {"type": "number"}, "params": {"type": "object"}, "gain": {"type": "object"}},
      "required": ["source", "points_m", "depths_m", "spacing_m", "params", "gain"]}
  },
  "required": ["message", "scene_toml", "scene_file", "period_ns"]
}"##;

    /// Schema of [`super::BuildRecord`].
    pub const BUILD: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "softhaptic.BuildRecord",
  "description": "Who wrote this recording and in which formats.",
  "type": "object",
  "properties": {
    "session_format_version": {"type": "integer", "minimum": 1},
    "protocol_version": {"type": "integer", "minimum": 1},
    "writer": {"type": "string"},
    "git_commit": {"type": ["string", "null"]},
    "session_id": {"type": "string"},
    "started_unix_ns": {"type": "integer", "minimum": 0}
  },
  "required": ["session_format_version", "protocol_version", "writer", "git_commit", "session_id", "started_unix_ns"]
}"##;

    /// Schema of [`super::RecordingStats`].
    pub const STATS: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "softhaptic.RecordingStats",
  "description": "The recorder's accounting of what it wrote and what it lost.",
  "type": "object",
  "properties": {
    "ticks_recorded": {"type": "integer", "minimum": 0},
    "ticks_dropped": {"type": "integer", "minimum": 0},
    "contact_frames_recorded": {"type": "integer", "minimum": 0},
    "contact_frames_dropped": {"type": "integer", "minimum": 0},
    "final": {"type": "boolean", "description": "true on the last message of a cleanly closed file"}
  },
  "required": ["ticks_recorded", "ticks_dropped", "contact_frames_recorded", "contact_frames_dropped", "final"]
}"##;

    /// Schema of the `stats` wire message on `/loop_stats`.
    pub const LOOP_STATS: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "softhaptic.StatsMessage",
  "description": "The 1 Hz loop timing message exactly as sent to viewers (protocol version 1).",
  "type": "object",
  "properties": {
    "type": {"type": "string", "const": "stats"},
    "loop_rate_hz": {"type": "number"},
    "period_error_us": {"type": "object", "properties": {
      "p50": {"type": "number"}, "p99": {"type": "number"}, "p999": {"type": "number"}, "max": {"type": "number"}}},
    "overruns": {"type": "integer", "minimum": 0},
    "standby_ticks": {"type": "integer", "minimum": 0},
    "compute_us": {"type": "object", "properties": {
      "p50": {"type": "number"}, "p99": {"type": "number"}, "max": {"type": "number"}}},
    "viewers": {"type": "integer", "minimum": 0},
    "dropped_frames": {"type": "integer", "minimum": 0},
    "device": {"type": "string", "enum": ["ok", "disconnected", "not_answering", "force_disabled", "needs_calibration", "overrun", "driver_error", "force_latched", "failed", "needs_calibration_reset", "calibration_updating"], "description": "the haptic device's state on the last tick"}
  },
  "required": ["type", "loop_rate_hz", "period_error_us", "overruns", "compute_us"]
}"##;

    /// Schema of the `mark` wire message.
    pub const MARKS: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "softhaptic.MarkMessage",
  "description": "An instructor's mark exactly as sent to viewers (protocol version 1).",
  "type": "object",
  "properties": {
    "type": {"type": "string", "const": "mark"},
    "id": {"type": "integer", "minimum": 1, "description": "1, 2, ... in the order made"},
    "time_ns": {"type": "integer", "minimum": 0, "description": "device time when made, ns"},
    "note": {"type": "string"},
    "point_m": {"type": ["array", "null"], "items": {"type": "number"}, "minItems": 3, "maxItems": 3, "description": "world frame, m"}
  },
  "required": ["type", "id", "time_ns", "note", "point_m"]
}"##;

    /// Schema of the `metrics` wire message.
    pub const METRICS: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "softhaptic.MetricsMessage",
  "description": "The trainee's metrics exactly as sent to viewers (protocol version 1), computed on the device host from every 1 kHz tick.",
  "type": "object",
  "properties": {
    "type": {"type": "string", "const": "metrics"},
    "peak_force_n": {"type": "number"},
    "peak_force_time_s": {"type": "number", "description": "device time of the peak, s"},
    "safe_force_n": {"type": "number", "description": "the scene's safe force, N"},
    "time_above_safe_s": {"type": "number"},
    "time_in_contact_s": {"type": "number"},
    "path_length_in_contact_m": {"type": "number"},
    "mean_squared_jerk_m2_s6": {"type": "number", "description": "of the tip in contact; lower is smoother"},
    "pushes": {"type": "integer", "minimum": 0},
    "device_fault_ticks": {"type": "integer", "minimum": 0},
    "flags_raised": {"type": "object", "additionalProperties": {"type": "integer", "minimum": 0}, "description": "how many times each contact flag turned on, by its wire name"},
    "ticks": {"type": "integer", "minimum": 0, "description": "ticks the metrics cover"},
    "final": {"type": "boolean", "description": "the session's last metrics (it ended)"}
  },
  "required": ["type", "peak_force_n", "safe_force_n", "time_above_safe_s", "time_in_contact_s", "path_length_in_contact_m", "pushes", "ticks"]
}"##;

    /// Schema of the `exercise` wire message (and its recorded form).
    pub const EXERCISE: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "softhaptic.ExerciseMessage",
  "description": "The exercise a station runs and where its attempt stands, as sent to viewers (protocol version 1); the recorded message that starts an attempt also holds the exercise file.",
  "type": "object",
  "properties": {
    "type": {"type": "string", "const": "exercise"},
    "trainee": {"type": "string"},
    "index": {"type": "integer", "minimum": 0, "description": "the exercise's place in the station's list, from 0"},
    "count": {"type": "integer", "minimum": 1, "description": "exercises in the list"},
    "attempt": {"type": "integer", "minimum": 1, "description": "1 for the first attempt at this exercise in the session"},
    "state": {"type": "string", "enum": ["running", "ended"]},
    "exercise": {"type": "object", "description": "name, instructions, time_limit_s, task (world frame, SI units), pass marks"},
    "time_ns": {"type": "integer", "minimum": 0, "description": "device time, ns"},
    "remaining_s": {"type": "number", "minimum": 0},
    "result": {"type": ["object", "null"], "description": "the attempt's scores, pass marks and outcome, once ended"},
    "next_in_s": {"type": ["number", "null"], "description": "seconds until the next exercise starts by itself"},
    "exercise_file": {"type": "string", "description": "recorded on an attempt's first message: the file's name"},
    "exercise_toml": {"type": "string", "description": "recorded on an attempt's first message: the file's text"}
  },
  "required": ["type", "trainee", "index", "count", "attempt", "state", "exercise", "time_ns", "remaining_s", "result", "next_in_s"]
}"##;

    /// Schema of an alert (`wire::Alert`).
    pub const ALERTS: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "softhaptic.Alert",
  "description": "An alert the session raised for its instructors (the dashboard's), written when raised and again when acknowledged.",
  "type": "object",
  "properties": {
    "id": {"type": "integer", "minimum": 1, "description": "1, 2, ... in the order raised"},
    "kind": {"type": "string", "enum": ["above_safe_force", "device_fault", "needs_calibration", "exercise_failed"]},
    "time_ns": {"type": "integer", "minimum": 0, "description": "device time when raised, ns"},
    "unix_ms": {"type": "integer", "minimum": 0, "description": "wall-clock time when raised"},
    "detail": {"type": "string"},
    "acknowledged": {"type": ["object", "null"], "properties": {"by": {"type": "string"}, "unix_ms": {"type": "integer"}}, "description": "who acknowledged it and when"}
  },
  "required": ["id", "kind", "time_ns", "unix_ms", "detail", "acknowledged"]
}"##;

    /// `(topic, schema name, schema)` of every channel.
    pub const ALL: [(&str, &str, &str); 10] = [
        (super::topic::BUILD, super::schema_name::BUILD, BUILD),
        (super::topic::SCENE, super::schema_name::SCENE, SCENE),
        (super::topic::DEVICE, super::schema_name::DEVICE, DEVICE),
        (super::topic::CONTACT, super::schema_name::CONTACT, CONTACT),
        (super::topic::STATS, super::schema_name::STATS, STATS),
        (
            super::topic::LOOP_STATS,
            super::schema_name::LOOP_STATS,
            LOOP_STATS,
        ),
        (super::topic::MARKS, super::schema_name::MARKS, MARKS),
        (super::topic::METRICS, super::schema_name::METRICS, METRICS),
        (
            super::topic::EXERCISE,
            super::schema_name::EXERCISE,
            EXERCISE,
        ),
        (super::topic::ALERTS, super::schema_name::ALERTS, ALERTS),
    ];
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use serde_json::Value;

    fn sample_device_record() -> DeviceRecord {
        DeviceRecord {
            tick: 7,
            time_ns: 7_000_000,
            sample: Some(SampleRecord {
                time_ns: 7_000_000,
                tip_position_m: [0.1, -0.2, 1.0 / 3.0],
                tip_orientation: [0.0, 0.0, 0.0, 1.0],
                tip_velocity_m_s: [f64::NAN, f64::INFINITY, f64::NEG_INFINITY],
                buttons: 1,
                flags: 1 << 10,
            }),
            device_fault: false,
            device_error: None,
            command_error: None,
            lost_before: 0,
            in_contact: true,
            depth_m: 0.0012345678901234567,
            force_n: [1e-300, -0.0, 7.9],
            flags: 0b101,
            guide: None,
        }
    }

    #[test]
    fn device_record_round_trips_bit_for_bit_including_non_finite() {
        let r = sample_device_record();
        let json = serde_json::to_string(&r).unwrap();
        assert!(
            json.contains("\"NaN\"") && json.contains("\"-inf\""),
            "{json}"
        );
        let back: DeviceRecord = serde_json::from_str(&json).unwrap();
        let a = r.sample.unwrap();
        let b = back.sample.unwrap();
        for (x, y) in a.tip_velocity_m_s.iter().zip(b.tip_velocity_m_s.iter()) {
            assert!(x.is_nan() && y.is_nan() || x.to_bits() == y.to_bits());
        }
        for (x, y) in r.force_n.iter().zip(back.force_n.iter()) {
            assert_eq!(x.to_bits(), y.to_bits());
        }
        assert_eq!(a.tip_position_m[2].to_bits(), b.tip_position_m[2].to_bits());
        assert_eq!(r.depth_m.to_bits(), back.depth_m.to_bits());
    }

    #[test]
    fn device_record_refuses_unknown_strings_and_wrong_lengths() {
        let good = serde_json::to_value(sample_device_record()).unwrap();
        let mut bad = good.clone();
        bad["force_n"] = serde_json::json!([1.0, "lots", 2.0]);
        let err = serde_json::from_value::<DeviceRecord>(bad).unwrap_err();
        assert!(err.to_string().contains("lots"), "{err}");
        let mut short = good;
        short["force_n"] = serde_json::json!([1.0, 2.0]);
        assert!(serde_json::from_value::<DeviceRecord>(short).is_err());
    }

    #[test]
    fn the_device_schema_names_every_contact_flag_with_its_bit() {
        // The schema is written by hand for MCAP viewers; the flags it lists must follow the
        // type, or a viewer of the file misreads a bit.
        let schema: Value = serde_json::from_str(schema::DEVICE).unwrap();
        let described = schema["properties"]["flags"]["description"]
            .as_str()
            .unwrap();
        for (flag, name) in crate::wire::FLAG_NAMES {
            let entry = format!("{} {name}", flag.bits());
            assert!(
                described.contains(&entry),
                "{entry:?} missing from the device schema's flags: {described}"
            );
        }
        let listed = described.matches(',').count() + 1;
        assert_eq!(listed, crate::wire::FLAG_NAMES.len(), "{described}");
        assert_eq!(
            crate::wire::FLAG_NAMES.len() as u32,
            crate::ContactFlags::all().bits().count_ones()
        );
    }

    /// Whether `value` is of a JSON-schema `type`; an integer is a number too.
    fn is_of_type(value: &Value, ty: &str) -> bool {
        match ty {
            "null" => value.is_null(),
            "boolean" => value.is_boolean(),
            "integer" => value.is_i64() || value.is_u64(),
            "number" => value.is_number(),
            "string" => value.is_string(),
            "array" => value.is_array(),
            "object" => value.is_object(),
            _ => false,
        }
    }

    /// Checks `value` against `schema` at every depth: its type, `enum`, `const`, item counts,
    /// every key of an object declared among its `properties` (when the schema lists them) and
    /// every required one present, each property and item against its own schema. `at` names
    /// the place in failures.
    fn assert_conforms(schema: &Value, value: &Value, at: &str) {
        if let Some(ty) = schema.get("type") {
            let types: Vec<&str> = match ty {
                Value::String(t) => vec![t.as_str()],
                Value::Array(ts) => ts.iter().filter_map(Value::as_str).collect(),
                _ => panic!("{at}: type {ty}"),
            };
            assert!(
                types.iter().any(|t| is_of_type(value, t)),
                "{at}: {value} is not of type {ty}"
            );
        }
        if let Some(values) = schema.get("enum").and_then(Value::as_array) {
            assert!(values.contains(value), "{at}: {value} not in {values:?}");
        }
        if let Some(c) = schema.get("const") {
            assert_eq!(c, value, "{at}");
        }
        match value {
            Value::Object(object) => {
                if let Some(props) = schema.get("properties").and_then(Value::as_object) {
                    for (key, v) in object {
                        let sub = props
                            .get(key)
                            .unwrap_or_else(|| panic!("{at}.{key} is not in the schema"));
                        assert_conforms(sub, v, &format!("{at}.{key}"));
                    }
                }
                for req in schema
                    .get("required")
                    .and_then(Value::as_array)
                    .into_iter()
                    .flatten()
                {
                    let req = req.as_str().unwrap();
                    assert!(object.contains_key(req), "{at}.{req} is not serialised");
                }
            }
            Value::Array(items) => {
                let count = items.len() as u64;
                if let Some(min) = schema.get("minItems").and_then(Value::as_u64) {
                    assert!(count >= min, "{at}: {count} items, fewer than {min}");
                }
                if let Some(max) = schema.get("maxItems").and_then(Value::as_u64) {
                    assert!(count <= max, "{at}: {count} items, more than {max}");
                }
                if let Some(item) = schema.get("items") {
                    for (i, v) in items.iter().enumerate() {
                        assert_conforms(item, v, &format!("{at}[{i}]"));
                    }
                }
            }
            _ => {}
        }
    }

    #[test]
    fn the_schema_check_finds_a_nested_field_the_schema_does_not_declare() {
        let schema: Value = serde_json::from_str(schema::DEVICE).unwrap();
        let mut value = serde_json::to_value(sample_device_record()).unwrap();
        value["sample"]["tip_acceleration"] = serde_json::json!([0.0, 0.0, 0.0]);
        let caught = std::panic::catch_unwind(|| assert_conforms(&schema, &value, "device"));
        assert!(caught.is_err(), "an undeclared nested field passed");
        let mut kind = serde_json::to_value(sample_device_record()).unwrap();
        kind["device_error"] = serde_json::json!({"kind": "unplugged"});
        assert!(std::panic::catch_unwind(|| assert_conforms(&schema, &kind, "device")).is_err());
    }

    /// Each schema parses, and every serialised record conforms to it at every depth (every field
    /// declared, every required one present, types, enums and item counts): the hand-written
    /// schemas cannot drift from the types.
    #[test]
    fn schemas_match_the_serialised_records() {
        let scene_message = crate::wire::message_vectors()
            .unwrap()
            .into_iter()
            .find_map(|v| match v {
                crate::wire::MessageVector::Valid { json, .. } if json["type"] == "scene" => {
                    match serde_json::from_value(json).unwrap() {
                        crate::wire::ServerMessage::Scene(s) => Some(*s),
                        _ => None,
                    }
                }
                _ => None,
            })
            .unwrap();
        let mesh = MeshRecord {
            positions_m: vec![[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.0, 0.01]],
            triangles: vec![[0, 1, 2]],
            sha256: "00".repeat(32),
        };
        let scenes: Vec<Value> = [
            None,
            Some(RecordedMeshes {
                haptic: mesh.clone(),
                render: None,
            }),
            Some(RecordedMeshes {
                haptic: mesh.clone(),
                render: Some(mesh),
            }),
        ]
        .into_iter()
        .map(|meshes| {
            serde_json::to_value(SceneRecord {
                message: scene_message.clone(),
                scene_toml: "[object]\nname = \"liver\"\n".into(),
                scene_file: Some("/lab/scenes/liver.toml".into()),
                period_ns: 1_000_000,
                meshes,
                inclusions: None,
                guide: None,
            })
            .unwrap()
        })
        .collect();
        let build = BuildRecord {
            session_format_version: SESSION_FORMAT_VERSION,
            protocol_version: 1,
            writer: "softhaptic 0".into(),
            git_commit: None,
            session_id: "s".into(),
            started_unix_ns: 1,
        };
        let mut faulty = sample_device_record();
        faulty.sample = None;
        faulty.device_fault = true;
        faulty.device_error = Some(DeviceErrorRecord::Driver { code: -3 });
        faulty.command_error = Some(DeviceErrorRecord::Disconnected);
        faulty.lost_before = 2;
        let mut guided = sample_device_record();
        guided.guide = Some(crate::GuideState {
            force_n: glam::DVec3::new(0.1, 0.0, -0.2),
            target_m: glam::DVec3::new(0.0, 0.05, 0.01),
            progress: 0.5,
            gain: 1.0,
            effective_gain: 0.5,
            engaged: true,
            pass: 2,
        });
        let mut cases: Vec<(&str, Value)> = vec![
            (
                schema::DEVICE,
                serde_json::to_value(sample_device_record()).unwrap(),
            ),
            (schema::DEVICE, serde_json::to_value(faulty).unwrap()),
            (schema::DEVICE, serde_json::to_value(guided).unwrap()),
            (
                schema::SCENE,
                serde_json::to_value(SceneRecord {
                    message: scene_message.clone(),
                    scene_toml: String::new(),
                    scene_file: None,
                    period_ns: 1_000_000,
                    meshes: None,
                    inclusions: None,
                    guide: Some(crate::guide::RecordedGuide {
                        source: "expert.mcap".into(),
                        source_scene: Some("default.toml".into()),
                        points_m: vec![[0.0; 3], [0.001, 0.0, 0.0]],
                        depths_m: vec![0.0, 0.001],
                        forces_n: Some(vec![0.0, 0.2]),
                        spacing_m: 0.001,
                        params: crate::GuideParams::default(),
                        gain: crate::GuideGain::AS_NEEDED,
                    }),
                })
                .unwrap(),
            ),
            (schema::BUILD, serde_json::to_value(build).unwrap()),
            (
                schema::STATS,
                serde_json::to_value(RecordingStats::default()).unwrap(),
            ),
        ];
        cases.extend(scenes.into_iter().map(|scene| (schema::SCENE, scene)));
        for (schema, value) in cases {
            let schema: Value = serde_json::from_str(schema).unwrap();
            let title = schema["title"].as_str().unwrap().to_owned();
            assert_conforms(&schema, &value, &title);
        }
        // The wire messages recorded verbatim, against their schemas.
        for v in crate::wire::message_vectors().unwrap() {
            let crate::wire::MessageVector::Valid { json, .. } = v else {
                continue;
            };
            let schema = match json["type"].as_str() {
                Some("contact") => schema::CONTACT,
                Some("stats") => schema::LOOP_STATS,
                Some("mark") => schema::MARKS,
                Some("metrics") => schema::METRICS,
                Some("exercise") => schema::EXERCISE,
                _ => continue,
            };
            let schema: Value = serde_json::from_str(schema).unwrap();
            let title = schema["title"].as_str().unwrap().to_owned();
            assert_conforms(&schema, &json, &title);
            assert_eq!(schema["properties"]["type"]["const"], json["type"]);
        }
        // No schema uses references or alternatives.
        for (_, _, text) in schema::ALL {
            assert!(!text.contains("$ref") && !text.contains("oneOf"));
        }
    }
}
