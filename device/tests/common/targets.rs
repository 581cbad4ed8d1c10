//! Where the pop-through tests put the tool in: a surface point of a mesh with its outward
//! normal, on the flat grid or on top of the liver's thick lobe.

// Each test binary that includes this uses part of it.
#![allow(dead_code)]

use glam::DVec3;
use softhaptic_device::liver;
use softhaptic_device::mesh::HapticMesh;

/// A surface point with its outward normal, on a mesh.
pub struct Target {
    pub mesh: HapticMesh,
    pub point_m: DVec3,
    pub normal: DVec3,
}

/// The flat grid, 1 mm spacing, at its centre vertex.
pub fn grid() -> Target {
    Target {
        mesh: HapticMesh::grid(81, 0.08),
        point_m: DVec3::ZERO,
        normal: DVec3::Y,
    }
}

/// The liver, on top of its thick lobe at the haptic mesh's vertex nearest
/// [`liver::top_contact`], along that vertex's normal: on a vertex, so that the paper's mode
/// starts a contact even for a tool smaller than the mesh spacing.
pub fn liver_top() -> Target {
    vertex_target(liver::haptic_mesh(), liver::top_contact().point_m)
}

/// The vertex of `mesh` nearest `near_m`, with its normal.
pub fn vertex_target(mesh: HapticMesh, near_m: DVec3) -> Target {
    let (index, _) = mesh
        .positions_m()
        .iter()
        .enumerate()
        .min_by(|a, b| {
            (*a.1 - near_m)
                .length()
                .total_cmp(&(*b.1 - near_m).length())
        })
        .expect("a mesh has vertices");
    Target {
        point_m: mesh.positions_m()[index],
        normal: mesh.normals()[index],
        mesh,
    }
}
