//! No pop-through for a tool that goes in faster than its own height in one tick, or that a
//! device outage lets sink in unopposed: the contact tracker (`device/src/tracking.rs`) must hold
//! it on the side it came from, with a force that pushes out and ramps in without a spike.
//!
//! `pop_through.rs` presses with the simulated hand, which moves the tip at most 0.1 mm a tick:
//! the collision always sees such a contact begin cleanly. Here the hand is stronger than the
//! device and moves the tip along a fixed path (the force does not slow it down), at 0.5 m/s,
//! 1 m/s and a quarter past each tool's height per tick, with the ticks placed so that the last
//! one above the surface is just above it. A tool that crosses more than its height (the 0.5 mm
//! tip 45° cone is 0.5 mm high, the 0.5 mm sphere 1 mm) between two readings is first seen by
//! the collision already clamped, and a tick later is past its reach: the cone at 1 m/s, every
//! tool a quarter past its height per tick, and, when the reading at the crossing is lost (a
//! late servo tick), the cone at 0.5 m/s and the 0.5 mm sphere at 1 m/s. Before the fix these
//! were never held: one clamped tick, at most one more, then no contact and zero force while the
//! tip went on 6 mm deep. The outage runs read the device as disconnected while the hand moves
//! the tip from outside to 10 mm deep; the first reading back is past the collision's reach,
//! with the tracker out of contact.
//!
//! Every run is on the flat grid and the liver, in both collision modes, and checks tick by tick
//! with the tip's exact position:
//! - the contact is never lost while the tip is below the surface (in the paper's vertex mode:
//!   deeper than half the tip's height, as in `pop_through.rs`), its normal stays on the side
//!   the tool came from, and past the tip's height it is flagged `PUSHED_THROUGH`;
//! - the force is finite, within the device's peak, never pulls in, and pushes out (more than
//!   1 N) while the tip is held still deep inside;
//! - it never spikes: the first force of the contact is at most the ramp's threshold (a larger
//!   one is ramped in from zero), and from tick to tick it changes by no more than the device's
//!   stable stiffness times the tip's motion, the dampings times the change of speed, one tick of
//!   the ramp and 0.05 N;
//! - with the tool back out on the side it entered it is released: no contact, zero force.
//!
//! Jumps that end outside the object (past a small ball, right through it) must not be held.

// Test code: a panic is how a failure is reported.
#![allow(clippy::unwrap_used)]

use std::f64::consts::FRAC_PI_4;

use glam::{DQuat, DVec3};
use softhaptic_device::collision::{Collider, CollisionMode};
use softhaptic_device::device::{DeviceError, DeviceLimits, DeviceSample};
use softhaptic_device::force::ForceConfig;
use softhaptic_device::mesh::HapticMesh;
use softhaptic_device::model::ForceModel;
use softhaptic_device::shape;
use softhaptic_device::world::HapticWorld;
use softhaptic_proto::{ContactFlags, ContactState, Material, ModelSpec, Pose, ToolShape};

#[path = "common/targets.rs"]
mod targets;
use targets::{Target, grid, liver_top};

const PERIOD_NS: u64 = 1_000_000;
const PERIOD_S: f64 = 1e-3;

/// Where the tip starts and ends, above the surface.
const ABOVE_M: f64 = 0.003;

/// How deep the hand takes the tip.
const DEEP_M: f64 = 0.006;

/// How deep the tip is when the device comes back after the outage.
const OUTAGE_DEEP_M: f64 = 0.01;

/// Speed of the slow pull back out.
const WITHDRAW_M_S: f64 = 0.05;

/// Tolerance on "below the surface" (the positions are exact here).
const TOLERANCE_M: f64 = 2e-5;

/// The 0.5 mm sphere, the 0.5 mm-tip 45° cone and the 1 mm sphere.
fn small_tools() -> [ToolShape; 3] {
    [
        ToolShape::sphere(0.0005).unwrap(),
        ToolShape::cone(FRAC_PI_4, 0.0005).unwrap(),
        ToolShape::sphere(0.001).unwrap(),
    ]
}

fn world(mesh: &HapticMesh, mode: CollisionMode, tool: ToolShape) -> HapticWorld {
    HapticWorld::with_model(
        Collider::new(mesh.clone(), mode),
        Pose::IDENTITY,
        ForceModel::new(tool, Material::PAPER_SOFT, ModelSpec::PAPER).unwrap(),
        ForceConfig::for_tool(&tool),
        DeviceLimits::PHANTOM_DESKTOP,
    )
}

