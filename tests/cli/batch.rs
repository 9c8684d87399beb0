//! `covec vectorize` over many files and directories: every image written, a summary table, a
//! non-zero exit when one fails (the others still written), clashes refused before running.
#![cfg(all(feature = "cli", feature = "service"))]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn covec(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_covec"))
        .args(args)
        .output()
        .expect("covec runs")
}

fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("batch_cli")
        .join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A 32 px image, different for each `seed`: a disc on a gradient.
fn write_image(path: &Path, seed: u32) {
    let image = image::RgbImage::from_fn(32, 32, |x, y| {
        let (dx, dy) = (x as i32 - 16, y as i32 - 16);
        if dx * dx + dy * dy < 64 + (seed as i32 % 5) * 20 {
            image::Rgb([200, (seed * 37 % 200) as u8, 40])
        } else {
            image::Rgb([(x * 6) as u8, 120, (y * 6 + seed) as u8])
        }
    });
    image.save(path).unwrap();
}

const SMALL: [&str; 4] = ["--max-size", "32", "--paths", "8"];

#[test]
fn a_batch_of_twenty_files_and_directories_writes_twenty_svgs_and_a_summary() {
    let dir = scratch("twenty");
    let photos = dir.join("photos");
    std::fs::create_dir_all(&photos).unwrap();
    let mut named = Vec::new();
    for index in 0..20 {
        // 15 in a directory, 5 named on the command line.
        let path = if index < 15 {
            photos.join(format!("p{index:02}.png"))
        } else {
            dir.join(format!("n{index:02}.png"))
        };
        write_image(&path, index);
        if index >= 15 {
            named.push(path.to_str().unwrap().to_owned());
        }
    }
    std::fs::write(photos.join("notes.txt"), "not an image").unwrap();
    let out_dir = dir.join("out");
    let mut args = vec!["vectorize", photos.to_str().unwrap()];
    args.extend(named.iter().map(String::as_str));
    args.extend(["-o", out_dir.to_str().unwrap(), "--threads", "2"]);
    args.extend(SMALL);
    let out = covec(&args);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let svgs: Vec<_> = std::fs::read_dir(&out_dir)
        .unwrap()
        .map(|entry| entry.unwrap().path())
        .filter(|path| path.extension().is_some_and(|e| e == "svg"))
        .collect();
    assert_eq!(svgs.len(), 20, "{svgs:?}");
    for svg in &svgs {
        let text = std::fs::read_to_string(svg).unwrap();
        let doc = roxmltree::Document::parse(&text).unwrap();
        assert!(doc.descendants().any(|n| n.has_tag_name("path")), "{svg:?}");
        assert!(svg.with_extension("json").is_file(), "{svg:?}");
    }
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 22, "{stdout}");
    assert!(
        lines[0].starts_with("input") && lines[0].contains("status"),
        "{stdout}"
    );
    assert_eq!(
        lines.iter().filter(|l| l.contains("  ok  ")).count(),
        20,
        "{stdout}"
    );
    assert!(
        lines[21].starts_with("20 images: 20 written, 0 failed"),
        "{stdout}"
    );
}

#[test]
fn a_failed_image_fails_the_batch_and_the_others_are_written() {
    let dir = scratch("one-bad");
    let (good, bad) = (dir.join("good.png"), dir.join("bad.png"));
    write_image(&good, 3);
    std::fs::write(&bad, b"not a png").unwrap();
    let out_dir = dir.join("out");
    let mut args = vec![
        "vectorize",
        bad.to_str().unwrap(),
        good.to_str().unwrap(),
        "-o",
        out_dir.to_str().unwrap(),
    ];
    args.extend(SMALL);
    let out = covec(&args);
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.starts_with("error: 1 of 2 images failed"),
        "{stderr}"
    );
    assert!(out_dir.join("good.svg").is_file());
    assert!(!out_dir.join("bad.svg").exists());
    assert!(
        stdout.contains("failed") && stdout.contains("bad.png"),
        "{stdout}"
    );
    assert!(stdout.contains("2 images: 1 written, 1 failed"), "{stdout}");
}

#[test]
fn batches_refuse_clashing_names_and_per_image_options_before_running() {
    let dir = scratch("refused");
    std::fs::create_dir_all(dir.join("a")).unwrap();
    write_image(&dir.join("a/x.png"), 1);
    write_image(&dir.join("x.png"), 2);
    let out_dir = dir.join("out");
    let path = |name: &str| dir.join(name).to_str().unwrap().to_owned();
    let (a, x, l) = (path("a"), path("x.png"), path("l"));
    let cases: [(Vec<&str>, &str); 5] = [
        (vec![&a, &x], "would both be written as x.svg"),
        (vec![&a], "needs -o DIR"),
        (vec![&a, "--layers", &l], "--layers applies to one image"),
        (vec![&a, "--stages"], "--stages applies to one image"),
        (
            vec![&x, "--jobs", "2"],
            "--threads and --jobs apply to a batch",
        ),
    ];
    for (inputs, needle) in cases {
        let mut args = vec!["vectorize"];
        args.extend(inputs);
        if needle != "needs -o DIR" && !needle.starts_with("--threads") {
            args.extend(["-o", out_dir.to_str().unwrap()]);
        }
        let out = covec(&args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{stderr}");
        assert_eq!(stderr.lines().count(), 1, "{stderr}");
        assert!(stderr.contains(needle), "{needle}: {stderr}");
        assert!(!out_dir.exists(), "nothing written");
    }
}
