//! Palpation on a flat block with the committed FEM inclusion table: sliding across an
//! inclusion's edge at hand speeds stays passive and continuous, and a scripted hand sweeping a
//! grid finds the inclusion where it is.

use glam::DVec3;
use softhaptic_device::collision::{Collider, CollisionMode};
use softhaptic_device::device::{DeviceLimits, DeviceSample};
use softhaptic_device::force::ForceConfig;
use softhaptic_device::inclusion::InclusionField;
use softhaptic_device::mesh::HapticMesh;
use softhaptic_device::world::HapticWorld;
use softhaptic_proto::{ContactFlags, Inclusion, InclusionTable, Material, Pose, ToolShape};

const MM: f64 = 1e-3;
const PERIOD_NS: u64 = 1_000_000;

fn table() -> InclusionTable {
    serde_json::from_str(include_str!(
        "../../scenes/calibration/inclusion_sphere10_50kpa.json"
    ))
    .expect("the committed inclusion table parses")
}

/// The inclusion, off the mesh's grid lines: under (4.3, −2.6) mm of the flat surface y = 0.
fn inclusion() -> Inclusion {
    Inclusion {
        centre_in_object_m: [4.3 * MM, -10.0 * MM, -2.6 * MM],
        radius_m: 5.0 * MM,
        stiffness_ratio: 6.0,
        centre_depth_m: 10.0 * MM,
    }
}

fn world(config: ForceConfig, with_inclusion: bool) -> HapticWorld {
    let tool = ToolShape::sphere(0.01).expect("valid tool");
    let collider = Collider::new(HapticMesh::grid(41, 0.1), CollisionMode::Continuous);
    let w = HapticWorld::new(
        collider,
        Pose::IDENTITY,
        tool,
        Material::PAPER_SOFT,
        config,
        DeviceLimits::PHANTOM_DESKTOP,
    );
    if with_inclusion {
        let field = InclusionField::new(table(), &[inclusion()]).expect("covered by the table");
        w.with_inclusions(field)
    } else {
        w
    }
}

fn sample(tick: u64, tip_m: DVec3, velocity_m_s: DVec3) -> DeviceSample {
    DeviceSample {
        time_ns: tick * PERIOD_NS,
        tip_in_world: Pose::from_position(tip_m),
        tip_velocity_m_s: velocity_m_s,
        buttons: 0,
        flags: ContactFlags::empty(),
    }
}

/// The tip (the sphere's lowest point, the tool frame's origin) `depth_m` below the surface at
/// (x, z).
fn tip(x: f64, z: f64, depth_m: f64) -> DVec3 {
    DVec3::new(x, -depth_m, z)
}

