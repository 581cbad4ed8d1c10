//! Scoring an exercise from the 1 kHz ticks.
//!
//! [`Scorer`] takes the same [`TickInput`] the trainee's metrics take, one per tick, so an
//! attempt scored live and the same attempt scored again from its recording agree exactly. It
//! runs beside the loop (on the ticks the recorder drains), never inside it; it allocates only
//! when built.
//!
//! Definitions (`dt` as in [`crate::metrics`]: the device time since the previous tick, at most
//! [`MAX_DT_S`]; "across" means in the surface, with the component along the surface's normal
//! removed, so the depth of a press is not a deviation):
//! - **press**: a tick is *held* when the tool is in contact, within `site_radius_m` of the site
//!   across the surface, with |F| within target ± tolerance. `hold_s` is the longest run of held
//!   ticks, from its first tick's time to its last's (a fault tick, a tick not held or a gap
//!   longer than [`MAX_DT_S`] ends a run); `time_to_hold_s` is the time from the first tick to
//!   the tick where a run first reached the required hold (the whole attempt when none did);
//!   `hold_force_sd_n` is the population standard deviation of |F| over the longest run.
//! - **trace**: for each tick in contact, the closest point of the path and the distance across
//!   to it. The path's length is cut into [`COVERAGE_BIN_M`] bins; a tick within `tolerance_m`
//!   marks its bin, and the bins between it and the previous tick when that one was on the path
//!   too (a fast stroke skips none). `coverage` is the fraction of bins marked; the deviations
//!   are over the ticks in contact; `force_cv` is σ/μ of |F| over them; `in_window_fraction` is
//!   Σ dt in the window / Σ dt in contact.
//! - **palpation**: a *mark* is a press of the device's first button (its rising edge, at
//!   most one per [`MARK_DEBOUNCE_NS`]) with the tip's position. A mark finds an inclusion when
//!   it lies within the inclusion's radius plus `tolerance_m` of its centre, across the
//!   surface; `found` counts the inclusions some mark found, `missed` the rest, `false_marks`
//!   the marks that found none; `localisation_error_m` is the mean over the found inclusions of
//!   the distance across from its centre to its nearest mark (when none is found: the largest
//!   radius plus the tolerance). The search area (a disc around its centre, across the surface)
//!   is cut into [`PALPATION_PATCH_M`] squares; a tick in contact at least `coverage_depth_m`
//!   deep marks the square under the tip, and `coverage` is the fraction of the disc's squares
//!   marked; `mean_force_n` is the mean |F| over the ticks in contact. The attempt is
//!   *completed* when no inclusion is missed and the false marks are within the allowed; it
//!   never ends by itself before its time limit (that would tell the trainee the answer).
//! - all: `peak_force_n` is the largest |F|; `time_above_safe_s` is Σ dt with |F| above the
//!   safe force; the attempt is *safe* when that is zero.

use std::collections::BTreeMap;

use glam::DVec3;
use softhaptic_proto::exercise::{PalpationTask, PressTask, Score, Task, TraceTask};

use crate::metrics::{MAX_DT_S, TickInput};

/// Length of one coverage bin along a traced path.
pub const COVERAGE_BIN_M: f64 = 0.001;
/// Side of one square of a palpation's search area.
pub const PALPATION_PATCH_M: f64 = 0.002;
/// A button pressed again within this time of a mark makes no second mark (a contact bounce).
pub const MARK_DEBOUNCE_NS: u64 = 200_000_000;
/// Most marks an attempt keeps (a stuck or hammered button must not grow the scorer).
pub const MAX_MARKS: usize = 100;

/// Scores one attempt, tick by tick.
#[derive(Debug, Clone)]
pub struct Scorer {
    kind: Kind,
    safe_force_n: f64,
    first_ns: Option<u64>,
    last_ns: Option<u64>,
    peak_force_n: f64,
    time_above_safe_s: f64,
}

#[derive(Debug, Clone)]
enum Kind {
    Press(PressScorer),
    Trace(TraceScorer),
    Palpation(Box<PalpationScorer>),
    Follow(Box<FollowScorer>),
}

/// The path deviation of an attempt never captured by the guide: the default capture distance,
/// nearer than which the trainee would have been captured.
const FOLLOW_UNCAPTURED_M: f64 = 0.015;

