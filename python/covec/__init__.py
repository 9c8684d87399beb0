"""covec: photographs to layered, editable SVG (albedo × shade + light).

    >>> import covec
    >>> result = covec.vectorize("photo.jpg", paths=64)
    >>> result.save("photo.svg")
    >>> blue = result.scene.recolor(at=(120, 88), color="#3366ff")
    >>> blue.save("blue.png", width=1024)

`vectorize` runs covec's pipeline with the interpreter released (other Python threads run
meanwhile, and several calls on several threads run in parallel); Ctrl-C stops it. Every file
and edit is made by covec's Rust library, byte for byte as the `covec` command makes it.
"""

import json
from typing import Callable, Optional

from . import _covec, _inputs
from ._errors import EditError, Error, InputError, ParamsError
from ._scene import MAX_PIXELS, Change, Path, Result, Scene

__all__ = [
    "vectorize",
    "render",
    "Result",
    "Scene",
    "Path",
    "Change",
    "Error",
    "InputError",
    "ParamsError",
    "EditError",
]

__version__ = _covec.VERSION

_DEFAULTS = json.loads(_covec.defaults())
_PARAMS = _DEFAULTS["params"]


def vectorize(
    image,
    *,
    paths: int = _PARAMS["paths"],
    mode: str = _PARAMS["mode"],
    albedo=None,
    masks=None,
    labels=None,
    seed: int = _PARAMS["seed"],
    max_size: int = _PARAMS["max_size"],
    threads: Optional[int] = None,
    progress: Optional[Callable[[str, float], object]] = None,
    max_pixels: int = MAX_PIXELS,
    max_masks: int = _DEFAULTS["limits"]["max_masks"],
    accept_truncated: bool = False,
) -> Result:
    """Vectorises `image` into a layered scene.

    image: a path, a PNG/JPEG/WebP file's bytes, a PIL image, or a numpy array (H×W, H×W×3
        or H×W×4; uint8, uint16, or float in [0, 1]). Alpha is composited over white. A path
        or bytes get their EXIF orientation applied; pixels are taken as they are.
    paths: the path budget over all layers, base path included (8-1024).
    mode: "photo" (albedo, shade and light), "simple" (albedo only, for emoji, icons and flat
        artwork) or "auto" (chosen from the image; `Result.mode_reason` says why).
    albedo: an albedo map with the image's aspect ratio (e.g. from an intrinsic-decomposition
        network), as `image` takes it. Default: covec's classical stand-in.
    masks: segmentation masks (e.g. SAM's), a sequence of binary masks as `image` takes them
        (bool or 0/255 arrays, paths, PIL images) or one N×H×W array. Default: covec
        segments the albedo map itself.
    labels: instead of `masks`, one label map: each distinct value is a segment (an integer
        array, or an image).
    seed: the seed of every random choice; equal inputs and seed give byte-identical files.
    max_size: the working size: the long side is scaled down to this (16-4096), never up.
    threads: threads for this run (a pool of its own); default all cores, shared with the
        other runs of the process.
    progress: called as `progress(stage, fraction)` on the calling thread while the run goes
        on, `fraction` the share of the whole run done, in [0, 1]; an exception it raises stops
        the run and is raised here.
    max_pixels, max_masks: refuse larger images and more masks.
    accept_truncated: use a JPEG cut short (its missing part is grey) instead of refusing it.

    Raises `InputError` for an input covec cannot use, `ParamsError` for a parameter out of
    range, `KeyboardInterrupt` on Ctrl-C (the run stops within an iteration).
    """
    if masks is not None and labels is not None:
        raise TypeError("give `masks` or `labels`, not both")
    scene, run_mode, reason = _covec.vectorize(
        _inputs.image(image, "image"),
        albedo=None if albedo is None else _inputs.image(albedo, "albedo"),
        masks=_inputs.masks(masks),
        labels=_inputs.labels(labels),
        paths=paths,
        mode=mode,
        seed=seed,
        max_size=max_size,
        threads=threads,
        progress=progress,
        max_pixels=max_pixels,
        max_masks=max_masks,
        accept_truncated=accept_truncated,
    )
    return Result(Scene(scene), run_mode, reason)


def render(scene, width: Optional[int] = None, *, max_pixels: int = MAX_PIXELS) -> bytes:
    """A PNG of `scene` (a `Scene`, a `Result`, or what `Scene.load` takes) drawn by covec's
    own renderer, `width` pixels wide (default: the original image's)."""
    if isinstance(scene, Result):
        scene = scene.scene
    elif not isinstance(scene, Scene):
        scene = Scene.load(scene, max_pixels=max_pixels)
    return scene.png(width, max_pixels=max_pixels)
