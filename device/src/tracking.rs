//! The contact followed from tick to tick, so that a tool pushed through the object is held on
//! the side it entered: no pop-through.
//!
//! Long because its last 270 lines are its tests, one per way a contact is held or let go; the
//! tracker itself is 460 lines, a third of them the reasons for each rule.
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
//! # A tool that jumps in
//! A tool that goes in faster than its own height per tick (the 0.5 mm-tip 45° cone past
//! 0.5 m/s, the 0.5 mm sphere past 1 m/s, or either at those speeds when one reading comes late),
//! or that sinks in unopposed while the device is unreadable (a fault gives zero force, and the
//! tracker sees no tick of it), is first seen by the collision already clamped, or not at all:
//! past its reach. There is no clean contact to take the entry plane from, so out of contact the
//! tracker remembers the tip's reference point ([`crate::shape::reference_point_local`]) on the
//! last tick the tool was known outside: a tick with no contact a small step from the last such
//! point, a release, or a tick whose nearest surface point
//! ([`Collider::closest_surface_point`]) has the tip on its outer side. When the tip has moved
//! more than [`JUMP_FRACTION_OF_HEIGHT`] of its height from that point (a slow press, at most
//! 0.1 mm a tick, moves less than that even for the 0.5 mm tools, and never takes this path),
//! the entry plane is the tangent plane at the surface point nearest that point, and the tool is
//! held against it, as after a normal entry, when its deepest point is below that plane and
//! - the collision clamps the contact (the tip went past its height);
//! - the collision measures a contact cleanly but on the far side of a thin part: a plane the
//!   remembered point is inside of, with a normal more than 60° from the entry plane's;
//! - or the collision finds nothing and the tip's reference point is inside the object (its
//!   nearest surface point has it on the inner side). A jump that ends outside, beside a small
//!   object or right through it, is not held.
//!
//! The force of such a contact begins as any contact's does: the renderer ([`crate::force`])
//! ramps in from zero a contact that begins with more than its threshold, and after a device
//! fault ramps the force in again whatever the contact, so no jump reaches the device. A tool
//! seen inside with no tick outside before it (at start, or after a clamped contact against some
//! other surface) has no side it entered and is reported as the collision measures it, as
//! before.
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
//! releases at the same ticks ([`crate::world`]). Bounded: a tick costs the collision query and
//! a support point, plus, out of contact after a jump or before the tool is known outside, at
//! most two nearest-surface queries. No allocation, no panic: a non-finite pose or
//! an invalid tool measures a NaN depth, which releases the contact. A device fault is a gap in
//! the readings, not a release: the tracker keeps its state through one (the renderer ramps the
//! force back in), so a glitch in the middle of a hard press does not drop the tool through.

use glam::DVec3;
use softhaptic_proto::{Pose, ToolShape};

use crate::collision::{Collider, ContactGeometry, SurfacePoint};
use crate::shape;

/// Two successive contacts whose normals are closer than this (cosine of 60°) are on the same
/// side of the object. On a smooth surface the normal turns by a small fraction of a degree per
/// tick; a larger swing is the collision switching to another surface (the far side of a thin
/// part), never the tool sliding.
pub const SAME_SIDE_COS: f64 = 0.5;

