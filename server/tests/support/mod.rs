//! What several of the server's integration tests need alike: stopping a started `softhaptic`
//! binary with a signal, and a TLS client that pins the certificate fingerprint the server
//! printed. Each test file includes it with `mod support;`.

// Every test file is its own crate and uses only part of this module; the rest would warn there.
#![allow(
    dead_code,
    reason = "each test binary that includes this module uses only part of it"
)]

use std::process::{Child, Command, ExitStatus};
use std::sync::Arc;
use std::time::{Duration, Instant};

use rustls::client::danger::{HandshakeSignatureValid, ServerCertVerified, ServerCertVerifier};
use rustls::crypto::CryptoProvider;
use rustls::pki_types::{CertificateDer, ServerName, UnixTime};
use rustls::{ClientConfig, DigitallySignedStruct, SignatureScheme};

/// How long a server may take to stop after a signal: generous, for a loaded machine.
pub const STOP_DEADLINE: Duration = Duration::from_secs(60);

/// Sends `kill -<signal>` (`"TERM"`, `"INT"`, …) to the child and waits until it exits, at most
/// [`STOP_DEADLINE`]; a child still running then is killed and the test fails naming the signal.
pub fn stop_with_signal(child: &mut Child, signal: &str) -> ExitStatus {
    let sent = Command::new("kill")
        .args([format!("-{signal}"), child.id().to_string()])
        .status()
        .expect("kill runs");
    assert!(sent.success(), "kill -{signal} failed: {sent}");
    let give_up = Instant::now() + STOP_DEADLINE;
    loop {
        if let Some(status) = child.try_wait().expect("the child's status can be read") {
            return status;
        }
        if Instant::now() >= give_up {
            let _ = child.kill();
            let _ = child.wait();
            panic!("SIG{signal} did not stop the server within {STOP_DEADLINE:?}");
        }
        #[allow(clippy::disallowed_methods)] // test code: polls a child process on its own thread
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The crypto provider every test client uses (ring, as the server does).
pub fn provider() -> Arc<CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

/// Trusts the one certificate whose SHA-256 fingerprint is the one the server printed, as a lab
/// without a CA would after comparing it with what the server's console shows; the handshake's
/// signatures are still checked with the certificate's key.
#[derive(Debug)]
struct Pinned {
    fingerprint: String,
    provider: Arc<CryptoProvider>,
}

impl ServerCertVerifier for Pinned {
    fn verify_server_cert(
        &self,
        end_entity: &CertificateDer<'_>,
        _intermediates: &[CertificateDer<'_>],
        _server_name: &ServerName<'_>,
        _ocsp_response: &[u8],
        _now: UnixTime,
    ) -> Result<ServerCertVerified, rustls::Error> {
        if softhaptic_server::tls::fingerprint_sha256(end_entity.as_ref()) == self.fingerprint {
            Ok(ServerCertVerified::assertion())
        } else {
            Err(rustls::Error::InvalidCertificate(
                rustls::CertificateError::ApplicationVerificationFailure,
            ))
        }
    }

    fn verify_tls12_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        rustls::crypto::verify_tls12_signature(
            message,
            cert,
            dss,
            &self.provider.signature_verification_algorithms,
        )
    }

    fn verify_tls13_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        rustls::crypto::verify_tls13_signature(
            message,
            cert,
            dss,
            &self.provider.signature_verification_algorithms,
        )
    }

    fn supported_verify_schemes(&self) -> Vec<SignatureScheme> {
        self.provider
            .signature_verification_algorithms
            .supported_schemes()
    }
}

/// A client that accepts the server's certificate exactly when its SHA-256 fingerprint is
/// `fingerprint` (the server's printed form), with no ALPN.
pub fn client_pinning(fingerprint: &str) -> Arc<ClientConfig> {
    Arc::new(
        ClientConfig::builder_with_provider(provider())
            .with_safe_default_protocol_versions()
            .expect("the ring provider supports the default TLS versions")
            .dangerous()
            .with_custom_certificate_verifier(Arc::new(Pinned {
                fingerprint: fingerprint.to_owned(),
                provider: provider(),
            }))
            .with_no_client_auth(),
    )
}
