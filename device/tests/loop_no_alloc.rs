//! The 1 kHz path never allocates (docs/design.md, invariant 1): counted with a global allocator,
//! once for the synchronous tick and once for the running loop thread. One test per binary, so
//! no other test's allocations are counted.

// Test code: a panic is how a failure is reported.
#![allow(clippy::unwrap_used)]

use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use glam::DVec3;
use softhaptic_device::collision::{Collider, CollisionMode};
use softhaptic_device::device::{DeviceLimits, HapticDevice};
use softhaptic_device::force::ForceConfig;
use softhaptic_device::haptic_loop::{HapticLoop, TickRecord};
use softhaptic_device::inclusion::InclusionField;
use softhaptic_device::liver;
use softhaptic_device::model::ForceModel;
use softhaptic_device::sim::{HandScript, SimParams, SimulatedPhantom};
use softhaptic_device::world::HapticWorld;
use softhaptic_proto::{
    ContactFlags, Inclusion, InclusionTable, Material, ModelSpec, Pose, ToolShape,
};

#[path = "common/counting_allocator.rs"]
mod counting_allocator;
use counting_allocator::ALLOCATIONS;

#[path = "common/liver_world.rs"]
mod liver_world;
use liver_world::{liver_world, test_loop};

fn setup(material: Material, spec: ModelSpec) -> (SimulatedPhantom, HapticWorld) {
    let top = liver::top_contact();
    let mut script = HandScript::press(top.point_m, top.normal, 0.015);
    script.approach_s = 0.05;
    script.press_s = 0.1;
    script.slide_s = 0.2;
    script.repeat = true;
    let tool = ToolShape::sphere(0.01).unwrap();
    let world = liver_world(ForceModel::new(tool, material, spec).unwrap());
    (SimulatedPhantom::new(script), world)
}

#[test]
fn ticks_do_not_allocate() {
    // Synchronous: press, hold, slide, release, repeat, through every safety limit; with the
    // paper's law and with the combined model, whose curvature changes as the tool slides (the
    // stiffness cap's depth is then found again on the tick).
    let combined = ModelSpec {
        exact_sphere: true,
        curvature: true,
        hyperelastic: true,
        ..ModelSpec::PAPER
    };
    for (material, spec) in [
        (Material::PAPER_SOFT, ModelSpec::PAPER),
        (Material::PAPER_STIFF, ModelSpec::PAPER),
        (Material::PAPER_SOFT, combined),
        (Material::PAPER_STIFF, combined),
    ] {
        let (mut device, mut world) = setup(material, spec);
        let before = ALLOCATIONS.load(Ordering::Relaxed);
        let mut touched = 0;
        for _ in 0..3000 {
            let state = world.step(device.read());
            touched += state.in_contact as u32;
            device.command_force(state.force_n).unwrap();
        }
        assert_eq!(ALLOCATIONS.load(Ordering::Relaxed), before);
        assert!(touched > 500);
    }

    // A 1 mm sphere that a grip ten times the default pushes 30 mm deep, in both collision
    // modes: the contact tracker holds it past the collision's reach, and that costs nothing
    // either.
    for mode in [CollisionMode::Continuous, CollisionMode::PaperVertices] {
        let top = liver::top_contact();
        let mesh = liver::haptic_mesh();
        let (vertex, _) = mesh
            .positions_m()
            .iter()
            .enumerate()
            .min_by(|a, b| {
                (*a.1 - top.point_m)
                    .length()
                    .total_cmp(&(*b.1 - top.point_m).length())
            })
            .unwrap();
        let mut script =
            HandScript::press(mesh.positions_m()[vertex], mesh.normals()[vertex], 0.03);
        script.repeat = true;
        let params = SimParams {
            hand_stiffness_n_per_m: 3000.0,
            ..SimParams::default()
        };
        let mut device = SimulatedPhantom::with_params(script, params);
        let tool = ToolShape::sphere(0.001).unwrap();
        let mut world = HapticWorld::with_model(
            Collider::new(mesh, mode),
            Pose::IDENTITY,
            ForceModel::new(tool, Material::PAPER_SOFT, combined).unwrap(),
            ForceConfig::for_tool(&tool),
            DeviceLimits::PHANTOM_DESKTOP,
        );
        let before = ALLOCATIONS.load(Ordering::Relaxed);
        let mut held = 0;
        for _ in 0..4000 {
            let state = world.step(device.read());
            held += state.flags.contains(ContactFlags::PUSHED_THROUGH) as u32;
            device.command_force(state.force_n).unwrap();
        }
        assert_eq!(ALLOCATIONS.load(Ordering::Relaxed), before, "{mode:?}");
        assert!(held > 1000, "{mode:?}: held {held} ticks");
    }

    // Palpation: the combined model with five stiffer inclusions under the press and slide,
    // read from the committed FEM table; the field is built before the ticks and read on them.
    let table: InclusionTable = serde_json::from_str(include_str!(
        "../../scenes/calibration/inclusion_sphere10_50kpa.json"
    ))
    .unwrap();
    let top = liver::top_contact();
    let inclusions: Vec<Inclusion> = (0..5)
        .map(|k| Inclusion {
            centre_in_object_m: (top.point_m - 0.01 * top.normal
                + DVec3::new(0.004 * k as f64, 0.0, 0.0))
            .to_array(),
            radius_m: 0.005,
            stiffness_ratio: 4.0,
            centre_depth_m: 0.01,
        })
        .collect();
    let (mut device, world) = setup(Material::PAPER_SOFT, combined);
    let mut world = world.with_inclusions(InclusionField::new(table, &inclusions).unwrap());
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    let mut touched = 0;
    for _ in 0..3000 {
        let state = world.step(device.read());
        touched += state.in_contact as u32;
        device.command_force(state.force_n).unwrap();
    }
    assert_eq!(
        ALLOCATIONS.load(Ordering::Relaxed),
        before,
        "with inclusions"
    );
    assert!(touched > 500);

    // The loop thread, with a tick ring: count only between two points of its steady state.
    let (device, world) = setup(Material::PAPER_SOFT, combined);
    let (producer, mut consumer) = rtrb::RingBuffer::<TickRecord>::new(16);
    let haptic = HapticLoop::spawn(Box::new(device), world, test_loop(Some(producer))).unwrap();
    let wait_for_tick = |tick: u64| {
        let give_up = Instant::now() + Duration::from_secs(30);
        while haptic.latest_contact().tick < tick {
            assert!(Instant::now() < give_up, "the loop does not advance");
            std::thread::sleep(Duration::from_millis(2));
        }
    };
    wait_for_tick(50);
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    let start_tick = haptic.latest_contact().tick;
    let mut drained = 0;
    while haptic.latest_contact().tick < start_tick + 300 {
        while consumer.pop().is_ok() {
            drained += 1;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let after = ALLOCATIONS.load(Ordering::Relaxed);
    let stats = haptic.stop();
    assert_eq!(after, before, "allocations while the loop ran");
    assert!(drained > 0 && stats.ticks >= start_tick + 300);
}
