#!/usr/bin/env python3
"""How covec's outputs look in other programs: the layered SVG, the flattened SVG and the PDF,
each rendered by the programs people open them with and compared with covec's own render of
the layered scene (the picture that was optimised).

    benches/renderers/compare.py [--covec BIN] [--paths 64] [--work DIR] [IMAGE[:MODE]...]

Default images: four covec-bench photos (photo mode) and one emoji (simple mode) from
/work/shared/covec-bench (see its MANIFEST.md), all 256x256, so the working size is the
original size and every renderer draws one file pixel per pixel. For each image it runs
`covec vectorize --paths N --mode MODE --seed 0` (layered SVG + JSON), then `covec render` for
the flattened SVG (`--flatten`), the PDF and the reference PNG, then renders:

- the SVGs in headless Chromium and Firefox ESR (benches/renderers/browsers.mjs; each file
  opened as its own document at its size, device scale 1), resvg (the CLI of the version covec's
  tests use: `cargo install resvg --version 0.49.0 --locked`), rsvg-convert (Debian
  librsvg2-bin), CairoSVG (PyPI) and Inkscape (Debian inkscape), each at the file's size;
- the PDF with poppler's pdftoppm at 96 dpi (one page pixel per image pixel; its default
  anti-aliasing, `-aa yes -aaVector yes`) and, for comparison, poppler's pdftocairo at 96 dpi.

Per image, output and renderer: the mean absolute difference over pixels and RGB channels, and
the 99th percentile over pixels of the largest channel difference, both in 1/255, against the
reference; renderers that are missing are reported as such. Then the sizes: bytes and gzip -9
bytes and path counts of the layered and flattened SVGs, and the PDF's bytes (its content
stream is already deflated). Prints Markdown
tables (README, "Flattened SVG and PDF: renderers"). Needs numpy and Pillow; scripts
setup-renderers.sh and setup-browser.sh install the renderers (plus Inkscape and the resvg CLI
above, which only this benchmark uses).
"""

import argparse
import gzip
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

BENCH = Path("/work/shared/covec-bench")
DEFAULT_IMAGES = [
    f"{BENCH}/faces/face_kodim04.png:photo",
    f"{BENCH}/faces/face_hopper.png:photo",
    f"{BENCH}/scenes/scene_kodim23.png:photo",
    f"{BENCH}/scenes/scene_b24.png:photo",
    f"{BENCH}/emoji/emoji_red-apple.png:simple",
]
REPO = Path(__file__).resolve().parents[2]
SVG_RENDERERS = ["Chromium", "Firefox ESR", "resvg", "rsvg-convert", "CairoSVG", "Inkscape"]
PDF_RENDERERS = ["pdftoppm", "pdftocairo"]


def run(command, **kwargs):
    return subprocess.run(command, check=True, capture_output=True, **kwargs)


def pixels(png):
    """RGB values 0-255 as floats, alpha composited over white."""
    image = Image.open(png).convert("RGBA")
    white = Image.new("RGBA", image.size, (255, 255, 255, 255))
    return np.asarray(Image.alpha_composite(white, image).convert("RGB")).astype(np.float64)


def difference(png, reference):
    ours = pixels(png)
    if ours.shape != reference.shape:
        raise RuntimeError(f"{png}: {ours.shape[1]}x{ours.shape[0]}, expected {reference.shape[1]}x{reference.shape[0]}")
    d = np.abs(ours - reference)
    return d.mean(), np.percentile(d.max(axis=2), 99)


def render_svg(renderer, svg, png, width, height):
    """One external program's render of `svg` at width x height into `png`."""
    w, h = str(width), str(height)
    if renderer == "resvg":
        run(["resvg", "-w", w, "-h", h, svg, png])
    elif renderer == "rsvg-convert":
        run(["rsvg-convert", "-w", w, "-h", h, "-o", png, svg])
    elif renderer == "CairoSVG":
        run([sys.executable, "-m", "cairosvg", svg, "--output-width", w, "--output-height", h, "-o", png])
    elif renderer == "Inkscape":
        run(["inkscape", "--export-type=png", f"--export-filename={png}", "-w", w, "-h", h, svg])
    else:
        raise ValueError(renderer)


def render_pdf(renderer, pdf, png):
    """poppler's render of `pdf` at 96 dpi into `png` (both tools append the extension)."""
    stem = str(Path(png).with_suffix(""))
    if renderer == "pdftoppm":
        run(["pdftoppm", "-r", "96", "-png", "-singlefile", pdf, stem])
    elif renderer == "pdftocairo":
        run(["pdftocairo", "-r", "96", "-png", "-singlefile", pdf, stem])
    else:
        raise ValueError(renderer)


def browser_renders(browser, svgs, out_dir, width, height):
    """Renders all `svgs` (same size) in one browser session; {svg: png}."""
    out_dir.mkdir(parents=True, exist_ok=True)
    run(["node", str(REPO / "benches/renderers/browsers.mjs"), browser, str(out_dir), str(width), str(height), *map(str, svgs)])
    return {svg: out_dir / f"{Path(svg).stem}.png" for svg in svgs}


