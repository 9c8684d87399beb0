#!/usr/bin/env python3
"""The image's name, set in one place: every container of every Kubernetes setup names an image
that the setup's kustomization renames, deploy/kubernetes/image holds the only `images:` list,
and every built service of the Compose files takes ${COVEC_IMAGE:-…}, with one default."""
import pathlib
import re
import sys

import yaml

deploy = pathlib.Path(sys.argv[1])
errors = []
KINDS = {
    "Kustomization": "kustomize.config.k8s.io/v1beta1",
    "Component": "kustomize.config.k8s.io/v1alpha1",
}
FIELDS = {"apiVersion", "kind", "resources", "components", "images"}
IMAGE_FIELDS = {"name", "newName", "newTag", "digest"}


def load(path):
    return yaml.safe_load(path.read_text()) or {}


image_lists = []
for path in sorted(deploy.glob("kubernetes/*/kustomization.yaml")):
    k = load(path)
    if KINDS.get(k.get("kind")) != k.get("apiVersion"):
        errors.append(f"{path}: kind {k.get('kind')} with apiVersion {k.get('apiVersion')}")
    if set(k) - FIELDS:
        errors.append(f"{path}: fields this check does not know: {sorted(set(k) - FIELDS)}")
    for entry in k.get("images", []):
        if "name" not in entry or not set(entry) & (IMAGE_FIELDS - {"name"}) or set(entry) - IMAGE_FIELDS:
            errors.append(f"{path}: images entry {entry}: give name and newName, newTag or digest")
    if "images" in k:
        image_lists.append(str(path))
    if k.get("kind") != "Kustomization":
        continue
    renamed = {entry.get("name") for entry in k.get("images", [])}
    for component in k.get("components", []):
        c = path.parent / component / "kustomization.yaml"
        if not c.is_file() or load(c).get("kind") != "Component":
            errors.append(f"{path}: component {component} is not a Component")
            continue
        renamed |= {entry.get("name") for entry in load(c).get("images", [])}
    for resource in k.get("resources", []):
        manifest = path.parent / resource
        if not manifest.is_file():
            errors.append(f"{path}: no resource {resource}")
            continue
        for doc in yaml.safe_load_all(manifest.read_text()):
            pod = ((doc or {}).get("spec") or {}).get("template", {}).get("spec", {})
            for container in pod.get("containers", []) + pod.get("initContainers", []):
                if re.split(r"[:@]", container["image"])[0] not in renamed:
                    errors.append(
                        f"{manifest}: image {container['image']} is not renamed by {path}"
                    )
if image_lists != [str(deploy / "kubernetes/image/kustomization.yaml")]:
    errors.append(f"images: lists in {image_lists}: expected one, in deploy/kubernetes/image")

defaults = set()
for path in sorted(deploy.glob("compose*.yaml")):
    for name, service in load(path)["services"].items():
        if "build" not in service:
            continue
        match = re.fullmatch(r"\$\{COVEC_IMAGE:-([^}]+)\}", service.get("image", ""))
        if match:
            defaults.add(match[1])
        else:
            errors.append(f"{path}: service {name}: image {service.get('image')!r}, not ${{COVEC_IMAGE:-…}}")
if len(defaults) > 1:
    errors.append(f"the Compose files default COVEC_IMAGE differently: {sorted(defaults)}")

for error in errors:
    print(f"check-image-name: {error}", file=sys.stderr)
sys.exit(1 if errors else 0)
