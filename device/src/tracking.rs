//! The contact followed from tick to tick, so that a tool pushed through the object is held on
//! the side it entered: no pop-through.
//!
//! A hand can overpower the device (a PHANTOM Desktop pushes back with 7.9 N at most, and holds
//! 1.75 N for long), and a small tool on soft tissue reaches the collision's depth bound, the
//! tip's height ([`crate::shape::max_depth_m`], 2 mm for a 1 mm sphere), at a fraction of a
//! newton. Past that bound one tick's collision ([`Collider::query`]) cannot tell where the tool
//! came from: it clamps the depth, then finds no surface within its reach, or finds the far side
//! of a thin part and pushes the tool out through it. Either way the force vanishes or turns
//! round, and the tool falls through the object.
//!
//! # What the tracker does
//! [`ContactTracker::query`] runs the collision and remembers, from every tick whose contact the
//! collision measured cleanly (depth not clamped, normal within 60° of the tick before), the
//! *entry plane*: that contact's point and outward normal. When the collision then stops
//! measuring the contact while the tip is below the entry plane, the tracker *holds* it:
//! - the depth was clamped (the tip went past its own height);
//! - the contact's normal swung by more than 60° in one tick (the far side of a thin part came
//!   closer than the side the tool entered);
//! - or the contact vanished with the tip deeper than half its height below the entry plane
//!   (pushed past the collision's reach, or, in the paper's mode, past the last vertex inside the
//!   tip). A contact that vanishes shallower is a release: the tool lifted off, or slid off a
//!   convex edge, where the entry plane of the tick before still lies a hair above the tip.
//!
//! A held contact has the entry plane's normal and curvature, and its depth is the tip's depth
//! below the entry plane along that normal (the tip's support point, as the collision measures
//! a cone), unclamped: past the tip's height the renderer continues the force as a line of the
//! device's stable stiffness ([`crate::force`]), so it keeps rising, continuously, until the
//! device saturates. The haptic world flags every held tick
//! [`PUSHED_THROUGH`](softhaptic_proto::ContactFlags::PUSHED_THROUGH). The collision takes the
//! contact back when it measures it cleanly again on the same side with the tip within its
//! height of the entry plane; the contact is released only when the tip comes back above the
//! entry plane: out on the side it entered, never through the far side.
//!
//! # Why a fixed entry plane, and not a proxy that slides on the surface
//! A god-object (a proxy point kept on the surface, moved each tick to the surface point nearest
//! the tip's projection) follows a curved surface while a held tool slides. But once the tip is
//! deeper than the surface's radius of curvature (a 10 mm ball, the thin lobe of the liver) the
//! nearest surface point drifts round the object toward its far side, a few degrees a tick, and
//! the proxy would lead the force out through the far side: the pop-through again, slower. The
//! entry plane cannot drift: it moves only while the collision measures the contact cleanly. Its
//! cost is a plane that goes stale while a deeply held tool slides along a curved surface (0.5 mm
//! below a 100 mm radius after a 10 mm slide), which changes the held force by that much depth
//! and is gone as soon as the collision takes the contact back.
//!
//! # Promises
//! Deterministic: the tracker's state evolves with the samples alone, so a replay holds and
//! releases at the same ticks ([`crate::world`]). No allocation, no panic: a non-finite pose or
//! an invalid tool measures a NaN depth, which releases the contact. A device fault is a gap in
//! the readings, not a release: the tracker keeps its state through one (the renderer ramps the
//! force back in), so a glitch in the middle of a hard press does not drop the tool through.

use glam::DVec3;
use softhaptic_proto::{Pose, ToolShape};

use crate::collision::{Collider, ContactGeometry};
use crate::shape;

/// Two successive contacts whose normals are closer than this (cosine of 60°) are on the same
/// side of the object. On a smooth surface the normal turns by a small fraction of a degree per
/// tick; a larger swing is the collision switching to another surface (the far side of a thin
/// part), never the tool sliding.
pub const SAME_SIDE_COS: f64 = 0.5;

/// A contact as the tracker reports it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackedContact {
    /// The collision's contact, or, when `pushed_through`, the held contact: the entry plane's
    /// normal, point above the tip and curvature, with `depth_m` measured from the entry plane,
    /// which may exceed the tip's height ([`crate::shape::max_depth_m`]).
    pub geometry: ContactGeometry,
    /// The contact is held by the tracker beyond what the collision measures this tick.
    pub pushed_through: bool,
}

