#!/usr/bin/env bash
# Installs the renderers the output tests call (tests/pipeline/flat_output.rs), idempotently: Debian's
# poppler-utils (pdftoppm, for the PDF) and librsvg2-bin (rsvg-convert), and CairoSVG from PyPI
# (for the flattened SVG). Safe to run on every test run.
set -euo pipefail

sudo_cmd=()
if [[ $(id -u) -ne 0 ]]; then sudo_cmd=(sudo); fi
missing=()
command -v pdftoppm >/dev/null || missing+=(poppler-utils)
command -v rsvg-convert >/dev/null || missing+=(librsvg2-bin)
if [[ ${#missing[@]} -gt 0 ]]; then
    echo "setup-renderers: installing Debian ${missing[*]}" >&2
    "${sudo_cmd[@]}" apt-get update -qq
    DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi
if ! python3 -c 'import cairosvg' 2>/dev/null; then
    echo "setup-renderers: installing CairoSVG (PyPI)" >&2
    python3 -m pip install --quiet cairosvg
fi
