//! TLS for the viewer's port: https and wss on the same address as plain http and ws, with
//! rustls (no OpenSSL).
//!
//! [`TlsArgs`] are the command-line options; [`server_config`] turns them into a rustls
//! configuration, from the lab's own certificate (`--tls-cert` / `--tls-key`, PEM) or from a
//! self-signed certificate (`--tls-self-signed`) that is made at the first start, kept in the data
//! directory and reused while it still names the requested hosts and has a month left; its SHA-256
//! fingerprint is what an instructor compares before trusting it. [`serve`] serves an axum router
//! on a listener, plainly without a configuration and over TLS with one.
//!
//! Why a client that does not speak TLS cannot hold the port: every connection is handled by its
//! own task, and that task gives the client [`HANDSHAKE_TIMEOUT`] to send its first byte and as
//! long again to finish the handshake, then [`FIRST_REQUEST_TIMEOUT`] to send a request, so a
//! slow or silent client holds one socket for a bounded time and never the accept loop. A client
//! whose first byte is not a TLS handshake record (a browser or a `ws://` viewer pointed at the
//! port) gets a plain-text `400` saying to use https and is closed; a failed handshake is closed
//! too. Either way it is one log line, and the other connections never notice.
//!
//! Both ways of serving hand every request its client's address as
//! [`axum::extract::ConnectInfo<SocketAddr>`], so per-client checks work the same with and
//! without TLS.

use std::fmt;
use std::future::Future;
use std::io;
use std::net::{IpAddr, SocketAddr};
use std::os::unix::fs::{DirBuilderExt, OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::Arc;
use std::time::{Duration, SystemTime};

use axum::Router;
use axum_server::accept::Accept;
use axum_server::tls_rustls::{RustlsAcceptor, RustlsConfig};
use rustls::ServerConfig;
use rustls::client::WebPkiServerVerifier;
use rustls::client::danger::ServerCertVerifier;
use rustls::crypto::CryptoProvider;
use rustls_pki_types::pem::{self, PemObject};
use rustls_pki_types::{CertificateDer, PrivateKeyDer, PrivatePkcs8KeyDer, ServerName, UnixTime};
use sha2::{Digest, Sha256};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio::task::JoinHandle;

/// The file in the data directory that keeps the self-signed certificate (PEM).
pub const SELF_SIGNED_CERT_FILE: &str = "self-signed-cert.pem";
/// The file in the data directory that keeps the self-signed certificate's private key (PEM,
/// mode 0600).
pub const SELF_SIGNED_KEY_FILE: &str = "self-signed-key.pem";

/// How long a new connection may take to send its first byte, and then again to complete the
/// TLS handshake. A browser on a lab network needs milliseconds; ten seconds forgives a slow
/// wireless link and still frees the socket of a client that never speaks.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);
/// How long a connection that finished its handshake may take to send its first request.
/// Browsers open connections ahead of use, so this is longer than the handshake's.
pub const FIRST_REQUEST_TIMEOUT: Duration = Duration::from_secs(30);

/// How long a self-signed certificate is valid. A year, so that a lab that starts the server
/// every week keeps one fingerprint for its whole course; it is replaced at a start less than
/// [`SELF_SIGNED_RENEW_BEFORE`] before it expires.
const SELF_SIGNED_VALIDITY: Duration = Duration::from_secs(365 * 24 * 3600);
/// A kept self-signed certificate with less than this left is replaced at start, so that it does
/// not expire in the middle of a course, between two starts.
pub const SELF_SIGNED_RENEW_BEFORE: Duration = Duration::from_secs(30 * 24 * 3600);
/// A new certificate is valid from a day before it is made: another machine's clock running a
/// little behind must not see it as not yet valid.
const CLOCK_SKEW_ALLOWANCE: Duration = Duration::from_secs(24 * 3600);

/// The first byte of every TLS connection: the record type of a handshake (RFC 8446 §5.1).
const TLS_HANDSHAKE_RECORD: u8 = 0x16;

/// What a client that spoke plain HTTP to the TLS port reads (in a `400 Bad Request`) before it
/// is closed: a browser shows it in place of a bare "connection reset".
const PLAIN_TEXT_REFUSAL: &str =
    "This softhaptic server speaks TLS only: open it with https:// (and its stream with wss://).\n";

/// The TLS options of the `softhaptic` command (flattened into its run and replay options).
#[derive(clap::Args, Debug, Clone, Default, PartialEq, Eq)]
pub struct TlsArgs {
    /// Serve https and wss with this certificate (PEM: the server's certificate first, then the
    /// intermediate certificates of its chain, as a CA delivers them).
    #[arg(
        long,
        value_name = "FILE",
        requires = "tls_key",
        conflicts_with = "tls_self_signed"
    )]
    pub tls_cert: Option<PathBuf>,
    /// The private key of --tls-cert (PEM, not encrypted: PKCS#8, PKCS#1 or SEC1).
    #[arg(long, value_name = "FILE", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// Serve https and wss with a self-signed certificate: made at the first start, kept in the
    /// data directory and reused while it still names every --tls-name and has a month left. Its
    /// SHA-256 fingerprint is printed at start: compare it with what the browser shows before
    /// trusting the certificate.
    #[arg(long)]
    pub tls_self_signed: bool,
    /// A host name or IP address the self-signed certificate names, as viewers will type it in
    /// the URL (repeatable) [default: localhost and 127.0.0.1]. The --addr IP is always named
    /// too, unless it is 0.0.0.0 or ::.
    #[arg(long = "tls-name", value_name = "NAME", requires = "tls_self_signed")]
    pub tls_names: Vec<String>,
    /// Where the self-signed certificate and its key are kept (created with mode 0700, the key
    /// 0600) [default: $XDG_DATA_HOME/softhaptic, else ~/.local/share/softhaptic].
    #[arg(long, value_name = "DIR")]
    pub data_dir: Option<PathBuf>,
}

