#!/usr/bin/env python3
"""The field set: varied images nobody tuned on, split once into a tuning half and a held-out
half (a tool for measuring, not part of covec).

    python3 benches/field/field_set.py OUT_DIR --bench BENCH [--venv DIR]
    covec eval OUT_DIR/held-out/* --paths 64 --method covec --out held-out.csv
    python3 benches/field/modes.py OUT_DIR held-out.csv      # auto mode per class, misses by name

Writes OUT_DIR/{tuning,held-out}/CLASS/NAME.png, OUT_DIR/faces.txt (skin masks of every face
in the set, for `covec eval --faces`) and checks the images against benches/field/MANIFEST.md,
which it writes with `--manifest` (the manifest is committed: it is the set's definition).

The split rule, fixed once: an image is held out when the first byte of the SHA-256 of its
name (the file stem, UTF-8) is odd. Thresholds and weights are chosen on the tuning half only;
figures are reported on the held-out half as well.

Classes, and the mode `auto` should choose for each:
- photo (photo): the bench's 8 scenes; photographs from scikit-image, scikit-learn and
  matplotlib sample data;
- portrait (photo): the bench's 8 faces, scikit-image's astronaut, matplotlib's Grace Hopper,
  and each bench face pasted small (120-220 px) into a 512² photo;
- product (photo): objects on a white sweep rendered with Mitsuba 3 and exposed so the ground
  clips to white; photographed objects cut out onto white;
- render (photo): full-frame Mitsuba renders of lit spheres and boxes with cast shadows and
  highlights on flat-coloured floors and walls, the same pasted small onto white canvases, and
  numpy-shaded spheres on flat backdrops;
- shaded-art (photo): 3D-shaded emoji (npm `@lobehub/fluent-emoji-3d`, MIT);
- flat-art (simple): flat emoji (the bench's 8 Noto emoji, Iconify's Noto, Twemoji, Fluent
  Emoji Flat, Fluent Emoji (colour, with gradients) and OpenMoji sets), logos and icons (Iconify's SVG Logos, Flat Color Icons,
  Streamline Ultimate Color), scikit-image's logo and horse, matplotlib's logo;
- screenshot (simple): charts, a terminal, a dialog, a table and a page drawn with matplotlib
  in its bundled DejaVu fonts.

Every image is at most 512 px on the long side. The packages go into a venv (default
OUT_DIR/.venv) that the script makes and re-runs itself in; npm packages are fetched with
`npm pack` into OUT_DIR/work.
"""
import glob
import hashlib
import io
import json
import os
import random
import re
import shutil
import subprocess
import sys
import tarfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))
from venvs import enter  # noqa: E402

PACKAGES = ["numpy", "pillow", "scikit-image==0.26.0", "scikit-learn==1.9.1", "matplotlib==3.11.2",
            "mitsuba==3.9.1", "resvg-cli==0.44.0"]
MANIFEST = os.path.join(HERE, "MANIFEST.md")
BENCH_FACES = os.path.join(HERE, "..", "quality", "faces.txt")
MODES = {"photo": "photo", "portrait": "photo", "product": "photo", "render": "photo",
         "shaded-art": "photo", "flat-art": "simple", "screenshot": "simple"}
MAX_SIDE = 512


def split_of(name):
    """The fixed split rule (module documentation)."""
    return "held-out" if hashlib.sha256(name.encode()).digest()[0] & 1 else "tuning"


class FieldSet:
    """Collects the images: each saved once, with its class, source and licence."""

    def __init__(self, out):
        self.out = out
        self.entries = []
        self.faces = []

    def add(self, name, cls, image, source, licence):
        from PIL import Image

        assert cls in MODES, cls
        assert re.fullmatch(r"[a-z0-9_-]+", name), name
        assert name not in {e[0] for e in self.entries}, f"{name} twice"
        if max(image.size) > MAX_SIDE:
            scale = MAX_SIDE / max(image.size)
            image = image.resize((round(image.width * scale), round(image.height * scale)), Image.LANCZOS)
        folder = os.path.join(self.out, split_of(name), cls)
        os.makedirs(folder, exist_ok=True)
        image.save(os.path.join(folder, f"{name}.png"))
        self.entries.append((name, cls, image.size, source, licence))

    def face(self, name, lines):
        """Skin mask lines (faces.txt format) for image `name`."""
        self.faces.append((name, lines))