/// Most samples a follow attempt keeps for its alignment: 10 minutes at one per 10 ms.
const FOLLOW_MAX_SAMPLES: usize = 60_000;
/// Every how many ticks a follow attempt samples the tip (10 ms at 1 kHz), as `info`'s alignment.
const FOLLOW_EVERY_TICKS: u64 = 10;

/// A guided pass along the expert's path: the tip and force sampled from the first captured
/// tick, the pass it started in, and whether the guide has moved on to the next.
#[derive(Debug, Clone)]
struct FollowScorer {
    expert: Vec<crate::deviation::Sample>,
    samples: Vec<crate::deviation::Sample>,
    /// Samples taken up to the last captured tick (the rest are the trainee lifting away).
    captured_len: usize,
    ticks: u64,
    first_pass: Option<u32>,
    first_gain: Option<f64>,
    next_pass_begun: bool,
}

impl FollowScorer {
    fn new(task: &softhaptic_proto::exercise::FollowTask) -> Self {
        Self {
            expert: task
                .expert_path
                .iter()
                .map(|(p, f)| (DVec3::from_array(*p), *f))
                .collect(),
            samples: Vec::new(),
            captured_len: 0,
            ticks: 0,
            first_pass: None,
            first_gain: None,
            next_pass_begun: false,
        }
    }

    fn tick(&mut self, t: &TickInput, force_n: f64) {
        let Some(g) = t.guide else { return };
        if self.next_pass_begun {
            return;
        }
        let pass = *self.first_pass.get_or_insert(g.pass);
        if g.pass != pass {
            self.next_pass_begun = true;
            return;
        }
        // From the first captured tick on.
        if self.first_gain.is_none() && !g.engaged {
            return;
        }
        self.first_gain.get_or_insert(g.gain);
        if self.ticks.is_multiple_of(FOLLOW_EVERY_TICKS)
            && self.samples.len() < FOLLOW_MAX_SAMPLES
            && let Some(p) = t.tip_position_m
        {
            self.samples.push((p, force_n));
            if g.engaged {
                self.captured_len = self.samples.len();
            }
        }
        self.ticks += 1;
    }

    fn deviation(&self) -> Option<crate::deviation::Deviation> {
        crate::deviation::deviation(&self.samples[..self.captured_len], &self.expert)
    }
}

/// Running sums of a force: count, Σ|F|, Σ|F|².
#[derive(Debug, Clone, Copy, Default)]
struct Moments {
    n: u64,
    sum: f64,
    sum_sq: f64,
}

impl Moments {
    fn add(&mut self, x: f64) {
        self.n += 1;
        self.sum += x;
        self.sum_sq += x * x;
    }

    fn mean(&self) -> f64 {
        if self.n == 0 {
            0.0
        } else {
            self.sum / self.n as f64
        }
    }

    /// Population standard deviation (0 for fewer than two values).
    fn sd(&self) -> f64 {
        if self.n < 2 {
            return 0.0;
        }
        let mean = self.mean();
        (self.sum_sq / self.n as f64 - mean * mean).max(0.0).sqrt()
    }
}

/// The distance from `p` to `q` across a surface of outward normal `n`.
fn across(p: DVec3, q: DVec3, n: DVec3) -> f64 {
    let d = p - q;
    (d - n * d.dot(n)).length()
}

fn unit(v: [f64; 3]) -> DVec3 {
    DVec3::from_array(v).try_normalize().unwrap_or(DVec3::Y)
}

#[derive(Debug, Clone)]
struct PressScorer {
    task: PressTask,
    site_m: DVec3,
    normal: DVec3,
    run_start_ns: Option<u64>,
    run: Moments,
    best_hold_s: f64,
    best: Moments,
    held_at_ns: Option<u64>,
}

impl PressScorer {
    fn new(task: &PressTask) -> Self {
        Self {
            site_m: DVec3::from_array(task.site_m),
            normal: unit(task.normal),
            task: task.clone(),
            run_start_ns: None,
            run: Moments::default(),
            best_hold_s: 0.0,
            best: Moments::default(),
            held_at_ns: None,
        }
    }

