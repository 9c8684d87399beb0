//! How results go out (docs/api.md, "Fetch the results"): every format listed on the job, each
//! named after the uploaded file, validated by a strong ETag with 304 for `If-None-Match`, and
//! cacheable until the results are removed; and the per-key rate in the IETF RateLimit fields.
#![cfg(all(feature = "cli", feature = "service"))]

use crate::service_support;

use std::time::Duration;

use base64::Engine;
use hyper::{Method, StatusCode};
use serde_json::json;
use service_support::{DataDir, QUICK_PARAMS, Server, problem, test_png};

#[tokio::test]
async fn results_are_named_after_the_upload_and_revalidate_with_304() {
    let dir = DataDir::new("downloads");
    let server = Server::start(&dir.0, &[]);
    // The test multipart sends the image part as `image.png`.
    let id = server.finished_job().await;
    let job = server.get(&format!("/v1/jobs/{id}")).await.json();
    assert_eq!(job["input_name"], "image.png");
    let results = &job["urls"]["results"];
    for (url, name, media_type) in [
        (&results["svg"], "image.svg", "image/svg+xml"),
        (&results["flat_svg"], "image-flat.svg", "image/svg+xml"),
        (&results["pdf"], "image.pdf", "application/pdf"),
        (&results["png"], "image.png", "image/png"),
        (&results["scene"], "image.json", "application/json"),
        (&results["albedo"], "image-albedo.svg", "image/svg+xml"),
    ] {
        let url = url
            .as_str()
            .unwrap_or_else(|| panic!("no URL for {name}: {job}"));
        let first = server.get(url).await;
        assert_eq!(first.status, StatusCode::OK, "{url}: {}", first.text());
        assert_eq!(first.header("content-type"), Some(media_type), "{url}");
        assert_eq!(
            first.header("content-disposition"),
            Some(format!("inline; filename=\"{name}\"").as_str()),
            "{url}"
        );
        let cache = first.header("cache-control").unwrap();
        assert!(
            cache.starts_with("private, max-age=") && cache.ends_with(", immutable"),
            "{url}: {cache}"
        );
        let max_age: u64 = cache["private, max-age=".len()..cache.len() - ", immutable".len()]
            .parse()
            .unwrap();
        assert!(max_age > 86_000 && max_age <= 86_400, "{url}: {cache}");
        let etag = first.header("etag").unwrap().to_owned();
        assert!(etag.starts_with('"') && etag.len() == 34, "{url}: {etag}");

        let again = server.get_with(url, &[("if-none-match", &etag)]).await;
        assert_eq!(again.status, StatusCode::NOT_MODIFIED, "{url}");
        assert!(again.body.is_empty());
        assert_eq!(again.header("etag"), Some(etag.as_str()));
        let weak = format!("\"other\", W/{etag}");
        let listed = server.get_with(url, &[("if-none-match", &weak)]).await;
        assert_eq!(listed.status, StatusCode::NOT_MODIFIED, "{url}");
        let stale = server
            .get_with(url, &[("if-none-match", "\"stale\"")])
            .await;
        assert_eq!((stale.status, stale.body), (first.status, first.body));
    }
    // Another width is another file, with its own validator.
    let png = server.get(&format!("/v1/jobs/{id}/png")).await;
    let wide = server.get(&format!("/v1/jobs/{id}/png?width=96")).await;
    assert_ne!(png.header("etag"), wide.header("etag"));
    // Previews too, and an edit's files, named after the job's input and the edit.
    let preview = server.get(&format!("/v1/jobs/{id}/previews")).await.json();
    let first = preview["items"][0]["name"].as_str().unwrap();
    let preview = server
        .get(&format!("/v1/jobs/{id}/previews/{first}.png"))
        .await;
    assert_eq!(
        preview.header("content-disposition"),
        Some(format!("inline; filename=\"image-{first}.png\"").as_str())
    );
    let edit = server
        .post_json(
            &format!("/v1/jobs/{id}/edits"),
            &json!({"changes": [{"at": {"x": 24, "y": 24}, "color": "#2060c0"}]}),
        )
        .await;
    assert_eq!(edit.status, StatusCode::CREATED, "{}", edit.text());
    let edit_id = edit.json()["id"].as_str().unwrap().to_owned();
    let edited = server
        .get(&format!("/v1/jobs/{id}/edits/{edit_id}/svg"))
        .await;
    assert_eq!(
        edited.header("content-disposition"),
        Some(format!("inline; filename=\"image-{edit_id}.svg\"").as_str())
    );
    server.stop();
}