/// The plane of the last contact the collision measured cleanly, object frame.
#[derive(Debug, Clone, Copy, PartialEq)]
struct EntryPlane {
    point_m: DVec3,
    /// Unit, out of the object.
    normal: DVec3,
    degenerate_normal: bool,
    curvature_1_per_m: f64,
}

impl EntryPlane {
    fn of(contact: &ContactGeometry) -> Self {
        Self {
            point_m: contact.contact_point_m,
            normal: contact.normal,
            degenerate_normal: contact.degenerate_normal,
            curvature_1_per_m: contact.curvature_1_per_m,
        }
    }

    /// Whether the collision measured `contact` cleanly on this plane's side.
    fn takes(&self, contact: &ContactGeometry) -> bool {
        !contact.depth_clamped && contact.normal.dot(self.normal) >= SAME_SIDE_COS
    }

    /// Depth of the tool's deepest point below the plane, along its normal (negative above it,
    /// NaN for an unusable pose or tool), and that point.
    fn depth_below_m(&self, tool: &ToolShape, tip_in_object: &Pose) -> (f64, DVec3) {
        let deepest = shape::support_point(tool, tip_in_object, -self.normal);
        ((self.point_m - deepest).dot(self.normal), deepest)
    }

    /// The held contact at `depth_m`, its point on the plane above the tool's deepest point (the
    /// collision's cone contact, built the same way).
    fn held(&self, depth_m: f64, deepest: DVec3) -> TrackedContact {
        TrackedContact {
            geometry: ContactGeometry {
                depth_m,
                normal: self.normal,
                contact_point_m: deepest + self.normal * depth_m,
                degenerate_normal: self.degenerate_normal,
                depth_clamped: false,
                curvature_1_per_m: self.curvature_1_per_m,
            },
            pushed_through: true,
        }
    }
}

/// Where the contact was left by the last tick.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    /// No contact, or one the collision never measured cleanly (a tool that appeared deep
    /// inside): nothing to hold on to.
    Free,
    /// The collision measured the contact cleanly; the plane it was on.
    Touching(EntryPlane),
    /// The tool is held against this entry plane.
    Held(EntryPlane),
}

/// Follows the contact across ticks and holds a tool pushed through the object on the side it
/// entered (module docs). `Copy`-sized state, no buffers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactTracker {
    phase: Phase,
}

impl Default for ContactTracker {
    fn default() -> Self {
        Self::new()
    }
}

impl ContactTracker {
    /// A tracker out of contact.
    pub const fn new() -> Self {
        Self { phase: Phase::Free }
    }

    /// True while the tracker holds a contact the collision no longer measures.
    pub fn is_holding(&self) -> bool {
        matches!(self.phase, Phase::Held(_))
    }

    /// The contact of `tool` at `tip_in_object` (the tool frame in the mesh's frame) this tick,
    /// or `None` out of contact: the collision's ([`Collider::query`]) or the held one.
    ///
    /// Cost: one collision query plus a support point; no allocation, no panic.
    pub fn query(
        &mut self,
        collider: &mut Collider,
        tool: &ToolShape,
        tip_in_object: &Pose,
    ) -> Option<TrackedContact> {
        let measured = collider.query(tool, tip_in_object);
        let (phase, contact) = self.next(measured, tool, tip_in_object);
        self.phase = phase;
        contact
    }

    /// The transition of one tick, given the collision's contact: a pure function of the state
    /// and the tick's inputs.
    fn next(
        &self,
        measured: Option<ContactGeometry>,
        tool: &ToolShape,
        tip_in_object: &Pose,
    ) -> (Phase, Option<TrackedContact>) {
        let max_depth_m = shape::max_depth_m(tool);
        let pose = unit_pose(tip_in_object);
        match self.phase {
            Phase::Free => free(measured),
            Phase::Touching(entry) => {
                if let Some(contact) = measured.filter(|c| entry.takes(c)) {
                    return touching(contact);
                }
                let (depth_m, deepest) = entry.depth_below_m(tool, &pose);
                // Clamped, or on another side: the tool is past what the collision measures if
                // it is below the plane at all. Vanished: only past half the tip's height, or
                // it is a tool lifting off (module docs). NaN compares false: released.
                let pushed_through = match measured {
                    Some(_) => depth_m > 0.0,
                    None => depth_m > 0.5 * max_depth_m,
                };
                if pushed_through {
                    (Phase::Held(entry), Some(entry.held(depth_m, deepest)))
                } else {
                    free(measured)
                }
            }
            Phase::Held(entry) => {
                let (depth_m, deepest) = entry.depth_below_m(tool, &pose);
                if let Some(contact) = measured.filter(|c| entry.takes(c))
                    && depth_m <= max_depth_m
                {
                    return touching(contact);
                }
                if depth_m > 0.0 {
                    (Phase::Held(entry), Some(entry.held(depth_m, deepest)))
                } else {
                    // Back above the entry plane (or an unusable pose): released; whatever the
                    // collision finds now is a new contact.
                    free(measured)
                }
            }
        }
    }
}

