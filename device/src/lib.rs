//! The part of the simulator that runs at 1 kHz next to the haptic device.
//!
//! This crate cannot name tokio or any networking crate: whatever happens on the network, nothing
//! here can wait for it (design.md, invariant 1).
//!
//! # Layout
//! - [`law`]: the closed-form contact laws (Hertz sphere, Sneddon cone), contact radius and
//!   stiffness, as pure functions of depth.
//! - [`model`]: [`ForceModel`](model::ForceModel), the paper's law times the corrections a scene
//!   turns on (curvature, layer thickness, exact sphere, hyperelastic fit, inclination).
//! - [`mesh`]: the coarse haptic mesh and the flat grids of the paper's timing study.
//! - [`collision`]: tool-tip collision with the haptic mesh (paper §4.1).
//! - [`shape`]: the tool tip as a solid: implicit inside test, bounding box, support point.
//! - [`liver`]: the procedural liver-like organ, as a coarse haptic mesh and a fine render surface.
//! - [`device`]: the [`HapticDevice`](device::HapticDevice) trait, device limits, samples, errors.
//! - [`sim`]: a simulated PHANTOM Desktop moved by a scripted hand (mass–spring–damper).
//! - [`render`]: contact law + damping, then the safety layer (stiffness cap, ramp, passivity,
//!   saturation, fault guard) with a flag for every limit that acts.
//! - [`passivity`]: the passivity observer and controller (Hannaford & Ryu 2002).
//! - [`world`]: [`HapticWorld`](world::HapticWorld), one tick as a synchronous function.
//! - [`haptic_loop`]: the 1 kHz thread and its wait-free publication of the latest contact.
//! - [`stats`]: fixed-size timing histograms and the loop's [`LoopStats`](stats::LoopStats).
//! - [`rt`]: monotonic clock, absolute-deadline sleep, SCHED_FIFO and mlockall requests.
//! - [`replay`]: [`ReplayDevice`](replay::ReplayDevice), a recorded session played back as a
//!   device, and the exact conversions between device samples and session-log records.

pub mod collision;
pub mod device;
pub mod haptic_loop;
pub mod law;
pub mod liver;
pub mod mesh;
pub mod model;
pub mod passivity;
pub mod render;
pub mod replay;
pub mod rt;
pub mod shape;
pub mod sim;
pub mod stats;
pub mod world;
