#!/usr/bin/env python3
"""How soon a job's first draft reaches a client (docs/benchmarks.md, "The first draft").

Starts one `covec serve` (1 worker, `--threads` threads) and runs the bench's images one job at a
time (`--paths` paths, the images' own size). For each job it follows `GET /v1/jobs/{id}/events`
from the submission on and notes when the first `event: draft` arrives, fetches the draft's URL
(a layered SVG, checked to parse and to hold the three layers), and waits for the job's end.
Prints per image: the draft's latency from the job's start (`started_at`, the server's clock,
the same machine's) and from the submission, the job's own run time, and the stage the draft came
after; then the medians. Exits 1 if a job has no draft before its end, or a draft does not parse.
Standard library only.

    python3 benches/service/first_draft.py target/release/covec --bench BENCH \\
        [--paths 64] [--threads 2]
"""

import argparse
import datetime
import glob
import http.client
import json
import os
import signal
import socket
import statistics
import subprocess
import tempfile
import time
import xml.etree.ElementTree as ElementTree


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def submit(port, image_path, params):
    boundary = "covecbench"
    with open(image_path, "rb") as f:
        image = f.read()
    name = os.path.basename(image_path)
    body = (
        f"--{boundary}\r\nContent-Disposition: form-data; name=\"image\"; filename=\"{name}\"\r\n"
        "Content-Type: image/png\r\n\r\n".encode() + image
        + f"\r\n--{boundary}\r\nContent-Disposition: form-data; name=\"params\"\r\n"
        "Content-Type: application/json\r\n\r\n".encode() + json.dumps(params).encode()
        + f"\r\n--{boundary}--\r\n".encode()
    )
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    conn.request("POST", "/v1/jobs", body, {"content-type": f"multipart/form-data; boundary={boundary}"})
    response = conn.getresponse()
    data = response.read()
    conn.close()
    if response.status != 201:
        raise SystemExit(f"first_draft: POST /v1/jobs answered {response.status}: {data[:200]!r}")
    return json.loads(data)["id"]


def events(port, job):
    """(arrival time, event name, job) for each event of the job's stream, as they come."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=600)
    conn.request("GET", f"/v1/jobs/{job}/events", headers={"accept": "text/event-stream"})
    response = conn.getresponse()
    name, data = None, []
    while True:
        line = response.readline()
        if not line:
            break
        line = line.decode().rstrip("\r\n")
        if line.startswith("event:"):
            name = line[6:].strip()
        elif line.startswith("data:"):
            data.append(line[5:].strip())
        elif not line and data:
            yield time.time(), name, json.loads("\n".join(data))
            name, data = None, []
    conn.close()


def seconds_of(rfc3339):
    return datetime.datetime.fromisoformat(rfc3339.replace("Z", "+00:00")).timestamp()


def get(port, path):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    conn.request("GET", path, headers={"cache-control": "no-cache"})
    response = conn.getresponse()
    data = response.read()
    conn.close()
    return response.status, data


def check_draft(svg):
    """Why the draft is not a complete layered SVG, or None."""
    try:
        root = ElementTree.fromstring(svg)
    except ElementTree.ParseError as error:
        return f"does not parse: {error}"
    groups = {g.get("id") for g in root.iter("{http://www.w3.org/2000/svg}g")}
    missing = {"albedo", "shade", "light"} - groups
    paths = sum(1 for _ in root.iter("{http://www.w3.org/2000/svg}path"))
    if missing:
        return f"no {', '.join(sorted(missing))} layer"
    return None if paths else "no paths"


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("covec")
    parser.add_argument("--bench", required=True, help="the covec-bench directory")
    parser.add_argument("--paths", type=int, default=64)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    images = sorted(glob.glob(os.path.join(args.bench, "*", "*.png")))
    if not images:
        raise SystemExit(f"first_draft: no PNG images under {args.bench}/*/")

    data_dir = tempfile.mkdtemp(prefix="covec-first-draft-")
    port = free_port()
    server = subprocess.Popen(
        [args.covec, "serve", "--addr", f"127.0.0.1:{port}", "--data-dir", data_dir,
         "--workers", "1", "--threads", str(args.threads)],
        stdout=subprocess.PIPE, stderr=open(os.path.join(data_dir, "serve.log"), "w"))
    server.stdout.readline()
    failed, rows = [], []
    try:
        # One job first, not counted: the worker's threads and the allocator warm up.
        for path in images[:1] + images:
            submitted = time.time()
            job = submit(port, path, {"paths": args.paths})
            draft_at, first, end = None, None, None
            for arrived, name, state in events(port, job):
                if name == "draft" and draft_at is None:
                    draft_at, first = arrived, state
                if name == "completed":
                    end = state
            if end is None or end["status"] != "succeeded":
                failed.append(f"{path}: the job ended {end and end['status']}")
                continue
            if draft_at is None:
                failed.append(f"{path}: no draft event before the end")
                continue
            status, svg = get(port, first["draft"]["url"])
            problem = f"answered {status}" if status != 200 else check_draft(svg)
            if problem:
                failed.append(f"{path}: the draft {problem}")
            started = seconds_of(first["started_at"])
            run = seconds_of(end["completed_at"]) - started
            rows.append((os.path.basename(path), (draft_at - started) * 1000,
                         (draft_at - submitted) * 1000, run, first["draft"]["stage"]))
        rows = rows[1:]
        print(f"{'image':28} {'draft after start':>18} {'after submit':>13} {'job':>7}  stage")
        for name, from_start, from_submit, run, stage in rows:
            print(f"{name:28} {from_start:15.0f} ms {from_submit:10.0f} ms {run:6.2f} s  {stage}")
        if rows:
            print(f"median over {len(rows)} images: {statistics.median(r[1] for r in rows):.0f} ms "
                  f"after the start, {statistics.median(r[2] for r in rows):.0f} ms after the "
                  f"submission; max {max(r[1] for r in rows):.0f} ms; the jobs' median "
                  f"{statistics.median(r[3] for r in rows):.2f} s")
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(timeout=120)
    if failed:
        for line in failed:
            print(f"first_draft: FAILED {line}")
        raise SystemExit(1)


if __name__ == "__main__":
    main()
