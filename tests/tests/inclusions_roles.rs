//! What each role is told of a palpation scene's inclusions, over real WebSockets
//! (docs/roles.md, "What each role sees"): an instructor of a station with tokens is sent where
//! they are as it connects; the trainee's viewer (an observer) is sent no `inclusions` message and
//! no coordinate of a lump in any message until the attempt ends, and then the answer; a viewer
//! that connects after the end gets it too, until the next attempt starts. On a station without
//! tokens nobody is sent them before the end. A replay of the recording tells each role what
//! the live station told it, and so does a lab hub relaying the station through a real
//! nats-server.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::sync::Arc;
use std::time::{Duration, Instant};

use futures_util::StreamExt;
use softhaptic_proto::wire::{ExerciseState, InclusionsMessage, ServerMessage};
use softhaptic_server::exercise::run::{ExerciseRun, inclusions_feed, station_exercises};
use softhaptic_server::scene::Scene;
use softhaptic_server::session::reader::Recording;
use softhaptic_server::session::replay;
use softhaptic_server::stream::ExerciseFeed;
use softhaptic_tests::{
    RecordedServer, Viewer, scratch_dir, start_recorded_observed, test_options,
};
use tokio_tungstenite::tungstenite::Message;

const I: &str = softhaptic_tests::INSTRUCTOR_TOKEN;
const O: &str = softhaptic_tests::OBSERVER_TOKEN;

fn root() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The palpation station, with or without tokens, recording into `dir`.
async fn station(dir: &std::path::Path, tokens: bool) -> (RecordedServer, Scene) {
    lab_station(dir, tokens, None).await
}

/// The palpation station, publishing to the NATS at `nats` as `(name, url)` when given.
async fn lab_station(
    dir: &std::path::Path,
    tokens: bool,
    nats: Option<(&str, String)>,
) -> (RecordedServer, Scene) {
    let scene_file = root().join("scenes/palpation.toml");
    let scene = Scene::load(&scene_file).unwrap();
    let exercises = station_exercises(
        &[root().join("exercises/palpation.toml")],
        &scene,
        Some(&scene_file),
    )
    .unwrap();
    let (feed, controls) = ExerciseFeed::with_controls();
    let feed = Arc::new(feed);
    let inclusions = inclusions_feed(&scene);
    assert!(inclusions.is_some());
    let run = ExerciseRun::new("ana".into(), exercises, Arc::clone(&feed), controls, None)
        .unwrap()
        .with_inclusions(inclusions.clone(), &scene);
    let mut options = test_options();
    if tokens {
        options.access.tokens = Some(softhaptic_tests::test_tokens());
    }
    options.exercises = Some(feed);
    options.inclusions = inclusions;
    options.lab = nats.map(
        |(name, url)| softhaptic_server::lab::station::StationOptions {
            nats: softhaptic_tests::nats::options(url),
            name: name.to_owned(),
        },
    );
    let live = start_recorded_observed(scene.clone(), dir, options, Some(Box::new(run))).await;
    (live, scene)
}

async fn viewer(addr: std::net::SocketAddr, token: Option<&str>) -> Viewer {
    let mut v = Viewer::connect(addr).await;
    if let Some(token) = token {
        v.authenticate(token).await;
    }
    v
}

/// The next text message, within 10 s.
async fn next_text(v: &mut Viewer) -> String {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        assert!(Instant::now() < deadline, "no message");
        if let Ok(Some(Ok(Message::Text(t)))) =
            tokio::time::timeout(Duration::from_secs(10), v.socket.next()).await
        {
            return t.to_string();
        }
    }
}

