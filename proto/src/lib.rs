//! The shared vocabulary of the soft-object haptic simulator.
//!
//! Every other crate speaks in these types: the 1 kHz loop in `softhaptic-device` fills a
//! [`ContactState`], the server turns it into wire messages, the calibration tool writes the
//! tables, and the web viewer mirrors the deformation profile. Nothing here does I/O, spawns a
//! thread or knows about tokio, so the real-time crate can depend on it freely.
//!
//! # Layout
//! - [`material`]: linear-elastic constants (E, ν) validated on construction, and the derived
//!   shear and plane-strain moduli.
//! - [`model`]: which contact model and corrections a scene object uses, the measured
//!   validity limits of each model (file format of the calibration's `model_limits.json`), and
//!   the limits a running model uses ([`ValidityLimits`]: measured, else the paper's).
//! - [`tool`]: the rigid tool tips (sphere, cone) and the cone half-angle convention.
//! - [`contact`]: poses, the per-tick [`ContactState`] and its [`ContactFlags`].
//! - [`calibration`]: the δ → R_d calibration table (JSON file format), its piecewise fit and
//!   the analytical half-space table used when no FEM table exists.
//! - [`guide`]: haptic guidance along an expert's recorded path: its settings, each tick's pull,
//!   the path as a recording keeps it and as the viewers draw it.
//! - [`inclusion`]: stiffer inclusions inside an object (palpation) and the FEM table of the
//!   force ratio they cause (never sent to the viewers).
//! - [`deformation`]: the reference Bézier deformation profile the viewer mirrors (proto/WIRE.md).
//! - [`exercise`]: exercises (press, trace), the metrics each kind scores with the direction
//!   that is better, pass marks, and an attempt's result.
//! - [`wire`]: the WebSocket messages between server and viewer, and their decoding; the render
//!   mesh's binary layout ([`wire::shm1`]).
//! - [`record`]: the session-log records (one MCAP channel each, JSON schemas) and the replay
//!   control messages.
//!
//! # Conventions
//! SI units everywhere, carried in the names (`depth_m`, `force_n`, `youngs_modulus_pa`).
//! Frames are named too (`tip_in_world`). The world frame is right-handed with y up.

pub mod calibration;
pub mod contact;
pub mod deformation;
pub mod exercise;
pub mod guide;
pub mod inclusion;
pub mod material;
pub mod model;
pub mod record;
pub mod tool;
pub mod wire;

pub use calibration::{CalibrationError, CalibrationSource, CalibrationTable};
pub use contact::{ContactFlags, ContactState, Pose};
pub use deformation::DeformationProfile;
pub use guide::{GuideGain, GuideParams, GuideState};
pub use inclusion::{Inclusion, InclusionTable, InclusionTableError};
pub use material::{Material, MaterialError};
pub use model::{LayerSpec, ModelError, ModelLimitsFile, ModelSpec, ValidityLimits};
pub use tool::{ToolError, ToolShape};
