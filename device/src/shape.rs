//! The tool tip as a solid: implicit inside test, bounding box, support point and depth bound.
//!
//! [`ToolShape`] (in `proto`) only names the tip and its sizes; the geometric queries the
//! collision needs live here, as free functions in the style of a geometry library: a
//! `*_local` function works in the tool frame, its counterpart takes the tool's pose.
//!
//! Tool frame (proto/src/tool.rs): the origin is the tip's proximal point (the bottom of the
//! sphere, the apex of the cone) and `+y` runs up the shaft, so the tool *points* along `−y`.
//! The solids modelled are
//! - sphere of radius R: the whole ball centred at `(0, R, 0)`;
//! - cone with half-angle α (axis to flank) and base radius r: apex at the origin, base disc of
//!   radius r at height h = r / tan α.
//!
//! Every function is total: it never panics. Callers validate the tool once
//! ([`ToolShape::validate`]); with an invalid tool (NaN or non-positive sizes) the results are
//! NaN or empty and the collision rejects them.

use glam::{DQuat, DVec3};
use softhaptic_proto::{Pose, ToolShape};

/// Whether `point_in_tool` (tool frame) lies inside or on the tip solid.
#[inline]
pub fn contains_local(tool: &ToolShape, point_in_tool: DVec3) -> bool {
    let q = point_in_tool;
    match *tool {
        ToolShape::Sphere { radius_m } => {
            (q - DVec3::Y * radius_m).length_squared() <= radius_m * radius_m
        }
        ToolShape::Cone {
            half_angle_rad,
            radius_m,
        } => {
            let tan = half_angle_rad.tan();
            let height = radius_m / tan;
            let rho = (q.x * q.x + q.z * q.z).sqrt();
            q.y >= 0.0 && q.y <= height && rho <= q.y * tan
        }
    }
}

/// Whether `point` (in the frame the tool's pose is given in, usually the object's) lies inside
/// or on the tip solid.
#[inline]
pub fn inside_tool(tool: &ToolShape, tip_in_object: &Pose, point: DVec3) -> bool {
    contains_local(tool, tip_in_object.inverse_transform_point(point))
}

/// Height of the tip solid along its axis: the sphere's diameter 2R, the cone's h = r / tan α.
///
/// The collision clamps the indentation δ to this value: once the whole tip is below the local
/// tangent plane, a deeper reading would only measure how far the tool has tunnelled into the
/// mesh, not an indentation the contact laws describe.
#[inline]
pub fn max_depth_m(tool: &ToolShape) -> f64 {
    match *tool {
        ToolShape::Sphere { radius_m } => 2.0 * radius_m,
        ToolShape::Cone { .. } => tool.tip_length_m(),
    }
}

/// The point of the tip the collision measures from, in the tool frame: the sphere's centre,
/// or the cone's apex (the origin).
#[inline]
pub fn reference_point_local(tool: &ToolShape) -> DVec3 {
    match *tool {
        ToolShape::Sphere { radius_m } => DVec3::Y * radius_m,
        ToolShape::Cone { .. } => DVec3::ZERO,
    }
}

/// Radius of the smallest ball around [`reference_point_local`] that holds the whole tip:
/// R for the sphere, the slant length √(h² + r²) for the cone.
#[inline]
pub fn bounding_radius_m(tool: &ToolShape) -> f64 {
    match *tool {
        ToolShape::Sphere { radius_m } => radius_m,
        ToolShape::Cone { radius_m, .. } => tool.tip_length_m().hypot(radius_m),
    }
}

/// Tight axis-aligned bounding box `(min, max)` of the tip solid in the pose's parent frame.
///
/// Exact for both solids (not the box of the rotated local box): the sphere's centre ± R, and
/// for the cone the union of the apex and the box of the tilted base disc, whose half-extent
/// along world axis i is r·√(1 − aᵢ²) for the unit shaft axis a.
pub fn aabb_m(tool: &ToolShape, tip_in_object: &Pose) -> (DVec3, DVec3) {
    let axis = tip_in_object.orientation * DVec3::Y;
    match *tool {
        ToolShape::Sphere { radius_m } => {
            let centre = tip_in_object.position_m + axis * radius_m;
            (
                centre - DVec3::splat(radius_m),
                centre + DVec3::splat(radius_m),
            )
        }
        ToolShape::Cone { radius_m, .. } => {
            let apex = tip_in_object.position_m;
            let base = apex + axis * tool.tip_length_m();
            let half = radius_m * (DVec3::ONE - axis * axis).max(DVec3::ZERO).sqrt();
            (apex.min(base - half), apex.max(base + half))
        }
    }
}

