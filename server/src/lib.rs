//! The device-host server: loads a scene, runs the 1 kHz haptic loop on its own thread, streams
//! 50 Hz contact frames to WebSocket viewers and serves the web viewer; the `softhaptic` binary
//! (`src/main.rs`) is its command line.
//!
//! # Layers
//! The server is several crates under `server/`, each using only the ones below it, so that the
//! compiler refuses a circle:
//! - `softhaptic-io` (`server/io/`): the files users name, the checked TOML files, the log.
//! - `softhaptic-serve` (`server/serve/`): serving viewers: access, TLS, the viewer's files, the
//!   stream, the HTTP routes every server shares.
//! - `softhaptic-scene` (`server/scene/`): scenes checked and loaded, and the device a scene
//!   names, opened.
//! - `softhaptic-doctor` (`server/doctor/`): the host's readiness for the loop, on the scenes.
//! - `softhaptic-session` (`server/session/`): recordings written, read, checked and replayed,
//!   on the scenes and the serving of viewers.
//! - `softhaptic-lab` (`server/lab/`): the teaching lab on NATS (station, hub, archive), on the
//!   serving of viewers and the sessions.
//! - this crate, on top: the live server, the session subcommands, exercises, the `softhaptic`
//!   binary.
//!
//! The modules of the crates below are re-exported here under their own names
//! (`softhaptic_server::access`, `softhaptic_server::stream`, …).
//!
//! # Layout
//! - [`scene`]: scene files (TOML), their validation and loading (meshes, calibration table,
//!   the object's contact model `[object.model]` built for the scene's tool only, and its
//!   validity limits from the measured limits file or the paper's), the haptic world a scene
//!   describes, the simulated hand's script at its press site, the built-in default scene (its
//!   calibration tables built into the binary), and the `scene` message a scene is sent as,
//!   whose `contact_model` names the active model and its limits.
//! - [`app`]: [`app::start`] builds the haptic world, spawns the loop, binds HTTP and WebSocket
//!   and returns a [`app::RunningServer`] with an orderly shutdown; the signals that stop it.
//! - [`datadir`]: where an installed binary finds the scenes and their tables without a source
//!   tree (`--scene cone.toml` → /usr/share/softhaptic/scenes/cone.toml).
//! - [`devices`]: opening the scene's device (simulated, or OpenHaptics with the limits it
//!   reports) and the `softhaptic devices` listing.
//! - [`doctor`]: `softhaptic doctor`: the host's readiness for the 1 kHz loop (preemption
//!   model, real-time limits, CPU isolation, interrupts, governor, swap, devices), each with its
//!   fix, and a short measurement of the loop idle and under load.
//! - [`exercise`]: exercise files (press, trace) checked and placed in their scene, attempts
//!   scored from the ticks, pass marks from experts (`benchmark`) and results (`results`).
//! - [`lab`]: the teaching lab on NATS: a station publishes its stream (`--nats`, `--station`),
//!   a hub (`softhaptic hub`) lists the stations and relays any of them to browsers.
//! - [`session`]: recording sessions to MCAP files and reading them back; a replay check
//!   rebuilds the recorded contact model from the recording's `scene` message; the session
//!   subcommands.
//! - [`vectors`]: writes and checks the shared test vectors under `proto/vectors/`.
//! - From `softhaptic-io`: [`files`], [`toml_file`], [`logging`].
//! - From `softhaptic-serve`: [`access`], [`tls`], [`viewer`], [`stream`], [`routes`].
//! - From `softhaptic-scene`: [`scene`] and [`devices`]; from `softhaptic-doctor`: [`doctor`]; from
//!   `softhaptic-lab`: [`lab`].

pub mod app;
pub mod datadir;
pub mod exercise;
pub mod session;
pub mod vectors;

// The layers below, under the names their modules had here.
pub use softhaptic_io::{files, logging, toml_file};
pub use softhaptic_scene::devices;
pub use softhaptic_serve::{access, routes, stream, tls, viewer};

/// The host doctor, from `softhaptic-doctor`.
pub use softhaptic_doctor as doctor;
/// The teaching lab, from `softhaptic-lab`.
pub use softhaptic_lab as lab;
/// Scenes, from `softhaptic-scene`.
pub use softhaptic_scene as scene;
