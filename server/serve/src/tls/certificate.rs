//! The certificate served: the lab's own (`--tls-cert`, `--tls-key`), or a self-signed one made
//! at the first start and kept in the data directory while a client that trusts it would still
//! accept it for every requested name; the rustls configuration built from either, and the
//! fingerprint an instructor compares.

use std::net::IpAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, SystemTime};

use rustls::ServerConfig;
use rustls::client::WebPkiServerVerifier;
use rustls::client::danger::ServerCertVerifier;
use rustls::crypto::CryptoProvider;
use rustls_pki_types::{CertificateDer, PrivateKeyDer, PrivatePkcs8KeyDer, ServerName, UnixTime};
use sha2::{Digest, Sha256};

use super::pem::{make_private_dir, read_certificates, read_private_key, write_file_atomically};
use super::{
    SELF_SIGNED_CERT_FILE, SELF_SIGNED_KEY_FILE, SELF_SIGNED_RENEW_BEFORE, TlsError, TlsSetup,
};

/// How long a self-signed certificate is valid. A year, so that a lab that starts the server
/// every week keeps one fingerprint for its whole course; it is replaced at a start less than
/// [`SELF_SIGNED_RENEW_BEFORE`] before it expires.
const SELF_SIGNED_VALIDITY: Duration = Duration::from_secs(365 * 24 * 3600);
/// A new certificate is valid from a day before it is made: another machine's clock running a
/// little behind must not see it as not yet valid.
const CLOCK_SKEW_ALLOWANCE: Duration = Duration::from_secs(24 * 3600);

/// The SHA-256 fingerprint of a certificate (DER) as browsers show it: `AB:CD:…`.
pub fn fingerprint_sha256(certificate_der: &[u8]) -> String {
    let digest = Sha256::digest(certificate_der);
    let pairs: Vec<String> = digest.iter().map(|byte| format!("{byte:02X}")).collect();
    pairs.join(":")
}

/// The data directory by the XDG convention: `$XDG_DATA_HOME/softhaptic` when that is an
/// absolute path, else `$HOME/.local/share/softhaptic`; `None` when neither is set.
pub fn default_data_dir() -> Option<PathBuf> {
    data_dir_from(std::env::var_os("XDG_DATA_HOME"), std::env::var_os("HOME"))
}

fn data_dir_from(
    xdg_data_home: Option<std::ffi::OsString>,
    home: Option<std::ffi::OsString>,
) -> Option<PathBuf> {
    // The XDG specification says a relative XDG_DATA_HOME is invalid and must be ignored.
    let xdg = xdg_data_home
        .map(PathBuf::from)
        .filter(|dir| dir.is_absolute());
    let base = match xdg {
        Some(dir) => dir,
        None => PathBuf::from(home.filter(|home| !home.is_empty())?)
            .join(".local")
            .join("share"),
    };
    Some(base.join("softhaptic"))
}

/// The names of a self-signed certificate: the given ones (or `localhost` and `127.0.0.1`) and the
/// bind address unless it is unspecified, each once, in that order; IP addresses in their
/// canonical form so that `::1` and `0:0::1` are one name.
pub(super) fn self_signed_names(
    given: &[String],
    bind_ip: IpAddr,
) -> Result<Vec<String>, TlsError> {
    let defaults = ["localhost".to_owned(), "127.0.0.1".to_owned()];
    let requested = if given.is_empty() {
        &defaults[..]
    } else {
        given
    };
    let mut names: Vec<String> = Vec::new();
    for name in requested {
        let name = name.trim();
        let canonical = match name.parse::<IpAddr>() {
            Ok(ip) => ip.to_string(),
            // A name a client can verify: the same rules a TLS client applies (no wildcards,
            // no empty labels, no spaces).
            Err(_) => match rustls_pki_types::DnsName::try_from(name) {
                Ok(dns) => dns.as_ref().to_ascii_lowercase(),
                Err(_) => {
                    return Err(TlsError::InvalidName {
                        name: name.to_owned(),
                    });
                }
            },
        };
        if !names.contains(&canonical) {
            names.push(canonical);
        }
    }
    if bind_ip.is_unspecified() {
        let only_loopback = names.iter().all(|name| {
            name == "localhost" || name.parse::<IpAddr>().is_ok_and(|ip| ip.is_loopback())
        });
        if only_loopback {
            tracing::warn!(
                names = %names.join(", "),
                "the server listens on every interface but its self-signed certificate names only \
                 this machine's loopback: viewers on other machines will see a name mismatch; \
                 add --tls-name with the name or address they will use"
            );
        }
    } else if !names.contains(&bind_ip.to_string()) {
        names.push(bind_ip.to_string());
    }
    Ok(names)
}

/// The crypto provider of every TLS configuration here: ring, chosen per configuration rather
/// than installed process-wide, so that nothing depends on which part of the program installed
/// a default first.
fn crypto_provider() -> Arc<CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

