#!/usr/bin/env python3
"""Cornell-type scenes with known layers, for `covec eval --intrinsic`: a tool for measuring, not
part of covec.

    python3 benches/quality/cornell.py OUT_DIR [--venv DIR] [--spp N]
    covec eval --intrinsic OUT_DIR --paths 64 --out cornell.csv

Each scene is rendered with Mitsuba 3 (PyPI `mitsuba`, CPU variant `scalar_rgb`, path tracer,
256², `--spp` samples per pixel, default 256) three times: as it is, with every plastic
replaced by a diffuse surface of the same diffuse reflectance, and with the `aov` integrator's
albedo (diffuse reflectance at the first hit). One folder per scene holds the truth files
covec reads:
- image.png: the full render;
- albedo.png: the albedo AOV;
- shade.png: the diffuse render over the albedo, clamped to [0, 1] per channel;
- light.png: what is left, image − albedo × shade (glossy highlights, and light above white).
All in 8-bit sRGB values: covec composites `albedo × shade + light` in sRGB values, so the truth
is split there too (at Mitsuba's own exposure the walls stay below white). Scenes, after
`mi.cornell_box()` (white walls and boxes of one material, a red and a green wall, a ceiling
light), so one albedo lies under many shades and the side walls bleed colour onto the white:
- cornell: the classic box;
- cornell-spheres: the tall box replaced by a red plastic sphere (highlights), a blue sphere;
- cornell-warm-sky: a warm ceiling light and a bluish light through the front: two light colours;
- cornell-checker: a checkerboard floor (patterned albedo under soft shadows).
The packages go into a venv (default OUT_DIR/.venv) that the script makes and re-runs itself in.
"""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from venvs import enter  # noqa: E402

PACKAGES = ["numpy", "pillow", "mitsuba==3.9.1"]
SIZE = 256


def scenes(mi):
    T = mi.ScalarTransform4f
    rgb = lambda v: {"type": "rgb", "value": v}
    plastic = lambda c: {"type": "roughplastic", "alpha": 0.1, "diffuse_reflectance": rgb(c)}

    def box(changes={}):
        """`mi.cornell_box()` at SIZE², with `changes` made to its dictionary (None: removed)."""
        scene = mi.cornell_box()
        scene["sensor"]["film"]["width"] = scene["sensor"]["film"]["height"] = SIZE
        for key, value in changes.items():
            if value is None:
                scene.pop(key, None)
            else:
                scene[key] = value
        return scene

    spheres = box({
        "large-box": None,
        "red-ball": {"type": "sphere", "center": [-0.35, -0.6, -0.3], "radius": 0.4, "bsdf": plastic([0.7, 0.1, 0.08])},
        "blue-ball": {"type": "sphere", "center": [-0.5, -0.78, 0.45], "radius": 0.22, "bsdf": plastic([0.1, 0.25, 0.7])},
    })
    warm = box()
    warm["light"]["emitter"]["radiance"] = rgb([22.0, 14.0, 7.0])
    warm["sky"] = {"type": "rectangle", "to_world": T().translate([0, 0, 4]).rotate([1, 0, 0], 180).scale(1.2),
                   "emitter": {"type": "area", "radiance": rgb([0.6, 0.9, 1.6])}}
    checker = box()
    checker["floor"]["bsdf"] = {"type": "diffuse", "reflectance": {
        "type": "checkerboard", "color0": rgb([0.8, 0.78, 0.7]), "color1": rgb([0.25, 0.3, 0.45]),
        "to_uv": mi.ScalarTransform4f().scale([4, 4, 1])}}
    return {"cornell": box(), "cornell-spheres": spheres, "cornell-warm-sky": warm, "cornell-checker": checker}


def as_diffuse(scene):
    """The scene with every plastic replaced by a diffuse surface of its diffuse reflectance."""
    out = {}
    for key, value in scene.items():
        if isinstance(value, dict):
            value = as_diffuse(value)
            if value.get("type") in ("plastic", "roughplastic"):
                value = {"type": "diffuse", "reflectance": value["diffuse_reflectance"]}
        out[key] = value
    return out


def main():
    out, args = enter(__doc__, PACKAGES)
    spp = int(args[args.index("--spp") + 1]) if "--spp" in args else 256

    import mitsuba as mi
    import numpy as np
    from PIL import Image

    mi.set_variant("scalar_rgb")
    srgb = lambda x: np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.clip(x, 0, 1), 1 / 2.4) - 0.055)
    save = lambda a, path: Image.fromarray((np.clip(a, 0, 1) * 255 + 0.5).astype(np.uint8)).save(path)

    def render(scene, integrator=None):
        scene = dict(scene)
        scene["sensor"] = dict(scene["sensor"], sampler={"type": "independent", "sample_count": spp})
        if integrator:
            scene["integrator"] = integrator
        return np.array(mi.render(mi.load_dict(scene)))[..., :3]

    for name, scene in scenes(mi).items():
        folder = os.path.join(out, name)
        os.makedirs(folder, exist_ok=True)
        full = srgb(render(scene))
        lambert = srgb(render(as_diffuse(scene)))
        albedo = srgb(render(scene, {"type": "aov", "aovs": "a:albedo"}))
        # 8-bit first, so that the files themselves add up: image = albedo × shade + light.
        full, lambert, albedo = (np.round(np.clip(a, 0, 1) * 255) / 255 for a in (full, lambert, albedo))
        shade = np.clip(np.divide(lambert, albedo, out=np.ones_like(lambert), where=albedo > 0), 0, 1)
        shade = np.round(shade * 255) / 255
        light = np.clip(full - albedo * shade, 0, 1)
        for layer, data in (("image", full), ("albedo", albedo), ("shade", shade), ("light", light)):
            save(data, os.path.join(folder, f"{layer}.png"))
        print(f"{name}: {spp} spp, written to {folder}")


if __name__ == "__main__":
    main()
