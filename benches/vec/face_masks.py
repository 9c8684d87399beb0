#!/usr/bin/env python3
"""Semantic masks of faces for measuring VeC (issue 21): a tool for measuring, not part of covec.

    python3 benches/vec/face_masks.py FACES_DIR OUT_DIR [--venv DIR]

For each image in FACES_DIR, writes four binary masks into OUT_DIR/<image stem>/ for
`covec eval FACES_DIR --semantic-masks OUT_DIR [--use-masks]`:
1-face.png (jaw line closed over the eyebrows), 2-eyes.png (both eye outlines), 3-nose.png
(convex hull of the nose points), 4-mouth.png (outer lip line). The landmarks come from dlib's
68-point model (PyPI `dlib-bin` 20.0.1.post1 and `face-recognition-models` 0.3.0, which ships the
model files): faces are found by dlib's HOG detector on the image upsampled twice, else by its
CNN detector (two bench faces, kodim15 and navy_sailor, need it). The packages go into a venv
(default: OUT_DIR/.venv) that the script makes and re-runs itself in.
"""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from venvs import ensure_venv  # noqa: E402

PACKAGES = ["dlib-bin==20.0.1.post1", "face-recognition-models==0.3.0", "numpy", "pillow"]


def landmarks(image):
    """The 68 (x, y) points of the largest face, or None."""
    import dlib
    import face_recognition_models as models

    faces = list(dlib.get_frontal_face_detector()(image, 2))
    if not faces:
        cnn = dlib.cnn_face_detection_model_v1(models.cnn_face_detector_model_location())
        faces = [d.rect for d in cnn(image, 1)]
    if not faces:
        return None
    face = max(faces, key=lambda r: r.width() * r.height())
    shape = dlib.shape_predictor(models.pose_predictor_model_location())(image, face)
    return [(p.x, p.y) for p in shape.parts()]


def convex_hull(points):
    """Andrew's monotone chain."""
    points = sorted(set(points))
    if len(points) < 3:
        return points

    def half(seq):
        out = []
        for p in seq:
            while len(out) >= 2 and (
                (out[-1][0] - out[-2][0]) * (p[1] - out[-2][1])
                - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])
            ) <= 0:
                out.pop()
            out.append(p)
        return out

    return half(points)[:-1] + half(reversed(points))[:-1]


def masks(points):
    """Name → list of polygons (dlib's 68-point numbering)."""
    return {
        "1-face": [points[0:17] + points[17:27][::-1]],
        "2-eyes": [points[36:42], points[42:48]],
        "3-nose": [convex_hull(points[27:36])],
        "4-mouth": [points[48:60]],
    }


def main():
    args = sys.argv[1:]
    if len(args) not in (2, 4) or (len(args) == 4 and args[2] != "--venv"):
        sys.exit(__doc__)
    faces, out = args[0], args[1]
    ensure_venv(args[3] if len(args) == 4 else os.path.join(out, ".venv"), PACKAGES)
    import numpy as np
    from PIL import Image, ImageDraw

    for name in sorted(os.listdir(faces)):
        if not name.lower().endswith((".png", ".jpg", ".jpeg", ".webp")):
            continue
        image = Image.open(os.path.join(faces, name)).convert("RGB")
        points = landmarks(np.asarray(image))
        stem = os.path.splitext(name)[0]
        if points is None:
            print(f"{stem}: no face found", file=sys.stderr)
            continue
        os.makedirs(os.path.join(out, stem), exist_ok=True)
        areas = []
        for mask_name, polygons in masks(points).items():
            mask = Image.new("L", image.size, 0)
            for polygon in polygons:
                ImageDraw.Draw(mask).polygon(polygon, fill=255)
            mask.save(os.path.join(out, stem, mask_name + ".png"))
            areas.append(f"{mask_name} {int((np.asarray(mask) > 0).sum())} px")
        print(f"{stem}: " + ", ".join(areas))


if __name__ == "__main__":
    main()
