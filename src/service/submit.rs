//! Reading a job submission (multipart or JSON with base64) and checking it against the limits.
//!
//! Every check that can fail on the client's input runs here, before a job exists, so bad input
//! is a 4xx on `POST /v1/jobs` rather than a failed job.

use axum::body::Bytes;
use axum::extract::{FromRequest, Multipart, Request};
use axum::http::header;
use base64::Engine;
use http_body_util::BodyExt;
use serde::Deserialize;
use sha2::{Digest, Sha256};

use utoipa::ToSchema;
use utoipa::openapi::schema::{AdditionalProperties, ArrayBuilder, KnownFormat, SchemaFormat};
use utoipa::openapi::{ObjectBuilder, Ref, RefOr, Schema, Type};

use super::error::ApiError;
use super::inputs::{EncodedInputs, InputLimits};
use super::model::{Priority, WebhookEvent, hex, input_name};
use super::webhooks::WebhookRequest;
use crate::pipeline::Params;

/// The encoded inputs and parameters of one job, as uploaded.
pub struct Submission {
    pub inputs: EncodedInputs,
    pub params: Params,
    /// `webhook` and `webhook_events`, unchecked ([`super::webhooks::Webhooks::target`] checks).
    pub webhook: WebhookRequest,
    /// `priority`, when sent (default interactive).
    pub priority: Option<Priority>,
    /// The image's file name as sent, made safe ([`input_name`]); not part of the fingerprint:
    /// a retry of the same image under another name is the same job.
    pub input_name: Option<String>,
}

/// The JSON form of a submission: images as standard base64, optionally as
/// `data:<type>;base64,` URLs.
#[derive(Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct JsonSubmission {
    #[schema(value_type = Base64Image)]
    image: String,
    #[schema(value_type = Option<Base64Image>)]
    albedo: Option<String>,
    #[serde(default)]
    #[schema(value_type = Vec<Base64Image>)]
    masks: Vec<String>,
    #[schema(value_type = Option<Base64Image>)]
    labels: Option<String>,
    #[schema(value_type = Option<Params>)]
    params: Option<serde_json::Value>,
    #[schema(value_type = Option<WebhookUrl>)]
    webhook: Option<String>,
    /// Events for the webhook (default `[completed]`).
    #[schema(value_type = Option<Vec<WebhookEvent>>, min_items = 1)]
    webhook_events: Option<Vec<String>>,
    #[schema(value_type = Option<Priority>)]
    priority: Option<String>,
    /// The image's file name (e.g. `hopper.jpg`): downloads of the results are named after
    /// its stem (`hopper.svg`, `hopper-flat.svg`, `hopper.pdf`). Default: the job id.
    #[schema(max_length = 255, example = "hopper.jpg")]
    filename: Option<String>,
}

/// One base64 image in the API document: standard base64, optionally a `data:` URL, with
/// padding as encoders write it.
pub(super) struct Base64Image;

impl utoipa::PartialSchema for Base64Image {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(Type::String)
            .content_encoding("base64")
            .pattern(Some(
                "^(data:[^,]*;base64,)?([A-Za-z0-9+/]{4})*([A-Za-z0-9+/]{2}==|[A-Za-z0-9+/]{3}=)?$",
            ))
            .into()
    }
}

impl utoipa::ToSchema for Base64Image {}

/// A submission's `webhook` in the API document.
pub(super) struct WebhookUrl;

impl utoipa::PartialSchema for WebhookUrl {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(Type::String)
            .max_length(Some(2048))
            .format(Some(SchemaFormat::Custom("uri".into())))
            .description(Some(
                "An absolute http(s) URL without user information, on a host of the server's \
                 allow-list (`--webhook-hosts`); others are refused with 422 \
                 `webhook-host-not-allowed`. Redirects are not followed.",
            ))
            .into()
    }
}

impl utoipa::ToSchema for WebhookUrl {}

/// The multipart form of a submission in the API document (read field by field by
/// [`read_multipart`]).
pub(super) struct MultipartSubmission;

