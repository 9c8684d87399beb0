//! A JSON scene (`covec render` / `covec edit` input, the service's `scene.json`), then what
//! the CLI does with one: SVG files, a bounded PNG render and a colour edit.
#![no_main]

use covec::edit::{self, ColorChange, Target};
use covec::output::{self, FileKind};
use covec::scene::{LayerKind, PathId};
use covec::{Point, Scene};
use libfuzzer_sys::fuzz_target;

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
    for change in changes {
        let _ = edit::recolor_paths(&scene, std::slice::from_ref(&change));
    }
});
