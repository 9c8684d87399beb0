# covec: multi-stage build, non-root runtime, data directory as a volume. Builds with Docker
# (BuildKit or the classic builder), podman and buildah; scripts/container-test.sh builds it and
# starts the result in the test command (docs/operations.md, "Container image").
#
# Bases by tag. To pin one to the exact image a registry serves for its tag, give the digest:
#   docker buildx imagetools inspect debian:bookworm-slim    (or: skopeo inspect --format
#   '{{.Digest}}' docker://docker.io/library/debian:bookworm-slim) prints it, then
#   --build-arg RUNTIME_BASE=debian:bookworm-slim@sha256:<digest> (RUST_BASE likewise),
# or write the digest into the defaults below.
ARG RUST_BASE=rust:1.95-slim-bookworm
ARG RUNTIME_BASE=debian:bookworm-slim

FROM ${RUST_BASE} AS build
# Debian's stable packages are pinned by the base image's release, not by version: a pinned
# version disappears from the archive at the next point release and the build breaks.
# hadolint ignore=DL3008
RUN apt-get update \
 && apt-get install -y --no-install-recommends pkg-config libsqlite3-dev \
 && rm -rf /var/lib/apt/lists/*
WORKDIR /src
# The image's binary carries no debug info or symbols (most of its size). Only here: the
# repository's release profile keeps line tables for profiling the benchmarks. Set before the
# dependency layer, so that both builds below use the same profile.
ENV CARGO_PROFILE_RELEASE_DEBUG=false \
    CARGO_PROFILE_RELEASE_STRIP=symbols
# The dependencies in a layer of their own, rebuilt only when Cargo.toml or Cargo.lock change
# (what cargo-chef does, without a tool to install): the package's manifest over empty sources.
# Layer caching works with every builder and with exported build caches (--cache-to), which
# BuildKit's cache mounts do not reach. The manifest's [[bench]] needs its file to exist; it
# is never built here, nor is the workspace's Python package, whose manifest cargo must read
# (an empty library stands for its sources). vendor/ holds a patched dependency
# (vendor/README.md).
COPY Cargo.toml Cargo.lock ./
COPY python/Cargo.toml python/Cargo.toml
COPY vendor vendor
RUN mkdir src benches python/src \
 && echo 'fn main() {}' > src/main.rs \
 && cp src/main.rs benches/render.rs \
 && touch src/lib.rs python/src/lib.rs \
 && cargo build --release --locked --bin covec \
 && rm -rf src
# What the binary is built from; .dockerignore keeps the rest of the tree out of the context.
COPY src src
COPY migrations migrations
# The copied sources keep their own, older times: touch the roots so that cargo rebuilds the
# package over the placeholder.
RUN touch src/lib.rs src/main.rs \
 && cargo build --release --locked --bin covec \
 && install -m 0755 target/release/covec /usr/local/bin/covec

FROM ${RUNTIME_BASE}
# ca-certificates: the trust store the S3 client (--object-store over HTTPS) verifies servers
# against (webhooks and PostgreSQL use the roots compiled in). libsqlite3-0: the embedded job
# database.
# hadolint ignore=DL3008
RUN apt-get update \
 && apt-get install -y --no-install-recommends ca-certificates libsqlite3-0 \
 && rm -rf /var/lib/apt/lists/* \
 && groupadd --system --gid 10001 covec \
 && useradd --system --uid 10001 --gid 10001 --home-dir /data --no-create-home \
      --shell /usr/sbin/nologin covec \
 && mkdir -p /data && chown covec:covec /data
COPY --from=build /usr/local/bin/covec /usr/local/bin/covec
USER 10001:10001
ENV COVEC_ADDR=0.0.0.0:8080 \
    COVEC_DATA_DIR=/data \
    COVEC_LOG=info
VOLUME ["/data"]
EXPOSE 8080
STOPSIGNAL SIGTERM
# `covec serve`'s /healthz at COVEC_ADDR. A `covec worker` has no API port: give its
# --ops-addr, e.g. `covec healthcheck --url http://127.0.0.1:9090/healthz` (deploy/compose-scaled.yaml).
HEALTHCHECK --interval=15s --timeout=3s --start-period=10s --retries=3 \
  CMD ["/usr/local/bin/covec", "healthcheck"]
ENTRYPOINT ["/usr/local/bin/covec"]
CMD ["serve"]
# Last, so that a new revision changes no layer above. VERSION and REVISION are the build's to
# give (scripts/container-test.sh passes Cargo.toml's version and the commit).
ARG RUNTIME_BASE
ARG VERSION=unknown
ARG REVISION=unknown
LABEL org.opencontainers.image.title="covec" \
      org.opencontainers.image.description="Photographs to layered, editable SVG (COVec): HTTP service, workers and command line" \
      org.opencontainers.image.licenses="Apache-2.0" \
      org.opencontainers.image.version="${VERSION}" \
      org.opencontainers.image.revision="${REVISION}" \
      org.opencontainers.image.base.name="${RUNTIME_BASE}"
