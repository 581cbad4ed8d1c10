//! The exercise a station runs, on the wire: `exercise` (server → viewer) and
//! `exercise_control` (viewer → server, instructors only).

use serde::{Deserialize, Serialize};

use crate::exercise::{AttemptResult, Exercise};

/// `exercise` (server → viewer): the exercise a station runs for its trainee, and where the
/// attempt at it stands. Sent when an attempt starts and when it ends, about once a second in
/// between (the countdown), and to a viewer as it connects. A recording keeps each one on its
/// own channel, the one that starts an attempt with the exercise file's text.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExerciseMessage {
    /// Who is being assessed (the station's `--trainee`).
    pub trainee: String,
    /// The exercise's place in the station's list, from 0, and the list's length.
    pub index: u32,
    pub count: u32,
    /// 1 for the first attempt at this exercise in the session, 2 for a repeat, …
    pub attempt: u32,
    pub state: ExerciseState,
    /// The task, in the scene's world frame: what the viewer draws (the site and its window,
    /// the path).
    pub exercise: Exercise,
    /// Device time of the message, ns (the contact frames' `time_ns`).
    pub time_ns: u64,
    /// Seconds left before the time limit; 0 once the attempt has ended.
    pub remaining_s: f64,
    /// The attempt's result, once it has ended.
    pub result: Option<AttemptResult>,
    /// Seconds until the next exercise starts by itself, once the attempt has ended; `null`
    /// when the station waits for an instructor (the list is done, or it never advances alone).
    pub next_in_s: Option<f64>,
    /// The exercise file's name and text, in a recording, on the message that starts an
    /// attempt; never sent to a viewer.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exercise_file: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exercise_toml: Option<String>,
}

/// Where an attempt stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ExerciseState {
    /// The trainee is at it: the clock runs.
    Running,
    /// It has ended (goal reached, time up or stopped); `result` says how it went.
    Ended,
}

/// `exercise_control` (viewer → server): an instructor moves a station's exercises on.
/// Instructors only, on a live station that runs exercises; logged with the instructor's address.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "type", rename = "exercise_control")]
pub struct ExerciseControl {
    pub action: ExerciseAction,
}

/// What an instructor asks of a station's exercises.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ExerciseAction {
    /// End the attempt in progress (if any) and start the next exercise of the list.
    Next,
    /// End the attempt in progress (if any) and start the same exercise again.
    Repeat,
    /// End the attempt in progress, scored as it stands; nothing starts.
    Stop,
}

impl ExerciseAction {
    pub fn as_str(self) -> &'static str {
        match self {
            ExerciseAction::Next => "next",
            ExerciseAction::Repeat => "repeat",
            ExerciseAction::Stop => "stop",
        }
    }
}
