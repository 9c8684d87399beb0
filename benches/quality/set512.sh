#!/usr/bin/env bash
# The 512² set of the quality benches: scikit-image's astronaut.png (public domain NASA photo,
# from the scikit-image 0.26.0 wheel on PyPI) and four bench photos upscaled 2× with Pillow's
# Lanczos.   benches/quality/set512.sh BENCH DIR PY   (BENCH: the covec-bench set; DIR: where the
# set goes, made once; PY: a python with pillow)
set -eu
bench=$1; dir=$2; py=$3
[ -f "$dir/astronaut.png" ] && exit 0
mkdir -p "$dir"
pip download -q --no-deps --only-binary=:all: scikit-image==0.26.0 -d "$dir/wheel"
"$py" - "$dir" "$bench" <<'PY'
import glob, sys, zipfile
from PIL import Image
out, bench = sys.argv[1:]
z = zipfile.ZipFile(glob.glob(f"{out}/wheel/scikit_image-*.whl")[0])
open(f"{out}/astronaut.png", "wb").write(z.read("skimage/data/astronaut.png"))
for c, n in [("faces", "face_hopper"), ("faces", "face_kodim04"), ("scenes", "scene_coffee"), ("scenes", "scene_kodim23")]:
    Image.open(f"{bench}/{c}/{n}.png").convert("RGB").resize((512, 512), Image.LANCZOS).save(f"{out}/{n}_512.png")
PY
rm -r "$dir/wheel"
