//! Haptic guidance: a pull toward an expert's recorded path, so a trainee feels how the expert
//! moved.
//!
//! [`GuidePath`] is the expert's tool path, resampled at an even spacing along its length, with
//! the expert's contact depth at each point. [`Guide`] follows a trainee along it, tick by tick:
//! - **The target advances with the trainee's progress, not the clock.** It is the closest
//!   point of the path to the tip, searched only in a window around the previous target, so a
//!   path that crosses itself never makes it jump to the other pass; its advance is
//!   rate-limited ([`GuideParams::max_target_speed_m_s`]). Until the trainee is captured the
//!   whole path is searched.
//! - **The force** is a spring–damper toward the target, F = k (q − p) − b v⊥ (v⊥ the tip's
//!   velocity across the path, so moving along it costs nothing), plus an optional push along
//!   the path's tangent, scaled by the gain (fading) and by a ramp that takes
//!   [`GuideParams::ramp_s`] to engage or release, so it never jumps.
//! - **Capture and escape**: the pull switches on within [`GuideParams::capture_m`] of the path
//!   and releases beyond [`GuideParams::escape_m`], so a trainee who leaves the path on purpose
//!   is let go.
//! - **Safe by construction**: never pushes into the object once the tool is as deep as the
//!   expert was at that point (the inward part along the contact normal is removed), and never
//!   more than [`GuideParams::max_force_n`], a cap of its own below the device's. A non-finite
//!   input gives zero.
//!
//! The gain fades as [`GuideGain`] says: fixed; a schedule, a gain per pass along the path (a
//! pass ends once the trainee has reached the end and lifts away); or guidance as needed, whose
//! gain follows the trainee's error with a forgetting factor (g ← f·g + c·e, every window).
//!
//! Allocation-free per tick; the path is built once.

use glam::DVec3;

use crate::passivity::PassivityObserver;
pub use softhaptic_proto::guide::{GuideGain, GuideParams};
use softhaptic_proto::guide::{GuideState, MAX_GUIDE_POINTS, RecordedGuide};

/// Why a path cannot guide.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GuideError {
    #[error("the expert's path is {length_m:.4} m long: too short to guide (at least {min_m} m)")]
    TooShort { length_m: f64, min_m: f64 },
    #[error("the spacing must be finite and positive, got {0}")]
    Spacing(f64),
    #[error("the expert's path has a non-finite point (sample {0})")]
    NonFinite(usize),
    #[error(
        "the expert's path has {points} points at {spacing_m} m: more than {max} (too long to guide)"
    )]
    TooLong {
        points: usize,
        spacing_m: f64,
        max: usize,
    },
    #[error("the recorded guide's points do not fit its spacing: {0}")]
    Inconsistent(&'static str),
}

/// The expert's path, resampled every `spacing_m` of its length.
#[derive(Debug, Clone, PartialEq)]
pub struct GuidePath {
    points_m: Vec<DVec3>,
    /// The expert's contact depth at each point (0 where free).
    depths_m: Vec<f64>,
    /// The size of the expert's force at each point (0 where unknown).
    forces_n: Vec<f64>,
    spacing_m: f64,
}

/// Most damping the pull's passivity controller adds until told the device's
/// ([`Guide::set_max_damping`]): a PHANTOM Desktop's stable damping.
const DEFAULT_MAX_DAMPING_N_S_PER_M: f64 = 5.0;

/// A pass is complete once the target is this far along the path.
const PASS_END: f64 = 0.98;

/// Half the span of path the damping's direction is taken over.
const TANGENT_SPAN_M: f64 = 0.003;

/// Shortest path that guides (a few spacings).
pub const MIN_PATH_M: f64 = 0.002;

impl GuidePath {
    /// From the expert's tip positions and contact depths, in order (a recording's ticks).
    /// Points are placed every `spacing_m` along the polyline through them, the last at its end;
    /// a sample that does not move adds nothing.
    pub fn resample(
        samples: impl IntoIterator<Item = (DVec3, f64)>,
        spacing_m: f64,
    ) -> Result<Self, GuideError> {
        Self::resample_with_forces(samples.into_iter().map(|(p, d)| (p, d, 0.0)), spacing_m)
    }

