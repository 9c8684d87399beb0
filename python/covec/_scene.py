"""`Scene` (a layered vector picture, its files and its edits) and `Result` (a scene with the
mode a run chose). Every file and edit is made by covec's library through the extension."""

import json
import os
from typing import NamedTuple, Optional, Sequence, Tuple, Union, cast

from . import _covec, _inputs
from ._errors import ParamsError

_DEFAULTS = json.loads(_covec.defaults())
MAX_PIXELS = _DEFAULTS["limits"]["max_pixels"]
_REFERENCE = _DEFAULTS["reference"]

Color = Union[str, Tuple[float, float, float]]
Target = Union[str, Tuple[float, float]]


class Path(NamedTuple):
    """One path of a scene."""

    layer: str
    """`albedo`, `shade` or `light`."""
    id: str
    """Its id in the SVG and for edits, e.g. `albedo-3` (layer and paint order)."""
    fill: str
    """`#rrggbb`."""
    opacity: float
    d: str
    """Its path data as the layered SVG writes it: whole quarter pixels, which the layer's
    group scales by 0.25."""
    points: list
    """Control points `(x, y)` in canvas pixels, three per cubic segment."""


class Change(NamedTuple):
    """A path an edit changed; one the edit added has `old_opacity` 0."""

    path: str
    old_fill: str
    new_fill: str
    old_opacity: float
    new_opacity: float


# What `save` writes for each extension.
_FORMATS = (".svg", ".png", ".pdf", ".json")


class Scene:
    """A layered vector picture: albedo × shade + light, each layer closed cubic Bézier paths.

    Scenes are immutable: an edit gives a new one. Coordinates are in the working canvas's
    pixels (`width` × `height`); files are drawn at the original size."""

    __slots__ = ("_scene",)

    def __init__(self, scene):
        """Not for direct use: scenes come from `covec.vectorize`, `Scene.load` and edits."""
        self._scene = scene

    @classmethod
    def load(cls, source, *, max_pixels: int = MAX_PIXELS) -> "Scene":
        """A scene from its JSON form (`covec vectorize`'s `.json`, the service's
        `scene.json`, `Scene.json()`): a path, the JSON text or bytes, or its dict. Refused
        (`InputError`) if it is no scene or its canvas has more than `max_pixels` pixels."""
        if isinstance(source, dict):
            data = json.dumps(source).encode()
        elif isinstance(source, (bytes, bytearray)):
            data = bytes(source)
        elif isinstance(source, str) and source.lstrip().startswith("{"):
            data = source.encode()
        elif isinstance(source, (str, os.PathLike)):
            with open(source, "rb") as file:
                data = file.read()
        else:
            raise TypeError(
                f"expected a path, JSON text or bytes, or a dict, not {type(source).__name__}"
            )
        return cls(_covec.Scene.from_json(data, max_pixels))

    @property
    def width(self) -> int:
        """Working canvas width in pixels: the coordinates' system and the SVG's viewBox."""
        return self._scene.size()[0]

    @property
    def height(self) -> int:
        """Working canvas height in pixels."""
        return self._scene.size()[1]

    @property
    def original_width(self) -> int:
        """The original image's width: the SVG's `width`, and a PNG's by default."""
        return self._scene.size()[2]

    @property
    def original_height(self) -> int:
        """The original image's height."""
        return self._scene.size()[3]

    def json(self) -> str:
        """The JSON scene, at full precision: `Scene.load` and the `covec` command read it back
        losslessly."""
        return self._scene.json()

    def to_dict(self) -> dict:
        """The JSON scene as a dict: `width`, `height`, `original_width`, `original_height`
        and the layers `albedo`, `shade`, `light`, each `{"paths": [{"points", "color",
        "opacity"}]}`."""
        return json.loads(self.json())

    def svg(self, flatten: bool = False, *, precision: Optional[int] = None) -> str:
        """The layered SVG (blend modes `multiply` and `plus-lighter`), or with `flatten` the
        same picture as plain opaque paths for programs without those blend modes.
        `precision`: decimals of the coordinates (0-6); default a quarter-pixel grid (a tenth
        when flattened)."""
        return self._scene.svg(flatten, precision)

    @property
    def layers(self) -> dict:
        """Each layer alone over its base colour, as SVG: `{"albedo": …, "shade": …,
        "light": …}`."""
        return dict(self._scene.layers(None))

    def pdf(self) -> bytes:
        """A vector PDF of the flattened picture."""
        return self._scene.pdf()

    def png(self, width: Optional[int] = None, *, max_pixels: int = MAX_PIXELS) -> bytes:
        """A PNG drawn by covec's own renderer (the picture that was optimised), `width`
        pixels wide (default: the original image's), the height keeping the aspect ratio."""
        return self._scene.png(width, max_pixels)

    def to_numpy(self, width: Optional[int] = None, *, max_pixels: int = MAX_PIXELS):
        """The pixels `png` encodes: a height × width × 3 `uint8` numpy array."""
        import numpy

        data, height, width = self._scene.pixels(width, max_pixels)
        return numpy.frombuffer(data, dtype=numpy.uint8).reshape(height, width, 3)

    @property
    def paths(self) -> list:
        """Every path, layer by layer (albedo, shade, light), each back to front."""
        return [Path(layer, id_, fill, opacity, d, points)
                for layer, id_, fill, opacity, d, points in self._scene.paths()]

    @property
    def changed(self) -> list:
        """The paths the edit that made this scene changed (empty for a scene not made by an
        edit)."""
        return [Change(*change) for change in self._scene.changed()]

    def save(self, path, *, width: Optional[int] = None, flatten: bool = False) -> None:
        """Writes the file the extension names: `.svg` (layered, or flattened with
        `flatten`), `.png` (`width` pixels wide), `.pdf` or `.json` (the scene)."""
        extension = os.path.splitext(os.fspath(path))[1].lower()
        if extension not in _FORMATS:
            raise ParamsError(
                f"{os.fspath(path)}: no format in its extension; give a .svg, .png, .pdf or "
                ".json path"
            )
        if width is not None and extension != ".png":
            raise ParamsError("`width` sets the size of a PNG; give a .png path")
        if flatten and extension != ".svg":
            raise ParamsError("`flatten` applies to an SVG (a PDF is always flat)")
        if extension == ".svg":
            data = self.svg(flatten).encode()
        elif extension == ".png":
            data = self.png(width)
        elif extension == ".pdf":
            data = self.pdf()
        else:
            data = self.json().encode()
        with open(path, "wb") as file:
            file.write(data)

    def recolor(
        self,
        changes: Optional[Union[dict, Sequence[Tuple[Target, Color]]]] = None,
        *,
        at: Optional[Tuple[float, float]] = None,
        path: Optional[str] = None,
        color: Optional[Color] = None,
    ) -> "Scene":
        """A new scene with paths recoloured; their shade and light stay, so shadows and
        highlights are kept.

        Either one change, `at=(x, y)` (the albedo path under that point, in canvas pixels) or
        `path="albedo-3"`, with `color`; or several, `changes`, a dict or a sequence of
        `(target, color)`, each target a path id or an `(x, y)` point. A colour is `"#rrggbb"`
        or three floats in [0, 1]. Raises `EditError` for an unknown path, a point no albedo
        path covers, or a bad colour."""
        if changes is None:
            if (at is None) == (path is None) or color is None:
                raise TypeError("give `changes`, or one of `at` and `path` with `color`")
            changes = [(cast(Target, tuple(at) if at is not None else path), color)]
        elif at is not None or path is not None or color is not None:
            raise TypeError("give either `changes` or `at`/`path` with `color`, not both")
        items = list(changes.items() if isinstance(changes, dict) else changes)
        return Scene(self._scene.recolor([(_target(t), c) for t, c in items]))

    def recolor_by_reference(
        self,
        reference,
        *,
        original=None,
        k: int = _REFERENCE["k"],
        tau: float = _REFERENCE["tau"],
        gamma: float = _REFERENCE["gamma"],
        delta: float = _REFERENCE["delta"],
        epsilon: float = _REFERENCE["epsilon"],
        max_pixels: int = MAX_PIXELS,
    ) -> "Scene":
        """A new scene following `reference`, an edited copy of the original image (a path,
        bytes, a PIL image or an array with the original's aspect ratio): the albedo paths
        under the edited region (at most `k`) take its colours, less the lighting, and the
        shade and light paths lying mostly inside it are refit. `original`: the image the
        reference was edited from; default the scene's own rendering, which counts
        vectorisation error as edits too. `tau`: the mean channel difference that makes a
        pixel edited; `gamma`: the least overlap of a path with the edit; `delta`: the least
        colour change; `epsilon`: added to the shade before dividing by it."""
        reference = _inputs.image(reference, "reference")
        original = None if original is None else _inputs.image(original, "original")
        return Scene(
            self._scene.recolor_by_reference(
                reference, original, k, tau, gamma, delta, epsilon, max_pixels
            )
        )

    def _repr_svg_(self) -> str:
        return self.svg()

    def __repr__(self) -> str:
        counts: dict[str, int] = {}
        for p in self.paths:
            counts[p.layer] = counts.get(p.layer, 0) + 1
        layers = ", ".join(f"{counts.get(name, 0)} {name}" for name in ("albedo", "shade", "light"))
        return f"<covec.Scene {self.width}×{self.height} ({layers} paths)>"


