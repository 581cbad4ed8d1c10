//! Sessions: recording, reading back, checking and replaying, from `softhaptic-session`
//! (`server/session/`), whose modules are re-exported here under their own names
//! (`session::reader`, `session::replay`, …); and [`cli`], the session subcommands of
//! `softhaptic` and the recording of a live session, which start the live server and so belong
//! to this crate.

pub mod cli;

pub use softhaptic_session::*;
