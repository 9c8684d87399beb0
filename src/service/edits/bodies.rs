//! The bodies of the edit routes: requests as sent and read, and the edit as served.

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa::openapi::schema::{
    AdditionalProperties, KnownFormat, RefBuilder, SchemaFormat, SchemaType,
};
use utoipa::openapi::{ObjectBuilder, OneOfBuilder, Ref, RefOr, Schema, Type};

use crate::edit::{ColorChange, ReferenceParams};
use crate::scene::Point;
use crate::service::error::ApiError;

/// Edit id: `edit_` + a UUIDv7 in hex.
pub(super) fn new_edit_id() -> String {
    format!("edit_{}", uuid::Uuid::now_v7().simple())
}

/// The edit id's schema in the API document: what [`check_edit_id`] accepts.
pub(super) struct EditId;

impl utoipa::PartialSchema for EditId {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(Type::String)
            .pattern(Some("^edit_[0-9a-f]{32}$"))
            .into()
    }
}

impl ToSchema for EditId {}

/// A colour in the API document: `#rrggbb`, as [`svg::parse_hex_colour`] reads it.
pub(super) struct Colour;

impl utoipa::PartialSchema for Colour {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(Type::String)
            .pattern(Some("^#[0-9a-fA-F]{6}$"))
            .into()
    }
}

impl ToSchema for Colour {}

pub(super) fn check_edit_id(id: &str) -> Result<(), ApiError> {
    let valid = id.strip_prefix("edit_").is_some_and(|hex| {
        hex.len() == 32
            && hex
                .bytes()
                .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
    });
    if valid {
        Ok(())
    } else {
        Err(ApiError::BadRequest(format!(
            "`{id}` is not an edit id (expected `edit_` followed by 32 lowercase hex digits)"
        )))
    }
}

/// JSON form: direct colour changes.
#[derive(Deserialize, ToSchema)]
#[schema(as = ColorEditRequest)]
#[serde(deny_unknown_fields)]
pub(super) struct ColorEdit {
    /// Apply on top of this edit (null or absent for the job's own scene).
    #[serde(default)]
    #[schema(value_type = Option<EditId>)]
    pub base: Option<String>,
    #[schema(min_items = 1)]
    pub changes: Vec<ChangeRequest>,
}

/// One change: exactly one of `path` and `at` (a `null` one counts as absent), a colour and
/// optionally an opacity. The API document gives it as one of two schemas ([`ChangeRequest`]'s
/// `PartialSchema`), a change by path and a change at a point, so that generated clients get
/// two plain types.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ChangeRequest {
    /// A path id such as `albedo-3`; or give `at`.
    #[serde(default)]
    pub path: Option<String>,
    /// A point in viewBox coordinates: the albedo path under it is recoloured.
    #[serde(default)]
    pub at: Option<Point>,
    pub color: String,
    #[serde(default)]
    pub opacity: Option<f32>,
}

impl utoipa::PartialSchema for ChangeRequest {
    fn schema() -> RefOr<Schema> {
        OneOfBuilder::new()
            .item(Ref::from_schema_name("PathChange"))
            .item(Ref::from_schema_name("PointChange"))
            .description(Some("A change by path id or by a point."))
            .into()
    }
}

