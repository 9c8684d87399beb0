//! TLS to PostgreSQL, with libpq's `sslmode` meanings: managed databases (RDS, Cloud SQL,
//! Azure) require TLS, and their users copy libpq connection strings.
//!
//! tokio-postgres itself knows `sslmode` `disable`, `prefer` and `require` only, rejects
//! `verify-ca`, `verify-full` and `sslrootcert`, and leaves checking the server's certificate
//! to the TLS connector. So [`TlsSettings::take_from`] takes `sslmode` and `sslrootcert` out of
//! the connection string, and [`TlsSettings::connector`] builds the matching check on rustls
//! with ring (the crypto provider of the rest of the service):
//!
//! | `sslmode` | TLS | the server's certificate |
//! |---|---|---|
//! | `disable` | never | — |
//! | `prefer` (default) | when the server offers it | not checked, unless `sslrootcert` is given (then as `verify-ca`) |
//! | `require` | always | as `prefer` |
//! | `verify-ca` | always | chains to `sslrootcert` (a PEM file; absent or `system`: the webpki roots) |
//! | `verify-full` | always | as `verify-ca`, and names the host connected to |
//!
//! As with libpq, `prefer` and `require` without a root certificate encrypt but do not
//! authenticate the server. Client certificates (`sslcert`, `sslkey`) are not supported.

use std::str::FromStr;
use std::sync::Arc;

use rustls::client::WebPkiServerVerifier;
use rustls::client::danger::{HandshakeSignatureValid, ServerCertVerified, ServerCertVerifier};
use rustls::crypto::CryptoProvider;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, ServerName, UnixTime};
use rustls::{CertificateError, ClientConfig, DigitallySignedStruct, RootCertStore};
use rustls::{Error as TlsError, SignatureScheme};
use tokio_postgres::config::SslMode;
use tokio_postgres_rustls::MakeRustlsConnect;

use crate::service::store::StoreError;

/// libpq's `sslmode` values that tokio-postgres accepts or that this module adds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
enum Mode {
    Disable,
    #[default]
    Prefer,
    Require,
    VerifyCa,
    VerifyFull,
}

impl FromStr for Mode {
    type Err = StoreError;

    fn from_str(text: &str) -> Result<Self, StoreError> {
        Ok(match text {
            "disable" => Mode::Disable,
            "prefer" => Mode::Prefer,
            "require" => Mode::Require,
            "verify-ca" => Mode::VerifyCa,
            "verify-full" => Mode::VerifyFull,
            other => {
                return Err(StoreError::DatabaseUrl(format!(
                    "sslmode {other:?}: expected disable, prefer, require, verify-ca or verify-full"
                )));
            }
        })
    }
}

/// The TLS part of a connection string.
#[derive(Debug, Default, PartialEq, Eq)]
pub struct TlsSettings {
    mode: Mode,
    /// `sslrootcert`: a PEM file of trusted roots, or `system`.
    root_certificate: Option<String>,
}

impl TlsSettings {
    /// Splits `url` (a `postgres://` URL or libpq's `key=value` form) into its TLS settings
    /// and the rest, which tokio-postgres parses.
    pub fn take_from(url: &str) -> Result<(Self, String), StoreError> {
        let mut settings = Self::default();
        let mut rest = String::with_capacity(url.len());
        if let Some((base, query)) = url.split_once('?') {
            let mut kept = Vec::new();
            for pair in query.split('&') {
                let (key, value) = pair.split_once('=').unwrap_or((pair, ""));
                let value = percent_encoding::percent_decode_str(value).decode_utf8_lossy();
                if !settings.take(key, &value)? {
                    kept.push(pair);
                }
            }
            rest.push_str(base);
            if !kept.is_empty() {
                rest.push('?');
                rest.push_str(&kept.join("&"));
            }
        } else if url.contains("://") {
            rest.push_str(url);
        } else {
            // key=value words; the text between taken words (quoted values too) stays as it is.
            let mut kept_from = 0;
            for word in url.split_ascii_whitespace() {
                if let Some((key, value)) = word.split_once('=')
                    && settings.take(key, value)?
                {
                    let at = word.as_ptr().addr() - url.as_ptr().addr();
                    rest.push_str(&url[kept_from..at]);
                    kept_from = at + word.len();
                }
            }
            rest.push_str(&url[kept_from..]);
        }
        Ok((settings, rest))
    }