    fn tick(&mut self, t: &TickInput, force_n: f64, gap: bool) {
        let at_site = t.in_contact
            && t.tip_position_m
                .is_some_and(|p| across(p, self.site_m, self.normal) <= self.task.site_radius_m);
        let in_window = (force_n - self.task.target_force_n).abs() <= self.task.tolerance_n;
        if !(at_site && in_window) || gap {
            self.run_start_ns = None;
            self.run = Moments::default();
            if !(at_site && in_window) {
                return;
            }
        }
        let start = *self.run_start_ns.get_or_insert(t.time_ns);
        self.run.add(force_n);
        let hold_s = t.time_ns.saturating_sub(start) as f64 * 1e-9;
        if hold_s > self.best_hold_s || self.best.n == 0 {
            self.best_hold_s = hold_s;
            self.best = self.run;
        }
        if hold_s >= self.task.hold_s && self.held_at_ns.is_none() {
            self.held_at_ns = Some(t.time_ns);
        }
    }
}

#[derive(Debug, Clone)]
struct TraceScorer {
    task: TraceTask,
    normal: DVec3,
    points_m: Vec<DVec3>,
    /// Arc length at each point.
    arc_m: Vec<f64>,
    bins: Vec<bool>,
    /// Arc position of the previous tick, when it was on the path.
    previous_on_path_m: Option<f64>,
    deviation_sum_m: f64,
    deviation_max_m: f64,
    in_contact_ticks: u64,
    force: Moments,
    contact_s: f64,
    in_window_s: f64,
}

impl TraceScorer {
    fn new(task: &TraceTask) -> Self {
        let points_m: Vec<DVec3> = task.path_m.iter().map(|p| DVec3::from_array(*p)).collect();
        let mut arc_m = Vec::with_capacity(points_m.len());
        let mut total = 0.0;
        for (i, p) in points_m.iter().enumerate() {
            if i > 0 {
                total += p.distance(points_m[i - 1]);
            }
            arc_m.push(total);
        }
        let bins = ((total / COVERAGE_BIN_M).ceil() as usize).max(1);
        Self {
            normal: unit(task.normal),
            task: task.clone(),
            points_m,
            arc_m,
            bins: vec![false; bins],
            previous_on_path_m: None,
            deviation_sum_m: 0.0,
            deviation_max_m: 0.0,
            in_contact_ticks: 0,
            force: Moments::default(),
            contact_s: 0.0,
            in_window_s: 0.0,
        }
    }

    /// The closest point of the path to `p` across the surface: (distance across, arc length).
    fn closest(&self, p: DVec3) -> (f64, f64) {
        if self.points_m.len() == 1 {
            return (across(p, self.points_m[0], self.normal), 0.0);
        }
        let mut best = (f64::INFINITY, 0.0);
        for (i, pair) in self.points_m.windows(2).enumerate() {
            let (a, b) = (pair[0], pair[1]);
            let ab = b - a;
            // Project across the surface too, so that depth does not pull the foot along.
            let flat = ab - self.normal * ab.dot(self.normal);
            let ap = p - a;
            let u = if flat.length_squared() > 0.0 {
                ((ap - self.normal * ap.dot(self.normal)).dot(flat) / flat.length_squared())
                    .clamp(0.0, 1.0)
            } else {
                0.0
            };
            let foot = a + ab * u;
            let d = across(p, foot, self.normal);
            if d < best.0 {
                best = (d, self.arc_m[i] + u * (self.arc_m[i + 1] - self.arc_m[i]));
            }
        }
        best
    }

    fn bin(&self, arc_m: f64) -> usize {
        ((arc_m / COVERAGE_BIN_M) as usize).min(self.bins.len() - 1)
    }

    fn tick(&mut self, t: &TickInput, force_n: f64, dt_s: f64, gap: bool) {
        let Some(tip) = t.tip_position_m.filter(|_| t.in_contact) else {
            self.previous_on_path_m = None;
            return;
        };
        let (deviation_m, arc_m) = self.closest(tip);
        self.in_contact_ticks += 1;
        self.deviation_sum_m += deviation_m;
        self.deviation_max_m = self.deviation_max_m.max(deviation_m);
        self.force.add(force_n);
        self.contact_s += dt_s;
        if let Some(target) = self.task.target_force_n
            && (force_n - target).abs() <= self.task.force_tolerance_n
        {
            self.in_window_s += dt_s;
        }
        if deviation_m <= self.task.tolerance_m {
            let here = self.bin(arc_m);
            let from = match self.previous_on_path_m {
                Some(previous) if !gap => self.bin(previous),
                _ => here,
            };
            for b in from.min(here)..=from.max(here) {
                self.bins[b] = true;
            }
            self.previous_on_path_m = Some(arc_m);
        } else {
            self.previous_on_path_m = None;
        }
    }

