#!/usr/bin/env python3
"""Gzip bytes per path of covec's layered SVG, and what rounding the coordinates costs.

    scripts/svg-size.py OLD_COVEC NEW_COVEC IMAGE... [--paths 64]

Vectorizes each image with both binaries (the scenes must come out equal; only the SVG writer
should differ), then reports per image the gzip -9 bytes per path of both SVGs and, for the new
one, the error its coordinate rounding adds: its path data is parsed back into the scene (in the
layer groups' grid units, scaled back to pixels; colours and opacities kept at full precision) and both scenes are rendered with `covec render` at the
working size; the table gives the largest and the mean pixel difference between the two renders and both
renders' MSE against the input (resized to the working size). Needs numpy and Pillow. The numbers
are in docs/history.md ("Compact path data").
"""

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

TOKEN = re.compile(r"[MCcZ]|-?(?:\d+\.?\d*|\.\d+)")
PATH = re.compile(r'<path id="(\w+)-(\d+)"[^>]* d="([^"]*)"')
# The layer groups' scale from grid units to pixels (the same on every group; none: pixels).
SCALE = re.compile(r'<g id="\w+"[^>]* transform="scale\(([^)]+)\)"')


def path_points(d):
    """The scene's points of one path (P0, then a, b, end per cubic; the last end is P0 again)."""
    tokens = TOKEN.findall(d)
    command, values, points = None, [], []
    for token in tokens + ["Z"]:
        if token in "MCcZ":
            command = token if token != "Z" else command
            continue
        values.append(float(token))
        if command == "M" and len(values) == 2:
            points.append(values)
            values = []
        elif command in "Cc" and len(values) == 6:
            # Relative offsets are from the current point, the last end point.
            base = points[-1] if command == "c" else [0.0, 0.0]
            points += [[base[0] + values[i], base[1] + values[i + 1]] for i in (0, 2, 4)]
            values = []
    return points[:-1]


def rounded_scene(scene, svg):
    out = json.loads(json.dumps(scene))
    scale = float(m.group(1)) if (m := SCALE.search(svg)) else 1.0
    for layer, index, d in PATH.findall(svg):
        points = [{"x": x * scale, "y": y * scale} for x, y in path_points(d)]
        out[layer]["paths"][int(index)]["points"] = points
    return out


def gzip_bytes(text):
    return len(subprocess.run(["gzip", "-9", "-c"], input=text.encode(), capture_output=True, check=True).stdout)


def render(covec, scene, width, tmp, name):
    scene_path, png_path = tmp / f"{name}.json", tmp / f"{name}.png"
    scene_path.write_text(json.dumps(scene))
    subprocess.run([covec, "render", scene_path, "-o", png_path, "--width", str(width)], check=True)
    return np.asarray(Image.open(png_path).convert("RGB"), dtype=np.float64) / 255


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old")
    parser.add_argument("new")
    parser.add_argument("images", nargs="+")
    parser.add_argument("--paths", default="64")
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="svg-size-"))
    print("image,paths,gzip_per_path_old,gzip_per_path_new,max_abs_diff_255,mean_abs_diff_255,mse_full,mse_rounded")
    totals = []
    for image in args.images:
        name = Path(image).stem
        svgs, scenes = {}, {}
        for which, covec in (("old", args.old), ("new", args.new)):
            svg = tmp / f"{name}-{which}.svg"
            subprocess.run([covec, "vectorize", image, "-o", svg, "--paths", args.paths], check=True)
            svgs[which] = svg.read_text()
            scenes[which] = json.loads(svg.with_suffix(".json").read_text())
        if scenes["old"] != scenes["new"]:
            sys.exit(f"{image}: the two binaries made different scenes")
        scene = scenes["new"]
        paths = sum(len(scene[layer]["paths"]) for layer in ("albedo", "shade", "light"))
        per_path = {w: gzip_bytes(s) / paths for w, s in svgs.items()}
        full = render(args.new, scene, scene["width"], tmp, f"{name}-full")
        rounded = render(args.new, rounded_scene(scene, svgs["new"]), scene["width"], tmp, f"{name}-rounded")
        source = Image.open(image).convert("RGB").resize((scene["width"], scene["height"]), Image.BILINEAR)
        source = np.asarray(source, dtype=np.float64) / 255
        row = (per_path["old"], per_path["new"], np.abs(full - rounded).max() * 255,
               np.abs(full - rounded).mean() * 255,
               ((full - source) ** 2).mean(), ((rounded - source) ** 2).mean())
        totals.append(row)
        print(f"{name},{paths}," + ",".join(f"{v:.6g}" for v in row))
    mean = np.mean(totals, axis=0)
    print(f"mean,," + ",".join(f"{v:.6g}" for v in mean))


if __name__ == "__main__":
    main()
