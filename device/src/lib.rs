//! The part of the simulator that runs at 1 kHz next to the haptic device.
//!
//! This crate cannot name tokio or any networking crate: whatever happens on the network, nothing
//! here can wait for it (design.md, invariant 1).
//!
//! # Layout
//! - [`law`]: the closed-form contact laws (Hertz sphere, Sneddon cone), contact radius and
//!   stiffness, as pure functions of depth.
//! - [`mesh`]: the coarse haptic mesh and the flat grids of the paper's timing study.
//! - [`collision`]: tool-tip collision with the haptic mesh (paper §4.1).

pub mod collision;
pub mod law;
pub mod mesh;
