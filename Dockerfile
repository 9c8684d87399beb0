# covec serve: multi-stage build, non-root runtime, data directory as a volume.
# Not built in the development environment (no Docker there); kept to standard instructions.

FROM rust:1.95-slim-bookworm AS build
# Debian's stable packages are pinned by the base image's release, not by version: a pinned
# version disappears from the archive at the next point release and the build breaks.
# hadolint ignore=DL3008
RUN apt-get update \
 && apt-get install -y --no-install-recommends pkg-config libsqlite3-dev \
 && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY . .
RUN cargo build --release --locked --bin covec \
 && install -m 0755 target/release/covec /usr/local/bin/covec

FROM debian:bookworm-slim
# hadolint ignore=DL3008
RUN apt-get update \
 && apt-get install -y --no-install-recommends libsqlite3-0 curl \
 && rm -rf /var/lib/apt/lists/* \
 && useradd --system --uid 10001 --home-dir /data --shell /usr/sbin/nologin covec \
 && mkdir -p /data && chown covec:covec /data
COPY --from=build /usr/local/bin/covec /usr/local/bin/covec
USER 10001:10001
ENV COVEC_ADDR=0.0.0.0:8080 \
    COVEC_DATA_DIR=/data \
    COVEC_LOG=info
VOLUME ["/data"]
EXPOSE 8080
STOPSIGNAL SIGTERM
HEALTHCHECK --interval=15s --timeout=3s --start-period=10s --retries=3 \
  CMD ["curl", "-fsS", "-o", "/dev/null", "http://127.0.0.1:8080/healthz"]
ENTRYPOINT ["covec"]
CMD ["serve"]