def npm_package(work, spec):
    """The unpacked `package/` folder of an npm package, fetched once with `npm pack`."""
    folder = os.path.join(work, re.sub(r"[^a-z0-9.-]+", "_", spec.lower()))
    if not os.path.exists(os.path.join(folder, "package", "package.json")):
        os.makedirs(folder, exist_ok=True)
        subprocess.check_call(["npm", "pack", "-q", spec], cwd=folder, stdout=subprocess.DEVNULL)
        with tarfile.open(glob.glob(os.path.join(folder, "*.tgz"))[0]) as tar:
            tar.extractall(folder, filter="data")
    return os.path.join(folder, "package")


def site_file(module, *parts):
    import importlib

    return os.path.join(os.path.dirname(importlib.import_module(module).__file__), *parts)


def on_white(image):
    from PIL import Image

    image = image.convert("RGBA")
    white = Image.new("RGBA", image.size, (255, 255, 255, 255))
    white.alpha_composite(image)
    return white.convert("RGB")


# --- photographs and portraits ----------------------------------------------------------------


def bench_images(fs, bench):
    from PIL import Image

    manifest = open(os.path.join(bench, "MANIFEST.md")).read()
    for path in sorted(glob.glob(os.path.join(bench, "*", "*.png"))):
        stem = os.path.splitext(os.path.basename(path))[0]
        folder = os.path.basename(os.path.dirname(path))
        cls = {"faces": "portrait", "scenes": "photo", "emoji": "flat-art"}[folder]
        row = next(line for line in manifest.splitlines() if f"{folder}/{stem}.png" in line)
        licence = row.rstrip(" |").rsplit("|", 1)[1].strip()
        fs.add(stem, cls, Image.open(path).convert("RGB"), f"covec-bench {folder}/{stem}.png", licence)


def registry_photos(fs):
    from PIL import Image

    sk = lambda f: site_file("skimage", "data", f)
    photos = [
        ("sk_rocket", sk("rocket.jpg"), "scikit-image 0.26.0 data/rocket.jpg", "Public domain (SpaceX)"),
        ("sk_motorcycle", sk("motorcycle_left.png"), "scikit-image 0.26.0 data/motorcycle_left.png",
         "Middlebury stereo data (scikit-image docstring: free to use with a citation of Scharstein et al. 2014)"),
        ("sk_retina", sk("retina.jpg"), "scikit-image 0.26.0 data/retina.jpg", "CC0 (Mikael Häggström, Wikimedia)"),
        ("sk_ihc", sk("ihc.png"), "scikit-image 0.26.0 data/ihc.png", "No known copyright restrictions"),
        ("sk_hubble", sk("hubble_deep_field.jpg"), "scikit-image 0.26.0 data/hubble_deep_field.jpg",
         "Public domain (NASA/ESA)"),
        ("sk_camera", sk("camera.png"), "scikit-image 0.26.0 data/camera.png", "CC0 (Lav Varshney)"),
        ("sk_coins", sk("coins.png"), "scikit-image 0.26.0 data/coins.png", "Public domain (Brooklyn Museum)"),
        ("sk_brick", sk("brick.png"), "scikit-image 0.26.0 data/brick.png", "CC0 (CC0Textures)"),
        ("sk_gravel", sk("gravel.png"), "scikit-image 0.26.0 data/gravel.png", "CC0 (CC0Textures)"),
        ("skl_china", site_file("sklearn", "datasets", "images", "china.jpg"),
         "scikit-learn 1.9.1 datasets/images/china.jpg", "CC BY 2.0 (danielbuechele, Flickr)"),
        ("skl_flower", site_file("sklearn", "datasets", "images", "flower.jpg"),
         "scikit-learn 1.9.1 datasets/images/flower.jpg", "CC BY 2.0 (vultilion, Flickr)"),
    ]
    for name, path, source, licence in photos:
        fs.add(name, "photo", Image.open(path).convert("RGB"), source, licence)
    # Two crops of the larger photos, each its own picture.
    china = Image.open(site_file("sklearn", "datasets", "images", "china.jpg")).convert("RGB")
    fs.add("skl_china_roof", "photo", china.crop((300, 60, 556, 316)),
           "scikit-learn 1.9.1 datasets/images/china.jpg, crop (300, 60, 556, 316)", "CC BY 2.0 (danielbuechele, Flickr)")
    rocket = Image.open(sk("rocket.jpg")).convert("RGB")
    fs.add("sk_rocket_pad", "photo", rocket.crop((200, 120, 456, 376)),
           "scikit-image 0.26.0 data/rocket.jpg, crop (200, 120, 456, 376)", "Public domain (SpaceX)")