def available(renderer):
    executable = {
        "Chromium": "/usr/bin/chromium",
        "Firefox ESR": "/usr/bin/firefox-esr",
        "resvg": "resvg",
        "rsvg-convert": "rsvg-convert",
        "Inkscape": "inkscape",
        "pdftoppm": "pdftoppm",
        "pdftocairo": "pdftocairo",
    }.get(renderer)
    if renderer == "CairoSVG":
        return subprocess.run([sys.executable, "-c", "import cairosvg"], capture_output=True).returncode == 0
    return shutil.which(executable) is not None


def path_count(svg_text):
    return len(re.findall(r"<path\b", svg_text))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("images", nargs="*", default=DEFAULT_IMAGES, help="IMAGE[:photo|simple|auto]")
    parser.add_argument("--covec", default=str(REPO / "target/release/covec"))
    parser.add_argument("--paths", type=int, default=64)
    parser.add_argument("--work", help="keep the files here (default: a temporary directory)")
    args = parser.parse_args()

    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="covec-renderers-"))
    work.mkdir(parents=True, exist_ok=True)
    renderers = {r: available(r) for r in SVG_RENDERERS + PDF_RENDERERS}
    missing = [r for r, ok in renderers.items() if not ok]
    if missing:
        print(f"missing renderers (skipped): {', '.join(missing)}", file=sys.stderr)

    results = []  # (image, output, renderer, mean, p99)
    sizes = []
    for spec in args.images:
        image, _, mode = spec.partition(":")
        mode = mode or "auto"
        name = Path(image).stem
        d = work / name
        d.mkdir(exist_ok=True)
        layered, scene = d / f"{name}.svg", d / f"{name}.json"
        flat, pdf, reference_png = d / f"{name}-flat.svg", d / f"{name}.pdf", d / f"{name}-covec.png"
        run([args.covec, "vectorize", image, "--paths", str(args.paths), "--mode", mode, "--seed", "0", "-o", str(layered)])
        run([args.covec, "render", str(scene), "--flatten", "-o", str(flat)])
        run([args.covec, "render", str(scene), "-o", str(pdf)])
        run([args.covec, "render", str(scene), "-o", str(reference_png)])
        reference = pixels(reference_png)
        height, width = reference.shape[:2]

        svgs = {"layered SVG": layered, "flattened SVG": flat}
        renders = {}  # (output, renderer) -> png
        for browser, key in [("chromium", "Chromium"), ("firefox", "Firefox ESR")]:
            if renderers[key]:
                done = browser_renders(browser, list(svgs.values()), d / browser, width, height)
                for output, svg in svgs.items():
                    renders[(output, key)] = done[svg]
        for renderer in ["resvg", "rsvg-convert", "CairoSVG", "Inkscape"]:
            if renderers[renderer]:
                for output, svg in svgs.items():
                    png = d / f"{svg.stem}-{renderer}.png"
                    render_svg(renderer, str(svg), str(png), width, height)
                    renders[(output, renderer)] = png
        for renderer in PDF_RENDERERS:
            if renderers[renderer]:
                png = d / f"{name}-pdf-{renderer}.png"
                render_pdf(renderer, str(pdf), str(png))
                renders[("PDF", renderer)] = png
        for (output, renderer), png in renders.items():
            mean, p99 = difference(png, reference)
            results.append((name, output, renderer, mean, p99))

        layered_text, flat_text = layered.read_text(), flat.read_text()
        sizes.append(
            (
                name,
                mode,
                len(layered_text.encode()),
                len(gzip.compress(layered_text.encode(), 9)),
                path_count(layered_text),
                len(flat_text.encode()),
                len(gzip.compress(flat_text.encode(), 9)),
                path_count(flat_text),
                pdf.stat().st_size,
            )
        )

    names = [Path(spec.partition(":")[0]).stem for spec in args.images]
    print(f"Mean |Δ| / 99th percentile of the per-pixel largest channel |Δ|, in 1/255, against covec's render of the layered scene ({args.paths} paths):\n")
    print("| output | renderer | " + " | ".join(names) + " |")
    print("|---|---|" + "---|" * len(names))
    for output, output_renderers in [("layered SVG", SVG_RENDERERS), ("flattened SVG", SVG_RENDERERS), ("PDF", PDF_RENDERERS)]:
        for renderer in output_renderers:
            cells = []
            for name in names:
                hit = [r for r in results if r[:3] == (name, output, renderer)]
                cells.append(f"{hit[0][3]:.2f} / {hit[0][4]:.0f}" if hit else "—")
            print(f"| {output} | {renderer} | " + " | ".join(cells) + " |")
    print("\nSizes (bytes; gzip -9 bytes; paths):\n")
    print("| image | mode | layered SVG | gzip | paths | flattened SVG | gzip | paths | flat/layered (gzip) | PDF (deflated) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for n, mode, lb, lg, lp, fb, fg, fp, pb in sizes:
        print(f"| {n} | {mode} | {lb} | {lg} | {lp} | {fb} | {fg} | {fp} | {fb / lb:.1f}× ({fg / lg:.1f}×) | {pb} |")
    if not args.work:
        shutil.rmtree(work)


if __name__ == "__main__":
    main()
