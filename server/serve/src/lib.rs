//! Serving viewers: who may connect, over what, and what each one is sent. The live server, a
//! recording's replay and the lab's hub all serve their viewers with this crate; it knows
//! nothing of where the frames come from beyond the haptic loop's publications.
//!
//! # Layout
//! - [`access`]: who may connect and how much: the roles' tokens (generated, from a file or the
//!   environment; compared in constant time), the Origin and Host rules, the security headers
//!   and their Content-Security-Policy, the connection limits and the per-connection audit line.
//! - [`tls`]: https and wss on the viewer's port (`--tls-cert`/`--tls-key`, or a kept
//!   self-signed certificate and its fingerprint); why a plain-text or silent client cannot hold
//!   the port.
//! - [`viewer`]: the viewer's files (page, modules, three.js) built into the binary and served
//!   with their type and ETag, or a checkout's `web/` with `--web-dir`; checked before a start.
//!   `build.rs` stops the build when three.js is missing.
//! - [`stream`]: the 50 Hz frame task, the 1 Hz stats task and each viewer's connection task;
//!   why a slow viewer never delays anyone.
//! - [`routes`]: the HTTP routes of proto/WIRE.md over a stream hub, served over TCP or TLS
//!   within the connection caps; the server's name in `hello`.
//!
//! The files it reads (tokens, PEM files, a checkout's viewer) go through
//! `softhaptic_io::files`, imported here as `files`.

pub mod access;
pub mod routes;
pub mod stream;
pub mod tls;
pub mod viewer;

use softhaptic_io::{files, logging};
