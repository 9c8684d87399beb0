#!/usr/bin/env python3
"""The 512² faces that faces.txt draws beside the bench's 8 (a tool for measuring, not part of covec).

    python3 benches/quality/face_set.py BENCH OUT

Writes OUT/astronaut.png (scikit-image's astronaut.png, public domain NASA photo, from the
scikit-image 0.26.0 wheel on PyPI, fetched with pip) and two bench faces pasted small into
bench scenes upscaled to 512² (Pillow's Lanczos): paste_obama_chapel.png (face_obama at 200 px)
and paste_hopper_coffee.png (face_hopper at 160 px). Then:

    covec eval BENCH/faces OUT --paths 64 --method covec --faces benches/quality/faces.txt
"""
import glob
import os
import subprocess
import sys
import tempfile
import zipfile

from PIL import Image

# name → (scene, face, x, y, size): the face's 256² crop resized to size, pasted at (x, y);
# faces.txt places the masks the same way.
PASTED = {
    "paste_obama_chapel": ("scene_chapel", "face_obama", 280, 40, 200),
    "paste_hopper_coffee": ("scene_coffee", "face_hopper", 40, 300, 160),
}


def main():
    bench, out = sys.argv[1:3]
    os.makedirs(out, exist_ok=True)
    astronaut = os.path.join(out, "astronaut.png")
    if not os.path.exists(astronaut):
        with tempfile.TemporaryDirectory() as wheel:
            subprocess.check_call([sys.executable, "-m", "pip", "download", "-q", "--no-deps",
                                   "--only-binary=:all:", "scikit-image==0.26.0", "-d", wheel])
            with zipfile.ZipFile(glob.glob(f"{wheel}/scikit_image-*.whl")[0]) as z:
                with open(astronaut, "wb") as f:
                    f.write(z.read("skimage/data/astronaut.png"))
    for name, (scene, face, x, y, size) in PASTED.items():
        image = Image.open(f"{bench}/scenes/{scene}.png").convert("RGB")
        image = image.resize((512, 512), Image.LANCZOS)
        small = Image.open(f"{bench}/faces/{face}.png").convert("RGB")
        image.paste(small.resize((size, size), Image.LANCZOS), (x, y))
        image.save(os.path.join(out, f"{name}.png"))


if __name__ == "__main__":
    main()
