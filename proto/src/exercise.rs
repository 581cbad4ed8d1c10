//! Exercises: a task with a goal, a time limit and pass marks, scored from the 1 kHz ticks.
//!
//! Four kinds: press a site to a force window and hold it, trace a path, palpate (find the
//! scene's hidden inclusions and mark them), and follow an expert's path, guided. An exercise file (`exercises/*.toml`, loaded and
//! validated by the server) becomes an
//! [`Exercise`]: its geometry in the world frame, ready for the scorer
//! (`softhaptic_device::exercise`). Each [`Task`] kind names its metrics once
//! ([`Task::metrics`]), with the direction that is better: the pass marks, the benchmark that
//! sets them from experts' recordings and the results report all read that one list.
//!
//! A score is a set of named metrics in SI units ([`Score`]); an attempt's [`AttemptResult`]
//! adds the pass marks it was held to and whether each was met. Both travel in recordings and on
//! the wire as JSON.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// One exercise, as the scorer and the viewer use it (world frame, SI units).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Exercise {
    /// Short name shown to the trainee and in the results.
    pub name: String,
    /// What the trainee is asked to do, in a sentence or two.
    pub instructions: String,
    /// The attempt ends after this long at the latest.
    pub time_limit_s: f64,
    pub task: Task,
    /// The marks an attempt must meet, besides completing the task safely.
    #[serde(default)]
    pub pass: Vec<PassMark>,
}

/// What the trainee must do.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Task {
    Press(PressTask),
    Trace(TraceTask),
    Palpation(PalpationTask),
    Follow(FollowTask),
}

/// Reach a force window at a marked site and hold it, without exceeding a safe force.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PressTask {
    /// The site on the surface, world frame.
    pub site_m: [f64; 3],
    /// The surface's outward normal there, world frame (unit).
    pub normal: [f64; 3],
    /// The tool counts as at the site within this distance of it along the surface.
    pub site_radius_m: f64,
    pub target_force_n: f64,
    /// The window is target ± tolerance.
    pub tolerance_n: f64,
    /// How long the force must stay in the window, continuously, at the site.
    pub hold_s: f64,
    pub safe_force_n: f64,
}

/// Follow a path drawn on the surface, optionally at a steady force.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TraceTask {
    /// The path's points, world frame, in order (a polyline on the surface).
    pub path_m: Vec<[f64; 3]>,
    /// The surface's outward normal along the path, world frame (unit): deviations are measured
    /// across the path in the surface, not in depth.
    pub normal: [f64; 3],
    /// A tick in contact within this distance of the path is on it.
    pub tolerance_m: f64,
    /// The force to keep while tracing, if the exercise asks for one.
    #[serde(default)]
    pub target_force_n: Option<f64>,
    /// The force window is target ± this.
    #[serde(default)]
    pub force_tolerance_n: f64,
    /// The task is complete once this fraction of the path's length has been traced.
    pub min_coverage: f64,
    pub safe_force_n: f64,
}

/// Find the scene's hidden inclusions by touch, and mark each with the device's button.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PalpationTask {
    /// The centre of the area to search, on the surface, world frame.
    pub area_centre_m: [f64; 3],
    /// The surface's outward normal over the area, world frame (unit): marks and coverage are
    /// measured across it.
    pub normal: [f64; 3],
    /// The area to search: a disc of this radius around its centre.
    pub area_radius_m: f64,
    /// A mark finds an inclusion within its radius plus this, across the surface.
    pub tolerance_m: f64,
    /// A patch of the area counts as searched once pressed at least this deep.
    pub coverage_depth_m: f64,
    /// Marks that find nothing an attempt may make and still pass.
    pub max_false_marks: u32,
    pub safe_force_n: f64,
    /// The inclusions to find, placed from the scene. Never written: an exercise is sent to
    /// every viewer (the trainee's among them) and recorded with each attempt, while the answer
    /// stays with the scene (whose record keeps the inclusions).
    #[serde(skip)]
    pub targets: Vec<PalpationTarget>,
}

/// One inclusion to find, world frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PalpationTarget {
    pub centre_m: [f64; 3],
    pub radius_m: f64,
}

