//! A mesh coarser than the tool tip: 20 mm grid spacing against a 5 mm sphere and a 45° cone.
//!
//! The paper's vertex test only feels the surface where a vertex falls inside the tip; the
//! continuous mode must feel it everywhere. Each test checks both, so a regression in either
//! mode (or the paper mode silently becoming continuous) fails.

// In tests a panic is the failure report.
#![allow(clippy::unwrap_used)]

use std::f64::consts::FRAC_PI_4;

use glam::{DQuat, DVec3};
use softhaptic_device::collision::{Collider, CollisionMode};
use softhaptic_device::mesh::HapticMesh;
use softhaptic_proto::{Pose, ToolShape};

/// 11 × 11 vertices over 0.2 m: vertices every 20 mm at x, z ∈ {−0.1, −0.08, …, 0.1}.
fn coarse(mode: CollisionMode) -> Collider {
    Collider::new(HapticMesh::grid(11, 0.2), mode)
}

fn sphere() -> ToolShape {
    ToolShape::sphere(0.005).unwrap()
}

fn cone() -> ToolShape {
    ToolShape::cone(FRAC_PI_4, 0.01).unwrap()
}

fn depth(collider: &mut Collider, tool: &ToolShape, tip_m: DVec3) -> f64 {
    collider
        .query(tool, &Pose::from_position(tip_m))
        .map_or(0.0, |c| c.depth_m)
}

#[test]
fn grid_sizes_match_table_1() {
    // The paper's Table 1 (`docs/physics.md`, "The paper's numbers and ours"): vertices, edges
    // and triangles of its N × N surfaces.
    let table = [
        (40, 1600, 4641, 3042),
        (50, 2500, 7301, 4802),
        (60, 3600, 10561, 6962),
        (70, 4900, 14421, 9522),
        (80, 6400, 18881, 12482),
        (90, 8100, 23941, 15842),
        (100, 10000, 29601, 19602),
    ];
    for (n, vertices, edges, triangles) in table {
        let g = HapticMesh::grid(n, 0.1);
        assert_eq!(g.positions_m().len(), vertices, "{n}²");
        assert_eq!(g.triangles().len(), triangles, "{n}²");
        // Euler's formula for a disc: V − E + F = 1.
        assert_eq!(vertices + triangles - 1, edges, "{n}²");
        let mut unique = std::collections::BTreeSet::new();
        for t in g.triangles() {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                unique.insert((a.min(b), a.max(b)));
            }
        }
        assert_eq!(unique.len(), edges, "{n}²");
    }
}

#[test]
fn entry_between_vertices_is_felt_only_in_continuous_mode() {
    let cell_centre = DVec3::new(0.01, -0.001, 0.01);
    for tool in [sphere(), cone()] {
        let mut continuous = coarse(CollisionMode::Continuous);
        let mut paper = coarse(CollisionMode::PaperVertices);
        let pose = Pose::from_position(cell_centre);
        let c = continuous
            .query(&tool, &pose)
            .expect("continuous mode feels the surface");
        assert!((c.depth_m - 0.001).abs() < 1e-12, "{tool:?}: {}", c.depth_m);
        assert!((c.normal - DVec3::Y).length() < 1e-12);
        assert!((c.contact_point_m - DVec3::new(0.01, 0.0, 0.01)).length() < 1e-12);
        assert!(!c.degenerate_normal && !c.depth_clamped);
        assert_eq!(
            paper.query(&tool, &pose),
            None,
            "{tool:?}: no vertex is inside the tip"
        );
    }
}