class Result:
    """What `covec.vectorize` returns: the scene, and the mode the run took and why."""

    __slots__ = ("scene", "mode", "mode_reason")

    def __init__(self, scene: Scene, mode: str, mode_reason: str):
        self.scene = scene
        """The vector picture (`Scene`): its files, paths and edits."""
        self.mode = mode
        """`photo` (albedo, shade and light) or `simple` (albedo only)."""
        self.mode_reason = mode_reason
        """Why that mode, one sentence."""

    def svg(self, flatten: bool = False, *, precision: Optional[int] = None) -> str:
        """`Scene.svg`."""
        return self.scene.svg(flatten, precision=precision)

    def pdf(self) -> bytes:
        """`Scene.pdf`."""
        return self.scene.pdf()

    def png(self, width: Optional[int] = None, *, max_pixels: int = MAX_PIXELS) -> bytes:
        """`Scene.png`."""
        return self.scene.png(width, max_pixels=max_pixels)

    def to_numpy(self, width: Optional[int] = None, *, max_pixels: int = MAX_PIXELS):
        """`Scene.to_numpy`."""
        return self.scene.to_numpy(width, max_pixels=max_pixels)

    @property
    def layers(self) -> dict:
        """`Scene.layers`."""
        return self.scene.layers

    @property
    def paths(self) -> list:
        """`Scene.paths`."""
        return self.scene.paths

    def save(self, path, *, width: Optional[int] = None, flatten: bool = False) -> None:
        """`Scene.save`."""
        self.scene.save(path, width=width, flatten=flatten)

    def _repr_svg_(self) -> str:
        return self.scene.svg()

    def __repr__(self) -> str:
        return f"<covec.Result {self.mode} mode, {self.scene!r}>"


def _target(target):
    return target if isinstance(target, str) else tuple(target)
