//! The API document (api/openapi.yaml), generated from the handlers' `#[utoipa::path]`
//! attributes and the models' `ToSchema` types; `covec openapi` writes it. What the attributes
//! cannot say (the links schemathesis follows from a created job, the request examples that
//! create one, multipart encodings, the security scheme) is added by [`Contract`].

use base64::Engine;
use serde_json::{Value, json};
use utoipa::openapi::encoding::EncodingBuilder;
use utoipa::openapi::header::{Header, HeaderBuilder};
use utoipa::openapi::link::LinkBuilder;
use utoipa::openapi::path::{
    HttpMethod, Operation, OperationBuilder, ParameterBuilder, ParameterIn, PathItemBuilder,
};
use utoipa::openapi::request_body::{RequestBody, RequestBodyBuilder};
use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityRequirement, SecurityScheme};
use utoipa::openapi::{Components, Content, OpenApi as Document, RefOr, Server};
use utoipa::openapi::{
    ContentBuilder, ObjectBuilder, Paths, PathsBuilder, Ref, Required, ResponseBuilder, Type,
};
use utoipa::{Modify, OpenApi};

use super::error::{TooManyRequests, Unavailable};
use super::model::{Problem, WebhookEvent};
use super::view::{IdempotentReplayed, WebhookMessage};
use super::{edits, events, jobs, limits, ops, results};
use crate::edit::ReferenceParams;

#[derive(OpenApi)]
#[openapi(
    info(
        title = "covec vectorisation service",
        description = DESCRIPTION,
        license(name = "Apache-2.0", identifier = "Apache-2.0"),
    ),
    paths(
        jobs::create, jobs::list, jobs::get, jobs::delete, jobs::cancel, events::events,
        results::svg, results::layer, results::scene, results::png, results::pdf,
        results::previews, results::preview, results::draft,
        edits::create, edits::get, edits::edit_svg, edits::edit_scene, edits::edit_preview,
        edits::edit_pdf, edits::edit_png,
        ops::healthz, ops::readyz, ops::metrics, limits::limits,
    ),
    // Schemas only referenced from hand-built ones (headers, multipart forms).
    components(
        schemas(IdempotentReplayed, ReferenceParams, WebhookMessage),
        responses(Problem, TooManyRequests, Unavailable),
    ),
    tags((name = "jobs"), (name = "results"), (name = "edits"), (name = "operations")),
    modifiers(&Contract),
)]
struct ApiDoc;

/// The document as YAML, keys sorted (so the text changes only when the API does).
pub fn document() -> String {
    let mut value = serde_json::to_value(ApiDoc::openapi()).expect("the document serialises");
    sort_keys(&mut value);
    yaml_serde::to_string(&value).expect("JSON values serialise as YAML")
}

/// Objects' keys in order: utoipa keeps some maps (extensions) in hash order.
fn sort_keys(value: &mut Value) {
    match value {
        Value::Object(map) => {
            let mut entries: Vec<_> = std::mem::take(map).into_iter().collect();
            entries.sort_by(|(a, _), (b, _)| a.cmp(b));
            for (key, mut item) in entries {
                sort_keys(&mut item);
                map.insert(key, item);
            }
        }
        Value::Array(items) => items.iter_mut().for_each(sort_keys),
        _ => {}
    }
}

/// Every operation on a job, reachable from the job `POST /v1/jobs` answers with
/// (schemathesis' stateful phase follows these links).
const JOB_OPERATIONS: [&str; 12] = [
    "getJob",
    "jobEvents",
    "cancelJob",
    "deleteJob",
    "getSvg",
    "getScene",
    "getLayerSvg",
    "getPng",
    "getPdf",
    "listPreviews",
    "getPreview",
    "createEdit",
];

/// Every operation on an edit, reachable from the edit `POST /v1/jobs/{id}/edits` answers.
const EDIT_OPERATIONS: [&str; 6] = [
    "getEdit",
    "getEditSvg",
    "getEditScene",
    "getEditPreview",
    "getEditPdf",
    "getEditPng",
];

/// What the attributes cannot say.
struct Contract;