/// Reads until `frames` contact frames and an exercise message in `state` have come, checking
/// that nothing read is an `inclusions` message or holds a lump's coordinate.
async fn told_nothing(v: &mut Viewer, secrets: &[String], frames: usize, state: ExerciseState) {
    let deadline = Instant::now() + Duration::from_secs(30);
    let (mut seen, mut exercise) = (0, false);
    while seen < frames || !exercise {
        assert!(
            Instant::now() < deadline,
            "{seen} frames, exercise {exercise}"
        );
        let t = next_text(v).await;
        assert!(!t.starts_with(r#"{"type":"inclusions""#), "{t}");
        for secret in secrets {
            assert!(!t.contains(secret.as_str()), "{secret} in {t}");
        }
        if t.starts_with(r#"{"type":"contact""#) {
            seen += 1;
        } else if let Ok(ServerMessage::Exercise(m)) = ServerMessage::decode(&t) {
            exercise |= m.state == state;
        }
    }
}

/// The next `inclusions` message (others skipped).
async fn next_inclusions(v: &mut Viewer) -> InclusionsMessage {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        assert!(Instant::now() < deadline, "no inclusions message");
        let t = next_text(v).await;
        if let Ok(ServerMessage::Inclusions(m)) = ServerMessage::decode(&t) {
            return m;
        }
    }
}

/// The message's inclusions are the scene's, in the world frame.
fn are_the_scenes(m: &InclusionsMessage, scene: &Scene) {
    assert_eq!(m.inclusions.len(), scene.inclusions.len());
    for (view, placed) in m.inclusions.iter().zip(&scene.inclusions) {
        let world = scene
            .object_in_world
            .transform_point(glam::DVec3::from_array(placed.centre_in_object_m));
        assert!((glam::DVec3::from_array(view.centre_m) - world).length() < 1e-12);
        assert_eq!(view.radius_m, placed.radius_m);
        assert_eq!(view.stiffness_ratio, placed.stiffness_ratio);
    }
}

fn control(action: &str) -> String {
    format!(r#"{{"type":"exercise_control","action":"{action}"}}"#)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn instructors_see_the_lumps_live_the_trainee_only_after_the_end() {
    let dir = scratch_dir("inclusions-roles");
    let (live, scene) = station(&dir, true).await;
    let secrets = softhaptic_tests::inclusion_coordinates(&scene);
    assert_eq!(secrets.len(), 12);
    let addr = live.server.local_addr();
    let mut trainee = viewer(addr, Some(O)).await;
    let mut instructor = viewer(addr, Some(I)).await;

    // The instructor is told at once; the trainee nothing, over frames and the exercise.
    let shown = next_inclusions(&mut instructor).await;
    assert!(!shown.revealed);
    are_the_scenes(&shown, &scene);
    told_nothing(&mut trainee, &secrets, 50, ExerciseState::Running).await;

    // Stopped: everyone is told, the trainee too, as the answer of attempt 1.
    instructor.send_text(&control("stop")).await;
    let revealed = next_inclusions(&mut trainee).await;
    assert!(revealed.revealed);
    assert_eq!(
        (revealed.exercise_index, revealed.attempt),
        (Some(0), Some(1))
    );
    are_the_scenes(&revealed, &scene);
    // A viewer that comes after the end is told as it connects.
    let mut late = viewer(addr, Some(O)).await;
    assert!(next_inclusions(&mut late).await.revealed);

    // A repeat hides it again from viewers that come later; the instructor is told attempt 2.
    instructor.send_text(&control("repeat")).await;
    loop {
        let m = next_inclusions(&mut instructor).await;
        if m.attempt == Some(2) {
            assert!(!m.revealed);
            break;
        }
    }
    // The trainee who was told attempt 1's answer is told it is withdrawn.
    let withdrawn = next_inclusions(&mut trainee).await;
    assert!(!withdrawn.revealed && withdrawn.inclusions.is_empty());
    let mut next_trainee = viewer(addr, Some(O)).await;
    told_nothing(&mut next_trainee, &secrets, 25, ExerciseState::Running).await;
    let (_, _, path, _) = live.finish().await;

    // The replay tells each role what the station told it: the instructor at once, the
    // observer only from attempt 1's end.
    let recording = Recording::open(&path).unwrap();
    let end_ns = recording
        .exercises
        .iter()
        .find(|m| m.state == ExerciseState::Ended && m.attempt == 1)
        .unwrap()
        .time_ns;
    let mut options = softhaptic_tests::replay_options(8.0, true);
    options.access.tokens = Some(softhaptic_tests::test_tokens());
    let replay = replay::start(recording, options).await.unwrap();
    let mut watcher = viewer(replay.local_addr(), Some(O)).await;
    let mut teacher = viewer(replay.local_addr(), Some(I)).await;
    let shown = next_inclusions(&mut teacher).await;
    assert!(!shown.revealed);
    are_the_scenes(&shown, &scene);
    teacher
        .send_text(r#"{"type":"replay_control","action":"play","speed":8.0}"#)
        .await;
    // The observer is told only once the replay has reached the attempt's end: every frame it
    // had before is at most a frame's time away from it (the two come on separate channels, so
    // either may be first), and nothing before holds a coordinate.
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut last_frame_ns = 0;
    loop {
        assert!(
            Instant::now() < deadline,
            "the replay's attempt did not end"
        );
        let t = next_text(&mut watcher).await;
        match ServerMessage::decode(&t) {
            Ok(ServerMessage::Contact(frame)) => last_frame_ns = frame.time_ns,
            Ok(ServerMessage::Inclusions(m)) => {
                assert!(m.revealed && m.attempt == Some(1));
                assert!(
                    last_frame_ns + 100_000_000 >= end_ns,
                    "told at {last_frame_ns} ns, the attempt ended at {end_ns} ns"
                );
                break;
            }
            _ => {}
        }
        for secret in &secrets {
            assert!(!t.contains(secret.as_str()), "{secret} in {t}");
        }
    }
    // Sought back before the end, the answer is withdrawn from the observer who was told it.
    teacher
        .send_text(r#"{"type":"replay_control","action":"seek","time_s":0.0}"#)
        .await;
    let withdrawn = next_inclusions(&mut watcher).await;
    assert!(!withdrawn.revealed && withdrawn.inclusions.is_empty());
    assert_eq!((withdrawn.exercise_index, withdrawn.attempt), (None, None));
    replay.shutdown().await;
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn without_tokens_nobody_sees_the_lumps_before_the_end() {
    let dir = scratch_dir("inclusions-no-tokens");
    let (live, scene) = station(&dir, false).await;
    let secrets = softhaptic_tests::inclusion_coordinates(&scene);
    let addr = live.server.local_addr();
    // Everyone is an instructor here, the trainee's screen too: told nothing until the end.
    let mut screen = viewer(addr, None).await;
    told_nothing(&mut screen, &secrets, 50, ExerciseState::Running).await;
    screen.send_text(&control("stop")).await;
    let revealed = next_inclusions(&mut screen).await;
    assert!(revealed.revealed);
    are_the_scenes(&revealed, &scene);
    live.finish().await;
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lab_hub_tells_each_role_what_the_station_would() {
    let nats = softhaptic_tests::nats::NatsServer::start("inclusions-hub");
    let dir = scratch_dir("inclusions-hub");
    let (live, scene) = lab_station(&dir, true, Some(("desk-p", nats.url()))).await;
    let secrets = softhaptic_tests::inclusion_coordinates(&scene);
    let hub =
        softhaptic_tests::nats::start_hub(softhaptic_tests::nats::options(nats.url()), true).await;
    softhaptic_tests::wait_until("the station listed on the hub", || {
        hub.stations()
            .iter()
            .any(|s| s.name == "desk-p" && s.state != "offline")
    })
    .await;
    let url = format!("ws://{}/ws?station=desk-p", hub.local_addr());
    let on_hub = |token: &'static str| {
        let url = url.clone();
        async move {
            let mut v = Viewer::connect_url(&url).await;
            v.authenticate(token).await;
            v
        }
    };
    let mut trainee = on_hub(O).await;
    let mut teacher = on_hub(I).await;

    // Through the hub as on the station: the instructor is told at once, the trainee nothing.
    let shown = next_inclusions(&mut teacher).await;
    assert!(!shown.revealed);
    are_the_scenes(&shown, &scene);
    told_nothing(&mut trainee, &secrets, 25, ExerciseState::Running).await;

    // A mark made at the station reaches the hub's viewers.
    let mut desk = viewer(live.server.local_addr(), Some(I)).await;
    desk.send_text(r#"{"type":"add_mark","note":"pressed too hard"}"#)
        .await;
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        assert!(Instant::now() < deadline, "no mark through the hub");
        if let Ok(ServerMessage::Mark(m)) = ServerMessage::decode(&next_text(&mut trainee).await) {
            assert_eq!((m.id, m.note.as_str()), (1, "pressed too hard"));
            break;
        }
    }

    // The attempt ends at the station: the hub's trainee is told the answer, and so is a viewer
    // of the hub that comes later, with the mark and the ended exercise.
    desk.send_text(&control("stop")).await;
    let revealed = next_inclusions(&mut trainee).await;
    assert!(revealed.revealed);
    are_the_scenes(&revealed, &scene);
    let mut late = on_hub(O).await;
    let (mut mark, mut ended, mut answer) = (false, false, false);
    let deadline = Instant::now() + Duration::from_secs(30);
    while !(mark && ended && answer) {
        assert!(
            Instant::now() < deadline,
            "mark {mark}, ended {ended}, answer {answer}"
        );
        match ServerMessage::decode(&next_text(&mut late).await) {
            Ok(ServerMessage::Mark(_)) => mark = true,
            Ok(ServerMessage::Exercise(m)) => ended |= m.state == ExerciseState::Ended,
            Ok(ServerMessage::Inclusions(m)) => answer |= m.revealed,
            _ => {}
        }
    }
    hub.shutdown().await;
    let _ = live.finish().await;
    let _ = std::fs::remove_dir_all(&dir);
}
