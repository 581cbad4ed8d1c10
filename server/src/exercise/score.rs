//! One attempt at an exercise, tick by tick: the scorer with the rule that ends it. The station
//! runs it on the ticks of a live session, and `exercise score`, `benchmark` and `results` run it
//! on a recording's ticks; the rule and the scorer are the same, so the scores are the same.
//!
//! An attempt starts at its first tick and ends at the first tick where its goal is reached
//! ([`AttemptEnd::Completed`]), or where its time limit has passed ([`AttemptEnd::TimeLimit`]),
//! or when it is stopped ([`Attempt::stop`]: an instructor, the end of the session or of the
//! recording).

use softhaptic_device::exercise::Scorer;
use softhaptic_device::metrics::TickInput;
use softhaptic_proto::exercise::{AttemptEnd, AttemptResult, Exercise};
use softhaptic_proto::record::DeviceRecord;

/// One attempt in progress, or ended.
#[derive(Debug, Clone)]
pub struct Attempt {
    exercise: Exercise,
    scorer: Scorer,
    start_ns: Option<u64>,
    last_ns: u64,
    ended: Option<AttemptEnd>,
}

impl Attempt {
    pub fn new(exercise: &Exercise) -> Self {
        Self {
            scorer: Scorer::new(&exercise.task),
            exercise: exercise.clone(),
            start_ns: None,
            last_ns: 0,
            ended: None,
        }
    }

    pub fn exercise(&self) -> &Exercise {
        &self.exercise
    }

    /// Adds one tick; `Some` on the tick that ends the attempt. Ticks after the end are ignored.
    pub fn update(&mut self, tick: &TickInput) -> Option<AttemptEnd> {
        if self.ended.is_some() {
            return None;
        }
        let start = *self.start_ns.get_or_insert(tick.time_ns);
        self.last_ns = tick.time_ns;
        self.scorer.update(tick);
        let elapsed_s = tick.time_ns.saturating_sub(start) as f64 * 1e-9;
        self.ended = if self.scorer.completed() {
            Some(AttemptEnd::Completed)
        } else if elapsed_s >= self.exercise.time_limit_s {
            Some(AttemptEnd::TimeLimit)
        } else {
            None
        };
        self.ended
    }

    /// Ends the attempt where it stands (no effect on one already ended).
    pub fn stop(&mut self) {
        self.ended.get_or_insert(AttemptEnd::Stopped);
    }

    pub fn ended(&self) -> Option<AttemptEnd> {
        self.ended
    }

    /// Seconds left before the time limit (the whole limit before the first tick).
    pub fn remaining_s(&self) -> f64 {
        let elapsed_s = match self.start_ns {
            Some(start) => self.last_ns.saturating_sub(start) as f64 * 1e-9,
            None => 0.0,
        };
        (self.exercise.time_limit_s - elapsed_s).max(0.0)
    }

    /// The result so far (for an attempt not yet ended, as if stopped now).
    pub fn result(&self, trainee: &str, attempt: u32) -> AttemptResult {
        let start = self.start_ns.unwrap_or(0);
        AttemptResult::judge(
            &self.exercise,
            trainee,
            attempt,
            (start, self.last_ns.max(start)),
            self.ended.unwrap_or(AttemptEnd::Stopped),
            self.scorer.score(),
        )
    }
}

/// Scores `ticks` (a recording's, in order) as one attempt from its first tick.
pub fn score_ticks<'a>(
    exercise: &Exercise,
    ticks: impl IntoIterator<Item = &'a DeviceRecord>,
    trainee: &str,
) -> AttemptResult {
    let mut attempt = Attempt::new(exercise);
    for record in ticks {
        if attempt.update(&TickInput::from_record(record)).is_some() {
            break;
        }
    }
    attempt.stop();
    attempt.result(trainee, 1)
}
