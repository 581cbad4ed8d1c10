//! The exercise commands: `exercise check`, `exercise score`, `benchmark` and `results`.
//!
//! A recording is scored as one attempt from its first tick (`score::score_ticks`), with the
//! exercise placed in the recording's own scene, so a scene moved since does not move the site.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use softhaptic_proto::exercise::{AttemptResult, Better, Exercise, ExpertSpread, MetricDef};

use super::file::LoadedExercise;
use super::score::score_ticks;
use crate::files::{self, FileKind};
use crate::session::check::recorded_scene;
use crate::session::cli::print_report;
use crate::session::reader::Recording;

/// Fewest experts' recordings a benchmark is made from: fewer give a spread that means nothing.
pub const MIN_EXPERT_RECORDINGS: usize = 5;

/// `softhaptic exercise …`
#[derive(clap::Subcommand, Debug, Clone)]
pub enum ExerciseCommand {
    /// Check exercise files: each is read, checked and placed in its scene, and summarised (its
    /// task, time limit and pass marks). Exits non-zero on the first refused file, naming the
    /// field and the value.
    Check {
        /// Exercise files (.toml).
        #[arg(required = true)]
        files: Vec<PathBuf>,
    },
    /// Score recordings as attempts at an exercise: each from its first tick until the goal is
    /// reached or the time limit has passed; prints every metric and whether it passed.
    Score {
        /// Recordings (.mcap).
        #[arg(required = true)]
        recordings: Vec<PathBuf>,
        /// The exercise file (.toml).
        #[arg(long, value_name = "FILE")]
        exercise: PathBuf,
    },
}

/// `softhaptic benchmark …`
#[derive(clap::Args, Debug, Clone)]
pub struct BenchmarkArgs {
    /// Experts' recordings of the exercise (.mcap), at least five.
    #[arg(required = true, value_name = "EXPERT_RECORDINGS")]
    pub recordings: Vec<PathBuf>,
    /// The exercise file (.toml) whose pass marks the experts set.
    #[arg(long, value_name = "FILE")]
    pub exercise: PathBuf,
    /// Write the pass marks into the exercise file (its other lines and comments are kept);
    /// without it they are printed as TOML to paste.
    #[arg(long)]
    pub write: bool,
}

/// `softhaptic results …`
#[derive(clap::Args, Debug, Clone)]
pub struct ResultsArgs {
    /// Recordings (.mcap), in the order they were made: of stations that ran exercises (their
    /// recorded attempts are gathered), or, with --exercise, each scored as one attempt.
    #[arg(required = true)]
    pub recordings: Vec<PathBuf>,
    /// Score each recording as one attempt at this exercise file (.toml) [default: the
    /// attempts the recordings hold, at every exercise they ran].
    #[arg(long, value_name = "FILE")]
    pub exercise: Option<PathBuf>,
    /// With --exercise: the trainee of every recording [default: each recording's file name].
    /// Without: only this trainee's attempts [default: everyone's].
    #[arg(long, value_name = "NAME")]
    pub trainee: Option<String>,
    /// Write one row per attempt here (CSV).
    #[arg(long, value_name = "FILE")]
    pub csv: PathBuf,
    /// Also write an HTML report: the attempts and a plot per metric against its pass mark.
    #[arg(long, value_name = "FILE")]
    pub html: Option<PathBuf>,
    /// Write over the CSV and HTML files if they exist (without it they are kept).
    #[arg(long)]
    pub replace: bool,
}

pub fn run_exercise(command: ExerciseCommand) -> anyhow::Result<()> {
    match command {
        ExerciseCommand::Check { files } => {
            for path in files {
                let loaded = LoadedExercise::load(&path)?;
                print_report(format_args!("{}", summary(&loaded)))?;
            }
            Ok(())
        }
        ExerciseCommand::Score {
            recordings,
            exercise,
        } => {
            for path in recordings {
                let (_, result) = score_recording(&path, &exercise, None)?;
                print_report(format_args!("{}\n", describe(&path, &result)))?;
            }
            Ok(())
        }
    }
}