/// One step of the hand's path: where the tip is (below the target's plane, along its normal;
/// negative above), and whether the device can be read.
#[derive(Clone, Copy)]
struct Waypoint {
    below_m: f64,
    readable: bool,
}

/// In at `speed_m_s` from about [`ABOVE_M`] above to [`DEEP_M`] below, held there 200 ticks,
/// then out slowly to [`ABOVE_M`] above, then 50 ticks still. The ticks fall so that the last
/// one above the surface is `gap` of a tick's travel above it (the next one is `1 − gap` of a
/// tick's travel below). With `lose_crossing`, the first reading below the surface is lost (a
/// late servo tick, an overrun: a device fault), so the tracker sees two ticks' travel at once.
fn fast_entry(speed_m_s: f64, gap: f64, lose_crossing: bool) -> Vec<Waypoint> {
    let step_m = speed_m_s * PERIOD_S;
    let mut path = Vec::new();
    let approach_ticks = ((ABOVE_M / step_m) - gap).ceil().max(1.0);
    let mut below_m = -(gap + approach_ticks) * step_m;
    for _ in 0..50 {
        path.push(below_m);
    }
    while below_m < DEEP_M {
        below_m = (below_m + speed_m_s * PERIOD_S).min(DEEP_M);
        path.push(below_m);
    }
    for _ in 0..200 {
        path.push(below_m);
    }
    while below_m > -ABOVE_M {
        below_m = (below_m - WITHDRAW_M_S * PERIOD_S).max(-ABOVE_M);
        path.push(below_m);
    }
    for _ in 0..50 {
        path.push(below_m);
    }
    let lost = lose_crossing
        .then(|| path.iter().position(|&b| b > 0.0))
        .flatten();
    path.into_iter()
        .enumerate()
        .map(|(k, below_m)| Waypoint {
            below_m,
            readable: Some(k) != lost,
        })
        .collect()
}

/// Still at [`ABOVE_M`] above; then the device is unreadable for 300 ticks while the hand sinks
/// to [`OUTAGE_DEEP_M`] below; then read again there, still, for 300 ticks; then out slowly.
fn outage() -> Vec<Waypoint> {
    let mut path: Vec<Waypoint> = (0..50)
        .map(|_| Waypoint {
            below_m: -ABOVE_M,
            readable: true,
        })
        .collect();
    for k in 1..=300 {
        path.push(Waypoint {
            below_m: -ABOVE_M + (OUTAGE_DEEP_M + ABOVE_M) * k as f64 / 300.0,
            readable: false,
        });
    }
    let mut below_m = OUTAGE_DEEP_M;
    for _ in 0..300 {
        path.push(Waypoint {
            below_m,
            readable: true,
        });
    }
    while below_m > -ABOVE_M {
        below_m = (below_m - WITHDRAW_M_S * PERIOD_S).max(-ABOVE_M);
        path.push(Waypoint {
            below_m,
            readable: true,
        });
    }
    for _ in 0..50 {
        path.push(Waypoint {
            below_m,
            readable: true,
        });
    }
    path
}

/// One tick of a run.
struct Tick {
    state: ContactState,
    readable: bool,
    /// Depth of the tip below the mesh surface (negative above it), exact.
    below_surface_m: f64,
    /// Depth of the tip below the target's plane.
    below_entry_m: f64,
    /// Tip velocity along the normal, positive inward.
    speed_in_m_s: f64,
    /// Force along the target's normal.
    force_n: f64,
}

/// Runs `tool` along `path` into `target`; the tool's axis is the target's normal, so the tool
/// frame's origin is the tip's deepest point.
fn run(target: &Target, mode: CollisionMode, tool: ToolShape, path: &[Waypoint]) -> Vec<Tick> {
    let mut world = world(&target.mesh, mode, tool);
    let mut surface = Collider::new(target.mesh.clone(), CollisionMode::Continuous);
    let n = target.normal;
    let orientation = DQuat::from_rotation_arc(DVec3::Y, n);
    let mut previous_m = path[0].below_m;
    path.iter()
        .enumerate()
        .map(|(k, w)| {
            let tip_m = target.point_m - n * w.below_m;
            let speed_in_m_s = (w.below_m - previous_m) / PERIOD_S;
            previous_m = w.below_m;
            let sample = DeviceSample {
                time_ns: k as u64 * PERIOD_NS,
                tip_in_world: Pose {
                    position_m: tip_m,
                    orientation,
                },
                tip_velocity_m_s: -n * speed_in_m_s,
                buttons: 0,
                flags: ContactFlags::empty(),
            };
            let state = world.step(if w.readable {
                Ok(sample)
            } else {
                Err(DeviceError::Disconnected)
            });
            Tick {
                state,
                readable: w.readable,
                below_surface_m: surface
                    .closest_surface_point(tip_m, 1.0)
                    .map_or(f64::NAN, |p| -p.signed_distance_m),
                below_entry_m: w.below_m,
                speed_in_m_s,
                force_n: state.force_n.dot(n),
            }
        })
        .collect()
}

