#!/usr/bin/env python3
"""covec's Python package against VTracer's (PyPI `vtracer`), both from Python, on the bench.

    python3 benches/python/against_vtracer.py OUT_DIR --wheel covec-….whl --bench BENCH
        [--venv DIR] [--runs N] [--threads N]

Each photo and emoji of the covec bench (BENCH: the covec-bench folder, not part of this
repository) goes in as its PNG file's bytes: covec.vectorize(…, paths=64) (`--threads`, default all cores), and
vtracer.convert_raw_image_to_svg with VTracer's defaults, and with filter_speckle=16 as
benches/quality/bench.sh runs VTracer. Time: the fastest of `--runs` calls (default 3) after a
warm-up, each tracer run in turn on one image. Each SVG is rendered over white by resvg (0.49 in
docs/benchmarks.md: `cargo install --locked resvg --version 0.49.0`) at the input's size and
scored by benches/quality/metrics.py: MSE (RGB in [0, 1]) and GMSD; bytes are the SVG's, raw
and gzipped (level 9, no name or time). Writes OUT_DIR/vtracer.md (tables per set, means) and
OUT_DIR/vtracer.tsv. The packages go into a venv (default OUT_DIR/.venv) made on first use;
with a new wheel, give a new --venv.
"""
import glob
import gzip
import os
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))
sys.path.insert(0, os.path.join(HERE, "..", "quality"))
from venvs import ensure_venv, venv_path  # noqa: E402

PACKAGES = ["vtracer==0.6.15", "numpy==2.4.6", "pillow==13.0.0"]
TRACERS = ["covec", "vtracer", "vtracer -f 16"]


def option(args, name, default):
    return args[args.index(name) + 1] if name in args else default


def main():
    args = sys.argv[1:]
    if not args or args[0].startswith("-") or "--wheel" not in args or "--bench" not in args:
        sys.exit(__doc__)
    out = args[0]
    ensure_venv(venv_path(out, args), [*PACKAGES, os.path.abspath(option(args, "--wheel", ""))])

    import covec
    import vtracer
    from metrics import flat, gmsd

    runs = int(option(args, "--runs", "3"))
    threads = option(args, "--threads", None)
    threads = None if threads is None else int(threads)
    bench = option(args, "--bench", "")
    sets = {
        "photos": sorted(glob.glob(f"{bench}/faces/*.png") + glob.glob(f"{bench}/scenes/*.png")),
        "emoji": sorted(glob.glob(f"{bench}/emoji/*.png")),
    }
    tracers = {
        "covec": lambda png: covec.vectorize(png, paths=64, threads=threads).svg(),
        "vtracer": lambda png: vtracer.convert_raw_image_to_svg(png, img_format="png"),
        "vtracer -f 16": lambda png: vtracer.convert_raw_image_to_svg(
            png, img_format="png", filter_speckle=16
        ),
    }
    os.makedirs(f"{out}/svg", exist_ok=True)
    rows = []
    for set_name, images in sets.items():
        for path in images:
            name = os.path.splitext(os.path.basename(path))[0]
            png = open(path, "rb").read()
            reference = flat(path)
            height, width = reference.shape[:2]
            for tracer, trace in tracers.items():
                svg = trace(png)
                seconds = []
                for _ in range(runs):
                    start = time.perf_counter()
                    trace(png)
                    seconds.append(time.perf_counter() - start)
                stem = f"{out}/svg/{name}.{tracer.replace(' ', '')}"
                with open(f"{stem}.svg", "w") as file:
                    file.write(svg)
                subprocess.run(
                    ["resvg", "-w", str(width), "-h", str(height), f"{stem}.svg", f"{stem}.png"],
                    check=True,
                )
                drawn = flat(f"{stem}.png")
                data = svg.encode()
                rows.append({
                    "set": set_name, "image": name, "tracer": tracer,
                    "seconds": min(seconds), "paths": svg.count("<path"), "bytes": len(data),
                    "gzip": len(gzip.compress(data, 9, mtime=0)),
                    "mse": float(((drawn - reference) ** 2).mean()),
                    "gmsd": float(gmsd(reference, drawn)),
                })
                print("\t".join(str(v) for v in rows[-1].values()), flush=True)
    write(out, rows, sets, runs, threads, covec.__version__, vtracer)


def write(out, rows, sets, runs, threads, covec_version, vtracer):
    keys = list(rows[0])
    with open(f"{out}/vtracer.tsv", "w") as file:
        file.write("\t".join(keys) + "\n")
        for row in rows:
            file.write("\t".join(str(row[k]) for k in keys) + "\n")
    lines = [
        f"covec {covec_version} (threads: {threads or 'all cores'}, {os.cpu_count()} here), "
        f"VTracer {getattr(vtracer, '__version__', '0.6.15')}, fastest of {runs} calls.",
        "",
        "| set | tracer | seconds per image | paths | SVG bytes | gzip bytes | MSE | GMSD |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for set_name in sets:
        for tracer in TRACERS:
            mine = [r for r in rows if r["set"] == set_name and r["tracer"] == tracer]
            if not mine:
                continue
            mean = {k: statistics.mean(r[k] for r in mine)
                    for k in ("seconds", "paths", "bytes", "gzip", "mse", "gmsd")}
            lines.append(
                f"| {set_name} ({len(mine)}) | {tracer} | {mean['seconds']:.3f} | "
                f"{mean['paths']:.0f} | {mean['bytes']:.0f} | {mean['gzip']:.0f} | "
                f"{mean['mse']:.5f} | {mean['gmsd']:.4f} |"
            )
    with open(f"{out}/vtracer.md", "w") as file:
        file.write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