/// The lines `exercise check` prints for one file.
fn summary(loaded: &LoadedExercise) -> String {
    let e = &loaded.exercise;
    let mut out = format!(
        "{}: {} ({}, {} s)\n",
        loaded.path.display(),
        e.name,
        e.task.kind(),
        e.time_limit_s
    );
    if !e.instructions.is_empty() {
        let _ = writeln!(out, "  {}", e.instructions);
    }
    let mm = |p: [f64; 3]| {
        format!(
            "[{:.1}, {:.1}, {:.1}] mm",
            p[0] * 1e3,
            p[1] * 1e3,
            p[2] * 1e3
        )
    };
    match &e.task {
        softhaptic_proto::exercise::Task::Press(p) => {
            let _ = writeln!(
                out,
                "  press {} ± {} N for {} s within {} mm of {} (world), safe force {} N",
                p.target_force_n,
                p.tolerance_n,
                p.hold_s,
                p.site_radius_m * 1e3,
                mm(p.site_m),
                p.safe_force_n
            );
        }
        softhaptic_proto::exercise::Task::Palpation(_) => {}
        softhaptic_proto::exercise::Task::Follow(f) => {
            let points = if f.expert_path.is_empty() {
                "the path comes from the station's --guide".to_owned()
            } else {
                format!("{} points", f.expert_path.len())
            };
            let _ = writeln!(
                out,
                "  follow the path of {} once, guided ({points}), to its end and away; safe force {} N",
                f.expert, f.safe_force_n
            );
        }
        softhaptic_proto::exercise::Task::Trace(t) => {
            let _ = writeln!(
                out,
                "  trace {} points from {} to {} (world) within {} mm, {} % of it, safe force {} N",
                t.path_m.len(),
                mm(t.path_m[0]),
                mm(t.path_m[t.path_m.len() - 1]),
                t.tolerance_m * 1e3,
                t.min_coverage * 100.0,
                t.safe_force_n
            );
        }
    }
    if let softhaptic_proto::exercise::Task::Palpation(p) = &e.task {
        let _ = writeln!(
            out,
            "  palpate {} mm around {} (world) for {} inclusions, marking each within its radius + {} mm; \
             searched once {} mm deep; at most {} false marks; safe force {} N",
            p.area_radius_m * 1e3,
            mm(p.area_centre_m),
            p.targets.len(),
            p.tolerance_m * 1e3,
            p.coverage_depth_m * 1e3,
            p.max_false_marks,
            p.safe_force_n
        );
    }
    if e.pass.is_empty() {
        out.push_str("  pass marks: none (complete the task without passing the safe force)\n");
    }
    for mark in &e.pass {
        let bound = match (mark.at_least, mark.at_most) {
            (Some(b), _) => format!("≥ {b}"),
            (_, Some(b)) => format!("≤ {b}"),
            _ => String::new(),
        };
        let unit = e.task.metric(&mark.metric).map_or("", |m| m.unit);
        let _ = write!(out, "  pass mark: {} {bound} {unit}", mark.metric);
        if let Some(x) = mark.experts {
            let _ = write!(
                out,
                " (experts: {} recordings, mean {:.4}, sd {:.4})",
                x.recordings, x.mean, x.sd
            );
        }
        out.push('\n');
    }
    out
}

/// Scores the recording at `path` against the exercise file at `exercise`, placed in the
/// recording's scene.
fn score_recording(
    path: &Path,
    exercise: &Path,
    trainee: Option<&str>,
) -> anyhow::Result<(Exercise, AttemptResult)> {
    let recording = Recording::open(path)?;
    let scene =
        recorded_scene(&recording).with_context(|| format!("{}: its scene", path.display()))?;
    let text = files::read_text(exercise, FileKind::Exercise)
        .map_err(|e| anyhow::anyhow!("{}: {e}", exercise.display()))?;
    let loaded = LoadedExercise::from_toml(&text, exercise, &scene)?;
    let trainee = trainee.map_or_else(
        || {
            path.file_stem()
                .map_or_else(String::new, |s| s.to_string_lossy().into_owned())
        },
        str::to_owned,
    );
    let result = score_ticks(&loaded.exercise, &recording.device, &trainee);
    Ok((loaded.exercise, result))
}

