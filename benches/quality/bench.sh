#!/usr/bin/env bash
# Quality and speed bench: two covec binaries, and VTracer, on the same images.
#   COVEC_BENCH=DIR benches/quality/bench.sh AFTER BEFORE OUT     (AFTER/BEFORE: covec binaries;
#   DIR: the covec-bench set, which is not part of this repository)
# Sets: the 16 covec-bench photos (256²) and a 512² set (scikit-image's astronaut.png, public
# domain NASA photo, from the scikit-image 0.26.0 wheel on PyPI; four bench photos upscaled
# 2× with Pillow's Lanczos). Each SVG (covec at 64 paths; VTracer -f 16 on the 512² set) is
# rendered by resvg over white and compared with its input: MSE and GMSD (metrics.py).
# Needs resvg, vtracer, hyperfine, python3 (a venv with pillow + numpy is made in OUT).
set -eu
after=$1; before=$2; out=$3; here=$(cd "$(dirname "$0")" && pwd); bench=${COVEC_BENCH:?set COVEC_BENCH to the covec-bench directory}
mkdir -p "$out/set512"; py=$out/venv/bin/python
[ -x "$py" ] || { python3 -m venv "$out/venv" && "$out/venv/bin/pip" -q install pillow numpy; }
"$py" "$here/metrics.py" --check "$here/../../tests/fixtures"
"$here/set512.sh" "$bench" "$out/set512" "$py"
# Cubic segments in the d attributes on stdin (M, then C/c only, as covec and VTracer write;
# one C may carry several cubics: six numbers each).
count_cubics='import re, sys
print(sum((len(re.findall(r"[-+]?(?:\d+\.?\d*|\.\d+)", sub)) - 2) // 6
          for sub in re.split(r"[Mm]", sys.stdin.read())[1:]))'
measure() {  # measure NAME BIN IMAGES... -> OUT/NAME.tsv: image, paths, cubic segments, mse, gmsd
  local name=$1 bin=$2; shift 2; mkdir -p "$out/$name"; : > "$out/$name.tsv"
  for img in "$@"; do
    n=$(basename "$img" .png)
    if [ "$bin" = vtracer ]; then vtracer -i "$img" -o "$out/$name/$n.svg" -f 16 >/dev/null
    else "$bin" vectorize "$img" -o "$out/$name/$n.svg" --paths 64 </dev/null >/dev/null; fi
    read -r w h < <("$py" -c "from PIL import Image; print(*Image.open('$img').size)")
    resvg -w "$w" -h "$h" "$out/$name/$n.svg" "$out/$name/$n.png"
    p=$(grep -o '<path' "$out/$name/$n.svg" | wc -l)
    s=$(grep -o ' d="[^"]*"' "$out/$name/$n.svg" | "$py" -c "$count_cubics")
    printf '%s\t%s\t%s\t%s\n' "$n" "$p" "$s" "$("$py" "$here/metrics.py" "$img" "$out/$name/$n.png" | tr ' ' '\t')" >> "$out/$name.tsv"
  done
}
photos=("$bench"/faces/*.png "$bench"/scenes/*.png); set512=("$out"/set512/*.png)
measure before256 "$before" "${photos[@]}"; measure after256 "$after" "${photos[@]}"
measure before512 "$before" "${set512[@]}"; measure after512 "$after" "${set512[@]}"; measure vtracer512 vtracer "${set512[@]}"
loop() { printf "for i in %s; do %s vectorize \$i -o $out/t.svg --paths 64; done" "$1" "$2"; }
hyperfine -w 1 -r "${RUNS:-5}" --export-markdown "$out/time256.md" -n before "$(loop "${photos[*]}" "$before")" -n after "$(loop "${photos[*]}" "$after")"
hyperfine -w 1 -r "${RUNS:-5}" --export-markdown "$out/time512.md" -n before "$(loop "${set512[*]}" "$before")" -n after "$(loop "${set512[*]}" "$after")"
