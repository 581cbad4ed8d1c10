//! The exercise file (TOML) and its checks: from text to a [`LoadedExercise`] whose geometry is
//! in the world frame of its scene. Every value is checked, and a refused one names the file,
//! the field and the value.
//!
//! ```toml
//! name = "Press and hold 2 N"
//! instructions = "Press the marked site with 2 N and hold it for 3 s without passing 4 N."
//! kind = "press"                 # or "trace"
//! scene = "../scenes/default.toml"  # optional: the built-in default scene
//! time_limit_s = 20.0
//!
//! [press]
//! site_m = [0.0, 0.03, 0.0]      # object frame; optional: the scene's press site
//! normal = [0.0, 1.0, 0.0]       # optional: the press site's normal
//! site_radius_m = 0.005
//! target_force_n = 2.0
//! tolerance_n = 0.3
//! hold_s = 3.0
//! safe_force_n = 4.0             # optional: the scene's safe force
//!
//! [pass.hold_force_sd_n]
//! at_most = 0.15
//! ```

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::Deserialize;
use softhaptic_proto::exercise::{
    Better, Exercise, ExpertSpread, FollowTask, PalpationTarget, PalpationTask, PassMark,
    PressTask, Task, TraceTask,
};

use crate::files::FileKind;
use crate::scene::{Scene, SceneError};
use crate::toml_file::{self, TomlFileError};

/// Why an exercise file was refused. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum ExerciseError {
    /// Not read, not TOML of an exercise file, or a value refused.
    #[error(transparent)]
    File(#[from] TomlFileError),
    #[error("{path}: scene: {source}")]
    Scene {
        path: PathBuf,
        #[source]
        source: Box<SceneError>,
    },
}

