//! The checked TOML files a user writes (scenes, exercises): read, parsed, and refused with an
//! error that names the file and, for a value, its field and the value, so that the user knows
//! what to change and where.

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;

use crate::files::{self, FileKind, ReadError};

/// Why a checked TOML file was refused. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum TomlFileError {
    /// The file could not be read. The OS's text is part of this message, not a separate
    /// cause, so that an error chain prints it once.
    #[error("{path}: {reason}")]
    Read { path: PathBuf, reason: ReadError },
    /// Syntax, an unknown field, a wrong type, or a value refused by its type (a scene's
    /// material, its tool): toml's message shows the line, the column and the offending text.
    #[error("{path}: {message}")]
    Parse { path: PathBuf, message: String },
    /// A value outside what its field allows.
    #[error("{path}: {field}: {reason}")]
    Field {
        path: PathBuf,
        field: String,
        reason: String,
    },
}

impl TomlFileError {
    /// The file at `path` refuses `field`'s value, for `reason`.
    pub fn field(path: &Path, field: &str, reason: String) -> Self {
        TomlFileError::Field {
            path: path.to_owned(),
            field: field.to_owned(),
            reason,
        }
    }

    /// The text at `path` does not parse, as `message` (one shown on its line) says.
    pub fn parse(path: &Path, message: String) -> Self {
        TomlFileError::Parse {
            path: path.to_owned(),
            message,
        }
    }
}

/// The text of the file at `path`, read as a file of `kind` ([`files::read_text`]).
pub fn read(path: &Path, kind: FileKind) -> Result<String, TomlFileError> {
    files::read_text(path, kind).map_err(|reason| TomlFileError::Read {
        path: path.to_owned(),
        reason,
    })
}

/// `text` parsed as TOML into `T`; `path` names it in errors.
pub fn parse<T: DeserializeOwned>(text: &str, path: &Path) -> Result<T, TomlFileError> {
    toml::from_str(text)
        .map_err(|e| TomlFileError::parse(path, e.to_string().trim_end().to_owned()))
}
