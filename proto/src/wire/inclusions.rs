//! `inclusions` (server → viewer): where a palpation scene's stiffer inclusions are, for the
//! viewers allowed to see them (docs/roles.md, "What each role sees").
//!
//! The positions are the answer a trainee must find by touch, so this message is the only one
//! that carries them, and the server sends it by role: to instructors while an attempt runs,
//! to every viewer once a palpation attempt has ended (`revealed`). Built here from the placed
//! inclusions ([`crate::Inclusion`], object frame) and the object's pose, so the live station and
//! a replay of its recording send the same numbers.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::Inclusion;
use crate::contact::Pose;

/// `inclusions`: the scene's inclusions in the world frame, and which attempt they answer.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InclusionsMessage {
    /// False while an attempt runs (sent to instructors only); true once a palpation attempt has
    /// ended and its answer is the exercise's result (sent to every viewer).
    pub revealed: bool,
    /// The exercise (its place in the station's list, from 0) and the attempt at it (from 1)
    /// this message belongs to; `null` on a session that runs no exercises. A viewer forgets a
    /// revealed answer when another attempt starts.
    pub exercise_index: Option<u32>,
    pub attempt: Option<u32>,
    pub inclusions: Vec<InclusionView>,
}

/// One inclusion as a viewer draws it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InclusionView {
    /// Centre, world frame.
    pub centre_m: [f64; 3],
    pub radius_m: f64,
    /// Its modulus over the tissue's.
    pub stiffness_ratio: f64,
    /// Depth of its centre below the surface, along the normal it was placed under.
    pub centre_depth_m: f64,
}

impl InclusionView {
    /// `placed` (object frame) as seen in the world, with the object at `object_in_world`.
    pub fn placed(placed: &[Inclusion], object_in_world: &Pose) -> Vec<InclusionView> {
        placed
            .iter()
            .map(|i| InclusionView {
                centre_m: object_in_world
                    .transform_point(DVec3::from_array(i.centre_in_object_m))
                    .to_array(),
                radius_m: i.radius_m,
                stiffness_ratio: i.stiffness_ratio,
                centre_depth_m: i.centre_depth_m,
            })
            .collect()
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn placed_inclusions_are_moved_into_the_world_with_the_object() {
        let pose = Pose {
            position_m: DVec3::new(0.1, 0.0, 0.0),
            orientation: glam::DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2),
        };
        let placed = [Inclusion {
            centre_in_object_m: [0.01, 0.0, 0.0],
            radius_m: 0.005,
            stiffness_ratio: 4.0,
            centre_depth_m: 0.008,
        }];
        let view = InclusionView::placed(&placed, &pose);
        let c = view[0].centre_m;
        assert!(
            (c[0] - 0.1).abs() < 1e-12 && (c[1] - 0.01).abs() < 1e-12,
            "{c:?}"
        );
        assert_eq!(view[0].radius_m, 0.005);
        assert_eq!(view[0].stiffness_ratio, 4.0);
    }
}
