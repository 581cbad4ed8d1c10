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
//! long again to finish the handshake, then [`FIRST_REQUEST_TIMEOUT`] to send a request and
//! [`HEADER_READ_TIMEOUT`] for each request's headers (plain http alike), an HTTP/2 connection
//! [`HTTP2_IDLE_TIMEOUT`] without traffic, so a slow, silent or idle
//! client holds one socket for a bounded time and never the accept loop; and the sockets held
//! open are capped per client address and in all ([`ConnectionCaps`]). A client
//! whose first byte is not a TLS handshake record (a browser or a `ws://` viewer pointed at the
//! port) gets a plain-text `400` saying to use https and is closed; a failed handshake is closed
//! too. Either way it is one log line, and the other connections never notice.
//!
//! Both ways of serving hand every request its client's address as
//! [`axum::extract::ConnectInfo<SocketAddr>`], so per-client checks work the same with and
//! without TLS.
//!
//! # Layout
//! - this file: the options ([`TlsArgs`]), what they resolve into ([`server_config`],
//!   [`TlsSetup`]) and why they could not ([`TlsError`]).
//! - `certificate.rs`: the lab's certificate or the kept self-signed one, its names, the data
//!   directory, the rustls configuration and the fingerprint.
//! - `pem.rs`: reading certificates and keys from PEM files, and writing the kept ones.
//! - `serve.rs`: [`serve`], plainly or over TLS, and the refusal of a plain-text client.
//! - `idle.rs`: the idle timeout of HTTP/2 connections.

mod certificate;
mod idle;
mod pem;
mod serve;

use std::fmt;
use std::io;
use std::net::IpAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use rustls::ServerConfig;

pub use certificate::{default_data_dir, fingerprint_sha256};
use certificate::{given_certificate, self_signed, self_signed_names};
pub use serve::{ConnectionCaps, ensure_open_file_limit, open_file_limit_plan, serve};

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
/// How long a request's headers may take to arrive, counted from when the connection is ready for
/// them: a client that sends them a byte at a time, or holds a keep-alive connection idle, is
/// closed after this. Browsers reopen idle connections as they need them.
pub const HEADER_READ_TIMEOUT: Duration = Duration::from_secs(30);
/// How long an HTTP/2 connection may go without a byte either way before it is closed: as long
/// as an HTTP/1.1 keep-alive connection may stay idle ([`HEADER_READ_TIMEOUT`]).
pub const HTTP2_IDLE_TIMEOUT: Duration = Duration::from_secs(30);
/// A kept self-signed certificate with less than this left is replaced at start, so that it does
/// not expire in the middle of a course, between two starts.
pub const SELF_SIGNED_RENEW_BEFORE: Duration = Duration::from_secs(30 * 24 * 3600);

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
    /// The certificate is a CA's (`--tls-cert`): browsers trust it without a click, so the
    /// server may tell them to use https only (`AccessConfig::strict_transport`).
    pub from_a_ca: bool,
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
        source: rustls_pki_types::pem::Error,
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
