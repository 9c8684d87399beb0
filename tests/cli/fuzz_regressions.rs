//! Inputs that crashed (or would crash) a fuzz target (`fuzz/`, README "Fuzzing"), kept from
//! `tests/fuzz_regressions/` and replayed through the code that failed on them.
#![cfg(all(feature = "cli", feature = "service"))]

use std::path::{Path, PathBuf};
use std::process::Command;

fn input(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fuzz_regressions")
        .join(name)
}

/// Where the commands write what they would make.
fn out_dir() -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("fuzz_regressions");
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Runs `covec ARGS` and holds it to the CLI's refusal: exit 1, one line naming `needle`.
fn assert_refused(args: &[&std::ffi::OsStr], needle: &str) {
    let out = Command::new(env!("CARGO_BIN_EXE_covec"))
        .args(args)
        .output()
        .expect("covec runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
    assert_eq!(stderr.lines().count(), 1, "{args:?}: {stderr}");
    assert!(stderr.contains(needle), "{args:?}: {stderr}");
}

/// Scenes whose canvas is empty (0×0: the preview's PNG encoder panicked), 100 000² (the
/// composite asked for 120 GB) or u32::MAX² (the pixel count overflowed): `covec edit`, which
/// draws the scene at its canvas size, refuses each with one line instead.
#[test]
fn edit_refuses_scenes_it_cannot_draw() {
    let out_dir = out_dir();
    let (edited, preview) = (out_dir.join("edited.svg"), out_dir.join("edited.png"));
    for (name, needle) in [
        ("scene-empty-canvas.json", "canvas has no pixels"),
        ("scene-huge-canvas.json", "more than the limit"),
        ("scene-max-canvas.json", "more than the limit"),
    ] {
        let path = input(name);
        let scene: covec::Scene = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        assert!(
            covec::output::check_canvas(&scene, 40_000_000).is_err(),
            "{name}"
        );
        assert_refused(
            &[
                "edit".as_ref(),
                path.as_ref(),
                "--set".as_ref(),
                "albedo-0=#ff0000".as_ref(),
                "-o".as_ref(),
                edited.as_ref(),
                "--preview".as_ref(),
                preview.as_ref(),
            ],
            needle,
        );
    }
}

/// A palette PNG whose PLTE chunk is 544 bytes (not a whole number of 3-byte entries) with
/// correct CRCs: png 0.18.1 panicked expanding it (the `image` target found it). Decoding
/// refuses it, and `covec vectorize` says so in one line.
#[test]
fn a_png_palette_of_partial_entries_is_refused() {
    let path = input("png-palette-544-bytes.png");
    let bytes = std::fs::read(&path).unwrap();
    let error = covec::imageio::decode_image(&bytes, &Default::default()).unwrap_err();
    assert!(
        error.to_string().contains("palette is 544 bytes"),
        "{error}"
    );

    let svg = out_dir().join("palette.svg");
    assert_refused(
        &[
            "vectorize".as_ref(),
            path.as_ref(),
            "-o".as_ref(),
            svg.as_ref(),
        ],
        "palette is 544 bytes",
    );
}
