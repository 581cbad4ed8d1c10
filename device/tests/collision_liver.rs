//! The procedural liver: a closed, outward-oriented haptic mesh that agrees with the render
//! surface, touched from above, from below and from random poses.

// In tests a panic is the failure report.
#![allow(clippy::unwrap_used)]

use std::cell::RefCell;
use std::collections::HashMap;

use glam::{DQuat, DVec3};
use proptest::prelude::*;
use softhaptic_device::collision::{Collider, CollisionMode};
use softhaptic_device::liver;
use softhaptic_device::mesh::HapticMesh;
use softhaptic_device::shape;
use softhaptic_proto::{Pose, ToolShape};

thread_local! {
    static LIVER: RefCell<Collider> =
        RefCell::new(Collider::new(liver::haptic_mesh(), CollisionMode::Continuous));
    static LIVER_PAPER: RefCell<Collider> =
        RefCell::new(Collider::new(liver::haptic_mesh(), CollisionMode::PaperVertices));
    static GRID: RefCell<Collider> =
        RefCell::new(Collider::new(HapticMesh::grid(30, 0.1), CollisionMode::Continuous));
}

#[test]
fn haptic_mesh_is_closed_and_consistently_wound() {
    let mesh = liver::haptic_mesh();
    assert_eq!(mesh.positions_m().len(), 10_242);
    // Every directed edge once, and its reverse once: closed, two-manifold, consistent winding.
    let mut directed: HashMap<(u32, u32), usize> = HashMap::new();
    for t in mesh.triangles() {
        for k in 0..3 {
            *directed.entry((t[k], t[(k + 1) % 3])).or_default() += 1;
        }
    }
    for (&(a, b), &n) in &directed {
        assert_eq!(n, 1, "edge {a}→{b} used {n} times");
        assert_eq!(directed.get(&(b, a)), Some(&1), "edge {a}→{b} has no twin");
    }
    // Outward: the enclosed volume (divergence theorem) is positive and about liver-sized.
    let volume_m3: f64 = mesh
        .triangles()
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.positions_m()[i as usize]);
            a.dot(b.cross(c)) / 6.0
        })
        .sum();
    assert!((5e-4..3e-3).contains(&volume_m3), "volume {volume_m3} m³");
}

#[test]
fn vertex_normals_point_out() {
    // A millimetre along each vertex normal is outside, a millimetre against it inside, as
    // judged by the collider's signed distance; every 7th vertex.
    LIVER.with_borrow_mut(|c| {
        let mesh = liver::haptic_mesh();
        for (p, n) in mesh.positions_m().iter().zip(mesh.normals()).step_by(7) {
            assert!((n.length() - 1.0).abs() < 1e-12);
            let out = c.closest_surface_point(*p + *n * 1e-3, 0.01).unwrap();
            let inn = c.closest_surface_point(*p - *n * 1e-3, 0.01).unwrap();
            assert!(
                out.signed_distance_m > 0.9e-3,
                "{p}: {}",
                out.signed_distance_m
            );
            assert!(
                inn.signed_distance_m < -0.9e-3,
                "{p}: {}",
                inn.signed_distance_m
            );
        }
    });
}

#[test]
fn render_surface_agrees_with_the_haptic_mesh() {
    let (render, render_triangles) = liver::render_surface();
    assert!(render.len() >= 100_000);
    assert_eq!(render_triangles.len(), 2 * render.len() - 4);
    let haptic = liver::haptic_mesh();
    assert_eq!(&render[..haptic.positions_m().len()], haptic.positions_m());
    // Render vertices between the haptic ones lie within the coarse triangles' chord error.
    let mut worst: f64 = 0.0;
    LIVER.with_borrow_mut(|c| {
        for p in render.iter().skip(haptic.positions_m().len()) {
            let s = c.closest_surface_point(*p, 0.01).unwrap();
            worst = worst.max(s.signed_distance_m.abs());
        }
    });
    // 0.035 mm measured, worst on the flanks of the notch.
    assert!(
        worst < 0.1e-3,
        "render and haptic surfaces differ by {worst} m"
    );
}

#[test]
fn pressing_the_top_contact_along_its_normal() {
    let top = liver::top_contact();
    let tool = ToolShape::sphere(0.005).unwrap();
    // Shaft along the normal, tip pushed 2 mm into the surface.
    let orientation = DQuat::from_rotation_arc(DVec3::Y, top.normal);
    LIVER.with_borrow_mut(|c| {
        let mut last = 0.0;
        for k in 0..=40 {
            let d = k as f64 * 1e-4;
            let pose = Pose {
                position_m: top.point_m - top.normal * d,
                orientation,
            };
            let g = c.query(&tool, &pose);
            let depth = g.map_or(0.0, |g| g.depth_m);
            // Within the chord error (0.1 mm) of the smooth surface the test point lies on,
            // and continuous while pressing.
            assert!((depth - d).abs() < 2e-4, "{d}: {depth}");
            assert!(depth >= last - 1e-9 && depth - last < 1e-4 + 1e-9);
            last = depth;
            if let Some(g) = g {
                assert!(g.normal.dot(top.normal) > 0.99);
            }
        }
    });
}