fn describe(path: &Path, r: &AttemptResult) -> String {
    let mut out = format!(
        "{}: {} — {} ({}{}, ended: {:?}, {:.3} s)\n",
        path.display(),
        r.exercise,
        if r.passed { "passed" } else { "not passed" },
        if r.score.completed {
            "completed"
        } else {
            "not completed"
        },
        if r.score.safe { ", safe" } else { ", UNSAFE" },
        r.ended,
        (r.end_ns.saturating_sub(r.start_ns)) as f64 * 1e-9
    );
    for (name, value) in &r.score.metrics {
        let _ = writeln!(out, "  {name:<20} {value:.6}");
    }
    for m in &r.marks {
        let _ = writeln!(
            out,
            "  mark {:<15} {:.6} {}",
            m.mark.metric,
            m.value,
            if m.met { "met" } else { "MISSED" }
        );
    }
    out
}

/// The experts' spread on one metric, and the pass mark it gives: the mean, loosened by one
/// standard deviation toward the worse side (proficiency-based progression: a trainee passes at
/// the experts' level, not at the best expert's).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Benchmark {
    pub metric: &'static MetricDef,
    pub spread: ExpertSpread,
    pub mark: f64,
}

/// The pass marks `results` of experts' attempts give, one per metric of the kind. Refused when
/// fewer than [`MIN_EXPERT_RECORDINGS`] attempts, or one that did not complete the task safely
/// (an expert who failed it is no benchmark).
pub fn benchmark(
    exercise: &Exercise,
    results: &[(PathBuf, AttemptResult)],
) -> anyhow::Result<Vec<Benchmark>> {
    if results.len() < MIN_EXPERT_RECORDINGS {
        bail!(
            "a benchmark needs at least {MIN_EXPERT_RECORDINGS} experts' recordings, got {}",
            results.len()
        );
    }
    for (path, r) in results {
        if !(r.score.completed && r.score.safe) {
            bail!(
                "{}: the expert did not complete the exercise safely (completed: {}, safe: {}): not a benchmark",
                path.display(),
                r.score.completed,
                r.score.safe
            );
        }
    }
    let mut out = Vec::new();
    for def in exercise.task.metrics() {
        let values: Vec<f64> = results
            .iter()
            .filter_map(|(_, r)| r.score.metrics.get(def.name).copied())
            .filter(|v| v.is_finite())
            .collect();
        if values.len() < MIN_EXPERT_RECORDINGS {
            continue;
        }
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let sd = (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        let spread = ExpertSpread {
            recordings: values.len() as u32,
            mean,
            sd,
            min: values.iter().copied().fold(f64::INFINITY, f64::min),
            max: values.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        };
        let mark = match def.better {
            Better::Higher => mean - sd,
            Better::Lower => mean + sd,
        };
        out.push(Benchmark {
            metric: def,
            spread,
            mark,
        });
    }
    Ok(out)
}

/// Writes `marks` as the `[pass.*]` tables of the exercise text, keeping its other lines and
/// comments; the existing pass marks are replaced.
pub fn with_pass_marks(text: &str, marks: &[Benchmark]) -> anyhow::Result<String> {
    let mut doc: toml_edit::DocumentMut = text.parse().context("the exercise file")?;
    let mut pass = toml_edit::Table::new();
    pass.set_implicit(true);
    for b in marks {
        let mut t = toml_edit::Table::new();
        let key = match b.metric.better {
            Better::Higher => "at_least",
            Better::Lower => "at_most",
        };
        t.insert(key, toml_edit::value(round(b.mark)));
        let mut experts = toml_edit::InlineTable::new();
        experts.insert("recordings", i64::from(b.spread.recordings).into());
        for (k, v) in [
            ("mean", b.spread.mean),
            ("sd", b.spread.sd),
            ("min", b.spread.min),
            ("max", b.spread.max),
        ] {
            experts.insert(k, round(v).into());
        }
        t.insert("experts", toml_edit::value(experts));
        pass.insert(b.metric.name, toml_edit::Item::Table(t));
    }
    doc.insert("pass", toml_edit::Item::Table(pass));
    Ok(doc.to_string())
}

/// Six significant digits: a benchmark is no more precise, and the file stays readable.
fn round(v: f64) -> f64 {
    if v == 0.0 || !v.is_finite() {
        return v;
    }
    let digits = 6 - (v.abs().log10().floor() as i32 + 1);
    let scale = 10f64.powi(digits);
    (v * scale).round() / scale
}

pub fn run_benchmark(args: BenchmarkArgs) -> anyhow::Result<()> {
    let mut results = Vec::new();
    let mut exercise = None;
    for path in &args.recordings {
        let (e, r) = score_recording(path, &args.exercise, None)?;
        exercise.get_or_insert(e);
        results.push((path.clone(), r));
    }
    let Some(exercise) = exercise else {
        bail!("no recordings given");
    };
    let marks = benchmark(&exercise, &results)?;
    let mut table = format!(
        "{}: {} experts' recordings\n{:<18} {:>5} {:>7} {:>12} {:>12} {:>12} {:>12}   pass mark\n",
        exercise.name,
        results.len(),
        "metric",
        "unit",
        "better",
        "mean",
        "sd",
        "min",
        "max"
    );
    for b in &marks {
        let (better, sign) = match b.metric.better {
            Better::Higher => ("higher", "≥"),
            Better::Lower => ("lower", "≤"),
        };
        let _ = writeln!(
            table,
            "{:<18} {:>5} {:>7} {:>12.6} {:>12.6} {:>12.6} {:>12.6}   {sign} {:.6}",
            b.metric.name,
            b.metric.unit,
            better,
            b.spread.mean,
            b.spread.sd,
            b.spread.min,
            b.spread.max,
            b.mark
        );
    }
    print_report(format_args!("{table}"))?;
    let text = files::read_text(&args.exercise, FileKind::Exercise)
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.exercise.display()))?;
    let updated = with_pass_marks(&text, &marks)?;
    if args.write {
        // Written beside, then renamed over: a failed write leaves the file as it was.
        let tmp = args.exercise.with_extension("toml.tmp");
        std::fs::write(&tmp, &updated).with_context(|| format!("writing {}", tmp.display()))?;
        std::fs::rename(&tmp, &args.exercise)
            .with_context(|| format!("replacing {}", args.exercise.display()))?;
        println!("wrote the pass marks into {}", args.exercise.display());
    } else {
        let pass_start = updated.find("[pass").unwrap_or(0);
        print_report(format_args!(
            "\n# the pass marks, to paste (or run again with --write):\n{}",
            &updated[pass_start..]
        ))?;
    }
    Ok(())
}

