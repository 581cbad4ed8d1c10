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
//! [`Fading`] sets the gain across attempts: a schedule (a gain per attempt), or guidance as
//! needed, whose gain follows the trainee's error with a forgetting factor (g ← f·g + c·e).
//!
//! Allocation-free per tick; the path is built once.

use glam::DVec3;

/// Why a path cannot guide.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GuideError {
    #[error("the expert's path is {length_m:.4} m long: too short to guide (at least {min_m} m)")]
    TooShort { length_m: f64, min_m: f64 },
    #[error("the spacing must be finite and positive, got {0}")]
    Spacing(f64),
    #[error("the expert's path has a non-finite point (sample {0})")]
    NonFinite(usize),
}

/// The expert's path, resampled every `spacing_m` of its length.
#[derive(Debug, Clone, PartialEq)]
pub struct GuidePath {
    points_m: Vec<DVec3>,
    /// The expert's contact depth at each point (0 where free).
    depths_m: Vec<f64>,
    spacing_m: f64,
}

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
        if !(spacing_m.is_finite() && spacing_m > 0.0) {
            return Err(GuideError::Spacing(spacing_m));
        }
        let mut points_m = Vec::new();
        let mut depths_m = Vec::new();
        // Arc length to the next point to place, from the previous sample.
        let mut previous: Option<(DVec3, f64)> = None;
        let mut to_next_m = 0.0;
        let mut length_m = 0.0;
        for (i, (p, depth)) in samples.into_iter().enumerate() {
            if !p.is_finite() {
                return Err(GuideError::NonFinite(i));
            }
            let depth = if depth.is_finite() {
                depth.max(0.0)
            } else {
                0.0
            };
            let Some((a, depth_a)) = previous else {
                points_m.push(p);
                depths_m.push(depth);
                previous = Some((p, depth));
                to_next_m = spacing_m;
                continue;
            };
            let segment_m = a.distance(p);
            let mut along_m = to_next_m;
            while along_m <= segment_m {
                let u = along_m / segment_m;
                points_m.push(a.lerp(p, u));
                depths_m.push(depth_a + (depth - depth_a) * u);
                along_m += spacing_m;
            }
            to_next_m = along_m - segment_m;
            length_m += segment_m;
            previous = Some((p, depth));
        }
        // The end itself, unless the last point placed is on it.
        if let Some((end, depth)) = previous
            && points_m
                .last()
                .is_some_and(|last| last.distance(end) > 1e-9)
        {
            points_m.push(end);
            depths_m.push(depth);
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
            spacing_m,
        })
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

/// How the guide pulls.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GuideParams {
    /// k, N/m.
    pub stiffness_n_per_m: f64,
    /// b across the path, N·s/m.
    pub damping_n_s_per_m: f64,
    /// The guide's own cap, N (below the device's peak: the contact's force has room).
    pub max_force_n: f64,
    /// The pull engages within this distance of the path...
    pub capture_m: f64,
    /// ...and releases beyond this one (larger: hysteresis).
    pub escape_m: f64,
    /// The target is searched from this far behind the previous one...
    pub search_back_m: f64,
    /// ...to this far ahead of it.
    pub search_ahead_m: f64,
    /// Fastest the target advances along the path.
    pub max_target_speed_m_s: f64,
    /// An extra push along the path's tangent, N (0: none).
    pub assist_n: f64,
    /// Time to engage or release fully, s.
    pub ramp_s: f64,
}