impl ToSchema for ChangeRequest {
    fn schemas(schemas: &mut Vec<(String, RefOr<Schema>)>) {
        let change = |key: &str, target: RefOr<Schema>, description: &str| {
            ObjectBuilder::new()
                .property(key, target)
                .required(key)
                .property("color", Ref::from_schema_name(Colour::name()))
                .required("color")
                .property(
                    "opacity",
                    ObjectBuilder::new()
                        .schema_type(SchemaType::from_iter([Type::Number, Type::Null]))
                        .minimum(Some(0.0))
                        .maximum(Some(1.0))
                        .description(Some("The new opacity (absent or null: unchanged).")),
                )
                .additional_properties(Some(AdditionalProperties::FreeForm(false)))
                .description(Some(description))
                .into()
        };
        let path_id = ObjectBuilder::new()
            .schema_type(Type::String)
            .description(Some("A path id such as `albedo-3`."))
            .into();
        schemas.push((
            "PathChange".into(),
            change("path", path_id, "Recolour the path with this id."),
        ));
        schemas.push((
            "PointChange".into(),
            change(
                "at",
                Ref::from_schema_name(Point::name()).into(),
                "Recolour the topmost albedo path under this point (viewBox coordinates).",
            ),
        ));
        schemas.push((
            Colour::name().into(),
            <Colour as utoipa::PartialSchema>::schema(),
        ));
        schemas.push((
            Point::name().into(),
            <Point as utoipa::PartialSchema>::schema(),
        ));
    }
}

/// What a stored edit says about itself.
#[derive(Serialize, Deserialize, ToSchema)]
#[schema(as = Edit)]
pub(super) struct EditRecord {
    pub id: String,
    pub job_id: String,
    #[schema(required)]
    pub base: Option<String>,
    pub kind: EditKind,
    pub changed: Vec<ChangedView>,
    #[schema(format = DateTime)]
    pub created_at: String,
    pub urls: EditUrls,
}

#[derive(Serialize, Deserialize, Clone, Copy, ToSchema)]
#[serde(rename_all = "lowercase")]
pub(super) enum EditKind {
    Colors,
    Reference,
}

/// A path the edit changed, with its fill before and after, by its id in the edited scene. A
/// path a reference edit added in photo mode (over the edited part of an albedo path that also
/// paints outside it, right above that path, so the ids of the albedo paths above move up) has
/// `old_opacity` 0.
#[derive(Serialize, Deserialize, ToSchema)]
pub(super) struct ChangedView {
    pub path: String,
    #[schema(value_type = Colour)]
    pub old_color: String,
    #[schema(value_type = Colour)]
    pub new_color: String,
    pub old_opacity: f32,
    pub new_opacity: f32,
}

#[derive(Serialize, Deserialize, ToSchema)]
pub(super) struct EditUrls {
    #[serde(rename = "self")]
    pub this: String,
    /// The edited layered SVG.
    pub svg: String,
    /// The edited picture as plain opaque paths.
    pub flat_svg: String,
    /// A vector PDF of the flattened edited picture.
    pub pdf: String,
    /// A PNG of the edited picture at the original width (add `?width=N` for another).
    pub png: String,
    pub scene: String,
    pub preview: String,
}

/// The multipart form of an edit in the API document (read by [`read_reference_edit`]).
pub(super) struct ReferenceEditRequest;

impl utoipa::PartialSchema for ReferenceEditRequest {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .property(
                "reference",
                ObjectBuilder::new()
                    .schema_type(Type::String)
                    .format(Some(SchemaFormat::KnownFormat(KnownFormat::Binary)))
                    .description(Some("The edited image, same size as the job's image.")),
            )
            .property(
                "k",
                ObjectBuilder::new()
                    .schema_type(Type::Integer)
                    .minimum(Some(1))
                    .description(Some("Overrides `params.k`.")),
            )
            .property(
                "params",
                RefBuilder::new()
                    .ref_location_from_schema_name(ReferenceParams::name())
                    .description(Some(
                        "A JSON part: the thresholds of Appendix D, each optional.",
                    )),
            )
            .property("base", Ref::from_schema_name(EditId::name()))
            .required("reference")
            .additional_properties(Some(AdditionalProperties::FreeForm(false)))
            .into()
    }
}

impl ToSchema for ReferenceEditRequest {}

/// The request as read, before the scene is loaded.
pub(super) enum EditRequest {
    Colors(Vec<ColorChange>),
    Reference {
        image: axum::body::Bytes,
        params: ReferenceParams,
    },
}