    /// [`GuidePath::resample`] with the size of the expert's force at each sample too, kept at
    /// each point to compare a trainee's force with the expert's.
    pub fn resample_with_forces(
        samples: impl IntoIterator<Item = (DVec3, f64, f64)>,
        spacing_m: f64,
    ) -> Result<Self, GuideError> {
        if !(spacing_m.is_finite() && spacing_m > 0.0) {
            return Err(GuideError::Spacing(spacing_m));
        }
        let mut points_m = Vec::new();
        let mut depths_m = Vec::new();
        let mut forces_n = Vec::new();
        // Arc length to the next point to place, from the previous sample.
        let mut previous: Option<(DVec3, f64, f64)> = None;
        let mut to_next_m = 0.0;
        let mut length_m = 0.0;
        for (i, (p, depth, force)) in samples.into_iter().enumerate() {
            if !p.is_finite() {
                return Err(GuideError::NonFinite(i));
            }
            let depth = if depth.is_finite() {
                depth.max(0.0)
            } else {
                0.0
            };
            let force = if force.is_finite() {
                force.max(0.0)
            } else {
                0.0
            };
            let Some((a, depth_a, force_a)) = previous else {
                points_m.push(p);
                depths_m.push(depth);
                forces_n.push(force);
                previous = Some((p, depth, force));
                to_next_m = spacing_m;
                continue;
            };
            let segment_m = a.distance(p);
            let mut along_m = to_next_m;
            while along_m <= segment_m {
                // Bounded before it is allocated: a recording's path can be any length.
                if points_m.len() >= MAX_GUIDE_POINTS {
                    return Err(GuideError::TooLong {
                        points: points_m.len() + 1,
                        spacing_m,
                        max: MAX_GUIDE_POINTS,
                    });
                }
                let u = along_m / segment_m;
                points_m.push(a.lerp(p, u));
                depths_m.push(depth_a + (depth - depth_a) * u);
                forces_n.push(force_a + (force - force_a) * u);
                along_m += spacing_m;
            }
            to_next_m = along_m - segment_m;
            length_m += segment_m;
            previous = Some((p, depth, force));
        }
        // The end itself, unless the last point placed is on it.
        if let Some((end, depth, force)) = previous
            && points_m
                .last()
                .is_some_and(|last| last.distance(end) > 1e-9)
        {
            points_m.push(end);
            depths_m.push(depth);
            forces_n.push(force);
        }
        if points_m.len() > MAX_GUIDE_POINTS {
            return Err(GuideError::TooLong {
                points: points_m.len(),
                spacing_m,
                max: MAX_GUIDE_POINTS,
            });
        }
        if length_m < MIN_PATH_M || points_m.len() < 2 {
            return Err(GuideError::TooShort {
                length_m,
                min_m: MIN_PATH_M,
            });
        }
        Ok(Self {
            points_m,
            depths_m,
            forces_n,
            spacing_m,
        })
    }

    /// A path as [`GuidePath::resample`] made it, back from a recording, exactly: the points
    /// must lie `spacing_m` apart along it (the last closer), within a rounding margin.
    pub fn from_recorded(guide: &RecordedGuide) -> Result<Self, GuideError> {
        let spacing_m = guide.spacing_m;
        if !(spacing_m.is_finite() && spacing_m > 0.0) {
            return Err(GuideError::Spacing(spacing_m));
        }
        let n = guide.points_m.len();
        if n > MAX_GUIDE_POINTS {
            return Err(GuideError::TooLong {
                points: n,
                spacing_m,
                max: MAX_GUIDE_POINTS,
            });
        }
        if guide.depths_m.len() != n {
            return Err(GuideError::Inconsistent(
                "a depth per point is needed, and the counts differ",
            ));
        }
        let points_m: Vec<DVec3> = guide
            .points_m
            .iter()
            .map(|p| DVec3::from_array(*p))
            .collect();
        if let Some(i) = points_m.iter().position(|p| !p.is_finite()) {
            return Err(GuideError::NonFinite(i));
        }
        if n < 2 {
            return Err(GuideError::TooShort {
                length_m: 0.0,
                min_m: MIN_PATH_M,
            });
        }
        // The arc-length lookups take point i to be i spacings along: no two points may be
        // farther apart than that (closer is a corner cut by the chord).
        let margin_m = spacing_m * 1e-6;
        if points_m
            .windows(2)
            .any(|w| w[0].distance(w[1]) > spacing_m + margin_m)
        {
            return Err(GuideError::Inconsistent(
                "two points are more than one spacing apart",
            ));
        }
        let forces_n = match &guide.forces_n {
            Some(f) if f.len() == n => f
                .iter()
                .map(|f| if f.is_finite() { f.max(0.0) } else { 0.0 })
                .collect(),
            Some(_) => {
                return Err(GuideError::Inconsistent(
                    "a force per point is needed, and the counts differ",
                ));
            }
            None => vec![0.0; n],
        };
        let path = Self {
            points_m,
            depths_m: guide
                .depths_m
                .iter()
                .map(|d| if d.is_finite() { d.max(0.0) } else { 0.0 })
                .collect(),
            forces_n,
            spacing_m,
        };
        let length_m = path.length_m();
        if length_m < MIN_PATH_M {
            return Err(GuideError::TooShort {
                length_m,
                min_m: MIN_PATH_M,
            });
        }
        Ok(path)
    }