/// Follow the expert's path once, guided along it (`run --guide`): an attempt is one pass, from
/// its start until the trainee, having reached the path's end, lifts away (the guide's next
/// pass), or the time limit. The gain of each pass is the guide's (`--guide-gain 1,0.6,0.3`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FollowTask {
    /// The expert's recording the station must be guided by, by file name.
    pub expert: String,
    pub safe_force_n: f64,
    /// The expert's path: each resampled point and the size of the expert's force there, world
    /// frame. Taken from the station's guide, which every viewer already has in its `scene`
    /// message; not repeated in each `exercise` message.
    #[serde(skip)]
    pub expert_path: Vec<([f64; 3], f64)>,
}

/// Which way a metric is better.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Better {
    Higher,
    Lower,
}

/// One metric a task's scorer computes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MetricDef {
    /// Its key in scores, pass marks and the results CSV.
    pub name: &'static str,
    /// SI unit (`"1"` for a fraction).
    pub unit: &'static str,
    pub better: Better,
    /// What it measures, for reports and `--help`.
    pub what: &'static str,
}

/// The two metrics every kind scores: how hard, and how long beyond the safe force.
const PEAK_FORCE: MetricDef = MetricDef {
    name: "peak_force_n",
    unit: "N",
    better: Better::Lower,
    what: "largest force during the attempt",
};
const TIME_ABOVE_SAFE: MetricDef = MetricDef {
    name: "time_above_safe_s",
    unit: "s",
    better: Better::Lower,
    what: "time spent above the safe force",
};

const PRESS_METRICS: &[MetricDef] = &[
    MetricDef {
        name: "hold_s",
        unit: "s",
        better: Better::Higher,
        what: "longest continuous time at the site with the force in the window",
    },
    MetricDef {
        name: "time_to_hold_s",
        unit: "s",
        better: Better::Lower,
        what: "time from the start until the required hold was complete (the whole attempt when never)",
    },
    MetricDef {
        name: "hold_force_sd_n",
        unit: "N",
        better: Better::Lower,
        what: "standard deviation of the force over the longest hold",
    },
    PEAK_FORCE,
    TIME_ABOVE_SAFE,
];

const TRACE_METRICS: &[MetricDef] = &[
    MetricDef {
        name: "coverage",
        unit: "1",
        better: Better::Higher,
        what: "fraction of the path's length traced within the tolerance",
    },
    MetricDef {
        name: "mean_deviation_m",
        unit: "m",
        better: Better::Lower,
        what: "mean distance across the path, over the ticks in contact",
    },
    MetricDef {
        name: "max_deviation_m",
        unit: "m",
        better: Better::Lower,
        what: "largest distance across the path while in contact",
    },
    MetricDef {
        name: "in_window_fraction",
        unit: "1",
        better: Better::Higher,
        what: "fraction of the time in contact with the force in the window (when the exercise sets a force)",
    },
    MetricDef {
        name: "force_cv",
        unit: "1",
        better: Better::Lower,
        what: "coefficient of variation of the force in contact (standard deviation / mean)",
    },
    PEAK_FORCE,
    TIME_ABOVE_SAFE,
];

const PALPATION_METRICS: &[MetricDef] = &[
    MetricDef {
        name: "found",
        unit: "1",
        better: Better::Higher,
        what: "inclusions marked: a mark within the inclusion's radius plus the tolerance of its centre, across the surface",
    },
    MetricDef {
        name: "missed",
        unit: "1",
        better: Better::Lower,
        what: "inclusions no mark found",
    },
    MetricDef {
        name: "false_marks",
        unit: "1",
        better: Better::Lower,
        what: "marks that found no inclusion",
    },
    MetricDef {
        name: "localisation_error_m",
        unit: "m",
        better: Better::Lower,
        what: "mean distance across the surface from each found inclusion's centre to its nearest mark (when none is found, the farthest a mark could be and still find one)",
    },
    MetricDef {
        name: "coverage",
        unit: "1",
        better: Better::Higher,
        what: "fraction of the search area pressed at least the coverage depth (2 mm patches)",
    },
    MetricDef {
        name: "mean_force_n",
        unit: "N",
        better: Better::Lower,
        what: "mean force while in contact",
    },
    PEAK_FORCE,
    TIME_ABOVE_SAFE,
];

