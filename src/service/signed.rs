//! Signed result URLs: a short-lived token that opens one job's files without the
//! `Authorization` header, so that `<img src>`, `<a download>` and other requests a browser
//! makes on its own work on a server with API keys.
//!
//! A token is `<expiry>.<signature>`: the Unix second it stops working and the HMAC-SHA256 of
//! the job id and that second under the server's URL secret (`--signed-url-secret`), base64url.
//! It goes in a file URL's query (`?token=…`) and opens the files of that job only (results,
//! layers, previews, an edit's files); never the job resource, its events, or another job's
//! files (403 `token-invalid`), and nothing after it expires (403 `token-expired`). Tokens are
//! handed out in the job resource's `signed` member to the key that owns the job.

use std::time::Duration;

use base64::Engine;
use base64::engine::general_purpose::URL_SAFE_NO_PAD;
use hmac::{Hmac, KeyInit, Mac};
use sha2::Sha256;

use super::error::ApiError;

/// The query parameter a token travels in.
pub const TOKEN_PARAM: &str = "token";

/// Bytes of a secret made at start when none is given.
const GENERATED_SECRET_BYTES: usize = 32;

/// What the HMAC covers besides the job id and expiry: tokens are for this use only.
const PURPOSE: &[u8] = b"covec signed file URL v1";

/// Signs and checks tokens.
pub struct UrlSigner {
    secret: Vec<u8>,
    lifetime: Duration,
}

/// Why a token was refused.
#[derive(Debug, PartialEq, Eq)]
pub enum TokenRefusal {
    /// Not a token, or not one this server signed for this job.
    Invalid,
    /// Signed for this job, but its time is up.
    Expired,
}

impl UrlSigner {
    /// A signer with `secret`, or with a random one (tokens then die with the process and
    /// work only on it), whose tokens last `lifetime` (at least; see [`UrlSigner::token`]).
    pub fn new(secret: Option<&str>, lifetime: Duration) -> std::io::Result<Self> {
        let secret = match secret {
            Some(secret) => secret.as_bytes().to_vec(),
            None => random_secret()?,
        };
        Ok(Self {
            secret,
            lifetime: lifetime.max(Duration::from_secs(1)),
        })
    }

    /// A token for `job`'s files and the Unix second it expires. The expiry is rounded up to a
    /// quarter of the lifetime, so that polls a little apart get the same URLs (and a browser
    /// its cached images): a token lasts between one and one and a quarter lifetimes.
    pub fn token(&self, job: &str, now_ms: u64) -> (String, u64) {
        let step = (self.lifetime.as_secs() / 4).max(1);
        let expires = (now_ms / 1000 + self.lifetime.as_secs()).div_ceil(step) * step;
        let signature = URL_SAFE_NO_PAD.encode(self.mac(job, expires).finalize().into_bytes());
        (format!("{expires}.{signature}"), expires)
    }

    /// Whether `token` opens `job`'s files at `now_ms`.
    pub fn check(&self, job: &str, token: &str, now_ms: u64) -> Result<(), TokenRefusal> {
        let (expires, signature) = token.split_once('.').ok_or(TokenRefusal::Invalid)?;
        let expires: u64 = expires.parse().map_err(|_| TokenRefusal::Invalid)?;
        let signature = URL_SAFE_NO_PAD
            .decode(signature)
            .map_err(|_| TokenRefusal::Invalid)?;
        // Constant-time comparison of the signature.
        self.mac(job, expires)
            .verify_slice(&signature)
            .map_err(|_| TokenRefusal::Invalid)?;
        if now_ms / 1000 >= expires {
            return Err(TokenRefusal::Expired);
        }
        Ok(())
    }

    fn mac(&self, job: &str, expires: u64) -> Hmac<Sha256> {
        let mut mac = Hmac::<Sha256>::new_from_slice(&self.secret).expect("HMAC takes any key");
        for part in [PURPOSE, job.as_bytes(), expires.to_string().as_bytes()] {
            mac.update(&(part.len() as u64).to_le_bytes());
            mac.update(part);
        }
        mac
    }
}

/// `url` with `token` added to its query.
pub fn with_token(url: &str, token: &str) -> String {
    let separator = if url.contains('?') { '&' } else { '?' };
    format!("{url}{separator}{TOKEN_PARAM}={token}")
}

/// The token in a request's query, if any.
pub fn query_token(query: Option<&str>) -> Option<&str> {
    query?
        .split('&')
        .find_map(|pair| pair.strip_prefix(TOKEN_PARAM)?.strip_prefix('='))
}