#[tokio::test]
async fn a_json_submission_names_its_downloads_by_its_filename() {
    let dir = DataDir::new("downloads-json");
    let server = Server::start(&dir.0, &[]);
    let params: serde_json::Value = serde_json::from_str(QUICK_PARAMS).unwrap();
    let image = base64::engine::general_purpose::STANDARD.encode(test_png(48));
    let created = server
        .post_json(
            "/v1/jobs",
            &json!({"image": image, "filename": "C:\\photos\\été 2026.jpg", "params": params}),
        )
        .await;
    assert_eq!(created.status, StatusCode::CREATED, "{}", created.text());
    let id = created.json()["id"].as_str().unwrap().to_owned();
    let job = server
        .wait_for(&id, Duration::from_secs(60), |job| {
            job["status"] == "succeeded"
        })
        .await;
    // Only the last path component is kept.
    assert_eq!(job["input_name"], "été 2026.jpg");
    let svg = server.get(&format!("/v1/jobs/{id}/svg")).await;
    assert_eq!(
        svg.header("content-disposition"),
        Some("inline; filename=\"_t_ 2026.svg\"; filename*=UTF-8''%C3%A9t%C3%A9%202026.svg")
    );
    server.stop();
}

#[tokio::test]
async fn a_keyed_submission_rate_shows_in_ratelimit_fields() {
    let dir = DataDir::new("ratelimit");
    let server = Server::start(&dir.0, &["--rate-per-key", "2", "--workers", "1"]);
    let image = test_png(32);
    let parts: [(&str, &[u8]); 2] = [("image", &image), ("params", QUICK_PARAMS.as_bytes())];
    let key = [("x-client-key", "batch-client")];
    let first = server.submit(&parts, &key).await;
    assert_eq!(first.status, StatusCode::CREATED, "{}", first.text());
    assert_eq!(
        first.header("ratelimit-policy"),
        Some("\"submissions\";q=2;w=60")
    );
    assert_eq!(first.header("ratelimit"), Some("\"submissions\";r=1;t=30"));
    let second = server.submit(&parts, &key).await;
    assert_eq!(second.header("ratelimit"), Some("\"submissions\";r=0;t=60"));
    let refused = server.submit(&parts, &key).await;
    assert_eq!(refused.status, StatusCode::TOO_MANY_REQUESTS);
    assert_eq!(problem(&refused)["code"], "rate-limited");
    let retry_after: u64 = refused.header("retry-after").unwrap().parse().unwrap();
    assert!((1..=30).contains(&retry_after), "{retry_after}");
    assert_eq!(
        refused.header("ratelimit"),
        Some(format!("\"submissions\";r=0;t={}", retry_after + 30).as_str())
    );
    server.stop();
}

#[tokio::test]
async fn client_keys_are_checked_with_api_keys_too_and_limits_need_no_key() {
    let dir = DataDir::new("client-key-with-keys");
    let server = Server::start(&dir.0, &["--api-keys", "alpha-key"]);
    let image = test_png(32);
    let parts: [(&str, &[u8]); 2] = [("image", &image), ("params", QUICK_PARAMS.as_bytes())];
    let refused = server
        .submit(
            &parts,
            &[
                ("authorization", "Bearer alpha-key"),
                ("x-client-key", "a\tb"),
            ],
        )
        .await;
    assert_eq!(
        refused.status,
        StatusCode::BAD_REQUEST,
        "{}",
        refused.text()
    );
    assert_eq!(problem(&refused)["code"], "bad-request");
    let limits = server
        .request(Method::GET, "/v1/limits", &[], Vec::new())
        .await;
    assert_eq!(limits.status, StatusCode::OK, "{}", limits.text());
    assert_eq!(limits.json()["defaults"]["paths"], 64);
    server.stop();
}

/// Submits a quick job with `headers` (an API key) and waits for it to succeed; its id.
async fn keyed_job(server: &Server, headers: &[(&str, &str)]) -> String {
    let image = test_png(48);
    let parts: [(&str, &[u8]); 2] = [("image", &image), ("params", QUICK_PARAMS.as_bytes())];
    let created = server.submit(&parts, headers).await;
    assert_eq!(created.status, StatusCode::CREATED, "{}", created.text());
    let id = created.json()["id"].as_str().unwrap().to_owned();
    for _ in 0..1200 {
        let job = server
            .get_with(&format!("/v1/jobs/{id}"), headers)
            .await
            .json();
        match job["status"].as_str() {
            Some("succeeded") => return id,
            Some("queued" | "running") => tokio::time::sleep(Duration::from_millis(50)).await,
            _ => panic!("{job}"),
        }
    }
    panic!("job {id} did not finish in a minute");
}

