//! Exercises through the real `softhaptic` binary, on attempts recorded from scripted hands:
//! `exercise check` on the shipped files, `exercise score` on hands that pass and that fail each
//! kind (the scores against what the scripted motion gives), `benchmark` from five scripted
//! experts (refused from four), and `results` as CSV read back by a CSV parser and an HTML
//! report with a plot per metric.

// Test code, synchronous: records the attempts and reads the files the commands wrote.
#![allow(clippy::disallowed_methods)]
#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use glam::DVec3;
use softhaptic_device::sim::HandScript;
use softhaptic_server::scene::Scene;
use softhaptic_server::session::script::record_hand;

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(path)
}

fn softhaptic(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_softhaptic"))
        .args(args)
        .env_remove("RUST_BACKTRACE")
        .output()
        .expect("softhaptic runs")
}

fn ok(out: &Output) -> String {
    assert!(
        out.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("softhaptic-exercise-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

const SCENE_TOML: &str = include_str!("../../scenes/default.toml");

fn scene() -> Scene {
    Scene::load(&repo("scenes/default.toml")).unwrap()
}

/// A press at the scene's press site, `depth_m` below the surface, held for `hold_s`.
fn press(scene: &Scene, depth_m: f64, hold_s: f64) -> HandScript {
    let mut s = scene.hand_script();
    s.repeat = false;
    s.press_depth_m = depth_m;
    s.hold_s = hold_s;
    s.slide_distance_m = 0.0;
    s.slide_s = 0.0;
    s
}

fn record(scene: &Scene, script: HandScript, out: &Path) {
    record_hand(scene, SCENE_TOML, script, "exercise-test", out, |_| {}).unwrap();
}

fn metric(report: &str, name: &str) -> f64 {
    report
        .lines()
        .find_map(|l| {
            let mut words = l.split_whitespace();
            (words.next() == Some(name)).then(|| words.next().unwrap().parse().unwrap())
        })
        .unwrap_or_else(|| panic!("{name} not in\n{report}"))
}

#[test]
fn the_shipped_exercises_check() {
    let files = [
        repo("exercises/press-hold.toml"),
        repo("exercises/trace-line.toml"),
        repo("exercises/palpation.toml"),
        repo("exercises/follow-slide.toml"),
    ];
    let mut args: Vec<&std::ffi::OsStr> = vec!["exercise".as_ref(), "check".as_ref()];
    args.extend(files.iter().map(|f| f.as_os_str()));
    let out = ok(&softhaptic(&args));
    assert!(out.contains("Press and hold 1 N (press, 20 s)"), "{out}");
    assert!(out.contains("Trace a line at 1 N (trace, 30 s)"), "{out}");
    assert!(out.contains("Find the lumps (palpation, 90 s)"), "{out}");
    assert!(out.contains("for 2 inclusions"), "{out}");
    assert!(
        out.contains("Follow the expert's slide (follow, 30 s)")
            && out.contains("the path comes from the station's --guide"),
        "{out}"
    );
}

#[test]
fn a_guided_slide_scores_its_deviation_from_the_expert_and_a_station_needs_the_guide() {
    // The shipped guided session: a loose hand 6 mm beside the slide, pulled at full gain. It
    // never lifts away, so the pass (the attempt) does not end; the deviation is `info`'s.
    let out = score(
        &repo("tests/sessions/guided-slide.mcap"),
        &repo("exercises/follow-slide.toml"),
    );
    let path_m = metric(&out, "path_deviation_m");
    assert!((0.0015..0.0021).contains(&path_m), "{out}");
    assert!(
        (metric(&out, "force_deviation_n") - 0.19).abs() < 0.02,
        "{out}"
    );
    assert_eq!(metric(&out, "guide_gain"), 1.0, "{out}");
    assert!(
        out.contains("mark path_deviation_m") && out.contains("not completed"),
        "{out}"
    );
    // Without a guide the station cannot run it, and says how.
    let follow = repo("exercises/follow-slide.toml");
    let default = repo("scenes/default.toml");
    let out = softhaptic(&[
        "run".as_ref(),
        "--addr".as_ref(),
        "127.0.0.1:0".as_ref(),
        "--no-realtime".as_ref(),
        "--scene".as_ref(),
        default.as_os_str(),
        "--exercises".as_ref(),
        follow.as_os_str(),
        "--trainee".as_ref(),
        "ana".as_ref(),
    ]);
    assert!(!out.status.success());
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(e.contains("start it with --guide slide.mcap"), "{e}");
}

fn score(recording: &Path, exercise: &Path) -> String {
    ok(&softhaptic(&[
        "exercise".as_ref(),
        "score".as_ref(),
        recording.as_os_str(),
        "--exercise".as_ref(),
        exercise.as_os_str(),
    ]))
}

#[test]
fn a_press_held_passes_and_one_too_hard_or_too_short_fails() {
    let d = dir("press");
    let scene = scene();
    let exercise = repo("exercises/press-hold.toml");
    // 6 mm into the liver gives about 1.0 N (the window is 1 ± 0.25 N), held 3 s: the script
    // approaches for 0.5 s and presses for 0.5 s, so the force enters the window between 0.5 s
    // and a little after 1 s, and the 2 s hold is complete 2 s later; the attempt ends there.
    let good = d.join("good.mcap");
    record(&scene, press(&scene, 0.006, 3.0), &good);
    let out = score(&good, &exercise);
    assert!(
        out.contains("— passed (completed, safe, ended: Completed"),
        "{out}"
    );
    assert_eq!(metric(&out, "hold_s"), 2.0);
    let to_hold = metric(&out, "time_to_hold_s");
    assert!((2.5..3.2).contains(&to_hold), "{out}");
    assert!(
        (0.75..=1.25).contains(&metric(&out, "peak_force_n")),
        "{out}"
    );
    assert!(metric(&out, "hold_force_sd_n") < 0.25, "{out}");
    assert_eq!(metric(&out, "time_above_safe_s"), 0.0);

    // 14 mm: the force passes the window and the scene's 2 N safe force.
    let hard = d.join("hard.mcap");
    record(&scene, press(&scene, 0.014, 3.0), &hard);
    let out = score(&hard, &exercise);
    assert!(out.contains("— not passed (not completed, UNSAFE"), "{out}");
    assert!(metric(&out, "peak_force_n") > 2.0, "{out}");
    assert!(metric(&out, "time_above_safe_s") > 0.5, "{out}");
    assert!(metric(&out, "hold_s") < 0.5, "{out}");

    // Held 1 s only: the hold is that second and the ramps' share of the window, short of 2 s.
    let short = d.join("short.mcap");
    record(&scene, press(&scene, 0.006, 1.0), &short);
    let out = score(&short, &exercise);
    assert!(
        out.contains("— not passed (not completed, safe, ended: Stopped"),
        "{out}"
    );
    let hold = metric(&out, "hold_s");
    assert!((1.0..1.8).contains(&hold), "{out}");
}

/// A trace: pressed 6 mm in, then slid 15 mm over 3 s along `direction` (world frame).
fn slide(scene: &Scene, direction: DVec3) -> HandScript {
    let mut s = press(scene, 0.006, 0.5);
    s.slide_direction = direction;
    s.slide_distance_m = 0.015;
    s.slide_s = 3.0;
    s
}

#[test]
fn a_stroke_along_the_line_traces_it_and_one_across_it_does_not() {
    let d = dir("trace");
    let scene = scene();
    let exercise = repo("exercises/trace-line.toml");
    // The file's line runs 15 mm from the press site along the surface toward +x.
    let along = d.join("along.mcap");
    record(&scene, slide(&scene, DVec3::X), &along);
    let out = score(&along, &exercise);
    assert!(
        out.contains("— passed (completed, safe, ended: Completed"),
        "{out}"
    );
    assert!(metric(&out, "coverage") >= 0.9, "{out}");
    // The hand follows the line: well inside the 3 mm tolerance all the way.
    assert!(metric(&out, "max_deviation_m") < 0.0015, "{out}");
    assert!(metric(&out, "mean_deviation_m") < 0.001, "{out}");
    assert!(metric(&out, "in_window_fraction") > 0.7, "{out}");

    // Across it (toward +z): only the first 3 mm of the line lie within 3 mm of the stroke's
    // start, about a fifth of its 15 mm.
    let across = d.join("across.mcap");
    record(&scene, slide(&scene, DVec3::Z), &across);
    let out = score(&across, &exercise);
    assert!(out.contains("— not passed (not completed, safe"), "{out}");
    let coverage = metric(&out, "coverage");
    assert!(coverage < 0.3, "{out}");
    assert!(metric(&out, "max_deviation_m") > 0.01, "{out}");
}

#[test]
fn a_benchmark_of_five_experts_sets_marks_that_an_expert_like_trainee_meets() {
    let d = dir("benchmark");
    let scene = scene();
    let exercise = d.join("press.toml");
    std::fs::copy(repo("exercises/press-hold.toml"), &exercise).unwrap();
    let experts: Vec<PathBuf> = [0.0058, 0.0059, 0.006, 0.0061, 0.0062]
        .iter()
        .enumerate()
        .map(|(i, depth)| {
            let path = d.join(format!("expert-{i}.mcap"));
            record(&scene, press(&scene, *depth, 3.0), &path);
            path
        })
        .collect();
    let mut args: Vec<&std::ffi::OsStr> = vec!["benchmark".as_ref()];
    args.extend(experts[..4].iter().map(|p| p.as_os_str()));
    args.extend(["--exercise".as_ref(), exercise.as_os_str()]);
    let four = softhaptic(&args);
    assert!(!four.status.success());
    assert!(
        String::from_utf8_lossy(&four.stderr)
            .contains("a benchmark needs at least 5 experts' recordings, got 4"),
        "{}",
        String::from_utf8_lossy(&four.stderr)
    );

    args.insert(5, experts[4].as_os_str());
    args.push("--write".as_ref());
    let out = ok(&softhaptic(&args));
    assert!(out.contains("5 experts' recordings"), "{out}");
    // The peaks each expert reached, from `exercise score`: the mark is their mean + 1 SD.
    let peaks: Vec<f64> = experts
        .iter()
        .map(|e| metric(&score(e, &exercise), "peak_force_n"))
        .collect();
    let mean = peaks.iter().sum::<f64>() / 5.0;
    let sd = (peaks.iter().map(|p| (p - mean).powi(2)).sum::<f64>() / 4.0).sqrt();
    let written = std::fs::read_to_string(&exercise).unwrap();
    let file: toml::Table = toml::from_str(&written).unwrap();
    let mark = file["pass"]["peak_force_n"]["at_most"].as_float().unwrap();
    assert!(
        (mark - (mean + sd)).abs() < 1e-5 * mark,
        "{mark} vs {mean} + {sd}"
    );
    assert_eq!(
        file["pass"]["peak_force_n"]["experts"]["recordings"].as_integer(),
        Some(5)
    );
    assert!(file["pass"]["hold_s"]["at_least"].as_float().is_some());
    // The file's comments and other lines are kept.
    assert!(written.starts_with("# Press the liver"), "{written}");
    assert!(written.contains("target_force_n = 1.0"));

    // A trainee who presses as the experts do passes every mark; one who presses 7 mm (1.2 N,
    // still in the window) completes the task but misses the experts' peak force.
    let like = d.join("trainee-like.mcap");
    record(&scene, press(&scene, 0.006, 3.0), &like);
    let out = score(&like, &exercise);
    assert!(out.contains("— passed"), "{out}");
    let harder = d.join("trainee-harder.mcap");
    record(&scene, press(&scene, 0.007, 3.0), &harder);
    let out = score(&harder, &exercise);
    assert!(out.contains("— not passed (completed, safe"), "{out}");
    assert!(out.contains("mark peak_force_n"), "{out}");
    assert!(
        out.lines()
            .any(|l| l.contains("mark peak_force_n") && l.ends_with("MISSED")),
        "{out}"
    );
}

#[test]
fn results_are_a_csv_row_per_attempt_and_a_report_with_a_plot_per_metric() {
    let d = dir("results");
    let scene = scene();
    let exercise = repo("exercises/press-hold.toml");
    let attempts: Vec<PathBuf> = [0.009, 0.0075, 0.006]
        .iter()
        .enumerate()
        .map(|(i, depth)| {
            let path = d.join(format!("attempt-{i}.mcap"));
            record(&scene, press(&scene, *depth, 3.0), &path);
            path
        })
        .collect();
    let (csv_path, html_path) = (d.join("results.csv"), d.join("results.html"));
    let mut args: Vec<&std::ffi::OsStr> = vec!["results".as_ref()];
    args.extend(attempts.iter().map(|p| p.as_os_str()));
    args.extend([
        "--exercise".as_ref(),
        exercise.as_os_str(),
        "--trainee".as_ref(),
        "ana".as_ref(),
        "--csv".as_ref(),
        csv_path.as_os_str(),
        "--html".as_ref(),
        html_path.as_os_str(),
    ]);
    ok(&softhaptic(&args));
    // Kept unless --replace.
    let again = softhaptic(&args);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("results --replace"));

    let mut reader = csv::Reader::from_path(&csv_path).unwrap();
    let header = reader.headers().unwrap().clone();
    for column in ["trainee", "attempt", "passed", "hold_s", "peak_force_n"] {
        assert!(header.iter().any(|h| h == column), "{header:?}");
    }
    let rows: Vec<csv::StringRecord> = reader.records().map(Result::unwrap).collect();
    assert_eq!(rows.len(), 3);
    let column = |name: &str| header.iter().position(|h| h == name).unwrap();
    let attempts_seen: Vec<&str> = rows.iter().map(|r| &r[column("attempt")]).collect();
    assert_eq!(attempts_seen, ["1", "2", "3"]);
    assert!(rows.iter().all(|r| &r[column("trainee")] == "ana"));
    // The hardest press misses the window; the last one, as the experts press, passes.
    assert_eq!(&rows[0][column("passed")], "false");
    assert_eq!(&rows[2][column("passed")], "true");
    // The same numbers as `exercise score` prints.
    let scored = score(&attempts[2], &exercise);
    let peak: f64 = rows[2][column("peak_force_n")].parse().unwrap();
    assert!((peak - metric(&scored, "peak_force_n")).abs() < 1e-6);

    let html = std::fs::read_to_string(&html_path).unwrap();
    assert_eq!(
        html.matches("<figure class=\"plot\"").count(),
        5,
        "a plot per metric"
    );
    assert_eq!(html.matches("<svg").count(), 5);
}

/// `run --exercises` refuses, before anything starts, what would lose results or score the
/// wrong scene: no recording, no trainee, an exercise set in another scene.
#[test]
fn a_station_refuses_exercises_it_cannot_record_or_that_are_for_another_scene() {
    let os = |s: &str| std::ffi::OsString::from(s);
    let press = repo("exercises/press-hold.toml");
    let base = [
        os("run"),
        os("--addr"),
        os("127.0.0.1:0"),
        os("--no-realtime"),
        os("--exercises"),
        press.clone().into_os_string(),
    ];
    let default = repo("scenes/default.toml");
    let default = default.to_str().unwrap();
    let refused = |extra: &[&str]| {
        let mut args: Vec<std::ffi::OsString> = base.to_vec();
        args.extend(extra.iter().map(|s| os(s)));
        let refs: Vec<&std::ffi::OsStr> = args.iter().map(|a| a.as_os_str()).collect();
        let out = softhaptic(&refs);
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let e = refused(&["--trainee", "ana", "--no-record", "--scene", default]);
    assert!(e.contains("--exercises with --no-record"), "{e}");
    let e = refused(&["--scene", default]);
    assert!(e.contains("--trainee"), "{e}");
    let cone = repo("scenes/cone.toml");
    let e = refused(&["--trainee", "ana", "--scene", cone.to_str().unwrap()]);
    assert!(
        e.contains("press-hold.toml: scene: set in ") && e.contains("but this station runs"),
        "{e}"
    );
    let e = refused(&["--trainee", " ", "--scene", default]);
    assert!(e.contains("--trainee: \"\""), "{e}");
}

/// A press `depth_m` deep at `surface_world_m` (its normal +y), the button held through the hold.
fn marking_press(surface_world_m: DVec3, depth_m: f64) -> HandScript {
    let mut s = HandScript::press(surface_world_m, DVec3::Y, depth_m);
    s.hold_s = 1.0;
    s.slide_distance_m = 0.0;
    s.slide_s = 0.0;
    s.button_in_hold = true;
    s
}

#[test]
fn a_palpation_scores_the_lump_marked_the_one_missed_and_a_mark_over_nothing() {
    let d = dir("palpation");
    let scene_path = repo("scenes/palpation.toml");
    let scene = Scene::load(&scene_path).unwrap();
    let scene_toml = std::fs::read_to_string(&scene_path).unwrap();
    let exercise = repo("exercises/palpation.toml");
    // Over the first lump: the surface point it was placed under (its centre, `centre_depth_m`
    // up along +y, the top's normal there), the hand sent 7 mm in (the tip stops shallower), and marked.
    let lump = scene.inclusions[0];
    let centre = scene
        .object_in_world
        .transform_point(DVec3::from_array(lump.centre_in_object_m));
    let over_lump = centre + DVec3::Y * lump.centre_depth_m;
    let found = d.join("found.mcap");
    record_hand(
        &scene,
        &scene_toml,
        marking_press(over_lump, 0.007),
        "palpation-found",
        &found,
        |_| {},
    )
    .unwrap();
    let out = score(&found, &exercise);
    assert_eq!(metric(&out, "found"), 1.0, "{out}");
    assert_eq!(metric(&out, "missed"), 1.0, "{out}");
    assert_eq!(metric(&out, "false_marks"), 0.0, "{out}");
    // The tip stays within a millimetre of where it was sent, across the surface.
    assert!(metric(&out, "localisation_error_m") < 0.001, "{out}");
    assert!(metric(&out, "coverage") > 0.0, "{out}");
    // A lump missed: not completed, so not passed; and it ends by its time limit only.
    assert!(out.contains("— not passed (not completed, safe"), "{out}");

    // 30 mm away across the top, over neither lump: a false mark, both missed.
    let second = scene
        .object_in_world
        .transform_point(DVec3::from_array(scene.inclusions[1].centre_in_object_m));
    let mut away = over_lump + DVec3::X * 0.03;
    if (away - second).with_y(0.0).length() < 0.012 {
        away = over_lump - DVec3::Z * 0.03;
    }
    let wrong = d.join("wrong.mcap");
    record_hand(
        &scene,
        &scene_toml,
        marking_press(away, 0.007),
        "palpation-wrong",
        &wrong,
        |_| {},
    )
    .unwrap();
    let out = score(&wrong, &exercise);
    assert_eq!(metric(&out, "found"), 0.0, "{out}");
    assert_eq!(metric(&out, "missed"), 2.0, "{out}");
    assert_eq!(metric(&out, "false_marks"), 1.0, "{out}");
    // No lump found: the farthest a finding mark could be, 5 + 3 mm.
    assert!(
        (metric(&out, "localisation_error_m") - 0.008).abs() < 1e-9,
        "{out}"
    );
    let _ = std::fs::remove_dir_all(&d);
}