/// A TLS configuration ready to serve, and what to tell the user about it.
#[derive(Debug, Clone)]
pub struct TlsSetup {
    /// What [`serve`] takes.
    pub config: Arc<ServerConfig>,
    /// The SHA-256 of the server's certificate (DER), as browsers and `openssl x509 -fingerprint
    /// -sha256` show it: upper-case hex pairs joined by colons.
    pub fingerprint_sha256: String,
    /// The certificate file: `--tls-cert`, or the kept self-signed certificate.
    pub certificate_path: PathBuf,
    /// The self-signed certificate was made at this start (a client that trusted the previous one
    /// must trust this one anew).
    pub generated: bool,
    /// The names the self-signed certificate is valid for; empty for `--tls-cert`, whose
    /// certificate carries its own names.
    pub self_signed_names: Vec<String>,
}

/// For the start-up message: which certificate, and the fingerprint to compare.
impl fmt::Display for TlsSetup {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let path = self.certificate_path.display();
        if self.self_signed_names.is_empty() {
            writeln!(f, "TLS certificate: {path}")?;
        } else {
            let age = if self.generated {
                "made at this start"
            } else {
                "kept from an earlier start"
            };
            writeln!(
                f,
                "TLS certificate: {path} (self-signed, {age}, for {})",
                self.self_signed_names.join(", ")
            )?;
        }
        write!(
            f,
            "TLS certificate SHA-256 fingerprint: {}",
            self.fingerprint_sha256
        )
    }
}