impl Modify for Contract {
    fn modify(&self, document: &mut Document) {
        downloads(document);
        signed_urls(document);
        request_ids(document);
        rate_limits(document);
        document.webhooks = Some(webhooks());
        // OpenAPI 3.1's `info.summary`, which utoipa's `Info` has no field for.
        document
            .info
            .extensions
            .get_or_insert_with(Default::default)
            .insert("summary".into(), SUMMARY.into());
        document.servers = Some(vec![Server::new("http://127.0.0.1:8080")]);
        // Anonymous unless the server has API keys.
        document.security = Some(vec![
            SecurityRequirement::default(),
            SecurityRequirement::new("bearer", Vec::<String>::new()),
        ]);
        document
            .components
            .get_or_insert_with(Components::new)
            .add_security_scheme(
                "bearer",
                SecurityScheme::Http(
                    HttpBuilder::new()
                        .scheme(HttpAuthScheme::Bearer)
                        .description(Some("Only when the server has API keys configured."))
                        .build(),
                ),
            );
        let paths = &mut document.paths.paths;
        let create_job = paths
            .get_mut("/v1/jobs")
            .and_then(|item| item.post.as_mut())
            .expect("POST /v1/jobs is documented");
        for status in ["200", "201", "202"] {
            if let Some(RefOr::T(response)) = create_job.responses.responses.get_mut(status) {
                for operation in JOB_OPERATIONS {
                    response.links.insert(
                        link_name(operation),
                        LinkBuilder::new()
                            .operation_id(operation)
                            .parameter("id", "$response.body#/id")
                            .build()
                            .into(),
                    );
                }
            }
        }
        require_body(&mut create_job.request_body);
        if let Some(content) = body_content(&mut create_job.request_body, "application/json") {
            content.example = Some(small_job());
        }
        if let Some(content) = body_content(&mut create_job.request_body, "multipart/form-data") {
            json_part(content, "params");
        }
        let previews = paths
            .get_mut("/v1/jobs/{id}/previews")
            .and_then(|item| item.get.as_mut())
            .expect("GET /v1/jobs/{id}/previews is documented");
        if let Some(RefOr::T(response)) = previews.responses.responses.get_mut("200") {
            response.links.insert(
                "GetFirstPreview".into(),
                LinkBuilder::new()
                    .operation_id("getPreview")
                    .parameter("id", "$request.path.id")
                    .parameter("file", "{$response.body#/items/0/name}.png")
                    .build()
                    .into(),
            );
        }
        let create_edit = paths
            .get_mut("/v1/jobs/{id}/edits")
            .and_then(|item| item.post.as_mut())
            .expect("POST /v1/jobs/{id}/edits is documented");
        if let Some(RefOr::T(response)) = create_edit.responses.responses.get_mut("201") {
            for operation in EDIT_OPERATIONS {
                response.links.insert(
                    link_name(operation),
                    LinkBuilder::new()
                        .operation_id(operation)
                        .parameter("id", "$response.body#/job_id")
                        .parameter("edit_id", "$response.body#/id")
                        .build()
                        .into(),
                );
            }
        }
        require_body(&mut create_edit.request_body);
        if let Some(content) = body_content(&mut create_edit.request_body, "multipart/form-data") {
            json_part(content, "params");
        }
    }
}

/// Operations that answer with a file ([`super::download::Download`]): a strong `ETag`,
/// `Cache-Control`, a `Content-Disposition` download name, and 304 for `If-None-Match`.
const FILE_OPERATIONS: [&str; 12] = [
    "getSvg",
    "getLayerSvg",
    "getScene",
    "getPng",
    "getPdf",
    "getPreview",
    "getEdit",
    "getEditSvg",
    "getEditScene",
    "getEditPreview",
    "getEditPdf",
    "getEditPng",
];

/// The file operations a signed URL's token opens ([`super::signed`]): every one but the
/// edit's record.
const SIGNED_OPERATIONS: [&str; 11] = [
    "getSvg",
    "getLayerSvg",
    "getScene",
    "getPng",
    "getPdf",
    "getPreview",
    "getEditSvg",
    "getEditScene",
    "getEditPreview",
    "getEditPdf",
    "getEditPng",
];

/// Every operation of the document.
fn operations(document: &mut Document) -> impl Iterator<Item = &mut Operation> {
    document.paths.paths.values_mut().flat_map(|item| {
        [
            &mut item.get,
            &mut item.post,
            &mut item.put,
            &mut item.patch,
            &mut item.delete,
        ]
        .into_iter()
        .flatten()
    })
}

fn string_header(description: &str) -> Header {
    HeaderBuilder::new()
        .schema(Some(ObjectBuilder::new().schema_type(Type::String)))
        .description(Some(description))
        .build()
}