def portraits(fs, bench):
    from PIL import Image

    fs.add("sk_astronaut", "portrait", Image.open(site_file("skimage", "data", "astronaut.png")).convert("RGB"),
           "scikit-image 0.26.0 data/astronaut.png", "Public domain (NASA)")
    fs.face("sk_astronaut", ["as face_astronaut 110 0 240"])
    hopper = Image.open(site_file("matplotlib", "mpl-data", "sample_data", "grace_hopper.jpg")).convert("RGB")
    fs.add("mpl_grace_hopper", "portrait", hopper, "matplotlib 3.11.2 mpl-data/sample_data/grace_hopper.jpg",
           "Public domain (US Navy)")
    # The bench's face_hopper is the crop (65, 15, 475, 425) of this one.
    fs.face("mpl_grace_hopper", ["as face_hopper 65 15 410"])
    # Each bench face pasted small into a 512² photo: the backdrop, size and place drawn at random.
    rng = random.Random(11)
    backdrops = [("scene", p) for p in sorted(glob.glob(os.path.join(bench, "scenes", "*.png")))]
    backdrops += [("sk", site_file("skimage", "data", "rocket.jpg")),
                  ("skl", site_file("sklearn", "datasets", "images", "china.jpg")),
                  ("skl", site_file("sklearn", "datasets", "images", "flower.jpg"))]
    for face in sorted(glob.glob(os.path.join(bench, "faces", "*.png"))):
        stem = os.path.splitext(os.path.basename(face))[0]
        kind, backdrop = rng.choice(backdrops)
        bstem = os.path.splitext(os.path.basename(backdrop))[0]
        size = rng.randrange(120, 221, 4)
        x, y = rng.randrange(0, 512 - size), rng.randrange(0, 512 - size)
        image = Image.open(backdrop).convert("RGB")
        side = min(image.size)
        left, top = (image.width - side) // 2, (image.height - side) // 2
        image = image.crop((left, top, left + side, top + side)).resize((512, 512), Image.LANCZOS)
        image.paste(Image.open(face).convert("RGB").resize((size, size), Image.LANCZOS), (x, y))
        name = f"paste_{stem.removeprefix('face_')}_{bstem.removeprefix('scene_')}"
        fs.add(name, "portrait", image,
               f"covec-bench faces/{stem}.png at {size} px, (x, y) = ({x}, {y}), into the centre square of "
               f"{bstem} ({kind}) resized to 512²", "as both sources")
        fs.face(name, [f"as {stem} {x} {y} {size}"])


# --- renders ----------------------------------------------------------------------------------


