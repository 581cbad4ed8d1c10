//! What the host process reads from the files users name and what it writes for the person who
//! runs it; below every other crate of the server.
//!
//! # Layout
//! - [`files`]: reading the files users name (scenes, meshes, tables, recordings, secrets, PEM
//!   files): regular files only, each kind bounded in size; a warning when others may read a
//!   secret.
//! - [`toml_file`]: the checked TOML files (scenes, exercises) read and parsed, and their
//!   errors, which name the file and, for a refused value, its field and the value.
//! - [`logging`]: the process's log, which never writes the libraries' payload traces (tokens,
//!   NATS credentials), whatever `RUST_LOG` asks for; a line or a report on stdout that a closed
//!   pipe does not turn into a panic; an error and its causes on one line.

pub mod files;
pub mod logging;
pub mod toml_file;