#[test]
fn pressing_is_continuous_and_monotone_in_continuous_mode_and_jumps_in_paper_mode() {
    // 3 mm beside a vertex: the sphere swallows the vertex once 1 mm deep
    // (5 − √(5² − 3²) = 1 mm), the cone once 3 mm deep.
    let step_m = 2e-5;
    for (tool, swallow_m) in [(sphere(), 0.001), (cone(), 0.003)] {
        let mut continuous = coarse(CollisionMode::Continuous);
        let mut paper = coarse(CollisionMode::PaperVertices);
        let mut last = 0.0;
        let mut paper_last = 0.0;
        let mut paper_jump: f64 = 0.0;
        for k in 0..250 {
            let y = 0.0005 - k as f64 * step_m;
            let tip = DVec3::new(0.003, y, 0.0);
            let d = depth(&mut continuous, &tool, tip);
            assert!(d >= last, "{tool:?} not monotone at y = {y}");
            assert!(d - last <= step_m + 1e-12, "{tool:?} jumps at y = {y}");
            assert!((d - (-y).max(0.0)).abs() < 1e-12);
            last = d;
            let p = depth(&mut paper, &tool, tip);
            paper_jump = paper_jump.max(p - paper_last);
            paper_last = p;
        }
        // Paper mode stays at zero until the vertex enters, then jumps to the full depth.
        assert!(
            (paper_jump - swallow_m).abs() < 2.0 * step_m,
            "{tool:?}: paper jump {paper_jump}"
        );
    }
}

/// Slides 60 mm along a line through a row of vertices at constant height; returns the
/// depths (0 when out of contact).
fn slide(collider: &mut Collider, tool: &ToolShape, tip_y_m: f64) -> Vec<f64> {
    (0..=600)
        .map(|k| {
            let x = -0.03 + k as f64 * 1e-4;
            depth(collider, tool, DVec3::new(x, tip_y_m, 0.0))
        })
        .collect()
}

#[test]
fn sliding_is_flat_in_continuous_mode_and_bumps_in_paper_mode() {
    // δ = 2 mm. The sphere holds a vertex while within √(5² − 3²) = 4 mm of it, so 8 mm of
    // every 20 mm (40 %); the 45° cone within 2 mm of it (20 %).
    for (tool, fraction) in [(sphere(), 0.4), (cone(), 0.2)] {
        let mut continuous = coarse(CollisionMode::Continuous);
        let smooth = slide(&mut continuous, &tool, -0.002);
        for d in &smooth {
            assert!((d - 0.002).abs() < 1e-12, "{tool:?}: {d}");
        }
        let mut paper = coarse(CollisionMode::PaperVertices);
        let bumpy = slide(&mut paper, &tool, -0.002);
        let max = bumpy.iter().cloned().fold(0.0, f64::max);
        let min = bumpy.iter().cloned().fold(f64::INFINITY, f64::min);
        // The bump is the whole indentation: 2 mm felt over a vertex, nothing between them.
        assert!(
            (max - min - 0.002).abs() < 1e-12,
            "{tool:?}: bump {}",
            max - min
        );
        let touching = bumpy.iter().filter(|d| **d > 0.0).count() as f64 / bumpy.len() as f64;
        assert!((touching - fraction).abs() < 0.01, "{tool:?}: {touching}");
    }
}

#[test]
fn tilted_cone_touches_with_its_rim_on_a_coarse_grid() {
    // Cone tilted 60° about z: its rim, not its apex, is the lowest point. The continuous mode
    // measures the support point along −n, so δ is the rim's depth below the plane.
    let tool = cone();
    let tilt = DQuat::from_rotation_z(60f64.to_radians());
    let apex_local_rim = tilt * DVec3::new(0.01, 0.01, 0.0);
    let rim_below = tilt * DVec3::new(-0.01, 0.01, 0.0);
    let lowest = apex_local_rim.y.min(rim_below.y).min(0.0);
    assert!(
        lowest < -0.003,
        "the rim must hang below the apex: {lowest}"
    );
    let mut continuous = coarse(CollisionMode::Continuous);
    let tip = DVec3::new(0.01, 0.001 - lowest, 0.01);
    // 1 mm above the plane: no contact.
    let pose = Pose {
        position_m: tip,
        orientation: tilt,
    };
    assert_eq!(continuous.query(&tool, &pose), None);
    // 1 mm below.
    let pose = Pose {
        position_m: tip - DVec3::Y * 0.002,
        orientation: tilt,
    };
    let c = continuous.query(&tool, &pose).unwrap();
    assert!((c.depth_m - 0.001).abs() < 1e-12, "{}", c.depth_m);
    assert!(c.contact_point_m.y.abs() < 1e-12);
    assert!((c.normal - DVec3::Y).length() < 1e-12);
}