#[tokio::test]
async fn signed_urls_open_one_jobs_files_without_the_key_until_they_expire() {
    let dir = DataDir::persistent("signed-urls");
    let server = Server::start(
        &dir.0,
        &["--api-keys", "alpha-key", "--signed-url-ttl", "2"],
    );
    let key = [("authorization", "Bearer alpha-key")];
    let id = keyed_job(&server, &key).await;
    let other = keyed_job(&server, &key).await;
    let edit = server
        .request(
            Method::POST,
            &format!("/v1/jobs/{id}/edits"),
            &[key[0], ("content-type", "application/json")],
            serde_json::to_vec(
                &json!({"changes": [{"at": {"x": 24, "y": 24}, "color": "#2060c0"}]}),
            )
            .unwrap(),
        )
        .await;
    assert_eq!(edit.status, StatusCode::CREATED, "{}", edit.text());
    let edit = edit.json()["id"].as_str().unwrap().to_owned();

    let job = server
        .get_with(&format!("/v1/jobs/{id}"), &key)
        .await
        .json();
    let signed = &job["signed"];
    let token = signed["token"].as_str().unwrap_or_else(|| panic!("{job}"));
    let svg = signed["results"]["svg"].as_str().unwrap();
    assert_eq!(svg, format!("/v1/jobs/{id}/svg?token={token}"));
    // The file, with no header, is the file the key gets.
    let keyed = server.get_with(&format!("/v1/jobs/{id}/svg"), &key).await;
    let opened = server.get(svg).await;
    assert_eq!(opened.status, StatusCode::OK, "{}", opened.text());
    assert_eq!(opened.body, keyed.body);
    for file in [
        format!("/v1/jobs/{id}/png?width=32&token={token}"),
        format!("/v1/jobs/{id}/layers/albedo.svg?token={token}"),
        format!("/v1/jobs/{id}/edits/{edit}/pdf?token={token}"),
        format!("/v1/jobs/{id}/edits/{edit}/svg?flatten=true&token={token}"),
        signed["results"]["flat_svg"].as_str().unwrap().to_owned(),
    ] {
        assert_eq!(server.get(&file).await.status, StatusCode::OK, "{file}");
    }
    // Another job's files: 403; the job resource, its events, listings: the key is needed.
    let elsewhere = server
        .get(&format!("/v1/jobs/{other}/svg?token={token}"))
        .await;
    assert_eq!(elsewhere.status, StatusCode::FORBIDDEN);
    assert_eq!(problem(&elsewhere)["code"], "token-invalid");
    for path in [
        format!("/v1/jobs/{id}?token={token}"),
        format!("/v1/jobs/{id}/events?token={token}"),
        format!("/v1/jobs/{id}/edits/{edit}?token={token}"),
        format!("/v1/jobs?token={token}"),
    ] {
        let refused = server.get(&path).await;
        assert_eq!(refused.status, StatusCode::UNAUTHORIZED, "{path}");
    }
    let forged = server
        .get(&format!(
            "/v1/jobs/{id}/svg?token=9999999999.{}",
            &token[11..]
        ))
        .await;
    assert_eq!(problem(&forged)["code"], "token-invalid");
    // Once expired: 403 `token-expired`.
    let expires: u64 = token.split('.').next().unwrap().parse().unwrap();
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64();
    tokio::time::sleep(Duration::from_secs_f64(expires as f64 - now + 0.2)).await;
    let expired = server.get(svg).await;
    assert_eq!(expired.status, StatusCode::FORBIDDEN);
    assert_eq!(problem(&expired)["code"], "token-expired");
    // Without keys there is nothing to sign.
    let open = DataDir::new("signed-urls-open");
    let open_server = Server::start(&open.0, &[]);
    let id = open_server.finished_job().await;
    let job = open_server.get(&format!("/v1/jobs/{id}")).await.json();
    assert!(job.get("signed").is_none(), "{job}");
    open_server.stop();
    server.stop();
}

