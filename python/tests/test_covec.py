"""The Python package end to end: every function on real images, numpy and PIL inputs, bad
inputs, progress and Ctrl-C, threads, and the same files as the `covec` command line."""

import io
import json
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from PIL import Image

import covec
from conftest import OTHER_PHOTOS, PHOTO, QUICK

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def run_cli(covec_bin, *args):
    done = subprocess.run([covec_bin, *map(str, args)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return done


# --- The result and its files ---------------------------------------------------------------


def test_vectorize_gives_a_layered_svg_and_its_mode(result):
    svg = result.svg()
    assert svg.startswith("<svg")
    for layer in ("albedo", "shade", "light"):
        assert f'id="{layer}"' in svg
    assert result.mode in ("photo", "simple")
    assert result.mode_reason
    assert result._repr_svg_() == svg
    assert "covec.Result" in repr(result) and "covec.Scene" in repr(result.scene)


def test_flattened_svg_has_no_blend_modes(result):
    flat = result.svg(flatten=True)
    assert flat.startswith("<svg") and "mix-blend-mode" not in flat
    assert "mix-blend-mode" in result.svg()
    # Coordinates to a tenth of a pixel write more digits than the default grid.
    assert len(result.svg(precision=1)) > len(result.svg(precision=0))
    with pytest.raises(covec.ParamsError, match="precision"):
        result.svg(precision=7)


def test_pdf_png_and_numpy_are_the_same_picture(result):
    assert result.pdf().startswith(b"%PDF")
    png = result.png()
    assert png.startswith(PNG_SIGNATURE)
    decoded = np.asarray(Image.open(io.BytesIO(png)))
    assert decoded.shape == (96, 96, 3)  # the original's size by default
    pixels = result.to_numpy()
    assert pixels.dtype == np.uint8 and np.array_equal(pixels, decoded)
    assert result.to_numpy(width=40).shape == (40, 40, 3)
    assert Image.open(io.BytesIO(result.png(width=200))).size == (200, 200)
    with pytest.raises(covec.ParamsError, match="width"):
        result.png(width=0)
    with pytest.raises(covec.ParamsError, match="limit"):
        result.png(width=5000, max_pixels=1000)


def test_layers_and_paths(result):
    layers = result.layers
    assert set(layers) == {"albedo", "shade", "light"}
    assert all(svg.startswith("<svg") for svg in layers.values())
    paths = result.paths
    assert paths[0].id == "albedo-0" and paths[0].layer == "albedo"
    assert len(paths) <= QUICK["paths"]
    svg = result.svg()
    for path in paths:
        assert f'id="{path.id}"' in svg and f'd="{path.d}"' in svg
        assert path.fill.startswith("#") and len(path.fill) == 7
        assert 0 <= path.opacity <= 1
        assert len(path.points) % 3 == 0 and all(len(p) == 2 for p in path.points)
    assert result.scene.changed == []


def test_save_writes_each_format_by_extension(result, tmp_path):
    for name, expected in [
        ("a.svg", result.svg().encode()),
        ("a.pdf", result.pdf()),
        ("a.json", result.scene.json().encode()),
        ("a.png", result.png()),
    ]:
        result.save(tmp_path / name)
        assert (tmp_path / name).read_bytes() == expected
    result.save(tmp_path / "flat.svg", flatten=True)
    assert (tmp_path / "flat.svg").read_text() == result.svg(flatten=True)
    result.save(tmp_path / "wide.png", width=30)
    assert Image.open(tmp_path / "wide.png").size == (30, 30)
    with pytest.raises(covec.ParamsError, match="extension"):
        result.save(tmp_path / "a.gif")
    with pytest.raises(covec.ParamsError, match="PNG"):
        result.save(tmp_path / "b.svg", width=30)


def test_scene_loads_back_losslessly(result, tmp_path):
    text = result.scene.json()
    path = tmp_path / "scene.json"
    path.write_text(text)
    for source in (text, text.encode(), json.loads(text), path, str(path)):
        scene = covec.Scene.load(source)
        assert scene.svg() == result.svg() and scene.json() == text
    scene = covec.Scene.load(path)
    assert (scene.width, scene.height) == (48, 48)
    assert (scene.original_width, scene.original_height) == (96, 96)
    assert scene.to_dict()["albedo"]["paths"]
    with pytest.raises(covec.InputError, match="not a covec scene"):
        covec.Scene.load('{"width": 3}')
    huge = dict(json.loads(text), width=100000, height=100000)
    with pytest.raises(covec.InputError, match="pixels"):
        covec.Scene.load(huge)
    with pytest.raises(FileNotFoundError):
        covec.Scene.load(tmp_path / "missing.json")


def test_render(result, tmp_path):
    assert covec.render(result, 40) == result.png(40)
    assert covec.render(result.scene) == result.png()
    path = tmp_path / "scene.json"
    result.save(path)
    assert covec.render(path, 64) == result.png(64)


def test_version_is_the_crates(covec_bin):
    assert run_cli(covec_bin, "--version").stdout.split()[-1] == covec.__version__


# --- The same files as the command line ----------------------------------------------------


def test_same_files_as_the_command_line(covec_bin, tmp_path):
    result = covec.vectorize(str(PHOTO), seed=7, mode="photo", **QUICK)
    args = ["--paths", 8, "--max-size", 48, "--seed", 7, "--mode", "photo"]
    run_cli(covec_bin, "vectorize", PHOTO, "-o", tmp_path / "cli.svg", *args)
    assert (tmp_path / "cli.svg").read_text() == result.svg()
    assert (tmp_path / "cli.json").read_text() == result.scene.json()
    run_cli(covec_bin, "vectorize", PHOTO, "-o", tmp_path / "flat.svg", "--flatten", *args)
    assert (tmp_path / "flat.svg").read_text() == result.svg(flatten=True)
    run_cli(covec_bin, "vectorize", PHOTO, "-o", tmp_path / "cli.pdf", *args)
    assert (tmp_path / "cli.pdf").read_bytes() == result.pdf()
    run_cli(covec_bin, "vectorize", PHOTO, "-o", tmp_path / "cli.png", "--width", 40, *args)
    assert (tmp_path / "cli.png").read_bytes() == result.png(40)
    run_cli(covec_bin, "vectorize", PHOTO, "-o", tmp_path / "l.svg", "--layers", tmp_path, *args)
    for name, svg in result.layers.items():
        assert (tmp_path / f"{name}.svg").read_text() == svg


def test_same_edits_as_the_command_line(covec_bin, result, tmp_path):
    scene_path = tmp_path / "scene.json"
    result.save(scene_path)
    edited = result.scene.recolor(at=(20, 20), color="#3366ff")
    run_cli(covec_bin, "edit", scene_path, "--at", "20,20=#3366ff", "-o", tmp_path / "at.svg")
    assert (tmp_path / "at.svg").read_text() == edited.svg()
    assert (tmp_path / "at.json").read_text() == edited.json()

    reference = result.to_numpy().copy()
    reference[30:70, 30:70] = [40, 60, 200]
    Image.fromarray(reference).save(tmp_path / "reference.png")
    by_reference = result.scene.recolor_by_reference(reference, k=2)
    run_cli(
        covec_bin, "edit", scene_path, "--reference", tmp_path / "reference.png", "--k", 2,
        "-o", tmp_path / "ref.svg",
    )
    assert (tmp_path / "ref.svg").read_text() == by_reference.svg()
    run_cli(covec_bin, "render", tmp_path / "ref.json", "-o", tmp_path / "ref.png", "--width", 50)
    assert (tmp_path / "ref.png").read_bytes() == covec.render(by_reference, 50)


# --- Inputs ------------------------------------------------------------------------------------


def test_path_bytes_pil_and_numpy_give_the_same_result(result):
    pil = Image.open(PHOTO)
    rgb = np.asarray(pil.convert("RGB"))
    rgba = np.dstack([rgb, np.full(rgb.shape[:2], 255, np.uint8)])
    for image in (str(PHOTO), PHOTO.read_bytes(), pil, pil.convert("RGBA"), rgb, rgba):
        assert covec.vectorize(image, seed=1, **QUICK).svg() == result.svg()


def test_grey_sixteen_bit_and_float_arrays():
    rgb = np.asarray(Image.open(PHOTO).convert("RGB"))
    grey = np.asarray(Image.open(PHOTO).convert("L"))
    for image in (
        grey,
        Image.fromarray(grey),
        rgb.astype(np.uint16) * 257,
        rgb.astype(np.float32) / 255,
        rgb / 255.0,
        rgb > 128,
        Image.open(PHOTO).convert("P"),
        Image.open(PHOTO).convert("F").point(lambda v: v / 255),
    ):
        svg = covec.vectorize(image, **QUICK).svg()
        assert svg.startswith("<svg") and 'id="albedo-0"' in svg
    # 16-bit and float copies of 8-bit pixels are the same picture.
    sixteen = covec.vectorize(rgb.astype(np.uint16) * 257, seed=1, **QUICK)
    assert sixteen.svg() == covec.vectorize(rgb, seed=1, **QUICK).svg()


def test_albedo_masks_and_labels():
    rgb = np.asarray(Image.open(PHOTO).convert("RGB"))
    left = np.zeros((96, 96), bool)
    left[:, :48] = True
    masks = [left, ~left]
    with_masks = covec.vectorize(PHOTO, masks=masks, mode="photo", **QUICK)
    as_stack = covec.vectorize(PHOTO, masks=np.stack(masks), mode="photo", **QUICK)
    as_uint8 = covec.vectorize(PHOTO, masks=[m.astype(np.uint8) * 255 for m in masks],
                               mode="photo", **QUICK)
    assert with_masks.svg() == as_stack.svg() == as_uint8.svg()
    # A label map's values only name its segments: any integers give the same run.
    small = covec.vectorize(PHOTO, labels=np.where(left, 0, 1), mode="photo", **QUICK)
    large = covec.vectorize(PHOTO, labels=np.where(left, -5, 10**12), mode="photo", **QUICK)
    assert small.svg() == large.svg()
    albedo = covec.vectorize(PHOTO, albedo=rgb // 2 + 64, **QUICK)
    assert albedo.svg().startswith("<svg")
    with pytest.raises(TypeError, match="not both"):
        covec.vectorize(PHOTO, masks=masks, labels=left)


def test_progress_reports_every_stage_in_order():
    reports = []
    result = covec.vectorize(PHOTO, mode="photo", progress=lambda s, f: reports.append((s, f)),
                             **QUICK)
    stages = [s for s, _ in reports]
    for stage in ("decompose", "init", "structure", "reconstruct", "refine", "split", "polish"):
        assert stage in stages
    fractions = [f for _, f in reports]
    assert fractions == sorted(fractions) and 0 <= fractions[0] and fractions[-1] == 1.0
    assert result.svg() == covec.vectorize(PHOTO, mode="photo", **QUICK).svg()


# --- Bad inputs ----------------------------------------------------------------------------


def jpeg_bytes():
    buffer = io.BytesIO()
    Image.open(PHOTO).convert("RGB").save(buffer, "JPEG")
    return buffer.getvalue()


@pytest.mark.parametrize(
    "image, message",
    [
        (PHOTO.read_bytes()[:400], "could not be decoded"),
        (b"not an image", "could not be decoded"),
        (jpeg_bytes()[:-500], "truncated"),
        (np.zeros((96, 96, 3), np.int64), "dtype int64"),
        (np.zeros((96, 96, 3), np.complex64), "dtype complex64"),
        (np.zeros((0, 0, 3), np.uint8), "empty"),
        (np.zeros((96, 96, 5), np.uint8), "channels"),
        (np.zeros((4, 96, 96, 3), np.uint8), "shape"),
        (np.full((96, 96, 3), 255.0), "outside \\[0, 1\\]"),
        (np.full((96, 96, 3), np.nan, np.float32), "outside \\[0, 1\\]"),
    ],
)
def test_bad_images_raise_input_errors(image, message):
    with pytest.raises(covec.InputError, match=message) as raised:
        covec.vectorize(image, **QUICK)
    assert isinstance(raised.value, covec.Error) and isinstance(raised.value, ValueError)


def test_a_cut_jpeg_is_used_when_accepted():
    result = covec.vectorize(jpeg_bytes()[:-500], accept_truncated=True, **QUICK)
    assert result.svg().startswith("<svg")


def test_bad_masks_and_labels_raise_input_errors():
    square = np.zeros((96, 96), bool)
    square[20:40, 20:40] = True
    with pytest.raises(covec.InputError, match="mask 1.*aspect ratio"):
        covec.vectorize(PHOTO, masks=[np.zeros((96, 40), bool)], **QUICK)
    with pytest.raises(covec.InputError, match="mask 2 is not binary"):
        covec.vectorize(PHOTO, masks=[square, np.arange(96 * 96, dtype=np.uint16).reshape(96, 96)],
                        **QUICK)
    with pytest.raises(covec.InputError, match="limit of 2"):
        covec.vectorize(PHOTO, masks=[square] * 3, max_masks=2, **QUICK)
    with pytest.raises(covec.InputError, match="mask 1: the image could not be decoded"):
        covec.vectorize(PHOTO, masks=[b"nothing"], **QUICK)
    with pytest.raises(covec.InputError, match="label map.*aspect ratio"):
        covec.vectorize(PHOTO, labels=np.zeros((50, 96), np.int32), **QUICK)
    with pytest.raises(covec.InputError, match="distinct values"):
        covec.vectorize(PHOTO, labels=np.arange(96 * 96).reshape(96, 96), **QUICK)
    with pytest.raises(covec.InputError, match="albedo"):
        covec.vectorize(PHOTO, albedo=b"nothing", **QUICK)
    with pytest.raises(TypeError, match="sequence of masks"):
        covec.vectorize(PHOTO, masks=str(PHOTO), **QUICK)


def test_bad_parameters_and_types():
    with pytest.raises(covec.ParamsError, match="paths"):
        covec.vectorize(PHOTO, paths=2, max_size=48)
    with pytest.raises(covec.ParamsError, match="max_size"):
        covec.vectorize(PHOTO, paths=8, max_size=8)
    with pytest.raises(covec.ParamsError, match="mode"):
        covec.vectorize(PHOTO, mode="bogus", **QUICK)
    with pytest.raises(covec.ParamsError, match="threads"):
        covec.vectorize(PHOTO, threads=0, **QUICK)
    with pytest.raises(covec.InputError, match="limit of 100"):
        covec.vectorize(PHOTO, max_pixels=100, **QUICK)
    with pytest.raises(FileNotFoundError):
        covec.vectorize("no/such/photo.png", **QUICK)
    with pytest.raises(TypeError, match="not int"):
        covec.vectorize(42, **QUICK)


def test_bad_edits_raise_edit_errors(result):
    scene = result.scene
    with pytest.raises(covec.EditError, match="unknown path id"):
        scene.recolor(path="albedo-99", color="#ff0000")
    with pytest.raises(covec.EditError, match="not a path id"):
        scene.recolor(path="halo-1", color="#ff0000")
    with pytest.raises(covec.EditError, match="no albedo path covers"):
        scene.recolor(at=(-10, -10), color="#ff0000")
    with pytest.raises(covec.EditError, match="not a colour"):
        scene.recolor(path="albedo-0", color="#zzzzzz")
    with pytest.raises(covec.EditError, match="not in \\[0, 1\\]"):
        scene.recolor(path="albedo-0", color=(2.0, 0.0, 0.0))
    with pytest.raises(covec.EditError, match="k must be"):
        scene.recolor_by_reference(result.to_numpy(), k=0)
    with pytest.raises(covec.InputError, match="aspect ratio"):
        scene.recolor_by_reference(np.zeros((96, 40, 3), np.uint8))
    with pytest.raises(TypeError):
        scene.recolor(path="albedo-0")


# --- Edits ---------------------------------------------------------------------------------


def test_recolouring_keeps_the_lighting(result):
    scene = result.scene
    edited = scene.recolor(at=(20, 20), color="#3366ff")
    (change,) = edited.changed
    assert change.new_fill == "#3366ff" and change.path.startswith("albedo-")
    assert edited.svg() != scene.svg()
    lighting = [p for p in scene.paths if p.layer != "albedo"]
    assert [p for p in edited.paths if p.layer != "albedo"] == lighting
    # The original is untouched; several changes at once, by id and by point.
    assert scene.changed == []
    both = scene.recolor({"albedo-0": (1.0, 0.0, 0.0), (20, 20): "#00ff00"})
    assert [c.new_fill for c in both.changed] == ["#ff0000", "#00ff00"]
    assert both.recolor([("albedo-0", "#123456")]).changed[0].old_fill == "#ff0000"


def test_recolouring_by_reference(result):
    reference = result.to_numpy().copy()
    reference[30:70, 30:70] = [40, 60, 200]
    edited = result.scene.recolor_by_reference(reference, k=2)
    assert 1 <= len(edited.changed) <= 2
    assert edited.svg() != result.svg()
    # From PIL, with the original given, at another size of the same aspect ratio.
    big = Image.fromarray(reference).resize((192, 192))
    original = Image.open(PHOTO)
    assert result.scene.recolor_by_reference(big, original=original).changed


# --- Cancelling, threads ---------------------------------------------------------------------


def test_an_exception_in_progress_stops_the_run():
    def progress(stage, fraction):
        raise ZeroDivisionError("stop here")

    with pytest.raises(ZeroDivisionError, match="stop here"):
        covec.vectorize(PHOTO, progress=progress, **QUICK)


@pytest.fixture
def ctrl_c():
    """Python's own Ctrl-C handler for the test, whatever the runner was started with (a shell
    starts background jobs with SIGINT ignored, and Python then raises nothing on Ctrl-C)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_ctrl_c_stops_a_run_in_process(ctrl_c):
    import _thread

    started = []

    def progress(stage, fraction):
        if not started:
            started.append(time.monotonic())
            _thread.interrupt_main()

    with pytest.raises(KeyboardInterrupt):
        covec.vectorize(PHOTO, paths=64, max_size=96, progress=progress)
    assert time.monotonic() - started[0] < 2


def test_ctrl_c_stops_a_run_in_a_process():
    """A real SIGINT to a Python process in the middle of a long run (256 paths)."""
    script = (
        "import signal, sys, covec\n"
        # As a terminal's foreground process has it, even if this test's runner ignores SIGINT.
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "def progress(stage, fraction):\n"
        "    if stage == 'structure': print('started', flush=True)\n"
        f"covec.vectorize({str(PHOTO)!r}, paths=256, max_size=96, progress=progress)\n"
        "print('finished', flush=True)\n"
    )
    child = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    assert child.stdout.readline().strip() == "started"
    signalled = time.monotonic()
    child.send_signal(signal.SIGINT)
    out, err = child.communicate(timeout=30)
    assert time.monotonic() - signalled < 5
    assert child.returncode != 0 and "KeyboardInterrupt" in err and "finished" not in out


def test_four_threads_at_once_give_the_serial_results():
    photos = [PHOTO, *OTHER_PHOTOS]
    serial = [covec.vectorize(p, seed=3, **QUICK).svg() for p in photos]
    parallel = [None] * 4

    def run(k):
        parallel[k] = covec.vectorize(photos[k], seed=3, **QUICK).svg()

    threads = [threading.Thread(target=run, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert parallel == serial
    # Any thread count gives the same bytes.
    assert covec.vectorize(PHOTO, seed=3, threads=1, **QUICK).svg() == serial[0]


def test_the_interpreter_runs_while_covec_works():
    ticks = []
    worker = threading.Thread(
        target=covec.vectorize, args=(PHOTO,), kwargs={"paths": 64, "max_size": 96}
    )
    worker.start()
    while worker.is_alive():
        ticks.append(time.monotonic())
        time.sleep(0.005)
    worker.join()
    # With the interpreter held for the run, this loop would stall until the end.
    gaps, run = np.diff(ticks), ticks[-1] - ticks[0]
    assert len(ticks) > 10 and gaps.max() < run / 2, (len(ticks), gaps.max(), run)


def test_the_package_is_typed():
    package = os.path.dirname(covec.__file__)
    assert os.path.exists(os.path.join(package, "py.typed"))
    assert os.path.exists(os.path.join(package, "_covec.pyi"))
