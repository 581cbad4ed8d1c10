//! Offline FEM calibration (see the crate manifest).