def mitsuba_renders(fs):
    import mitsuba as mi
    import numpy as np
    from PIL import Image

    mi.set_variant("scalar_rgb")
    T = mi.ScalarTransform4f
    rgb = lambda v: {"type": "rgb", "value": list(v)}
    srgb = lambda x: np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.clip(x, 0, 1), 1 / 2.4) - 0.055)
    rng = random.Random(5)

    def colour(saturation=(0.4, 0.9), value=(0.3, 0.8)):
        import colorsys

        return list(colorsys.hsv_to_rgb(rng.random(), rng.uniform(*saturation), rng.uniform(*value)))

    def material(c):
        if rng.random() < 0.6:
            return {"type": "roughplastic", "alpha": rng.uniform(0.05, 0.3), "diffuse_reflectance": rgb(c)}
        return {"type": "diffuse", "reflectance": rgb(c)}

    def objects(count):
        out, placed = {}, []
        for k in range(count):
            for _ in range(50):
                r = rng.uniform(0.3, 0.7)
                x, z = rng.uniform(-1.1, 1.1), rng.uniform(-0.8, 0.8)
                if all((x - px) ** 2 + (z - pz) ** 2 > (r + pr + 0.05) ** 2 for px, pz, pr in placed):
                    break
            placed.append((x, z, r))
            kind = rng.choice(["sphere", "sphere", "cube", "cylinder"])
            if kind == "sphere":
                out[f"o{k}"] = {"type": "sphere", "center": [x, r, z], "radius": r, "bsdf": material(colour())}
            elif kind == "cube":
                out[f"o{k}"] = {"type": "cube", "bsdf": material(colour()),
                                "to_world": T().translate([x, r * 0.8, z]).rotate([0, 1, 0], rng.uniform(0, 90)).scale(r * 0.8)}
            else:
                bsdf = material(colour())
                out[f"o{k}"] = {"type": "cylinder", "p0": [x, 0, z], "p1": [x, 2 * r, z], "radius": r * 0.7,
                                "bsdf": bsdf}
                out[f"o{k}cap"] = {"type": "disk", "bsdf": bsdf,
                                   "to_world": T().translate([x, 2 * r, z]).rotate([1, 0, 0], -90).scale(r * 0.7)}
        return out

    def render(scene, exposure):
        image = np.array(mi.render(mi.load_dict(scene)))[..., :3] * exposure
        return Image.fromarray((srgb(image) * 255 + 0.5).astype(np.uint8))

    def base(width, height, floor, wall, light, camera):
        return {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 6},
            "sensor": {"type": "perspective", "fov": 40,
                       "to_world": T().look_at(origin=camera, target=[0, 0.4, 0], up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "gaussian"}},
                       "sampler": {"type": "independent", "sample_count": 96}},
            "floor": {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90).scale(30),
                      "bsdf": {"type": "diffuse", "reflectance": rgb(floor)}},
            "wall": {"type": "rectangle", "to_world": T().translate([0, 0, -2.5]).scale(30),
                     "bsdf": {"type": "diffuse", "reflectance": rgb(wall)}},
            **light,
        }

    def lights():
        """A small bright light for crisp cast shadows and highlights, and a dim surround."""
        origin = [rng.uniform(-4, 4), rng.uniform(3, 6), rng.uniform(1, 4)]
        warm = rng.uniform(0.85, 1.0)
        return {
            "key": {"type": "rectangle", "to_world": T().look_at(origin=origin, target=[0, 0, 0], up=[0, 1, 0]).scale(
                rng.uniform(0.3, 0.9)), "emitter": {"type": "area", "radiance": rgb([40, 40 * warm, 40 * warm ** 2])}},
            "env": {"type": "constant", "radiance": rgb([rng.uniform(0.03, 0.12)] * 3)},
        }

    # Full frame: flat-coloured floor and wall, 1-4 objects.
    for k in range(10):
        floor, wall = colour((0.1, 0.6), (0.4, 0.9)), colour((0.1, 0.6), (0.4, 0.9))
        scene = {**base(320, 256, floor, wall, lights(), [0, 1.8, 4.4]), **objects(rng.choice([1, 2, 3, 4]))}
        image = render(scene, rng.uniform(0.7, 1.1))
        fs.add(f"render_room_{k:02d}", "render", image, f"Mitsuba 3.9.1 (scalar_rgb, 96 spp), seed 5 scene {k}",
               "CC0 (made by this script)")
        if k < 4:
            canvas = Image.new("RGB", (512, 512), (255, 255, 255))
            small = image.resize((200, 160), Image.LANCZOS)
            canvas.paste(small, (rng.randrange(20, 290), rng.randrange(20, 330)))
            fs.add(f"render_room_{k:02d}_small", "render", canvas,
                   f"render_room_{k:02d} at 200×160 px on a white 512² canvas", "CC0 (made by this script)")
    # Products: objects on a white sweep, the ground exposed to clip to white.
    for k in range(8):
        white = [0.95, 0.95, 0.95]
        light = {
            "key": {"type": "rectangle", "to_world": T().look_at(origin=[rng.uniform(-3, 3), 5, 4], target=[0, 0, 0],
                                                                  up=[0, 1, 0]).scale(2.0),
                    "emitter": {"type": "area", "radiance": rgb([9, 9, 9])}},
            "env": {"type": "constant", "radiance": rgb([0.25] * 3)},
        }
        scene = {**base(256, 256, white, white, light, [0, 1.4, 3.6]), **objects(rng.choice([1, 1, 2, 3]))}
        fs.add(f"product_render_{k:02d}", "product", render(scene, rng.uniform(1.5, 1.8)),
               f"Mitsuba 3.9.1 (scalar_rgb, 96 spp), seed 5 product {k}", "CC0 (made by this script)")


