//! A station running exercises for a trainee: every viewer sees the task, the countdown and the
//! result; an attempt ends by its time limit and the next exercise starts after the pause; an
//! instructor repeats and stops one, an observer is refused; a later viewer is told where things
//! stand; the recording holds every attempt with its exercise file, `info` and `export` show
//! them, a replay shows them, and each live score is the one the recorded ticks give.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::sync::Arc;
use std::time::{Duration, Instant};

use futures_util::StreamExt;
use softhaptic_proto::exercise::{AttemptEnd, AttemptResult};
use softhaptic_proto::wire::{ExerciseMessage, ExerciseState, ServerMessage};
use softhaptic_server::exercise::run::{ExerciseRun, station_exercises};
use softhaptic_server::exercise::score::score_ticks;
use softhaptic_server::scene::Scene;
use softhaptic_server::session::reader::Recording;
use softhaptic_server::session::replay;
use softhaptic_server::session::tools::{Info, export};
use softhaptic_server::stream::{ExerciseFeed, REFUSED_EXERCISE_NONE, REFUSED_EXERCISE_OBSERVER};
use softhaptic_tests::{Viewer, scratch_dir, start_recorded_observed, test_options};
use tokio_tungstenite::tungstenite::Message;

const I: &str = softhaptic_tests::INSTRUCTOR_TOKEN;
const O: &str = softhaptic_tests::OBSERVER_TOKEN;

/// A press the scripted hand of the simulated device does not hold (it peaks near 1.4 N): it
/// ends by its 1 s limit.
const PRESS: &str = r#"
name = "Press and hold 1.8 N"
instructions = "Press the marked site with 1.8 N and hold it for 0.9 s."
kind = "press"
time_limit_s = 1.0

[press]
site_radius_m = 0.005
target_force_n = 1.8
tolerance_n = 0.1
hold_s = 0.9
"#;

/// A trace with a long limit: it runs until an instructor moves it on.
const TRACE: &str = r#"
name = "Trace a line"
instructions = "Follow the line from end to end."
kind = "trace"
time_limit_s = 600.0

[trace]
path_m = [[-0.0297, 0.0681, 0.0068], [-0.01495, 0.0700, 0.00667]]
tolerance_m = 0.003
min_coverage = 0.9
"#;

/// The next `exercise` message for which `until` holds (earlier ones are skipped).
async fn next_exercise(
    viewer: &mut Viewer,
    until: impl Fn(&ExerciseMessage) -> bool,
) -> ExerciseMessage {
    loop {
        let text = viewer.next_of("exercise").await;
        let ServerMessage::Exercise(m) = ServerMessage::decode(&text).unwrap() else {
            unreachable!()
        };
        assert!(
            m.exercise_toml.is_none() && m.exercise_file.is_none(),
            "a viewer is sent no file"
        );
        if until(&m) {
            return *m;
        }
    }
}

async fn viewer(addr: std::net::SocketAddr, token: &str) -> Viewer {
    let mut v = Viewer::connect(addr).await;
    v.authenticate(token).await;
    v
}

