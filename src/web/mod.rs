//! The web page for people: upload images (or try the sample), watch the layers form, toggle
//! and recolour them, download the results; the job ids live in the page's address.
//!
//! Plain HTML, CSS and JavaScript with no build step, embedded in the binary so `covec serve`
//! needs no other files and works offline. The page talks only to the `/v1` API of the same
//! origin, and reads every limit and default from `GET /v1/limits`. Mount it with `Router::merge(web::routes())` at the root of the service's router.
//!
//! Caching: the page itself is revalidated on every load (`no-cache` + `ETag`), and it asks for
//! its script and style sheet under a `?v=<content hash>` query, which may then be cached for a
//! year; an asset requested without the current hash is revalidated like the page.

use std::sync::LazyLock;

use axum::Router;
use axum::body::Bytes;
use axum::extract::RawQuery;
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;

const INDEX_HTML: &str = include_str!("index.html");
const APP_JS: &str = include_str!("app.js");
const APP_CSS: &str = include_str!("app.css");
const FAVICON_SVG: &str = include_str!("favicon.svg");
/// The photo to try without a file of one's own (licence: docs/README.md).
const SAMPLE_JPG: &[u8] = include_bytes!("sample.jpg");
/// The first screen's picture of the layers: the left part of docs/layers.jpg at half size.
const LAYERS_JPG: &[u8] = include_bytes!("layers.jpg");

/// Where `index.html` says the asset version goes (`app.js?v=ASSET_VERSION`).
const VERSION_PLACEHOLDER: &str = "ASSET_VERSION";

/// What the page may load: its own assets, the API, and `blob:` images (the picked file shown
/// before upload). Inline `style` attributes are allowed because the inlined SVG carries its
/// blend modes in them.
const CONTENT_SECURITY_POLICY: &str = "default-src 'none'; script-src 'self'; \
     style-src 'self' 'unsafe-inline'; img-src 'self' blob:; connect-src 'self'; \
     form-action 'none'; frame-ancestors 'none'; base-uri 'none'";

const REVALIDATE: &str = "no-cache";
const IMMUTABLE: &str = "public, max-age=31536000, immutable";

/// One embedded file with its content type and strong `ETag`.
struct Asset {
    body: Bytes,
    content_type: &'static str,
    etag: String,
}

impl Asset {
    fn new(body: impl Into<Bytes>, content_type: &'static str) -> Self {
        let body = body.into();
        let etag = format!("\"{:016x}\"", fnv1a(&body));
        Self {
            body,
            content_type,
            etag,
        }
    }
}

/// Hash of the script and style sheet together: it changes whenever either does.
static ASSET_VERSION: LazyLock<String> =
    LazyLock::new(|| format!("{:016x}", fnv1a(format!("{APP_JS}\0{APP_CSS}").as_bytes())));

static INDEX: LazyLock<Asset> = LazyLock::new(|| {
    Asset::new(
        INDEX_HTML.replace(VERSION_PLACEHOLDER, &ASSET_VERSION),
        "text/html; charset=utf-8",
    )
});
static SCRIPT: LazyLock<Asset> =
    LazyLock::new(|| Asset::new(APP_JS, "text/javascript; charset=utf-8"));
static ICON: LazyLock<Asset> = LazyLock::new(|| Asset::new(FAVICON_SVG, "image/svg+xml"));
static STYLE: LazyLock<Asset> = LazyLock::new(|| Asset::new(APP_CSS, "text/css; charset=utf-8"));
static SAMPLE: LazyLock<Asset> = LazyLock::new(|| Asset::new(SAMPLE_JPG, "image/jpeg"));
static LAYERS_PICTURE: LazyLock<Asset> = LazyLock::new(|| Asset::new(LAYERS_JPG, "image/jpeg"));

/// The page's routes: `/`, `/app.js`, `/app.css`, `/favicon.svg`, `/sample.jpg` and
/// `/layers.jpg`. Generic over the service's state, which they do not use.
pub fn routes<S>() -> Router<S>
where
    S: Clone + Send + Sync + 'static,
{
    Router::new()
        .route(
            "/",
            get(|headers: HeaderMap| async move { serve(&INDEX, REVALIDATE, &headers) }),
        )
        .route(
            "/app.js",
            get(|query, headers| async move { serve_versioned(&SCRIPT, query, &headers) }),
        )
        .route(
            "/app.css",
            get(|query, headers| async move { serve_versioned(&STYLE, query, &headers) }),
        )
        .route(
            "/favicon.svg",
            get(|headers: HeaderMap| async move { serve(&ICON, REVALIDATE, &headers) }),
        )
        .route(
            "/sample.jpg",
            get(|headers: HeaderMap| async move { serve(&SAMPLE, REVALIDATE, &headers) }),
        )
        .route(
            "/layers.jpg",
            get(|headers: HeaderMap| async move { serve(&LAYERS_PICTURE, REVALIDATE, &headers) }),
        )
}

fn serve_versioned(asset: &Asset, RawQuery(query): RawQuery, headers: &HeaderMap) -> Response {
    let current =
        query.as_deref().and_then(|q| q.strip_prefix("v=")) == Some(ASSET_VERSION.as_str());
    serve(asset, if current { IMMUTABLE } else { REVALIDATE }, headers)
}

