//! Reading the files a user names (scenes, meshes, calibration tables, limits, recordings):
//! regular files only, each kind bounded in size.
//!
//! A path to `/dev/zero` would otherwise grow the process until memory runs out, and a FIFO
//! would block the start forever; both are refused before they are opened, with what the path
//! is. A file larger than its kind's limit is refused with its size and the limit; the read
//! itself stops at the limit too, so a file that grows while it is read cannot pass.

use std::fmt;
use std::io::Read;
use std::path::Path;

/// The kinds of file read, with their size limits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileKind {
    /// A scene (TOML): a page of settings.
    Scene,
    /// An exercise (TOML): a page of settings, a traced path of up to a thousand points.
    Exercise,
    /// An OBJ mesh: a fine render mesh of a few million triangles is about 200 MB of text.
    Mesh,
    /// A calibration table or a model-limits file (JSON): a few hundred rows.
    Table,
    /// A session recording (MCAP): about 85 kB per second of session, so 13 hours.
    Recording,
    /// A token file or NATS credentials: a few lines (a `.creds` file is about 1 kB).
    Secrets,
    /// A TLS certificate chain or private key (PEM): a few kB, a long chain a few tens.
    Pem,
    /// The viewer's page (`index.html`), read for its scripts' hashes: a few kB.
    Page,
}

impl FileKind {
    /// The largest file of this kind that is read, bytes.
    pub const fn max_bytes(self) -> u64 {
        match self {
            FileKind::Scene => 1 << 20,
            FileKind::Exercise => 1 << 20,
            FileKind::Mesh => 256 << 20,
            FileKind::Table => 16 << 20,
            FileKind::Recording => 4 << 30,
            FileKind::Secrets => 64 << 10,
            FileKind::Pem => 1 << 20,
            FileKind::Page => 1 << 20,
        }
    }

    fn name(self) -> &'static str {
        match self {
            FileKind::Scene => "a scene file",
            FileKind::Exercise => "an exercise file",
            FileKind::Mesh => "a mesh",
            FileKind::Table => "a calibration or limits file",
            FileKind::Recording => "a recording",
            FileKind::Secrets => "a token or credentials file",
            FileKind::Pem => "a PEM certificate or key file",
            FileKind::Page => "the viewer's page",
        }
    }
}

/// Why a file was not read. Its text does not repeat the path: callers name it.
#[derive(Debug)]
pub enum ReadError {
    Io(std::io::Error),
    /// Not a regular file: a directory, a FIFO, a device, a socket.
    NotRegular(&'static str),
    TooLarge {
        len: u64,
        kind: FileKind,
    },
    NotText,
}

impl fmt::Display for ReadError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            // The OS's text alone: its `Display` already carries the code.
            ReadError::Io(e) => write!(f, "{e}"),
            ReadError::NotRegular(what) => write!(f, "is {what}, not a regular file"),
            ReadError::TooLarge { len, kind } => write!(
                f,
                "is {} bytes, more than the {} bytes {} may be",
                len,
                kind.max_bytes(),
                kind.name()
            ),
            ReadError::NotText => write!(f, "is not UTF-8 text"),
        }
    }
}

impl std::error::Error for ReadError {}

impl From<ReadError> for std::io::Error {
    fn from(e: ReadError) -> Self {
        match e {
            ReadError::Io(e) => e,
            other => std::io::Error::new(std::io::ErrorKind::InvalidInput, other.to_string()),
        }
    }
}

/// Whether users other than the owner may read or write `path` (a secret: a key, a token or
/// credentials file; a directory of them): said as a warning naming it, `what` it is and the
/// `chmod` that fixes it. A secret others may read is theirs too; it is not refused, as the
/// owner may mean it (a group of instructors), but it is never silent.
pub fn warn_if_others_may_read(path: &Path, what: &str) -> bool {
    use std::os::unix::fs::PermissionsExt;
    let Ok(meta) = std::fs::metadata(path) else {
        return false;
    };
    let open = meta.permissions().mode() & 0o077 != 0;
    if open {
        let fix = if meta.is_dir() { "700" } else { "600" };
        tracing::warn!(
            file = %path.display(),
            mode = format_args!("{:o}", meta.permissions().mode() & 0o777),
            "{what} may be read by other users of this machine (chmod {fix} it)"
        );
    }
    open
}

/// What a path that is not a regular file is, in words.
fn kind_of(file_type: std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if file_type.is_dir() {
        "a directory"
    } else if file_type.is_fifo() {
        "a FIFO"
    } else if file_type.is_char_device() {
        "a character device"
    } else if file_type.is_block_device() {
        "a block device"
    } else if file_type.is_socket() {
        "a socket"
    } else {
        "not a regular file"
    }
}