/// The validator, caching and naming headers of a file, and the 304 that `If-None-Match`
/// gets.
fn downloads(document: &mut Document) {
    let file_headers = [
        (
            "ETag",
            "A strong validator of the file's bytes; send it back as `If-None-Match` to get \
             a 304 instead of the file again.",
        ),
        (
            "Cache-Control",
            "`private, max-age=<seconds until the results are removed>, immutable` once the \
             job has ended (results never change while they exist); `private, no-cache` for \
             the previews and the draft of a running job.",
        ),
        (
            "Content-Disposition",
            "`inline; filename=\"<stem><suffix>\"`: the uploaded image's file name without \
             its extension (else the job id), e.g. `hopper.svg`, `hopper-flat.svg`, \
             `hopper.pdf`, `hopper-albedo.svg`, `hopper.json`; an edit's files add the edit \
             id. Non-ASCII names also come as RFC 8187 `filename*`.",
        ),
    ];
    for operation in operations(document) {
        let is_file = operation
            .operation_id
            .as_deref()
            .is_some_and(|id| FILE_OPERATIONS.contains(&id));
        if !is_file {
            continue;
        }
        operation.parameters.get_or_insert_with(Vec::new).push(
            ParameterBuilder::new()
                .name("If-None-Match")
                .parameter_in(ParameterIn::Header)
                .required(Required::False)
                .schema(Some(ObjectBuilder::new().schema_type(Type::String)))
                .description(Some(
                    "The `ETag` of a copy the client holds: 304 without a body when it is \
                         still the file's.",
                ))
                .build()
                .into(),
        );
        let mut not_modified = ResponseBuilder::new()
            .description("Not Modified: the copy named by `If-None-Match` is current.");
        for (name, description) in file_headers {
            not_modified = not_modified.header(name, string_header(description));
            if let Some(RefOr::T(ok)) = operation.responses.responses.get_mut("200") {
                ok.headers
                    .insert(name.into(), string_header(description).into());
            }
        }
        operation
            .responses
            .responses
            .insert("304".into(), not_modified.build().into());
    }
}

/// The `token` query parameter of the operations a signed URL opens.
fn signed_urls(document: &mut Document) {
    for operation in operations(document) {
        let signed = operation
            .operation_id
            .as_deref()
            .is_some_and(|id| SIGNED_OPERATIONS.contains(&id));
        if !signed {
            continue;
        }
        operation.parameters.get_or_insert_with(Vec::new).push(
            ParameterBuilder::new()
                .name(super::signed::TOKEN_PARAM)
                .parameter_in(ParameterIn::Query)
                .required(Required::False)
                .schema(Some(ObjectBuilder::new().schema_type(Type::String)))
                .description(Some(
                    "On a server with API keys, instead of `Authorization`: the job's \
                     `signed.token`, which opens this job's files until it expires (403 \
                     `token-expired`; a token of another job, or not a token: 403 \
                     `token-invalid`). Ignored on a server without keys.",
                ))
                .build()
                .into(),
        );
    }
}

/// `x-request-id` on every response: the id the server logs the request under (the client's
/// own when it sent one).
fn request_ids(document: &mut Document) {
    let header = || {
        string_header(
            "The request's id in the server's logs: the client's `x-request-id` when it sent \
             one, else a UUID. Quote it when reporting a problem.",
        )
    };
    for operation in operations(document) {
        for response in operation.responses.responses.values_mut() {
            if let RefOr::T(response) = response {
                response
                    .headers
                    .insert("x-request-id".into(), header().into());
            }
        }
    }
    if let Some(components) = document.components.as_mut() {
        for response in components.responses.values_mut() {
            if let RefOr::T(response) = response {
                response
                    .headers
                    .insert("x-request-id".into(), header().into());
            }
        }
    }
}

/// The `RateLimit-Policy` and `RateLimit` fields of a submission (and its 429).
fn rate_limits(document: &mut Document) {
    let fields = [
        (
            "RateLimit-Policy",
            "When a submission rate applies to the key (`--rate-per-key`, `--key-limits`): \
             `\"submissions\";q=<per minute>;w=60` (IETF RateLimit header fields).",
        ),
        (
            "RateLimit",
            "When a submission rate applies to the key: `\"submissions\";r=<submissions \
             left now>;t=<seconds until the whole quota is back>`.",
        ),
    ];
    let create_job = document
        .paths
        .paths
        .get_mut("/v1/jobs")
        .and_then(|item| item.post.as_mut())
        .expect("POST /v1/jobs is documented");
    for status in ["200", "201", "202"] {
        if let Some(RefOr::T(response)) = create_job.responses.responses.get_mut(status) {
            for (name, description) in fields {
                response
                    .headers
                    .insert(name.into(), string_header(description).into());
            }
        }
    }
    if let Some(RefOr::T(too_many)) = document
        .components
        .as_mut()
        .and_then(|components| components.responses.get_mut("TooManyRequests"))
    {
        for (name, description) in fields {
            too_many
                .headers
                .insert(name.into(), string_header(description).into());
        }
    }
}

