#!/usr/bin/env python3
"""The image set `auto` mode is checked on: a tool for measuring, not part of covec.

    python3 benches/quality/auto_mode.py OUT_DIR [--venv DIR]
    covec eval OUT_DIR/photo OUT_DIR/artwork --paths 16 --method covec --iteration-scale 0.01 --out modes.csv

`photo/` should all resolve to photo mode, `artwork/` to simple mode (the CSV's `mode` and
`mode_reason` columns; the iterations hardly matter for the choice, which is made first). Made
here, all 256 px on the long side:
- photo/spheres-*.png (4): lit spheres (Lambert + Blinn-Phong, ambient 0.12, 4×4 supersampled,
  no noise) on flat grey, blue, white and black backdrops;
- photo/product-render-*.png (2): coloured objects on a white sweep lit by an area light,
  rendered with Mitsuba 3 (PyPI `mitsuba`, 64 samples per pixel) and exposed so the background
  clips to white;
- photo/product-coffee.png: scikit-image's coffee photo (CC0, Rachel Michetti) with cup and
  saucer cut out by hand (ellipses and a polygon) onto clipped white;
- artwork/logo_skimage.png: scikit-image's logo over white;
- artwork/emoji_*.png (60), artwork/logo_*.png (40): icons drawn at random (seed 7) from the
  Iconify JSON sets `@iconify-json/noto` 1.2.9 (Noto Emoji, Apache-2.0) and
  `@iconify-json/logos` 1.2.19 (SVG Logos, CC0-1.0), fetched with `npm pack` and rendered with
  resvg (PyPI `resvg-cli`) over white.
Add the covec-bench emoji (artwork) and photos (photo) from the bench itself. The packages go
into a venv (default OUT_DIR/.venv) that the script makes and re-runs itself in.
"""
import glob
import json
import os
import random
import subprocess
import sys
import tarfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from venvs import enter  # noqa: E402

PACKAGES = ["numpy", "pillow", "scikit-image==0.26.0", "mitsuba==3.9.1", "resvg-cli==0.44.0"]


def spheres(out):
    import numpy as np
    from PIL import Image

    def render(size, backdrop, objects, light, ss=4, spec=0.4, ambient=0.12):
        n = size * ss
        ys, xs = np.mgrid[0:n, 0:n] + 0.5
        x, y = xs / n * 2 - 1, 1 - ys / n * 2
        img = np.zeros((n, n, 3))
        img[:] = backdrop
        depth = np.full((n, n), np.inf)
        light = np.array(light, float) / np.linalg.norm(light)
        half = (light + [0, 0, 1]) / np.linalg.norm(light + [0, 0, 1])
        for cx, cy, r, colour in objects:
            d2 = (x - cx) ** 2 + (y - cy) ** 2
            z = np.sqrt(np.clip(r * r - d2, 0, None))
            normal = np.stack([(x - cx) / r, (y - cy) / r, z / r], -1)
            lit = np.clip(normal @ light, 0, None)
            c = np.array(colour) * (ambient + (1 - ambient) * lit)[..., None] \
                + spec * (np.clip(normal @ half, 0, None) ** 40)[..., None]
            sel = (d2 < r * r) & (-z < depth)
            img[sel], depth[sel] = c[sel], -z[sel]
        img = np.clip(img, 0, 1).reshape(size, ss, size, ss, 3).mean((1, 3))
        return Image.fromarray((img * 255 + 0.5).astype(np.uint8))

    sets = {
        "grey": ((0.55, 0.55, 0.58), [(-0.3, -0.1, 0.45, (0.8, 0.2, 0.15)), (0.45, 0.2, 0.3, (0.2, 0.5, 0.85))], (-1, 1, 1.2)),
        "blue": ((0.25, 0.45, 0.75), [(0.0, 0.0, 0.6, (0.9, 0.8, 0.3))], (1, 1, 1)),
        "white": ((1.0, 1.0, 1.0), [(-0.45, -0.3, 0.3, (0.2, 0.7, 0.3)), (0.1, 0.1, 0.35, (0.9, 0.5, 0.1)),
                                    (0.55, -0.35, 0.25, (0.6, 0.3, 0.7))], (-0.5, 1, 1)),
        "black": ((0.05, 0.05, 0.05), [(-0.2, 0.05, 0.5, (0.95, 0.9, 0.85)), (0.55, -0.4, 0.2, (0.85, 0.1, 0.3))], (1, 0.5, 1)),
    }
    for name, (backdrop, objects, light) in sets.items():
        render(256, backdrop, objects, light).save(os.path.join(out, f"spheres-{name}.png"))


