//! A recording as a guide: the expert's tool path, resampled, for a trainee's session to pull
//! along (`softhaptic run --guide EXPERT.mcap`).
//!
//! Any recording guides: a live session's, a shipped one, an archived one. It must have been
//! made with this session's object and tool, or the path would lead through another shape; the
//! first field that differs is named ([`GuideLoadError::OtherScene`]). The path is the tip's
//! position at every recorded tick with a reading, resampled every [`GUIDE_SPACING_M`], with
//! the expert's contact depth at each point (the guide never pushes deeper).

use std::path::{Path, PathBuf};

use glam::DVec3;
use softhaptic_device::deviation::{Deviation, deviation};
use softhaptic_device::guide::{GuideError, GuidePath};
use softhaptic_proto::guide::{GuideGain, GuideParams, RecordedGuide};
use softhaptic_proto::wire::SceneMessage;

use crate::SessionError;
use crate::reader::Recording;
use crate::scene::Scene;

/// Spacing of the resampled path: finer than a hand's tremor matters, coarse enough that a
/// minute's path is tens of thousands of points at most.
pub const GUIDE_SPACING_M: f64 = 0.001;

/// Position differences below this are the same placement (a file's rounding).
const SAME_M: f64 = 1e-9;

/// Why a recording cannot guide this session.
#[derive(Debug, thiserror::Error)]
pub enum GuideLoadError {
    #[error("--guide {path}: {source}")]
    Read {
        path: PathBuf,
        #[source]
        source: Box<SessionError>,
    },
    #[error(
        "--guide {path}: recorded with another {what}: {field} is {expert} in the expert's recording and {here} in this session's scene; record the expert with this scene"
    )]
    OtherScene {
        path: PathBuf,
        what: &'static str,
        field: String,
        expert: String,
        here: String,
    },
    #[error("--guide {path}: the expert's path cannot guide: {source}")]
    Path {
        path: PathBuf,
        #[source]
        source: GuideError,
    },
    #[error("--guide {path}: {reason}")]
    Settings { path: PathBuf, reason: String },
}

/// The guide `path`'s recording makes for `scene`, pulling with `params` and `gain`.
pub fn guide_from_file(
    path: &Path,
    scene: &Scene,
    params: GuideParams,
    gain: GuideGain,
) -> Result<RecordedGuide, GuideLoadError> {
    let recording = Recording::open(path).map_err(|e| GuideLoadError::Read {
        path: path.to_owned(),
        source: Box::new(e),
    })?;
    guide_from_recording(&recording, scene, params, gain)
}

/// [`guide_from_file`] for a recording already read.
pub fn guide_from_recording(
    recording: &Recording,
    scene: &Scene,
    params: GuideParams,
    gain: GuideGain,
) -> Result<RecordedGuide, GuideLoadError> {
    let path = recording.path.clone();
    same_placement(&recording.scene.message, &scene.message(), &path)?;
    if let (Some(expert), Some(here)) = (&recording.scene.meshes, scene.recorded_meshes())
        && expert.haptic.sha256 != here.haptic.sha256
    {
        return Err(GuideLoadError::OtherScene {
            path,
            what: "object",
            field: "the haptic mesh's SHA-256".into(),
            expert: expert.haptic.sha256.clone(),
            here: here.haptic.sha256,
        });
    }
    let samples = recording.device.iter().filter_map(|r| {
        let s = r.sample.as_ref()?;
        let depth_m = if r.in_contact { r.depth_m } else { 0.0 };
        let force_n = DVec3::from_array(r.force_n).length();
        Some((DVec3::from_array(s.tip_position_m), depth_m, force_n))
    });
    let resampled =
        GuidePath::resample_with_forces(samples, GUIDE_SPACING_M).map_err(|source| {
            GuideLoadError::Path {
                path: path.clone(),
                source,
            }
        })?;
    let guide = RecordedGuide {
        source: recording.file_name(),
        source_scene: recording.scene.scene_file.as_deref().map(|f| {
            Path::new(f)
                .file_name()
                .map_or_else(|| f.to_owned(), |n| n.to_string_lossy().into_owned())
        }),
        points_m: resampled.points_m().iter().map(|p| p.to_array()).collect(),
        depths_m: resampled.depths_m().to_vec(),
        forces_n: Some(resampled.forces_n().to_vec()),
        spacing_m: resampled.spacing_m(),
        params,
        gain,
    };
    // The same checks a recording of this session will meet when it is checked or replayed.
    let mut trial = scene.clone();
    trial
        .set_guide(guide.clone())
        .map_err(|reason| GuideLoadError::Settings {
            path: path.clone(),
            reason,
        })?;
    Ok(guide)
}

