#!/usr/bin/env bash
# Rate-distortion bench: covec at each path count against VTracer's best at equal gzip bytes,
# VTracer 0.6.5 and, with VTRACER1, VTracer 1.0 with its size options.
#   COVEC_BENCH=DIR benches/quality/rd.sh COVEC OUT      (COVEC: a covec binary; DIR: the
#   covec-bench set, which is not part of this repository)
# Environment: PATHS (covec's path counts, default "8 16 32 64 128 256"); SETS (default "256
# 512": the 16 bench photos at 256², the 512² set of bench.sh: scikit-image's astronaut.png
# and four bench photos upscaled 2× with Pillow's Lanczos; "pasted" adds face_set.py's two
# bench faces pasted small into 512² scenes; "emoji" the bench's rocket emoji); VTRACER1 (a
# VTracer 1.0 CLI, `cargo install vtracer-cli@1.0.0-alpha.4`: its points are a second anchor,
# spline with `--simplify 1.5 --optimize 2` and polygon with `--optimize 2` over GRID1); PY (a python with pillow, numpy and
# scikit-image; default: a venv made in OUT).
# Every SVG (covec at each path count; VTracer over a grid of filter_speckle × colour
# precision × gradient step, in spline and in polygon mode) is measured by its `gzip -9n`
# bytes and by the MSE and GMSD of its resvg render over white at the input's size against
# the input (metrics.py). VTracer's best at covec's byte count, for each error separately,
# is the lower convex hull of all its (bytes, error) points, both modes together, linearly
# interpolated; below VTracer's smallest file the smallest file's error is used (marked <),
# above the lowest-error point the lowest error (marked >). On the 11 faces that faces.txt
# draws, the skin is scored too (metrics.py --skin: mean skin colour and mean per-pixel
# CIEDE2000), and VTracer's best per-pixel skin error taken the same way. The staircase, VTracer's best
# error among its files of at most covec's bytes, is in ratios.tsv too. Points are kept per
# image in OUT/pts/, so a run that stops resumes (a new binary or grid needs a new OUT).
# Writes OUT/points.tsv (every point), OUT/ratios.tsv and OUT/ratios.md (covec / VTracer, a
# table per anchor).
# Needs resvg, vtracer, gzip, python3.
set -eu
covec=$1; out=$2; here=$(cd "$(dirname "$0")" && pwd); bench=${COVEC_BENCH:?set COVEC_BENCH to the covec-bench directory}
paths=${PATHS:-8 16 32 64 128 256}; sets=${SETS:-256 512}
mkdir -p "$out/set512" "$out/pts"; py=${PY:-$out/venv/bin/python}
[ -x "$py" ] || { python3 -m venv "$out/venv" && "$out/venv/bin/pip" -q install pillow numpy scikit-image; }
"$py" "$here/metrics.py" --check "$here/../../tests/fixtures"
if [[ " $sets " == *" 512 "* ]]; then "$here/set512.sh" "$bench" "$out/set512" "$py"; fi
if [[ " $sets " == *" pasted "* ]]; then [ -f "$out/faceset/astronaut.png" ] || "$py" "$here/face_set.py" "$bench" "$out/faceset"; fi
"$covec" eval --faces "$here/faces.txt" --write-masks "$out/masks" 2>/dev/null
# VTracer's grid, "filter_speckle colour_precision gradient_step" a line, run in both modes:
# from a few hundred gzip bytes (polygon, 8 bits, step 128) to about 100 kB at 256² (spline,
# 8 bits, 1 px, step 4). Mostly 8 bits: below 8 VTracer truncates the fills, and on
# scene_chapel 6 and 7 bits stay above twice the MSE of 8 at any size.
grid=${GRID:-"16 8 128
16 8 64
16 8 32
16 8 16
8 8 64
8 8 32
8 8 16
4 8 64
4 8 32
4 8 16
4 8 8
2 8 32
2 8 16
2 8 8
1 8 8
1 8 4
8 7 32
2 7 16
16 6 64
8 6 32
4 6 16
2 6 8
16 4 32
4 4 32
16 3 64
4 3 32"}
# VTracer 1.0's grid: its size options make speckle filtering the main size control (-f 4-64).
grid1=${GRID1:-"64 8 64
32 8 64
32 8 32
16 8 32
16 8 16
8 8 32
8 8 16
8 8 8
4 8 16
4 8 8
4 8 4
16 6 32
4 6 16"}
vtracer1=${VTRACER1:-}
one() {  # one SET IMG: every point of one image -> OUT/pts/SET_NAME.tsv
  local size=$1 img=$2 n w h d svgs=() rows=() tag i skin=() pad=$'\t\t'
  n=$(basename "$img" .png); [ -s "$out/pts/${size}_$n.tsv" ] && return
  d=$out/svg/${size}_$n; mkdir -p "$d"
  read -r w h < <("$py" -c "from PIL import Image; print(*Image.open('$img').size)")
  for p in $paths; do
    "$covec" vectorize "$img" -o "$d/covec_$p.svg" --paths "$p" </dev/null >/dev/null
    svgs+=("$d/covec_$p.svg"); rows+=("covec	-	paths=$p")
  done
  for mode in spline polygon; do
    while read -r f c g; do
      tag=f${f}_p${c}_g$g
      vtracer -i "$img" -o "$d/vt_${mode}_$tag.svg" --mode "$mode" -f "$f" -p "$c" -g "$g" >/dev/null
      svgs+=("$d/vt_${mode}_$tag.svg"); rows+=("vtracer	$mode	$tag")
    done <<< "$grid"
    [ -n "$vtracer1" ] || continue
    local size_options=(--optimize 2); [ "$mode" = spline ] && size_options+=(--simplify 1.5)
    while read -r f c g; do
      tag=f${f}_p${c}_g$g
      "$vtracer1" -i "$img" -o "$d/vt1_${mode}_$tag.svg" --mode "$mode" -f "$f" -p "$c" -g "$g" "${size_options[@]}" >/dev/null
      svgs+=("$d/vt1_${mode}_$tag.svg"); rows+=("vtracer1	$mode	$tag")
    done <<< "$grid1"
  done
  for s in "${svgs[@]}"; do resvg -w "$w" -h "$h" "$s" "${s%.svg}.png"; done
  [ -f "$out/masks/$n.png" ] && { skin=(--skin "$out/masks/$n.png"); pad=; }
  mapfile -t errs < <("$py" "$here/metrics.py" "${skin[@]}" "$img" "${svgs[@]/%.svg/.png}")
  [ "${#errs[@]}" = "${#svgs[@]}" ] || { echo "metrics.py failed on $img" >&2; exit 1; }
  : > "$out/pts/${size}_$n.tmp"
  for i in "${!svgs[@]}"; do
    printf '%s\t%s\t%s\t%s\t%s\t%s%s\n' "$n" "$size" "${rows[$i]}" "$(grep -o '<path' "${svgs[$i]}" | wc -l)" \
      "$(gzip -9n < "${svgs[$i]}" | wc -c)" "$(tr ' ' '\t' <<< "${errs[$i]}")" "$pad" >> "$out/pts/${size}_$n.tmp"
  done
  mv "$out/pts/${size}_$n.tmp" "$out/pts/${size}_$n.tsv"; rm -f "$d"/*.png "$d"/*.json
  echo "$size $n done" >&2
}
for size in $sets; do
  case $size in
    256) imgs=("$bench"/faces/*.png "$bench"/scenes/*.png) ;;
    512) imgs=("$out"/set512/*.png) ;;
    pasted) imgs=("$out"/faceset/paste_*.png) ;;
    emoji) imgs=("$bench"/emoji/emoji_rocket.png) ;;
    *) echo "unknown set $size (256, 512, pasted, emoji)" >&2; exit 2 ;;
  esac
  for img in "${imgs[@]}"; do one "$size" "$img"; done
done
{ printf 'image\tsize\ttool\tmode\tsetting\tpaths\tgzip_bytes\tmse\tgmsd\tskin_colour\tskin_pixel\n'
  for size in $sets; do cat "$out"/pts/"${size}"_*.tsv; done; } > "$out/points.tsv"
"$py" - "$out" "$sets" <<'PY'
import csv, math, sys
out, sets = sys.argv[1], sys.argv[2].split()
label = lambda size: f"{size}²" if size.isdigit() else size
all_rows = list(csv.DictReader(open(f"{out}/points.tsv"), delimiter="\t"))
def hull(pts):  # lower convex hull of (bytes, err), bytes ascending, then its decreasing part
    pts = sorted(set(pts)); h = []
    for p in pts:
        while len(h) >= 2 and (h[-1][0]-h[-2][0])*(p[1]-h[-2][1]) - (h[-1][1]-h[-2][1])*(p[0]-h[-2][0]) <= 0:
            h.pop()
        h.append(p)
    best = min(range(len(h)), key=lambda i: h[i][1])
    return h[:best + 1]
def interp(h, b):  # (error, flag): flag "<" below the smallest file, ">" above the best one
    if b < h[0][0]: return h[0][1], "<"
    if b >= h[-1][0]: return h[-1][1], ">" if b > h[-1][0] else ""
    for (b0, e0), (b1, e1) in zip(h, h[1:]):
        if b0 <= b <= b1: return e0 + (e1 - e0) * (b - b0) / (b1 - b0), ""
def stair(pts, b):  # best error at bytes <= b (None below the smallest file)
    e = [err for (x, err) in pts if x <= b]
    return min(e) if e else None
cols = ["image", "size", "paths", "covec_bytes", "covec_mse", "vt_mse", "ratio_mse", "stair_ratio_mse",
        "covec_gmsd", "vt_gmsd", "ratio_gmsd", "stair_ratio_gmsd", "flag_mse", "flag_gmsd",
        "covec_skin_colour", "covec_skin_pixel", "vt_skin_pixel", "ratio_skin_pixel", "stair_ratio_skin_pixel",
        "flag_skin_pixel"]
names = {"vtracer": "VTracer 0.6.5", "vtracer1": "VTracer 1.0 (size options on)"}
tsv, md = [], []
def report(anchor):  # appends the anchor's rows to tsv and its tables to md
    global md
    rows = [r for r in all_rows if r["tool"] in ("covec", anchor)]
    keys = sorted({(r["size"], r["image"]) for r in rows}, key=lambda k: (sets.index(k[0]), k[1]))
    res = []
    for size, img in keys:
        rs = [r for r in rows if r["image"] == img and r["size"] == size]
        vt = [r for r in rs if r["tool"] == anchor]
        for c in sorted((r for r in rs if r["tool"] == "covec"), key=lambda r: int(r["setting"].split("=")[1])):
            b = int(c["gzip_bytes"]); o = {"image": img, "size": size, "paths": c["setting"].split("=")[1], "covec_bytes": b}
            for m in ("mse", "gmsd", "skin_pixel"):
                if not c[m]: continue
                pts = [(int(r["gzip_bytes"]), float(r[m])) for r in vt]
                e, flag = interp(hull(pts), b); s = stair(pts, b)
                o[f"covec_{m}"] = float(c[m]); o[f"vt_{m}"] = e; o[f"flag_{m}"] = flag
                o[f"ratio_{m}"] = float(c[m]) / e if e > 0 else math.inf
                o[f"stair_ratio_{m}"] = float(c[m]) / s if s else math.nan
            if c["skin_colour"]: o["covec_skin_colour"] = float(c["skin_colour"])
            res.append(o)
    tsv.extend("\t".join([anchor] + [f"{o[c]:.4g}" if isinstance(o.get(c), float) else str(o.get(c, "")) for c in cols]) + "\n"
               for o in res)
    ps = sorted({int(o["paths"]) for o in res})
    md += ["covec / VTracer's best (lower convex hull of its spline and polygon points) at covec's gzip bytes: "
          "MSE ratio / GMSD ratio; **bold**: above 1 (covec worse); < covec's file is smaller than any "
          "VTracer file (VTracer's smallest used), > larger than VTracer's best (its lowest error used).", "",
          "| image | size | " + " | ".join(f"{p}" for p in ps) + " |", "|---|---|" + "---|" * len(ps)]
    cell = lambda x: f"**{x:.2f}**" if x > 1 else f"{x:.2f}"
    for size, img in keys:
        by = {int(o["paths"]): o for o in res if o["image"] == img and o["size"] == size}
        md.append(f"| {img} | {label(size)} | " + " | ".join(
            f"{cell(by[p]['ratio_mse'])}{by[p]['flag_mse']} / {cell(by[p]['ratio_gmsd'])}{by[p]['flag_gmsd']}" if p in by else "" for p in ps) + " |")
    for size in sorted({k[0] for k in keys}, key=sets.index):
        g = lambda m, p: math.exp(sum(math.log(o[f"ratio_{m}"]) for o in res if o["size"] == size and int(o["paths"]) == p)
                                  / max(1, sum(1 for o in res if o["size"] == size and int(o["paths"]) == p)))
        md.append(f"| geometric mean | {label(size)} | " + " | ".join(f"{g('mse', p):.2f} / {g('gmsd', p):.2f}" for p in ps) + " |")
    above = [o for o in res if o["ratio_mse"] > 1 or o["ratio_gmsd"] > 1]
    md += ["", f"{len(above)} of {len(res)} (image, path count) points have a ratio above 1:"]
    md += [f"- {o['image']} {label(o['size'])} {o['paths']} paths: " + ", ".join(
            f"{m.upper()} {o['ratio_' + m]:.2f}" for m in ("mse", "gmsd") if o["ratio_" + m] > 1) for o in above]
    skin = [k for k in keys if any("ratio_skin_pixel" in o for o in res if (o["size"], o["image"]) == k)]
    if skin:
        md += ["", "Skin inside faces.txt's masks, in CIEDE2000: covec's mean skin colour against the photo's, "
               "then covec's mean per-pixel error over VTracer's best at covec's gzip bytes; **bold**: a colour "
               "above 2.3 or a ratio above 1.", "",
               "| image | size | " + " | ".join(f"{p}" for p in ps) + " |", "|---|---|" + "---|" * len(ps)]
        for size, img in skin:
            by = {int(o["paths"]): o for o in res if o["image"] == img and o["size"] == size}
            colour = lambda x: f"**{x:.2f}**" if x > 2.3 else f"{x:.2f}"
            md.append(f"| {img} | {label(size)} | " + " | ".join(
                f"{colour(by[p]['covec_skin_colour'])} / {cell(by[p]['ratio_skin_pixel'])}{by[p]['flag_skin_pixel']}"
                if p in by else "" for p in ps) + " |")
for anchor in names:
    if any(r["tool"] == anchor for r in all_rows):
        md += [f"## Against {names[anchor]}", ""]
        report(anchor)
        md.append("")
with open(f"{out}/ratios.tsv", "w") as f:
    f.write("\t".join(["anchor"] + cols) + "\n")
    f.writelines(tsv)
open(f"{out}/ratios.md", "w").write("\n".join(md) + "\n")
print("\n".join(md))
PY
