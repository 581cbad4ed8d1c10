//! A station's list of exercises, run for its trainee on the live ticks.
//!
//! [`ExerciseRun`] is shown every tick the recorder writes ([`TickObserver`]), so an attempt is
//! scored from exactly the ticks its recording holds, by the same [`Attempt`] that `exercise
//! score` and `results` run on a recording. It publishes where the attempt stands to the viewers
//! ([`ExerciseFeed`]): when an attempt starts and ends, and once a second of device time in
//! between; each message is also recorded, the one that starts an attempt with the exercise
//! file's name and text.
//!
//! The first exercise starts with the session. An attempt ends when its goal is reached, its
//! time runs out, or an instructor stops it; the result is shown, and after the pause the next
//! exercise starts by itself (unless the station waits for an instructor, or the list is done).
//! An instructor may at any time start the next exercise, repeat the current one, or stop it.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::mpsc::Receiver;

use anyhow::{Context, bail};
use axum::extract::ws::Utf8Bytes;
use softhaptic_device::metrics::TickInput;
use softhaptic_proto::exercise::{AttemptResult, Task};
use softhaptic_proto::record::DeviceRecord;
use softhaptic_proto::wire::{
    ExerciseAction, ExerciseMessage, ExerciseState, InclusionView, InclusionsMessage, ServerMessage,
};

use super::file::LoadedExercise;
use super::score::Attempt;
use crate::files::{self, FileKind};
use crate::scene::Scene;
use crate::session::writer::TickObserver;
use crate::stream::{ExerciseFeed, InclusionsFeed};

/// Device time between two `exercise` messages while nothing changes: the viewer's countdown
/// runs on its own clock in between, and a viewer that lost a message is right again within it.
const REPEAT_NS: u64 = 1_000_000_000;

/// Longest trainee name, characters (it is shown on every viewer and in every result).
pub const MAX_TRAINEE_CHARS: usize = 80;

/// Loads the exercises a station runs: each file checked, and set in the scene the station runs
/// (an exercise made for another scene is refused, naming both).
pub fn station_exercises(
    paths: &[PathBuf],
    station_scene: &Scene,
    station_scene_file: Option<&Path>,
) -> anyhow::Result<Vec<LoadedExercise>> {
    let mut out = Vec::new();
    for path in paths {
        let loaded = LoadedExercise::load(path)?;
        let same = match (&loaded.scene_path, station_scene_file) {
            (None, None) => true,
            (Some(theirs), Some(ours)) => same_scene(theirs, ours, station_scene),
            _ => false,
        };
        if !same {
            let name = |p: Option<&Path>| {
                p.map_or_else(
                    || "the built-in default scene".to_owned(),
                    |p| p.display().to_string(),
                )
            };
            bail!(
                "{}: scene: set in {}, but this station runs {} (start it with that scene, or \
                 run exercises made for this one)",
                path.display(),
                name(loaded.scene_path.as_deref()),
                name(station_scene_file)
            );
        }
        // Placed in the station's own scene, the one its ticks are in.
        let placed = LoadedExercise::from_toml(&loaded.source_toml, path, station_scene)?;
        if let softhaptic_proto::exercise::Task::Follow(f) = &placed.exercise.task
            && f.expert_path.is_empty()
        {
            bail!(
                "{}: kind: a follow exercise needs the station guided by the expert's \
                 recording: start it with --guide {}",
                path.display(),
                f.expert
            );
        }
        out.push(placed);
    }
    Ok(out)
}

/// Whether the scene file `theirs` is the one the station runs: the same file, or the same text.
fn same_scene(theirs: &Path, ours: &Path, station_scene: &Scene) -> bool {
    if let (Ok(a), Ok(b)) = (theirs.canonicalize(), ours.canonicalize())
        && a == b
    {
        return true;
    }
    files::read_text(theirs, FileKind::Scene).is_ok_and(|text| text == station_scene.source_toml)
}

/// Checks a trainee's name: shown to everyone and written into every result.
pub fn check_trainee(name: &str) -> anyhow::Result<String> {
    let name = name.trim();
    let n = name.chars().count();
    if n == 0 || n > MAX_TRAINEE_CHARS || name.chars().any(char::is_control) {
        bail!(
            "--trainee: {name:?}: a name of 1 to {MAX_TRAINEE_CHARS} characters without control \
             characters"
        );
    }
    Ok(name.to_owned())
}

/// Where the station's exercises stand.
enum Stage {
    /// An attempt runs; `announced` once its first message (with the file) has gone out.
    Running { attempt: Box<Attempt>, number: u32 },
    /// It has ended; the next one starts at `advance_at_ns`, if set.
    Ended {
        result: Box<AttemptResult>,
        number: u32,
        advance_at_ns: Option<u64>,
    },
}