#[tokio::test]
async fn derived_files_are_drawn_once_then_served_from_storage() {
    let dir = DataDir::new("derived");
    let server = Server::start(&dir.0, &[]);
    let id = server.finished_job().await;
    let version = env!("CARGO_PKG_VERSION");
    for (url, stored) in [
        (format!("/v1/jobs/{id}/png?width=64"), "png-64.png"),
        (format!("/v1/jobs/{id}/png"), "png-original.png"),
        (format!("/v1/jobs/{id}/pdf"), "result.pdf"),
        (format!("/v1/jobs/{id}/svg?flatten=true"), "result-flat.svg"),
    ] {
        let first = server.get(&url).await;
        assert_eq!(first.status, StatusCode::OK, "{url}: {}", first.text());
        let name = format!("derived/{version}/{stored}");
        assert_eq!(
            dir.read_job_file(&id, &name).as_deref(),
            Some(&first.body[..]),
            "{url}: not stored as {name}"
        );
        let again = server.get(&url).await;
        assert_eq!(again.body, first.body, "{url}");
        assert_eq!(again.header("etag"), first.header("etag"), "{url}");
    }
    // What is stored is what is served: another file put there with its digest comes back as it
    // is (so a second download reads storage and draws nothing), with the same validator.
    let name = format!("derived/{version}/png-64.png");
    let planted = test_png(20);
    let digest = {
        use sha2::Digest;
        sha2::Sha256::digest(&planted)
            .iter()
            .map(|byte| format!("{byte:02x}"))
            .collect::<String>()
    };
    dir.write_job_file(&id, &name, &planted);
    dir.write_job_file(&id, &format!("{name}.sha256"), digest.as_bytes());
    let served = server.get(&format!("/v1/jobs/{id}/png?width=64")).await;
    assert_eq!(served.body, planted);
    // A stored copy that does not match its digest is drawn again (and stored again).
    dir.write_job_file(&id, &name, b"damaged");
    let redrawn = server.get(&format!("/v1/jobs/{id}/png?width=64")).await;
    assert_eq!(redrawn.status, StatusCode::OK);
    assert_eq!(&redrawn.body[1..4], b"PNG");
    assert_eq!(dir.read_job_file(&id, &name), Some(redrawn.body.to_vec()));

    // An edit's flattened SVG, PDF and PNG: its own colours, named after it, stored beside it.
    let edit = server
        .post_json(
            &format!("/v1/jobs/{id}/edits"),
            &json!({"changes": [{"at": {"x": 24, "y": 24}, "color": "#2060c0"}]}),
        )
        .await;
    assert_eq!(edit.status, StatusCode::CREATED, "{}", edit.text());
    let edit = edit.json();
    let edit_id = edit["id"].as_str().unwrap();
    for (key, job_url, name, stored) in [
        (
            "flat_svg",
            format!("/v1/jobs/{id}/svg?flatten=true"),
            format!("image-{edit_id}-flat.svg"),
            "result-flat.svg",
        ),
        (
            "pdf",
            format!("/v1/jobs/{id}/pdf"),
            format!("image-{edit_id}.pdf"),
            "result.pdf",
        ),
        (
            "png",
            format!("/v1/jobs/{id}/png"),
            format!("image-{edit_id}.png"),
            "png-original.png",
        ),
    ] {
        let url = edit["urls"][key]
            .as_str()
            .unwrap_or_else(|| panic!("no {key}: {edit}"));
        let file = server.get(url).await;
        assert_eq!(file.status, StatusCode::OK, "{url}: {}", file.text());
        assert_eq!(
            file.header("content-disposition"),
            Some(format!("inline; filename=\"{name}\"").as_str())
        );
        assert_ne!(
            file.body,
            server.get(&job_url).await.body,
            "{url} is the job's file"
        );
        assert_eq!(
            dir.read_job_file(&id, &format!("edits/{edit_id}/derived/{version}/{stored}")),
            Some(file.body.to_vec())
        );
        let etag = file.header("etag").unwrap().to_owned();
        let cached = server.get_with(url, &[("if-none-match", &etag)]).await;
        assert_eq!(cached.status, StatusCode::NOT_MODIFIED);
    }
    let wide = server
        .get(&format!("/v1/jobs/{id}/edits/{edit_id}/png?width=0"))
        .await;
    assert_eq!(problem(&wide)["code"], "invalid-params");
    server.stop();
}