#[test]
fn entering_from_below_pushes_back_down_and_stays_bounded() {
    // The tool points down (identity orientation) but rises from under the organ, through it,
    // and out of its top: the far side is met first, the depth never exceeds the tip's
    // height, and inside the organ, out of reach of any surface, there is no contact.
    let tool = ToolShape::sphere(0.005).unwrap();
    let x = liver::top_contact().point_m.x;
    let bound = shape::max_depth_m(&tool);
    let mut first_normal = None;
    let mut lost_inside = false;
    LIVER.with_borrow_mut(|c| {
        for k in 0..=200 {
            let y = -0.08 + k as f64 * 1e-3;
            let g = c.query(&tool, &Pose::from_position(DVec3::new(x, y, 0.0)));
            match g {
                Some(g) => {
                    assert!(g.depth_m > 0.0 && g.depth_m <= bound, "{y}: {}", g.depth_m);
                    assert!((g.normal.length() - 1.0).abs() < 1e-12);
                    first_normal.get_or_insert(g.normal);
                }
                None if first_normal.is_some() && y < 0.0 => lost_inside = true,
                None => {}
            }
        }
    });
    let first = first_normal.expect("the underside is touched");
    assert!(first.y < -0.5, "underside normal points down: {first}");
    assert!(lost_inside, "deep inside, no surface is in reach");
}

/// End points of the edge whose midpoint is highest.
fn coarse_top_edge(mesh: &HapticMesh) -> (DVec3, DVec3) {
    let p = mesh.positions_m();
    mesh.triangles()
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .map(|(i, j)| (p[i as usize], p[j as usize]))
        .max_by(|x, y| (x.0.y + x.1.y).total_cmp(&(y.0.y + y.1.y)))
        .unwrap()
}

#[test]
fn sliding_over_a_coarse_curved_organ_has_no_jumps_in_continuous_mode() {
    // The organ at subdivision 2 (162 vertices, edges of 2–3 cm) against a 5 mm sphere held
    // 4 mm under its highest edge while it slides along it, past both ends: the continuous depth
    // may follow the facets but never jumps (it is 1-Lipschitz in the tip position); the paper
    // mode feels the two vertices only, and jumps.
    let coarse = liver::mesh(2);
    let (a, b) = coarse_top_edge(&coarse);
    let mut continuous = Collider::new(coarse.clone(), CollisionMode::Continuous);
    let mut paper = Collider::new(coarse, CollisionMode::PaperVertices);
    let tool = ToolShape::sphere(0.005).unwrap();
    let path: Vec<DVec3> = (0..=800)
        .map(|k| a + (b - a) * (-0.2 + 1.4 * k as f64 / 800.0) - DVec3::Y * 0.004)
        .collect();
    let step_m = path
        .windows(2)
        .map(|w| (w[1] - w[0]).length())
        .fold(0.0, f64::max);
    let (mut last, mut last_paper): (Option<f64>, f64) = (None, 0.0);
    let (mut worst_step, mut worst_paper_step): (f64, f64) = (0.0, 0.0);
    let mut touching = 0;
    for tip in &path {
        let pose = Pose::from_position(*tip);
        let d = continuous.query(&tool, &pose).map_or(0.0, |g| g.depth_m);
        if let Some(previous) = last {
            worst_step = worst_step.max((d - previous).abs());
        }
        touching += usize::from(d > 0.0);
        last = Some(d);
        let p = paper.query(&tool, &pose).map_or(0.0, |g| g.depth_m);
        worst_paper_step = worst_paper_step.max((p - last_paper).abs());
        last_paper = p;
    }
    assert!(
        touching == path.len(),
        "the slide stays in contact: {touching}"
    );
    assert!(worst_step <= step_m + 1e-12, "continuous step {worst_step}");
    assert!(worst_paper_step > 1e-3, "paper step {worst_paper_step}");
}

