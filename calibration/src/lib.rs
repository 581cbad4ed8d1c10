//! Offline FEM calibration of the soft-object haptic simulator, and the paper's experiments.
//!
//! A static finite-element model of an elastic block (or ball) indented by a rigid frictionless
//! sphere or cone, displacement controlled, bottom clamped. It writes the δ → R_d tables the
//! viewer's deformation uses (paper §3.3.2), measures the runtime contact models of
//! `softhaptic-device` (the paper's laws and every correction) against the FEM (paper §3.2,
//! §4.3), fits the runtime's hyperelastic correction, and writes the measured validity limits
//! of each model (`scenes/calibration/model_limits.json`).
//!
//! # Layout
//! - [`mesh`]: graded structured meshes of 10-node tetrahedra (blocks, quarter balls), boundary
//!   conditions, symmetry.
//! - [`element`]: the 10-node tetrahedron and the linear / neo-Hookean laws (forces, tangents).
//! - [`sparse`]: fixed-pattern sparse assembly and the sparse Cholesky factorisation (faer),
//!   ordered by nested dissection of the structured grid.
//! - [`indenter`]: rigid sphere, cone and paraboloid indenters and their gap functions.
//! - [`solver`]: Newton's method with an active set for frictionless contact, load stepping.
//! - [`analytic`]: closed-form references that are not runtime models (Sneddon's exact sphere,
//!   Lin et al.'s neo-Hookean sphere).
//! - [`models`]: the runtime models (`softhaptic_device::model::ForceModel`) as the studies
//!   score and time them.
//! - [`experiments`]: the FEM runs each experiment needs, solved once and in parallel, and the
//!   experiments' figures (including the hyperelastic fit and the model limits).
//! - [`inclusion`]: palpation: the FEM with a stiffer sphere inside the block, the force-ratio
//!   table the runtime interpolates, its held-out validation and the perceptibility table.
//! - [`report`]: markdown, CSV and SVG output.
//!
//! # Frame
//! The FEM frame has `+z` out of the indented surface (the block lies in `z ≤ 0`). The
//! calibration results are radial distances and forces along the surface normal, so they need
//! no conversion to the simulator's y-up world frame.

// The element and solver kernels index small fixed-size arrays by component (i, j, k) the way
// the formulas are written; iterator rewrites would hide the tensor algebra.
#![allow(clippy::needless_range_loop)]

pub mod analytic;
pub mod element;
pub mod experiments;
pub mod inclusion;
pub mod indenter;
pub mod mesh;
pub mod models;
pub mod report;
pub mod solver;
pub mod sparse;
