//! The exercise a station runs, between the scorer and the viewers: the `exercise` messages
//! the scorer publishes (the latest kept for a viewer that connects later) and the instructors'
//! `exercise_control` requests it takes.
//!
//! The scorer runs on the recorder's thread, tick by tick (`softhaptic_server::exercise::run`,
//! in the crate that starts a station); the viewers' tasks run on the async runtime. Both sides
//! only try: a publication never waits for a viewer, and a control never waits for the scorer
//! (a full queue refuses it).

use std::sync::Mutex;
use std::sync::mpsc::{Receiver, SyncSender, TrySendError};

use axum::extract::ws::Utf8Bytes;
use softhaptic_proto::wire::ExerciseAction;
use tokio::sync::broadcast;

/// `exercise` messages a slow viewer may fall behind by before it loses one (about one a second;
/// the next one says all the lost one did).
pub const EXERCISE_BACKLOG: usize = 8;
/// Instructors' controls waiting for the scorer (it takes them within a few milliseconds).
const CONTROL_QUEUE: usize = 8;

/// The feed of one stream: empty, and taking no controls, where no exercises run.
pub struct ExerciseFeed {
    pub messages: broadcast::Sender<Utf8Bytes>,
    latest: Mutex<Option<Utf8Bytes>>,
    controls: Option<SyncSender<ExerciseAction>>,
}

/// Why an instructor's control was not passed on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ControlRefusal {
    /// This stream runs no exercises (a plain session, a replay, a lab hub).
    NoExercises,
    /// Controls arrive faster than the scorer takes them.
    Busy,
}

impl ExerciseFeed {
    /// The feed of a stream without exercises.
    pub fn none() -> Self {
        Self {
            messages: broadcast::channel(EXERCISE_BACKLOG).0,
            latest: Mutex::new(None),
            controls: None,
        }
    }

    /// The feed of a station running exercises, and the scorer's end of its controls.
    pub fn with_controls() -> (Self, Receiver<ExerciseAction>) {
        let (tx, rx) = std::sync::mpsc::sync_channel(CONTROL_QUEUE);
        (
            Self {
                controls: Some(tx),
                ..Self::none()
            },
            rx,
        )
    }

    /// Whether an instructor may move exercises on here.
    pub fn takes_controls(&self) -> bool {
        self.controls.is_some()
    }

    /// Sends `text` (an encoded `exercise` message) to every viewer and keeps it for later ones.
    pub fn publish(&self, text: Utf8Bytes) {
        *self.latest.lock().unwrap_or_else(|p| p.into_inner()) = Some(text.clone());
        // No viewer connected is not an error: the latest is kept.
        let _ = self.messages.send(text);
    }

    /// The latest message, for a viewer as it connects.
    pub fn latest(&self) -> Option<Utf8Bytes> {
        self.latest
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Passes an instructor's control to the scorer.
    pub fn control(&self, action: ExerciseAction) -> Result<(), ControlRefusal> {
        let Some(tx) = &self.controls else {
            return Err(ControlRefusal::NoExercises);
        };
        match tx.try_send(action) {
            Ok(()) => Ok(()),
            Err(TrySendError::Full(_)) => Err(ControlRefusal::Busy),
            // The scorer has stopped with the session: there is nothing left to move on.
            Err(TrySendError::Disconnected(_)) => Err(ControlRefusal::NoExercises),
        }
    }
}