impl utoipa::PartialSchema for MultipartSubmission {
    fn schema() -> RefOr<Schema> {
        let binary = |description: &str| {
            ObjectBuilder::new()
                .schema_type(Type::String)
                .format(Some(SchemaFormat::KnownFormat(KnownFormat::Binary)))
                .description(Some(description))
        };
        ObjectBuilder::new()
            .property("image", binary("PNG, JPEG or WebP."))
            .property("albedo", binary("An albedo map with the image's aspect ratio."))
            .property(
                "mask",
                ArrayBuilder::new()
                    .items(
                        ObjectBuilder::new()
                            .schema_type(Type::String)
                            .format(Some(SchemaFormat::KnownFormat(KnownFormat::Binary))),
                    )
                    .description(Some(
                        "Binary masks, each the image's size (repeat the field). Not with `labels`.",
                    )),
            )
            .property("labels", binary("One label map the image's size."))
            .property("params", Ref::from_schema_name(Params::name()))
            .property("webhook", Ref::from_schema_name(WebhookUrl::name()))
            .property(
                "webhook_events",
                ObjectBuilder::new().schema_type(Type::String).description(Some(
                    "Comma-separated events for the webhook, `started` and/or `completed` \
                     (default `completed`).",
                )),
            )
            .property("priority", Ref::from_schema_name(<Priority as ToSchema>::name()))
            .required("image")
            .additional_properties(Some(AdditionalProperties::FreeForm(false)))
            .into()
    }
}

impl utoipa::ToSchema for MultipartSubmission {}

/// The query of a request that uploads images (`POST /v1/jobs`, a reference edit).
#[derive(Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
#[serde(deny_unknown_fields)]
pub(super) struct UploadQuery {
    /// Use JPEGs cut short (the missing part decodes as grey) instead of refusing them with
    /// 422 `truncated-image`.
    #[serde(default)]
    #[param(default = false)]
    pub accept_truncated: bool,
}

impl UploadQuery {
    pub fn of(request: &Request) -> Result<Self, ApiError> {
        axum::extract::Query::<Self>::try_from_uri(request.uri())
            .map(|query| query.0)
            .map_err(|rejection| ApiError::BadQuery(rejection.body_text()))
    }
}

/// Reads the body of `POST /v1/jobs`.
pub async fn read(request: Request, limits: &InputLimits) -> Result<Submission, ApiError> {
    let content_type = request
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|value| value.to_str().ok())
        .unwrap_or("")
        .to_owned();
    let request = refuse_declared_over(request, limits.max_body_bytes).await?;
    let media_type = content_type
        .split(';')
        .next()
        .unwrap_or("")
        .trim()
        .to_ascii_lowercase();
    let submission = match media_type.as_str() {
        "multipart/form-data" => read_multipart(request, limits).await?,
        "application/json" => read_json(request, limits).await?,
        _ => return Err(ApiError::UnsupportedMediaType(content_type)),
    };
    check_params(&submission.params, limits)?;
    Ok(submission)
}

async fn read_multipart(request: Request, limits: &InputLimits) -> Result<Submission, ApiError> {
    let mut multipart = Multipart::from_request(request, &())
        .await
        .map_err(|rejection| ApiError::BadRequest(rejection.body_text()))?;
    let field_error = |error: axum::extract::multipart::MultipartError| {
        if error.status() == axum::http::StatusCode::PAYLOAD_TOO_LARGE {
            ApiError::BodyTooLarge {
                limit: limits.max_body_bytes,
            }
        } else {
            ApiError::BadRequest(error.body_text())
        }
    };
    let (mut image, mut albedo, mut masks, mut labels, mut params) =
        (None, None, Vec::new(), None, None);
    let (mut webhook, mut webhook_events, mut priority) = (None, None, None);
    let mut image_name = None;
    while let Some(field) = multipart.next_field().await.map_err(field_error)? {
        let name = field.name().unwrap_or("").to_owned();
        if name == "image" {
            image_name = field.file_name().and_then(input_name);
        }
        let bytes = field.bytes().await.map_err(field_error)?;
        let slot = match name.as_str() {
            "image" => &mut image,
            "albedo" => &mut albedo,
            "labels" => &mut labels,
            "params" => &mut params,
            "webhook" => &mut webhook,
            "webhook_events" => &mut webhook_events,
            "priority" => &mut priority,
            "mask" => {
                masks.push(bytes);
                if masks.len() > limits.max_masks {
                    return Err(too_many_masks(masks.len(), limits));
                }
                continue;
            }
            other => {
                return Err(ApiError::BadRequest(format!(
                    "unknown form field `{other}`"
                )));
            }
        };
        if slot.replace(bytes).is_some() {
            return Err(ApiError::BadRequest(format!(
                "form field `{name}` given twice"
            )));
        }
    }
    let params =
        match params {
            Some(json) => parse_params(serde_json::from_slice(&json).map_err(|error| {
                ApiError::InvalidParams(format!("`params` is not JSON: {error}"))
            })?)?,
            None => Params::default(),
        };
    let image =
        image.ok_or_else(|| ApiError::BadRequest("the form field `image` is required".into()))?;
    let text = |name: &str, bytes: Bytes| {
        String::from_utf8(bytes.to_vec())
            .map_err(|_| ApiError::InvalidParams(format!("`{name}` is not UTF-8 text")))
    };
    Ok(Submission {
        inputs: EncodedInputs {
            image,
            albedo,
            masks,
            labels,
        },
        params,
        priority: priority
            .map(|priority| parse_priority(&text("priority", priority)?))
            .transpose()?,
        webhook: WebhookRequest {
            url: webhook.map(|url| text("webhook", url)).transpose()?,
            // A comma-separated list in a form.
            events: webhook_events
                .map(|events| text("webhook_events", events))
                .transpose()?
                .map(|events| events.split(',').map(|e| e.trim().to_owned()).collect()),
        },
        input_name: image_name,
    })
}