/// A contact the collision measured cleanly, reported as it is; its plane is the entry plane.
fn touching(contact: ContactGeometry) -> (Phase, Option<TrackedContact>) {
    (
        Phase::Touching(EntryPlane::of(&contact)),
        Some(TrackedContact {
            geometry: contact,
            pushed_through: false,
        }),
    )
}

/// No contact to hold on to: the collision's answer as it is. Only a contact measured cleanly
/// starts a tracked one; a clamped one (a tool that appeared deep inside the object) has no side
/// it entered, so it is reported as the collision measures it and never held.
fn free(measured: Option<ContactGeometry>) -> (Phase, Option<TrackedContact>) {
    match measured {
        Some(contact) if !contact.depth_clamped => touching(contact),
        other => (
            Phase::Free,
            other.map(|geometry| TrackedContact {
                geometry,
                pushed_through: false,
            }),
        ),
    }
}

/// The pose with a unit quaternion, as the collision uses it; a zero or non-finite one stays
/// unusable and gives a NaN depth.
fn unit_pose(pose: &Pose) -> Pose {
    Pose {
        position_m: pose.position_m,
        orientation: pose.orientation / pose.orientation.length(),
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use glam::DQuat;

    fn sphere() -> ToolShape {
        ToolShape::sphere(0.001).unwrap()
    }

    /// The collision's contact with the plane y = 0 of a tip whose bottom is at `tip_y`.
    fn measured(tip_y: f64, normal: DVec3, clamped: bool) -> ContactGeometry {
        ContactGeometry {
            depth_m: (-tip_y).min(0.002),
            normal,
            contact_point_m: DVec3::new(0.0, 0.0, 0.0),
            degenerate_normal: false,
            depth_clamped: clamped,
            curvature_1_per_m: 0.0,
        }
    }

    fn at(tip_y: f64) -> Pose {
        Pose::from_position(DVec3::new(0.0, tip_y, 0.0))
    }

    /// Steps the tracker by `next` alone (no collider), as `query` would.
    fn step(
        t: &mut ContactTracker,
        measured: Option<ContactGeometry>,
        pose: Pose,
    ) -> Option<TrackedContact> {
        let (phase, contact) = t.next(measured, &sphere(), &pose);
        t.phase = phase;
        contact
    }

    #[test]
    fn a_clean_contact_passes_through_unchanged() {
        let mut t = ContactTracker::new();
        let m = measured(-0.0005, DVec3::Y, false);
        let c = step(&mut t, Some(m), at(-0.0005)).unwrap();
        assert_eq!(c.geometry, m);
        assert!(!c.pushed_through && !t.is_holding());
        assert_eq!(step(&mut t, None, at(0.001)), None);
        assert_eq!(t.phase, Phase::Free);
    }

    #[test]
    fn a_clamped_contact_is_held_deeper_along_the_entry_normal() {
        let mut t = ContactTracker::new();
        step(
            &mut t,
            Some(measured(-0.0019, DVec3::Y, false)),
            at(-0.0019),
        );
        let c = step(&mut t, Some(measured(-0.0021, DVec3::Y, true)), at(-0.0021)).unwrap();
        assert!(c.pushed_through && t.is_holding());
        assert!((c.geometry.depth_m - 0.0021).abs() < 1e-15);
        assert_eq!(c.geometry.normal, DVec3::Y);
        // Lost by the collision altogether, far deeper: still held, deeper still.
        let c = step(&mut t, None, at(-0.008)).unwrap();
        assert!(c.pushed_through && (c.geometry.depth_m - 0.008).abs() < 1e-15);
        assert!((c.geometry.contact_point_m - DVec3::ZERO).length() < 1e-15);
        // The collision measures it cleanly again within the tip's height: handed back.
        let m = measured(-0.0015, DVec3::Y, false);
        let c = step(&mut t, Some(m), at(-0.0015)).unwrap();
        assert_eq!(c.geometry, m);
        assert!(!c.pushed_through && !t.is_holding());
    }

    #[test]
    fn the_far_side_of_a_thin_part_is_ignored_until_the_tool_is_back_out_above() {
        let mut t = ContactTracker::new();
        step(&mut t, Some(measured(-0.001, DVec3::Y, false)), at(-0.001));
        // The bottom face came closer: its normal points down. Held against the top instead.
        let c = step(
            &mut t,
            Some(measured(-0.0012, -DVec3::Y, false)),
            at(-0.0012),
        )
        .unwrap();
        assert!(c.pushed_through);
        assert_eq!(c.geometry.normal, DVec3::Y);
        // Out through the bottom, 30 mm below the top: still held, pushing up.
        let c = step(&mut t, None, at(-0.03)).unwrap();
        assert!(c.pushed_through && c.geometry.depth_m > 0.029);
        // A downward contact while still below the top plane: still the top's.
        let c = step(
            &mut t,
            Some(measured(-0.0005, -DVec3::Y, false)),
            at(-0.0005),
        )
        .unwrap();
        assert!(c.pushed_through && c.geometry.normal == DVec3::Y);
        // Above the top plane: released.
        assert_eq!(step(&mut t, None, at(0.0001)), None);
        assert!(!t.is_holding());
    }

    #[test]
    fn a_contact_that_vanishes_near_the_surface_is_released_not_held() {
        // Lifting off, or sliding off a convex edge: the tip is a hair below last tick's plane.
        let mut t = ContactTracker::new();
        step(
            &mut t,
            Some(measured(-0.0001, DVec3::Y, false)),
            at(-0.0001),
        );
        assert_eq!(step(&mut t, None, at(-0.00005)), None);
        assert_eq!(t.phase, Phase::Free);
        // Past half the tip's height (1 mm for R = 1 mm), it is a push-through.
        step(
            &mut t,
            Some(measured(-0.0009, DVec3::Y, false)),
            at(-0.0009),
        );
        let c = step(&mut t, None, at(-0.0012)).unwrap();
        assert!(c.pushed_through);
    }

    #[test]
    fn a_tool_that_appears_deep_inside_is_not_held() {
        let mut t = ContactTracker::new();
        let m = measured(-0.004, DVec3::Y, true);
        let c = step(&mut t, Some(m), at(-0.004)).unwrap();
        assert!(!c.pushed_through && c.geometry == m);
        assert_eq!(step(&mut t, None, at(-0.008)), None);
    }

    #[test]
    fn an_unusable_pose_releases_without_a_nan() {
        let mut t = ContactTracker::new();
        step(
            &mut t,
            Some(measured(-0.0019, DVec3::Y, false)),
            at(-0.0019),
        );
        step(&mut t, Some(measured(-0.0021, DVec3::Y, true)), at(-0.0021));
        assert!(t.is_holding());
        let broken = Pose {
            position_m: DVec3::new(0.0, -0.003, 0.0),
            orientation: DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0),
        };
        assert_eq!(step(&mut t, None, broken), None);
        assert!(!t.is_holding());
        let nan = Pose::from_position(DVec3::new(f64::NAN, 0.0, 0.0));
        step(
            &mut t,
            Some(measured(-0.0019, DVec3::Y, false)),
            at(-0.0019),
        );
        assert_eq!(step(&mut t, None, nan), None);
    }

    #[test]
    fn a_tilted_cone_is_measured_at_its_deepest_point() {
        let cone = ToolShape::cone(std::f64::consts::FRAC_PI_4, 0.002).unwrap();
        let entry = EntryPlane {
            point_m: DVec3::ZERO,
            normal: DVec3::Y,
            degenerate_normal: false,
            curvature_1_per_m: 0.0,
        };
        // Apex 3 mm down, axis tilted 60° from the normal, more than 90° − α: a point of the
        // base rim (h = r = 2 mm) is lower than the apex, by r sin 60° − h cos 60°.
        let tilt = 60f64.to_radians();
        let pose = Pose {
            position_m: DVec3::new(0.0, -0.003, 0.0),
            orientation: DQuat::from_rotation_z(tilt),
        };
        let (depth_m, deepest) = entry.depth_below_m(&cone, &pose);
        let expected_m = 0.003 + 0.002 * tilt.sin() - 0.002 * tilt.cos();
        assert!(
            (depth_m - expected_m).abs() < 1e-12,
            "{depth_m} vs {expected_m}"
        );
        assert!((depth_m + deepest.y).abs() < 1e-15);
    }
}
