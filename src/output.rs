//! The files covec writes for a scene, in one place: their names, media types and contents. The
//! command line writes them to paths, the service to its store, the editor to either; none of
//! them builds an SVG, JSON or preview of its own.

use crate::imageio::encode_png;
use crate::render::composite::composite;
use crate::scene::{LayerKind, Scene};
use crate::svg::{self, SvgOptions};

/// One kind of file made from a scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FileKind {
    /// The layered SVG (`result.svg`).
    LayeredSvg,
    /// The JSON scene, full precision, loaded back losslessly (`scene.json`).
    SceneJson,
    /// One layer alone over its base colour (`layers/<layer>.svg`).
    Layer(LayerKind),
    /// The scene as shown, rendered by covec's own renderer (`preview.png`).
    Preview,
}

impl FileKind {
    /// The file's name relative to its job or output directory.
    pub fn name(self) -> String {
        match self {
            FileKind::LayeredSvg => "result.svg".into(),
            FileKind::SceneJson => "scene.json".into(),
            FileKind::Layer(kind) => format!("layers/{}.svg", kind.name()),
            FileKind::Preview => "preview.png".into(),
        }
    }

    /// The media type it is served as.
    pub fn media_type(self) -> &'static str {
        match self {
            FileKind::LayeredSvg | FileKind::Layer(_) => "image/svg+xml",
            FileKind::SceneJson => "application/json",
            FileKind::Preview => "image/png",
        }
    }
}

/// A finished run's files. The layered SVG comes last: a store that finds it knows the set is
/// complete.
pub const RESULT_FILES: &[FileKind] = &[
    FileKind::Layer(LayerKind::Albedo),
    FileKind::Layer(LayerKind::Shade),
    FileKind::Layer(LayerKind::Light),
    FileKind::SceneJson,
    FileKind::LayeredSvg,
];

/// An edit's files.
pub const EDIT_FILES: &[FileKind] = &[FileKind::SceneJson, FileKind::LayeredSvg, FileKind::Preview];

/// One file's contents.
#[derive(Clone, Debug, PartialEq)]
pub struct Artefact {
    /// What it is (and so its name and media type).
    pub kind: FileKind,
    /// Its bytes, ready to write.
    pub bytes: Vec<u8>,
}

/// The files of `kinds` for `scene`, in that order, with default SVG options. Equal scenes give
/// byte-identical files.
pub fn artefacts(scene: &Scene, kinds: &[FileKind]) -> Vec<Artefact> {
    artefacts_with(scene, kinds, &SvgOptions::default())
}

/// [`artefacts`] with the SVGs formatted as `options` say.
pub fn artefacts_with(scene: &Scene, kinds: &[FileKind], options: &SvgOptions) -> Vec<Artefact> {
    kinds
        .iter()
        .map(|&kind| Artefact {
            kind,
            bytes: match kind {
                FileKind::LayeredSvg => svg::to_svg(scene, options).into_bytes(),
                FileKind::SceneJson => {
                    serde_json::to_vec_pretty(scene).expect("a scene always serialises")
                }
                FileKind::Layer(layer) => svg::layer_to_svg(scene, layer, options).into_bytes(),
                FileKind::Preview => encode_png(&composite(scene)),
            },
        })
        .collect()
}