fn control(action: &str) -> String {
    format!(r#"{{"type":"exercise_control","action":"{action}"}}"#)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_station_runs_its_exercises_for_a_trainee_and_records_every_attempt() {
    let dir = scratch_dir("exercises-live");
    let press = dir.join("press.toml");
    let trace = dir.join("trace.toml");
    std::fs::write(&press, PRESS).unwrap();
    std::fs::write(&trace, TRACE).unwrap();
    let scene = Scene::builtin_default().unwrap();
    let exercises = station_exercises(&[press.clone(), trace.clone()], &scene, None).unwrap();
    let (feed, controls) = ExerciseFeed::with_controls();
    let feed = Arc::new(feed);
    let run = ExerciseRun::new(
        "ana".into(),
        exercises,
        Arc::clone(&feed),
        controls,
        Some(0.5),
    )
    .unwrap();
    let mut options = test_options();
    options.access.tokens = Some(softhaptic_tests::test_tokens());
    options.exercises = Some(feed);
    let live = start_recorded_observed(scene, &dir, options, Some(Box::new(run))).await;
    let addr = live.server.local_addr();
    let mut instructor = viewer(addr, I).await;
    let mut observer = viewer(addr, O).await;

    // The first exercise runs from the start: the task, for the trainee, counting down.
    let first = next_exercise(&mut observer, |_| true).await;
    assert_eq!(first.trainee, "ana");
    assert_eq!((first.index, first.count, first.attempt), (0, 2, 1));
    assert_eq!(first.exercise.name, "Press and hold 1.8 N");
    assert_eq!(first.exercise.task.kind(), "press");
    // It ends by its 1 s limit, with its result; the next one is due after the 0.5 s pause.
    let ended = next_exercise(&mut observer, |m| m.state == ExerciseState::Ended).await;
    assert_eq!(ended.index, 0);
    assert_eq!(ended.remaining_s, 0.0);
    let result = ended.result.clone().unwrap();
    assert_eq!(result.ended, AttemptEnd::TimeLimit);
    assert_eq!((result.trainee.as_str(), result.attempt), ("ana", 1));
    assert!(!result.passed, "{result:?}");
    assert!((result.end_ns - result.start_ns) as f64 * 1e-9 >= 1.0);
    assert!(ended.next_in_s.is_some_and(|s| s <= 0.5), "{ended:?}");
    let second = next_exercise(&mut instructor, |m| m.index == 1).await;
    assert_eq!((second.state, second.attempt), (ExerciseState::Running, 1));
    assert!(second.remaining_s > 590.0 && second.remaining_s <= 600.0);

    // An observer may not move the exercises on; an instructor repeats the trace, then stops it.
    observer.send_text(&control("next")).await;
    let refused = observer.next_of("refused").await;
    assert!(refused.contains(REFUSED_EXERCISE_OBSERVER), "{refused}");
    instructor.send_text(&control("repeat")).await;
    let repeat = next_exercise(&mut observer, |m| m.attempt == 2).await;
    assert_eq!((repeat.index, repeat.state), (1, ExerciseState::Running));
    instructor.send_text(&control("stop")).await;
    let stopped = next_exercise(&mut observer, |m| m.state == ExerciseState::Ended).await;
    assert_eq!((stopped.index, stopped.attempt), (1, 2));
    assert_eq!(stopped.result.as_ref().unwrap().ended, AttemptEnd::Stopped);
    // Stopped by an instructor, the station waits for the next word.
    assert_eq!(stopped.next_in_s, None);

    // A viewer that comes now is told where things stand as it connects.
    let mut late = viewer(addr, O).await;
    let now = next_exercise(&mut late, |_| true).await;
    assert_eq!(
        (now.index, now.attempt, now.state),
        (1, 2, ExerciseState::Ended)
    );

    let (_, _, path, _) = live.finish().await;
    let r = Recording::open(&path).unwrap();
    let attempts: Vec<&AttemptResult> = r.attempts().collect();
    let summary: Vec<(&str, u32, AttemptEnd)> = attempts
        .iter()
        .map(|a| (a.exercise.as_str(), a.attempt, a.ended))
        .collect();
    assert_eq!(
        summary,
        [
            ("Press and hold 1.8 N", 1, AttemptEnd::TimeLimit),
            ("Trace a line", 1, AttemptEnd::Stopped),
            ("Trace a line", 2, AttemptEnd::Stopped),
        ]
    );
    assert_eq!(*attempts[0], result);
    // Each attempt's first record carries its exercise file.
    for (name, file, text) in [
        ("Press and hold 1.8 N", &press, PRESS),
        ("Trace a line", &trace, TRACE),
    ] {
        let (recorded_file, recorded_text) = r.exercise_toml(name).unwrap();
        assert_eq!(recorded_file, file.display().to_string());
        assert_eq!(recorded_text, text);
    }
    // The live score is the one the recorded ticks give, with the same scorer.
    let press_exercise = &r.exercises.iter().find(|m| m.index == 0).unwrap().exercise;
    let rescored = score_ticks(
        press_exercise,
        r.device.iter().filter(|d| d.time_ns >= result.start_ns),
        "ana",
    );
    assert_eq!(rescored.score, result.score);
    assert_eq!(
        (rescored.start_ns, rescored.end_ns),
        (result.start_ns, result.end_ns)
    );

    // `info` lists the attempts; `export` writes them as JSON.
    let info = Info::of(&r).to_string();
    assert!(
        info.contains("\nexercises:         3 attempts, 0 passed\n"),
        "{info}"
    );
    assert!(
        info.contains("  ana, Press and hold 1.8 N #1 at "),
        "{info}"
    );
    let written = export(&r, &dir.join("export"), false).unwrap();
    let exported: Vec<AttemptResult> =
        serde_json::from_str(&std::fs::read_to_string(&written.attempts).unwrap()).unwrap();
    assert_eq!(exported.len(), 3);
    assert_eq!(exported[0], result);

    // `results` gathers the recorded attempts, at both exercises, into one CSV and a page with
    // a section per exercise.
    let (csv, html) = (dir.join("results.csv"), dir.join("results.html"));
    softhaptic_server::exercise::cli::run_results(softhaptic_server::exercise::cli::ResultsArgs {
        recordings: vec![path.clone()],
        exercise: None,
        trainee: None,
        csv: csv.clone(),
        html: Some(html.clone()),
        replace: false,
    })
    .unwrap();
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let cells = |name: &str| rows.iter().map(|r| r[column(name)]).collect::<Vec<_>>();
    assert_eq!(
        cells("exercise"),
        ["Press and hold 1.8 N", "Trace a line", "Trace a line"]
    );
    assert_eq!(cells("attempt"), ["1", "1", "2"]);
    assert_eq!(cells("ended"), ["time_limit", "stopped", "stopped"]);
    // Each kind's metrics, empty where the other kind has none.
    assert_eq!(cells("hold_s")[1], "");
    assert_eq!(cells("mean_deviation_m")[0], "");
    assert_eq!(
        cells("hold_s")[0],
        result.score.metrics["hold_s"].to_string()
    );
    let page = std::fs::read_to_string(&html).unwrap();
    assert_eq!(page.matches("<section class=\"exercise\">").count(), 2);
    assert!(page.contains("data-metric=\"hold_s\"") && page.contains("data-metric=\"coverage\""));

    // A replay shows the attempts as the station's viewers saw them, and takes no controls.
    let replay = replay::start(r, softhaptic_tests::replay_options(4.0, true))
        .await
        .unwrap();
    let mut watcher = Viewer::connect(replay.local_addr()).await;
    watcher.next_of("replay").await;
    watcher
        .send_text(r#"{"type":"replay_control","action":"play","speed":4.0}"#)
        .await;
    let replayed = next_exercise(&mut watcher, |m| m.state == ExerciseState::Ended).await;
    assert_eq!(replayed.result.as_ref(), Some(&result));
    watcher.send_text(&control("next")).await;
    let refused = watcher.next_of("refused").await;
    assert!(refused.contains(REFUSED_EXERCISE_NONE), "{refused}");
    replay.shutdown().await;
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_exercise_made_for_another_scene_is_refused_naming_both() {
    let dir = scratch_dir("exercises-scene");
    let file = dir.join("press.toml");
    let scene_file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cone.toml");
    std::fs::write(
        &file,
        format!("scene = {:?}\n{PRESS}", scene_file.display().to_string()),
    )
    .unwrap();
    let station = Scene::builtin_default().unwrap();
    let e = station_exercises(std::slice::from_ref(&file), &station, None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("press.toml: scene: set in "), "{e}");
    assert!(
        e.contains("cone.toml, but this station runs the built-in default scene"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A palpation at a station: the trainee's viewer (an observer) is sent nothing that says where
/// the lumps are — not in the scene, not in a frame, not in the exercise — until the attempt
/// ends, and then only how many were found.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_palpation_never_tells_the_trainee_where_the_lumps_are() {
    let dir = scratch_dir("exercises-palpation");
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let scene_file = root.join("scenes/palpation.toml");
    let scene = Scene::load(&scene_file).unwrap();
    // Every coordinate of every lump, as JSON would write it (world frame, and object frame).
    let secrets = softhaptic_tests::inclusion_coordinates(&scene);
    assert_eq!(secrets.len(), 12);
    let exercises = station_exercises(
        &[root.join("exercises/palpation.toml")],
        &scene,
        Some(&scene_file),
    )
    .unwrap();
    let (feed, controls) = ExerciseFeed::with_controls();
    let feed = Arc::new(feed);
    let run = ExerciseRun::new("ana".into(), exercises, Arc::clone(&feed), controls, None).unwrap();
    let mut options = test_options();
    options.access.tokens = Some(softhaptic_tests::test_tokens());
    options.exercises = Some(feed);
    let live = start_recorded_observed(scene, &dir, options, Some(Box::new(run))).await;
    let addr = live.server.local_addr();
    let mut trainee = viewer(addr, O).await;

    // Everything the trainee's viewer is sent while the attempt runs: the scene, frames while
    // the scripted hand presses, stats, the exercise.
    let deadline = Instant::now() + Duration::from_secs(30);
    let (mut frames, mut exercise) = (0, None);
    while frames < 100 || exercise.is_none() {
        assert!(
            Instant::now() < deadline,
            "{frames} frames, exercise {exercise:?}"
        );
        let Ok(Some(Ok(Message::Text(t)))) =
            tokio::time::timeout(Duration::from_secs(10), trainee.socket.next()).await
        else {
            continue;
        };
        for secret in &secrets {
            assert!(!t.contains(secret.as_str()), "{secret} in {t}");
        }
        if t.starts_with(r#"{"type":"contact""#) {
            frames += 1;
        } else if t.starts_with(r#"{"type":"exercise""#) {
            let ServerMessage::Exercise(m) = ServerMessage::decode(&t).unwrap() else {
                unreachable!()
            };
            assert_eq!(m.exercise.task.kind(), "palpation");
            exercise = Some(m.state);
        }
    }
    assert_eq!(exercise, Some(ExerciseState::Running));

    // Stopped, the result says how many were found (none: the hand pressed no button).
    let mut instructor = viewer(addr, I).await;
    instructor.send_text(&control("stop")).await;
    let ended = next_exercise(&mut trainee, |m| m.state == ExerciseState::Ended).await;
    let score = &ended.result.as_ref().unwrap().score;
    assert_eq!(score.metrics["found"], 0.0);
    assert_eq!(score.metrics["missed"], 2.0);
    assert!(!score.completed);
    live.finish().await;
    let _ = std::fs::remove_dir_all(&dir);
}
