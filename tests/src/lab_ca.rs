//! A lab's own certificate authority and a server certificate it signed, as a lab's CA issues
//! them, for the tests of TLS with a CA-signed certificate: the viewer's port
//! (`server/tests/tls.rs`) and NATS (`tests/lab_permissions.rs`).
//!
//! The server's integration tests include this file by its path (`#[path]`), since they cannot
//! depend on this crate, which depends on the server: so it uses nothing of this crate.

/// The CA's certificate and a server certificate it signed, with the server's key.
#[derive(Debug, Clone)]
pub struct LabCa {
    /// The CA's certificate (DER): what a client trusts.
    pub ca_der: Vec<u8>,
    /// The CA's certificate (PEM).
    pub ca_pem: String,
    /// The server's certificate (PEM), signed by the CA.
    pub server_pem: String,
    /// The server's private key (PEM, PKCS#8).
    pub server_key_pem: String,
    /// The server's certificate (DER).
    pub server_der: Vec<u8>,
}

impl LabCa {
    /// A new CA ("Lab CA") and a server certificate it signed for `server_names` (host names or
    /// IP addresses), for server authentication.
    pub fn new(server_names: &[&str]) -> LabCa {
        let ca_key = rcgen::KeyPair::generate().expect("a CA key");
        let mut ca_params =
            rcgen::CertificateParams::new(Vec::<String>::new()).expect("the CA's parameters");
        ca_params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
        ca_params
            .distinguished_name
            .push(rcgen::DnType::CommonName, "Lab CA");
        ca_params.key_usages = vec![
            rcgen::KeyUsagePurpose::KeyCertSign,
            rcgen::KeyUsagePurpose::CrlSign,
        ];
        let ca_cert = ca_params
            .self_signed(&ca_key)
            .expect("the CA's certificate");
        let issuer = rcgen::Issuer::new(ca_params, ca_key);
        let server_key = rcgen::KeyPair::generate().expect("a server key");
        let names = server_names
            .iter()
            .map(|&n| n.to_owned())
            .collect::<Vec<_>>();
        let mut server_params =
            rcgen::CertificateParams::new(names).expect("the server certificate's names");
        server_params.extended_key_usages = vec![rcgen::ExtendedKeyUsagePurpose::ServerAuth];
        let server_cert = server_params
            .signed_by(&server_key, &issuer)
            .expect("the server's certificate");
        LabCa {
            ca_der: ca_cert.der().to_vec(),
            ca_pem: ca_cert.pem(),
            server_pem: server_cert.pem(),
            server_key_pem: server_key.serialize_pem(),
            server_der: server_cert.der().to_vec(),
        }
    }
}
