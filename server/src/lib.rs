//! The device-host server (see the crate manifest).
