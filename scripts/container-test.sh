#!/usr/bin/env bash
# The container image, built from the Dockerfile and started, as part of the test command
# (docs/operations.md, "Container image"). There is no Docker engine here and no image registry,
# so, as root:
#   1. podman and debootstrap from Debian's packages, if missing;
#   2. the Dockerfile's bases made locally and tagged under the names it uses: Debian's minbase
#      trimmed as the official slim images are (debuerreotype's settings), and from it a Rust
#      builder holding this machine's toolchain and trust store (cargo reaches crates.io through
#      this machine's TLS set-up; that trust store never reaches the runtime image). Both are
#      kept in podman's image store, labelled with what they were made from, and made again
#      only when that changes;
#   3. `podman build --isolation=chroot` of the Dockerfile as it is;
#   4. the runtime image's file system exported and started with chroot as its user, running
#      its ENTRYPOINT, CMD, environment and HEALTHCHECK as `podman inspect` gives them (podman
#      run is refused here: crun cannot set the container's rlimits, `setrlimit` not permitted);
#   5. one node: the image as shipped refuses to start without API keys (one line); on
#      loopback, /healthz through the image's own health check, one job to `succeeded` and its
#      SVG, the TLS roots, the image's size (total, and what the Dockerfile adds to its base);
#   6. scaled: an API and a worker with the commands and settings of deploy/compose-scaled.yaml
#      as `docker compose config` renders it (with an API key), against a throwaway PostgreSQL
#      and moto's S3 server over HTTPS (its certificate from a throwaway CA added to the image's
#      trust store, as a deployer with a private CA would), one job through them (keyed, its
#      SVG through its signed URL), the worker's health through its --ops-addr.
# Every step either passes or stops the script with a message naming it; what cannot run on
# these machines is printed in the summary with the reason. Logs, the exported image's SVGs and
# the summary go to tests/artifacts/container/.
set -euo pipefail
cd "$(dirname "$0")/.."

started=$SECONDS
artifacts=tests/artifacts/container
step="start"
summary=()
log() { printf 'container-test: %s\n' "$*" >&2; }
begin() {
    step=$1
    step_started=$SECONDS
    log "== $step"
}
# One summary line for the step that just passed, with its time.
passed() { summary+=("ok    $step ($((SECONDS - step_started)) s)${1:+: $1}"); }
fail() {
    log "FAILED at \"$step\": $*"
    exit 1
}

if ((EUID != 0)); then
    log "cannot run: making the bases (debootstrap), building (podman build --isolation=chroot) and"
    log "starting the image (chroot to uid 10001) all need root; CI runs the test command as root."
    log "Not run: bases, build, one-node start, scaled start. COVEC_SKIP_CONTAINER=1 skips this script."
    exit 1
fi

# Everything started here is stopped on exit, by process id.
pids=()
work=""
cleanup() {
    local status=$?
    for pid in "${pids[@]}"; do
        kill "$pid" 2>/dev/null || true
    done
    for pid in "${pids[@]}"; do
        wait "$pid" 2>/dev/null || true
    done
    if [[ -n $work ]]; then
        # debootstrap mounts these inside its target while it runs; an interrupted one leaves them.
        for mount in "$work"/rootfs/proc "$work"/rootfs/sys; do
            mountpoint -q "$mount" 2>/dev/null && umount -l "$mount"
        done
        rm -rf "$work"
    fi
    ((status == 0)) || log "FAILED at \"$step\" (exit $status); logs in $artifacts/"
}
trap cleanup EXIT