/// 413 for a request whose declared `Content-Length` is over `limit`, before reading it.
async fn refuse_declared_over(request: Request, limit: u64) -> Result<Request, ApiError> {
    let declared_length = request
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|value| value.to_str().ok())
        .and_then(|value| value.parse::<u64>().ok());
    if let Some(length) = declared_length
        && length > limit
    {
        // Read (and drop) a body up to twice the limit before answering: closing a connection
        // with unread data makes the kernel reset it, and the client may lose the 413.
        // Anything larger is cut off at once.
        if length <= limit.saturating_mul(2) {
            let mut body = request.into_body();
            while let Some(Ok(_)) = body.frame().await {}
        }
        return Err(ApiError::BodyTooLarge { limit });
    }
    Ok(request)
}

/// A whole request body of at most `limit` bytes: 413 beyond it, 400 when it cannot be read.
pub(super) async fn read_body(request: Request, limit: u64) -> Result<Bytes, ApiError> {
    let request = refuse_declared_over(request, limit).await?;
    axum::body::to_bytes(request.into_body(), limit as usize)
        .await
        .map_err(|error| {
            let over_limit = std::error::Error::source(&error)
                .is_some_and(|source| source.is::<http_body_util::LengthLimitError>())
                || error.into_inner().is::<http_body_util::LengthLimitError>();
            if over_limit {
                ApiError::BodyTooLarge { limit }
            } else {
                ApiError::BadRequest("the request body could not be read".into())
            }
        })
}

async fn read_json(request: Request, limits: &InputLimits) -> Result<Submission, ApiError> {
    let body = read_body(request, limits.max_body_bytes).await?;
    let json: JsonSubmission = serde_json::from_slice(&body)
        .map_err(|error| ApiError::BadRequest(format!("JSON body: {error}")))?;
    if json.masks.len() > limits.max_masks {
        return Err(too_many_masks(json.masks.len(), limits));
    }
    let masks = json
        .masks
        .iter()
        .map(|mask| decode_base64("masks[]", mask))
        .collect::<Result<_, _>>()?;
    Ok(Submission {
        inputs: EncodedInputs {
            image: decode_base64("image", &json.image)?,
            albedo: json
                .albedo
                .as_deref()
                .map(|albedo| decode_base64("albedo", albedo))
                .transpose()?,
            masks,
            labels: json
                .labels
                .as_deref()
                .map(|labels| decode_base64("labels", labels))
                .transpose()?,
        },
        params: json
            .params
            .map(parse_params)
            .transpose()?
            .unwrap_or_default(),
        priority: json.priority.as_deref().map(parse_priority).transpose()?,
        webhook: WebhookRequest {
            url: json.webhook,
            events: json.webhook_events,
        },
        input_name: json.filename.as_deref().and_then(input_name),
    })
}

fn too_many_masks(actual: usize, limits: &InputLimits) -> ApiError {
    ApiError::TooManyMasks {
        limit: limits.max_masks as u64,
        actual: actual as u64,
    }
}

