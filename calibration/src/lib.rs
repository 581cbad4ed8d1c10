//! Offline FEM calibration of the soft-object haptic simulator, and the paper's experiments.
//!
//! A static finite-element model of an elastic block (or ball) indented by a rigid frictionless
//! sphere or cone, displacement controlled, bottom clamped. It writes the δ → R_d tables the
//! viewer's deformation uses (paper §3.3.2), and measures the closed-form contact laws of
//! `softhaptic-device` against the FEM (paper §3.2, §4.3).
//!
//! # Layout
//! - [`mesh`]: graded structured meshes of 10-node tetrahedra (blocks, quarter balls), boundary
//!   conditions, symmetry.
//! - [`element`]: the 10-node tetrahedron and the linear / neo-Hookean laws (forces, tangents).
//! - [`sparse`]: fixed-pattern sparse assembly and the sparse Cholesky factorisation (faer).
//! - [`indenter`]: rigid sphere, cone and paraboloid indenters and their gap functions.
//! - [`solver`]: Newton's method with an active set for frictionless contact, load stepping.
//! - [`analytic`]: the closed-form references (Hertz, exact sphere, half-space profiles).
//! - [`experiments`]: the paper's experiments, each returning its figures.
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
pub mod indenter;
pub mod mesh;
pub mod report;
pub mod solver;
pub mod sparse;
