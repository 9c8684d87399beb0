"""Shared fixtures: small images from tests/fixtures (see its README for their licences), the
`covec` command line the package is held to (COVEC_BIN, set by scripts/test-python.sh), and one
small run reused by the tests that only read its result."""

import os
import pathlib

import pytest

import covec

FIXTURES = pathlib.Path(__file__).resolve().parents[2] / "tests" / "fixtures"
PHOTO = FIXTURES / "photo96_face_hopper.png"
OTHER_PHOTOS = [
    FIXTURES / "photo96_face_astronaut.png",
    FIXTURES / "photo96_scene_coffee.png",
    FIXTURES / "photo96_scene_chelsea.png",
]
# Few paths on a small working canvas: a run takes a fraction of a second.
QUICK = {"paths": 8, "max_size": 48}


@pytest.fixture(scope="session")
def covec_bin():
    path = os.environ.get("COVEC_BIN")
    assert path, "set COVEC_BIN to a built `covec` binary (scripts/test-python.sh does)"
    return path


@pytest.fixture(scope="session")
def result():
    return covec.vectorize(PHOTO, seed=1, **QUICK)
