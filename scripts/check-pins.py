#!/usr/bin/env python3
"""Every image the deploy files run is pinned: named with a version tag (at least MAJOR.MINOR,
never `latest`) or a digest, as Compose and kustomize render them (the variables' defaults
resolved, kustomize's `images:` applied). A floating tag (`latest`, none, or a bare major such
as `postgres:17`) is the first thing to break on a fresh host when its project moves on or stops
publishing. covec's own image must be the release of Cargo.toml's version.

  check-pins.py CARGO_TOML RENDERED...   rendered Compose files (JSON) and manifests (YAML)
  check-pins.py --self-test              shows that it refuses floating references
"""
import json
import re
import sys

import yaml

# A tag that names a release: digits, a dot, digits (`17.6-bookworm`, `4.44`, `0.1.0`, `v1.2`).
VERSION_TAG = re.compile(r"^v?\d+\.\d+")
DIGEST = re.compile(r"@sha256:[0-9a-f]{64}$")
COVEC = re.compile(r"(^|/)covec$")


def images(document):
    """Every `image` value of a rendered Compose file or Kubernetes object, with where it is."""
    if isinstance(document, dict):
        services = document.get("services")
        if isinstance(services, dict):
            for name, service in services.items():
                if isinstance(service, dict) and "image" in service:
                    yield f"service {name}", service["image"]
        spec = (document.get("spec") or {}).get("template", {}).get("spec", {})
        for container in spec.get("containers", []) + spec.get("initContainers", []):
            kind = document.get("kind", "?")
            name = (document.get("metadata") or {}).get("name", "?")
            yield f"{kind} {name}, container {container.get('name')}", container.get("image", "")


def refusal(image, version):
    """Why `image` is not pinned, or None."""
    if DIGEST.search(image):
        return None
    name, _, tag = image.rpartition(":") if ":" in image.rsplit("/", 1)[-1] else (image, "", "")
    if not tag:
        return "no tag (Docker takes `latest`)"
    if tag == "latest" or not VERSION_TAG.match(tag):
        return f"the tag `{tag}` floats: give a version (MAJOR.MINOR at least) or a digest"
    if COVEC.search(name) and tag.lstrip("v") != version:
        return f"covec's image is tagged `{tag}`, not this version `{version}` (Cargo.toml)"
    return None


def check(paths, version):
    errors = []
    for path in paths:
        text = open(path).read()
        documents = [json.loads(text)] if path.endswith(".json") else yaml.safe_load_all(text)
        for document in documents:
            for where, image in images(document):
                reason = refusal(image, version)
                if reason:
                    errors.append(f"{path}: {where}: {image}: {reason}")
    return errors


def self_test():
    floating = ["minio/minio:latest", "minio/mc", "postgres:17", "postgres:bookworm",
                "registry.example.com:5000/covec", "ghcr.io/covec/covec:0.0.9"]
    pinned = ["postgres:17.6-bookworm", "chrislusf/seaweedfs:4.44", "ghcr.io/covec/covec:0.1.0",
              "registry.example.com:5000/team/covec:0.1.0",
              "example.com/x@sha256:" + "0" * 64]
    wrong = [image for image in floating if refusal(image, "0.1.0") is None]
    wrong += [image for image in pinned if refusal(image, "0.1.0") is not None]
    if wrong:
        print(f"check-pins --self-test: misjudged {wrong}", file=sys.stderr)
        return 1
    print(f"check-pins --self-test: refuses {len(floating)} floating references, passes {len(pinned)} pinned ones",
          file=sys.stderr)
    return 0


def main():
    if sys.argv[1:] == ["--self-test"]:
        return self_test()
    cargo, *paths = sys.argv[1:]
    version = re.search(r'^version = "([^"]+)"', open(cargo).read(), re.M)[1]
    errors = check(paths, version)
    for error in errors:
        print(f"check-pins: {error}", file=sys.stderr)
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