/// A station's exercises for one trainee, run on the recorder's thread.
pub struct ExerciseRun {
    trainee: String,
    exercises: Vec<LoadedExercise>,
    index: usize,
    /// Attempts made at each exercise so far.
    attempts: Vec<u32>,
    stage: Stage,
    /// The next message starts an attempt: it carries the file.
    starting: bool,
    feed: Arc<ExerciseFeed>,
    controls: Receiver<ExerciseAction>,
    /// Device time after an attempt ends before the next exercise starts by itself; `None`:
    /// the station waits for an instructor.
    pause_ns: Option<u64>,
    now_ns: u64,
    last_sent_ns: Option<u64>,
    /// The scene's inclusions (world frame) and where they are published: to instructors as
    /// each attempt starts, to everyone as a palpation attempt ends. `None` without inclusions.
    inclusions: Option<(Arc<InclusionsFeed>, Vec<InclusionView>)>,
}

/// The feed of a scene's inclusions, holding the answer for instructors from the start (the
/// `inclusions` message of a session before, or without, exercises); `None` for a scene without
/// inclusions.
pub fn inclusions_feed(scene: &Scene) -> Option<Arc<InclusionsFeed>> {
    if scene.inclusions.is_empty() {
        return None;
    }
    let feed = Arc::new(InclusionsFeed::none());
    let message = InclusionsMessage {
        revealed: false,
        exercise_index: None,
        attempt: None,
        inclusions: InclusionView::placed(&scene.inclusions, &scene.object_in_world),
    };
    match ServerMessage::Inclusions(message).encode() {
        Ok(text) => feed.show_instructors(Utf8Bytes::from(text)),
        Err(e) => tracing::error!(error = %e, "could not encode the inclusions"),
    }
    Some(feed)
}

impl ExerciseRun {
    /// The run of `exercises` (at least one) for `trainee`, publishing to `feed` and taking
    /// `controls`; `pause_s` between an attempt's end and the next exercise (`None`: wait for an
    /// instructor).
    pub fn new(
        trainee: String,
        exercises: Vec<LoadedExercise>,
        feed: Arc<ExerciseFeed>,
        controls: Receiver<ExerciseAction>,
        pause_s: Option<f64>,
    ) -> anyhow::Result<Self> {
        let first = exercises.first().context("no exercises to run")?;
        let attempt = Box::new(Attempt::new(&first.exercise));
        let mut attempts = vec![0; exercises.len()];
        attempts[0] = 1;
        Ok(Self {
            trainee,
            attempts,
            exercises,
            index: 0,
            stage: Stage::Running { attempt, number: 1 },
            starting: true,
            feed,
            controls,
            pause_ns: pause_s.map(|s| (s.max(0.0) * 1e9) as u64),
            now_ns: 0,
            last_sent_ns: None,
            inclusions: None,
        })
    }

    /// The run of a scene with inclusions: they are published to `feed` (from
    /// [`inclusions_feed`]) as attempts start and end.
    pub fn with_inclusions(mut self, feed: Option<Arc<InclusionsFeed>>, scene: &Scene) -> Self {
        self.inclusions = feed.map(|feed| {
            (
                feed,
                InclusionView::placed(&scene.inclusions, &scene.object_in_world),
            )
        });
        self
    }

    /// Publishes the inclusions for the attempt `message` starts or ends: to instructors as it
    /// starts, to everyone as a palpation attempt ends (its answer is then its result).
    fn publish_inclusions(&self, message: &ExerciseMessage, starting: bool) {
        let Some((feed, views)) = &self.inclusions else {
            return;
        };
        let revealed = match message.state {
            ExerciseState::Running if starting => false,
            ExerciseState::Ended if matches!(message.exercise.task, Task::Palpation(_)) => true,
            _ => return,
        };
        let text = ServerMessage::Inclusions(InclusionsMessage {
            revealed,
            exercise_index: Some(message.index),
            attempt: Some(message.attempt),
            inclusions: views.clone(),
        })
        .encode();
        match text {
            Ok(text) if revealed => feed.reveal(Utf8Bytes::from(text)),
            Ok(text) => feed.show_instructors(Utf8Bytes::from(text)),
            Err(e) => tracing::error!(error = %e, "could not encode the inclusions"),
        }
    }

    /// Starts a new attempt at exercise `index`.
    fn start(&mut self, index: usize) {
        self.index = index;
        self.attempts[index] += 1;
        self.stage = Stage::Running {
            attempt: Box::new(Attempt::new(&self.exercises[index].exercise)),
            number: self.attempts[index],
        };
        self.starting = true;
        self.last_sent_ns = None;
    }

