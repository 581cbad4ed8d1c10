//! Exercises: tasks a trainee completes, scored from the 1 kHz ticks and held against pass marks
//! set from experts' recordings.
//!
//! # Layout
//! - [`mod@file`]: the exercise file (TOML) and its checks, placed in its scene's world frame.
//! - [`score`]: an attempt scored from a recording's ticks, exactly as it was live.
//! - [`run`]: a station's list of exercises run for its trainee on the live ticks (on the
//!   recorder's thread), published to the viewers and recorded.
//! - [`cli`]: `exercise check`, `exercise score`, `benchmark` (pass marks from experts) and
//!   `results` (a trainee's or a class's attempts as CSV and an HTML report).

pub mod cli;
pub mod file;
pub mod run;
pub mod score;

pub use file::{ExerciseError, LoadedExercise};
