//! A replay's two messages: the controls an instructor sends (`replay_control`) and where the
//! replay stands (`replay`, a [`super::ServerMessage`]), with what its timeline shows: the
//! stretches without ticks, those above the safe force, the instructors' marks.

use serde::{Deserialize, Serialize};

/// What a viewer may ask of a replay (client → server, `"type":"replay_control"`).
///
/// `{"type":"replay_control","action":"pause"}`,
/// `{"type":"replay_control","action":"play","speed":2.0}` (speed optional, kept when absent),
/// `{"type":"replay_control","action":"seek","time_s":1.5}`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename = "replay_control")]
pub struct ReplayControl {
    pub action: ReplayAction,
    /// Target time for `seek`, seconds from the recording's start.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_s: Option<f64>,
    /// New playback speed (1.0 = real time), with any action.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub speed: Option<f64>,
}

/// The replay actions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ReplayAction {
    Pause,
    Play,
    Seek,
}

/// Why a replay control was refused.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum ReplayControlError {
    #[error("replay_control: seek needs time_s")]
    SeekWithoutTime,
    #[error("replay_control: time_s must be finite and >= 0, got {0}")]
    Time(f64),
    #[error("replay_control: speed must be finite and in [0.01, 100], got {0}")]
    Speed(f64),
}

impl ReplayControl {
    /// Slowest and fastest replay speeds accepted.
    pub const SPEED_RANGE: (f64, f64) = (0.01, 100.0);

    /// Checks the fields that serde cannot: a seek has a time, times and speeds are sane.
    pub fn validate(&self) -> Result<(), ReplayControlError> {
        if self.action == ReplayAction::Seek && self.time_s.is_none() {
            return Err(ReplayControlError::SeekWithoutTime);
        }
        if let Some(t) = self.time_s
            && !(t.is_finite() && t >= 0.0)
        {
            return Err(ReplayControlError::Time(t));
        }
        if let Some(s) = self.speed
            && !(s.is_finite() && (Self::SPEED_RANGE.0..=Self::SPEED_RANGE.1).contains(&s))
        {
            return Err(ReplayControlError::Speed(s));
        }
        Ok(())
    }
}

/// Where a replay stands (server → viewer, `"type":"replay"`): sent once a second (paused or
/// playing, so a viewer that connects learns the state within a second) and after every control.
///
/// Sent as [`super::ServerMessage::Replay`], whose tag gives it its `type`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReplayStatus {
    /// Length of the recording, seconds of device time.
    pub duration_s: f64,
    /// Current position, seconds from the recording's start.
    pub time_s: f64,
    pub paused: bool,
    pub speed: f64,
    /// The recording's file name (no directories).
    pub file: String,
    /// Stretches of the recording with no ticks in it, for the timeline to mark; absent when
    /// there are none (and from servers before it).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub gaps: Vec<ReplayGap>,
    /// Stretches where the force was above the scene's safe force, for the timeline to mark;
    /// absent when there are none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub above_safe: Vec<ReplaySpan>,
    /// The instructors' marks of the recording, for the timeline; absent when there are none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub marks: Vec<ReplayMark>,
}

/// An instructor's mark on a replayed recording's timeline.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReplayMark {
    pub id: u64,
    /// Seconds from the recording's start (its first contact frame).
    pub time_s: f64,
    pub note: String,
}

/// A stretch of a replayed recording, seconds from its start.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ReplaySpan {
    pub start_s: f64,
    pub end_s: f64,
}

/// A stretch of a replayed recording without ticks: the loop lost them (deadlines that passed
/// with no tick; the device held its last force), or the file lost them (a damaged stretch the
/// reader skipped).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReplayGap {
    /// Where it starts and ends, seconds from the recording's start.
    pub start_s: f64,
    pub end_s: f64,
    /// Ticks missing in it.
    pub ticks: u64,
    pub cause: GapCause,
}

/// Why a [`ReplayGap`] has no ticks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GapCause {
    /// The loop lost them (recorded as lost ticks).
    LostTicks,
    /// The recording lost them (damage the reader skipped).
    Damaged,
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn replay_control_parses_and_validates() {
        let c: ReplayControl =
            serde_json::from_str(r#"{"type":"replay_control","action":"seek","time_s":1.5}"#)
                .unwrap();
        assert_eq!(c.action, ReplayAction::Seek);
        assert_eq!(c.validate(), Ok(()));
        let no_time: ReplayControl =
            serde_json::from_str(r#"{"type":"replay_control","action":"seek"}"#).unwrap();
        assert_eq!(no_time.validate(), Err(ReplayControlError::SeekWithoutTime));
        let fast: ReplayControl =
            serde_json::from_str(r#"{"type":"replay_control","action":"play","speed":1000}"#)
                .unwrap();
        assert_eq!(fast.validate(), Err(ReplayControlError::Speed(1000.0)));
        assert!(
            serde_json::from_str::<ReplayControl>(r#"{"type":"replay_control","action":"rewind"}"#)
                .is_err()
        );
        let status = ReplayStatus {
            duration_s: 3.0,
            time_s: 1.0,
            paused: true,
            speed: 1.0,
            file: "a.mcap".into(),
            gaps: Vec::new(),
            above_safe: Vec::new(),
            marks: Vec::new(),
        };
        let v = serde_json::to_value(super::super::ServerMessage::Replay(status)).unwrap();
        assert_eq!(v["type"], "replay");
    }
}