/// The server configuration for a certificate chain and its key, offering HTTP/2 and HTTP/1.1.
fn rustls_config(
    chain: Vec<CertificateDer<'static>>,
    key: PrivateKeyDer<'static>,
    cert_path: &Path,
    key_path: &Path,
) -> Result<ServerConfig, TlsError> {
    let provider = crypto_provider();
    // Load the key first so that a key rustls cannot sign with is reported as such, not as a
    // mismatch.
    provider
        .key_provider
        .load_private_key(key.clone_key())
        .map_err(|source| TlsError::UnusableKey {
            path: key_path.to_owned(),
            source,
        })?;
    let mut config = ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(TlsError::Config)?
        .with_no_client_auth()
        .with_single_cert(chain, key)
        .map_err(|e| match e {
            rustls::Error::InconsistentKeys(_) => TlsError::KeyMismatch {
                cert: cert_path.to_owned(),
                key: key_path.to_owned(),
            },
            // The key loaded above, so what is left is the certificate's fault.
            source => TlsError::BadCertificate {
                path: cert_path.to_owned(),
                source,
            },
        })?;
    // HTTP/2 lets a browser fetch the viewer's many modules over one connection; a WebSocket then
    // opens its own HTTP/1.1 connection (the server does not announce WebSockets over HTTP/2).
    config.alpn_protocols = vec![b"h2".to_vec(), b"http/1.1".to_vec()];
    Ok(config)
}

/// `--tls-cert` / `--tls-key`.
pub(super) fn given_certificate(cert_path: &Path, key_path: &Path) -> Result<TlsSetup, TlsError> {
    let chain = read_certificates(cert_path)?;
    let key = read_private_key(key_path)?;
    crate::files::warn_if_others_may_read(key_path, "the TLS key (--tls-key)");
    // `read_certificates` refuses a file without a certificate, so there is a first one.
    let fingerprint = fingerprint_sha256(chain[0].as_ref());
    let config = rustls_config(chain, key, cert_path, key_path)?;
    Ok(TlsSetup {
        config: Arc::new(config),
        fingerprint_sha256: fingerprint,
        certificate_path: cert_path.to_owned(),
        generated: false,
        self_signed_names: Vec::new(),
        from_a_ca: true,
    })
}

/// `--tls-self-signed`: the kept certificate when it still serves, else a new one.
pub(super) fn self_signed(dir: &Path, names: Vec<String>) -> Result<TlsSetup, TlsError> {
    // Made 0700 when it is made; one that was there before is only looked at.
    crate::files::warn_if_others_may_read(dir, "the data directory (it keeps the TLS key)");
    let cert_path = dir.join(SELF_SIGNED_CERT_FILE);
    let key_path = dir.join(SELF_SIGNED_KEY_FILE);
    if !cert_path.exists() {
        tracing::info!(
            dir = %dir.display(),
            names = %names.join(", "),
            "making a self-signed certificate (none is kept yet)"
        );
    } else {
        match kept_self_signed(&cert_path, &key_path, &names) {
            Ok(setup) => return Ok(setup),
            Err(why) => tracing::warn!(
                dir = %dir.display(),
                names = %names.join(", "),
                "making a new self-signed certificate: {why}; viewers that trusted the previous \
                 one must trust the new one (its fingerprint follows)"
            ),
        }
    }
    let key_pair = rcgen::KeyPair::generate()?;
    let mut params = rcgen::CertificateParams::new(names.clone())?;
    let mut subject = rcgen::DistinguishedName::new();
    subject.push(rcgen::DnType::OrganizationName, "softhaptic");
    // The names are in the subject alternative names, where clients look; the common name only
    // labels the certificate in a browser's certificate viewer.
    subject.push(rcgen::DnType::CommonName, "softhaptic self-signed");
    params.distinguished_name = subject;
    let now = time::OffsetDateTime::now_utc();
    params.not_before = now - CLOCK_SKEW_ALLOWANCE;
    params.not_after = now + SELF_SIGNED_VALIDITY;
    params.key_usages = vec![rcgen::KeyUsagePurpose::DigitalSignature];
    params.extended_key_usages = vec![rcgen::ExtendedKeyUsagePurpose::ServerAuth];
    let certificate = params.self_signed(&key_pair)?;

    make_private_dir(dir)?;
    // The key before the certificate: a start that dies between the two renames leaves a
    // certificate that does not match its key, which the next start notices and replaces.
    write_file_atomically(&key_path, key_pair.serialize_pem().as_bytes(), 0o600)?;
    write_file_atomically(&cert_path, certificate.pem().as_bytes(), 0o644)?;

    let chain = vec![certificate.der().clone()];
    // rcgen serialises its keys as PKCS#8.
    let key = PrivateKeyDer::from(PrivatePkcs8KeyDer::from(key_pair.serialize_der()));
    let fingerprint = fingerprint_sha256(certificate.der().as_ref());
    let config = rustls_config(chain, key, &cert_path, &key_path)?;
    Ok(TlsSetup {
        config: Arc::new(config),
        fingerprint_sha256: fingerprint,
        certificate_path: cert_path,
        generated: true,
        self_signed_names: names,
        from_a_ca: false,
    })
}