    /// Takes `key` if it is a TLS setting; whether it was one.
    fn take(&mut self, key: &str, value: &str) -> Result<bool, StoreError> {
        match key {
            "sslmode" => self.mode = value.parse()?,
            "sslrootcert" => self.root_certificate = Some(value.to_owned()),
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// What tokio-postgres is to ask of the server.
    pub fn ssl_mode(&self) -> SslMode {
        match self.mode {
            Mode::Disable => SslMode::Disable,
            Mode::Prefer => SslMode::Prefer,
            Mode::Require | Mode::VerifyCa | Mode::VerifyFull => SslMode::Require,
        }
    }

    /// The connector doing the handshake and the certificate check of the table above.
    pub fn connector(&self) -> Result<MakeRustlsConnect, StoreError> {
        let provider = Arc::new(rustls::crypto::ring::default_provider());
        let builder = ClientConfig::builder_with_provider(Arc::clone(&provider))
            .with_safe_default_protocol_versions()
            .map_err(tls_setup)?;
        let checks_chain = matches!(self.mode, Mode::VerifyCa | Mode::VerifyFull)
            || self.root_certificate.is_some();
        let chain = if checks_chain {
            let verifier = WebPkiServerVerifier::builder_with_provider(
                Arc::new(self.roots()?),
                Arc::clone(&provider),
            )
            .build()
            .map_err(tls_setup)?;
            Some(verifier)
        } else {
            None
        };
        let config = match chain {
            Some(verifier) if self.mode == Mode::VerifyFull => {
                builder.with_webpki_verifier(verifier)
            }
            chain => builder
                .dangerous()
                .with_custom_certificate_verifier(Arc::new(Lenient { chain, provider })),
        };
        Ok(MakeRustlsConnect::new(config.with_no_client_auth()))
    }

    fn roots(&self) -> Result<RootCertStore, StoreError> {
        let mut roots = RootCertStore::empty();
        match self.root_certificate.as_deref() {
            None | Some("system") => roots.extend(webpki_roots::TLS_SERVER_ROOTS.iter().cloned()),
            Some(path) => {
                let unreadable = |error: &dyn std::fmt::Display| {
                    StoreError::DatabaseUrl(format!("sslrootcert {path}: {error}"))
                };
                for certificate in
                    CertificateDer::pem_file_iter(path).map_err(|e| unreadable(&e))?
                {
                    roots
                        .add(certificate.map_err(|e| unreadable(&e))?)
                        .map_err(|e| unreadable(&e))?;
                }
                if roots.is_empty() {
                    return Err(unreadable(&"no certificate in the file"));
                }
            }
        }
        Ok(roots)
    }
}

fn tls_setup(error: impl std::fmt::Display) -> StoreError {
    StoreError::DatabaseUrl(format!("TLS: {error}"))
}

/// The check of `verify-ca` (`chain`: the name is not checked, as libpq), and of `prefer` and
/// `require` without a root certificate (no `chain`: any certificate is taken, encryption
/// without authentication, as libpq). The handshake's signatures are checked either way.
#[derive(Debug)]
struct Lenient {
    chain: Option<Arc<WebPkiServerVerifier>>,
    provider: Arc<CryptoProvider>,
}

impl ServerCertVerifier for Lenient {
    fn verify_server_cert(
        &self,
        end_entity: &CertificateDer<'_>,
        intermediates: &[CertificateDer<'_>],
        server_name: &ServerName<'_>,
        ocsp_response: &[u8],
        now: UnixTime,
    ) -> Result<ServerCertVerified, TlsError> {
        let Some(chain) = &self.chain else {
            return Ok(ServerCertVerified::assertion());
        };
        match chain.verify_server_cert(end_entity, intermediates, server_name, ocsp_response, now) {
            Err(TlsError::InvalidCertificate(
                CertificateError::NotValidForName | CertificateError::NotValidForNameContext { .. },
            )) => Ok(ServerCertVerified::assertion()),
            other => other,
        }
    }

    fn verify_tls12_signature(
        &self,
        message: &[u8],
        certificate: &CertificateDer<'_>,
        signature: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, TlsError> {
        rustls::crypto::verify_tls12_signature(
            message,
            certificate,
            signature,
            &self.provider.signature_verification_algorithms,
        )
    }

    fn verify_tls13_signature(
        &self,
        message: &[u8],
        certificate: &CertificateDer<'_>,
        signature: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, TlsError> {
        rustls::crypto::verify_tls13_signature(
            message,
            certificate,
            signature,
            &self.provider.signature_verification_algorithms,
        )
    }

    fn supported_verify_schemes(&self) -> Vec<SignatureScheme> {
        self.provider
            .signature_verification_algorithms
            .supported_schemes()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn split(url: &str) -> (TlsSettings, String) {
        TlsSettings::take_from(url).unwrap()
    }

    #[test]
    fn url_form_loses_only_the_tls_keys() {
        let (settings, rest) = split(
            "postgres://u@db:5432/jobs?sslmode=verify-full&application_name=covec&sslrootcert=%2Fca%20dir%2Froot.pem",
        );
        assert_eq!(settings.mode, Mode::VerifyFull);
        assert_eq!(
            settings.root_certificate.as_deref(),
            Some("/ca dir/root.pem")
        );
        assert_eq!(rest, "postgres://u@db:5432/jobs?application_name=covec");
        assert_eq!(
            split("postgres://u@db/jobs?sslmode=require").1,
            "postgres://u@db/jobs"
        );
        assert_eq!(split("postgres://u@db/jobs").0, TlsSettings::default());
    }

    #[test]
    fn key_value_form_keeps_quoted_values_of_other_keys() {
        let (settings, rest) =
            split("host=db  password='a b' sslmode=verify-ca user=u sslrootcert=/r.pem");
        assert_eq!(settings.mode, Mode::VerifyCa);
        assert_eq!(settings.root_certificate.as_deref(), Some("/r.pem"));
        assert_eq!(rest, "host=db  password='a b'  user=u ");
        tokio_postgres::Config::from_str(&rest).unwrap();
    }

    #[test]
    fn an_unknown_mode_or_a_missing_root_file_is_a_configuration_error() {
        let error = TlsSettings::take_from("postgres://db/x?sslmode=verify").unwrap_err();
        assert!(error.to_string().contains("verify-full"), "{error}");
        let (settings, _) = split("postgres://db/x?sslmode=verify-ca&sslrootcert=/nonexistent.pem");
        let error = settings.connector().err().unwrap();
        assert!(error.to_string().contains("/nonexistent.pem"), "{error}");
    }
}