/// The object and the tool, as each session's `scene` message states them.
fn same_placement(
    expert: &SceneMessage,
    here: &SceneMessage,
    path: &Path,
) -> Result<(), GuideLoadError> {
    let differs = |what: &'static str, field: &str, expert: String, here: String| {
        Err(GuideLoadError::OtherScene {
            path: path.to_owned(),
            what,
            field: field.to_owned(),
            expert,
            here,
        })
    };
    let tool = |m: &SceneMessage| serde_json::to_value(m.tool).unwrap_or_default();
    let (tool_expert, tool_here) = (tool(expert), tool(here));
    if tool_expert != tool_here {
        // The first field of the tool's own description that differs.
        let field = ["shape", "radius_m", "half_angle_rad"]
            .into_iter()
            .find(|f| tool_expert.get(f) != tool_here.get(f))
            .unwrap_or("shape");
        let show = |v: &serde_json::Value| {
            v.get(field)
                .map_or_else(|| "absent".to_owned(), ToString::to_string)
        };
        return differs(
            "tool",
            &format!("tool.{field}"),
            show(&tool_expert),
            show(&tool_here),
        );
    }
    let (Some(a), Some(b)) = (expert.render_meshes.first(), here.render_meshes.first()) else {
        return differs(
            "object",
            "object",
            format!("{} objects", expert.render_meshes.len()),
            format!("{} objects", here.render_meshes.len()),
        );
    };
    if a.name != b.name {
        return differs("object", "object.name", a.name.clone(), b.name.clone());
    }
    if a.object_in_world
        .position_m
        .distance(b.object_in_world.position_m)
        > SAME_M
    {
        return differs(
            "object",
            "object.position_m",
            format!("{:?}", a.object_in_world.position_m.to_array()),
            format!("{:?}", b.object_in_world.position_m.to_array()),
        );
    }
    if !a
        .object_in_world
        .orientation
        .abs_diff_eq(b.object_in_world.orientation, 1e-9)
    {
        return differs(
            "object",
            "object.orientation",
            format!("{:?}", a.object_in_world.orientation.to_array()),
            format!("{:?}", b.object_in_world.orientation.to_array()),
        );
    }
    if a.vertex_count != b.vertex_count {
        return differs(
            "object",
            "object's render mesh vertex count",
            a.vertex_count.to_string(),
            b.vertex_count.to_string(),
        );
    }
    Ok(())
}

/// How a guided session went: how long the pull held the trainee, how far from the target,
/// the gain's range, and the deviation from the expert after time alignment, over the whole
/// session and pass by pass.
#[derive(Debug, Clone, PartialEq)]
pub struct GuidanceSummary {
    /// The expert's recording, by file name.
    pub source: String,
    pub gain: GuideGain,
    /// Time the trainee was captured, s.
    pub engaged_s: f64,
    /// Mean distance from the tip to the guide's target while captured, m.
    pub mean_tracking_m: f64,
    /// The fading gain's least and last values over the session.
    pub least_gain: f64,
    pub last_gain: f64,
    /// The trainee's path and force against the expert's, aligned by dynamic time warping over
    /// the stretch from the first captured tick to the last (`None`: never captured).
    pub deviation: Option<Deviation>,
    /// Each pass along the path (an attempt: from its first captured tick to its last).
    pub passes: Vec<PassSummary>,
}

