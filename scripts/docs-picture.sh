#!/usr/bin/env bash
# Makes docs/layers.jpg: a photo, its albedo, shade and light layers, covec's SVG and a
# recolour, side by side. `scripts/docs-picture.sh IMAGE X,Y=#rrggbb [covec binary]`: the point
# (in the working size's pixels) picks the albedo path to recolour. The README's picture is
#   scripts/docs-picture.sh coffee.png 128,112=#3a78c8
# on the covec benchmark set's 256² crop of scikit-image's coffee.png (CC0).
set -euo pipefail
image=$1 change=$2 covec=${3:-target/release/covec}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$covec" vectorize "$image" -o "$work/scene.svg" --paths 64 --previews "$work/previews"
"$covec" edit "$work/scene.json" --at "$change" -o "$work/edited.svg" --preview "$work/edited.png"
python3 -c 'import PIL' 2>/dev/null || pip install -q pillow
python3 - "$work" "$image" <<'PY'
import pathlib, sys
from PIL import Image, ImageDraw
work, image = pathlib.Path(sys.argv[1]), sys.argv[2]
previews = work / "previews"
last = lambda suffix: sorted(previews.glob(f"*-polish-{suffix}.png"))[-1]
tiles = [(Image.open(image).convert("RGB"), "photo"), (Image.open(last("albedo")), "albedo"),
         (Image.open(last("shade")), "shade"), (Image.open(last("light")), "light"),
         (Image.open(last("composite")), "SVG"), (Image.open(work / "edited.png"), "recoloured")]
size = 256
sheet = Image.new("RGB", (len(tiles) * (size + 8) - 8, size + 22), "white")
draw = ImageDraw.Draw(sheet)
for i, (tile, label) in enumerate(tiles):
    x = i * (size + 8)
    sheet.paste(tile.convert("RGB").resize((size, size), Image.LANCZOS), (x, 0))
    draw.text((x + size // 2 - 3 * len(label), size + 5), label, fill="black")
sheet.save("docs/layers.jpg", quality=85, optimize=True)
PY
echo "wrote docs/layers.jpg"