/// The checks of the module docs on one run; `what` names it in a failure.
fn assert_held_and_pushed_out(
    run: &[Tick],
    tool: &ToolShape,
    mode: CollisionMode,
    normal: DVec3,
    what: &str,
) {
    let limits = DeviceLimits::PHANTOM_DESKTOP;
    let config = ForceConfig::for_tool(tool);
    let height_m = shape::max_depth_m(tool);
    let must_touch_m = match mode {
        CollisionMode::Continuous => TOLERANCE_M,
        CollisionMode::PaperVertices => 0.5 * height_m + TOLERANCE_M,
    };
    let ramp_step_n = limits.peak_force_n * PERIOD_NS as f64 / config.ramp_ns as f64;
    let dampings_n_s_per_m = config.damping_n_s_per_m + limits.damping_n_s_per_m;
    let mut first_contact = true;
    let mut still_deep = 0;
    for (k, t) in run.iter().enumerate() {
        let at = || {
            format!(
                "{what}, tick {k}: {:.3} mm below, {:?}",
                t.below_surface_m * 1e3,
                t.state
            )
        };
        let force = t.state.force_n;
        assert!(
            force.is_finite() && force.length() <= limits.peak_force_n + 1e-9,
            "{}: force out of bounds",
            at()
        );
        assert!(t.force_n >= -1e-9, "{}: the force pulls in", at());
        if !t.readable {
            assert!(
                force == DVec3::ZERO && t.state.flags.contains(ContactFlags::DEVICE_FAULT),
                "{}: a fault must give zero force and the flag",
                at()
            );
            continue;
        }
        if t.below_surface_m > must_touch_m {
            assert!(t.state.in_contact, "{}: contact lost", at());
        }
        if t.state.in_contact {
            assert!(
                t.state.normal.dot(normal) > 0.5,
                "{}: the contact turned away from the side the tool came from",
                at()
            );
            if first_contact {
                assert!(
                    force.length() <= config.ramp_threshold_n + 1e-9,
                    "{}: the contact begins with a step",
                    at()
                );
                first_contact = false;
            }
        }
        if t.below_surface_m > height_m + TOLERANCE_M {
            assert!(
                t.state.flags.contains(ContactFlags::PUSHED_THROUGH),
                "{}: past the tip's height and not flagged",
                at()
            );
        }
        // Held still deep inside, past the ramp: pushed out.
        if t.speed_in_m_s == 0.0 && t.below_entry_m > height_m + TOLERANCE_M {
            still_deep += 1;
            if still_deep > 100 {
                assert!(t.force_n > 1.0, "{}: not pushed out", at());
            }
        } else {
            still_deep = 0;
        }
    }
    for (k, w) in run.windows(2).enumerate() {
        let jump_n = (w[1].state.force_n - w[0].state.force_n).length();
        let allowed_n = limits.max_stiffness_n_per_m
            * (w[1].below_entry_m - w[0].below_entry_m).abs()
            + dampings_n_s_per_m * (w[1].speed_in_m_s - w[0].speed_in_m_s).abs()
            + ramp_step_n
            + 0.05;
        assert!(
            jump_n <= allowed_n,
            "{what}, tick {}: the force jumps by {jump_n} N ({} → {} N), allowed {allowed_n} N",
            k + 1,
            w[0].force_n,
            w[1].force_n
        );
    }
    assert!(
        run.iter()
            .any(|t| t.state.flags.contains(ContactFlags::PUSHED_THROUGH)),
        "{what}: never held"
    );
    let last = run.last().unwrap();
    assert!(last.below_entry_m < -0.002, "{what}: the hand ends above");
    assert!(
        !last.state.in_contact
            && last.state.force_n == DVec3::ZERO
            && !last.state.flags.contains(ContactFlags::PUSHED_THROUGH),
        "{what}: not released: {:?}",
        last.state
    );
}