pub fn run_results(args: ResultsArgs) -> anyhow::Result<()> {
    for out in std::iter::once(&args.csv).chain(args.html.as_ref()) {
        if !args.replace && out.exists() {
            bail!(
                "{} exists already and is kept (results --replace writes over it)",
                out.display()
            );
        }
    }
    let mut groups: Vec<(Exercise, Vec<(PathBuf, AttemptResult)>)> = Vec::new();
    let mut add = |exercise: Exercise, path: &Path, result: AttemptResult| match groups
        .iter_mut()
        .find(|(e, _)| e.name == exercise.name)
    {
        Some((_, rows)) => rows.push((path.to_path_buf(), result)),
        None => groups.push((exercise, vec![(path.to_path_buf(), result)])),
    };
    for path in &args.recordings {
        match &args.exercise {
            Some(file) => {
                let (e, r) = score_recording(path, file, args.trainee.as_deref())?;
                add(e, path, r);
            }
            None => {
                let recording = Recording::open(path)?;
                let mut found = 0;
                for m in &recording.exercises {
                    let Some(r) = &m.result else { continue };
                    if args.trainee.as_ref().is_some_and(|t| *t != r.trainee) {
                        continue;
                    }
                    add(m.exercise.clone(), path, r.clone());
                    found += 1;
                }
                if found == 0 {
                    eprintln!(
                        "{}: no attempts at exercises{} (score it as one with --exercise FILE)",
                        path.display(),
                        args.trainee
                            .as_ref()
                            .map_or_else(String::new, |t| format!(" by {t}"))
                    );
                }
            }
        }
    }
    if groups.is_empty() {
        bail!("no attempts in the recordings given");
    }
    // Attempts are numbered per trainee and exercise, in the order given.
    let mut seen: std::collections::HashMap<(String, String), u32> =
        std::collections::HashMap::new();
    let mut total = 0;
    for (e, rows) in &mut groups {
        for (_, r) in rows.iter_mut() {
            let n = seen.entry((r.trainee.clone(), e.name.clone())).or_insert(0);
            *n += 1;
            r.attempt = *n;
            total += 1;
        }
    }
    let csv = results_csv(&groups)?;
    std::fs::write(&args.csv, csv).with_context(|| format!("writing {}", args.csv.display()))?;
    println!(
        "wrote {} ({total} attempts at {} exercises)",
        args.csv.display(),
        groups.len()
    );
    if let Some(html) = &args.html {
        std::fs::write(html, results_html(&groups)?)
            .with_context(|| format!("writing {}", html.display()))?;
        println!("wrote {}", html.display());
    }
    Ok(())
}

