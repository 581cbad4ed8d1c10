//! One haptic step (collision + contact law + damping) on the paper's timing surfaces.
//!
//! The surfaces of the paper's Table 1 (flat 0.1 m grids of 40² … 100² vertices) plus 316² and
//! 1000² vertices, a 10 mm sphere 5 mm deep, in both collision modes. The tip circles 1 mm
//! around the grid centre so consecutive steps do not repeat the same pose.
//!
//! `palpation_step` is the whole world step (collision, model, safety) on a 100² grid with 0, 1
//! and 5 stiffer inclusions from the committed FEM table, the tip sliding 1 mm around the first
//! one's centre, where every inclusion is read.
//!
//! `guide_step` is one tick of haptic guidance (the target's search near the previous one and
//! the pull) on a 1 m expert path resampled every 1 mm, the tip moving along it.
//!
//! `cargo bench -p softhaptic-device --bench haptic_step`; the step report
//! (`cargo run --release -p softhaptic-device --features tools --bin step-report`) prints the same step side by
//! side with the paper's figures. Measurement windows are short: CI machines have two cores.

use std::hint::black_box;
use std::time::Duration;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use glam::DVec3;
use softhaptic_device::collision::{Collider, CollisionMode, timing_step_force_n};
use softhaptic_device::device::{DeviceLimits, DeviceSample};
use softhaptic_device::force::ForceConfig;
use softhaptic_device::inclusion::InclusionField;
use softhaptic_device::mesh::HapticMesh;
use softhaptic_device::world::HapticWorld;
use softhaptic_proto::{ContactFlags, Inclusion, InclusionTable, Material, Pose, ToolShape};

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

fn palpation_step(c: &mut Criterion) {
    let table: InclusionTable = serde_json::from_str(include_str!(
        "../../scenes/calibration/inclusion_sphere10_50kpa.json"
    ))
    .expect("the committed inclusion table parses");
    let tool = ToolShape::sphere(0.01).expect("a 10 mm sphere is a valid tool");
    let collider = Collider::new(HapticMesh::grid(100, 0.1), CollisionMode::Continuous);
    // Five inclusions 5 mm apart around the path, so that each is within the table's reach.
    let inclusions: Vec<Inclusion> = (0..5)
        .map(|k| Inclusion {
            centre_in_object_m: [0.005 * k as f64 - 0.01, -0.01, 0.002],
            radius_m: 0.005,
            stiffness_ratio: 4.0,
            centre_depth_m: 0.01,
        })
        .collect();
    let path: Vec<Pose> = (0..64)
        .map(|k| {
            let a = k as f64 / 64.0 * std::f64::consts::TAU;
            Pose::from_position(DVec3::new(0.001 * a.cos(), -0.003, 0.001 * a.sin()))
        })
        .collect();
    let mut group = c.benchmark_group("palpation_step");
    group
        .sample_size(20)
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_secs(1));
    for count in [0usize, 1, 5] {
        let world = HapticWorld::new(
            collider.clone(),
            Pose::IDENTITY,
            tool,
            Material::PAPER_SOFT,
            ForceConfig::for_tool(&tool),
            DeviceLimits::PHANTOM_DESKTOP,
        );
        let mut world = if count == 0 {
            world
        } else {
            let field = InclusionField::new(table.clone(), &inclusions[..count])
                .expect("the table covers the inclusions");
            world.with_inclusions(field)
        };
        let mut k = 0u64;
        group.bench_function(BenchmarkId::new("inclusions", count), |b| {
            b.iter(|| {
                k += 1;
                let pose = path[(k % 64) as usize];
                black_box(world.step(Ok(DeviceSample {
                    time_ns: k * 1_000_000,
                    tip_in_world: black_box(pose),
                    tip_velocity_m_s: DVec3::new(0.01, 0.0, 0.0),
                    buttons: 0,
                    flags: ContactFlags::empty(),
                })))
            })
        });
    }
    group.finish();
}

fn guide_step(c: &mut Criterion) {
    use softhaptic_device::guide::{Guide, GuideParams, GuidePath};
    // A 1 m wavy path (1000 points): the search must stay local for the cost to stay flat.
    let path = GuidePath::resample(
        (0..=2000).map(|i| {
            let x = i as f64 * 0.0005;
            (DVec3::new(x, 0.0, 0.01 * (x * 40.0).sin()), 0.002)
        }),
        0.001,
    )
    .expect("the path guides");
    let mut guide = Guide::new(path, GuideParams::default());
    let mut t: u64 = 0;
    let mut group = c.benchmark_group("guide_step");
    group.measurement_time(Duration::from_secs(2));
    group.bench_function("1000_points", |b| {
        b.iter(|| {
            t += 1;
            let x = (t % 1_000_000) as f64 * 1e-6;
            let tip = DVec3::new(x, 0.002, 0.01 * (x * 40.0).sin() + 0.003);
            black_box(guide.step(
                black_box(tip),
                DVec3::new(0.1, 0.0, 0.0),
                None,
                t * 1_000_000,
            ))
        })
    });
    group.finish();
}

criterion_group!(benches, haptic_step, palpation_step, guide_step);
criterion_main!(benches);