/// The kept self-signed certificate, or why it cannot be reused.
///
/// It is reused when a client that trusts exactly this certificate would accept it for every
/// requested name, both now and [`SELF_SIGNED_RENEW_BEFORE`] from now; that is checked by the
/// same verifier a rustls client runs, rather than by reading the fields ourselves, so "reused"
/// means "what viewers already trust still works".
fn kept_self_signed(
    cert_path: &Path,
    key_path: &Path,
    names: &[String],
) -> Result<TlsSetup, String> {
    let chain = read_certificates(cert_path).map_err(|e| e.to_string())?;
    let key = read_private_key(key_path).map_err(|e| e.to_string())?;
    crate::files::warn_if_others_may_read(key_path, "the self-signed certificate's key");
    let [certificate] = &chain[..] else {
        return Err(format!(
            "{} holds more than one certificate",
            cert_path.display()
        ));
    };

    let mut roots = rustls::RootCertStore::empty();
    roots
        .add(certificate.clone())
        .map_err(|e| format!("{} cannot be parsed: {e}", cert_path.display()))?;
    let verifier = WebPkiServerVerifier::builder_with_provider(Arc::new(roots), crypto_provider())
        .build()
        .map_err(|e| format!("{} cannot be checked: {e}", cert_path.display()))?;
    let now = SystemTime::now();
    for (when, time) in [("now", now), ("in a month", now + SELF_SIGNED_RENEW_BEFORE)] {
        let unix_time = UnixTime::since_unix_epoch(
            time.duration_since(SystemTime::UNIX_EPOCH)
                .unwrap_or(Duration::ZERO),
        );
        for name in names {
            let server_name = ServerName::try_from(name.as_str())
                .map_err(|e| format!("{name:?} is not a server name: {e}"))?;
            verifier
                .verify_server_cert(certificate, &[], &server_name, &[], unix_time)
                .map_err(|e| format!("the kept one is not valid for {name} {when}: {e}"))?;
        }
    }

    let fingerprint = fingerprint_sha256(certificate.as_ref());
    let config = rustls_config(chain, key, cert_path, key_path).map_err(|e| e.to_string())?;
    Ok(TlsSetup {
        config: Arc::new(config),
        fingerprint_sha256: fingerprint,
        certificate_path: cert_path.to_owned(),
        generated: false,
        self_signed_names: names.to_vec(),
        from_a_ca: false,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

    use super::*;

    #[test]
    fn the_data_dir_follows_xdg_data_home_and_falls_back_to_home() {
        assert_eq!(
            data_dir_from(Some("/data".into()), Some("/home/u".into())),
            Some(PathBuf::from("/data/softhaptic"))
        );
        assert_eq!(
            data_dir_from(None, Some("/home/u".into())),
            Some(PathBuf::from("/home/u/.local/share/softhaptic"))
        );
        // A relative XDG_DATA_HOME is ignored, as the specification says.
        assert_eq!(
            data_dir_from(Some("rel".into()), Some("/home/u".into())),
            Some(PathBuf::from("/home/u/.local/share/softhaptic"))
        );
        assert_eq!(data_dir_from(None, None), None);
        assert_eq!(data_dir_from(None, Some("".into())), None);
    }

    #[test]
    fn self_signed_names_default_to_loopback_and_add_a_specific_bind_address() {
        let loopback: IpAddr = "127.0.0.1".parse().unwrap();
        let any: IpAddr = "0.0.0.0".parse().unwrap();
        let lab: IpAddr = "10.1.2.3".parse().unwrap();
        assert_eq!(
            self_signed_names(&[], loopback).unwrap(),
            ["localhost", "127.0.0.1"]
        );
        assert_eq!(
            self_signed_names(&[], any).unwrap(),
            ["localhost", "127.0.0.1"]
        );
        assert_eq!(
            self_signed_names(&[], lab).unwrap(),
            ["localhost", "127.0.0.1", "10.1.2.3"]
        );
        assert_eq!(
            self_signed_names(&["Lab-PC.local".into(), "0:0::1".into(), "::1".into()], lab)
                .unwrap(),
            ["lab-pc.local", "::1", "10.1.2.3"]
        );
        for bad in ["*.lab.local", "two words", "", "lab..local"] {
            assert!(
                matches!(
                    self_signed_names(&[bad.into()], loopback),
                    Err(TlsError::InvalidName { .. })
                ),
                "{bad:?} was accepted"
            );
        }
    }

    #[test]
    fn the_fingerprint_is_upper_case_hex_pairs_joined_by_colons() {
        // SHA-256 of the empty input.
        assert_eq!(
            fingerprint_sha256(b""),
            "E3:B0:C4:42:98:FC:1C:14:9A:FB:F4:C8:99:6F:B9:24:27:AE:41:E4:64:9B:93:4C:A4:95:99:1B:78:52:B8:55"
        );
    }
}