def numpy_spheres(fs):
    """Lit spheres (Lambert + Blinn-Phong, 4×4 supersampled, no noise) on flat backdrops."""
    import numpy as np
    from PIL import Image

    rng = random.Random(3)
    for k in range(18):
        size, ss = 256, 4
        n = size * ss
        ys, xs = np.mgrid[0:n, 0:n] + 0.5
        x, y = xs / n * 2 - 1, 1 - ys / n * 2
        img = np.zeros((n, n, 3))
        img[:] = [rng.uniform(0, 1) for _ in range(3)]
        depth = np.full((n, n), np.inf)
        light = np.array([rng.uniform(-1, 1), rng.uniform(0.2, 1), 1.0])
        light /= np.linalg.norm(light)
        half = (light + [0, 0, 1]) / np.linalg.norm(light + [0, 0, 1])
        ambient, spec = rng.uniform(0.05, 0.3), rng.uniform(0.1, 0.5)
        for _ in range(rng.choice([1, 2, 3])):
            cx, cy, r = rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(0.2, 0.5)
            c0 = np.array([rng.uniform(0.1, 0.95) for _ in range(3)])
            d2 = (x - cx) ** 2 + (y - cy) ** 2
            z = np.sqrt(np.clip(r * r - d2, 0, None))
            normal = np.stack([(x - cx) / r, (y - cy) / r, z / r], -1)
            lit = np.clip(normal @ light, 0, None)
            c = c0 * (ambient + (1 - ambient) * lit)[..., None] + spec * (np.clip(normal @ half, 0, None) ** 40)[..., None]
            sel = (d2 < r * r) & (-z < depth)
            img[sel], depth[sel] = c[sel], -z[sel]
        img = np.clip(img, 0, 1).reshape(size, ss, size, ss, 3).mean((1, 3))
        fs.add(f"spheres_{k:02d}", "render", Image.fromarray((img * 255 + 0.5).astype(np.uint8)),
               "numpy-shaded spheres, seed 3", "CC0 (made by this script)")


def cutouts(fs):
    """Photographed objects cut out by hand onto white."""
    import numpy as np
    from PIL import Image, ImageDraw

    coffee = Image.open(site_file("skimage", "data", "coffee.png")).convert("RGB")
    mask = Image.new("L", coffee.size, 0)
    draw = ImageDraw.Draw(mask)
    draw.ellipse([74, 90, 480, 388], fill=255)
    draw.ellipse([172, 15, 408, 205], fill=255)
    draw.polygon([(398, 72), (412, 66), (424, 80), (392, 240), (378, 236)], fill=255)
    k = np.asarray(mask)[..., None] / 255.0
    cut = np.asarray(coffee).astype(float) * k + 255 * (1 - k)
    fs.add("cutout_coffee", "product", Image.fromarray(cut.astype(np.uint8)).crop((40, 0, 560, 400)),
           "scikit-image 0.26.0 data/coffee.png, cup and saucer cut out by hand onto white", "CC0 (Rachel Michetti)")
    present = Image.open(site_file("matplotlib", "mpl-data", "sample_data", "Minduka_Present_Blue_Pack.png"))
    fs.add("mpl_present", "product", on_white(present).resize((256, 256), Image.LANCZOS),
           "matplotlib 3.11.2 mpl-data/sample_data/Minduka_Present_Blue_Pack.png over white",
           "CC0 (Minduka, openclipart; matplotlib's sample data)")


