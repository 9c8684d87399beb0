//! How a result goes out: a strong `ETag` with `304 Not Modified` for `If-None-Match`,
//! `Cache-Control` until the result is removed (results never change while they exist), and a
//! `Content-Disposition` naming the download after the uploaded image (`hopper.svg`,
//! `hopper-flat.svg`, `hopper.pdf`), so `curl -OJ` and browsers save it under a useful name.

use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use sha2::{Digest, Sha256};

use super::model::{JobRecord, hex, now_ms};

/// A result about to be served.
pub struct Download {
    /// The strong validator, quoted (see [`etag_of`]).
    pub etag: String,
    /// The file name offered for saving, e.g. `hopper-flat.svg`.
    pub filename: String,
    pub media_type: &'static str,
    /// Unix milliseconds at which the result will be removed, when known: caches may keep it
    /// until then without asking again.
    pub expires_at: Option<u64>,
}

/// A strong entity tag for `parts` (the bytes served, or what determines them): the first 128
/// bits of their SHA-256, quoted.
pub fn etag_of(parts: &[&[u8]]) -> String {
    let mut hasher = Sha256::new();
    for part in parts {
        hasher.update((part.len() as u64).to_le_bytes());
        hasher.update(part);
    }
    format!("\"{}\"", hex(&hasher.finalize()[..16]))
}

/// The download name of one of a job's files: the uploaded image's stem (or the job id) with
/// `suffix`, e.g. `-flat.svg`.
pub fn filename(record: &JobRecord, suffix: &str) -> String {
    format!("{}{suffix}", record.download_stem())
}

impl Download {
    /// The names and lifetime of `record`'s file `filename` of `media_type`, validated by `etag`.
    pub fn of(
        record: &JobRecord,
        etag: String,
        filename: String,
        media_type: &'static str,
    ) -> Self {
        Self {
            etag,
            filename,
            media_type,
            expires_at: record.expires_at,
        }
    }

    /// True when the request's `If-None-Match` already names this result (RFC 9110, 13.1.2:
    /// weak comparison, `*` matches any).
    pub fn is_cached_by(&self, request: &HeaderMap) -> bool {
        request
            .get_all(header::IF_NONE_MATCH)
            .iter()
            .filter_map(|value| value.to_str().ok())
            .flat_map(|value| value.split(','))
            .map(|tag| tag.trim())
            .any(|tag| tag == "*" || tag.trim_start_matches("W/") == self.etag)
    }

    /// `304 Not Modified` when the request's `If-None-Match` names this result (`bytes` is not
    /// called then), else 200 with the bytes. Both carry the validator and caching headers.
    pub fn respond(self, request: &HeaderMap, bytes: impl FnOnce() -> Vec<u8>) -> Response {
        let cached = self.is_cached_by(request);
        let headers = self.headers();
        if cached {
            (StatusCode::NOT_MODIFIED, headers).into_response()
        } else {
            (headers, bytes()).into_response()
        }
    }

    fn headers(&self) -> [(header::HeaderName, HeaderValue); 4] {
        let cache_control = match self.expires_at {
            // A job's results are private to its key; they never change, and go at expiry.
            Some(at) => format!(
                "private, max-age={}, immutable",
                at.saturating_sub(now_ms()) / 1000
            ),
            // Not yet ended (previews of a running job): ask again, cheaply, with the ETag.
            None => "private, no-cache".to_owned(),
        };
        [
            (
                header::CONTENT_TYPE,
                HeaderValue::from_static(self.media_type),
            ),
            (
                header::ETAG,
                HeaderValue::from_str(&self.etag).expect("hex digits are a header value"),
            ),
            (
                header::CACHE_CONTROL,
                HeaderValue::from_str(&cache_control).expect("ASCII"),
            ),
            (
                header::CONTENT_DISPOSITION,
                content_disposition(&self.filename),
            ),
        ]
    }
}

/// `inline; filename="…"` with an ASCII fallback, plus RFC 8187's `filename*` when the name has
/// other characters (RFC 6266, section 4.3).
fn content_disposition(name: &str) -> HeaderValue {
    let fallback: String = name
        .chars()
        .map(|c| match c {
            ' '..='~' if c != '"' && c != '\\' => c,
            _ => '_',
        })
        .collect();
    let mut value = format!("inline; filename=\"{fallback}\"");
    if fallback != name {
        value.push_str("; filename*=UTF-8''");
        value.push_str(&percent_encoding::utf8_percent_encode(name, RFC8187_ESCAPED).to_string());
    }
    HeaderValue::from_str(&value).expect("only visible ASCII")
}

/// Characters outside RFC 8187's `attr-char`.
const RFC8187_ESCAPED: &percent_encoding::AsciiSet = &percent_encoding::NON_ALPHANUMERIC
    .remove(b'!')
    .remove(b'#')
    .remove(b'$')
    .remove(b'&')
    .remove(b'+')
    .remove(b'-')
    .remove(b'.')
    .remove(b'^')
    .remove(b'_')
    .remove(b'`')
    .remove(b'|')
    .remove(b'~');

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_safe_header_values() {
        assert_eq!(
            content_disposition("hopper.svg"),
            "inline; filename=\"hopper.svg\""
        );
        assert_eq!(
            content_disposition("été \"x\".svg"),
            "inline; filename=\"_t_ _x_.svg\"; filename*=UTF-8''%C3%A9t%C3%A9%20%22x%22.svg"
        );
    }

    #[test]
    fn if_none_match_compares_weakly_and_takes_lists() {
        let download = Download {
            etag: etag_of(&[b"svg"]),
            filename: "a.svg".into(),
            media_type: "image/svg+xml",
            expires_at: None,
        };
        let mut request = HeaderMap::new();
        assert!(!download.is_cached_by(&request));
        let listed = format!("\"other\", W/{}", download.etag);
        request.insert(
            header::IF_NONE_MATCH,
            HeaderValue::from_str(&listed).unwrap(),
        );
        assert!(download.is_cached_by(&request));
        request.insert(header::IF_NONE_MATCH, HeaderValue::from_static("\"other\""));
        assert!(!download.is_cached_by(&request));
        request.insert(header::IF_NONE_MATCH, HeaderValue::from_static("*"));
        assert!(download.is_cached_by(&request));
    }
}