    fn coverage(&self) -> f64 {
        self.bins.iter().filter(|b| **b).count() as f64 / self.bins.len() as f64
    }
}

#[derive(Debug, Clone)]
struct PalpationScorer {
    task: PalpationTask,
    centre_m: DVec3,
    normal: DVec3,
    /// Two axes across the surface, for the squares.
    u: DVec3,
    v: DVec3,
    /// Squares per side, and which are inside the disc and which are searched.
    side: usize,
    inside: Vec<bool>,
    searched: Vec<bool>,
    marks_m: Vec<DVec3>,
    last_mark_ns: Option<u64>,
    button_was_down: bool,
    force: Moments,
}

impl PalpationScorer {
    fn new(task: &PalpationTask) -> Self {
        let normal = unit(task.normal);
        let u = normal.any_orthonormal_vector();
        let v = normal.cross(u);
        let side = ((2.0 * task.area_radius_m / PALPATION_PATCH_M).ceil() as usize).clamp(1, 1000);
        let half = side as f64 * PALPATION_PATCH_M / 2.0;
        let mut inside = vec![false; side * side];
        for (k, cell) in inside.iter_mut().enumerate() {
            let x = -half + ((k % side) as f64 + 0.5) * PALPATION_PATCH_M;
            let y = -half + ((k / side) as f64 + 0.5) * PALPATION_PATCH_M;
            *cell = x.hypot(y) <= task.area_radius_m;
        }
        Self {
            centre_m: DVec3::from_array(task.area_centre_m),
            task: task.clone(),
            normal,
            u,
            v,
            side,
            searched: vec![false; side * side],
            inside,
            marks_m: Vec::with_capacity(MAX_MARKS),
            last_mark_ns: None,
            button_was_down: false,
            force: Moments::default(),
        }
    }

    fn tick(&mut self, t: &TickInput, force_n: f64) {
        let down = t.buttons & 1 != 0;
        if down
            && !self.button_was_down
            && let Some(tip) = t.tip_position_m
            && self
                .last_mark_ns
                .is_none_or(|last| t.time_ns.saturating_sub(last) >= MARK_DEBOUNCE_NS)
            && self.marks_m.len() < MAX_MARKS
        {
            self.marks_m.push(tip);
            self.last_mark_ns = Some(t.time_ns);
        }
        self.button_was_down = down;
        if t.in_contact {
            self.force.add(force_n);
            if t.depth_m >= self.task.coverage_depth_m
                && let Some(tip) = t.tip_position_m
            {
                let d = tip - self.centre_m;
                let half = self.side as f64 * PALPATION_PATCH_M / 2.0;
                let i = ((d.dot(self.u) + half) / PALPATION_PATCH_M).floor();
                let j = ((d.dot(self.v) + half) / PALPATION_PATCH_M).floor();
                let n = self.side as f64;
                if (0.0..n).contains(&i) && (0.0..n).contains(&j) {
                    let k = j as usize * self.side + i as usize;
                    if self.inside[k] {
                        self.searched[k] = true;
                    }
                }
            }
        }
    }

    /// Per inclusion, the distance across from its centre to its nearest mark that finds it.
    fn found(&self) -> Vec<Option<f64>> {
        self.task
            .targets
            .iter()
            .map(|target| {
                let c = DVec3::from_array(target.centre_m);
                self.marks_m
                    .iter()
                    .map(|m| across(*m, c, self.normal))
                    .filter(|d| *d <= target.radius_m + self.task.tolerance_m)
                    .min_by(f64::total_cmp)
            })
            .collect()
    }

    fn false_marks(&self) -> usize {
        self.marks_m
            .iter()
            .filter(|m| {
                !self.task.targets.iter().any(|target| {
                    across(**m, DVec3::from_array(target.centre_m), self.normal)
                        <= target.radius_m + self.task.tolerance_m
                })
            })
            .count()
    }

    fn coverage(&self) -> f64 {
        let inside = self.inside.iter().filter(|c| **c).count().max(1);
        self.searched.iter().filter(|c| **c).count() as f64 / inside as f64
    }

    fn completed(&self) -> bool {
        self.found().iter().all(Option::is_some)
            && self.false_marks() <= self.task.max_false_marks as usize
    }
}