# --- artwork ----------------------------------------------------------------------------------


def fluent_3d(fs, work):
    from PIL import Image

    package = npm_package(work, "@lobehub/fluent-emoji-3d@1.1.0")
    files = sorted(glob.glob(os.path.join(package, "assets", "*.webp")))
    rng = random.Random(17)
    for k, path in enumerate(rng.sample(files, 20)):
        stem = os.path.splitext(os.path.basename(path))[0]
        image = Image.open(path).convert("RGBA").resize((256, 256), Image.LANCZOS)
        if k % 4 == 3:
            # A quarter on a flat coloured ground, as stickers on a slide.
            ground = Image.new("RGBA", image.size, tuple(rng.randrange(60, 230) for _ in range(3)) + (255,))
            ground.alpha_composite(image)
            image = ground.convert("RGB")
        else:
            image = on_white(image)
        fs.add(f"fluent3d_{stem}", "shaded-art", image, f"npm @lobehub/fluent-emoji-3d 1.1.0 assets/{stem}.webp",
               "MIT (Microsoft Fluent Emoji, packaged by LobeHub)")


ICON_SETS = [
    # (npm package, version, name prefix, count, licence)
    ("noto", "1.2.9", "noto", 12, "Apache-2.0 (Google Noto Emoji)"),
    ("fluent-emoji", "1.2.7", "fluentcolor", 8, "MIT (Microsoft Fluent Emoji, colour style)"),
    ("twemoji", "1.2.5", "twemoji", 8, "CC BY 4.0 (Twitter Twemoji)"),
    ("fluent-emoji-flat", "1.2.6", "fluentflat", 8, "MIT (Microsoft Fluent Emoji)"),
    ("openmoji", "1.2.29", "openmoji", 6, "CC BY-SA 4.0 (OpenMoji)"),
    ("logos", "1.2.19", "logo", 8, "CC0-1.0 (SVG Logos, Gil Barbara)"),
    ("flat-color-icons", "1.2.3", "flaticon", 6, "MIT (Icons8 Flat Color Icons)"),
    ("streamline-ultimate-color", "1.2.2", "streamline", 4, "CC BY 4.0 (Streamline)"),
]


def icon_sets(fs, work):
    from PIL import Image

    resvg = os.path.join(os.path.dirname(sys.executable), "resvg")
    for package, version, prefix, count, licence in ICON_SETS:
        data = json.load(open(os.path.join(npm_package(work, f"@iconify-json/{package}@{version}"), "icons.json")))
        names = sorted(data["icons"])
        random.Random(f"{prefix}-23").shuffle(names)
        for name in names[:count]:
            icon = data["icons"][name]
            w, h = icon.get("width", data.get("width", 16)), icon.get("height", data.get("height", 16))
            svg = os.path.join(work, "svg", f"{prefix}_{name}.svg")
            os.makedirs(os.path.dirname(svg), exist_ok=True)
            with open(svg, "w") as f:
                f.write(f'<svg xmlns="http://www.w3.org/2000/svg" xmlns:xlink="http://www.w3.org/1999/xlink" '
                        f'viewBox="0 0 {w} {h}" width="256" height="256">{icon["body"]}</svg>')
            png = svg[:-4] + ".png"
            subprocess.run([resvg, "-w", "256", "-h", "256", "--background", "white", svg, png], check=True,
                           capture_output=True)
            stem = re.sub(r"[^a-z0-9_-]+", "-", f"{prefix}_{name}".lower())
            fs.add(stem, "flat-art", Image.open(png).convert("RGB"),
                   f"npm @iconify-json/{package} {version} icon '{name}', rendered with resvg 0.44 over white", licence)


