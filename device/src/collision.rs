//! Collision of the tool tip with the haptic mesh (paper §4.1).
//!
//! The API every caller uses: build a [`Collider`] once from a [`HapticMesh`], then call
//! [`Collider::query`] each tick. It never allocates after construction.

use glam::DVec3;
use softhaptic_proto::{Pose, ToolShape};

use crate::mesh::HapticMesh;

/// How the narrow phase finds the contact.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CollisionMode {
    /// The paper's method: mesh vertices inside the tool's implicit shape.
    PaperVertices,
    /// Continuous in the tool pose: depth measured against the triangles near the tip, so a
    /// mesh coarser than the tip is not felt.
    #[default]
    Continuous,
}

/// The geometric contact found by one query.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactGeometry {
    /// Indentation δ ≥ 0 along `normal`.
    pub depth_m: f64,
    /// Unit contact normal, object frame, pointing out of the object.
    pub normal: DVec3,
    /// Contact centre on the undeformed surface, object frame.
    pub contact_point_m: DVec3,
    /// True when the colliding normals cancelled and `normal` is a fallback.
    pub degenerate_normal: bool,
}

/// Collision queries against one haptic mesh.
pub struct Collider {
    mesh: HapticMesh,
    mode: CollisionMode,
}

impl Collider {
    pub fn new(mesh: HapticMesh, mode: CollisionMode) -> Self {
        Self { mesh, mode }
    }

    pub fn mesh(&self) -> &HapticMesh {
        &self.mesh
    }

    pub fn mode(&self) -> CollisionMode {
        self.mode
    }

    /// The contact of `tool` at `tip_in_object` (the tool frame in the mesh's frame), or `None`
    /// out of contact.
    pub fn query(&mut self, tool: &ToolShape, tip_in_object: &Pose) -> Option<ContactGeometry> {
        // Vertices inside the tool's implicit shape (the paper's narrow phase, brute force).
        let axis = tip_in_object.orientation * DVec3::Y;
        let mut sum_p = DVec3::ZERO;
        let mut sum_n = DVec3::ZERO;
        let mut count = 0usize;
        for (p, n) in self.mesh.positions_m().iter().zip(self.mesh.normals()) {
            if inside_tool(tool, tip_in_object, *p) {
                sum_p += *p;
                sum_n += *n;
                count += 1;
            }
        }
        if count == 0 {
            return None;
        }
        let centre = sum_p / count as f64;
        let (normal, degenerate_normal) = match sum_n.try_normalize() {
            Some(n) => (n, false),
            None => (-axis, true),
        };
        let depth_m = (centre - tip_in_object.position_m).dot(normal).max(0.0);
        Some(ContactGeometry {
            depth_m,
            normal,
            contact_point_m: centre,
            degenerate_normal,
        })
    }
}

/// Whether `point` (object frame) lies inside the tool tip.
pub fn inside_tool(tool: &ToolShape, tip_in_object: &Pose, point: DVec3) -> bool {
    let q = tip_in_object.inverse_transform_point(point);
    match *tool {
        ToolShape::Sphere { radius_m } => {
            (q - DVec3::Y * radius_m).length_squared() <= radius_m * radius_m
        }
        ToolShape::Cone {
            half_angle_rad,
            radius_m,
        } => {
            let rho = (q.x * q.x + q.z * q.z).sqrt();
            let height = radius_m / half_angle_rad.tan();
            q.y >= 0.0 && q.y <= height && rho <= q.y * half_angle_rad.tan()
        }
    }
}
