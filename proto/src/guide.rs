//! Haptic guidance from an expert's recording: how the pull is tuned, how its gain fades, what
//! each tick's guidance was, and the path as a recording keeps it and a viewer draws it.
//!
//! The device crate's `guide` module computes the pull; these are the values that cross to the
//! rest of the program: [`GuideParams`] and [`GuideGain`] configure it, [`GuideState`] is one
//! tick's result (in the [`crate::ContactState`], the `contact` frame and the recording's device
//! channel), [`RecordedGuide`] is the resampled path a session ran with (so a check rebuilds the
//! same pull without the expert's file) and [`GuidePathInfo`] is the path as the viewers get it
//! in the `scene` message.

use glam::DVec3;
use serde::{Deserialize, Serialize};

/// How the guide pulls. Every field is a finite, non-negative number
/// ([`GuideParams::validate`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
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

impl GuideParams {
    /// The first field that is not a finite, non-negative number, or an escape distance inside
    /// the capture distance: (its name, its value).
    pub fn validate(&self) -> Result<(), (&'static str, f64)> {
        let fields = [
            ("stiffness_n_per_m", self.stiffness_n_per_m),
            ("damping_n_s_per_m", self.damping_n_s_per_m),
            ("max_force_n", self.max_force_n),
            ("capture_m", self.capture_m),
            ("escape_m", self.escape_m),
            ("search_back_m", self.search_back_m),
            ("search_ahead_m", self.search_ahead_m),
            ("max_target_speed_m_s", self.max_target_speed_m_s),
            ("assist_n", self.assist_n),
            ("ramp_s", self.ramp_s),
        ];
        if let Some(bad) = fields.iter().find(|(_, v)| !(v.is_finite() && *v >= 0.0)) {
            return Err(*bad);
        }
        if self.escape_m < self.capture_m {
            return Err(("escape_m", self.escape_m));
        }
        Ok(())
    }
}

/// Most gains a schedule lists.
pub const MAX_SCHEDULED_PASSES: usize = 100;

/// How the guidance's gain is set while a session runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "mode", rename_all = "snake_case", deny_unknown_fields)]
pub enum GuideGain {
    /// One gain, 0 … 1, for the whole session.
    Fixed { gain: f64 },
    /// Guidance as needed: after each window of `window_s` the gain becomes
    /// clamp(f·g + c·e, 0, 1), e the mean distance from the path over the window's engaged
    /// ticks, f the forgetting factor and c the error gain (1/m); it starts at `initial`. A
    /// trainee who keeps to the path is let go of gradually; one who strays is held again.
    AsNeeded {
        initial: f64,
        forgetting: f64,
        error_gain_per_m: f64,
        window_s: f64,
    },
    /// A gain per pass along the path, in order; the last holds for the passes after it. A
    /// pass ends when the trainee, captured, reaches the path's end; the next begins when the
    /// pull next lets go (the trainee lifts away to start again).
    Schedule { gains: Vec<f64> },
}

impl Default for GuideGain {
    fn default() -> Self {
        GuideGain::Fixed { gain: 1.0 }
    }
}

impl GuideGain {
    /// Guidance as needed with the usual constants: starts at full gain, forgets 10 % a half
    /// second, and settles at g = c·e/(1 − f) = 1 for a 10 mm error (0.2 for 2 mm).
    pub const AS_NEEDED: GuideGain = GuideGain::AsNeeded {
        initial: 1.0,
        forgetting: 0.9,
        error_gain_per_m: 10.0,
        window_s: 0.5,
    };

    /// The gain the session starts with.
    pub fn initial(&self) -> f64 {
        self.for_pass(0)
    }

    /// The gain of pass `pass` (from 0): a schedule's entry, the last for later passes; the
    /// initial gain otherwise (guidance as needed moves on from it by itself).
    pub fn for_pass(&self, pass: usize) -> f64 {
        match self {
            GuideGain::Fixed { gain } => *gain,
            GuideGain::AsNeeded { initial, .. } => *initial,
            GuideGain::Schedule { gains } => {
                gains.get(pass).or(gains.last()).copied().unwrap_or(0.0)
            }
        }
    }

    /// The first field that is out of its range: (its name, its value).
    pub fn validate(&self) -> Result<(), (&'static str, f64)> {
        let unit = |name: &'static str, v: f64| {
            if (0.0..=1.0).contains(&v) {
                Ok(())
            } else {
                Err((name, v))
            }
        };
        match *self {
            GuideGain::Schedule { ref gains } => {
                if gains.is_empty() || gains.len() > MAX_SCHEDULED_PASSES {
                    return Err(("gains", gains.len() as f64));
                }
                gains.iter().try_for_each(|g| unit("gains", *g))
            }
            GuideGain::Fixed { gain } => unit("gain", gain),
            GuideGain::AsNeeded {
                initial,
                forgetting,
                error_gain_per_m,
                window_s,
            } => {
                unit("initial", initial)?;
                unit("forgetting", forgetting)?;
                if !(error_gain_per_m.is_finite() && error_gain_per_m >= 0.0) {
                    return Err(("error_gain_per_m", error_gain_per_m));
                }
                if !(window_s.is_finite() && window_s > 0.0) {
                    return Err(("window_s", window_s));
                }
                Ok(())
            }
        }
    }
}

