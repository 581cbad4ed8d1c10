//! The PEM files of TLS: the certificates and the private key read from them (each failure
//! named: not PEM, damaged, encrypted, holding something else), and the kept self-signed ones
//! written atomically into a directory only their owner reads.

use std::io;
use std::os::unix::fs::{DirBuilderExt, OpenOptionsExt};
use std::path::{Path, PathBuf};

use rustls_pki_types::pem::{self, PemObject};
use rustls_pki_types::{CertificateDer, PrivateKeyDer};

use super::TlsError;

/// The certificates of a PEM file, in file order (the server's own first).
pub(super) fn read_certificates(path: &Path) -> Result<Vec<CertificateDer<'static>>, TlsError> {
    let text = read_pem_file(path)?;
    let chain = CertificateDer::pem_slice_iter(&text)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|source| TlsError::BadPem {
            path: path.to_owned(),
            source,
        })?;
    if chain.is_empty() {
        return Err(TlsError::NoCertificate {
            path: path.to_owned(),
            found: pem_labels(&text),
        });
    }
    Ok(chain)
}

/// The private key of a PEM file (the first one).
pub(super) fn read_private_key(path: &Path) -> Result<PrivateKeyDer<'static>, TlsError> {
    let text = read_pem_file(path)?;
    match PrivateKeyDer::from_pem_slice(&text) {
        Ok(key) => Ok(key),
        Err(pem::Error::NoItemsFound) => {
            let found = pem_labels(&text);
            if found.contains("ENCRYPTED PRIVATE KEY") {
                Err(TlsError::EncryptedKey {
                    path: path.to_owned(),
                })
            } else {
                Err(TlsError::NoPrivateKey {
                    path: path.to_owned(),
                    found,
                })
            }
        }
        Err(source) => Err(TlsError::BadPem {
            path: path.to_owned(),
            source,
        }),
    }
}

/// The bytes of a file that must be PEM.
fn read_pem_file(path: &Path) -> Result<Vec<u8>, TlsError> {
    // Through the project's reader: a FIFO would block the start and /dev/zero grow it without
    // end.
    let text =
        crate::files::read(path, crate::files::FileKind::Pem).map_err(|e| TlsError::Read {
            path: path.to_owned(),
            source: e.into(),
        })?;
    if !text.windows(10).any(|w| w == b"-----BEGIN") {
        return Err(TlsError::NotPem {
            path: path.to_owned(),
        });
    }
    Ok(text)
}

/// The labels of a PEM file's blocks (`CERTIFICATE, PRIVATE KEY`), for an error that says what
/// the file holds instead of what was expected.
fn pem_labels(text: &[u8]) -> String {
    let text = String::from_utf8_lossy(text);
    let labels: Vec<String> = text
        .lines()
        .filter_map(|line| line.trim().strip_prefix("-----BEGIN "))
        .filter_map(|rest| rest.strip_suffix("-----"))
        .map(str::to_owned)
        .collect();
    if labels.is_empty() {
        "none".into()
    } else {
        labels.join(", ")
    }
}

/// Creates the data directory readable only by its owner (the key is kept there); an existing
/// directory is left as it is.
pub(super) fn make_private_dir(dir: &Path) -> Result<(), TlsError> {
    std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(dir)
        .map_err(|source| TlsError::DataDir {
            path: dir.to_owned(),
            source,
        })
}

/// Writes `bytes` to a temporary file beside `path` with `mode`, then renames it over `path`, so
/// that `path` is either the old file or the whole new one, and a key is never readable by others
/// even for a moment.
pub(super) fn write_file_atomically(path: &Path, bytes: &[u8], mode: u32) -> Result<(), TlsError> {
    let error = |source| TlsError::Write {
        path: path.to_owned(),
        source,
    };
    let mut temporary = path.as_os_str().to_owned();
    temporary.push(".new");
    let temporary = PathBuf::from(temporary);
    // A leftover from an interrupted start may have other permissions; `mode` applies only to a
    // file that is created.
    match std::fs::remove_file(&temporary) {
        Ok(()) => {}
        Err(e) if e.kind() == io::ErrorKind::NotFound => {}
        Err(e) => return Err(error(e)),
    }
    let written = (|| {
        use std::io::Write as _;
        let mut file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .mode(mode)
            .open(&temporary)?;
        file.write_all(bytes)?;
        file.sync_all()?;
        std::fs::rename(&temporary, path)
    })();
    written.map_err(error)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

    use super::*;

    #[test]
    fn pem_labels_say_what_a_file_holds() {
        let text = b"-----BEGIN PRIVATE KEY-----\nAAAA\n-----END PRIVATE KEY-----\n\
            -----BEGIN CERTIFICATE-----\nAAAA\n-----END CERTIFICATE-----\n";
        assert_eq!(pem_labels(text), "PRIVATE KEY, CERTIFICATE");
        assert_eq!(pem_labels(b"hello"), "none");
    }

    #[test]
    fn a_certificate_or_key_path_that_is_not_a_regular_file_is_refused_at_once() {
        // /dev/zero would grow the process without end, a FIFO block the start.
        let zero = read_certificates(Path::new("/dev/zero"))
            .unwrap_err()
            .to_string();
        assert!(
            zero.contains("/dev/zero") && zero.contains("character device"),
            "{zero}"
        );
        let dir = std::env::temp_dir().join(format!("softhaptic-pem-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let fifo = dir.join("key.fifo");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(made.success());
        let e = read_private_key(&fifo).unwrap_err().to_string();
        assert!(e.contains("is a FIFO, not a regular file"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