/// The `webhooks` section: what a webhook receiver gets.
fn webhooks() -> Paths {
    let mut paths = PathsBuilder::new();
    for event in WebhookEvent::ALL {
        let name = format!("job.{}", event.name());
        let signed = [
            (
                "webhook-id",
                "`msg_<job id>_<event>`: the same on every attempt of one event; deduplicate \
                 on it.",
            ),
            ("webhook-timestamp", "Unix seconds of this attempt."),
            (
                "webhook-signature",
                "`v1,<base64 of HMAC-SHA256 over \"<webhook-id>.<webhook-timestamp>.<body>\">`, \
                 keyed with the server's `--webhook-secret` (base64 after `whsec_`), as \
                 Standard Webhooks sign.",
            ),
        ];
        let mut operation = OperationBuilder::new()
            .operation_id(Some(format!("webhook{}", link_name(event.name()))))
            .summary(Some(match event {
                WebhookEvent::Started => "A worker took the job",
                WebhookEvent::Completed => "The job ended (succeeded, failed or canceled)",
            }))
            .description(Some(
                "POSTed to the submission's `webhook` URL for each event it asked for \
                 (`webhook_events`), signed as Standard Webhooks. Anything but a 2xx within \
                 10 s is retried after 10 s, 20 s, 40 s … up to `--webhook-attempts`; \
                 deliveries go on after a restart, so delivery is at least once.",
            ))
            .request_body(Some(
                RequestBodyBuilder::new()
                    .required(Some(Required::True))
                    .content(
                        "application/json",
                        ContentBuilder::new()
                            .schema(Some(Ref::from_schema_name("WebhookMessage")))
                            .build(),
                    )
                    .build(),
            ))
            .response(
                "2XX",
                ResponseBuilder::new().description("Received: no further attempt."),
            )
            .response(
                "default",
                ResponseBuilder::new().description("Not received: the delivery is retried."),
            );
        for (header, description) in signed {
            operation = operation.parameter(
                ParameterBuilder::new()
                    .name(header)
                    .parameter_in(ParameterIn::Header)
                    .required(Required::True)
                    .schema(Some(ObjectBuilder::new().schema_type(Type::String)))
                    .description(Some(description)),
            );
        }
        paths = paths.path(
            name,
            PathItemBuilder::new()
                .operation(HttpMethod::Post, operation.build())
                .build(),
        );
    }
    paths.build()
}

/// The request body's content of `media_type`, when the attributes declared it.
fn body_content<'a>(
    body: &'a mut Option<RefOr<RequestBody>>,
    media_type: &str,
) -> Option<&'a mut Content> {
    match body.as_mut()? {
        RefOr::T(body) => match body.content.get_mut(media_type)? {
            RefOr::T(content) => Some(content),
            RefOr::Ref(_) => None,
        },
        RefOr::Ref(_) => None,
    }
}

/// A request body the operation cannot do without (the attributes leave `required` out).
fn require_body(body: &mut Option<RefOr<RequestBody>>) {
    if let Some(RefOr::T(body)) = body.as_mut() {
        body.required = Some(Required::True);
    }
}

/// Marks the multipart form field `name` as a JSON part.
fn json_part(content: &mut Content, name: &str) {
    content.encoding.insert(
        name.into(),
        EncodingBuilder::new()
            .content_type(Some("application/json"))
            .build(),
    );
}

/// `getJob` → `GetJob`.
fn link_name(operation: &str) -> String {
    let mut name = operation.to_owned();
    name[..1].make_ascii_uppercase();
    name
}

/// A real job of seconds of work (a 16×16 PNG, few paths and iterations): what the links from
/// its answer then follow.
fn small_job() -> Value {
    let png = crate::imageio::encode_png(&crate::render::Image::filled(16, 16, [0.2, 0.5, 0.8]));
    json!({
        "image": base64::engine::general_purpose::STANDARD.encode(png),
        "params": {
            "paths": 8, "max_size": 48, "seed": 1,
            "iterations": {
                "structure": 3, "reconstruction": 3, "refine_rounds": 1, "refine": 3, "polish": 3,
            },
        },
    })
}

