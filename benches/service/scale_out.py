#!/usr/bin/env python3
"""Throughput of the shared backend with N workers (issue 14): one API replica
(`covec serve --workers 0`) and N `covec worker --threads 1` processes on one PostgreSQL
database and one scratch data directory; submits every PNG under the image folders as a
64-path job, waits for all to succeed, prints jobs per minute, stops the processes and empties
the jobs table. Standard library only; PostgreSQL is the caller's (`--database-url`).

    python3 benches/service/scale_out.py BIN --database-url postgres://… --workers 2 DIR…
    farm-bench -n 3 --timeout 1800 --vs 'python3 benches/service/scale_out.py BIN --database-url URL --workers 1 DIR…' \\
        -- python3 benches/service/scale_out.py BIN --database-url URL --workers 2 DIR…
"""

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
import uuid

PARAMS = json.dumps({"paths": 64})


def submit(base, image_path):
    boundary = uuid.uuid4().hex
    with open(image_path, "rb") as f:
        image = f.read()
    body = b"".join([
        f"--{boundary}\r\nContent-Disposition: form-data; name=\"image\"; filename=\"i.png\"\r\n"
        f"Content-Type: image/png\r\n\r\n".encode(), image, b"\r\n",
        f"--{boundary}\r\nContent-Disposition: form-data; name=\"params\"\r\n"
        f"Content-Type: application/json\r\n\r\n{PARAMS}\r\n--{boundary}--\r\n".encode(),
    ])
    request = urllib.request.Request(
        f"{base}/v1/jobs", data=body, method="POST",
        headers={"content-type": f"multipart/form-data; boundary={boundary}"})
    with urllib.request.urlopen(request) as response:
        return json.load(response)["id"]


def status(base, job):
    with urllib.request.urlopen(f"{base}/v1/jobs/{job}") as response:
        return json.load(response)["status"]


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("covec")
    parser.add_argument("dirs", nargs="+")
    parser.add_argument("--database-url", required=True)
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    images = sorted(os.path.join(d, name) for d in args.dirs for name in os.listdir(d)
                    if name.endswith(".png"))
    data = tempfile.mkdtemp(prefix="covec-scale-")
    common = ["--data-dir", data, "--database-url", args.database_url]
    log = open(os.path.join(data, "log"), "w")
    api = subprocess.Popen([args.covec, "serve", "--addr", "127.0.0.1:0", "--workers", "0", *common],
                           stdout=subprocess.PIPE, stderr=log, text=True)
    base = api.stdout.readline().strip().removeprefix("covec serve: listening on ")
    workers = [subprocess.Popen([args.covec, "worker", "--threads", "1", *common],
                                stdout=subprocess.DEVNULL, stderr=log)
               for _ in range(args.workers)]
    started = time.monotonic()
    try:
        jobs = [submit(base, image) for image in images]
        pending = set(jobs)
        while pending:
            for job in list(pending):
                state = status(base, job)
                if state in ("failed", "canceled"):
                    sys.exit(f"job {job} {state}")
                if state == "succeeded":
                    pending.discard(job)
            time.sleep(0.2)
        minutes = (time.monotonic() - started) / 60
        print(f"{len(jobs)} jobs, {args.workers} workers: {len(jobs) / minutes:.1f} jobs/min")
    finally:
        for process in [api, *workers]:
            process.send_signal(signal.SIGTERM)
        for process in [api, *workers]:
            process.wait()
        subprocess.run(["psql", args.database_url, "-Xq", "-c", "DELETE FROM jobs"], check=True)
        subprocess.run(["rm", "-rf", data], check=True)


if __name__ == "__main__":
    main()