const FOLLOW_METRICS: &[MetricDef] = &[
    MetricDef {
        name: "path_deviation_m",
        unit: "m",
        better: Better::Lower,
        what: "mean distance from the expert's path after aligning the two in time (dynamic time warping), from the first captured tick to the last",
    },
    MetricDef {
        name: "max_path_deviation_m",
        unit: "m",
        better: Better::Lower,
        what: "largest distance from the expert's path over the same alignment",
    },
    MetricDef {
        name: "force_deviation_n",
        unit: "N",
        better: Better::Lower,
        what: "mean difference between the trainee's and the expert's force over the same alignment",
    },
    MetricDef {
        name: "guide_gain",
        unit: "1",
        better: Better::Lower,
        what: "the guidance's gain at the start of the attempt (less help is better)",
    },
    PEAK_FORCE,
    TIME_ABOVE_SAFE,
];

impl Task {
    /// The kind's name in exercise files.
    pub fn kind(&self) -> &'static str {
        match self {
            Task::Press(_) => "press",
            Task::Trace(_) => "trace",
            Task::Palpation(_) => "palpation",
            Task::Follow(_) => "follow",
        }
    }

    /// Every metric this kind's scorer computes, in report order.
    pub fn metrics(&self) -> &'static [MetricDef] {
        match self {
            Task::Press(_) => PRESS_METRICS,
            Task::Trace(_) => TRACE_METRICS,
            Task::Palpation(_) => PALPATION_METRICS,
            Task::Follow(_) => FOLLOW_METRICS,
        }
    }

    /// The metric called `name`, if this kind computes it.
    pub fn metric(&self, name: &str) -> Option<&'static MetricDef> {
        self.metrics().iter().find(|m| m.name == name)
    }

    /// The force above which the attempt is unsafe.
    pub fn safe_force_n(&self) -> f64 {
        match self {
            Task::Press(p) => p.safe_force_n,
            Task::Trace(t) => t.safe_force_n,
            Task::Palpation(p) => p.safe_force_n,
            Task::Follow(f) => f.safe_force_n,
        }
    }
}

/// A bound one metric must meet for an attempt to pass.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PassMark {
    pub metric: String,
    /// `at_least` for a metric where higher is better, `at_most` for one where lower is.
    pub at_least: Option<f64>,
    pub at_most: Option<f64>,
    /// Where the bound came from, when a benchmark of experts set it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub experts: Option<ExpertSpread>,
}

impl PassMark {
    /// Whether `value` meets the mark (a NaN never does).
    pub fn met_by(&self, value: f64) -> bool {
        self.at_least.is_none_or(|b| value >= b) && self.at_most.is_none_or(|b| value <= b)
    }
}

/// The experts' level on one metric: what a benchmark measured.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ExpertSpread {
    /// Recordings the benchmark used.
    pub recordings: u32,
    pub mean: f64,
    /// Sample standard deviation.
    pub sd: f64,
    pub min: f64,
    pub max: f64,
}

/// What a scorer measured over one attempt.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Score {
    /// The task's goal was reached (the hold, the coverage).
    pub completed: bool,
    /// The force never exceeded the safe force.
    pub safe: bool,
    /// Each metric of the kind, by name.
    pub metrics: BTreeMap<String, f64>,
}

/// How an attempt ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AttemptEnd {
    /// The time limit ran out.
    TimeLimit,
    /// The goal was reached (the attempt ends by itself then).
    Completed,
    /// An instructor ended it, or the session stopped.
    Stopped,
}

/// One pass mark held against an attempt.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MarkOutcome {
    pub mark: PassMark,
    pub value: f64,
    pub met: bool,
}

/// An attempt's result: its score, held against the exercise's pass marks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AttemptResult {
    pub exercise: String,
    pub trainee: String,
    /// 1 for the first attempt at this exercise in the session.
    pub attempt: u32,
    /// Device time of the attempt's first and last tick, ns.
    pub start_ns: u64,
    pub end_ns: u64,
    pub ended: AttemptEnd,
    pub score: Score,
    pub marks: Vec<MarkOutcome>,
    /// Completed, safe, and every mark met.
    pub passed: bool,
}