/// The document's one-line summary.
const SUMMARY: &str =
    "Photographs to layered, editable SVG (albedo × shade + light), as asynchronous jobs.";

/// The document's description: how the service behaves beyond single operations.
const DESCRIPTION: &str = "\
Submit an image as a job (`POST /v1/jobs`), follow it by polling `GET /v1/jobs/{id}` or with
Server-Sent Events (`GET /v1/jobs/{id}/events`), then fetch the layered SVG, the per-layer
SVGs, the JSON scene, a PNG of any width and the stage previews. While it runs, its draft
(`GET /v1/jobs/{id}/draft.svg`, from the end of the initialisation on) is a complete layered
SVG to show at once, improving as stages end.

Every error is an RFC 9457 problem (`application/problem+json`) with a stable `code`:
`unauthorized`, `token-invalid` and `token-expired` (403: a signed URL's token that is not
this job's, or has expired), `job-not-found`, `job-expired` (410: the job ended longer ago than the
record retention and its record is deleted; an id that never existed is `job-not-found`),
`malformed-job-id`, `route-not-found`, `method-not-allowed`,
`result-not-found`, `unsupported-media-type`, `body-too-large`, `too-many-pixels`,
`too-many-masks`, `too-many-changes`, `inputs-too-large`, `bad-request`, `bad-query`,
`undecodable-image`, `truncated-image`, `invalid-params`, `invalid-input`, `webhook-host-not-allowed`,
`idempotency-key-reused`, `key-queue-full`, `rate-limited`, `queue-full`, `decode-busy`,
`shutting-down`, `storage-unavailable` (503: the job database or store cannot be reached, or
is full, for now),
`job-not-succeeded`, `data-removed`, `result-corrupt` (a stored result that no longer
matches the digest recorded when it was written), `internal`, and in a failed job's `error`
also `time-limit`, `pipeline-crashed`, `workers-lost` (PostgreSQL backend: every
attempt's worker vanished). `type` is `urn:covec:problem:<code>`.

Limits (server flags / environment variables, defaults in brackets): body size
`--max-body-bytes` [32 MiB], pixels per image `--max-pixels` [16 000 000, read from the header
before decoding], masks `--max-masks` [256], `params.paths` `--max-paths` [1024],
`params.max_size` `--max-size` [1024], total iterations `--max-iterations` [5000], run time
per job `--job-time-limit` [600 s], queued jobs `--max-queued` [64], result retention
`--retention` [24 h], record retention `--record-retention` [30 days], Idempotency-Key
window `--idempotency-window` [24 h], decoded inputs per job `--max-decoded-bytes` [256 MiB], requests
decoding at once `--decode-slots` [2; others wait up to `--decode-wait` [5 s], then 503 `decode-busy`], JSON
edit bodies 1 MiB and 4096 changes (fixed).

Webhooks: a submission may name a `webhook` URL (and `webhook_events`, default
`[completed]`); the server POSTs `{\"type\": \"job.started\" | \"job.completed\", \"timestamp\",
\"data\": <Job>}` there, signed as Standard Webhooks (`webhook-id`, `webhook-timestamp`,
`webhook-signature: v1,<base64 HMAC-SHA256 of \"id.timestamp.body\">` with the server's
secret), retrying with doubling delays until a 2xx or `--webhook-attempts` [8]. Each
attempt shows in the job's `webhook.deliveries`. Destinations must be on the server's
allow-list (`--webhook-hosts`, none by default): others are refused with 422
`webhook-host-not-allowed`.

With API keys configured (`--api-keys`), every `/v1` request needs
`Authorization: Bearer <key>` (the scheme in any case), and a job is visible only to the key
that created it (others get 404). A job's files also open with the short-lived token of its
`signed` member (`?token=…`), for browsers' `<img>` and downloads, which send no header.

Fair scheduling: jobs take turns by key (the API key; without keys the `X-Client-Key`
header, or one anonymous key for requests without it). The next job to run is chosen among
keys below their running limit: `interactive` jobs first (a `batch` job that has waited
`--batch-age` [300 s] counts as interactive), then the key with the fewest jobs running,
then the key served longest ago, then its oldest job. Per-key limits: queued jobs
`--max-queued-per-key` [none beyond `--max-queued`; then 429 `key-queue-full`], running jobs
`--max-running-per-key` [none; further jobs wait], submissions per minute `--rate-per-key`
[none; then 429 `rate-limited`], with per-key overrides (`--key-limits`).
";

#[cfg(test)]
mod tests;