impl Scorer {
    pub fn new(task: &Task) -> Self {
        let kind = match task {
            Task::Press(p) => Kind::Press(PressScorer::new(p)),
            Task::Trace(t) => Kind::Trace(TraceScorer::new(t)),
            Task::Palpation(p) => Kind::Palpation(Box::new(PalpationScorer::new(p))),
            Task::Follow(f) => Kind::Follow(Box::new(FollowScorer::new(f))),
        };
        Self {
            kind,
            safe_force_n: task.safe_force_n(),
            first_ns: None,
            last_ns: None,
            peak_force_n: 0.0,
            time_above_safe_s: 0.0,
        }
    }

    /// Adds one tick.
    pub fn update(&mut self, t: &TickInput) {
        let force_n = t.force_n.length();
        let force_n = if force_n.is_finite() { force_n } else { 0.0 };
        self.first_ns.get_or_insert(t.time_ns);
        let since_s = self
            .last_ns
            .map_or(0.0, |last| t.time_ns.saturating_sub(last) as f64 * 1e-9);
        let gap = since_s > MAX_DT_S;
        let dt_s = since_s.min(MAX_DT_S);
        self.last_ns = Some(t.time_ns);
        self.peak_force_n = self.peak_force_n.max(force_n);
        if force_n > self.safe_force_n {
            self.time_above_safe_s += dt_s;
        }
        match &mut self.kind {
            Kind::Press(p) => p.tick(t, force_n, gap),
            Kind::Trace(s) => s.tick(t, force_n, dt_s, gap),
            Kind::Palpation(s) => s.tick(t, force_n),
            Kind::Follow(s) => s.tick(t, force_n),
        }
    }

    /// Whether the task's goal has been reached and the attempt ends there (a palpation's
    /// never does before its time limit: ending would give the answer away).
    pub fn completed(&self) -> bool {
        match &self.kind {
            Kind::Press(p) => p.held_at_ns.is_some(),
            Kind::Trace(s) => s.coverage() >= s.task.min_coverage,
            Kind::Palpation(_) => false,
            // The pass is over once the guide has moved on to the next one: the trainee reached
            // the end and lifted away.
            Kind::Follow(s) => s.next_pass_begun,
        }
    }

    /// Whether the goal was reached, for the score.
    fn goal_reached(&self) -> bool {
        match &self.kind {
            Kind::Palpation(p) => p.completed(),
            _ => self.completed(),
        }
    }

    /// Seconds from the first tick to the last.
    pub fn elapsed_s(&self) -> f64 {
        match (self.first_ns, self.last_ns) {
            (Some(a), Some(b)) => b.saturating_sub(a) as f64 * 1e-9,
            _ => 0.0,
        }
    }