fn serve(asset: &Asset, cache_control: &'static str, request: &HeaderMap) -> Response {
    let not_modified = request
        .get_all(header::IF_NONE_MATCH)
        .iter()
        .filter_map(|value| value.to_str().ok())
        .flat_map(|value| value.split(','))
        .any(|tag| {
            let tag = tag.trim();
            tag == "*" || tag.trim_start_matches("W/") == asset.etag
        });
    let mut response = if not_modified {
        StatusCode::NOT_MODIFIED.into_response()
    } else {
        (
            [(header::CONTENT_TYPE, asset.content_type)],
            asset.body.clone(),
        )
            .into_response()
    };
    let headers = response.headers_mut();
    headers.insert(
        header::CACHE_CONTROL,
        HeaderValue::from_static(cache_control),
    );
    if let Ok(etag) = HeaderValue::from_str(&asset.etag) {
        headers.insert(header::ETAG, etag);
    }
    headers.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    headers.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(CONTENT_SECURITY_POLICY),
    );
    headers.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    response
}

/// 64-bit FNV-1a: a stable content hash for `ETag`s and the asset version (not for security).
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |hash, &byte| {
        (hash ^ u64::from(byte)).wrapping_mul(0x0100_0000_01b3)
    })
}

#[cfg(test)]
mod tests {
    use axum::body::{Body, to_bytes};
    use axum::http::Request;
    use tower::ServiceExt;

    use super::*;

    async fn get(uri: &str, if_none_match: Option<&str>) -> Response {
        let mut request = Request::get(uri);
        if let Some(tag) = if_none_match {
            request = request.header(header::IF_NONE_MATCH, tag);
        }
        routes::<()>()
            .oneshot(request.body(Body::empty()).unwrap())
            .await
            .unwrap()
    }

    fn header_of(response: &Response, name: header::HeaderName) -> &str {
        response.headers().get(name).unwrap().to_str().unwrap()
    }

    #[tokio::test]
    async fn page_links_its_assets_by_current_version() {
        let response = get("/", None).await;
        assert_eq!(response.status(), StatusCode::OK);
        assert_eq!(
            header_of(&response, header::CONTENT_TYPE),
            "text/html; charset=utf-8"
        );
        assert_eq!(header_of(&response, header::CACHE_CONTROL), "no-cache");
        let body = to_bytes(response.into_body(), usize::MAX).await.unwrap();
        let html = std::str::from_utf8(&body).unwrap();
        assert!(!html.contains(VERSION_PLACEHOLDER));
        assert!(html.contains(&format!("/app.js?v={}", *ASSET_VERSION)));
        assert!(html.contains(&format!("/app.css?v={}", *ASSET_VERSION)));
    }

    #[tokio::test]
    async fn assets_have_their_types_and_are_immutable_only_when_versioned() {
        for (path, content_type, body) in [
            ("/app.js", "text/javascript; charset=utf-8", APP_JS),
            ("/app.css", "text/css; charset=utf-8", APP_CSS),
        ] {
            let versioned = get(&format!("{path}?v={}", *ASSET_VERSION), None).await;
            assert_eq!(versioned.status(), StatusCode::OK);
            assert_eq!(header_of(&versioned, header::CONTENT_TYPE), content_type);
            assert_eq!(header_of(&versioned, header::CACHE_CONTROL), IMMUTABLE);
            assert_eq!(
                header_of(&versioned, header::X_CONTENT_TYPE_OPTIONS),
                "nosniff"
            );
            let bytes = to_bytes(versioned.into_body(), usize::MAX).await.unwrap();
            assert_eq!(bytes, body.as_bytes());

            for stale in [path.to_owned(), format!("{path}?v=0000")] {
                let response = get(&stale, None).await;
                assert_eq!(
                    header_of(&response, header::CACHE_CONTROL),
                    REVALIDATE,
                    "{stale}"
                );
            }
        }
    }

    #[tokio::test]
    async fn matching_etag_gives_not_modified() {
        let first = get("/app.css", None).await;
        let etag = header_of(&first, header::ETAG).to_owned();
        let again = get("/app.css", Some(&format!("\"other\", {etag}"))).await;
        assert_eq!(again.status(), StatusCode::NOT_MODIFIED);
        assert!(
            to_bytes(again.into_body(), usize::MAX)
                .await
                .unwrap()
                .is_empty()
        );
        let changed = get("/app.css", Some("\"other\"")).await;
        assert_eq!(changed.status(), StatusCode::OK);
    }

    #[tokio::test]
    async fn favicon_is_an_svg() {
        let response = get("/favicon.svg", None).await;
        assert_eq!(response.status(), StatusCode::OK);
        assert_eq!(header_of(&response, header::CONTENT_TYPE), "image/svg+xml");
    }

    #[tokio::test]
    async fn the_sample_and_the_layers_picture_are_jpegs() {
        for (path, bytes) in [("/sample.jpg", SAMPLE_JPG), ("/layers.jpg", LAYERS_JPG)] {
            let response = get(path, None).await;
            assert_eq!(response.status(), StatusCode::OK, "{path}");
            assert_eq!(header_of(&response, header::CONTENT_TYPE), "image/jpeg");
            let body = to_bytes(response.into_body(), usize::MAX).await.unwrap();
            assert_eq!(body, bytes, "{path}");
            assert!(body.starts_with(&[0xff, 0xd8]), "{path} is not a JPEG");
        }
    }

    #[tokio::test]
    async fn unknown_paths_are_not_served() {
        assert_eq!(
            get("/index.html.bak", None).await.status(),
            StatusCode::NOT_FOUND
        );
    }
}