    /// Ends the running attempt (if one runs), scored as it stands; the next exercise starts
    /// after the pause when `advance` and there is one.
    fn end(&mut self, advance: bool) {
        let Stage::Running { attempt, number } = &mut self.stage else {
            return;
        };
        attempt.stop();
        let result = Box::new(attempt.result(&self.trainee, *number));
        let has_next = self.index + 1 < self.exercises.len();
        let advance_at_ns = match self.pause_ns {
            Some(pause) if advance && has_next => Some(self.now_ns + pause),
            _ => None,
        };
        tracing::info!(
            trainee = %self.trainee,
            exercise = %result.exercise,
            attempt = result.attempt,
            passed = result.passed,
            ended = ?result.ended,
            "exercise attempt ended"
        );
        self.stage = Stage::Ended {
            result,
            number: *number,
            advance_at_ns,
        };
        self.last_sent_ns = None;
    }

    /// Ends the running attempt (if one runs) for an instructor's control, and says so.
    fn end_for_control(&mut self, out: &mut Vec<String>) {
        if matches!(self.stage, Stage::Running { .. }) {
            self.end(false);
            out.extend(self.send(true));
        }
    }

    /// An instructor's control; what it ended is published and recorded into `out` at once,
    /// before what it starts.
    fn apply(&mut self, action: ExerciseAction, out: &mut Vec<String>) {
        match action {
            ExerciseAction::Next => {
                self.end_for_control(out);
                if self.index + 1 < self.exercises.len() {
                    self.start(self.index + 1);
                }
            }
            ExerciseAction::Repeat => {
                self.end_for_control(out);
                self.start(self.index);
            }
            ExerciseAction::Stop => self.end_for_control(out),
        }
    }

    /// The message saying where things stand now.
    fn message(&self) -> ExerciseMessage {
        let loaded = &self.exercises[self.index];
        let (state, attempt, remaining_s, result, next_in_s) = match &self.stage {
            Stage::Running { attempt, number } => (
                ExerciseState::Running,
                *number,
                attempt.remaining_s(),
                None,
                None,
            ),
            Stage::Ended {
                result,
                number,
                advance_at_ns,
            } => (
                ExerciseState::Ended,
                *number,
                0.0,
                Some((**result).clone()),
                advance_at_ns.map(|at| at.saturating_sub(self.now_ns) as f64 * 1e-9),
            ),
        };
        ExerciseMessage {
            trainee: self.trainee.clone(),
            index: self.index as u32,
            count: self.exercises.len() as u32,
            attempt,
            state,
            exercise: loaded.exercise.clone(),
            time_ns: self.now_ns,
            remaining_s,
            result,
            next_in_s,
            exercise_file: None,
            exercise_toml: None,
        }
    }

    /// Publishes where things stand, and returns the record of it when `record` (an attempt
    /// started or ended: the messages in between only count down, which a replay's viewer does
    /// on its own).
    fn send(&mut self, record: bool) -> Vec<String> {
        let mut message = self.message();
        self.last_sent_ns = Some(self.now_ns);
        let viewers = ServerMessage::Exercise(Box::new(message.clone())).encode();
        match viewers {
            Ok(text) => self.feed.publish(Utf8Bytes::from(text)),
            Err(e) => tracing::error!(error = %e, "could not encode an exercise message"),
        }
        if !record {
            return Vec::new();
        }
        self.publish_inclusions(&message, self.starting);
        if std::mem::take(&mut self.starting) {
            let loaded = &self.exercises[self.index];
            message.exercise_file = Some(loaded.path.display().to_string());
            message.exercise_toml = Some(loaded.source_toml.clone());
        }
        match ServerMessage::Exercise(Box::new(message)).encode() {
            Ok(text) => vec![text],
            Err(e) => {
                tracing::error!(error = %e, "could not encode an exercise record");
                Vec::new()
            }
        }
    }
}

impl TickObserver for ExerciseRun {
    fn tick(&mut self, record: &DeviceRecord) -> Vec<String> {
        self.now_ns = record.time_ns;
        let mut out = Vec::new();
        while let Ok(action) = self.controls.try_recv() {
            self.apply(action, &mut out);
        }
        let mut changed = self.starting;
        match &mut self.stage {
            Stage::Running { attempt, .. } => {
                if attempt.update(&TickInput::from_record(record)).is_some() {
                    self.end(true);
                    changed = true;
                }
            }
            Stage::Ended {
                advance_at_ns: Some(at),
                ..
            } if self.now_ns >= *at => {
                self.start(self.index + 1);
                changed = true;
            }
            Stage::Ended { .. } => {}
        }
        let due = self
            .last_sent_ns
            .is_none_or(|last| self.now_ns.saturating_sub(last) >= REPEAT_NS);
        if changed || due {
            out.extend(self.send(changed));
        }
        out
    }

    fn finish(&mut self) -> Vec<String> {
        if matches!(self.stage, Stage::Running { .. }) {
            self.end(false);
            self.send(true)
        } else {
            Vec::new()
        }
    }
}
