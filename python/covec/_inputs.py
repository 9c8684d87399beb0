"""What a user passes, turned into what the extension module takes: `(name, data)`, the name
for error messages (a path, or what the input is), `data` a file's bytes or `(samples, height,
width, channels, sample type)` with little-endian samples of type `u8`, `u16` or `f32`. The
extension decodes and checks everything under covec's limits; this only reads files and
unpacks PIL images and numpy arrays."""

import os
import sys
from array import array

from ._errors import InputError

# Most distinct labels a label-map array may hold: they travel as 16-bit values.
_MAX_LABELS = 1 << 16


def image(value, what):
    """An image, albedo map or reference: a path, a file's bytes, a PIL image or an array."""
    if isinstance(value, (str, os.PathLike)):
        path = os.fspath(value)
        with open(path, "rb") as file:
            return path, file.read()
    if isinstance(value, (bytes, bytearray, memoryview)):
        return what, bytes(value)
    if _is_pil(value):
        return what, _pil_pixels(value, what)
    if hasattr(value, "__array_interface__") or hasattr(value, "__array__"):
        return what, _array_pixels(_numpy().asarray(value), what)
    raise TypeError(
        f"{what}: expected a path, bytes, a PIL image or a numpy array, not {type(value).__name__}"
    )


def masks(value):
    """Binary masks: a sequence of images (as `image` takes), or one N×H×W array."""
    if value is None:
        return None
    if isinstance(value, (str, bytes, os.PathLike)) or _is_pil(value):
        raise TypeError(
            "masks: expected a sequence of masks or an N×H×W array, not one image "
            "(for a directory of mask files: sorted(pathlib.Path(dir).glob('*.png')))"
        )
    if hasattr(value, "__array_interface__") or hasattr(value, "__array__"):
        stack = _numpy().asarray(value)
        if stack.ndim != 3:
            raise InputError(
                f"masks: an array of shape {stack.shape}; a stack of masks is N×H×W "
                "(or give a list of H×W arrays)"
            )
        value = list(stack)
    return [image(mask, str(k + 1)) for k, mask in enumerate(value)]


def labels(value):
    """A label map: an image (as `image` takes); an integer array may hold any values."""
    if value is None:
        return None
    if not _is_pil(value) and (
        hasattr(value, "__array_interface__") or hasattr(value, "__array__")
    ):
        np = _numpy()
        array_ = np.asarray(value)
        if array_.ndim == 2 and array_.dtype.kind in "iu" and array_.size:
            if array_.min() < 0 or array_.max() > 0xFFFF:
                values, array_ = np.unique(array_, return_inverse=True)
                if len(values) > _MAX_LABELS:
                    raise InputError(
                        f"labels: the label map holds {len(values)} distinct values; "
                        f"covec takes at most {_MAX_LABELS}"
                    )
                array_ = array_.reshape(np.shape(value))
            array_ = array_.astype("<u2")
        return "labels", _array_pixels(array_, "labels")
    return image(value, "labels")


def _numpy():
    import numpy

    return numpy


def _is_pil(value):
    pil = sys.modules.get("PIL.Image")
    return pil is not None and isinstance(value, pil.Image)


def _array_pixels(a, what):
    if a.ndim == 2:
        (height, width), channels = a.shape, 1
    elif a.ndim == 3:
        height, width, channels = a.shape
    else:
        raise InputError(
            f"{what}: an array of shape {a.shape}; an image is H×W, H×W×3 or H×W×4"
        )
    kind = a.dtype.kind
    if kind == "b":
        samples, sample_type = (a.astype("u1") * 255), "u8"
    elif a.dtype == _numpy().uint8:
        samples, sample_type = a, "u8"
    elif a.dtype == _numpy().uint16:
        samples, sample_type = a.astype("<u2"), "u16"
    elif kind == "f":
        samples, sample_type = a.astype("<f4"), "f32"
    else:
        raise InputError(
            f"{what}: an array of dtype {a.dtype}; covec takes uint8, uint16, bool, or float "
            "arrays with values in [0, 1]"
        )
    data = _numpy().ascontiguousarray(samples).tobytes()
    return data, height, width, channels, sample_type


# PIL modes whose bytes go over as they are: channels and sample type.
_PIL_DIRECT = {"L": (1, "u8"), "LA": (2, "u8"), "RGB": (3, "u8"), "RGBA": (4, "u8"),
               "I;16": (1, "u16"), "I;16L": (1, "u16")}


def _pil_pixels(img, what):
    mode = img.mode
    if mode == "1":
        img, mode = img.convert("L"), "L"
    elif mode in ("P", "PA"):
        alpha = mode == "PA" or "transparency" in img.info
        mode = "RGBA" if alpha else "RGB"
        img = img.convert(mode)
    width, height = img.size
    if mode in _PIL_DIRECT:
        channels, sample_type = _PIL_DIRECT[mode]
        return img.tobytes(), height, width, channels, sample_type
    if mode == "I;16B":
        big = img.tobytes()
        little = bytearray(len(big))
        little[0::2], little[1::2] = big[1::2], big[0::2]
        return bytes(little), height, width, 1, "u16"
    if mode == "F":
        return _little_endian(array("f", img.tobytes())), height, width, 1, "f32"
    if mode == "I":
        low, high = img.getextrema()
        if low < 0 or high > 0xFFFF:
            raise InputError(
                f"{what}: a 32-bit PIL image with values {low}-{high}; covec takes 0-65535"
            )
        samples = array("H", array("i", img.tobytes()))
        return _little_endian(samples), height, width, 1, "u16"
    alpha = any(band in ("A", "a") for band in img.getbands())
    mode = "RGBA" if alpha else "RGB"
    return _pil_pixels(img.convert(mode), what)


def _little_endian(samples):
    if sys.byteorder == "big":
        samples.byteswap()
    return samples.tobytes()
