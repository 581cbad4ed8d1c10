//! The extremes of docs/design.md invariant 4, for both collision modes: tool far away, grazing
//! contact, tip exactly on a vertex or an edge, normals that cancel, depth past the tool radius,
//! and poses or tools that are not valid.

// In tests a panic is the failure report.
#![allow(clippy::unwrap_used)]

use glam::{DQuat, DVec3};
use softhaptic_device::collision::{Collider, CollisionMode};
use softhaptic_device::mesh::HapticMesh;
use softhaptic_device::shape;
use softhaptic_proto::{Pose, ToolShape};

const MODES: [CollisionMode; 2] = [CollisionMode::Continuous, CollisionMode::PaperVertices];

/// 21 × 21 vertices over 0.1 m: 5 mm spacing, vertices at multiples of 5 mm.
fn grid(mode: CollisionMode) -> Collider {
    Collider::new(HapticMesh::grid(21, 0.1), mode)
}

fn sphere() -> ToolShape {
    ToolShape::sphere(0.005).unwrap()
}

#[test]
fn tool_far_away_is_out_of_contact() {
    for mode in MODES {
        let mut c = grid(mode);
        for p in [
            DVec3::new(0.0, 1.0, 0.0),
            DVec3::new(10.0, 0.0, 0.0),
            DVec3::new(0.0, -1.0, 0.0),
            DVec3::new(1e12, -1e12, 1e12),
        ] {
            assert_eq!(
                c.query(&sphere(), &Pose::from_position(p)),
                None,
                "{mode:?} {p}"
            );
        }
    }
}

#[test]
fn grazing_contact_starts_at_zero_depth() {
    for mode in MODES {
        let mut c = grid(mode);
        let above = Pose::from_position(DVec3::new(0.0, 1e-12, 0.0));
        assert_eq!(c.query(&sphere(), &above), None, "{mode:?}");
        let touching = Pose::from_position(DVec3::new(0.0, -1e-12, 0.0));
        let g = c
            .query(&sphere(), &touching)
            .expect("grazing contact is a contact");
        assert!((g.depth_m - 1e-12).abs() < 1e-15, "{mode:?}: {}", g.depth_m);
        assert!((g.normal - DVec3::Y).length() < 1e-12);
    }
}

#[test]
fn tip_exactly_on_a_vertex_and_on_an_edge() {
    // On the vertex at the origin, on the edge between (0,0,0) and (5 mm,0,0), and on the
    // diagonal edge of a cell: both modes agree where the paper mode sees a vertex, and the
    // continuous mode gives the same depth everywhere.
    for tip in [
        DVec3::new(0.0, -0.001, 0.0),
        DVec3::new(0.0025, -0.001, 0.0),
        DVec3::new(0.0025, -0.001, 0.0025),
    ] {
        let mut continuous = grid(CollisionMode::Continuous);
        let c = continuous
            .query(&sphere(), &Pose::from_position(tip))
            .unwrap();
        assert!((c.depth_m - 0.001).abs() < 1e-12, "{tip}");
        assert!((c.normal - DVec3::Y).length() < 1e-12);
        // A nanometre away, nothing changes: the answer does not depend on which of the
        // triangles sharing the vertex or edge was found first.
        for d in [DVec3::X, DVec3::Z, -DVec3::X, -DVec3::Z] {
            let near = continuous
                .query(&sphere(), &Pose::from_position(tip + d * 1e-9))
                .unwrap();
            assert!((near.depth_m - c.depth_m).abs() < 1e-15);
            assert!((near.normal - c.normal).length() < 1e-12);
        }
    }
    let mut paper = grid(CollisionMode::PaperVertices);
    let on_vertex = paper
        .query(
            &sphere(),
            &Pose::from_position(DVec3::new(0.0, -0.001, 0.0)),
        )
        .unwrap();
    assert!((on_vertex.depth_m - 0.001).abs() < 1e-12);
    assert!(on_vertex.contact_point_m.length() < 1e-12);
}

/// A two-sided sheet: every triangle twice, with both windings, on shared vertices, so every
/// vertex normal cancels to zero.
fn two_sided_sheet() -> HapticMesh {
    let g = HapticMesh::grid(5, 0.1);
    let mut triangles = g.triangles().to_vec();
    triangles.extend(g.triangles().iter().map(|&[a, b, c]| [a, c, b]));
    HapticMesh::new(g.positions_m().to_vec(), triangles).unwrap()
}