impl AttemptResult {
    /// Holds `score` against the pass marks of `exercise`.
    pub fn judge(
        exercise: &Exercise,
        trainee: &str,
        attempt: u32,
        (start_ns, end_ns): (u64, u64),
        ended: AttemptEnd,
        score: Score,
    ) -> Self {
        let marks: Vec<MarkOutcome> = exercise
            .pass
            .iter()
            .map(|mark| {
                let value = score.metrics.get(&mark.metric).copied().unwrap_or(f64::NAN);
                MarkOutcome {
                    mark: mark.clone(),
                    value,
                    met: mark.met_by(value),
                }
            })
            .collect();
        let passed = score.completed && score.safe && marks.iter().all(|m| m.met);
        Self {
            exercise: exercise.name.clone(),
            trainee: trainee.to_owned(),
            attempt,
            start_ns,
            end_ns,
            ended,
            score,
            marks,
            passed,
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    fn press() -> Exercise {
        Exercise {
            name: "press".into(),
            instructions: String::new(),
            time_limit_s: 10.0,
            task: Task::Press(PressTask {
                site_m: [0.0; 3],
                normal: [0.0, 1.0, 0.0],
                site_radius_m: 0.005,
                target_force_n: 2.0,
                tolerance_n: 0.3,
                hold_s: 3.0,
                safe_force_n: 4.0,
            }),
            pass: vec![PassMark {
                metric: "peak_force_n".into(),
                at_least: None,
                at_most: Some(3.0),
                experts: None,
            }],
        }
    }

    fn score(completed: bool, safe: bool, peak: f64) -> Score {
        Score {
            completed,
            safe,
            metrics: [("peak_force_n".to_owned(), peak)].into_iter().collect(),
        }
    }

    #[test]
    fn an_attempt_passes_when_complete_safe_and_every_mark_is_met() {
        let e = press();
        let judge = |s| AttemptResult::judge(&e, "ana", 1, (0, 1), AttemptEnd::Completed, s);
        assert!(judge(score(true, true, 2.5)).passed);
        assert!(!judge(score(true, true, 3.5)).passed, "a mark missed");
        assert!(!judge(score(false, true, 2.5)).passed, "not completed");
        assert!(!judge(score(true, false, 2.5)).passed, "unsafe");
        let missing = Score {
            completed: true,
            safe: true,
            metrics: BTreeMap::new(),
        };
        assert!(
            !judge(missing).passed,
            "a metric not measured meets no mark"
        );
    }

    #[test]
    fn every_kind_names_its_metrics_once() {
        for metrics in [PRESS_METRICS, TRACE_METRICS] {
            let names: Vec<_> = metrics.iter().map(|m| m.name).collect();
            let mut unique = names.clone();
            unique.sort_unstable();
            unique.dedup();
            assert_eq!(unique.len(), names.len(), "{names:?}");
        }
        assert!(TRACE_METRICS.iter().any(|m| m.name == "coverage"));
    }

    #[test]
    fn results_travel_as_json() {
        let e = press();
        let r = AttemptResult::judge(
            &e,
            "ana",
            2,
            (5, 9),
            AttemptEnd::TimeLimit,
            score(true, true, 2.5),
        );
        let text = serde_json::to_string(&r).unwrap();
        assert!(text.contains("\"ended\":\"time_limit\""), "{text}");
        assert_eq!(serde_json::from_str::<AttemptResult>(&text).unwrap(), r);
        let e_text = serde_json::to_string(&e).unwrap();
        assert!(e_text.contains("\"kind\":\"press\""), "{e_text}");
        assert_eq!(serde_json::from_str::<Exercise>(&e_text).unwrap(), e);
    }

    #[test]
    fn a_palpation_never_writes_where_its_inclusions_are() {
        let task = Task::Palpation(PalpationTask {
            area_centre_m: [0.0, 0.09, 0.0],
            normal: [0.0, 1.0, 0.0],
            area_radius_m: 0.035,
            tolerance_m: 0.003,
            coverage_depth_m: 0.002,
            max_false_marks: 1,
            safe_force_n: 2.0,
            targets: vec![PalpationTarget {
                centre_m: [-0.0123, 0.0812, 0.0067],
                radius_m: 0.005,
            }],
        });
        let json = serde_json::to_string(&task).unwrap();
        assert!(
            !json.contains("targets") && !json.contains("0.0123"),
            "{json}"
        );
        // Read back (a recording's, a viewer's), it has none.
        let Task::Palpation(back) = serde_json::from_str::<Task>(&json).unwrap() else {
            unreachable!()
        };
        assert!(back.targets.is_empty());
        assert_eq!(task.kind(), "palpation");
        assert!(task.metric("found").is_some());
    }
}
