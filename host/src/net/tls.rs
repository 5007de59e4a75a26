//! `wss://`: TLS on the protocol's port with rustls (ring provider; no
//! OpenSSL), from a PEM certificate chain and private key.
//!
//! A certificate every client will refuse is refused at start, saying why
//! (expired, not yet valid, a CA certificate, a key that is not its own),
//! rather than failing every handshake later; one that names none of the
//! names clients reach the daemon by is only warned about (the daemon
//! cannot know every name a client uses).

use std::net::IpAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{SystemTime, UNIX_EPOCH};

use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer, ServerName};
use tokio_rustls::TlsAcceptor;
use x509_parser::prelude::{FromDer, X509Certificate};

/// Why the certificate or key cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    /// The certificate file cannot be read or holds no PEM certificate.
    #[error("cannot read a PEM certificate chain from {path}: {why}")]
    Certificate {
        /// The file.
        path: PathBuf,
        /// Why.
        why: String,
    },
    /// The key file cannot be read or holds no PEM private key.
    #[error("cannot read a PEM private key from {path}: {why}")]
    Key {
        /// The file.
        path: PathBuf,
        /// Why.
        why: String,
    },
    /// The certificate's validity ended.
    #[error("the certificate in {path} expired ({until}): issue a new one")]
    Expired {
        /// The file.
        path: PathBuf,
        /// Its `notAfter`.
        until: String,
    },
    /// The certificate's validity has not begun.
    #[error("the certificate in {path} is not valid before {from}: is this machine's clock right?")]
    NotYetValid {
        /// The file.
        path: PathBuf,
        /// Its `notBefore`.
        from: String,
    },
    /// The server's certificate is a CA certificate, which clients refuse.
    #[error(
        "the certificate in {0} is a CA certificate (basicConstraints CA:TRUE), which clients refuse \
         from a server: issue a server certificate with CA:FALSE"
    )]
    CaCertificate(PathBuf),
    /// The private key belongs to another certificate.
    #[error("the private key in {key} is not the key of the certificate in {cert}")]
    KeyMismatch {
        /// The certificate file.
        cert: PathBuf,
        /// The key file.
        key: PathBuf,
    },
    /// rustls refused the pair for another reason.
    #[error("the certificate and key cannot be used together: {0}")]
    Config(#[from] rustls::Error),
}

/// The crypto provider of every TLS configuration here.
pub fn provider() -> Arc<rustls::crypto::CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

/// A certificate and key ready to serve `wss://`.
pub struct Served {
    /// The acceptor for new connections.
    pub acceptor: TlsAcceptor,
    leaf: CertificateDer<'static>,
}

impl Served {
    /// Whether the certificate is valid for at least one of `names` (IP
    /// addresses or DNS names), as a client checks it.
    pub fn names_any<'n>(&self, names: impl IntoIterator<Item = &'n str>) -> bool {
        let Ok(cert) = webpki::EndEntityCert::try_from(&self.leaf) else {
            return false;
        };
        names.into_iter().any(|name| {
            ServerName::try_from(name).is_ok_and(|n| cert.verify_is_valid_for_subject_name(&n).is_ok())
        })
    }
}

/// A TLS acceptor for the certificate chain in `cert` and the key in `key`,
/// refused when no client would accept the certificate at `now`.
pub fn acceptor(cert: &Path, key: &Path, now: SystemTime) -> Result<Served, TlsError> {
    let unreadable = |why: String| TlsError::Certificate {
        path: cert.to_owned(),
        why,
    };
    let chain = CertificateDer::pem_file_iter(cert)
        .and_then(|certs| certs.collect::<Result<Vec<_>, _>>())
        .map_err(|e| unreadable(e.to_string()))?;
    let leaf = chain
        .first()
        .cloned()
        .ok_or_else(|| unreadable("no CERTIFICATE block in the file".into()))?;
    check_leaf(&leaf, cert, now)?;
    let private = PrivateKeyDer::from_pem_file(key).map_err(|e| TlsError::Key {
        path: key.to_owned(),
        why: e.to_string(),
    })?;
    let config = rustls::ServerConfig::builder_with_provider(provider())
        .with_safe_default_protocol_versions()?
        .with_no_client_auth()
        .with_single_cert(chain, private)
        .map_err(|e| match e {
            rustls::Error::InconsistentKeys(rustls::InconsistentKeys::KeyMismatch) => TlsError::KeyMismatch {
                cert: cert.to_owned(),
                key: key.to_owned(),
            },
            e => TlsError::Config(e),
        })?;
    Ok(Served {
        acceptor: TlsAcceptor::from(Arc::new(config)),
        leaf,
    })
}

/// Refuses a server certificate that clients refuse whatever their trust
/// store: outside its validity, or a CA's.
fn check_leaf(leaf: &CertificateDer<'_>, path: &Path, now: SystemTime) -> Result<(), TlsError> {
    let (_, x509) = X509Certificate::from_der(leaf).map_err(|e| TlsError::Certificate {
        path: path.to_owned(),
        why: format!("not an X.509 certificate ({e})"),
    })?;
    let now_s = now
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_secs()).unwrap_or(i64::MAX));
    let validity = x509.validity();
    if now_s > validity.not_after.timestamp() {
        return Err(TlsError::Expired {
            path: path.to_owned(),
            until: validity.not_after.to_string(),
        });
    }
    if now_s < validity.not_before.timestamp() {
        return Err(TlsError::NotYetValid {
            path: path.to_owned(),
            from: validity.not_before.to_string(),
        });
    }
    if x509.is_ca() {
        return Err(TlsError::CaCertificate(path.to_owned()));
    }
    Ok(())
}

/// The names clients may reach a daemon bound to `bind` by: that address
/// (every interface's, when it is unspecified), `localhost` on loopback,
/// and the operator's `--allow-host` names.
pub fn reachable_names(bind: IpAddr, hosts: &[String]) -> Vec<String> {
    let mut names: Vec<String> = if bind.is_unspecified() {
        nix::ifaddrs::getifaddrs()
            .map(|all| {
                all.filter_map(|i| i.address)
                    .filter_map(|a| match (a.as_sockaddr_in(), a.as_sockaddr_in6()) {
                        (Some(v4), _) => Some(IpAddr::V4(v4.ip())),
                        (_, Some(v6)) => Some(IpAddr::V6(v6.ip())),
                        _ => None,
                    })
                    .map(|ip| ip.to_string())
                    .collect()
            })
            .unwrap_or_default()
    } else {
        vec![bind.to_string()]
    };
    if bind.is_unspecified() || bind.is_loopback() {
        names.push("localhost".into());
    }
    names.extend(hosts.iter().cloned());
    names
}
