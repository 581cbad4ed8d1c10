//! The world most of the loop's tests run: the built-in liver at the origin, collided
//! continuously, in a simulated PHANTOM Desktop, with a tool, its contact model and the force
//! pipeline for that tool; and the loop configuration they run it with.

// Each test binary that includes this uses part of it.
#![allow(dead_code)]

use softhaptic_device::collision::{Collider, CollisionMode};
use softhaptic_device::device::DeviceLimits;
use softhaptic_device::force::ForceConfig;
use softhaptic_device::haptic_loop::{LoopConfig, TickRecord};
use softhaptic_device::liver;
use softhaptic_device::model::ForceModel;
use softhaptic_device::world::HapticWorld;
use softhaptic_proto::Pose;

/// The liver under `model`'s tool, with the tool's default force pipeline.
pub fn liver_world(model: ForceModel) -> HapticWorld {
    let force = ForceConfig::for_tool(model.tool());
    liver_world_with(model, force)
}

/// The liver under `model`'s tool, with the force pipeline `force`.
pub fn liver_world_with(model: ForceModel, force: ForceConfig) -> HapticWorld {
    HapticWorld::with_model(
        Collider::new(liver::haptic_mesh(), CollisionMode::Continuous),
        Pose::IDENTITY,
        model,
        force,
        DeviceLimits::PHANTOM_DESKTOP,
    )
}

/// The loop as the tests run it: every 1 ms, without asking for real-time scheduling (the test
/// machine may not grant it), zero force in standby, the tick records into `tick_sink`.
pub fn test_loop(tick_sink: Option<rtrb::Producer<TickRecord>>) -> LoopConfig {
    LoopConfig {
        period_ns: 1_000_000,
        realtime: false,
        tick_sink,
        standby: true,
    }
}