def registry_artwork(fs):
    from PIL import Image

    fs.add("sk_logo", "flat-art", on_white(Image.open(site_file("skimage", "data", "logo.png"))),
           "scikit-image 0.26.0 data/logo.png over white", "CC0 (scikit-image logo)")
    fs.add("sk_horse", "flat-art", Image.open(site_file("skimage", "data", "horse.png")).convert("RGB"),
           "scikit-image 0.26.0 data/horse.png", "CC0 (Andreas Preuss, openclipart)")
    fs.add("mpl_logo", "flat-art",
           on_white(Image.open(site_file("matplotlib", "mpl-data", "sample_data", "logo2.png"))),
           "matplotlib 3.11.2 mpl-data/sample_data/logo2.png over white", "Matplotlib licence (PSF-based)")


def screenshots(fs):
    """Flat screens drawn with matplotlib (Agg, its bundled DejaVu fonts): made here, CC0."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from PIL import Image

    def save(fig, name, what):
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=100)
        plt.close(fig)
        fs.add(name, "screenshot", Image.open(buffer).convert("RGB"), f"matplotlib 3.11.2: {what}",
               "CC0 (made by this script)")

    rng = np.random.default_rng(1)
    fig, ax = plt.subplots(figsize=(4.8, 3.6))
    for k in range(3):
        ax.plot(np.cumsum(rng.normal(size=60)), label=f"series {k + 1}")
    ax.legend(), ax.set_title("Weekly load"), ax.grid(True)
    save(fig, "screen_line_chart", "a line chart")
    fig, ax = plt.subplots(figsize=(4.8, 3.6))
    ax.bar(["north", "east", "south", "west"], [12, 7, 15, 4], color=["#4c72b0", "#dd8452", "#55a868", "#c44e52"])
    ax.set_ylabel("orders")
    save(fig, "screen_bar_chart", "a bar chart")
    fig, ax = plt.subplots(figsize=(3.6, 3.6))
    ax.pie([35, 25, 20, 20], labels=["A", "B", "C", "D"], autopct="%1.0f%%")
    save(fig, "screen_pie_chart", "a pie chart")
    # A terminal.
    fig = plt.figure(figsize=(5.12, 3.2), facecolor="#1e1e1e")
    lines = ["$ covec vectorize photo.jpg --paths 64", "decompose  ok  0.05 s", "init       ok  0.02 s",
             "structure  ok  0.21 s", "reconstruct ok 0.18 s", "refine     ok  0.40 s", "wrote photo.svg (18.4 KB)", "$ _"]
    for k, line in enumerate(lines):
        fig.text(0.03, 0.92 - k * 0.11, line, family="DejaVu Sans Mono", fontsize=10,
                 color="#9cdcfe" if line.startswith("$") else "#d4d4d4")
    save(fig, "screen_terminal", "a terminal")
    # A dialog.
    fig = plt.figure(figsize=(4.0, 3.0), facecolor="#f3f3f3")
    fig.patches.append(plt.Rectangle((0, 0.86), 1, 0.14, transform=fig.transFigure, color="#2b579a"))
    fig.text(0.04, 0.9, "Export settings", color="white", fontsize=11)
    for k, label in enumerate(["Width", "Height", "Quality"]):
        fig.text(0.06, 0.7 - k * 0.15, label, fontsize=10)
        fig.patches.append(plt.Rectangle((0.4, 0.67 - k * 0.15), 0.5, 0.09, transform=fig.transFigure,
                                         facecolor="white", edgecolor="#8a8a8a"))
        fig.text(0.42, 0.695 - k * 0.15, ["1920", "1080", "high"][k], fontsize=9)
    for k, (label, colour) in enumerate([("Cancel", "#e1e1e1"), ("Export", "#2b579a")]):
        fig.patches.append(plt.Rectangle((0.42 + k * 0.28, 0.06), 0.24, 0.11, transform=fig.transFigure, color=colour))
        fig.text(0.46 + k * 0.28, 0.095, label, fontsize=9, color="white" if k else "black")
    save(fig, "screen_dialog", "a dialog")
    # A table.
    fig, ax = plt.subplots(figsize=(4.8, 2.6))
    ax.axis("off")
    table = ax.table(cellText=[[f"{r}{c}" if c else f"row {r}" for c in range(4)] for r in range(1, 7)],
                     colLabels=["name", "min", "mean", "max"], loc="center")
    for (r, _), cell in table.get_celld().items():
        cell.set_facecolor("#dae3f3" if r == 0 else ("#ffffff" if r % 2 else "#f2f2f2"))
    save(fig, "screen_table", "a table")
    # A page: heading, text, a flat banner.
    fig = plt.figure(figsize=(4.0, 5.0), facecolor="white")
    fig.patches.append(plt.Rectangle((0, 0.8), 1, 0.2, transform=fig.transFigure, color="#ff7043"))
    fig.text(0.06, 0.87, "covec", fontsize=22, color="white", weight="bold")
    for k in range(12):
        fig.text(0.06, 0.72 - k * 0.05, " ".join(["lorem", "ipsum", "dolor", "sit", "amet"][: 2 + k % 4]) * 2,
                 fontsize=8, color="#333333")
    save(fig, "screen_page", "a web page")


# --- the manifest -----------------------------------------------------------------------------


def manifest_text(fs):
    rows = sorted(fs.entries)
    count = lambda split: sum(split_of(r[0]) == split for r in rows)
    lines = [
        "# The field set",
        "",
        "Made by `benches/field/field_set.py` (its documentation says how and from what); this file",
        "is the set's definition, and the script checks what it makes against it. Split rule, fixed",
        "once: an image is held out when the first byte of the SHA-256 of its name is odd.",
        "",
        f"{len(rows)} images: {count('tuning')} tuning, {count('held-out')} held out.",
        "",
        "| class | auto should choose | tuning | held out |",
        "|---|---|---|---|",
    ]
    for cls, mode in MODES.items():
        n = lambda split: sum(r[1] == cls and split_of(r[0]) == split for r in rows)
        lines.append(f"| {cls} | {mode} | {n('tuning')} | {n('held-out')} |")
    lines += ["", "| name | class | split | size | source | licence |", "|---|---|---|---|---|---|"]
    for name, cls, (w, h), source, licence in rows:
        lines.append(f"| {name} | {cls} | {split_of(name)} | {w}×{h} | {source} | {licence} |")
    return "\n".join(lines) + "\n"


def faces_text(fs):
    """The field's skin masks: the bench faces' drawings, then each of the set's other faces."""
    bench = open(BENCH_FACES).read()
    blocks = re.split(r"\n(?=face )", bench)
    lines = ["# Skin masks of the field set's faces (made by benches/field/field_set.py).", ""]
    lines += [b.strip() for b in blocks if re.match(r"face face_\w+ 256 256", b.strip())]
    for name, shapes in fs.faces:
        w, h = next(e[2] for e in fs.entries if e[0] == name)
        lines += ["", f"face {name} {w} {h}", *shapes]
    return "\n".join(lines) + "\n"