impl Default for GuideParams {
    /// A gentle pull: 150 N/m, 2 N·s/m across, 1.5 N at most; captured within 15 mm, let go
    /// beyond 30 mm; a 0.2 s ramp; the target searched 5 mm back and 10 mm ahead and moving at
    /// most 0.2 m/s; no assist.
    fn default() -> Self {
        Self {
            stiffness_n_per_m: 150.0,
            damping_n_s_per_m: 2.0,
            max_force_n: 1.5,
            capture_m: 0.015,
            escape_m: 0.03,
            search_back_m: 0.005,
            search_ahead_m: 0.01,
            max_target_speed_m_s: 0.2,
            assist_n: 0.0,
            ramp_s: 0.2,
        }
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
}

/// A trainee followed along one path.
#[derive(Debug, Clone)]
pub struct Guide {
    path: GuidePath,
    params: GuideParams,
    gain: f64,
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
            target_s_m: 0.0,
            engaged: false,
            ramp: 0.0,
            last_time_ns: None,
        }
    }

    pub fn path(&self) -> &GuidePath {
        &self.path
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
    }

    /// Lets go at once (a device fault): the pull ramps in again from zero once the trainee is
    /// captured again, as the contact's force does after a fault.
    pub fn release(&mut self) {
        self.engaged = false;
        self.ramp = 0.0;
        self.last_time_ns = None;
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
            let (target_m, _, _) = self.path.at(self.target_s_m);
            return GuideOutput {
                force_n: DVec3::ZERO,
                target_m,
                progress: self.target_s_m / length_m,
                distance_m: f64::INFINITY,
                engaged: false,
                effective_gain: 0.0,
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
        }
        let step = if p.ramp_s > 0.0 { dt_s / p.ramp_s } else { 1.0 };
        self.ramp = if self.engaged {
            (self.ramp + step).min(1.0)
        } else {
            (self.ramp - step).max(0.0)
        };
        let effective_gain = self.gain * self.ramp;
        let across_v = velocity_m_s - tangent * tangent.dot(velocity_m_s);
        let mut force_n = (target_m - tip_m) * p.stiffness_n_per_m - across_v * p.damping_n_s_per_m;
        if self.target_s_m < length_m {
            force_n += tangent * p.assist_n;
        }
        force_n *= effective_gain;
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
        GuideOutput {
            force_n,
            target_m,
            progress: self.target_s_m / length_m,
            distance_m,
            engaged: self.engaged,
            effective_gain,
        }
    }
}

/// The gain across attempts.
#[derive(Debug, Clone, PartialEq)]
pub enum Fading {
    /// A gain per attempt, in order; the last one holds for the attempts after it.
    Schedule(Vec<f64>),
    /// Guidance as needed: g₀ = `initial`, then g ← clamp(f·g + c·e, 0, 1) after each attempt,
    /// e its mean distance from the path (m), f the forgetting factor, c the error gain (1/m).
    AsNeeded {
        initial: f64,
        forgetting: f64,
        error_gain_per_m: f64,
    },
}

impl Fading {
    /// The gain of attempt `attempt` (from 0), given the mean errors of the attempts before it.
    pub fn gain(&self, attempt: usize, earlier_errors_m: &[f64]) -> f64 {
        let g = match self {
            Fading::Schedule(gains) => match gains.get(attempt).or(gains.last()) {
                Some(g) => *g,
                None => 0.0,
            },
            Fading::AsNeeded {
                initial,
                forgetting,
                error_gain_per_m,
            } => earlier_errors_m
                .iter()
                .take(attempt)
                .fold(*initial, |g, e| {
                    (forgetting * g + error_gain_per_m * e.max(0.0)).clamp(0.0, 1.0)
                }),
        };
        if g.is_finite() {
            g.clamp(0.0, 1.0)
        } else {
            0.0
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

    #[test]
    fn fading_follows_its_schedule_or_the_trainees_error() {
        let schedule = Fading::Schedule(vec![1.0, 0.6, 0.3]);
        let gains: Vec<f64> = (0..5).map(|a| schedule.gain(a, &[])).collect();
        assert_eq!(gains, [1.0, 0.6, 0.3, 0.3, 0.3]);
        // As needed: f = 0.5, c = 50 /m; errors of 10, 6, 2 and 1 mm.
        let as_needed = Fading::AsNeeded {
            initial: 1.0,
            forgetting: 0.5,
            error_gain_per_m: 50.0,
        };
        let errors = [0.010, 0.006, 0.002, 0.001];
        let gains: Vec<f64> = (0..5).map(|a| as_needed.gain(a, &errors)).collect();
        // 1; 0.5 + 0.5 = 1 (clamped); 0.5 + 0.3 = 0.8; 0.4 + 0.1 = 0.5; 0.25 + 0.05 = 0.3.
        let expected = [1.0, 1.0, 0.8, 0.5, 0.3];
        for (g, e) in gains.iter().zip(expected) {
            assert!((g - e).abs() < 1e-12, "{gains:?}");
        }
    }
}