    /// The score so far.
    pub fn score(&self) -> Score {
        let mut metrics = BTreeMap::new();
        let mut put = |name: &str, value: f64| {
            metrics.insert(name.to_owned(), value);
        };
        put("peak_force_n", self.peak_force_n);
        put("time_above_safe_s", self.time_above_safe_s);
        match &self.kind {
            Kind::Press(p) => {
                put("hold_s", p.best_hold_s);
                let to_hold = match (p.held_at_ns, self.first_ns) {
                    (Some(at), Some(first)) => at.saturating_sub(first) as f64 * 1e-9,
                    _ => self.elapsed_s(),
                };
                put("time_to_hold_s", to_hold);
                put("hold_force_sd_n", p.best.sd());
            }
            Kind::Trace(s) => {
                put("coverage", s.coverage());
                let n = s.in_contact_ticks.max(1) as f64;
                put("mean_deviation_m", s.deviation_sum_m / n);
                put("max_deviation_m", s.deviation_max_m);
                if s.task.target_force_n.is_some() {
                    let fraction = if s.contact_s > 0.0 {
                        s.in_window_s / s.contact_s
                    } else {
                        0.0
                    };
                    put("in_window_fraction", fraction);
                }
                let mean = s.force.mean();
                put(
                    "force_cv",
                    if mean > 0.0 { s.force.sd() / mean } else { 0.0 },
                );
            }
            Kind::Palpation(p) => {
                let found = p.found();
                let hits: Vec<f64> = found.iter().flatten().copied().collect();
                put("found", hits.len() as f64);
                put("missed", (found.len() - hits.len()) as f64);
                put("false_marks", p.false_marks() as f64);
                let worst = p
                    .task
                    .targets
                    .iter()
                    .map(|t| t.radius_m + p.task.tolerance_m)
                    .fold(p.task.tolerance_m, f64::max);
                put(
                    "localisation_error_m",
                    if hits.is_empty() {
                        worst
                    } else {
                        hits.iter().sum::<f64>() / hits.len() as f64
                    },
                );
                put("coverage", p.coverage());
                put("mean_force_n", p.force.mean());
            }
            Kind::Follow(f) => {
                // Never captured: as far as the path can be judged, the largest of the
                // trainee's distances there is none, so the capture distance stands in.
                let d = f.deviation();
                put(
                    "path_deviation_m",
                    d.map_or(FOLLOW_UNCAPTURED_M, |d| d.mean_path_m),
                );
                put(
                    "max_path_deviation_m",
                    d.map_or(FOLLOW_UNCAPTURED_M, |d| d.max_path_m),
                );
                put("force_deviation_n", d.map_or(0.0, |d| d.mean_force_n));
                put("guide_gain", f.first_gain.unwrap_or(0.0));
            }
        }
        Score {
            completed: self.goal_reached(),
            safe: self.time_above_safe_s == 0.0,
            metrics,
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use softhaptic_proto::ContactFlags;

    const MS: u64 = 1_000_000;

    fn press_task() -> Task {
        Task::Press(PressTask {
            site_m: [0.0, 0.0, 0.0],
            normal: [0.0, 1.0, 0.0],
            site_radius_m: 0.005,
            target_force_n: 2.0,
            tolerance_n: 0.3,
            hold_s: 1.0,
            safe_force_n: 4.0,
        })
    }

    fn tick(ms: u64, tip: DVec3, force: f64) -> TickInput {
        TickInput {
            time_ns: ms * MS,
            tip_position_m: Some(tip),
            in_contact: force > 0.0,
            depth_m: 0.0,
            force_n: DVec3::new(0.0, force, 0.0),
            flags: ContactFlags::empty(),
            buttons: 0,
            guide: None,
        }
    }

    #[test]
    fn a_press_held_in_the_window_scores_its_hold_and_when_it_was_reached() {
        let mut s = Scorer::new(&press_task());
        // 500 ms approaching (free), 1.5 s at 2.1 N and 3 mm deep at the site (the depth is not
        // a distance from the site), then 2.0 N 8 mm off the site for 500 ms.
        for ms in 0..2500 {
            let (tip, f) = match ms {
                0..500 => (DVec3::new(0.0, 0.01, 0.0), 0.0),
                500..2000 => (DVec3::new(0.002, -0.003, 0.0), 2.1 + 0.1 * (ms % 2) as f64),
                _ => (DVec3::new(0.008, -0.003, 0.0), 2.0),
            };
            s.update(&tick(ms, tip, f));
            if ms == 1499 {
                assert!(!s.completed());
            }
        }
        let score = s.score();
        let m = &score.metrics;
        // Held from the tick at 500 ms to the one at 1999 ms.
        assert!((m["hold_s"] - 1.499).abs() < 1e-9, "{m:?}");
        // The run reached 1 s at the tick of 1500 ms.
        assert!((m["time_to_hold_s"] - 1.5).abs() < 1e-9);
        // Alternating 2.1 and 2.2 N: σ = 0.05 N.
        assert!((m["hold_force_sd_n"] - 0.05).abs() < 1e-9);
        assert!((m["peak_force_n"] - 2.2).abs() < 1e-12);
        assert_eq!(m["time_above_safe_s"], 0.0);
        assert!(score.completed && score.safe);
    }

    #[test]
    fn a_press_outside_the_window_or_off_the_site_is_no_hold_and_a_spike_is_unsafe() {
        let mut s = Scorer::new(&press_task());
        for ms in 0..3000 {
            let f = match ms {
                0..1000 => 2.5,    // above the window
                1000..1010 => 4.5, // 10 ms above the safe force
                _ => 2.0,
            };
            // Off the site from 1500 ms: 6 mm across.
            let x = if ms < 1500 { 0.0 } else { 0.006 };
            s.update(&tick(ms, DVec3::new(x, -0.002, 0.0), f));
        }
        let score = s.score();
        let m = &score.metrics;
        // Held from 1010 ms to 1499 ms only.
        assert!((m["hold_s"] - 0.489).abs() < 1e-9, "{m:?}");
        assert!((m["time_above_safe_s"] - 0.010).abs() < 1e-9);
        assert!((m["time_to_hold_s"] - 2.999).abs() < 1e-9);
        assert!(!score.completed && !score.safe);
    }

    #[test]
    fn a_fault_or_a_gap_breaks_a_hold() {
        let mut s = Scorer::new(&press_task());
        for ms in 0..1000 {
            let mut t = tick(ms, DVec3::ZERO, 2.0);
            if ms == 400 {
                t.tip_position_m = None;
            }
            s.update(&t);
        }
        // 50 ms lost, then held again.
        for ms in 1050..1300 {
            s.update(&tick(ms, DVec3::ZERO, 2.0));
        }
        assert!((s.score().metrics["hold_s"] - 0.598).abs() < 1e-9);
    }

    fn trace_task(target: Option<f64>) -> Task {
        Task::Trace(TraceTask {
            path_m: vec![[0.0, 0.0, 0.0], [0.02, 0.0, 0.0], [0.02, 0.0, 0.02]],
            normal: [0.0, 1.0, 0.0],
            tolerance_m: 0.002,
            target_force_n: target,
            force_tolerance_n: 0.25,
            min_coverage: 0.9,
            safe_force_n: 4.0,
        })
    }

    #[test]
    fn tracing_the_first_leg_covers_half_the_path_with_its_offset_as_deviation() {
        let mut s = Scorer::new(&trace_task(Some(1.5)));
        // Along the first leg (20 mm of 40) at 1 mm off it and 2 mm deep, 10 mm/s; the force
        // alternates 1.5 and 1.9 N (in the window half the time).
        for ms in 0..2000u64 {
            let x = ms as f64 * 1e-5;
            let f = if ms % 2 == 0 { 1.5 } else { 1.9 };
            // Offset to the outside of the corner, so the second leg is never closer.
            s.update(&tick(ms, DVec3::new(x, -0.002, -0.001), f));
        }
        let score = s.score();
        let m = &score.metrics;
        assert!((m["coverage"] - 0.5).abs() < 1e-9, "{m:?}");
        assert!((m["mean_deviation_m"] - 0.001).abs() < 1e-12);
        assert!((m["max_deviation_m"] - 0.001).abs() < 1e-12);
        // σ/μ of alternating 1.5 and 1.9 N: 0.2 / 1.7.
        assert!(
            (m["force_cv"] - 0.2 / 1.7).abs() < 1e-9,
            "{}",
            m["force_cv"]
        );
        assert!((m["in_window_fraction"] - 0.5).abs() < 1e-3);
        assert!(!score.completed);
    }

    #[test]
    fn the_whole_path_traced_completes_and_a_stroke_off_it_marks_nothing() {
        let mut s = Scorer::new(&trace_task(None));
        // 5 mm off the path: nothing marked.
        for ms in 0..1000u64 {
            s.update(&tick(ms, DVec3::new(0.01, -0.001, 0.005), 1.0));
        }
        assert_eq!(s.score().metrics["coverage"], 0.0);
        assert!(!s.score().metrics.contains_key("in_window_fraction"));
        // Then both legs, 1 mm a tick, with one stroke of 5 mm in a tick (10 to 15 mm): it
        // marks the bins it passed over.
        for (k, mm) in (0..=10u64).chain(15..=40).enumerate() {
            let a = mm as f64 * 1e-3;
            let p = if a <= 0.02 {
                DVec3::new(a, 0.0, 0.0)
            } else {
                DVec3::new(0.02, 0.0, a - 0.02)
            };
            s.update(&tick(1000 + k as u64, p, 1.0));
        }
        let score = s.score();
        assert_eq!(score.metrics["coverage"], 1.0);
        assert!(score.completed);
    }

    fn palpation_task() -> Task {
        use softhaptic_proto::exercise::PalpationTarget;
        Task::Palpation(PalpationTask {
            area_centre_m: [0.0, 0.0, 0.0],
            normal: [0.0, 1.0, 0.0],
            area_radius_m: 0.01,
            tolerance_m: 0.002,
            coverage_depth_m: 0.003,
            max_false_marks: 1,
            safe_force_n: 4.0,
            targets: vec![
                PalpationTarget {
                    centre_m: [0.004, -0.01, 0.0],
                    radius_m: 0.003,
                },
                PalpationTarget {
                    centre_m: [-0.005, -0.008, 0.0],
                    radius_m: 0.002,
                },
            ],
        })
    }

    fn palpating(ms: u64, tip: DVec3, depth_m: f64, force: f64, button: bool) -> TickInput {
        TickInput {
            depth_m,
            buttons: u32::from(button),
            ..tick(ms, tip, force)
        }
    }

    #[test]
    fn a_palpation_counts_found_missed_and_false_marks_and_the_area_pressed() {
        let mut s = Scorer::new(&palpation_task());
        let over_a = DVec3::new(0.005, -0.004, 0.0);
        let elsewhere = DVec3::new(0.0, -0.004, 0.008);
        for ms in 0..600 {
            let t = match ms {
                // Free, 20 mm above.
                0..100 => tick(ms, DVec3::new(0.0, 0.02, 0.0), 0.0),
                // 4 mm deep over the first lump, 1 N, the button down from 200 to 249 ms.
                100..300 => palpating(ms, over_a, 0.004, 1.0, (200..250).contains(&ms)),
                // 2 mm deep elsewhere, 0.5 N; the button down at 450 ms, up at 455, down again
                // at 460 (a bounce: no third mark).
                _ => palpating(
                    ms,
                    elsewhere,
                    0.002,
                    0.5,
                    (450..455).contains(&ms) || (460..470).contains(&ms),
                ),
            };
            s.update(&t);
            // It never ends by itself: that would say the answer.
            assert!(!s.completed());
        }
        let score = s.score();
        let m = &score.metrics;
        // The first mark lies 1 mm across from the first lump's centre (within 3 + 2 mm); the
        // second, 8.9 mm from the first and 9.4 mm from the second (beyond 5 and 4 mm), finds
        // nothing.
        assert_eq!(m["found"], 1.0);
        assert_eq!(m["missed"], 1.0);
        assert_eq!(m["false_marks"], 1.0);
        assert!((m["localisation_error_m"] - 0.001).abs() < 1e-12);
        // 200 ticks at 1 N and 300 at 0.5 N in contact.
        assert!((m["mean_force_n"] - 350.0 / 500.0).abs() < 1e-12);
        // Only the ticks at least 3 mm deep search: one 2 mm square of the 80 whose centres lie
        // within the 10 mm disc (20 + 20 + 16 + 16 + 8 for columns 1, 3, 5, 7, 9 mm out).
        assert_eq!(m["coverage"], 1.0 / 80.0);
        assert_eq!(m["peak_force_n"], 1.0);
        assert!(score.safe);
        // A lump missed: not completed.
        assert!(!score.completed);
    }

    #[test]
    fn a_follow_scores_its_pass_aligned_with_the_experts_and_ends_with_the_next_pass() {
        // The expert: 50 mm along x at 1 N. The trainee: the same path 2 mm aside at 1.5 N,
        // captured, at its own pace; then it lifts away and the guide's next pass begins.
        let task = Task::Follow(softhaptic_proto::exercise::FollowTask {
            expert: "expert.mcap".into(),
            safe_force_n: 2.0,
            expert_path: (0..=50)
                .map(|i| ([0.001 * i as f64, 0.0, 0.0], 1.0))
                .collect(),
        });
        let guide = |pass: u32, engaged: bool| {
            Some(softhaptic_proto::GuideState {
                force_n: DVec3::ZERO,
                target_m: DVec3::ZERO,
                progress: 0.0,
                gain: 0.6,
                effective_gain: 0.6,
                engaged,
                pass,
            })
        };
        let mut s = Scorer::new(&task);
        // Free and not yet captured: not sampled.
        for ms in 0..100 {
            s.update(&TickInput {
                guide: guide(0, false),
                ..tick(ms, DVec3::new(0.0, 0.03, 0.0), 0.0)
            });
        }
        for ms in 100..2100 {
            let x = 0.05 * (ms - 100) as f64 / 2000.0;
            s.update(&TickInput {
                guide: guide(0, true),
                ..tick(ms, DVec3::new(x, 0.0, 0.002), 1.5)
            });
        }
        assert!(!s.completed());
        s.update(&TickInput {
            guide: guide(1, false),
            ..tick(2100, DVec3::new(0.05, 0.04, 0.0), 0.0)
        });
        assert!(s.completed());
        let score = s.score();
        let m = &score.metrics;
        assert!((m["path_deviation_m"] - 0.002).abs() < 1e-4, "{m:?}");
        assert!((m["force_deviation_n"] - 0.5).abs() < 1e-9, "{m:?}");
        assert_eq!(m["guide_gain"], 0.6);
        assert!(score.completed && score.safe);
    }
}