/// Opens `path`, a regular file of at most `kind`'s size limit, for a reader that takes it a
/// piece at a time; with its length when opened (the part to read, should it grow).
pub fn open(path: &Path, kind: FileKind) -> Result<(std::fs::File, u64), ReadError> {
    // Looked at before it is opened: opening a FIFO would block until a writer came.
    let meta = std::fs::metadata(path).map_err(ReadError::Io)?;
    if !meta.file_type().is_file() {
        return Err(ReadError::NotRegular(kind_of(meta.file_type())));
    }
    let file = std::fs::File::open(path).map_err(ReadError::Io)?;
    // What was opened, not what the path named a moment before.
    let meta = file.metadata().map_err(ReadError::Io)?;
    if !meta.file_type().is_file() {
        return Err(ReadError::NotRegular(kind_of(meta.file_type())));
    }
    if meta.len() > kind.max_bytes() {
        return Err(ReadError::TooLarge {
            len: meta.len(),
            kind,
        });
    }
    Ok((file, meta.len()))
}

/// Reads `path`, a regular file of at most `kind`'s size limit.
pub fn read(path: &Path, kind: FileKind) -> Result<Vec<u8>, ReadError> {
    // Looked at before it is opened: opening a FIFO would block until a writer came.
    let meta = std::fs::metadata(path).map_err(ReadError::Io)?;
    if !meta.file_type().is_file() {
        return Err(ReadError::NotRegular(kind_of(meta.file_type())));
    }
    let limit = kind.max_bytes();
    if meta.len() > limit {
        return Err(ReadError::TooLarge {
            len: meta.len(),
            kind,
        });
    }
    let file = std::fs::File::open(path).map_err(ReadError::Io)?;
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(limit + 1)
        .read_to_end(&mut bytes)
        .map_err(ReadError::Io)?;
    if bytes.len() as u64 > limit {
        return Err(ReadError::TooLarge {
            len: bytes.len() as u64,
            kind,
        });
    }
    Ok(bytes)
}

/// Reads `path` as UTF-8 text, a regular file of at most `kind`'s size limit.
pub fn read_text(path: &Path, kind: FileKind) -> Result<String, ReadError> {
    String::from_utf8(read(path, kind)?).map_err(|_| ReadError::NotText)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn a_secret_others_may_read_is_told_and_one_only_its_owner_reads_is_not() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let key = dir.path().join("key.pem");
        std::fs::write(&key, "secret").unwrap();
        for (mode, open) in [(0o644, true), (0o640, true), (0o600, false), (0o400, false)] {
            std::fs::set_permissions(&key, std::fs::Permissions::from_mode(mode)).unwrap();
            assert_eq!(warn_if_others_may_read(&key, "a key"), open, "{mode:o}");
        }
        std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
        assert!(warn_if_others_may_read(dir.path(), "a data directory"));
        assert!(!warn_if_others_may_read(
            &dir.path().join("none"),
            "nothing"
        ));
    }

    fn scratch(name: &str) -> std::path::PathBuf {
        let dir =
            std::env::temp_dir().join(format!("softhaptic-files-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn devices_directories_and_fifos_are_refused_without_being_opened() {
        let e = read(Path::new("/dev/zero"), FileKind::Recording).unwrap_err();
        assert_eq!(e.to_string(), "is a character device, not a regular file");
        let dir = scratch("kinds");
        let e = read(&dir, FileKind::Scene).unwrap_err();
        assert_eq!(e.to_string(), "is a directory, not a regular file");
        let fifo = dir.join("pipe");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        if made.is_ok_and(|s| s.success()) {
            // Would block forever if it were opened.
            let e = read(&fifo, FileKind::Scene).unwrap_err();
            assert_eq!(e.to_string(), "is a FIFO, not a regular file");
        }
        let e = read(&dir.join("missing.toml"), FileKind::Scene).unwrap_err();
        assert!(e.to_string().contains("No such file"), "{e}");
        assert_eq!(e.to_string().matches("No such file").count(), 1, "{e}");
    }

    #[test]
    fn a_file_past_its_kind_s_limit_is_refused_with_its_size() {
        let dir = scratch("limits");
        let big = dir.join("big.toml");
        let file = std::fs::File::create(&big).unwrap();
        // Sparse: no disk space, but the size a reader would try to load.
        file.set_len(FileKind::Scene.max_bytes() + 1).unwrap();
        let e = read_text(&big, FileKind::Scene).unwrap_err();
        assert_eq!(
            e.to_string(),
            "is 1048577 bytes, more than the 1048576 bytes a scene file may be"
        );
        // The same size is a fine mesh.
        assert_eq!(
            read(&big, FileKind::Mesh).unwrap().len() as u64,
            FileKind::Scene.max_bytes() + 1
        );
        std::fs::write(dir.join("binary.toml"), [0xff, 0xfe, 0x00]).unwrap();
        let e = read_text(&dir.join("binary.toml"), FileKind::Scene).unwrap_err();
        assert_eq!(e.to_string(), "is not UTF-8 text");
    }
}