def product_renders(out):
    import mitsuba as mi
    import numpy as np
    from PIL import Image

    mi.set_variant("scalar_rgb")
    T = mi.ScalarTransform4f
    rgb = lambda v: {"type": "rgb", "value": v}
    plastic = lambda c: {"type": "roughplastic", "alpha": 0.15, "diffuse_reflectance": rgb(c)}
    srgb = lambda x: np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.clip(x, 0, 1), 1 / 2.4) - 0.055)
    base = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 6},
        "sensor": {"type": "perspective", "fov": 35,
                   "to_world": T().look_at(origin=[0, 1.2, 5], target=[0, 0.4, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 256, "height": 256, "rfilter": {"type": "gaussian"}},
                   "sampler": {"type": "independent", "sample_count": 64}},
        "floor": {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90).scale(20),
                  "bsdf": {"type": "diffuse", "reflectance": rgb([0.9, 0.9, 0.9])}},
        "back": {"type": "rectangle", "to_world": T().translate([0, 0, -3]).scale(20),
                 "bsdf": {"type": "diffuse", "reflectance": rgb([0.9, 0.9, 0.9])}},
        "light": {"type": "rectangle", "to_world": T().look_at(origin=[-2, 5, 4], target=[0, 0, 0], up=[0, 1, 0]).scale(2.0),
                  "emitter": {"type": "area", "radiance": rgb([9, 9, 9])}},
        "env": {"type": "constant", "radiance": rgb([0.25, 0.25, 0.25])},
    }
    scenes = {
        "a": {"ball": {"type": "sphere", "center": [-0.7, 0.5, 0.3], "radius": 0.5, "bsdf": plastic([0.7, 0.08, 0.05])},
              "box": {"type": "cube", "to_world": T().translate([0.7, 0.45, -0.2]).rotate([0, 1, 0], 30).scale(0.45),
                      "bsdf": {"type": "diffuse", "reflectance": rgb([0.1, 0.3, 0.7])}}},
        "b": {"can": {"type": "cylinder", "p0": [0, 0, 0], "p1": [0, 1.3, 0], "radius": 0.45, "bsdf": plastic([0.9, 0.75, 0.1])},
              "ball": {"type": "sphere", "center": [0.9, 0.3, 0.6], "radius": 0.3, "bsdf": plastic([0.1, 0.6, 0.2])}},
    }
    for name, objects in scenes.items():
        image = np.array(mi.render(mi.load_dict({**base, **objects})))[..., :3] * 1.6
        Image.fromarray((srgb(image) * 255 + 0.5).astype(np.uint8)).save(os.path.join(out, f"product-render-{name}.png"))


def skimage_images(photo, artwork):
    import numpy as np
    import skimage
    from PIL import Image, ImageDraw

    data = os.path.join(os.path.dirname(skimage.__file__), "data")
    coffee = Image.open(os.path.join(data, "coffee.png")).convert("RGB")
    mask = Image.new("L", coffee.size, 0)
    draw = ImageDraw.Draw(mask)
    draw.ellipse([74, 90, 480, 388], fill=255)
    draw.ellipse([172, 15, 408, 205], fill=255)
    draw.polygon([(398, 72), (412, 66), (424, 80), (392, 240), (378, 236)], fill=255)
    k = np.asarray(mask)[..., None] / 255.0
    cut = np.asarray(coffee).astype(float) * k + 255 * (1 - k)
    Image.fromarray(cut.astype(np.uint8)).crop((40, 0, 560, 400)).resize((256, 197), Image.LANCZOS) \
        .save(os.path.join(photo, "product-coffee.png"))
    logo = Image.open(os.path.join(data, "logo.png")).convert("RGBA")
    white = Image.new("RGBA", logo.size, (255, 255, 255, 255))
    white.alpha_composite(logo)
    white.convert("RGB").resize((256, 256), Image.LANCZOS).save(os.path.join(artwork, "logo_skimage.png"))


def icons(out, work):
    for package, version, prefix, count in (("noto", "1.2.9", "emoji", 60), ("logos", "1.2.19", "logo", 40)):
        folder = os.path.join(work, package)
        if not os.path.exists(os.path.join(folder, "package", "icons.json")):
            os.makedirs(folder, exist_ok=True)
            subprocess.check_call(["npm", "pack", "-q", f"@iconify-json/{package}@{version}"], cwd=folder,
                                  stdout=subprocess.DEVNULL)
            with tarfile.open(glob.glob(os.path.join(folder, "*.tgz"))[0]) as tar:
                tar.extractall(folder, filter="data")
        data = json.load(open(os.path.join(folder, "package", "icons.json")))
        names = sorted(data["icons"])
        random.Random(7).shuffle(names)
        for name in names[:count]:
            icon = data["icons"][name]
            w, h = icon.get("width", data.get("width", 16)), icon.get("height", data.get("height", 16))
            svg = os.path.join(work, f"{prefix}_{name}.svg")
            with open(svg, "w") as f:
                f.write(f'<svg xmlns="http://www.w3.org/2000/svg" xmlns:xlink="http://www.w3.org/1999/xlink" '
                        f'viewBox="0 0 {w} {h}" width="256" height="256">{icon["body"]}</svg>')
            resvg = os.path.join(os.path.dirname(sys.executable), "resvg")
            subprocess.run([resvg, "-w", "256", "-h", "256", "--background", "white", svg,
                            os.path.join(out, f"{prefix}_{name}.png")], check=False, capture_output=True)


def main():
    out, args = enter(__doc__, PACKAGES)
    photo, artwork, work = (os.path.join(out, d) for d in ("photo", "artwork", "work"))
    for d in (photo, artwork, work):
        os.makedirs(d, exist_ok=True)
    spheres(photo)
    product_renders(photo)
    skimage_images(photo, artwork)
    icons(artwork, work)
    print(f"{len(os.listdir(photo))} photo, {len(os.listdir(artwork))} artwork images in {out}")


if __name__ == "__main__":
    main()