/// One row per attempt: who, which, whether it passed, then every metric of the exercises'
/// kinds and, for each pass mark, whether it was met (empty where an exercise has no such
/// metric or mark). Columns described once, here.
pub fn results_csv(groups: &[(Exercise, Vec<(PathBuf, AttemptResult)>)]) -> anyhow::Result<String> {
    let mut metrics: Vec<&str> = Vec::new();
    let mut marks: Vec<&str> = Vec::new();
    for (e, _) in groups {
        for m in e.task.metrics() {
            if !metrics.contains(&m.name) {
                metrics.push(m.name);
            }
        }
        for p in &e.pass {
            if !marks.contains(&p.metric.as_str()) {
                marks.push(&p.metric);
            }
        }
    }
    let mut w = csv::Writer::from_writer(Vec::new());
    let mut header: Vec<String> = [
        "recording",
        "trainee",
        "exercise",
        "attempt",
        "passed",
        "completed",
        "safe",
        "ended",
        "duration_s",
    ]
    .map(str::to_owned)
    .into();
    header.extend(metrics.iter().map(|m| (*m).to_owned()));
    header.extend(marks.iter().map(|m| format!("{m}_met")));
    w.write_record(&header)?;
    for (path, r) in groups.iter().flat_map(|(_, rows)| rows) {
        let mut record = vec![
            path.display().to_string(),
            r.trainee.clone(),
            r.exercise.clone(),
            r.attempt.to_string(),
            r.passed.to_string(),
            r.score.completed.to_string(),
            r.score.safe.to_string(),
            serde_json::to_value(r.ended)?
                .as_str()
                .unwrap_or_default()
                .to_owned(),
            format!("{:.3}", (r.end_ns.saturating_sub(r.start_ns)) as f64 * 1e-9),
        ];
        record.extend(metrics.iter().map(|m| {
            r.score
                .metrics
                .get(*m)
                .map_or_else(String::new, |v| v.to_string())
        }));
        record.extend(marks.iter().map(|name| {
            r.marks
                .iter()
                .find(|o| o.mark.metric == *name)
                .map_or_else(String::new, |o| o.met.to_string())
        }));
        w.write_record(&record)?;
    }
    Ok(String::from_utf8(w.into_inner()?)?)
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A self-contained page: for each exercise, the attempts as a table, then one SVG plot per
/// metric (each trainee's attempts in order, the pass mark as a line).
pub fn results_html(
    groups: &[(Exercise, Vec<(PathBuf, AttemptResult)>)],
) -> anyhow::Result<String> {
    let title = groups
        .iter()
        .map(|(e, _)| escape(&e.name))
        .collect::<Vec<_>>()
        .join(", ");
    let mut page = format!(
        "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{title}: results</title>\n\
         <style>body{{font-family:sans-serif;margin:2em}}table{{border-collapse:collapse}}\
         td,th{{border:1px solid #ccc;padding:2px 6px}}.fail{{color:#b00}}.pass{{color:#070}}</style>\n\
         </head><body>\n"
    );
    for (exercise, rows) in groups {
        page.push_str(&exercise_section(exercise, rows)?);
    }
    page.push_str("</body></html>\n");
    Ok(page)
}

/// One exercise's part of the results page.
fn exercise_section(
    exercise: &Exercise,
    rows: &[(PathBuf, AttemptResult)],
) -> anyhow::Result<String> {
    let mut page = format!(
        "<section class=\"exercise\">\n<h1>{name}</h1>\n<p>{n} attempts. {instructions}</p>\n<table>\n\
         <tr><th>trainee</th><th>attempt</th><th>result</th><th>ended</th>",
        name = escape(&exercise.name),
        n = rows.len(),
        instructions = escape(&exercise.instructions),
    );
    let metrics = exercise.task.metrics();
    for m in metrics {
        let _ = write!(page, "<th>{} ({})</th>", m.name, m.unit);
    }
    page.push_str("</tr>\n");
    for (_, r) in rows {
        let _ = write!(
            page,
            "<tr><td>{}</td><td>{}</td><td class=\"{}\">{}</td><td>{:?}</td>",
            escape(&r.trainee),
            r.attempt,
            if r.passed { "pass" } else { "fail" },
            if r.passed { "passed" } else { "not passed" },
            r.ended
        );
        for m in metrics {
            let v = r
                .score
                .metrics
                .get(m.name)
                .map_or_else(String::new, |v| format!("{v:.4}"));
            let _ = write!(page, "<td>{v}</td>");
        }
        page.push_str("</tr>\n");
    }
    page.push_str("</table>\n");
    for m in metrics {
        let mark = exercise
            .pass
            .iter()
            .find(|p| p.metric == m.name)
            .and_then(|p| p.at_least.or(p.at_most));
        let _ = write!(
            page,
            "<h2>{} ({})</h2>\n<p>{}</p>\n<figure class=\"plot\" data-metric=\"{}\">{}</figure>\n",
            m.name,
            m.unit,
            escape(m.what),
            m.name,
            plot(m, mark, rows)?
        );
    }
    page.push_str("</section>\n");
    Ok(page)
}

/// One metric over the attempts: a line per trainee, the pass mark dashed.
fn plot(
    metric: &MetricDef,
    mark: Option<f64>,
    rows: &[(PathBuf, AttemptResult)],
) -> anyhow::Result<String> {
    use plotters::prelude::*;
    let mut trainees: Vec<&str> = Vec::new();
    for (_, r) in rows {
        if !trainees.contains(&r.trainee.as_str()) {
            trainees.push(&r.trainee);
        }
    }
    let values: Vec<f64> = rows
        .iter()
        .filter_map(|(_, r)| r.score.metrics.get(metric.name).copied())
        .chain(mark)
        .filter(|v| v.is_finite())
        .collect();
    let low = values
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min)
        .min(0.0);
    let mut high = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    // No values, or all equal: a unit span, so the axis still draws.
    if high.partial_cmp(&low) != Some(std::cmp::Ordering::Greater) {
        high = low + 1.0;
    }
    let attempts = rows
        .iter()
        .map(|(_, r)| r.attempt)
        .max()
        .unwrap_or(1)
        .max(2);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (640, 300)).into_drawing_area();
        root.fill(&WHITE)
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        let mut chart = ChartBuilder::on(&root)
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(60)
            .build_cartesian_2d(1f64..f64::from(attempts), low..high + 0.05 * (high - low))
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        chart
            .configure_mesh()
            .x_desc("attempt")
            .y_desc(format!("{} ({})", metric.name, metric.unit))
            .draw()
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        for (i, trainee) in trainees.iter().enumerate() {
            let colour = Palette99::pick(i).to_rgba();
            let points: Vec<(f64, f64)> = rows
                .iter()
                .filter(|(_, r)| r.trainee == *trainee)
                .filter_map(|(_, r)| {
                    r.score
                        .metrics
                        .get(metric.name)
                        .map(|v| (f64::from(r.attempt), *v))
                })
                .collect();
            chart
                .draw_series(LineSeries::new(points.clone(), colour.stroke_width(2)))
                .map_err(|e| anyhow::anyhow!("plot: {e}"))?
                .label(*trainee)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour));
            chart
                .draw_series(
                    points
                        .into_iter()
                        .map(|p| Circle::new(p, 3, colour.filled())),
                )
                .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        }
        if let Some(m) = mark {
            chart
                .draw_series(DashedLineSeries::new(
                    vec![(1.0, m), (f64::from(attempts), m)],
                    6,
                    4,
                    RED.stroke_width(1),
                ))
                .map_err(|e| anyhow::anyhow!("plot: {e}"))?
                .label("pass mark")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], RED));
        }
        chart
            .configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE.mix(0.8))
            .draw()
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        root.present().map_err(|e| anyhow::anyhow!("plot: {e}"))?;
    }
    Ok(svg)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn rounding_keeps_six_significant_digits() {
        assert_eq!(round(1.234_567_89), 1.234_57);
        assert_eq!(round(0.000_123_456_78), 0.000_123_457);
        assert_eq!(round(0.0), 0.0);
    }
}