/// A tool out of contact whose tip moved farther than this fraction of its height since the
/// last tick it was known outside has *jumped* (module docs): the tracker looks for the side it
/// entered. A slow press moves less than that per tick and never takes this path.
pub const JUMP_FRACTION_OF_HEIGHT: f64 = 0.5;

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

    /// The tangent plane at a surface point; where the vertex normals cancel, the plane across
    /// the tool's shaft (the collision's fallback, flagged the same way).
    fn at(surface: &SurfacePoint, curvature_1_per_m: f64, tip_in_object: &Pose) -> Self {
        let (normal, degenerate_normal) = match surface.normal.try_normalize() {
            Some(n) => (n, false),
            None => (tip_in_object.orientation * DVec3::Y, true),
        };
        Self {
            point_m: surface.point_m,
            normal,
            degenerate_normal,
            curvature_1_per_m,
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
    /// inside). Holds the tip's reference point ([`crate::shape::reference_point_local`],
    /// object frame) on the last tick the tool was known to be outside the object, if any: the
    /// side a tool that jumps in will be held on.
    Free(Option<DVec3>),
    /// The collision measured the contact cleanly; the plane it was on.
    Touching(EntryPlane),
    /// The tool is held against this entry plane.
    Held(EntryPlane),
}

/// The surface queries the tracker makes besides the tick's contact, only when a tool out of
/// contact jumps (module docs): the collider's, or a stand-in in the unit tests.
trait Surface {
    /// The surface point nearest `point_m` within `max_distance_m`
    /// ([`Collider::closest_surface_point`]).
    fn nearest(&mut self, point_m: DVec3, max_distance_m: f64) -> Option<SurfacePoint>;
    /// The surface's curvature at `point`, as the collision reports it on a contact there.
    fn curvature_at(&self, point: &SurfacePoint) -> f64;
}

impl Surface for Collider {
    fn nearest(&mut self, point_m: DVec3, max_distance_m: f64) -> Option<SurfacePoint> {
        self.closest_surface_point(point_m, max_distance_m)
    }

    /// The triangle's vertex curvatures blended by the point's barycentric weights, as the
    /// continuous collision blends them; zero without [`Collider::with_curvature`].
    fn curvature_at(&self, point: &SurfacePoint) -> f64 {
        let k = self.vertex_curvatures_1_per_m();
        if k.is_empty() {
            return 0.0;
        }
        let Some(triangle) = self.mesh().triangles().get(point.triangle as usize) else {
            return 0.0;
        };
        let at = |v: u32| k.get(v as usize).copied().unwrap_or(0.0);
        let w = point.barycentric;
        w.x * at(triangle[0]) + w.y * at(triangle[1]) + w.z * at(triangle[2])
    }
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
    /// A tracker out of contact, not yet knowing where the tool is.
    pub const fn new() -> Self {
        Self {
            phase: Phase::Free(None),
        }
    }

    /// True while the tracker holds a contact the collision no longer measures.
    pub fn is_holding(&self) -> bool {
        matches!(self.phase, Phase::Held(_))
    }

    /// The contact of `tool` at `tip_in_object` (the tool frame in the mesh's frame) this tick,
    /// or `None` out of contact: the collision's ([`Collider::query`]) or the held one.
    ///
    /// Cost: one collision query plus a support point; out of contact, when the tool jumps
    /// (module docs), up to two nearest-surface queries more. No allocation, no panic.
    pub fn query(
        &mut self,
        collider: &mut Collider,
        tool: &ToolShape,
        tip_in_object: &Pose,
    ) -> Option<TrackedContact> {
        let measured = collider.query(tool, tip_in_object);
        let (phase, contact) = self.next(measured, tool, tip_in_object, collider);
        self.phase = phase;
        contact
    }

    /// The transition of one tick, given the collision's contact: a pure function of the state,
    /// the tick's inputs and the surface.
    fn next(
        &self,
        measured: Option<ContactGeometry>,
        tool: &ToolShape,
        tip_in_object: &Pose,
        surface: &mut impl Surface,
    ) -> (Phase, Option<TrackedContact>) {
        let max_depth_m = shape::max_depth_m(tool);
        let pose = unit_pose(tip_in_object);
        match self.phase {
            Phase::Free(outside) => free(outside, measured, tool, &pose, surface),
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
                    released(measured, tool, &pose)
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
                    released(measured, tool, &pose)
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

/// The collision's contact reported as it measures it, not held.
fn as_measured(contact: ContactGeometry) -> TrackedContact {
    TrackedContact {
        geometry: contact,
        pushed_through: false,
    }
}

/// The reference point of the tool at `pose` (unit), object frame, when it is finite.
fn reference_point(tool: &ToolShape, pose: &Pose) -> Option<DVec3> {
    let q = pose.transform_point(shape::reference_point_local(tool));
    q.is_finite().then_some(q)
}

/// A tracked contact let go: the collision's answer as it is. A tool released with no contact
/// is outside, on the side it entered, and a clean contact starts a new tracked one; a clamped
/// one (against another surface) leaves the tracker not knowing where the tool is.
fn released(
    measured: Option<ContactGeometry>,
    tool: &ToolShape,
    pose: &Pose,
) -> (Phase, Option<TrackedContact>) {
    match measured {
        Some(contact) if !contact.depth_clamped => touching(contact),
        Some(contact) => (Phase::Free(None), Some(as_measured(contact))),
        None => (Phase::Free(reference_point(tool, pose)), None),
    }
}

/// A tick out of contact (module docs, "A tool that jumps in"). `outside` is the tip's
/// reference point on the last tick it was known outside the object.
fn free(
    outside: Option<DVec3>,
    measured: Option<ContactGeometry>,
    tool: &ToolShape,
    pose: &Pose,
    surface: &mut impl Surface,
) -> (Phase, Option<TrackedContact>) {
    let q = reference_point(tool, pose);
    // The last outside point, when the tip has jumped from it this tick; `None` for a tip that
    // moved less (a slow approach: the collision sees its contact begin, as it always did).
    let jumped_from = match (outside, q) {
        (Some(q0), Some(q)) => {
            ((q - q0).length() > JUMP_FRACTION_OF_HEIGHT * shape::max_depth_m(tool)).then_some(q0)
        }
        _ => None,
    };
    match measured {
        Some(contact) if !contact.depth_clamped => {
            // A clean contact is the entry, unless the tool jumped in from the inner side of its
            // plane: the far side of a thin part, reached in one tick.
            if let Some(q0) = jumped_from
                && (q0 - contact.contact_point_m).dot(contact.normal) < 0.0
                && let Some((entry, depth_m, deepest)) = entry_below(q0, tool, pose, surface)
                && !entry.takes(&contact)
            {
                return (Phase::Held(entry), Some(entry.held(depth_m, deepest)));
            }
            touching(contact)
        }
        Some(contact) => {
            // Clamped at first sight: the tip went past its own height in one tick. Held on the
            // side it came from, if it came from outside.
            if let Some(q0) = jumped_from
                && let Some((entry, depth_m, deepest)) = entry_below(q0, tool, pose, surface)
            {
                return (Phase::Held(entry), Some(entry.held(depth_m, deepest)));
            }
            (Phase::Free(outside), Some(as_measured(contact)))
        }
        None => {
            let Some(q) = q else {
                return (Phase::Free(None), None);
            };
            if outside.is_some() && jumped_from.is_none() {
                // A small step from outside, and no contact: still outside.
                return (Phase::Free(Some(q)), None);
            }
            // Jumped, or not yet known: inside past the collision's reach, or outside?
            if let Some(q0) = jumped_from
                && let Some((entry, depth_m, deepest)) = entry_below(q0, tool, pose, surface)
            {
                return if is_inside(q, entry.point_m, surface) {
                    (Phase::Held(entry), Some(entry.held(depth_m, deepest)))
                } else {
                    (Phase::Free(Some(q)), None)
                };
            }
            let nearest = surface.nearest(q, f64::INFINITY);
            if nearest.is_none_or(|s| s.signed_distance_m >= 0.0) {
                (Phase::Free(Some(q)), None)
            } else {
                (Phase::Free(outside), None)
            }
        }
    }
}

/// The entry plane of a tool that jumped in from the outside point `q0`: the tangent plane at
/// the surface point nearest `q0`, when the tool's deepest point is now below it, with that
/// depth and point. The surface the tip crossed is within its step of `q0` (plus the
/// collision's reach, for a tip that touched without its reference point crossing).
fn entry_below(
    q0: DVec3,
    tool: &ToolShape,
    pose: &Pose,
    surface: &mut impl Surface,
) -> Option<(EntryPlane, f64, DVec3)> {
    let q = pose.transform_point(shape::reference_point_local(tool));
    let reach_m = shape::bounding_radius_m(tool) + shape::max_depth_m(tool);
    let nearest = surface.nearest(q0, (q - q0).length() + reach_m)?;
    let entry = EntryPlane::at(&nearest, surface.curvature_at(&nearest), pose);
    let (depth_m, deepest) = entry.depth_below_m(tool, pose);
    // NaN compares false: not held.
    (depth_m > 0.0 && entry.normal.is_finite()).then_some((entry, depth_m, deepest))
}

/// Whether `q` is inside the object: the surface point nearest it has it on its inner side.
/// That point is no farther than `on_surface_m`, a point of the surface, so the search is
/// bounded by it and its answer is the nearest point's: not inside is outside.
fn is_inside(q: DVec3, on_surface_m: DVec3, surface: &mut impl Surface) -> bool {
    let bound_m = (q - on_surface_m).length() * (1.0 + 1e-9) + 1e-12;
    surface
        .nearest(q, bound_m)
        .is_some_and(|s| s.signed_distance_m < 0.0)
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

    /// The plane y = 0, infinite, its outside up: the surface the `measured` contacts are on.
    struct Plane;

    impl Surface for Plane {
        fn nearest(&mut self, point_m: DVec3, max_distance_m: f64) -> Option<SurfacePoint> {
            (point_m.is_finite() && point_m.y.abs() <= max_distance_m).then_some(SurfacePoint {
                point_m: DVec3::new(point_m.x, 0.0, point_m.z),
                normal: DVec3::Y,
                signed_distance_m: point_m.y,
                triangle: 0,
                barycentric: DVec3::X,
            })
        }

        fn curvature_at(&self, _: &SurfacePoint) -> f64 {
            0.0
        }
    }

    /// Steps the tracker by `next` alone (no collider, the plane y = 0), as `query` would.
    fn step(
        t: &mut ContactTracker,
        measured: Option<ContactGeometry>,
        pose: Pose,
    ) -> Option<TrackedContact> {
        let (phase, contact) = t.next(measured, &sphere(), &pose, &mut Plane);
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
        // Released outside: the sphere's centre is remembered as the last point outside.
        assert_eq!(t.phase, Phase::Free(Some(DVec3::new(0.0, 0.002, 0.0))));
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
        assert!(matches!(t.phase, Phase::Free(_)));
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
    fn a_first_contact_seen_clamped_after_a_jump_is_held_on_the_side_it_came_from() {
        // 0.5 mm above, then 2.5 mm below in one tick (3 m/s, or a gap in the readings): the
        // collision's first sight of the contact is already clamped.
        let mut t = ContactTracker::new();
        assert_eq!(step(&mut t, None, at(0.0005)), None);
        assert_eq!(t.phase, Phase::Free(Some(DVec3::new(0.0, 0.0015, 0.0))));
        let c = step(&mut t, Some(measured(-0.0025, DVec3::Y, true)), at(-0.0025)).unwrap();
        assert!(c.pushed_through && t.is_holding());
        assert!((c.geometry.depth_m - 0.0025).abs() < 1e-15);
        assert_eq!(c.geometry.normal, DVec3::Y);
        assert!(c.geometry.contact_point_m.length() < 1e-15);
        // Past the collision's reach: still held, deeper.
        let c = step(&mut t, None, at(-0.006)).unwrap();
        assert!(c.pushed_through && (c.geometry.depth_m - 0.006).abs() < 1e-15);
        // Out on the side it entered: released, and known outside again.
        assert_eq!(step(&mut t, None, at(0.0001)), None);
        assert_eq!(t.phase, Phase::Free(Some(DVec3::new(0.0, 0.0011, 0.0))));
    }

    #[test]
    fn a_tool_that_jumps_past_the_collisions_reach_is_held() {
        // A device outage: the last reading 1 mm above, the next 10 mm deep, where the collision
        // finds nothing at all.
        let mut t = ContactTracker::new();
        step(&mut t, None, at(0.001));
        let c = step(&mut t, None, at(-0.01)).unwrap();
        assert!(c.pushed_through && t.is_holding());
        assert!((c.geometry.depth_m - 0.01).abs() < 1e-15);
        assert_eq!(c.geometry.normal, DVec3::Y);
        assert!(c.geometry.depth_m.is_finite() && !c.geometry.depth_clamped);
    }

    #[test]
    fn a_jump_onto_the_far_side_of_a_thin_part_is_held_against_the_near_side() {
        // From 1 mm above the top straight to within the tip's height of a bottom face 3 mm
        // down: the collision measures that face cleanly, its normal pointing down.
        let mut t = ContactTracker::new();
        step(&mut t, None, at(0.001));
        let bottom = ContactGeometry {
            depth_m: 0.0005,
            normal: -DVec3::Y,
            contact_point_m: DVec3::new(0.0, -0.003, 0.0),
            degenerate_normal: false,
            depth_clamped: false,
            curvature_1_per_m: 0.0,
        };
        let c = step(&mut t, Some(bottom), at(-0.0025)).unwrap();
        assert!(c.pushed_through && c.geometry.normal == DVec3::Y);
        assert!((c.geometry.depth_m - 0.0025).abs() < 1e-15);
        // A tool first seen inside, past the collision's reach, is not known to be outside:
        // there is no side it came from to hold it on.
        let mut t = ContactTracker::new();
        assert_eq!(step(&mut t, None, at(-0.006)), None);
        assert_eq!(t.phase, Phase::Free(None));
    }

    #[test]
    fn small_steps_out_of_contact_behave_as_before() {
        // Steps under half the tip's height: no jump, no extra query; a clamped contact seen
        // then (a tool that was inside without the collision seeing it) is not held.
        let mut t = ContactTracker::new();
        step(&mut t, None, at(0.0002));
        step(&mut t, None, at(0.0001));
        assert_eq!(t.phase, Phase::Free(Some(DVec3::new(0.0, 0.0011, 0.0))));
        let m = measured(-0.0003, DVec3::Y, true);
        let c = step(&mut t, Some(m), at(-0.0003)).unwrap();
        assert!(!c.pushed_through && c.geometry == m && !t.is_holding());
        let m = measured(-0.0002, DVec3::Y, false);
        assert_eq!(step(&mut t, Some(m), at(-0.0002)).unwrap().geometry, m);
        assert!(matches!(t.phase, Phase::Touching(_)));
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
