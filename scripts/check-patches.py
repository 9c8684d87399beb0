#!/usr/bin/env python3
"""Fails unless every crate Cargo.toml's [patch.crates-io] names is the patched copy in use.

A `cargo update` that moves a dependency past the vendored version (vendor/README.md) leaves the
patch unused with only a warning, and the crates.io copy is built instead: the build still
passes, the measured change silently gone. Reads the resolved graph (`cargo metadata`): each
patched crate must appear, and only from its path."""
import json
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main() -> int:
    manifest = tomllib.loads((ROOT / "Cargo.toml").read_text())
    patched = manifest.get("patch", {}).get("crates-io", {})
    metadata = json.loads(
        subprocess.run(
            ["cargo", "metadata", "--format-version", "1", "--quiet"],
            cwd=ROOT, check=True, capture_output=True, text=True,
        ).stdout
    )
    used = {node["id"] for node in metadata["resolve"]["nodes"]}
    bad = []
    for name, spec in patched.items():
        path = (ROOT / spec["path"]).resolve()
        copies = [p for p in metadata["packages"] if p["name"] == name and p["id"] in used]
        if not copies:
            bad.append(f"{name}: patched but not in the dependency graph")
        for copy in copies:
            if Path(copy["manifest_path"]).resolve().parent != path:
                bad.append(f"{name} {copy['version']} is built from {copy['source']}, not {spec['path']}"
                           f" (the [patch] no longer applies: update the vendored copy)")
    if bad:
        print("check-patches:", *bad, sep="\n  ")
        return 1
    print(f"check-patches: {', '.join(patched)} from vendor/, as patched")
    return 0


if __name__ == "__main__":
    sys.exit(main())
