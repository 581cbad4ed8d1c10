//! The device-host server: loads a scene, runs the 1 kHz haptic loop on its own thread, streams
//! 50 Hz contact frames to WebSocket viewers and serves the web viewer.
//!
//! # Layout
//! - [`access`]: who may connect and how much: the roles' tokens (generated, from a file or the
//!   environment; compared in constant time), the Origin and Host rules, the security headers
//!   and their Content-Security-Policy, the connection limits and the per-connection audit line.
//! - [`scene`]: scene files (TOML), their validation and loading (meshes, calibration table,
//!   the object's contact model `[object.model]` built for the scene's tool only, and its
//!   validity limits from the measured limits file or the paper's), the haptic world a scene
//!   describes, the simulated hand's script at its press site, the built-in default scene (its
//!   calibration tables built into the binary), and the `scene` message a scene is sent as,
//!   whose `contact_model` names the active model and its limits.
//! - [`app`]: [`app::start`] builds the haptic world, spawns the loop, binds HTTP and WebSocket
//!   and returns a [`app::RunningServer`] with an orderly shutdown; the HTTP routes of
//!   proto/WIRE.md.
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
//! - [`files`]: reading the files users name: regular files only, each kind bounded in size.
//! - [`toml_file`]: the checked TOML files (scenes, exercises) read and parsed, and their
//!   errors, which name the file and, for a refused value, its field and the value.
//! - [`logging`]: the process's log, which never writes the libraries' payload traces (tokens,
//!   NATS credentials), whatever `RUST_LOG` asks for; the reports commands print on stdout.
//! - [`routes`]: the HTTP side the live server, the replay server and the lab's hub share: the
//!   routes of proto/WIRE.md over a stream hub, served over TCP or TLS within the connection
//!   caps; the server's name in `hello`.
//! - [`stream`]: the 50 Hz frame task, the 1 Hz stats task and each viewer's connection task;
//!   why a slow viewer never delays anyone.
//! - [`vectors`]: writes and checks the shared test vectors under `proto/vectors/`.
//! - [`viewer`]: the viewer's files (page, modules, three.js) built into the binary and served
//!   with their type and ETag, or a checkout's `web/` with `--web-dir`; checked before a start.
//! - [`session`]: recording sessions to MCAP files and reading them back; a replay check
//!   rebuilds the recorded contact model from the recording's `scene` message.
//! - [`tls`]: https and wss on the viewer's port (`--tls-cert`/`--tls-key`, or a kept
//!   self-signed certificate and its fingerprint); why a plain-text or silent client cannot hold
//!   the port.

pub mod access;
pub mod app;
pub mod datadir;
pub mod devices;
pub mod doctor;
pub mod exercise;
pub mod files;
pub mod lab;
pub mod logging;
pub mod routes;
pub mod scene;
pub mod session;
pub mod stream;
pub mod tls;
pub mod toml_file;
pub mod vectors;
pub mod viewer;
