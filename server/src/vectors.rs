//! The shared test vectors (`proto/vectors/*.json`): written from the proto crate's reference
//! code, read by the viewer's tests, checked by a proto test so they cannot drift.

use std::path::{Path, PathBuf};

/// Why the vectors could not be written, or differ from the code.
#[derive(Debug, thiserror::Error)]
pub enum VectorsError {
    #[error("could not encode the vectors: {0}")]
    Encode(#[from] serde_json::Error),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{} out of date (run `softhaptic vectors write`)", .paths.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", "))]
    Stale { paths: Vec<PathBuf> },
}

/// The source tree's `proto/vectors/`.
pub fn default_dir() -> PathBuf {
    let server = Path::new(env!("CARGO_MANIFEST_DIR"));
    // The crate sits in the workspace root; `..` is kept only if it somehow does not.
    server
        .parent()
        .map_or_else(|| server.join(".."), Path::to_path_buf)
        .join("proto")
        .join("vectors")
}

/// Writes every vector file into `dir`, or with `check` only compares them; returns the files.
pub fn write_or_check(dir: &Path, check: bool) -> Result<Vec<PathBuf>, VectorsError> {
    let files = softhaptic_proto::wire::vector_files()?;
    let mut stale = Vec::new();
    let mut written = Vec::new();
    if !check {
        std::fs::create_dir_all(dir).map_err(|source| VectorsError::Io {
            path: dir.to_owned(),
            source,
        })?;
    }
    for (name, contents) in files {
        let path = dir.join(name);
        if check {
            // The project's own vector files, read by a command on the main thread with no async
            // runtime.
            #[allow(clippy::disallowed_methods)]
            let on_disk = std::fs::read_to_string(&path);
            match on_disk {
                Ok(on_disk) if on_disk == contents => {}
                Ok(_) => stale.push(path.clone()),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => stale.push(path.clone()),
                Err(source) => return Err(VectorsError::Io { path, source }),
            }
        } else {
            std::fs::write(&path, contents).map_err(|source| VectorsError::Io {
                path: path.clone(),
                source,
            })?;
        }
        written.push(path);
    }
    if stale.is_empty() {
        Ok(written)
    } else {
        Err(VectorsError::Stale { paths: stale })
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn check_detects_a_changed_file_and_write_repairs_it() {
        let dir = std::env::temp_dir().join(format!("softhaptic-vectors-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        assert!(matches!(
            write_or_check(&dir, true),
            Err(VectorsError::Stale { .. })
        ));
        let files = write_or_check(&dir, false).unwrap();
        assert_eq!(files.len(), 3);
        write_or_check(&dir, true).unwrap();
        std::fs::write(&files[0], "[]").unwrap();
        let err = write_or_check(&dir, true).unwrap_err();
        assert!(err.to_string().contains("deformation.json"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