/// The point of the tip solid farthest along `direction_in_tool` (tool frame; need not be unit
/// length). For a zero direction it returns the reference point.
///
/// For the cone the farthest point is the apex or a point of the base rim; of the rim, the one
/// whose radial direction best matches the direction. When the direction is exactly along the
/// shaft, the base centre is returned (the whole base disc is equally far).
pub fn support_point_local(tool: &ToolShape, direction_in_tool: DVec3) -> DVec3 {
    let Some(d) = direction_in_tool.try_normalize() else {
        return reference_point_local(tool);
    };
    match *tool {
        ToolShape::Sphere { radius_m } => DVec3::Y * radius_m + d * radius_m,
        ToolShape::Cone { radius_m, .. } => {
            let radial = DVec3::new(d.x, 0.0, d.z).normalize_or_zero();
            let rim = DVec3::Y * tool.tip_length_m() + radial * radius_m;
            if rim.dot(d) > 0.0 { rim } else { DVec3::ZERO }
        }
    }
}

/// [`support_point_local`] for a tool at `tip_in_object`, direction and result in the parent
/// frame.
pub fn support_point(tool: &ToolShape, tip_in_object: &Pose, direction: DVec3) -> DVec3 {
    let inverse: DQuat = tip_in_object.orientation.inverse();
    tip_in_object.transform_point(support_point_local(tool, inverse * direction))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // In tests a panic is the failure report.
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_4;

    fn cone45() -> ToolShape {
        ToolShape::cone(FRAC_PI_4, 0.01).unwrap()
    }

    #[test]
    fn sphere_contains_its_centre_and_not_points_past_its_radius() {
        let s = ToolShape::sphere(0.005).unwrap();
        assert!(contains_local(&s, DVec3::new(0.0, 0.005, 0.0)));
        assert!(contains_local(&s, DVec3::ZERO));
        assert!(!contains_local(&s, DVec3::new(0.0, -1e-9, 0.0)));
        assert!(!contains_local(&s, DVec3::new(0.0051, 0.005, 0.0)));
    }

    #[test]
    fn cone_follows_half_angle_from_axis_to_flank() {
        let c = ToolShape::cone(30f64.to_radians(), 0.01).unwrap();
        // At height y the flank is at y·tan 30°.
        let y = 0.004;
        let flank = y * 30f64.to_radians().tan();
        assert!(contains_local(&c, DVec3::new(flank * 0.99, y, 0.0)));
        assert!(!contains_local(&c, DVec3::new(flank * 1.01, y, 0.0)));
        // Nothing above the base.
        let h = c.tip_length_m();
        assert!(!contains_local(&c, DVec3::new(0.0, h * 1.001, 0.0)));
    }

    #[test]
    fn tilted_cone_box_is_tight_and_contains_the_solid() {
        let c = cone45();
        let pose = Pose {
            position_m: DVec3::new(0.1, 0.2, -0.3),
            orientation: DQuat::from_rotation_z(0.7) * DQuat::from_rotation_x(-0.4),
        };
        let (lo, hi) = aabb_m(&c, &pose);
        // Sample the solid and check containment; check tightness via the extreme samples.
        let mut seen_lo = DVec3::splat(f64::INFINITY);
        let mut seen_hi = DVec3::splat(f64::NEG_INFINITY);
        for i in 0..=20 {
            for k in 0..64 {
                let y = c.tip_length_m() * i as f64 / 20.0;
                let a = k as f64 / 64.0 * std::f64::consts::TAU;
                let q = DVec3::new(y * a.cos(), y, y * a.sin());
                let p = pose.transform_point(q);
                assert!(p.cmpge(lo - 1e-12).all() && p.cmple(hi + 1e-12).all());
                seen_lo = seen_lo.min(p);
                seen_hi = seen_hi.max(p);
            }
        }
        assert!((seen_lo - lo).abs().max_element() < 1e-4);
        assert!((seen_hi - hi).abs().max_element() < 1e-4);
    }

    #[test]
    fn support_points_are_the_farthest_points() {
        let c = cone45();
        // Pointing down the shaft's opposite (−y): the apex.
        assert_eq!(support_point_local(&c, -DVec3::Y), DVec3::ZERO);
        // Sideways: a rim point.
        let s = support_point_local(&c, DVec3::X);
        assert!((s - DVec3::new(0.01, 0.01, 0.0)).length() < 1e-12);
        let sphere = ToolShape::sphere(0.005).unwrap();
        let p = support_point_local(&sphere, DVec3::new(0.0, -2.0, 0.0));
        assert!(p.length() < 1e-15);
        assert_eq!(support_point_local(&sphere, DVec3::ZERO), DVec3::Y * 0.005);
        // In the parent frame, through a rotation.
        let pose = Pose {
            position_m: DVec3::new(1.0, 0.0, 0.0),
            orientation: DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2),
        };
        let w = support_point(&sphere, &pose, DVec3::X);
        assert!((w - DVec3::new(1.0, 0.0, 0.0)).length() < 1e-12);
    }

    #[test]
    fn depth_bound_is_the_tip_height() {
        assert_eq!(max_depth_m(&ToolShape::sphere(0.005).unwrap()), 0.01);
        assert!((max_depth_m(&cone45()) - 0.01).abs() < 1e-12);
    }
}