#[test]
fn sliding_across_the_edge_at_hand_speeds_is_passive_and_continuous() {
    for speed_m_s in [0.02, 0.1, 0.3] {
        let mut w = world(
            ForceConfig::for_tool(&ToolShape::sphere(0.01).expect("tool")),
            true,
        );
        // Press in beside the inclusion, slide across it and past, lift off over it on the way
        // back: the cycle that would create energy if the stiffening had no sideways part.
        let mut path: Vec<(DVec3, DVec3)> = Vec::new();
        let press_ticks = 200;
        for k in 0..=press_ticks {
            let d = 4.0 * MM * k as f64 / press_ticks as f64;
            path.push((tip(-20.0 * MM, -2.6 * MM, d), DVec3::new(0.0, -0.02, 0.0)));
        }
        let step_m = speed_m_s * 1e-3;
        let mut x = -20.0 * MM;
        while x < 25.0 * MM {
            x += step_m;
            path.push((tip(x, -2.6 * MM, 4.0 * MM), DVec3::new(speed_m_s, 0.0, 0.0)));
        }
        while x > 4.3 * MM {
            x -= step_m;
            path.push((
                tip(x, -2.6 * MM, 4.0 * MM),
                DVec3::new(-speed_m_s, 0.0, 0.0),
            ));
        }
        for k in 0..=press_ticks {
            let d = 4.0 * MM * (1.0 - k as f64 / press_ticks as f64);
            path.push((tip(x, -2.6 * MM, d), DVec3::new(0.0, 0.02, 0.0)));
        }
        let mut last: Option<DVec3> = None;
        let mut max_jump_n: f64 = 0.0;
        let mut peak_sideways_n: f64 = 0.0;
        for (tick, (p, v)) in path.iter().enumerate() {
            let s = w.step(Ok(sample(tick as u64, *p, *v)));
            assert!(
                !s.flags.contains(ContactFlags::PASSIVITY_DAMPING),
                "{speed_m_s} m/s: the passivity controller acted at tick {tick}, x = {:.2} mm",
                p.x / MM
            );
            // Every tick but those where the scripted velocity changes and the contact's onset
            // (the damping's b·v steps in there): pressing, sliding and lifting move the force
            // by what the motion explains, across the table's offsets and indentations alike.
            let velocity_steps = [0, 1, press_ticks + 1, path.len() - press_ticks - 1];
            if let Some(l) = last
                && !velocity_steps.contains(&tick)
            {
                max_jump_n = max_jump_n.max((s.force_n - l).length());
            }
            peak_sideways_n = peak_sideways_n.max(s.force_n.x.abs());
            last = Some(s.force_n);
        }
        // 0.3 mm per tick at the fastest sliding, 20 µm per tick pressing (about 800 N/m over
        // the inclusion): the force's slope along the path times that.
        assert!(
            max_jump_n < 0.02,
            "{speed_m_s} m/s: force jumped {max_jump_n} N in one tick"
        );
        // The edge pushes the tool sideways: felt, but a fraction of the normal force.
        assert!(
            peak_sideways_n > 1e-3 && peak_sideways_n < 0.5,
            "{peak_sideways_n}"
        );
        assert!(w.passivity_energy_j() >= -1e-9);
    }
}

#[test]
fn a_scripted_hand_sweeping_a_grid_finds_the_inclusion_where_it_is() {
    // A static force map: each grid point pressed 4 mm, no ramp or passivity memory between
    // points (they are separate presses, not a motion).
    let mut config = ForceConfig::for_tool(&ToolShape::sphere(0.01).expect("tool"));
    config.ramp_ns = 0;
    config.passivity = false;
    config.damping_n_s_per_m = 0.0;
    let mut with = world(config, true);
    let mut plain = world(config, false);
    let mut best = (f64::MIN, 0.0, 0.0);
    let mut contrasts = Vec::new();
    let mut tick = 0u64;
    for i in -20..=20 {
        for j in -20..=20 {
            let (x, z) = (i as f64 * MM, j as f64 * MM);
            let p = tip(x, z, 4.0 * MM);
            let a = with.step(Ok(sample(tick, p, DVec3::ZERO))).force_n.y;
            let b = plain.step(Ok(sample(tick, p, DVec3::ZERO))).force_n.y;
            tick += 1;
            let c = a / b - 1.0;
            contrasts.push((x, z, c));
            if c > best.0 {
                best = (c, x, z);
            }
        }
    }
    let (peak, x, z) = best;
    let miss_m = ((x - 4.3 * MM).powi(2) + (z + 2.6 * MM).powi(2)).sqrt();
    assert!(
        miss_m <= 1.0 * MM,
        "peak contrast {peak} at {miss_m} m from the centre"
    );
    assert!(peak > 0.05, "{peak}");
    // Nowhere else: beyond 15 mm from the centre the contrast is a tenth of the peak at most.
    for (x, z, c) in contrasts {
        if ((x - 4.3 * MM).powi(2) + (z + 2.6 * MM).powi(2)).sqrt() > 15.0 * MM {
            assert!(c < 0.1 * peak, "contrast {c} at ({x}, {z})");
        }
    }
}