/// Why TLS could not be set up. Each names the option or file and what is wrong with it.
#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    #[error(
        "--tls-cert and --tls-self-signed were both given: serve with your certificate or with a \
         self-signed one, not both"
    )]
    CertAndSelfSigned,
    #[error("--tls-cert {} needs --tls-key, the file of its private key", cert.display())]
    CertWithoutKey { cert: PathBuf },
    #[error("--tls-key {} needs --tls-cert, the file of its certificate", key.display())]
    KeyWithoutCert { key: PathBuf },
    #[error(
        "--tls-name applies only to --tls-self-signed (a certificate given with --tls-cert \
         carries its own names)"
    )]
    NamesWithoutSelfSigned,
    #[error("--tls-name {name:?} is not a host name or an IP address")]
    InvalidName { name: String },
    #[error("could not read {}: {source}", path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error(
        "{} is not a PEM file (no \"-----BEGIN\" line); a DER file converts with \
         `openssl x509 -inform der` (certificate) or `openssl pkey -inform der` (key)",
        path.display()
    )]
    NotPem { path: PathBuf },
    #[error("{} is damaged PEM: {source}", path.display())]
    BadPem {
        path: PathBuf,
        #[source]
        source: pem::Error,
    },
    #[error("{} holds no certificate (its PEM blocks: {found})", path.display())]
    NoCertificate { path: PathBuf, found: String },
    #[error(
        "{} holds no private key (its PEM blocks: {found}; expected PRIVATE KEY, RSA PRIVATE KEY \
         or EC PRIVATE KEY)",
        path.display()
    )]
    NoPrivateKey { path: PathBuf, found: String },
    #[error(
        "the private key in {} is encrypted; write it out unencrypted for the server with \
         `openssl pkey -in KEY -out KEY.plain.pem` and keep that file readable only by the server's \
         user",
        path.display()
    )]
    EncryptedKey { path: PathBuf },
    #[error("the private key in {} cannot be used: {source}", path.display())]
    UnusableKey {
        path: PathBuf,
        #[source]
        source: rustls::Error,
    },
    #[error("the certificate in {} cannot be used: {source}", path.display())]
    BadCertificate {
        path: PathBuf,
        #[source]
        source: rustls::Error,
    },
    #[error(
        "the private key in {} does not belong to the certificate in {}",
        key.display(),
        cert.display()
    )]
    KeyMismatch { cert: PathBuf, key: PathBuf },
    #[error(
        "no data directory to keep the self-signed certificate in: neither XDG_DATA_HOME nor HOME \
         is set; give --data-dir"
    )]
    NoDataDir,
    #[error("could not create the data directory {}: {source}", path.display())]
    DataDir {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error("could not write {}: {source}", path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error("could not make a self-signed certificate: {0}")]
    Generate(#[from] rcgen::Error),
    #[error("TLS configuration: {0}")]
    Config(#[source] rustls::Error),
}

/// The TLS configuration the options ask for: `None` without TLS options, else the certificate
/// from `--tls-cert` / `--tls-key`, or the self-signed certificate (kept in the data directory
/// and reused while it covers the names and has more than [`SELF_SIGNED_RENEW_BEFORE`] left,
/// otherwise made anew with a log line saying why).
///
/// `bind_ip` is the address the server listens on; a self-signed certificate names it too unless
/// it is unspecified (`0.0.0.0`, `::`).
///
/// Runs before the server starts (it reads and may write files, and makes a key); call it where
/// blocking is fine.
pub fn server_config(args: &TlsArgs, bind_ip: IpAddr) -> Result<Option<TlsSetup>, TlsError> {
    // The same rules clap enforces on the command line, for callers that build `TlsArgs`
    // themselves.
    if args.tls_cert.is_some() && args.tls_self_signed {
        return Err(TlsError::CertAndSelfSigned);
    }
    if !args.tls_self_signed && !args.tls_names.is_empty() {
        return Err(TlsError::NamesWithoutSelfSigned);
    }
    match (&args.tls_cert, &args.tls_key) {
        (Some(cert), Some(key)) => given_certificate(cert, key).map(Some),
        (Some(cert), None) => Err(TlsError::CertWithoutKey { cert: cert.clone() }),
        (None, Some(key)) => Err(TlsError::KeyWithoutCert { key: key.clone() }),
        (None, None) if args.tls_self_signed => {
            let names = self_signed_names(&args.tls_names, bind_ip)?;
            let dir = match &args.data_dir {
                Some(dir) => dir.clone(),
                None => default_data_dir().ok_or(TlsError::NoDataDir)?,
            };
            self_signed(&dir, names).map(Some)
        }
        (None, None) => Ok(None),
    }
}

/// Serves `app` on `listener` until `shutdown` turns true (or its sender is dropped), then stops
/// accepting and lets open requests finish. Without `tls` it is plain http and ws, as
/// `axum::serve` serves; with it, https and wss on the same port (HTTP/1.1 and HTTP/2, WebSocket upgrades
/// over HTTP/1.1), a plain-text client refused as the module's docs say.
///
/// Requests carry [`axum::extract::ConnectInfo<SocketAddr>`] either way.
pub fn serve(
    listener: TcpListener,
    app: Router,
    tls: Option<Arc<ServerConfig>>,
    mut shutdown: watch::Receiver<bool>,
) -> JoinHandle<()> {
    let service = app.into_make_service_with_connect_info::<SocketAddr>();
    let Some(config) = tls else {
        return tokio::spawn(async move {
            let served = axum::serve(listener, service)
                .with_graceful_shutdown(async move {
                    let _ = shutdown.wait_for(|stop| *stop).await;
                })
                .await;
            if let Err(e) = served {
                tracing::error!(error = %e, "HTTP server failed");
            }
        });
    };
    let handle = axum_server::Handle::new();
    let acceptor = RustlsAcceptor::new(RustlsConfig::from_config(config))
        .handshake_timeout(HANDSHAKE_TIMEOUT)
        .acceptor(RefusePlainText);
    let server = axum_server::Server::from_listener(listener)
        .acceptor(acceptor)
        .handle(handle.clone())
        .first_request_timeout(FIRST_REQUEST_TIMEOUT)
        .accept_error_handler(log_refused_connection);
    tokio::spawn(async move {
        let served = server.serve(service);
        tokio::pin!(served);
        let stop = async move {
            let _ = shutdown.wait_for(|stop| *stop).await;
        };
        let served = tokio::select! {
            served = &mut served => served,
            () = stop => {
                // No deadline, as with axum's own graceful shutdown: requests in flight finish
                // and idle connections close. An upgraded WebSocket is no longer the server's
                // connection; the router's viewer tasks close theirs on the same signal.
                handle.graceful_shutdown(None);
                served.await
            }
        };
        if let Err(e) = served {
            tracing::error!(error = %e, "HTTPS server failed");
        }
    })
}

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
fn self_signed_names(given: &[String], bind_ip: IpAddr) -> Result<Vec<String>, TlsError> {
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
fn given_certificate(cert_path: &Path, key_path: &Path) -> Result<TlsSetup, TlsError> {
    let chain = read_certificates(cert_path)?;
    let key = read_private_key(key_path)?;
    // `read_certificates` refuses a file without a certificate, so there is a first one.
    let fingerprint = fingerprint_sha256(chain[0].as_ref());
    let config = rustls_config(chain, key, cert_path, key_path)?;
    Ok(TlsSetup {
        config: Arc::new(config),
        fingerprint_sha256: fingerprint,
        certificate_path: cert_path.to_owned(),
        generated: false,
        self_signed_names: Vec::new(),
    })
}

/// `--tls-self-signed`: the kept certificate when it still serves, else a new one.
fn self_signed(dir: &Path, names: Vec<String>) -> Result<TlsSetup, TlsError> {
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
    let others_may_read = std::fs::metadata(key_path)
        .is_ok_and(|metadata| metadata.permissions().mode() & 0o077 != 0);
    if others_may_read {
        tracing::warn!(
            key = %key_path.display(),
            "the self-signed certificate's key is readable by other users; `chmod 600` it"
        );
    }
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
    })
}

/// The certificates of a PEM file, in file order (the server's own first).
fn read_certificates(path: &Path) -> Result<Vec<CertificateDer<'static>>, TlsError> {
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
fn read_private_key(path: &Path) -> Result<PrivateKeyDer<'static>, TlsError> {
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
    let text = std::fs::read(path).map_err(|source| TlsError::Read {
        path: path.to_owned(),
        source,
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
fn make_private_dir(dir: &Path) -> Result<(), TlsError> {
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
fn write_file_atomically(path: &Path, bytes: &[u8], mode: u32) -> Result<(), TlsError> {
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

/// The inner acceptor of the TLS acceptor: lets a connection through to the TLS handshake only
/// when its first byte starts one, and otherwise answers a short plain-text 400 and closes.
#[derive(Debug, Clone, Copy)]
struct RefusePlainText;

/// The error a plain-text client's connection ends with, told apart in the log.
#[derive(Debug, thiserror::Error)]
#[error("a plain-text client on the TLS port (http:// or ws:// instead of https:// or wss://)")]
struct PlainTextRefused;

impl<S: Send + 'static> Accept<TcpStream, S> for RefusePlainText {
    type Stream = TcpStream;
    type Service = S;
    type Future = Pin<Box<dyn Future<Output = io::Result<(TcpStream, S)>> + Send>>;

    fn accept(&self, stream: TcpStream, service: S) -> Self::Future {
        Box::pin(async move {
            let mut first = [0_u8; 1];
            let peeked = tokio::time::timeout(HANDSHAKE_TIMEOUT, stream.peek(&mut first))
                .await
                .map_err(|_| {
                    io::Error::new(io::ErrorKind::TimedOut, "no TLS handshake began in time")
                })??;
            if peeked == 0 {
                return Err(io::Error::new(
                    io::ErrorKind::UnexpectedEof,
                    "closed before the TLS handshake",
                ));
            }
            if first[0] != TLS_HANDSHAKE_RECORD {
                refuse_plain_text(stream).await;
                return Err(io::Error::new(io::ErrorKind::InvalidData, PlainTextRefused));
            }
            Ok((stream, service))
        })
    }
}

/// Tells a plain-text client to use https and closes its connection, in at most about 2.5 s.
async fn refuse_plain_text(mut stream: TcpStream) {
    // Read the request first: closing a socket with unread data sends a reset, and a reset can
    // make the client discard our answer before showing it.
    let mut buffer = [0_u8; 4096];
    let _ = tokio::time::timeout(Duration::from_millis(500), stream.read(&mut buffer)).await;
    let _ = tokio::time::timeout(Duration::from_secs(1), async {
        let response = format!(
            "HTTP/1.1 400 Bad Request\r\nContent-Type: text/plain; charset=utf-8\r\n\
             Content-Length: {}\r\nConnection: close\r\n\r\n{PLAIN_TEXT_REFUSAL}",
            PLAIN_TEXT_REFUSAL.len()
        );
        stream.write_all(response.as_bytes()).await?;
        stream.shutdown().await
    })
    .await;
    // Then wait (briefly) for the client to close its side, for the same reason.
    let _ = tokio::time::timeout(Duration::from_secs(1), async {
        while let Ok(n) = stream.read(&mut buffer).await {
            if n == 0 {
                break;
            }
        }
    })
    .await;
}

/// One log line per connection that did not become a TLS connection; never an error, because a
/// client (or a port scanner) causes it, not the server.
fn log_refused_connection(client: Option<&SocketAddr>, error: &io::Error) {
    let Some(client) = client else {
        // The listener itself failed (out of file descriptors, say); axum-server backs off and
        // keeps accepting.
        tracing::warn!(error = %error, "could not accept a connection");
        return;
    };
    let inner = error.get_ref();
    if inner.is_some_and(|e| e.is::<PlainTextRefused>()) {
        tracing::info!(
            %client,
            "refused a plain-text request on the TLS port: told the client to use https:// and wss://"
        );
    } else if let Some(rustls::Error::AlertReceived(alert)) =
        inner.and_then(|e| e.downcast_ref::<rustls::Error>())
    {
        // The usual cause is a browser or viewer that does not trust the certificate yet; worth
        // seeing when a lab machine cannot connect.
        tracing::info!(
            %client,
            alert = ?alert,
            "a client ended the TLS handshake (does it trust this server's certificate?)"
        );
    } else {
        tracing::debug!(%client, error = %error, "TLS handshake failed");
    }
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

    #[test]
    fn pem_labels_say_what_a_file_holds() {
        let text = b"-----BEGIN PRIVATE KEY-----\nAAAA\n-----END PRIVATE KEY-----\n\
            -----BEGIN CERTIFICATE-----\nAAAA\n-----END CERTIFICATE-----\n";
        assert_eq!(pem_labels(text), "PRIVATE KEY, CERTIFICATE");
        assert_eq!(pem_labels(b"hello"), "none");
    }
}