#[test]
fn independent_builds_answer_bit_for_bit_alike() {
    // Deterministic replay (docs/design.md invariant 5) needs the tree, and so the tie-breaks
    // between equally close triangles, to be the same in every process.
    let tool = ToolShape::cone(0.6, 0.008).unwrap();
    for mode in [CollisionMode::Continuous, CollisionMode::PaperVertices] {
        let mut a = Collider::new(liver::haptic_mesh(), mode);
        let mut b = Collider::new(liver::haptic_mesh(), mode);
        let top = liver::top_contact();
        let mut contacts = 0;
        for k in 0..500 {
            let t = k as f64 * 0.02;
            let pose = Pose {
                position_m: top.point_m + DVec3::new(0.01 * t.sin(), -0.004 * t.cos(), 0.01 * t),
                orientation: DQuat::from_rotation_z(0.2 * t.sin()),
            };
            let (ga, gb) = (a.query(&tool, &pose), b.query(&tool, &pose));
            assert_eq!(ga, gb, "{mode:?} step {k}");
            contacts += usize::from(ga.is_some());
        }
        assert!(contacts > 20, "{mode:?}: {contacts}");
    }
}

fn tool_strategy() -> impl Strategy<Value = ToolShape> {
    prop_oneof![
        (0.001f64..0.02).prop_map(|r| ToolShape::sphere(r).unwrap()),
        (0.1f64..1.4, 0.001f64..0.02).prop_map(|(a, r)| ToolShape::cone(a, r).unwrap()),
    ]
}

fn pose_strategy(half_extent_m: f64) -> impl Strategy<Value = Pose> {
    (
        -half_extent_m..half_extent_m,
        -half_extent_m..half_extent_m,
        -half_extent_m..half_extent_m,
        -1.0f64..1.0,
        -1.0f64..1.0,
        -1.0f64..1.0,
        -1.0f64..1.0,
    )
        .prop_map(|(x, y, z, qx, qy, qz, qw)| Pose {
            position_m: DVec3::new(x, y, z),
            // Any quaternion, normalised by the collider (or refused if ~0).
            orientation: DQuat::from_xyzw(qx, qy, qz, qw),
        })
}

fn check_contact(tool: &ToolShape, g: &softhaptic_device::collision::ContactGeometry) {
    assert!(g.depth_m.is_finite() && g.depth_m >= 0.0, "{g:?}");
    assert!(g.depth_m <= shape::max_depth_m(tool), "{g:?}");
    assert!((g.normal.length() - 1.0).abs() < 1e-9, "{g:?}");
    assert!(g.contact_point_m.is_finite(), "{g:?}");
}

/// Depth, or `None` when the answer is out of contact or clamped (where continuity is not
/// promised: the clamp and the reach are documented edges).
fn free_depth(g: Option<softhaptic_device::collision::ContactGeometry>) -> Option<f64> {
    match g {
        Some(g) if g.depth_clamped => None,
        Some(g) => Some(g.depth_m),
        None => Some(0.0),
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn random_poses_on_the_liver_are_sane(tool in tool_strategy(), pose in pose_strategy(0.13)) {
        for collider in [&LIVER, &LIVER_PAPER] {
            collider.with_borrow_mut(|c| {
                if let Some(g) = c.query(&tool, &pose) {
                    check_contact(&tool, &g);
                }
            });
        }
    }

    #[test]
    fn random_poses_on_a_grid_are_sane_and_continuous(
        tool in tool_strategy(),
        pose in pose_strategy(0.05),
        direction in (-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0),
    ) {
        let moved = Pose {
            position_m: pose.position_m
                + DVec3::from(direction).normalize_or(DVec3::X) * 1e-6,
            ..pose
        };
        GRID.with_borrow_mut(|c| {
            let a = c.query(&tool, &pose);
            let b = c.query(&tool, &moved);
            for g in [a, b].into_iter().flatten() {
                check_contact(&tool, &g);
            }
            // δ is 1-Lipschitz in the tool's position: the sphere's δ is R minus a distance,
            // the cone's is a support-point depth below the grid's plane.
            if let (Some(da), Some(db)) = (free_depth(a), free_depth(b)) {
                prop_assert!((da - db).abs() <= 1e-6 + 1e-12, "{da} vs {db}");
            }
            Ok(())
        })?;
    }

    #[test]
    fn sphere_depth_is_continuous_on_the_liver(
        radius_m in 0.001f64..0.02,
        pose in pose_strategy(0.13),
        direction in (-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0),
    ) {
        let tool = ToolShape::sphere(radius_m).unwrap();
        let moved = Pose {
            position_m: pose.position_m
                + DVec3::from(direction).normalize_or(DVec3::X) * 1e-6,
            ..pose
        };
        LIVER.with_borrow_mut(|c| {
            if let (Some(da), Some(db)) =
                (free_depth(c.query(&tool, &pose)), free_depth(c.query(&tool, &moved)))
            {
                prop_assert!((da - db).abs() <= 1e-6 + 1e-12, "{da} vs {db}");
            }
            Ok(())
        })?;
    }
}
