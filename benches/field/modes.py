#!/usr/bin/env python3
"""How `auto` chose on the field set: per class and split, the share of images that got the
mode MANIFEST.md says they should, and the misses by name (a tool for measuring).

    covec eval OUT/tuning/* OUT/held-out/* --paths 16 --method covec --iteration-scale 0.01 --out modes.csv
    python3 benches/field/modes.py modes.csv

The eval CSV's `class` column is the image's folder (field_set.py's class); the split comes
from the manifest. Standard library only.
"""
import csv
import os
import re
import sys

MANIFEST = os.path.join(os.path.dirname(os.path.abspath(__file__)), "MANIFEST.md")


def manifest():
    """(class → expected mode, image name → split) from the manifest's two tables."""
    expected, split = {}, {}
    for line in open(MANIFEST):
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 4 and cells[1] in ("photo", "simple"):
            expected[cells[0]] = cells[1]
        elif len(cells) == 6 and cells[2] in ("tuning", "held-out"):
            split[cells[0]] = cells[2]
    return expected, split


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    expected, split = manifest()
    rows = [r for path in sys.argv[1:] for r in csv.DictReader(open(path)) if r["method"] == "covec"]
    seen = set()
    tally = {}
    for r in rows:
        name = os.path.splitext(os.path.basename(r["image"]))[0]
        if name in seen or name not in split:
            continue
        seen.add(name)
        want = expected[r["class"]]
        key = (split[name], want)
        ok, total, misses = tally.get(key, (0, 0, []))
        hit = r["mode"] == want
        tally[key] = (ok + hit, total + 1, misses if hit else misses + [f"{name} ({r['class']}: {r['mode_reason']})"])
    print("| split | should be | chosen right | share |")
    print("|---|---|---|---|")
    for (s, want), (ok, total, _) in sorted(tally.items(), key=lambda kv: (kv[0][0] != "tuning", kv[0][1])):
        print(f"| {s} | {want} | {ok} of {total} | {100 * ok / total:.0f} % |")
    for (s, want), (_, _, misses) in sorted(tally.items()):
        for m in misses:
            print(f"- miss, {s}, should be {want}: {m}")
    unseen = sorted(set(split) - seen)
    if unseen:
        print(f"({len(unseen)} images of the manifest are not in the CSV: {', '.join(unseen[:5])}...)")


if __name__ == "__main__":
    main()