/// The job whose file `path` names, for the routes a token opens: `/v1/jobs/{id}/` followed by
/// `svg`, `pdf`, `png`, `scene.json`, `draft.svg`, `layers/…`, `previews/…` (a file, not the
/// list) or an edit's `svg`, `pdf`, `png`, `scene.json` or `preview.png`. `None` for every other
/// path.
pub fn file_route_job(path: &str) -> Option<&str> {
    let rest = path.strip_prefix("/v1/jobs/")?;
    let (job, file) = rest.split_once('/')?;
    let parts: Vec<&str> = file.split('/').collect();
    let opened = match parts.as_slice() {
        ["svg" | "pdf" | "png" | "scene.json" | "draft.svg"] => true,
        ["layers" | "previews", name] => !name.is_empty(),
        [
            "edits",
            edit,
            "svg" | "pdf" | "png" | "scene.json" | "preview.png",
        ] => !edit.is_empty(),
        _ => false,
    };
    opened.then_some(job)
}

impl From<TokenRefusal> for ApiError {
    fn from(refusal: TokenRefusal) -> Self {
        match refusal {
            TokenRefusal::Invalid => ApiError::TokenInvalid,
            TokenRefusal::Expired => ApiError::TokenExpired,
        }
    }
}

fn random_secret() -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let mut secret = vec![0; GENERATED_SECRET_BYTES];
    std::fs::File::open("/dev/urandom")?.read_exact(&mut secret)?;
    Ok(secret)
}

#[cfg(test)]
mod tests {
    use super::*;

    const JOB: &str = "job_0193aaaaaaaaaaaaaaaaaaaaaaaaaaaa";
    const OTHER: &str = "job_0193bbbbbbbbbbbbbbbbbbbbbbbbbbbb";

    #[test]
    fn a_token_opens_its_job_until_it_expires() {
        let signer = UrlSigner::new(Some("secret"), Duration::from_secs(600)).unwrap();
        let now = 1_800_000_000_000;
        let (token, expires) = signer.token(JOB, now);
        assert!((600..=750).contains(&(expires - now / 1000)), "{expires}");
        assert_eq!(signer.check(JOB, &token, now), Ok(()));
        assert_eq!(
            signer.check(JOB, &token, expires * 1000 - 1),
            Ok(()),
            "still valid in its last millisecond"
        );
        assert_eq!(
            signer.check(JOB, &token, expires * 1000),
            Err(TokenRefusal::Expired)
        );
        assert_eq!(signer.check(OTHER, &token, now), Err(TokenRefusal::Invalid));
        // A later expiry written into the token breaks its signature.
        let (_, signature) = token.split_once('.').unwrap();
        let forged = format!("{}.{signature}", expires + 3600);
        assert_eq!(signer.check(JOB, &forged, now), Err(TokenRefusal::Invalid));
        let other_server = UrlSigner::new(Some("other"), Duration::from_secs(600)).unwrap();
        assert_eq!(
            other_server.check(JOB, &token, now),
            Err(TokenRefusal::Invalid)
        );
        for garbage in ["", ".", "x.y", "12", "12.!!"] {
            assert_eq!(signer.check(JOB, garbage, now), Err(TokenRefusal::Invalid));
        }
    }

    #[test]
    fn polls_close_together_get_the_same_token() {
        let signer = UrlSigner::new(None, Duration::from_secs(600)).unwrap();
        // Expiries step every 150 s: polls a second apart, not across a step.
        let now = 1_800_000_010_000;
        assert_eq!(signer.token(JOB, now), signer.token(JOB, now + 1000));
        assert_ne!(signer.token(JOB, now), signer.token(JOB, now + 150_000));
    }

    #[test]
    fn tokens_open_file_routes_only() {
        for path in [
            "/v1/jobs/J/svg",
            "/v1/jobs/J/pdf",
            "/v1/jobs/J/png",
            "/v1/jobs/J/scene.json",
            "/v1/jobs/J/layers/albedo.svg",
            "/v1/jobs/J/previews/00-input.png",
            "/v1/jobs/J/edits/E/svg",
            "/v1/jobs/J/edits/E/png",
            "/v1/jobs/J/edits/E/preview.png",
        ] {
            assert_eq!(file_route_job(path), Some("J"), "{path}");
        }
        for path in [
            "/v1/jobs/J",
            "/v1/jobs/J/",
            "/v1/jobs/J/events",
            "/v1/jobs/J/previews",
            "/v1/jobs/J/cancel",
            "/v1/jobs/J/edits",
            "/v1/jobs/J/edits/E",
            "/v1/jobs",
            "/metrics",
        ] {
            assert_eq!(file_route_job(path), None, "{path}");
        }
        assert_eq!(query_token(Some("width=9&token=1.abc")), Some("1.abc"));
        assert_eq!(query_token(Some("tokens=1")), None);
        assert_eq!(
            with_token("/a/svg?flatten=true", "T"),
            "/a/svg?flatten=true&token=T"
        );
    }
}