/// One tick's guidance: what the pull did, in the world frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GuideState {
    /// The guiding force, N, as added before the safety stages (the commanded `force_n`
    /// includes it).
    pub force_n: DVec3,
    /// The target on the expert's path: where the expert's tool was.
    pub target_m: DVec3,
    /// Arc length of the target over the path's length, 0 … 1.
    pub progress: f64,
    /// The fading gain, 0 … 1.
    pub gain: f64,
    /// The gain in force now: the fading gain times the engage/release ramp.
    pub effective_gain: f64,
    /// Whether the trainee is captured (within the capture distance, not yet escaped).
    pub engaged: bool,
    /// Passes along the path completed before this one (0 in the first). Absent in recordings
    /// made before passes were counted: 0.
    #[serde(default)]
    pub pass: u32,
}

impl GuideState {
    /// The same state with every non-finite number made 0, so that it always encodes to JSON
    /// numbers (the guide never produces one; the wire must stay valid whatever happens).
    pub fn finite(self) -> Self {
        let f = |x: f64| if x.is_finite() { x } else { 0.0 };
        let v = |d: DVec3| DVec3::new(f(d.x), f(d.y), f(d.z));
        GuideState {
            force_n: v(self.force_n),
            target_m: v(self.target_m),
            progress: f(self.progress),
            gain: f(self.gain),
            effective_gain: f(self.effective_gain),
            engaged: self.engaged,
            pass: self.pass,
        }
    }
}

/// Most points of a guide path a scene or recording holds: 20 m at 1 mm.
pub const MAX_GUIDE_POINTS: usize = 20_000;

/// The expert's path as a session ran with it: the resampled points and the expert's depth at
/// each, exactly, with the pull's settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordedGuide {
    /// The expert's recording, by file name (where it was is not kept).
    pub source: String,
    /// The expert's scene file as that recording names it, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source_scene: Option<String>,
    pub points_m: Vec<[f64; 3]>,
    pub depths_m: Vec<f64>,
    /// The size of the expert's force at each point, N, to compare the trainee's with
    /// (absent: not known).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub forces_n: Option<Vec<f64>>,
    pub spacing_m: f64,
    pub params: GuideParams,
    pub gain: GuideGain,
}

/// Most points of the path the viewers get: they draw it, and need no more.
pub const MAX_DRAWN_GUIDE_POINTS: usize = 2_000;

/// The guide as the viewers get it in the `scene` message: the path to draw (evenly thinned to
/// at most [`MAX_DRAWN_GUIDE_POINTS`], its ends kept), its length, and how the pull is set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GuidePathInfo {
    /// The expert's recording, by file name.
    pub source: String,
    /// World frame, in the expert's order; evenly spaced along the path, so a frame's
    /// `progress` × (n − 1) is the index of its target.
    pub path_m: Vec<DVec3>,
    pub length_m: f64,
    pub max_force_n: f64,
    pub gain: GuideGain,
}

impl GuidePathInfo {
    /// The drawn path of a recorded guide.
    pub fn from_recorded(guide: &RecordedGuide) -> Self {
        let n = guide.points_m.len();
        let path_m = if n <= MAX_DRAWN_GUIDE_POINTS {
            guide
                .points_m
                .iter()
                .map(|p| DVec3::from_array(*p))
                .collect()
        } else {
            let last = MAX_DRAWN_GUIDE_POINTS - 1;
            (0..=last)
                .map(|i| DVec3::from_array(guide.points_m[i * (n - 1) / last]))
                .collect()
        };
        let length_m = guide.spacing_m * n.saturating_sub(2) as f64
            + match guide.points_m.as_slice() {
                [.., a, b] => DVec3::from_array(*a).distance(DVec3::from_array(*b)),
                _ => 0.0,
            };
        GuidePathInfo {
            source: guide.source.clone(),
            path_m,
            length_m,
            max_force_n: guide.params.max_force_n,
            gain: guide.gain.clone(),
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn settings_out_of_range_are_named() {
        assert_eq!(GuideParams::default().validate(), Ok(()));
        let p = GuideParams {
            max_force_n: f64::NAN,
            ..GuideParams::default()
        };
        assert_eq!(p.validate().unwrap_err().0, "max_force_n");
        let p = GuideParams {
            escape_m: 0.01,
            ..GuideParams::default()
        };
        assert_eq!(p.validate(), Err(("escape_m", 0.01)));
        assert_eq!(GuideGain::AS_NEEDED.validate(), Ok(()));
        assert_eq!(
            GuideGain::Fixed { gain: 1.5 }.validate(),
            Err(("gain", 1.5))
        );
        let g = GuideGain::AsNeeded {
            initial: 1.0,
            forgetting: 0.9,
            error_gain_per_m: 10.0,
            window_s: 0.0,
        };
        assert_eq!(g.validate(), Err(("window_s", 0.0)));
    }

    #[test]
    fn the_drawn_path_is_thinned_evenly_and_keeps_both_ends() {
        let n = 5_001;
        let guide = RecordedGuide {
            source: "expert.mcap".into(),
            source_scene: None,
            points_m: (0..n).map(|i| [i as f64 * 0.001, 0.0, 0.0]).collect(),
            depths_m: vec![0.0; n],
            forces_n: None,
            spacing_m: 0.001,
            params: GuideParams::default(),
            gain: GuideGain::default(),
        };
        let info = GuidePathInfo::from_recorded(&guide);
        assert_eq!(info.path_m.len(), MAX_DRAWN_GUIDE_POINTS);
        assert_eq!(info.path_m[0], DVec3::ZERO);
        assert_eq!(info.path_m.last().unwrap().x, 5.0);
        assert!((info.length_m - 5.0).abs() < 1e-9);
        let text = serde_json::to_string(&guide).unwrap();
        assert_eq!(serde_json::from_str::<RecordedGuide>(&text).unwrap(), guide);
    }
}