begin "tools"
need=()
command -v podman >/dev/null || need+=(podman)
command -v debootstrap >/dev/null || need+=(debootstrap)
command -v openssl >/dev/null || need+=(openssl)
if ((${#need[@]})); then
    log "installing ${need[*]} (apt)"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
fi
scripts/setup-postgres.sh
scripts/setup-s3.sh
python3 -c 'import yaml' 2>/dev/null || python3 -m pip install --quiet pyyaml
rm -rf "$artifacts"
mkdir -p "$artifacts"
work=$(mktemp -d /var/tmp/covec-container.XXXXXX)
# PostgreSQL's user works under it too.
chmod 711 "$work"
passed "$(podman --version)"

free_port() {
    python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}
# The fully qualified name podman resolves a Dockerfile's short name to.
qualified() {
    case $1 in
    */*/*) echo "$1" ;;
    */*) echo "docker.io/$1" ;;
    *) echo "docker.io/library/$1" ;;
    esac
}
# A base's default, from the Dockerfile (the one place that names it).
dockerfile_arg() {
    sed -n "s/^ARG $1=//p" Dockerfile | head -n 1
}
# The label recording what an image was made from, or nothing.
recipe_of() {
    podman image inspect --format '{{index .Labels "covec.recipe"}}' "$1" 2>/dev/null || true
}

runtime_base=$(qualified "$(dockerfile_arg RUNTIME_BASE)")
rust_base=$(qualified "$(dockerfile_arg RUST_BASE)")
[[ $runtime_base == docker.io/library/debian:*-slim ]] ||
    fail "the Dockerfile's runtime base $runtime_base is not a Debian slim image, which this script knows how to make"
suite=${runtime_base##*:}
suite=${suite%-slim}

# Debian's minbase, as the official slim images are made (debuerreotype: apt's and dpkg's
# settings for images, the documentation, manuals and translations left out now and on every
# later install, no apt caches or lists, no host names or resolver of this machine).
make_runtime_base() {
    local rootfs=$work/rootfs
    if ! debootstrap --variant=minbase "$suite" "$rootfs" http://deb.debian.org/debian \
        >"$artifacts/debootstrap.log" 2>&1; then
        tail -n 20 "$artifacts/debootstrap.log" >&2
        fail "debootstrap $suite"
    fi
    local conf=$rootfs/etc/apt/apt.conf.d
    cat >"$conf/docker-clean" <<'EOF'
DPkg::Post-Invoke { "rm -f /var/cache/apt/archives/*.deb /var/cache/apt/archives/partial/*.deb /var/cache/apt/*.bin || true"; };
APT::Update::Post-Invoke { "rm -f /var/cache/apt/archives/*.deb /var/cache/apt/archives/partial/*.deb /var/cache/apt/*.bin || true"; };
Dir::Cache::pkgcache "";
Dir::Cache::srcpkgcache "";
EOF
    echo 'Acquire::GzipIndexes "true";' >"$conf/docker-gzip-indexes"
    echo 'Acquire::Languages "none";' >"$conf/docker-no-languages"
    echo 'Apt::AutoRemove::SuggestsImportant "false";' >"$conf/docker-autoremove-suggests"
    rm -f "$conf/01autoremove-kernels"
    echo 'force-unsafe-io' >"$rootfs/etc/dpkg/dpkg.cfg.d/docker-apt-speedup"
    local excludes=(/usr/share/doc /usr/share/groff /usr/share/info /usr/share/linda
        /usr/share/lintian/overrides /usr/share/locale /usr/share/man)
    # Patterns for dpkg and find, not for this shell to expand.
    local includes=('/usr/share/doc/*/copyright' /usr/share/locale/all_languages
        '/usr/share/locale/currency/*' '/usr/share/locale/l10n/*' /usr/share/locale/languages
        /usr/share/locale/locale.alias)
    local dir pattern keep=()
    {
        echo '# The "slim" variant: files unneeded in containers stay out on every install.'
        for dir in "${excludes[@]}"; do echo "path-exclude $dir/*"; done
        for pattern in "${includes[@]}"; do echo "path-include $pattern"; done
    } >"$rootfs/etc/dpkg/dpkg.cfg.d/docker"
    for pattern in "${includes[@]}"; do keep+=(-not -path "$pattern"); done
    for dir in "${excludes[@]}"; do
        [[ -d $rootfs$dir ]] || continue
        # Inside the root, so that absolute symbolic links resolve there.
        chroot "$rootfs" find "$dir" -depth -mindepth 1 "${keep[@]}" -not -type d -delete
        chroot "$rootfs" find "$dir" -depth -mindepth 1 \( -empty -o -xtype l \) -delete
    done
    rm -f "$rootfs"/etc/apt/sources.list
    cat >"$rootfs/etc/apt/sources.list.d/debian.sources" <<EOF
Types: deb
URIs: http://deb.debian.org/debian
Suites: $suite $suite-updates
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg

Types: deb
URIs: http://deb.debian.org/debian-security
Suites: $suite-security
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg
EOF
    rm -rf "$rootfs"/var/cache/apt/* "$rootfs"/var/lib/apt/lists/* "$rootfs"/var/log/apt/*.log
    : >"$rootfs/etc/resolv.conf"
    : >"$rootfs/etc/hostname"
    tar --numeric-owner -C "$rootfs" --exclude=./proc/* --exclude=./sys/* -c . |
        podman import --quiet \
            --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
            --change 'CMD ["bash"]' \
            --change "LABEL covec.recipe=$1" - "$runtime_base" >/dev/null
    rm -rf "$rootfs"
}

# The official Rust image's layout (gcc, libc6-dev, ca-certificates; CARGO_HOME, RUSTUP_HOME),
# with this machine's toolchain in place of rustup's (no toolchain can be downloaded here).
make_rust_base() {
    local context=$work/rust-base sysroot
    sysroot=$(rustc --print sysroot)
    mkdir -p "$context/rust/bin"
    # Hard links: the toolchain is about 0.5 GB without its documentation.
    cp -al "$sysroot/lib" "$context/rust/" 2>/dev/null || cp -a "$sysroot/lib" "$context/rust/"
    for tool in cargo rustc rustdoc; do
        cp -al "$sysroot/bin/$tool" "$context/rust/bin/" 2>/dev/null || cp -a "$sysroot/bin/$tool" "$context/rust/bin/"
    done
    cp /etc/ssl/certs/ca-certificates.crt "$context/machine-roots.crt"
    cat >"$context/Containerfile" <<EOF
FROM $runtime_base
RUN apt-get update \\
 && apt-get install -y --no-install-recommends gcc libc6-dev ca-certificates \\
 && rm -rf /var/lib/apt/lists/*
COPY machine-roots.crt /usr/local/share/machine-roots.crt
RUN cat /usr/local/share/machine-roots.crt >> /etc/ssl/certs/ca-certificates.crt
COPY rust /usr/local/rust
ENV RUSTUP_HOME=/usr/local/rustup CARGO_HOME=/usr/local/cargo \\
    PATH=/usr/local/cargo/bin:/usr/local/rust/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin
LABEL covec.recipe=$1
EOF
    if ! podman build --isolation=chroot --quiet -t "$rust_base" "$context" \
        >"$artifacts/rust-base.log" 2>&1; then
        tail -n 20 "$artifacts/rust-base.log" >&2
        fail "building the Rust base"
    fi
    rm -rf "$context"
}

begin "bases"
# What each base is made from: this script's recipe, and for the builder also the toolchain and
# this machine's trust store.
runtime_recipe=$(declare -f make_runtime_base | cat - <(echo "$runtime_base") | sha256sum | cut -c1-16)
rust_recipe=$({
    declare -f make_rust_base
    echo "$runtime_recipe $rust_base"
    rustc -vV
    cat /etc/ssl/certs/ca-certificates.crt
} | sha256sum | cut -c1-16)
made=()
if [[ $(recipe_of "$runtime_base") != "$runtime_recipe" ]]; then
    make_runtime_base "$runtime_recipe"
    made+=("$runtime_base")
fi
if [[ $(recipe_of "$rust_base") != "$rust_recipe" ]]; then
    make_rust_base "$rust_recipe"
    made+=("$rust_base")
fi
passed "${made[*]:-both kept from an earlier run} ($(rustc --version))"

begin "build"
image=localhost/${COVEC_IMAGE:-covec:latest}
version=$(sed -n 's/^version = "\(.*\)"$/\1/p' Cargo.toml | head -n 1)
revision=$(git rev-parse HEAD 2>/dev/null || echo unknown)
# Docker's image format: the OCI one has no HEALTHCHECK.
if ! podman build --isolation=chroot --format docker --layers \
    --build-arg "VERSION=$version" --build-arg "REVISION=$revision" \
    -t "$image" . >"$artifacts/build.log" 2>&1; then
    tail -n 40 "$artifacts/build.log" >&2
    fail "podman build (log: $artifacts/build.log)"
fi
# The build stage's last layer stays tagged (the next build's cache); older builds' layers
# go (each holds a target/ directory).
podman build --isolation=chroot --format docker --layers --target build \
    -t localhost/covec-build-cache:latest . >>"$artifacts/build.log" 2>&1
podman image prune -f >/dev/null
passed "$image"

begin "image configuration"
podman image inspect "$image" >"$work/inspect.json"
# One value per line: ENTRYPOINT, CMD, environment, user, working directory, health check.
config() {
    python3 - "$work/inspect.json" "$1" <<'EOF'
import json, sys
image = json.load(open(sys.argv[1]))[0]
config = image.get("Config") or {}
health = image.get("Healthcheck") or config.get("Healthcheck") or {}
value = {
    "entrypoint": config.get("Entrypoint") or [],
    "cmd": config.get("Cmd") or [],
    "env": config.get("Env") or [],
    "user": [config.get("User") or "0:0"],
    "workdir": [config.get("WorkingDir") or "/"],
    "healthcheck": health.get("Test") or [],
    "labels": [f"{k}={v}" for k, v in sorted((config.get("Labels") or {}).items())],
}[sys.argv[2]]
print("\n".join(value))
EOF
}
mapfile -t entrypoint < <(config entrypoint)
mapfile -t cmd < <(config cmd)
mapfile -t image_env < <(config env)
user=$(config user)
mapfile -t healthcheck < <(config healthcheck)
[[ $user =~ ^[0-9]+:[0-9]+$ ]] || fail "USER is \"$user\": expected a numeric uid:gid (the manifests' runAsUser)"
[[ $(config workdir) == / ]] || fail "WORKDIR is not / (chroot starts there)"
((${#entrypoint[@]})) || fail "no ENTRYPOINT"
[[ ${healthcheck[0]:-} == CMD ]] || fail "HEALTHCHECK is \"${healthcheck[*]:-none}\": expected an exec-form CMD"
health=("${healthcheck[@]:1}")
config labels | grep -q '^org.opencontainers.image.version=' || fail "no OCI version label"
passed "user $user, ENTRYPOINT+CMD \"${entrypoint[*]} ${cmd[*]}\", HEALTHCHECK \"${health[*]}\""

begin "size"
size_mb() { python3 -c "print(f'{$1 / 1e6:.1f}')"; }
total=$(podman image inspect --format '{{.Size}}' "$image")
base=$(podman image inspect --format '{{.Size}}' "$runtime_base")
base_layers=$(podman history --quiet "$runtime_base" | wc -l)
{
    echo "runtime image $image: $(size_mb "$total") MB; its base $runtime_base (made here): $(size_mb "$base") MB; the Dockerfile adds $(size_mb "$((total - base))") MB:"
    podman history --format '{{.Size}}\t{{.CreatedBy}}' "$image" | head -n "-$base_layers" |
        cut -c1-110 | sed 's/^/    /'
} | tee "$artifacts/size.txt" >&2
((total <= 120 * 1000 * 1000)) || log "note: the image is over the 120 MB goal"
passed "$(size_mb "$total") MB in all, $(size_mb "$((total - base))") MB above the base"

begin "export"
root=$work/root
mkdir "$root"
cid=$(podman create "$image")
podman export "$cid" | tar -x -C "$root"
# (podman complains here that there is no systemd to remove a health-check timer from.)
podman rm "$cid" >/dev/null 2>>"$artifacts/podman.log"
passed "$(du -sm "$root" | cut -f1) MB of files"

begin "TLS roots"
bundle=$root/etc/ssl/certs/ca-certificates.crt
[[ -s $bundle ]] || fail "no $bundle in the image"
roots=$(grep -c 'BEGIN CERTIFICATE' "$bundle")
((roots >= 100)) || fail "only $roots certificates in the image's trust store"
[[ ! -e $root/usr/bin/curl ]] || fail "curl is in the runtime image"
[[ ! -e $root/usr/local/share/machine-roots.crt ]] || fail "the builder's trust store reached the runtime image"
passed "$roots certificates in /etc/ssl/certs/ca-certificates.crt (Debian's ca-certificates); no curl"

# Sets `run` to the command that runs a program in the image as its user, with its environment
# and then the NAME=VALUE overrides given: `in_image NAME=VALUE...; "${run[@]}" ARGS...`. env
# and chroot each exec the next, so a process started in the background is the program itself.
in_image() {
    run=(env -i "${image_env[@]}" "$@" chroot --userspec="$user" "$root")
}
# Waits until FILE has a line with TEXT (a server printing its address) or PID exits.
wait_for_line() {
    local file=$1 text=$2 pid=$3
    for _ in $(seq 300); do
        grep -q "$text" "$file" 2>/dev/null && return 0
        kill -0 "$pid" 2>/dev/null || return 1
        sleep 0.1
    done
    return 1
}
params='{"max_size":48,"paths":8,"seed":1,"iterations":{"structure":3,"reconstruction":3,"refine":3,"refine_rounds":1,"polish":3}}'
fixture=tests/fixtures/emoji_red-apple.png

begin "one node: refuses to start open"
# The image as shipped (COVEC_ADDR=0.0.0.0:8080) without API keys: one line, non-zero exit.
in_image
if "${run[@]}" "${entrypoint[@]}" "${cmd[@]}" >"$artifacts/refused.out" 2>"$artifacts/refused.log"; then
    fail "\"${entrypoint[*]} ${cmd[*]}\" started on 0.0.0.0 without API keys"
fi
[[ $(wc -l <"$artifacts/refused.log") -eq 1 ]] && grep -q "without API keys" "$artifacts/refused.log" ||
    fail "the refusal is not one line: $(cat "$artifacts/refused.log")"
passed "$(cat "$artifacts/refused.log")"

begin "one node: start"
port=$(free_port)
in_image "COVEC_ADDR=127.0.0.1:$port"
"${run[@]}" "${entrypoint[@]}" "${cmd[@]}" \
    >"$artifacts/serve.out" 2>"$artifacts/serve.log" &
serve_pid=$!
pids+=("$serve_pid")
wait_for_line "$artifacts/serve.out" "listening on" "$serve_pid" ||
    fail "\"${entrypoint[*]} ${cmd[*]}\" did not start (log: $artifacts/serve.log)"
passed "\"${entrypoint[*]} ${cmd[*]}\" as $user: $(head -n 1 "$artifacts/serve.out")"

begin "one node: health check"
"${run[@]}" "${health[@]}" ||
    fail "the image's HEALTHCHECK \"${health[*]}\" failed against the running service"
passed "\"${health[*]}\" exit 0 (/healthz 200)"

begin "one node: a job"
job=$(curl -sS --fail-with-body --max-time 120 -H 'Prefer: wait=100' -F "image=@$fixture" \
    -F "params=$params;type=application/json" "http://127.0.0.1:$port/v1/jobs") ||
    fail "POST /v1/jobs: $job"
read -r id status < <(python3 -c 'import json, sys; j = json.loads(sys.argv[1]); print(j["id"], j["status"])' "$job")
[[ $status == succeeded ]] || fail "job $id is $status: $job"
curl -sS --fail --max-time 30 -o "$artifacts/one-node.svg" "http://127.0.0.1:$port/v1/jobs/$id/svg" ||
    fail "GET /v1/jobs/$id/svg"
grep -q '<svg' "$artifacts/one-node.svg" || fail "the SVG of job $id is not SVG"
grep -q 'mix-blend-mode' "$artifacts/one-node.svg" || fail "the SVG of job $id has no blended layers"
passed "$fixture -> job $id succeeded, SVG $(wc -c <"$artifacts/one-node.svg") bytes (in /data, uid ${user%%:*})"

begin "one node: health check when stopped"
kill "$serve_pid"
wait "$serve_pid" || fail "covec serve exited with $? on SIGTERM (log: $artifacts/serve.log)"
if "${run[@]}" "${health[@]}" 2>"$work/health.err"; then
    fail "the health check passed with the service stopped"
fi
[[ $(wc -l <"$work/health.err") -eq 1 ]] || fail "the failing health check printed: $(cat "$work/health.err")"
passed "SIGTERM: clean exit; then the health check fails: $(cat "$work/health.err")"

begin "scaled: PostgreSQL and S3 over HTTPS"
# PostgreSQL refuses root: as `postgres`, as tests/service/service_support/postgres.rs runs it.
pg_bin=$(find /usr/lib/postgresql -path '*/bin/initdb' -printf '%h\n' 2>/dev/null | sort -V | tail -n 1)
[[ -n $pg_bin ]] || pg_bin=$(dirname "$(command -v initdb)")
as_postgres() { setpriv --reuid=postgres --regid=postgres --init-groups "$@"; }
mkdir "$work/pg"
chown postgres "$work/pg"
as_postgres "$pg_bin/initdb" -D "$work/pg/data" -U covec --auth=trust -E UTF8 --no-sync >/dev/null
pg_port=$(free_port)
as_postgres "$pg_bin/postgres" -D "$work/pg/data" -p "$pg_port" -h 127.0.0.1 -k "$work/pg" \
    -c fsync=off >"$artifacts/postgres.log" 2>&1 &
pids+=($!)
for _ in $(seq 300); do
    pg_isready -q -h 127.0.0.1 -p "$pg_port" && break
    sleep 0.1
done
psql -q "postgres://covec@127.0.0.1:$pg_port/postgres" -c 'CREATE DATABASE covec' ||
    fail "PostgreSQL did not start (log: $artifacts/postgres.log)"
# A throwaway CA and a certificate for 127.0.0.1 that it signs.
tls=$work/tls
mkdir "$tls"
openssl req -x509 -newkey rsa:2048 -nodes -days 1 -subj /CN=covec-test-ca \
    -keyout "$tls/ca.key" -out "$tls/ca.crt" 2>/dev/null
openssl req -newkey rsa:2048 -nodes -subj /CN=127.0.0.1 -keyout "$tls/s3.key" -out "$tls/s3.csr" 2>/dev/null
printf 'subjectAltName=IP:127.0.0.1\nbasicConstraints=CA:FALSE\nextendedKeyUsage=serverAuth\n' >"$tls/ext"
openssl x509 -req -days 1 -in "$tls/s3.csr" -CA "$tls/ca.crt" -CAkey "$tls/ca.key" \
    -CAcreateserial -extfile "$tls/ext" -out "$tls/s3.crt" 2>/dev/null
s3_port=$(free_port)
moto_server -H 127.0.0.1 -p "$s3_port" -c "$tls/s3.crt" -k "$tls/s3.key" >"$artifacts/moto.log" 2>&1 &
pids+=($!)
s3=https://127.0.0.1:$s3_port
s3_curl() { curl -sS --fail --max-time 30 --cacert "$tls/ca.crt" --aws-sigv4 aws:amz:us-east-1:s3 --user covec:secret "$@"; }
for _ in $(seq 300); do
    curl -s --cacert "$tls/ca.crt" -o /dev/null "$s3/" && break
    sleep 0.1
done
cat "$tls/ca.crt" >>"$bundle"
passed "PostgreSQL $("$pg_bin/postgres" --version | awk '{print $3}') on :$pg_port, moto on $s3 (its CA added to the exported image's trust store)"

begin "scaled: deploy/compose-scaled.yaml's API and worker"
api_port=$(free_port)
ops_port=$(free_port)
# The Compose file as Compose resolves it, with an API key given as its users give one.
api_key=container-test-key
PATH="$(scripts/setup-deploy-tools.sh):$PATH"
env -u COVEC_IMAGE COVEC_API_KEYS=$api_key docker-compose -f deploy/compose-scaled.yaml \
    config --format json >"$work/compose-scaled.json" || fail "docker compose config"
# A service of the rendered Compose file: its image, then its command, health check and
# environment, one per line, with the Compose network's names and ports replaced by this
# machine's loopback ones.
compose_service() {
    python3 - "$work/compose-scaled.json" "$1" \
        "postgres:5432=127.0.0.1:$pg_port" "http://seaweedfs:8333=$s3" \
        "0.0.0.0:8080=127.0.0.1:$api_port" ":9090=:$ops_port" <<'EOF'
import json, sys
path, name, *replacements = sys.argv[1:]
service = json.load(open(path))["services"][name]
pairs = [r.split("=", 1) for r in replacements]
def local(text):
    for old, new in pairs:
        text = text.replace(old, new)
    return text
print(service["image"])
for args in service["command"], service.get("healthcheck", {}).get("test", []):
    print(len(args))
    for arg in args:
        print(local(arg))
# Plain HTTP to the bucket is for Compose's SeaweedFS; here the store speaks HTTPS. A variable
# without a value (COVEC_THREADS) is unset in the container, as Compose leaves it.
for name, value in service["environment"].items():
    if name != "AWS_ALLOW_HTTP" and value is not None:
        print(f"{name}={local(str(value))}")
EOF
}
start_service() {
    local name=$1 lines command health env
    mapfile -t lines < <(compose_service "$name")
    compose_image=${lines[0]}
    command=("${lines[@]:2:${lines[1]}}")
    local at=$((2 + ${lines[1]}))
    health=("${lines[@]:$((at + 1)):${lines[at]}}")
    env=("${lines[@]:$((at + 1 + ${lines[at]}))}")
    in_image "${env[@]}"
    "${run[@]}" "${entrypoint[@]}" "${command[@]}" \
        >"$artifacts/$name.out" 2>"$artifacts/$name.log" &
    pids+=($!)
    service_pid=$!
    service_command=("${command[@]}")
    service_health=("${health[@]}")
}
s3_curl -X PUT "$s3/covec-artefacts" >/dev/null || fail "creating the bucket (log: $artifacts/moto.log)"
start_service api-1
api_pid=$service_pid
api_command=("${service_command[@]}")
wait_for_line "$artifacts/api-1.out" "listening on" "$api_pid" ||
    fail "api-1 \"${api_command[*]}\" did not start (log: $artifacts/api-1.log)"
start_service worker
worker_pid=$service_pid
worker_command=("${service_command[@]}")
worker_health=("${service_health[@]}")
wait_for_line "$artifacts/worker.out" "probes and metrics on" "$worker_pid" ||
    fail "worker \"${worker_command[*]}\" did not start (log: $artifacts/worker.log)"
passed "api-1 \"${api_command[*]}\" on :$api_port with an API key, worker \"${worker_command[*]}\" ($compose_image)"

begin "scaled: worker health"
((${#worker_health[@]})) && [[ ${worker_health[0]} == CMD ]] ||
    fail "the worker's Compose healthcheck is \"${worker_health[*]}\": expected an exec-form CMD"
in_image
"${run[@]}" "${worker_health[@]:1}" || fail "the worker's health check \"${worker_health[*]:1}\" failed"
"${run[@]}" "${entrypoint[@]}" healthcheck --url "http://127.0.0.1:$ops_port/healthz" ||
    fail "the worker's /healthz failed (log: $artifacts/worker.log)"
passed "\"${worker_health[*]:1}\" exit 0, and /healthz on its --ops-addr"

begin "scaled: a job through the API and the worker"
anonymous=$(curl -sS -o /dev/null -w '%{http_code}' --max-time 10 "http://127.0.0.1:$api_port/v1/jobs")
[[ $anonymous == 401 ]] || fail "GET /v1/jobs without the key answered $anonymous, not 401"
# The scheme in any case (RFC 9110).
job=$(curl -sS --fail-with-body --max-time 30 -H "Authorization: bearer $api_key" -F "image=@$fixture" \
    -F "params=$params;type=application/json" "http://127.0.0.1:$api_port/v1/jobs") ||
    fail "POST /v1/jobs: $job"
id=$(python3 -c 'import json, sys; print(json.loads(sys.argv[1])["id"])' "$job")
status=queued
for _ in $(seq 240); do
    job=$(curl -sS --fail --max-time 10 -H "Authorization: BEARER $api_key" "http://127.0.0.1:$api_port/v1/jobs/$id") ||
        fail "GET /v1/jobs/$id"
    status=$(python3 -c 'import json, sys; print(json.loads(sys.argv[1])["status"])' "$job")
    [[ $status == queued || $status == running ]] || break
    sleep 0.5
done
[[ $status == succeeded ]] || fail "job $id is $status: $job (logs: $artifacts/worker.log)"
# Through the signed URL the job resource gives its key, as a browser's <img> would: no header.
svg_url=$(python3 -c 'import json, sys; print(json.loads(sys.argv[1])["signed"]["results"]["svg"])' "$job") ||
    fail "no signed SVG URL in the job: $job"
curl -sS --fail --max-time 30 -o "$artifacts/scaled.svg" "http://127.0.0.1:$api_port$svg_url" ||
    fail "GET $svg_url"
grep -q 'mix-blend-mode' "$artifacts/scaled.svg" || fail "the SVG of job $id has no blended layers"
listing=$(s3_curl "$s3/covec-artefacts?list-type=2") || fail "listing the bucket"
objects=$(grep -o "<Key>[^<]*/$id/[^<]*</Key>" <<<"$listing" | wc -l)
((objects > 0)) || fail "no object of job $id in the bucket: $listing"
record=$(psql -XAtq "postgres://covec@127.0.0.1:$pg_port/covec" -c "SELECT status FROM jobs WHERE id = '$id'") ||
    fail "reading job $id's record in PostgreSQL"
[[ $record == succeeded ]] || fail "job $id's record in PostgreSQL says \"$record\""
passed "job $id succeeded on the worker (keyed: 401 without the key, \"bearer\" and \"BEARER\" taken), SVG $(wc -c <"$artifacts/scaled.svg") bytes through its signed URL, $objects objects in the bucket, its record in PostgreSQL"

begin "scaled: stop"
kill "$api_pid" "$worker_pid"
wait "$api_pid" || fail "api-1 exited with $? on SIGTERM"
wait "$worker_pid" || fail "the worker exited with $? on SIGTERM"
passed "SIGTERM: both exited cleanly"

{
    echo "container-test: passed in $((SECONDS - started)) s"
    printf '  %s\n' "${summary[@]}"
    echo "  not run here, and why:"
    echo "    - podman run / docker run / docker compose up: no Docker engine on these machines, and podman"
    echo "      run is refused (crun cannot set the container's rlimits: setrlimit not permitted). The image's"
    echo "      file system ran under chroot as its USER instead: no namespaces, cgroups, read-only root,"
    echo "      dropped capabilities or seccomp as a runtime or Kubernetes would apply them."
    echo "    - the engine's HEALTHCHECK schedule (interval, retries): its command was run once, by hand."
    echo "    - Compose's postgres and seaweedfs images (no registry here):"
    echo "      Debian's PostgreSQL and moto's S3 server stood in, on loopback ports instead of Compose's"
    echo "      network names; one worker instead of its 2 replicas."
    echo "    - Kubernetes (no cluster): deploy/kubernetes is rendered and validated by scripts/check-deploy.sh."
} | tee "$artifacts/summary.txt"