def main():
    out, args = enter(__doc__, PACKAGES)
    if "--bench" not in args:
        sys.exit("field_set.py: --bench BENCH (the covec-bench folder) is required")
    bench = args[args.index("--bench") + 1]
    for split in ("tuning", "held-out"):
        shutil.rmtree(os.path.join(out, split), ignore_errors=True)
    work = os.path.join(out, "work")
    os.makedirs(work, exist_ok=True)
    fs = FieldSet(out)
    bench_images(fs, bench)
    registry_photos(fs)
    portraits(fs, bench)
    mitsuba_renders(fs)
    numpy_spheres(fs)
    cutouts(fs)
    fluent_3d(fs, work)
    icon_sets(fs, work)
    registry_artwork(fs)
    screenshots(fs)
    with open(os.path.join(out, "faces.txt"), "w") as f:
        f.write(faces_text(fs))
    text = manifest_text(fs)
    if "--manifest" in args:
        with open(MANIFEST, "w") as f:
            f.write(text)
    elif not os.path.exists(MANIFEST) or open(MANIFEST).read() != text:
        sys.exit(f"field_set.py: the images made differ from {MANIFEST} (run with --manifest to rewrite it, "
                 "and commit it only if the set is meant to change)")
    print(f"{len(fs.entries)} images in {out}")


if __name__ == "__main__":
    main()
