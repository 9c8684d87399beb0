//! Edits through the API: direct recolour (by id and by point, chained on a base edit),
//! recolour by reference image, and bad edit requests → 4xx problem+json.
#![cfg(all(feature = "cli", feature = "service"))]

use crate::service_support;

use hyper::{Method, StatusCode};
use serde_json::json;
use service_support::{DataDir, Server, multipart, png, problem, test_png};

async fn post_reference(
    server: &Server,
    id: &str,
    parts: &[(&str, &[u8])],
) -> service_support::Reply {
    let (content_type, body) = multipart(parts);
    server
        .request(
            Method::POST,
            &format!("/v1/jobs/{id}/edits"),
            &[("content-type", content_type.as_str())],
            body,
        )
        .await
}

#[tokio::test]
async fn direct_recolour_by_id_and_point_keeps_the_rest() {
    let dir = DataDir::new("edits-direct");
    let server = Server::start(&dir.0, &["--workers", "1"]);
    let id = server.finished_job().await;
    let original = server.get(&format!("/v1/jobs/{id}/svg")).await.text();

    let created = server
        .post_json(
            &format!("/v1/jobs/{id}/edits"),
            &json!({"changes": [{"path": "albedo-0", "color": "#00ff00"}]}),
        )
        .await;
    assert_eq!(created.status, StatusCode::CREATED, "{}", created.text());
    let edit = created.json();
    let edit_url = edit["urls"]["self"].as_str().unwrap().to_owned();
    assert_eq!(created.header("location"), Some(edit_url.as_str()));
    assert_eq!(edit["changed"][0]["path"], "albedo-0");
    assert_eq!(edit["changed"][0]["new_color"], "#00ff00");

    let svg = server.get(edit["urls"]["svg"].as_str().unwrap()).await;
    assert_eq!(svg.status, StatusCode::OK);
    let svg = svg.text();
    assert!(
        svg.contains(r##"id="albedo-0" fill="#00ff00""##) || svg.contains("#00ff00"),
        "{svg}"
    );
    // Only the fill of albedo-0 differs from the job's SVG: shade and light are kept.
    let differing: Vec<_> = original
        .lines()
        .zip(svg.lines())
        .filter(|(a, b)| a != b)
        .collect();
    assert_eq!(differing.len(), 1, "{differing:?}");
    assert_eq!(
        server.get(&format!("/v1/jobs/{id}/svg")).await.text(),
        original,
        "the job keeps its scene"
    );

    let preview = server.get(edit["urls"]["preview"].as_str().unwrap()).await;
    assert_eq!(preview.header("content-type"), Some("image/png"));
    assert!(preview.body.starts_with(b"\x89PNG"));
    let scene = server
        .get(edit["urls"]["scene"].as_str().unwrap())
        .await
        .json();
    assert_eq!(scene["albedo"]["paths"][0]["color"], json!([0.0, 1.0, 0.0]));
    assert_eq!(server.get(&edit_url).await.json()["id"], edit["id"]);

    // A second edit on top of the first (the page's undo history): both changes show.
    let chained = server
        .post_json(
            &format!("/v1/jobs/{id}/edits"),
            &json!({"base": edit["id"], "changes": [{"at": {"x": 2.0, "y": 2.0}, "color": "#0000ff", "opacity": 1.0}]}),
        )
        .await;
    assert_eq!(chained.status, StatusCode::CREATED, "{}", chained.text());
    let chained = chained.json();
    assert_eq!(chained["base"], edit["id"]);
    let picked = chained["changed"][0]["path"].as_str().unwrap();
    assert!(picked.starts_with("albedo-"), "{picked}");
    let scene = server
        .get(chained["urls"]["scene"].as_str().unwrap())
        .await
        .json();
    let index: usize = picked.trim_start_matches("albedo-").parse().unwrap();
    assert_eq!(
        scene["albedo"]["paths"][index]["color"],
        json!([0.0, 0.0, 1.0])
    );
    server.stop();
}

#[tokio::test]
async fn recolour_by_reference_changes_the_edited_region() {
    let dir = DataDir::new("edits-reference");
    let server = Server::start(&dir.0, &["--workers", "1"]);
    let id = server.finished_job().await;
    // The test image with its red disc turned green.
    let image = image::load_from_memory(&test_png(48)).unwrap().to_rgb8();
    let edited = image::RgbImage::from_fn(48, 48, |x, y| {
        let p = image.get_pixel(x, y);
        if p[0] > p[2] {
            image::Rgb([p[1], p[0], p[2]])
        } else {
            *p
        }
    });
    let mut png = Vec::new();
    image::DynamicImage::ImageRgb8(edited)
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    let reply = post_reference(&server, &id, &[("reference", &png), ("k", b"2")]).await;
    assert_eq!(reply.status, StatusCode::CREATED, "{}", reply.text());
    let edit = reply.json();
    // At most k = 2 albedo paths, and with them the disc's own shade and light paths.
    let changed = edit["changed"].as_array().unwrap();
    let albedo: Vec<_> = changed
        .iter()
        .filter(|c| c["path"].as_str().unwrap().starts_with("albedo-"))
        .collect();
    assert!(!albedo.is_empty() && albedo.len() <= 2, "{edit}");
    for c in albedo {
        let green = u8::from_str_radix(&c["new_color"].as_str().unwrap()[3..5], 16).unwrap();
        let red = u8::from_str_radix(&c["new_color"].as_str().unwrap()[1..3], 16).unwrap();
        assert!(green > red, "the disc's paths turn green: {c}");
    }
    server.stop();
}

#[tokio::test]
async fn bad_edits_are_4xx_problems() {
    let dir = DataDir::new("edits-bad");
    let server = Server::start(&dir.0, &["--workers", "1"]);
    let id = server.finished_job().await;
    let path = format!("/v1/jobs/{id}/edits");
    let cases = [
        (
            json!({"changes": [{"path": "albedo-999", "color": "#ffffff"}]}),
            StatusCode::UNPROCESSABLE_ENTITY,
        ),
        (
            json!({"changes": [{"path": "halo-1", "color": "#ffffff"}]}),
            StatusCode::UNPROCESSABLE_ENTITY,
        ),
        (
            json!({"changes": [{"path": "albedo-0", "color": "red"}]}),
            StatusCode::UNPROCESSABLE_ENTITY,
        ),
        (
            json!({"changes": [{"path": "albedo-0", "color": "#ffffff", "opacity": 2.0}]}),
            StatusCode::UNPROCESSABLE_ENTITY,
        ),
        (
            json!({"changes": [{"at": {"x": -50.0, "y": 3.0}, "color": "#ffffff"}]}),
            StatusCode::UNPROCESSABLE_ENTITY,
        ),
        (json!({"changes": []}), StatusCode::BAD_REQUEST),
        (
            json!({"changes": [{"color": "#ffffff"}]}),
            StatusCode::BAD_REQUEST,
        ),
        (
            json!({"base": "edit_nope", "changes": [{"path": "albedo-0", "color": "#ffffff"}]}),
            StatusCode::BAD_REQUEST,
        ),
        (
            json!({"base": "edit_0123456789abcdef0123456789abcdef", "changes": [{"path": "albedo-0", "color": "#ffffff"}]}),
            StatusCode::NOT_FOUND,
        ),
    ];
    for (body, status) in cases {
        let reply = server.post_json(&path, &body).await;
        assert_eq!(reply.status, status, "{body}: {}", reply.text());
        problem(&reply);
    }
    // A reference of another aspect ratio, an undecodable one, a bad k, a missing reference.
    let wide = png(&image::DynamicImage::ImageRgb8(image::RgbImage::new(
        48, 24,
    )));
    for (parts, status) in [
        (vec![("reference", wide)], StatusCode::UNPROCESSABLE_ENTITY),
        (
            vec![("reference", b"not an image".to_vec())],
            StatusCode::UNPROCESSABLE_ENTITY,
        ),
        (
            vec![("reference", test_png(48)), ("k", b"0".to_vec())],
            StatusCode::UNPROCESSABLE_ENTITY,
        ),
        (vec![("k", b"2".to_vec())], StatusCode::BAD_REQUEST),
    ] {
        let parts: Vec<(&str, &[u8])> = parts.iter().map(|(n, b)| (*n, b.as_slice())).collect();
        let reply = post_reference(&server, &id, &parts).await;
        assert_eq!(
            reply.status,
            status,
            "{:?}: {}",
            parts.iter().map(|p| p.0).collect::<Vec<_>>(),
            reply.text()
        );
        problem(&reply);
    }
    let reply = server
        .request(
            Method::POST,
            &path,
            &[("content-type", "text/plain")],
            b"hi".to_vec(),
        )
        .await;
    assert_eq!(reply.status, StatusCode::UNSUPPORTED_MEDIA_TYPE);
    problem(&reply);
    let reply = server
        .get(&format!(
            "/v1/jobs/{id}/edits/edit_0123456789abcdef0123456789abcdef/svg"
        ))
        .await;
    assert_eq!(reply.status, StatusCode::NOT_FOUND);
    problem(&reply);
    let reply = server
        .post_json(
            "/v1/jobs/job_0123456789abcdef0123456789abcdef/edits",
            &json!({"changes": []}),
        )
        .await;
    assert_eq!(reply.status, StatusCode::NOT_FOUND);
    problem(&reply);
    server.stop();
}

/// Edits are capped (issue 13, item 7): too many changes or too large a body is a 413 with its
/// code, an oversized reference image a 413 `too-many-pixels`; a capped edit's files are
/// served without its record being read (its preview is a few KB whatever the edit holds).
#[tokio::test]
async fn edits_are_capped_and_their_files_served_without_the_record() {
    let dir = DataDir::new("edits-capped");
    let server = Server::start(&dir.0, &["--workers", "1", "--max-pixels", "4000"]);
    let id = server.finished_job().await;
    let path = format!("/v1/jobs/{id}/edits");
    let change = json!({"path": "albedo-0", "color": "#123456"});
    let reply = server
        .post_json(&path, &json!({ "changes": vec![change.clone(); 4097] }))
        .await;
    assert_eq!(
        reply.status,
        StatusCode::PAYLOAD_TOO_LARGE,
        "{}",
        reply.text()
    );
    let refused = problem(&reply);
    assert_eq!(
        (refused["code"].as_str(), refused["limit"].as_u64()),
        (Some("too-many-changes"), Some(4096))
    );
    // 1.5 MiB: over the 1 MiB limit, within the twice-the-limit the server reads before
    // answering (so the client gets the 413 rather than a reset).
    let padding = " ".repeat(3 << 19);
    let reply = server
        .request(
            Method::POST,
            &path,
            &[("content-type", "application/json")],
            format!(r#"{{"changes": [{change}]{padding}}}"#).into_bytes(),
        )
        .await;
    assert_eq!(
        reply.status,
        StatusCode::PAYLOAD_TOO_LARGE,
        "{}",
        reply.text()
    );
    assert_eq!(problem(&reply)["code"], "body-too-large");
    // 96² = 9216 pixels, over the limit of 4000 (the job's 48² input is under it).
    let big = test_png(96);
    let reply = post_reference(&server, &id, &[("reference", &big)]).await;
    assert_eq!(
        reply.status,
        StatusCode::PAYLOAD_TOO_LARGE,
        "{}",
        reply.text()
    );
    assert_eq!(problem(&reply)["code"], "too-many-pixels");

    // The largest edit allowed; then its record is replaced by bytes that cannot be read as
    // one: the files still serve, so serving them never reads the record.
    let created = server
        .post_json(&path, &json!({ "changes": vec![change; 4096] }))
        .await;
    assert_eq!(created.status, StatusCode::CREATED, "{}", created.text());
    let edit = created.json()["id"].as_str().unwrap().to_owned();
    dir.write_job_file(&id, &format!("edits/{edit}/edit.json"), b"not a record");
    for file in ["preview.png", "svg", "scene.json"] {
        let reply = server
            .get(&format!("/v1/jobs/{id}/edits/{edit}/{file}"))
            .await;
        assert_eq!(reply.status, StatusCode::OK, "{file}: {}", reply.text());
    }
    server.stop();
}