/// Longest time limit an exercise may set: an hour.
const MAX_TIME_LIMIT_S: f64 = 3600.0;
/// Most points a traced path may have.
const MAX_PATH_POINTS: usize = 1000;
/// Largest force any exercise may name, N (above every desktop device's peak).
const MAX_FORCE_N: f64 = 100.0;
/// Largest distance any exercise may name, m (an object is a few tens of centimetres).
const MAX_DISTANCE_M: f64 = 1.0;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ExerciseFile {
    name: String,
    #[serde(default)]
    instructions: String,
    kind: String,
    scene: Option<PathBuf>,
    time_limit_s: f64,
    press: Option<PressSection>,
    trace: Option<TraceSection>,
    palpation: Option<PalpationSection>,
    follow: Option<FollowSection>,
    #[serde(default)]
    pass: BTreeMap<String, PassSection>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FollowSection {
    /// The expert's recording the station is guided by (`run --guide`), by file name.
    expert: String,
    safe_force_n: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PalpationSection {
    area_centre_m: Option<[f64; 3]>,
    normal: Option<[f64; 3]>,
    area_radius_m: f64,
    tolerance_m: f64,
    #[serde(default = "default_coverage_depth_m")]
    coverage_depth_m: f64,
    #[serde(default)]
    max_false_marks: u32,
    safe_force_n: Option<f64>,
}

fn default_coverage_depth_m() -> f64 {
    0.002
}

/// Most false marks a palpation may allow (a mark is a deliberate press of the button).
const MAX_FALSE_MARKS: u32 = 20;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PressSection {
    site_m: Option<[f64; 3]>,
    normal: Option<[f64; 3]>,
    site_radius_m: f64,
    target_force_n: f64,
    tolerance_n: f64,
    hold_s: f64,
    safe_force_n: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TraceSection {
    path_m: Vec<[f64; 3]>,
    normal: Option<[f64; 3]>,
    tolerance_m: f64,
    target_force_n: Option<f64>,
    #[serde(default)]
    force_tolerance_n: f64,
    #[serde(default = "default_min_coverage")]
    min_coverage: f64,
    safe_force_n: Option<f64>,
}

fn default_min_coverage() -> f64 {
    0.9
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PassSection {
    at_least: Option<f64>,
    at_most: Option<f64>,
    experts: Option<ExpertSpread>,
}

/// An exercise file, checked and placed in its scene.
#[derive(Debug, Clone)]
pub struct LoadedExercise {
    /// The file it came from.
    pub path: PathBuf,
    /// Its text, as recorded with each attempt.
    pub source_toml: String,
    /// The scene it names, resolved against the file's directory (`None`: the built-in default).
    pub scene_path: Option<PathBuf>,
    pub exercise: Exercise,
}

impl LoadedExercise {
    /// Reads, checks and places the exercise file at `path`, loading the scene it names.
    pub fn load(path: &Path) -> Result<Self, ExerciseError> {
        let text = toml_file::read(path, FileKind::Exercise)?;
        let file = parse(&text, path)?;
        let base = path.parent().unwrap_or(Path::new("."));
        let scene_path = file.scene.as_ref().map(|p| base.join(p));
        let scene = match &scene_path {
            Some(p) => Scene::load(p),
            None => Scene::builtin_default(),
        }
        .map_err(|e| ExerciseError::Scene {
            path: path.to_owned(),
            source: Box::new(e),
        })?;
        let exercise = check(file, path, &scene)?;
        Ok(Self {
            path: path.to_owned(),
            source_toml: text,
            scene_path,
            exercise,
        })
    }

    /// Checks and places exercise text against an already loaded `scene` (the station's, or the
    /// one a recording carries); `path` names it in errors.
    pub fn from_toml(text: &str, path: &Path, scene: &Scene) -> Result<Self, ExerciseError> {
        let file = parse(text, path)?;
        let base = path.parent().unwrap_or(Path::new("."));
        let scene_path = file.scene.as_ref().map(|p| base.join(p));
        let exercise = check(file, path, scene)?;
        Ok(Self {
            path: path.to_owned(),
            source_toml: text.to_owned(),
            scene_path,
            exercise,
        })
    }
}

fn parse(text: &str, path: &Path) -> Result<ExerciseFile, ExerciseError> {
    Ok(toml_file::parse(text, path)?)
}

/// The checks of one file, with the error constructor that names it.
struct Checker<'a> {
    path: &'a Path,
}

impl Checker<'_> {
    fn refuse(&self, field: &str, reason: String) -> ExerciseError {
        TomlFileError::field(self.path, field, reason).into()
    }

    /// A finite value in `(low, high]` (or `[low, high]` when `low_inclusive`).
    fn range(
        &self,
        field: &str,
        value: f64,
        low: f64,
        high: f64,
        low_inclusive: bool,
    ) -> Result<f64, ExerciseError> {
        let above = if low_inclusive {
            value >= low
        } else {
            value > low
        };
        if value.is_finite() && above && value <= high {
            Ok(value)
        } else {
            let open = if low_inclusive { '[' } else { '(' };
            Err(self.refuse(
                field,
                format!("must be in {open}{low}, {high}], got {value}"),
            ))
        }
    }

    fn point(&self, field: &str, v: [f64; 3]) -> Result<DVec3, ExerciseError> {
        let p = DVec3::from_array(v);
        if p.is_finite() && p.length() <= MAX_DISTANCE_M {
            Ok(p)
        } else {
            Err(self.refuse(
                field,
                format!("must be a finite point within {MAX_DISTANCE_M} m of the object's origin, got {v:?}"),
            ))
        }
    }

    fn normal(&self, field: &str, v: [f64; 3]) -> Result<DVec3, ExerciseError> {
        match DVec3::from_array(v).try_normalize() {
            Some(n) => Ok(n),
            None => Err(self.refuse(
                field,
                format!("must be a finite non-zero direction, got {v:?}"),
            )),
        }
    }
}

fn check(file: ExerciseFile, path: &Path, scene: &Scene) -> Result<Exercise, ExerciseError> {
    let c = Checker { path };
    let name = file.name.trim();
    if name.is_empty() || name.chars().count() > 80 || name.chars().any(char::is_control) {
        return Err(c.refuse(
            "name",
            format!("must be 1 to 80 printable characters, got {:?}", file.name),
        ));
    }
    if file.instructions.chars().count() > 1000 {
        return Err(c.refuse(
            "instructions",
            format!(
                "must be at most 1000 characters, got {}",
                file.instructions.chars().count()
            ),
        ));
    }
    let time_limit_s = c.range(
        "time_limit_s",
        file.time_limit_s,
        0.0,
        MAX_TIME_LIMIT_S,
        false,
    )?;
    let to_world = |p: DVec3| scene.object_in_world.transform_point(p);
    let rotate = |n: DVec3| scene.object_in_world.orientation * n;
    let (site_in_object, site_normal) = scene.press_site_in_object;
    let safe = |field: &str, value: Option<f64>| match value {
        Some(v) => c.range(field, v, 0.0, MAX_FORCE_N, false),
        None => Ok(scene.safe_force_n),
    };
    // Each kind has its own section and no other's.
    for (section, present) in [
        ("press", file.press.is_some()),
        ("trace", file.trace.is_some()),
        ("palpation", file.palpation.is_some()),
        ("follow", file.follow.is_some()),
    ] {
        if present
            && section != file.kind
            && ["press", "trace", "palpation", "follow"].contains(&file.kind.as_str())
        {
            return Err(c.refuse(
                section,
                format!(
                    "a {kind} exercise has a [{kind}] section, not [{section}]",
                    kind = file.kind
                ),
            ));
        }
    }
    let task = match file.kind.as_str() {
        "press" => {
            let Some(p) = file.press else {
                return Err(c.refuse("press", "a press exercise needs its [press] section".into()));
            };
            let site = match p.site_m {
                Some(v) => c.point("press.site_m", v)?,
                None => site_in_object,
            };
            let normal = match p.normal {
                Some(v) => c.normal("press.normal", v)?,
                None => site_normal,
            };
            let safe_force_n = safe("press.safe_force_n", p.safe_force_n)?;
            let target = c.range(
                "press.target_force_n",
                p.target_force_n,
                0.0,
                MAX_FORCE_N,
                false,
            )?;
            let tolerance = c.range("press.tolerance_n", p.tolerance_n, 0.0, target, false)?;
            if target + tolerance > safe_force_n {
                return Err(c.refuse(
                    "press.target_force_n",
                    format!(
                        "the window's top, {target} + {tolerance} N, is above the safe force {safe_force_n} N: no hold could be safe"
                    ),
                ));
            }
            Task::Press(PressTask {
                site_m: to_world(site).to_array(),
                normal: rotate(normal).to_array(),
                site_radius_m: c.range(
                    "press.site_radius_m",
                    p.site_radius_m,
                    0.0,
                    MAX_DISTANCE_M,
                    false,
                )?,
                target_force_n: target,
                tolerance_n: tolerance,
                hold_s: c.range("press.hold_s", p.hold_s, 0.0, time_limit_s, false)?,
                safe_force_n,
            })
        }
        "trace" => {
            let Some(t) = file.trace else {
                return Err(c.refuse("trace", "a trace exercise needs its [trace] section".into()));
            };
            if !(2..=MAX_PATH_POINTS).contains(&t.path_m.len()) {
                return Err(c.refuse(
                    "trace.path_m",
                    format!(
                        "must have 2 to {MAX_PATH_POINTS} points, got {}",
                        t.path_m.len()
                    ),
                ));
            }
            let mut path_m = Vec::with_capacity(t.path_m.len());
            let mut length_m = 0.0;
            for (i, v) in t.path_m.iter().enumerate() {
                let p = c.point(&format!("trace.path_m[{i}]"), *v)?;
                if let Some(previous) = path_m.last() {
                    length_m += to_world(p).distance(*previous);
                }
                path_m.push(to_world(p));
            }
            if length_m < 0.001 {
                return Err(c.refuse(
                    "trace.path_m",
                    format!("must be at least 1 mm long, got {:.6} m", length_m),
                ));
            }
            let normal = match t.normal {
                Some(v) => c.normal("trace.normal", v)?,
                None => site_normal,
            };
            let safe_force_n = safe("trace.safe_force_n", t.safe_force_n)?;
            let target_force_n = match t.target_force_n {
                Some(v) => {
                    let target = c.range("trace.target_force_n", v, 0.0, safe_force_n, false)?;
                    c.range(
                        "trace.force_tolerance_n",
                        t.force_tolerance_n,
                        0.0,
                        target,
                        false,
                    )?;
                    Some(target)
                }
                None => None,
            };
            Task::Trace(TraceTask {
                path_m: path_m.iter().map(|p| p.to_array()).collect(),
                normal: rotate(normal).to_array(),
                tolerance_m: c.range(
                    "trace.tolerance_m",
                    t.tolerance_m,
                    0.0,
                    MAX_DISTANCE_M,
                    false,
                )?,
                target_force_n,
                force_tolerance_n: t.force_tolerance_n,
                min_coverage: c.range("trace.min_coverage", t.min_coverage, 0.0, 1.0, false)?,
                safe_force_n,
            })
        }
        "palpation" => {
            let Some(p) = file.palpation else {
                return Err(c.refuse(
                    "palpation",
                    "a palpation exercise needs its [palpation] section".into(),
                ));
            };
            if scene.inclusions.is_empty() {
                return Err(c.refuse(
                    "kind",
                    "a palpation exercise needs a scene with inclusions to find ([[inclusion]], as scenes/palpation.toml)".into(),
                ));
            }
            let centre = match p.area_centre_m {
                Some(v) => c.point("palpation.area_centre_m", v)?,
                None => site_in_object,
            };
            let normal = match p.normal {
                Some(v) => c.normal("palpation.normal", v)?,
                None => site_normal,
            };
            Task::Palpation(PalpationTask {
                area_centre_m: to_world(centre).to_array(),
                normal: rotate(normal).to_array(),
                area_radius_m: c.range(
                    "palpation.area_radius_m",
                    p.area_radius_m,
                    0.0,
                    MAX_DISTANCE_M,
                    false,
                )?,
                tolerance_m: c.range(
                    "palpation.tolerance_m",
                    p.tolerance_m,
                    0.0,
                    MAX_DISTANCE_M,
                    true,
                )?,
                coverage_depth_m: c.range(
                    "palpation.coverage_depth_m",
                    p.coverage_depth_m,
                    0.0,
                    MAX_DISTANCE_M,
                    false,
                )?,
                max_false_marks: if p.max_false_marks <= MAX_FALSE_MARKS {
                    p.max_false_marks
                } else {
                    return Err(c.refuse(
                        "palpation.max_false_marks",
                        format!(
                            "must be at most {MAX_FALSE_MARKS}, got {}",
                            p.max_false_marks
                        ),
                    ));
                },
                safe_force_n: safe("palpation.safe_force_n", p.safe_force_n)?,
                targets: scene
                    .inclusions
                    .iter()
                    .map(|i| PalpationTarget {
                        centre_m: to_world(DVec3::from_array(i.centre_in_object_m)).to_array(),
                        radius_m: i.radius_m,
                    })
                    .collect(),
            })
        }
        "follow" => {
            let Some(f) = file.follow else {
                return Err(c.refuse(
                    "follow",
                    "a follow exercise needs its [follow] section".into(),
                ));
            };
            // Placed in a scene without a guide (`exercise check`, or a recording made without
            // one) the task has no path to follow: a station refuses it (`station_exercises`),
            // and an attempt scored against it is never captured.
            let empty = Vec::new();
            let (points, forces) = match &scene.guide {
                Some(guide) if guide.recorded.source != f.expert => {
                    return Err(c.refuse(
                        "follow.expert",
                        format!(
                            "the scene is guided by {:?}, not {:?}",
                            guide.recorded.source, f.expert
                        ),
                    ));
                }
                Some(guide) => (&guide.recorded.points_m, guide.recorded.forces_n.as_deref()),
                None => (&empty, None),
            };
            Task::Follow(FollowTask {
                expert: f.expert,
                safe_force_n: safe("follow.safe_force_n", f.safe_force_n)?,
                expert_path: points
                    .iter()
                    .enumerate()
                    .map(|(i, p)| (*p, forces.and_then(|f| f.get(i)).copied().unwrap_or(0.0)))
                    .collect(),
            })
        }
        other => {
            return Err(c.refuse(
                "kind",
                format!("must be \"press\", \"trace\", \"palpation\" or \"follow\", got {other:?}"),
            ));
        }
    };
    let mut pass = Vec::with_capacity(file.pass.len());
    for (metric, mark) in file.pass {
        let field = format!("pass.{metric}");
        let Some(def) = task.metric(&metric) else {
            let known: Vec<_> = task.metrics().iter().map(|m| m.name).collect();
            return Err(c.refuse(
                &field,
                format!(
                    "a {} exercise has no metric {metric:?}; its metrics are {}",
                    task.kind(),
                    known.join(", ")
                ),
            ));
        };
        let (bound, expected) = match (def.better, mark.at_least, mark.at_most) {
            (Better::Higher, Some(b), None) => (b, "at_least"),
            (Better::Lower, None, Some(b)) => (b, "at_most"),
            _ => {
                let wanted = match def.better {
                    Better::Higher => "at_least (higher is better)",
                    Better::Lower => "at_most (lower is better)",
                };
                return Err(c.refuse(
                    &field,
                    format!("{metric} takes exactly one bound, {wanted}"),
                ));
            }
        };
        if !bound.is_finite() {
            return Err(c.refuse(
                &format!("{field}.{expected}"),
                format!("must be finite, got {bound}"),
            ));
        }
        pass.push(PassMark {
            metric,
            at_least: mark.at_least,
            at_most: mark.at_most,
            experts: mark.experts,
        });
    }
    Ok(Exercise {
        name: name.to_owned(),
        instructions: file.instructions.trim().to_owned(),
        time_limit_s,
        task,
        pass,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    fn load(text: &str) -> Result<Exercise, ExerciseError> {
        let scene = Scene::builtin_default().unwrap();
        LoadedExercise::from_toml(text, Path::new("exercises/x.toml"), &scene).map(|l| l.exercise)
    }

    const PRESS: &str = r#"
name = "Press"
kind = "press"
time_limit_s = 20
[press]
site_radius_m = 0.005
target_force_n = 1.5
tolerance_n = 0.3
hold_s = 3
[pass.hold_force_sd_n]
at_most = 0.2
"#;

    #[test]
    fn a_press_defaults_to_the_scene_s_site_and_safe_force_in_the_world_frame() {
        let scene = Scene::builtin_default().unwrap();
        let e = load(PRESS).unwrap();
        let Task::Press(p) = &e.task else {
            panic!("{e:?}")
        };
        let (site, _) = scene.press_site_in_object;
        let world = scene.object_in_world.transform_point(site);
        assert!((DVec3::from_array(p.site_m) - world).length() < 1e-12);
        assert_eq!(p.safe_force_n, scene.safe_force_n);
        assert_eq!(e.pass.len(), 1);
        assert_eq!(e.pass[0].at_most, Some(0.2));
    }

    #[test]
    fn a_bad_value_is_refused_naming_the_file_the_field_and_the_value() {
        let cases = [
            (
                PRESS.replace("time_limit_s = 20", "time_limit_s = -1"),
                "time_limit_s: must be in (0, 3600], got -1",
            ),
            (
                PRESS.replace("tolerance_n = 0.3", "tolerance_n = 3.0"),
                "press.tolerance_n: must be in (0, 1.5], got 3",
            ),
            (
                PRESS.replace("kind = \"press\"", "kind = \"poke\""),
                "kind: must be \"press\", \"trace\", \"palpation\" or \"follow\", got \"poke\"",
            ),
            (
                PRESS.replace("[pass.hold_force_sd_n]", "[pass.coverage]"),
                "pass.coverage: a press exercise has no metric \"coverage\"",
            ),
            (
                PRESS.replace("at_most = 0.2", "at_least = 0.2"),
                "pass.hold_force_sd_n: hold_force_sd_n takes exactly one bound, at_most",
            ),
            (
                PRESS.replace("hold_s = 3", "hold_s = 3\nsafe_force_n = 1.6"),
                "press.target_force_n: the window's top, 1.5 + 0.3 N, is above the safe force 1.6 N",
            ),
            (PRESS.replace("[press]", "[trace]"), "unknown field"),
        ];
        for (text, expected) in cases {
            let e = load(&text).unwrap_err().to_string();
            assert!(e.starts_with("exercises/x.toml: "), "{e}");
            assert!(e.contains(expected), "{e}\nexpected: {expected}");
        }
    }

    #[test]
    fn a_trace_path_is_placed_in_the_world_frame_and_checked() {
        let text = r#"
name = "Trace"
kind = "trace"
time_limit_s = 30
[trace]
path_m = [[0.0, 0.03, 0.0], [0.02, 0.03, 0.0]]
tolerance_m = 0.003
target_force_n = 1.5
force_tolerance_n = 0.3
"#;
        let scene = Scene::builtin_default().unwrap();
        let e = load(text).unwrap();
        let Task::Trace(t) = &e.task else {
            panic!("{e:?}")
        };
        let first = scene
            .object_in_world
            .transform_point(DVec3::new(0.0, 0.03, 0.0));
        assert!((DVec3::from_array(t.path_m[0]) - first).length() < 1e-12);
        assert_eq!(t.min_coverage, 0.9);
        let one_point = text.replace(", [0.02, 0.03, 0.0]", "");
        assert!(
            load(&one_point)
                .unwrap_err()
                .to_string()
                .contains("trace.path_m: must have 2 to 1000 points, got 1")
        );
        let far = text.replace("[0.02, 0.03, 0.0]", "[5.0, 0.0, 0.0]");
        assert!(
            load(&far)
                .unwrap_err()
                .to_string()
                .contains("trace.path_m[1]: must be a finite point within 1 m")
        );
    }
}
