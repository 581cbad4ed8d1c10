//! One haptic step (collision + contact law + damping) on the paper's timing surfaces.
//!
//! The surfaces of the paper's Table 1 (flat 0.1 m grids of 40² … 100² vertices) plus 316² and
//! 1000² vertices, a 10 mm sphere 5 mm deep, in both collision modes. The tip circles 1 mm
//! around the grid centre so consecutive steps do not repeat the same pose.
//!
//! `cargo bench -p softhaptic-device --bench haptic_step`; the step report
//! (`cargo run --release -p softhaptic-device --features tools --bin step-report`) prints the same step side by
//! side with the paper's figures. Measurement windows are short: CI machines have two cores.

use std::hint::black_box;
use std::time::Duration;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use glam::DVec3;
use softhaptic_device::collision::{Collider, CollisionMode, timing_step_force_n};
use softhaptic_device::mesh::HapticMesh;
use softhaptic_proto::{Material, Pose, ToolShape};

/// Vertices per side: the paper's Table 1, then ≈ 10⁵ and 10⁶ vertices.
const SIDES: [usize; 9] = [40, 50, 60, 70, 80, 90, 100, 316, 1000];

/// Tip positions: 64 points on a 1 mm circle, 5 mm below the grid's plane.
fn tip_path() -> Vec<Pose> {
    (0..64)
        .map(|k| {
            let a = k as f64 / 64.0 * std::f64::consts::TAU;
            Pose::from_position(DVec3::new(0.001 * a.cos(), -0.005, 0.001 * a.sin()))
        })
        .collect()
}

fn haptic_step(c: &mut Criterion) {
    let tool = ToolShape::sphere(0.01).expect("a 10 mm sphere is a valid tool");
    let material = Material::PAPER_SOFT;
    let velocity_m_s = DVec3::new(0.01, -0.02, 0.0);
    let path = tip_path();
    let mut group = c.benchmark_group("haptic_step");
    group
        .sample_size(20)
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_secs(1));
    // In a debug build (`cargo test --all-targets` runs benches once) only the smallest grid:
    // building the 10⁶-vertex tree unoptimised would dominate the test run.
    let sides = if cfg!(debug_assertions) {
        &SIDES[..1]
    } else {
        &SIDES[..]
    };
    for &side in sides {
        let mut collider = Collider::new(HapticMesh::grid(side, 0.1), CollisionMode::Continuous);
        for (name, mode) in [
            ("continuous", CollisionMode::Continuous),
            ("paper", CollisionMode::PaperVertices),
        ] {
            collider.set_mode(mode);
            let mut k = 0usize;
            group.bench_function(BenchmarkId::new(name, side * side), |b| {
                b.iter(|| {
                    k = (k + 1) % path.len();
                    black_box(timing_step_force_n(
                        &mut collider,
                        &tool,
                        &material,
                        black_box(&path[k]),
                        velocity_m_s,
                        5.0,
                    ))
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, haptic_step);
criterion_main!(benches);