/// Standard-alphabet base64 as common decoders read it (Python's `b64decode`, browsers' `atob`,
/// Node's `Buffer`): padding optional and non-zero trailing bits ignored, so `…T75==` decodes as
/// it does there rather than being refused.
const LENIENT_BASE64: base64::engine::GeneralPurpose = base64::engine::GeneralPurpose::new(
    &base64::alphabet::STANDARD,
    base64::engine::GeneralPurposeConfig::new()
        .with_decode_allow_trailing_bits(true)
        .with_decode_padding_mode(base64::engine::DecodePaddingMode::Indifferent),
);

/// Base64 ([`LENIENT_BASE64`]), optionally wrapped in a `data:<type>;base64,` URL.
fn decode_base64(field: &str, text: &str) -> Result<Bytes, ApiError> {
    let payload = match text.strip_prefix("data:") {
        Some(url) => url
            .split_once(";base64,")
            .map(|(_, payload)| payload)
            .ok_or_else(|| {
                ApiError::BadRequest(format!("`{field}` is a data URL without `;base64,`"))
            })?,
        None => text,
    };
    LENIENT_BASE64
        .decode(payload.trim())
        .map(Bytes::from)
        .map_err(|error| ApiError::BadRequest(format!("`{field}` is not valid base64: {error}")))
}

fn parse_priority(name: &str) -> Result<Priority, ApiError> {
    Priority::from_name(name.trim()).ok_or_else(|| {
        ApiError::InvalidParams(format!(
            "`priority` is `{name}`; expected `interactive` or `batch`"
        ))
    })
}

fn parse_params(value: serde_json::Value) -> Result<Params, ApiError> {
    serde_json::from_value(value).map_err(|error| ApiError::InvalidParams(error.to_string()))
}

/// The parameters' ranges, as configured: [`Params::validate`] is their one home.
fn check_params(params: &Params, limits: &InputLimits) -> Result<(), ApiError> {
    params
        .validate(&limits.params())
        .map_err(|error| match error {
            crate::pipeline::Error::Params(detail) => ApiError::InvalidParams(detail),
            other => ApiError::Internal(other.to_string()),
        })
}

impl Submission {
    /// SHA-256 over the parameters and every input, for `Idempotency-Key`.
    pub fn fingerprint(&self) -> String {
        let mut hasher = Sha256::new();
        hasher.update(serde_json::to_vec(&self.params).expect("params always serialise"));
        let mut part = |tag: &[u8], bytes: &[u8]| {
            hasher.update(tag);
            hasher.update((bytes.len() as u64).to_le_bytes());
            hasher.update(bytes);
        };
        let inputs = &self.inputs;
        part(b"image", &inputs.image);
        if let Some(albedo) = &inputs.albedo {
            part(b"albedo", albedo);
        }
        for mask in &inputs.masks {
            part(b"mask", mask);
        }
        if let Some(labels) = &inputs.labels {
            part(b"labels", labels);
        }
        // Only when sent: fingerprints of submissions without a webhook stay as they were.
        if self.webhook.url.is_some() || self.webhook.events.is_some() {
            part(
                b"webhook",
                &serde_json::to_vec(&self.webhook).expect("strings always serialise"),
            );
        }
        // Likewise only when sent.
        if let Some(priority) = self.priority {
            part(b"priority", priority.name().as_bytes());
        }
        hex(&hasher.finalize())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(text: &str) -> Result<Vec<u8>, ApiError> {
        decode_base64("image", text).map(|bytes| bytes.to_vec())
    }

    #[test]
    fn base64_is_read_as_common_decoders_read_it() {
        // Canonical, with and without padding.
        assert_eq!(decode("QUJDRA==").unwrap(), b"ABCD");
        assert_eq!(decode("QUJDRA").unwrap(), b"ABCD");
        // Non-zero padding bits, as schemathesis sent (`75==`: `5` leaves 0b1001 unused, the
        // canonical form is `74==`); Python's `b64decode` and browsers' `atob` read both alike.
        assert_eq!(decode("AAAT75==").unwrap(), [0, 0, 0x13, 0xef]);
        assert_eq!(decode("AAAT75").unwrap(), [0, 0, 0x13, 0xef]);
        assert_eq!(decode("QUJDRB==").unwrap(), b"ABCD");
        assert_eq!(decode("data:image/png;base64,QUJDRB").unwrap(), b"ABCD");
    }

    #[test]
    fn what_is_not_base64_stays_a_400() {
        for text in ["%%%not base64%%%", "QUJDR", "QUJDRA===", "QU=JDRA=="] {
            assert!(
                matches!(decode(text), Err(ApiError::BadRequest(_))),
                "{text} accepted"
            );
        }
    }
}
