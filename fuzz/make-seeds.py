#!/usr/bin/env python3
"""Writes the fuzz targets' seed corpora (fuzz/seeds/<target>/) from tiny images made here
(Pillow) and hand-written JSON. Rerun after changing it; the outputs are committed."""
import base64
import io
import json
import shutil
from pathlib import Path

from PIL import Image, ImageDraw

SEEDS = Path(__file__).resolve().parent / "seeds"
BOUNDARY = b"covecfuzz"


def encode(image, fmt, **options):
    out = io.BytesIO()
    image.save(out, fmt, **options)
    return out.getvalue()


def picture(mode="RGB", size=(12, 8)):
    image = Image.new("RGB", size, (200, 40, 30))
    draw = ImageDraw.Draw(image)
    draw.ellipse((2, 1, 9, 7), fill=(30, 90, 220))
    return image.convert(mode)


def mask(size=(12, 8)):
    image = Image.new("L", size, 0)
    ImageDraw.Draw(image).rectangle((3, 2, 8, 6), fill=255)
    return image


def labels(size=(12, 8)):
    image = Image.new("L", size, 0)
    draw = ImageDraw.Draw(image)
    draw.rectangle((0, 0, 5, 7), fill=1)
    draw.rectangle((6, 0, 11, 3), fill=2)
    return image


def images():
    rotated = io.BytesIO()
    exif = Image.Exif()
    exif[0x0112] = 6  # orientation: rotate 90
    picture().save(rotated, "JPEG", exif=exif)
    rgba16 = Image.new("I;16", (6, 4), 30000)
    return {
        "rgb.png": encode(picture(), "PNG"),
        "rgba.png": encode(picture("RGBA"), "PNG"),
        "grey.png": encode(picture("L"), "PNG"),
        "palette.png": encode(picture("P"), "PNG"),
        "grey16.png": encode(rgba16, "PNG"),
        "rgb.jpg": encode(picture(), "JPEG", quality=80),
        "progressive.jpg": encode(picture(), "JPEG", progressive=True),
        "grey.jpg": encode(picture("L"), "JPEG"),
        "rotated.jpg": rotated.getvalue(),
        "lossy.webp": encode(picture(), "WEBP", quality=70),
        "lossless.webp": encode(picture("RGBA"), "WEBP", lossless=True),
        "mask.png": encode(mask(), "PNG"),
        "labels.png": encode(labels(), "PNG"),
    }


def part(name, data, filename=None, content_type=None):
    head = b'Content-Disposition: form-data; name="' + name.encode() + b'"'
    if filename:
        head += b'; filename="' + filename.encode() + b'"'
    head += b"\r\n"
    if content_type:
        head += b"Content-Type: " + content_type.encode() + b"\r\n"
    return b"--" + BOUNDARY + b"\r\n" + head + b"\r\n" + data + b"\r\n"


def multipart(*parts):
    return b"".join(parts) + b"--" + BOUNDARY + b"--\r\n"


def scene():
    def rect(x0, y0, x1, y1, color, opacity):
        corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
        points = []
        for i, (ax, ay) in enumerate(corners):
            bx, by = corners[(i + 1) % 4]
            points += [(ax, ay), (ax + (bx - ax) / 3, ay + (by - ay) / 3),
                       (ax + 2 * (bx - ax) / 3, ay + 2 * (by - ay) / 3)]
        return {"points": [{"x": x, "y": y} for x, y in points], "color": color,
                "opacity": opacity}

    return {
        "width": 32, "height": 24, "original_width": 64, "original_height": 48,
        "albedo": {"paths": [rect(0, 0, 32, 24, [0.8, 0.2, 0.1], 1.0),
                             rect(4, 4, 20, 18, [0.1, 0.4, 0.9], 0.8)]},
        "shade": {"paths": [rect(10, 2, 30, 22, [0.5, 0.5, 0.5], 0.6)]},
        "light": {"paths": [rect(12, 8, 16, 12, [0.3, 0.3, 0.2], 0.4)]},
    }


def write(target, name, data):
    (SEEDS / target).mkdir(parents=True, exist_ok=True)
    (SEEDS / target / name).write_bytes(data)


def b64(data):
    return base64.b64encode(data).decode()


def main():
    shutil.rmtree(SEEDS, ignore_errors=True)
    files = images()

    # image: first byte 0 = image, 1 = mask, 2 = label map.
    for name, data in files.items():
        selector = {"mask.png": 1, "labels.png": 2}.get(name, 0)
        write("image", name, bytes([selector]) + data)
    write("image", "mask-as-labels.png", b"\x02" + files["mask.png"])

    params = [
        {},
        {"paths": 16, "mode": "photo", "max_size": 64, "seed": 3,
         "iterations": {"structure": 2, "reconstruction": 2, "refine_rounds": 1, "refine": 2,
                        "polish": 2}},
        {"mode": "simple", "paths": 8},
        {"k": 2, "tau": 0.1, "gamma": 0.02, "delta": 0.05, "epsilon": 0.01},
    ]
    for i, value in enumerate(params):
        write("params", f"params-{i}.json", json.dumps(value).encode())

    write("scene", "scene.json", json.dumps(scene()).encode())
    write("scene", "empty.json", json.dumps({**scene(), "albedo": {"paths": []},
                                              "shade": {"paths": []},
                                              "light": {"paths": []}}).encode())

    # submission: first byte 0 = multipart (boundary covecfuzz), 1 = JSON.
    small = json.dumps({"paths": 16, "max_size": 32}).encode()
    write("submission", "image.multipart", b"\x00" + multipart(
        part("image", files["rgb.png"], "a.png", "image/png")))
    write("submission", "all.multipart", b"\x00" + multipart(
        part("image", files["rgb.jpg"], "a.jpg", "image/jpeg"),
        part("albedo", files["rgb.png"], "b.png", "image/png"),
        part("mask", files["mask.png"], "m.png", "image/png"),
        part("mask", files["mask.png"], "n.png", "image/png"),
        part("params", small)))
    write("submission", "labels.multipart", b"\x00" + multipart(
        part("image", files["lossy.webp"], "a.webp"),
        part("labels", files["labels.png"], "l.png"),
        part("params", small)))
    write("submission", "body.json", b"\x01" + json.dumps({
        "image": b64(files["rgb.png"]),
        "masks": [b64(files["mask.png"])],
        "params": {"paths": 16},
    }).encode())
    write("submission", "dataurl.json", b"\x01" + json.dumps({
        "image": "data:image/jpeg;base64," + b64(files["grey.jpg"]),
        "albedo": b64(files["rgb.png"]),
        "labels": b64(files["labels.png"]),
    }).encode())


if __name__ == "__main__":
    main()
