//! A JSON scene (`covec render` / `covec edit` input, the service's `scene.json`), then what
//! the CLI does with one: SVG files, a bounded PNG render, colour edits with a preview, and a
//! reference edit against the scene's own composite.
#![no_main]

use covec::edit::{self, ColorChange, ReferenceParams, Target};
use covec::output::{self, FileKind};
use covec::render::composite::composite;
use covec::scene::{LayerKind, PathId};
use covec::{Point, Scene};
use libfuzzer_sys::fuzz_target;

/// `covec edit`'s canvas limit is `Limits::default().max_pixels`; smaller here, to fuzz quickly.
const MAX_CANVAS_PIXELS: u64 = 1 << 16;

fuzz_target!(|data: &[u8]| {
    let Ok(scene) = serde_json::from_slice::<Scene>(data) else {
        return;
    };
    let kinds = [
        FileKind::SceneJson,
        FileKind::LayeredSvg,
        FileKind::Layer(LayerKind::Albedo),
        FileKind::Layer(LayerKind::Shade),
        FileKind::Layer(LayerKind::Light),
    ];
    let _ = output::artefacts(&scene, &kinds);
    let _ = output::png(&scene, Some(48), 48 * 48);
    let changes = [
        ColorChange {
            target: Target::Path(PathId {
                layer: LayerKind::Albedo,
                index: 0,
            }),
            color: [0.5, 0.25, 1.0],
            opacity: Some(0.5),
        },
        ColorChange {
            target: Target::AlbedoAt(Point::new(
                scene.width as f32 / 2.0,
                scene.height as f32 / 2.0,
            )),
            color: [0.0, 1.0, 0.0],
            opacity: None,
        },
    ];
    // `covec edit` refuses what it cannot draw at canvas size before anything else.
    if output::check_canvas(&scene, MAX_CANVAS_PIXELS).is_err() {
        return;
    }
    for change in changes {
        if let Ok(edited) = edit::recolor_paths(&scene, std::slice::from_ref(&change)) {
            // `covec edit --preview`: the edited scene drawn at its canvas size.
            let _ = output::artefacts(&edited.scene, &[FileKind::Preview]);
        }
    }
    // `covec edit --reference` without `--original`: the scene's composite is the original.
    let original = composite(&scene);
    let mut reference = original.clone();
    reference
        .data
        .iter_mut()
        .step_by(7)
        .for_each(|v| *v = 1.0 - *v);
    let _ = edit::recolor_by_reference(&scene, &original, &reference, &ReferenceParams::default());
});
