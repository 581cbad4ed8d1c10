//! Who may do what: the one table every HTTP route and every WebSocket message consults
//! (docs/roles.md says the same in words).
//!
//! A route or a message names the [`Action`] it performs; [`may`] answers for a role. Keeping
//! the answer in one `match` (rather than a check written at each route) is what makes "an
//! observer may not download the archive" true of every route that downloads it, the HTTP
//! ones and the WebSocket ones alike.

use softhaptic_proto::wire::Role;

/// What a request or a message does, as far as the roles are concerned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    /// Watch a live session: its scene and meshes, its frames, stats, metrics and marks (a
    /// station's page, a hub's relay of a station), and a hub's station list.
    WatchLive,
    /// Watch a replay that is already open: a replay server's (its command line opened it), or
    /// a hub's replay of an archived recording while an instructor's viewer has it open.
    WatchOpenReplay,
    /// Open an archived recording's replay on a hub: the hub fetches and decodes the file.
    OpenReplay,
    /// Play, pause, seek or change the speed of a replay (`replay_control`).
    ControlReplay,
    /// Mark a live session (`add_mark`).
    Mark,
    /// Switch a live device's force output back on after it latched off (`rearm_device`).
    RearmDevice,
    /// Start the next exercise, repeat one or stop one at a station (`exercise_control`).
    ControlExercise,
    /// List a lab's archived recordings (`GET /api/archive`).
    ListArchive,
    /// Download an archived recording's file (`GET /stations/NAME/archive/FILE`).
    DownloadArchive,
    /// Be sent where a palpation scene's inclusions are while an attempt runs (`inclusions`
    /// with `revealed: false`): the answer the trainee must find. Once a palpation attempt has
    /// ended every viewer is sent it. A station without tokens sends it to no one before the
    /// end: there everyone is an instructor, the trainee's own screen too.
    SeeInclusions,
    /// Act on a station from a lab hub's dashboard (`station_action`): acknowledge an alert,
    /// start, repeat or stop its exercise, mark its session, re-arm its device.
    ActOnStation,
}

impl Action {
    /// Every action, for tables and tests.
    pub const ALL: [Action; 11] = [
        Action::WatchLive,
        Action::WatchOpenReplay,
        Action::OpenReplay,
        Action::ControlReplay,
        Action::Mark,
        Action::RearmDevice,
        Action::ControlExercise,
        Action::ListArchive,
        Action::DownloadArchive,
        Action::SeeInclusions,
        Action::ActOnStation,
    ];

    /// What an observer is told when it tries this (one sentence, no secret, no internal state).
    pub const fn observer_refusal(self) -> &'static str {
        match self {
            Action::WatchLive | Action::WatchOpenReplay => "allowed",
            Action::OpenReplay => {
                "an observer watches a replay only once an instructor has opened it"
            }
            Action::ControlReplay => {
                "an observer cannot control the replay: only an instructor's link can"
            }
            Action::Mark => "only an instructor marks the session",
            Action::RearmDevice => "only an instructor re-arms the device",
            Action::ControlExercise => "only an instructor starts, repeats or stops an exercise",
            Action::ListArchive => "only an instructor lists the archive",
            Action::DownloadArchive => "only an instructor downloads archived recordings",
            Action::SeeInclusions => {
                "only an instructor sees where the inclusions are before the attempt ends"
            }
            Action::ActOnStation => "only an instructor acts on a station",
        }
    }
}

/// Whether `role` may do `action`. An instructor may do everything; an observer watches, and
/// nothing else: it neither changes what others see (controls, marks), nor makes a hub fetch a
/// recording, nor takes recordings away (the raw samples and the instructors' marks of every
/// trainee).
pub fn may(role: Role, action: Action) -> bool {
    match role {
        Role::Instructor => true,
        Role::Observer => matches!(action, Action::WatchLive | Action::WatchOpenReplay),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_instructor_may_everything_an_observer_only_watch() {
        for action in Action::ALL {
            assert!(may(Role::Instructor, action), "{action:?}");
            let watching = matches!(action, Action::WatchLive | Action::WatchOpenReplay);
            assert_eq!(may(Role::Observer, action), watching, "{action:?}");
            if !watching {
                assert_ne!(action.observer_refusal(), "allowed");
            }
        }
    }
}