    /// The path's resampled points and depths, to record.
    pub fn depths_m(&self) -> &[f64] {
        &self.depths_m
    }

    /// The size of the expert's force at each point (0 where the recording did not say).
    pub fn forces_n(&self) -> &[f64] {
        &self.forces_n
    }

    /// The spacing the path was resampled at.
    pub fn spacing_m(&self) -> f64 {
        self.spacing_m
    }

    /// The resampled points, in order.
    pub fn points_m(&self) -> &[DVec3] {
        &self.points_m
    }

    /// Arc length from the start to the last point.
    pub fn length_m(&self) -> f64 {
        let n = self.points_m.len();
        (n - 2) as f64 * self.spacing_m + self.points_m[n - 2].distance(self.points_m[n - 1])
    }

    /// The segment index and fraction at arc length `s_m` (clamped to the path).
    fn locate(&self, s_m: f64) -> (usize, f64) {
        let last = self.points_m.len() - 2;
        let s = s_m.max(0.0);
        let i = ((s / self.spacing_m) as usize).min(last);
        let len = self.points_m[i].distance(self.points_m[i + 1]);
        let u = if len > 0.0 {
            ((s - i as f64 * self.spacing_m) / len).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (i, u)
    }

    /// The point, the unit tangent and the expert's depth at arc length `s_m`.
    pub fn at(&self, s_m: f64) -> (DVec3, DVec3, f64) {
        let (i, u) = self.locate(s_m);
        let (a, b) = (self.points_m[i], self.points_m[i + 1]);
        let tangent = (b - a).try_normalize().unwrap_or(DVec3::ZERO);
        let depth = self.depths_m[i] + (self.depths_m[i + 1] - self.depths_m[i]) * u;
        (a.lerp(b, u), tangent, depth)
    }

    /// The closest point to `p` with arc length in `[from_m, to_m]`: its arc length and
    /// distance. Segments are visited once each (no allocation).
    pub fn closest_in(&self, p: DVec3, from_m: f64, to_m: f64) -> (f64, f64) {
        let last = self.points_m.len() - 2;
        let first_i = ((from_m.max(0.0) / self.spacing_m) as usize).min(last);
        let last_i = ((to_m.max(0.0) / self.spacing_m) as usize).min(last);
        let (lo, hi) = (from_m.max(0.0), to_m.min(self.length_m()));
        let mut best = (lo, f64::INFINITY);
        for i in first_i..=last_i {
            let (a, b) = (self.points_m[i], self.points_m[i + 1]);
            let ab = b - a;
            let len2 = ab.length_squared();
            let u = if len2 > 0.0 {
                ((p - a).dot(ab) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let s = (i as f64 * self.spacing_m + u * len2.sqrt()).clamp(lo, hi.max(lo));
            let (q, _, _) = self.at(s);
            let d = q.distance(p);
            if d < best.1 {
                best = (s, d);
            }
        }
        best
    }
}

/// What the guide did on one tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GuideOutput {
    /// The guiding force, world frame (to add before the safety stages).
    pub force_n: DVec3,
    /// The target on the path.
    pub target_m: DVec3,
    /// Arc length of the target over the path's length, 0 … 1.
    pub progress: f64,
    /// Distance from the tip to the target.
    pub distance_m: f64,
    /// Whether the pull is engaged (captured and not escaped).
    pub engaged: bool,
    /// The gain in force now: the fading gain times the ramp.
    pub effective_gain: f64,
    /// The fading gain this tick's force used.
    pub gain: f64,
    /// The guide's passivity controller damped this tick's pull.
    pub passivity_damping: bool,
    /// Passes along the path completed before this one.
    pub pass: u32,
}

impl GuideOutput {
    /// As the rest of the program sees it (the contact state, the wire, the recording).
    pub fn state(&self) -> GuideState {
        GuideState {
            force_n: self.force_n,
            target_m: self.target_m,
            progress: self.progress,
            gain: self.gain,
            effective_gain: self.effective_gain,
            engaged: self.engaged,
            pass: self.pass,
        }
        .finite()
    }
}

/// A trainee followed along one path.
#[derive(Debug, Clone)]
pub struct Guide {
    path: GuidePath,
    params: GuideParams,
    gain: f64,
    mode: GuideGain,
    /// Passes completed, and whether the current one has reached the path's end.
    pass: u32,
    pass_done: bool,
    /// Guidance as needed: time into the current window, and the engaged time and the
    /// distance integrated over it.
    window_s: f64,
    window_engaged_s: f64,
    window_error_m_s: f64,
    /// The energy balance of the pull alone (the contact books its own): what it has absorbed
    /// from the hand, with the energy its ramp stores credited. Its controller damps the pull
    /// when it would give back more than it took.
    observer: PassivityObserver,
    previous_tip_m: Option<DVec3>,
    previous_target_m: Option<DVec3>,
    previous_force_n: DVec3,
    /// The assist's part of last tick's force (it does work by design, and is credited).
    previous_assist_n: DVec3,
    previous_effective_gain: f64,
    /// Most damping the controller may add: the device's stable damping.
    max_damping_n_s_per_m: f64,
    target_s_m: f64,
    engaged: bool,
    ramp: f64,
    last_time_ns: Option<u64>,
}

impl Guide {
    pub fn new(path: GuidePath, params: GuideParams) -> Self {
        Self {
            path,
            params,
            gain: 1.0,
            mode: GuideGain::Fixed { gain: 1.0 },
            pass: 0,
            pass_done: false,
            window_s: 0.0,
            window_engaged_s: 0.0,
            window_error_m_s: 0.0,
            observer: PassivityObserver::new(),
            previous_tip_m: None,
            previous_target_m: None,
            previous_force_n: DVec3::ZERO,
            previous_assist_n: DVec3::ZERO,
            previous_effective_gain: 0.0,
            max_damping_n_s_per_m: DEFAULT_MAX_DAMPING_N_S_PER_M,
            target_s_m: 0.0,
            engaged: false,
            ramp: 0.0,
            last_time_ns: None,
        }
    }

    pub fn path(&self) -> &GuidePath {
        &self.path
    }

    /// The most damping the pull's passivity controller may add: the device's stable damping.
    pub fn set_max_damping(&mut self, damping_n_s_per_m: f64) {
        if damping_n_s_per_m.is_finite() && damping_n_s_per_m >= 0.0 {
            self.max_damping_n_s_per_m = damping_n_s_per_m;
        }
    }

    /// Forgets the motion history (a release, a restart, a broken reading).
    fn forget_motion(&mut self) {
        self.observer.reset();
        self.previous_tip_m = None;
        self.previous_target_m = None;
        self.previous_force_n = DVec3::ZERO;
        self.previous_assist_n = DVec3::ZERO;
        self.previous_effective_gain = 0.0;
    }

    /// How the gain is set from now on (its initial value at once).
    pub fn set_gain_mode(&mut self, mode: GuideGain) {
        self.set_gain(mode.initial());
        self.mode = mode;
        self.pass = 0;
        self.pass_done = false;
        self.window_s = 0.0;
        self.window_engaged_s = 0.0;
        self.window_error_m_s = 0.0;
    }

    /// The fading gain now.
    pub fn gain(&self) -> f64 {
        self.gain
    }

    /// The fading gain, 0 … 1 (a non-finite one is 0).
    pub fn set_gain(&mut self, gain: f64) {
        self.gain = if gain.is_finite() {
            gain.clamp(0.0, 1.0)
        } else {
            0.0
        };
    }

    /// Back to the start of the path, released (a new attempt).
    pub fn restart(&mut self) {
        self.target_s_m = 0.0;
        self.engaged = false;
        self.ramp = 0.0;
        self.last_time_ns = None;
        self.forget_motion();
    }

    /// Lets go at once (a device fault): the pull ramps in again from zero once the trainee is
    /// captured again, as the contact's force does after a fault.
    pub fn release(&mut self) {
        self.engaged = false;
        self.ramp = 0.0;
        self.last_time_ns = None;
        self.forget_motion();
    }

    /// One tick: the tip's position and velocity, the contact (outward normal and depth) when
    /// in contact, and the sample's device time.
    pub fn step(
        &mut self,
        tip_m: DVec3,
        velocity_m_s: DVec3,
        contact: Option<(DVec3, f64)>,
        time_ns: u64,
    ) -> GuideOutput {
        let p = self.params;
        let dt_s = match self.last_time_ns {
            Some(last) if time_ns > last => ((time_ns - last) as f64 * 1e-9).min(0.01),
            _ => 0.0,
        };
        self.last_time_ns = Some(time_ns);
        let length_m = self.path.length_m();
        if !(tip_m.is_finite() && velocity_m_s.is_finite()) {
            // No position to guide from: let go, smoothly on the next good tick.
            self.engaged = false;
            self.ramp = 0.0;
            self.forget_motion();
            let (target_m, _, _) = self.path.at(self.target_s_m);
            return GuideOutput {
                force_n: DVec3::ZERO,
                target_m,
                progress: self.target_s_m / length_m,
                distance_m: f64::INFINITY,
                engaged: false,
                effective_gain: 0.0,
                gain: self.gain,
                passivity_damping: false,
                pass: self.pass,
            };
        }
        // The target: near the previous one while engaged, anywhere until then.
        let (s_m, _) = if self.engaged {
            self.path.closest_in(
                tip_m,
                self.target_s_m - p.search_back_m,
                self.target_s_m + p.search_ahead_m,
            )
        } else {
            self.path.closest_in(tip_m, 0.0, length_m)
        };
        self.target_s_m = if self.engaged {
            s_m.min(self.target_s_m + p.max_target_speed_m_s * dt_s)
        } else {
            s_m
        };
        let (target_m, tangent, expert_depth_m) = self.path.at(self.target_s_m);
        let distance_m = target_m.distance(tip_m);
        if !self.engaged && distance_m <= p.capture_m {
            self.engaged = true;
        } else if self.engaged && distance_m > p.escape_m {
            self.engaged = false;
            if self.pass_done {
                // The trainee reached the end and has lifted away: the next pass, at its gain
                // (a schedule's next entry) from the next tick.
                self.pass_done = false;
                self.pass = self.pass.saturating_add(1);
                if matches!(self.mode, GuideGain::Schedule { .. }) {
                    self.set_gain(self.mode.for_pass(self.pass as usize));
                }
            }
        }
        if self.engaged && self.target_s_m >= length_m * PASS_END {
            self.pass_done = true;
        }
        let step = if p.ramp_s > 0.0 { dt_s / p.ramp_s } else { 1.0 };
        self.ramp = if self.engaged {
            (self.ramp + step).min(1.0)
        } else {
            (self.ramp - step).max(0.0)
        };
        let effective_gain = self.gain * self.ramp;
        // Book last tick's pull over the displacement the tip really made; the assist's work is
        // wanted (it pushes the trainee along), so it is credited rather than damped.
        if let (Some(previous), Some(previous_target)) =
            (self.previous_tip_m, self.previous_target_m)
        {
            let moved_m = tip_m - previous;
            self.observer.observe(self.previous_force_n, moved_m);
            self.observer.credit(self.previous_assist_n.dot(moved_m));
            // The target moving along the path is the expert's motion leading the hand: the
            // energy it puts into the spring (F·Δq) is the guidance itself, booked as given, so
            // the controller answers only what the sampling creates.
            self.observer
                .observe(-self.previous_force_n, target_m - previous_target);
        }
        // A rising gain stores the spring's energy at this distance without the hand's work,
        // as the contact's ramp does: credited, so the controller does not fight the ramp.
        if effective_gain > self.previous_effective_gain {
            self.observer.credit(
                (effective_gain - self.previous_effective_gain)
                    * 0.5
                    * p.stiffness_n_per_m
                    * distance_m
                    * distance_m,
            );
        }
        // Damped across the path's direction over a few millimetres around the target, not the
        // segment's own: at a corner the segment's turns at once, and so would the damping of a
        // tip moving through it (a step of b·v the hand feels).
        let (behind_m, _, _) = self.path.at(self.target_s_m - TANGENT_SPAN_M);
        let (ahead_m, _, _) = self.path.at(self.target_s_m + TANGENT_SPAN_M);
        let direction = (ahead_m - behind_m).try_normalize().unwrap_or(tangent);
        let across_v = velocity_m_s - direction * direction.dot(velocity_m_s);
        let mut force_n = (target_m - tip_m) * p.stiffness_n_per_m - across_v * p.damping_n_s_per_m;
        let mut assist_n = DVec3::ZERO;
        if self.target_s_m < length_m {
            assist_n = tangent * (p.assist_n * effective_gain);
            force_n += tangent * p.assist_n;
        }
        force_n *= effective_gain;
        let c = self
            .observer
            .correct(force_n, velocity_m_s, dt_s, self.max_damping_n_s_per_m);
        let passivity_damping = c.added_damping_n_s_per_m > 0.0;
        force_n = c.force_n;
        // Never deeper than the expert was here: no push inward once as deep.
        if let Some((normal, depth_m)) = contact
            && depth_m >= expert_depth_m
        {
            let inward = force_n.dot(normal);
            if inward < 0.0 {
                force_n -= normal * inward;
            }
        }
        let size = force_n.length();
        if size > p.max_force_n {
            force_n *= p.max_force_n / size;
        }
        if !force_n.is_finite() {
            force_n = DVec3::ZERO;
        }
        self.previous_tip_m = Some(tip_m);
        self.previous_target_m = Some(target_m);
        self.previous_force_n = force_n;
        self.previous_assist_n = assist_n;
        self.previous_effective_gain = effective_gain;
        let out = GuideOutput {
            force_n,
            target_m,
            progress: self.target_s_m / length_m,
            distance_m,
            engaged: self.engaged,
            effective_gain,
            gain: self.gain,
            passivity_damping,
            pass: self.pass,
        };
        self.fade(dt_s, distance_m);
        out
    }

    /// Guidance as needed: at the end of each window, g ← clamp(f·g + c·e, 0, 1), e the mean
    /// distance over the window's engaged ticks. A window with no engaged tick leaves g as it
    /// is: nothing was learned about the trainee.
    fn fade(&mut self, dt_s: f64, distance_m: f64) {
        let GuideGain::AsNeeded {
            forgetting,
            error_gain_per_m,
            window_s,
            ..
        } = self.mode
        else {
            return;
        };
        self.window_s += dt_s;
        if self.engaged && distance_m.is_finite() {
            self.window_engaged_s += dt_s;
            self.window_error_m_s += distance_m * dt_s;
        }
        if self.window_s >= window_s {
            if self.window_engaged_s > 0.0 {
                let e = self.window_error_m_s / self.window_engaged_s;
                self.set_gain(forgetting * self.gain + error_gain_per_m * e);
            }
            self.window_s = 0.0;
            self.window_engaged_s = 0.0;
            self.window_error_m_s = 0.0;
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    /// A straight 100 mm path along x at y = 0, 2 mm deep all along, every 1 mm.
    fn straight() -> GuidePath {
        GuidePath::resample(
            (0..=20).map(|i| (DVec3::new(0.005 * i as f64, 0.0, 0.0), 0.002)),
            0.001,
        )
        .unwrap()
    }

    #[test]
    fn a_path_is_resampled_evenly_along_its_length() {
        // Irregular samples along an L: 30 mm along x, then 40 mm along z; repeats add nothing.
        let raw = [
            DVec3::ZERO,
            DVec3::ZERO,
            DVec3::new(0.007, 0.0, 0.0),
            DVec3::new(0.03, 0.0, 0.0),
            DVec3::new(0.03, 0.0, 0.011),
            DVec3::new(0.03, 0.0, 0.04),
        ];
        let path = GuidePath::resample(raw.iter().map(|p| (*p, 0.0)), 0.002).unwrap();
        assert!((path.length_m() - 0.07).abs() < 1e-12);
        // 0, 2, …, 70 mm: 36 points, 2 mm apart along the path.
        assert_eq!(path.points_m().len(), 36);
        assert!(path.points_m()[15].distance(DVec3::new(0.03, 0.0, 0.0)) < 1e-12);
        assert!(path.points_m()[35].distance(DVec3::new(0.03, 0.0, 0.04)) < 1e-12);
        for w in path.points_m()[..16].windows(2) {
            assert!((w[0].distance(w[1]) - 0.002).abs() < 1e-12);
        }
        assert!(matches!(
            GuidePath::resample([(DVec3::ZERO, 0.0), (DVec3::X * 0.001, 0.0)], 0.001),
            Err(GuideError::TooShort { .. })
        ));
        assert!(matches!(
            GuidePath::resample([(DVec3::ZERO, 0.0), (DVec3::NAN, 0.0)], 0.001),
            Err(GuideError::NonFinite(1))
        ));
    }

    #[test]
    fn the_pull_engages_within_capture_ramps_in_is_capped_and_lets_go_beyond_escape() {
        let params = GuideParams::default();
        let mut g = Guide::new(straight(), params);
        // 20 mm off the path: beyond capture, nothing.
        let off = DVec3::new(0.05, 0.02, 0.0);
        let out = g.step(off, DVec3::ZERO, None, 0);
        assert!(!out.engaged && out.force_n == DVec3::ZERO);
        // 10 mm off: captured; the force ramps in over 0.2 s toward the path, never jumping.
        let near = DVec3::new(0.05, 0.01, 0.0);
        let mut previous = DVec3::ZERO;
        for t in 1..=300u64 {
            let out = g.step(near, DVec3::ZERO, None, t * MS);
            assert!(out.engaged);
            assert!((out.force_n - previous).length() <= 1.5 * 0.001 / 0.2 + 1e-12);
            previous = out.force_n;
        }
        // Full gain: k × 10 mm = 1.5 N, exactly the cap, straight down to the path.
        assert!((previous - DVec3::new(0.0, -1.5, 0.0)).length() < 1e-9);
        // 25 mm off (inside escape): still pulled, at the cap.
        let out = g.step(DVec3::new(0.05, 0.025, 0.0), DVec3::ZERO, None, 301 * MS);
        assert!(out.engaged && (out.force_n.length() - 1.5).abs() < 1e-9);
        // 35 mm off: let go; the pull ramps out over 0.2 s (held at the cap meanwhile, as the
        // spring is stretched far beyond it), then nothing.
        let away = DVec3::new(0.05, 0.035, 0.0);
        let out = g.step(away, DVec3::ZERO, None, 302 * MS);
        assert!(!out.engaged);
        assert!(out.effective_gain < 1.0 && out.effective_gain > 0.99);
        for t in 303..=502u64 {
            let out = g.step(away, DVec3::ZERO, None, t * MS);
            assert!(out.force_n.length() <= 1.5 + 1e-12);
        }
        assert_eq!(
            g.step(away, DVec3::ZERO, None, 503 * MS).force_n,
            DVec3::ZERO
        );
        // At gain 0 nothing pulls, engaged or not.
        g.set_gain(0.0);
        let out = g.step(near, DVec3::ZERO, None, 504 * MS);
        assert_eq!(out.force_n, DVec3::ZERO);
    }

    #[test]
    fn a_path_that_crosses_itself_does_not_make_the_target_jump() {
        // Out along x for 40 mm, up 20 mm in z, back along x at z = 20 mm, then down across the
        // first leg at x = 20 mm: the path crosses itself there.
        let corners = [
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(0.04, 0.0, 0.0),
            DVec3::new(0.04, 0.0, 0.02),
            DVec3::new(0.02, 0.0, 0.02),
            DVec3::new(0.02, 0.0, -0.02),
        ];
        let path = GuidePath::resample(corners.iter().map(|p| (*p, 0.0)), 0.001).unwrap();
        let mut g = Guide::new(path, GuideParams::default());
        // The trainee walks the first leg at 0.1 m/s, through the crossing at x = 20 mm.
        let mut at_crossing = None;
        for t in 0..=300u64 {
            let x = 0.1 * t as f64 * 1e-3;
            let out = g.step(
                DVec3::new(x, 0.0, 0.0),
                DVec3::new(0.1, 0.0, 0.0),
                None,
                t * MS,
            );
            if t == 200 {
                at_crossing = Some(out);
            }
        }
        // At the crossing the target is on the first leg (20 mm along), not the last (120 mm).
        let out = at_crossing.unwrap();
        // (40 + 20 + 20 + 40 mm.)
        assert!((g.path().length_m() - 0.12).abs() < 1e-12);
        assert!((out.progress * 0.12 - 0.02).abs() < 0.002, "{out:?}");
    }

    #[test]
    fn the_guide_never_pushes_deeper_than_the_expert_went() {
        let mut g = Guide::new(straight(), GuideParams::default());
        let up = DVec3::Y;
        // The target is 5 mm below the tip (the path at y = 0, the tip at y = 5 mm)...
        let tip = DVec3::new(0.05, 0.005, 0.0);
        for t in 0..300u64 {
            g.step(tip, DVec3::ZERO, Some((up, 0.001)), t * MS);
        }
        // ...shallower than the expert's 2 mm: pulled in.
        let out = g.step(tip, DVec3::ZERO, Some((up, 0.001)), 300 * MS);
        assert!(out.force_n.y < -0.5, "{out:?}");
        // As deep as the expert: no inward part left.
        let out = g.step(tip, DVec3::ZERO, Some((up, 0.002)), 301 * MS);
        assert!(out.force_n.y >= 0.0, "{out:?}");
    }

    /// A light hand held loosely toward `aim`, pulled by the guide: where it ends up.
    fn follow(gain: f64) -> f64 {
        let mut g = Guide::new(straight(), GuideParams::default());
        g.set_gain(gain);
        // The hand means to go along the path but drifts 12 mm to the side (+z), softly held.
        let (mass, grip, damping) = (0.1, 40.0, 4.0);
        let mut p = DVec3::ZERO;
        let mut v = DVec3::ZERO;
        let mut worst = 0.0_f64;
        for t in 0..1000u64 {
            let time_s = t as f64 * 1e-3;
            let aim = DVec3::new(0.09 * time_s, 0.0, 0.012 * (time_s * 4.0).min(1.0));
            let out = g.step(p, v, None, t * MS);
            let force = grip * (aim - p) - damping * v + out.force_n;
            v += force / mass * 1e-3;
            p += v * 1e-3;
            if t > 500 {
                worst = worst.max(p.z.abs());
            }
        }
        worst
    }

    #[test]
    fn a_yielding_hand_follows_the_path_at_full_gain_and_drifts_at_none() {
        let free = follow(0.0);
        let guided = follow(1.0);
        // Unguided it drifts the whole 12 mm; guided, k = 150 N/m against a 40 N/m grip holds
        // it to about 12 × 40 / 190 ≈ 2.5 mm.
        assert!((free - 0.012).abs() < 5e-4, "{free}");
        assert!(guided < 0.003, "{guided}");
    }

    /// The gain after holding the tip `off_m` to the side of the straight path for `seconds`.
    fn held_off(off_m: f64, seconds: f64) -> (f64, Vec<f64>) {
        let mut guide = Guide::new(straight(), GuideParams::default());
        guide.set_gain_mode(GuideGain::AS_NEEDED);
        let mut gains = Vec::new();
        for t in 0..(seconds * 1000.0) as u64 {
            let out = guide.step(DVec3::new(0.05, off_m, 0.0), DVec3::ZERO, None, t * MS);
            gains.push(out.gain);
        }
        (guide.gain(), gains)
    }

    #[test]
    fn guidance_as_needed_settles_where_the_trainees_error_puts_it() {
        // f = 0.9, c = 10 /m, a window of 0.5 s: g settles at c·e/(1 − f) = 100·e.
        let (near, gains) = held_off(0.002, 40.0);
        assert!((near - 0.2).abs() < 0.002, "{near}");
        // It falls step by step, once a window, never rising while the error is steady.
        assert!(gains.windows(2).all(|w| w[1] <= w[0]));
        assert_eq!(gains[0], 1.0);
        let (far, _) = held_off(0.012, 20.0);
        assert_eq!(far, 1.0, "a 12 mm error keeps the full pull");
    }

    #[test]
    fn a_recorded_path_comes_back_exactly_and_a_forged_one_is_refused() {
        let path = straight();
        let recorded = RecordedGuide {
            source: "expert.mcap".into(),
            source_scene: None,
            points_m: path.points_m().iter().map(|p| p.to_array()).collect(),
            depths_m: path.depths_m().to_vec(),
            forces_n: Some(path.forces_n().to_vec()),
            spacing_m: path.spacing_m(),
            params: GuideParams::default(),
            gain: GuideGain::default(),
        };
        assert_eq!(GuidePath::from_recorded(&recorded).unwrap(), path);
        let mut gap = recorded.clone();
        gap.points_m[10][0] += 0.0015;
        assert!(matches!(
            GuidePath::from_recorded(&gap),
            Err(GuideError::Inconsistent(_))
        ));
        let mut short = recorded.clone();
        short.depths_m.pop();
        assert!(GuidePath::from_recorded(&short).is_err());
        // A path longer than the bound is refused before it is built.
        let long = GuidePath::resample(
            [(DVec3::ZERO, 0.0), (DVec3::new(100.0, 0.0, 0.0), 0.0)],
            0.001,
        );
        assert!(matches!(long, Err(GuideError::TooLong { .. })), "{long:?}");
    }

    #[test]
    fn a_schedule_sets_each_pass_gain_and_a_pass_ends_at_the_end_once_let_go() {
        let mut guide = Guide::new(straight(), GuideParams::default());
        guide.set_gain_mode(GuideGain::Schedule {
            gains: vec![1.0, 0.5, 0.0],
        });
        let mut t = 0;
        let mut passes_and_gains = Vec::new();
        // Along the 100 mm path at 0.1 m/s, then 50 mm up and away, then back to its start.
        let mut run = |guide: &mut Guide, from: DVec3, to: DVec3, ticks: u64| {
            for k in 0..ticks {
                let p = from.lerp(to, k as f64 / ticks as f64);
                let out = guide.step(p, (to - from) / (ticks as f64 * 1e-3), None, t * MS);
                t += 1;
                if passes_and_gains.last() != Some(&(out.pass, out.gain)) {
                    passes_and_gains.push((out.pass, out.gain));
                }
            }
        };
        let (start, end) = (DVec3::ZERO, DVec3::new(0.1, 0.0, 0.0));
        let away = DVec3::new(0.1, 0.05, 0.0);
        for _ in 0..3 {
            run(&mut guide, start, end, 1000);
            run(&mut guide, end, away, 200);
            run(&mut guide, away, start, 500);
        }
        assert_eq!(passes_and_gains, [(0, 1.0), (1, 0.5), (2, 0.0), (3, 0.0)]);
        // A fault's release is not the end of a pass.
        let mut guide = Guide::new(straight(), GuideParams::default());
        guide.set_gain_mode(GuideGain::Schedule {
            gains: vec![1.0, 0.5],
        });
        let out = guide.step(DVec3::new(0.099, 0.0, 0.0), DVec3::ZERO, None, 0);
        assert!(out.engaged);
        let out = guide.step(DVec3::new(0.1, 0.0, 0.0), DVec3::ZERO, None, MS);
        assert!(out.progress >= 0.98);
        guide.release();
        let out = guide.step(DVec3::new(0.1, 0.0, 0.0), DVec3::ZERO, None, 2 * MS);
        assert_eq!((out.pass, out.gain), (0, 1.0));
    }
}