#[test]
fn cancelling_normals_fall_back_to_the_shaft_direction() {
    let sheet = two_sided_sheet();
    assert!(sheet.normals().iter().all(|n| *n == DVec3::ZERO));
    let tilt = DQuat::from_rotation_x(0.3);
    let shaft = tilt * DVec3::Y;
    for mode in MODES {
        let mut c = Collider::new(sheet.clone(), mode);
        let pose = Pose {
            position_m: DVec3::new(0.0, -0.001, 0.0),
            orientation: tilt,
        };
        let g = c.query(&sphere(), &pose).expect("the sheet is touched");
        assert!(g.degenerate_normal, "{mode:?}");
        assert!(
            (g.normal - shaft).length() < 1e-12,
            "{mode:?}: {:?}",
            g.normal
        );
        assert!(
            g.depth_m.is_finite() && g.depth_m > 0.0,
            "{mode:?}: {}",
            g.depth_m
        );
        assert!(g.depth_m <= shape::max_depth_m(&sphere()));
    }
}

#[test]
fn depth_past_the_tool_radius_is_finite_then_clamped() {
    let tool = sphere();
    let mut continuous = grid(CollisionMode::Continuous);
    // 8 mm deep, past the 5 mm radius: measured as is.
    let g = continuous
        .query(&tool, &Pose::from_position(DVec3::new(0.001, -0.008, 0.0)))
        .unwrap();
    assert!((g.depth_m - 0.008).abs() < 1e-12 && !g.depth_clamped);
    // 12 mm deep: the whole ball is under the plane; clamped to its 10 mm height.
    let g = continuous
        .query(&tool, &Pose::from_position(DVec3::new(0.001, -0.012, 0.0)))
        .unwrap();
    assert_eq!(g.depth_m, 0.010);
    assert!(g.depth_clamped);
    assert!((g.normal - DVec3::Y).length() < 1e-12);
    // Past the reach (bounding radius + depth bound = 15 mm from the centre): out of reach.
    assert_eq!(
        continuous.query(&tool, &Pose::from_position(DVec3::new(0.001, -0.03, 0.0))),
        None
    );
    // The paper mode measures vertices inside the ball: 8 mm is felt, and once the ball has
    // passed through the plane no vertex is inside any more.
    let mut paper = grid(CollisionMode::PaperVertices);
    let g = paper
        .query(&tool, &Pose::from_position(DVec3::new(0.0, -0.008, 0.0)))
        .unwrap();
    assert!((g.depth_m - 0.008).abs() < 1e-12);
    assert_eq!(
        paper.query(&tool, &Pose::from_position(DVec3::new(0.0, -0.012, 0.0))),
        None
    );
}

#[test]
fn invalid_poses_and_tools_give_no_contact_and_no_panic() {
    let nan = f64::NAN;
    let bad_poses = [
        Pose::from_position(DVec3::new(nan, 0.0, 0.0)),
        Pose::from_position(DVec3::new(0.0, f64::INFINITY, 0.0)),
        Pose {
            position_m: DVec3::ZERO,
            orientation: DQuat::from_xyzw(nan, 0.0, 0.0, 1.0),
        },
        Pose {
            position_m: DVec3::new(0.0, -0.001, 0.0),
            orientation: DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0),
        },
    ];
    let bad_tools = [
        ToolShape::Sphere { radius_m: nan },
        ToolShape::Sphere { radius_m: 0.0 },
        ToolShape::Sphere { radius_m: -0.01 },
        ToolShape::Cone {
            half_angle_rad: 2.0,
            radius_m: 0.01,
        },
    ];
    for mode in MODES {
        let mut c = grid(mode);
        for pose in &bad_poses {
            assert_eq!(c.query(&sphere(), pose), None, "{mode:?} {pose:?}");
        }
        let inside = Pose::from_position(DVec3::new(0.0, -0.001, 0.0));
        for tool in &bad_tools {
            assert_eq!(c.query(tool, &inside), None, "{mode:?} {tool:?}");
        }
        // A quaternion that is not unit length is normalised, not rejected.
        let scaled = Pose {
            position_m: inside.position_m,
            orientation: DQuat::from_xyzw(0.0, 0.0, 0.0, 2.0),
        };
        assert_eq!(c.query(&sphere(), &scaled), c.query(&sphere(), &inside));
        assert_eq!(c.closest_surface_point(DVec3::NAN, 1.0), None);
        assert_eq!(c.closest_surface_point(DVec3::ZERO, f64::NAN), None);
    }
}