/// One pass along the expert's path.
#[derive(Debug, Clone, PartialEq)]
pub struct PassSummary {
    /// From 0.
    pub pass: u32,
    /// The fading gain at the pass's first captured tick.
    pub gain: f64,
    /// Time captured during the pass, s.
    pub engaged_s: f64,
    /// Whether the trainee reached the path's end in it.
    pub reached_end: bool,
    pub deviation: Option<Deviation>,
}

/// Every how many ticks the trainee's path is sampled for the alignment: 10 ms, finer than a
/// hand's motion, and the alignment's cost stays small for a long session.
const DEVIATION_EVERY_TICKS: usize = 10;

/// Most passes summarised (the rest are counted in the session's figures only).
const MAX_PASSES: usize = 100;

/// The summary of a guided recording (`None` for a session without a guide).
pub fn summary(recording: &Recording) -> Option<GuidanceSummary> {
    let guide = recording.scene.guide.as_ref()?;
    let period_s = recording.scene.period_ns as f64 * 1e-9;
    let forces = guide.forces_n.as_deref();
    let expert: Vec<_> = guide
        .points_m
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let f = forces.and_then(|f| f.get(i)).copied().unwrap_or(0.0);
            (DVec3::from_array(*p), f)
        })
        .collect();
    let aligned = |from: usize, to: usize| {
        let trainee: Vec<_> = recording.device[from..=to]
            .iter()
            .step_by(DEVIATION_EVERY_TICKS)
            .filter_map(|r| {
                let s = r.sample.as_ref()?;
                Some((
                    DVec3::from_array(s.tip_position_m),
                    DVec3::from_array(r.force_n).length(),
                ))
            })
            .collect();
        deviation(&trainee, &expert)
    };
    let mut engaged_ticks = 0_u64;
    let mut tracking_sum_m = 0.0;
    let mut least_gain = f64::INFINITY;
    let mut last_gain = guide.gain.initial();
    let mut first_engaged = None;
    let mut last_engaged = None;
    // Per pass: (pass, gain, first engaged tick, last engaged tick, engaged ticks, reached end).
    let mut passes: Vec<(u32, f64, usize, usize, u64, bool)> = Vec::new();
    for (i, r) in recording.device.iter().enumerate() {
        let Some(g) = &r.guide else { continue };
        least_gain = least_gain.min(g.gain);
        last_gain = g.gain;
        if !g.engaged {
            continue;
        }
        first_engaged.get_or_insert(i);
        last_engaged = Some(i);
        let count = passes.len();
        match passes.last_mut() {
            Some(p) if p.0 == g.pass => {
                p.3 = i;
                p.4 += 1;
                p.5 |= g.progress >= 0.98;
            }
            _ if count < MAX_PASSES => {
                passes.push((g.pass, g.gain, i, i, 1, g.progress >= 0.98));
            }
            _ => {}
        }
        if let Some(s) = &r.sample {
            engaged_ticks += 1;
            tracking_sum_m += DVec3::from_array(s.tip_position_m).distance(g.target_m);
        }
    }
    let deviation = first_engaged
        .zip(last_engaged)
        .and_then(|(from, to)| aligned(from, to));
    Some(GuidanceSummary {
        source: guide.source.clone(),
        gain: guide.gain.clone(),
        engaged_s: engaged_ticks as f64 * period_s,
        mean_tracking_m: if engaged_ticks > 0 {
            tracking_sum_m / engaged_ticks as f64
        } else {
            0.0
        },
        least_gain: if least_gain.is_finite() {
            least_gain
        } else {
            last_gain
        },
        last_gain,
        deviation,
        passes: passes
            .into_iter()
            .map(|(pass, gain, from, to, ticks, reached_end)| PassSummary {
                pass,
                gain,
                engaged_s: ticks as f64 * period_s,
                reached_end,
                deviation: aligned(from, to),
            })
            .collect(),
    })
}