/// Runs every tool at `speed_m_s` into the grid and the liver in both modes, with the last tick
/// above the surface a tenth and six tenths of a tick's travel above it, each with every
/// reading and with the crossing's reading lost.
fn fast_entries_are_held(speed_m_s: f64, tools: &[ToolShape], lose_crossing: &[bool]) {
    for (name, target) in [("grid", grid()), ("liver", liver_top())] {
        for mode in [CollisionMode::Continuous, CollisionMode::PaperVertices] {
            for tool in tools {
                for gap in [0.1, 0.6] {
                    for &lose in lose_crossing {
                        let what = format!(
                            "{name} {mode:?} {tool:?} at {speed_m_s} m/s, gap {gap}, \
                             crossing reading lost: {lose}"
                        );
                        let path = fast_entry(speed_m_s, gap, lose);
                        let ticks = run(&target, mode, *tool, &path);
                        assert_held_and_pushed_out(&ticks, tool, mode, target.normal, &what);
                    }
                }
            }
        }
    }
}

#[test]
fn a_cone_and_a_small_sphere_entering_at_half_a_metre_per_second_are_held() {
    // The cone crosses its 0.5 mm height in one tick; with one reading lost, in the two ticks
    // the tracker sees, so does every tool.
    fast_entries_are_held(0.5, &small_tools(), &[false, true]);
}

#[test]
fn a_cone_and_a_small_sphere_entering_at_a_metre_per_second_are_held() {
    fast_entries_are_held(1.0, &small_tools(), &[false, true]);
}

#[test]
fn a_tool_faster_than_its_own_height_per_tick_is_held() {
    // A quarter faster than its height per tick, every reading there: with the last tick above
    // the surface a tenth of a tick's travel above it, the collision's first sight of the
    // contact is clamped.
    for tool in small_tools() {
        let speed_m_s = 1.25 * shape::max_depth_m(&tool) / PERIOD_S;
        fast_entries_are_held(speed_m_s, &[tool], &[false]);
    }
}

#[test]
fn a_tool_that_sank_in_during_a_device_outage_is_held_and_ramped_in() {
    for (name, target) in [("grid", grid()), ("liver", liver_top())] {
        for mode in [CollisionMode::Continuous, CollisionMode::PaperVertices] {
            for tool in small_tools() {
                let what = format!("{name} {mode:?} {tool:?} after an outage");
                let ticks = run(&target, mode, tool, &outage());
                assert_held_and_pushed_out(&ticks, &tool, mode, target.normal, &what);
                // The first reading back: held, flagged, and ramped in from zero.
                let back = ticks.iter().position(|t| !t.readable).unwrap()
                    + ticks.iter().filter(|t| !t.readable).count();
                let first = &ticks[back];
                assert!(
                    first.state.in_contact
                        && first.state.flags.contains(ContactFlags::PUSHED_THROUGH)
                        && first.state.flags.contains(ContactFlags::RAMPING)
                        && first.state.force_n.length() < 0.2,
                    "{what}: the first reading back: {:?}",
                    first.state
                );
                let ramped = &ticks[back + 100];
                assert!(
                    ramped.force_n > 1.0,
                    "{what}: 100 ms after reconnecting: {:?}",
                    ramped.state
                );
            }
        }
    }
}

#[test]
fn a_jump_that_ends_outside_the_object_is_not_held() {
    // A 6 mm ball: a 0.5 mm sphere jumps from 1 mm above its top to 1 mm beside it (level with
    // its centre), then to 2 mm below its bottom, in single ticks. Never inside: no contact.
    let r0 = 0.003;
    let ball = HapticMesh::sphere(r0, 4).unwrap();
    for mode in [CollisionMode::Continuous, CollisionMode::PaperVertices] {
        let tool = ToolShape::sphere(0.0005).unwrap();
        let mut w = world(&ball, mode, tool);
        let places = [
            DVec3::Y * (r0 + 0.001),
            DVec3::X * (r0 + 0.001),
            DVec3::Y * (r0 + 0.001),
            -DVec3::Y * (r0 + 0.003),
            DVec3::Y * (r0 + 0.001),
        ];
        for (k, p) in places.iter().enumerate() {
            let state = w.step(Ok(DeviceSample {
                time_ns: k as u64 * PERIOD_NS,
                tip_in_world: Pose::from_position(*p),
                tip_velocity_m_s: DVec3::ZERO,
                buttons: 0,
                flags: ContactFlags::empty(),
            }));
            assert!(
                !state.in_contact && state.force_n == DVec3::ZERO,
                "{mode:?}, tick {k}: {state:?}"
            );
        }
    }
}
