#!/usr/bin/env python3
"""An interactive job behind a batch backlog (issue 20): one `covec serve --workers 1` with API
keys `a` and `b`; key `a` queues 60 batch jobs (a 96 px photo at `max_size` 64, so 64² jobs);
once two of them have succeeded, key `b` submits one interactive job of the same kind at a
random moment of the job then running, and its time from submission to success, L, is read
from its record. The job duration D is the mean run time of the jobs that ran meanwhile (the
one of `a` running when `b`'s arrived, and `b`'s), so load on the machine during the run
counts in both. Prints L / D per run (the issue asks for at most 2: the rest of the running
job, then `b`'s own), and how far the job's `estimated_start_at` was from its real start.

    python3 benches/service/fair_latency.py BIN [--runs 5] [--database-url postgres://…]

With `--database-url` the server keeps its queue in that PostgreSQL (its job slot claims by
the SQL rule); the jobs it made are deleted after. Standard library only.
"""

import argparse
import contextlib
import datetime
import http.client
import json
import os
import random
import signal
import statistics
import subprocess
import tempfile
import time
import uuid

IMAGE = os.path.join(os.path.dirname(__file__), "../../tests/fixtures/photo96_face_hopper.png")
PARAMS = json.dumps({"max_size": 64, "seed": 1})
BACKLOG = 60


@contextlib.contextmanager
def server(covec, database_url):
    """Yields a connection factory for `covec serve` with one worker and keys `a`, `b`."""
    data = tempfile.mkdtemp(prefix="covec-fair-")
    extra = ["--database-url", database_url] if database_url else []
    log = open(os.path.join(data, "log"), "w")
    process = subprocess.Popen(
        [covec, "serve", "--addr", "127.0.0.1:0", "--data-dir", data, "--workers", "1",
         "--max-queued", "200", "--api-keys", "a,b", *extra],
        stdout=subprocess.PIPE, stderr=log, text=True)
    host, port = process.stdout.readline().strip().rsplit("/", 1)[1].split(":")
    try:
        yield lambda: http.client.HTTPConnection(host, int(port))
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait()
        if database_url:
            subprocess.run(["psql", database_url, "-Xq", "-c",
                            "DELETE FROM jobs; DELETE FROM queue_clients"], check=True)
        subprocess.run(["rm", "-rf", data], check=True)


def call(connection, method, path, key, body=None, headers=None):
    connection.request(method, path, body=body,
                       headers={"authorization": f"Bearer {key}", **(headers or {})})
    response = connection.getresponse()
    return response.status, json.loads(response.read() or b"null")


def submit(connection, key, priority):
    boundary = uuid.uuid4().hex
    with open(IMAGE, "rb") as f:
        image = f.read()
    part = f"--{boundary}\r\nContent-Disposition: form-data; name=\"{{}}\"\r\n\r\n{{}}\r\n"
    body = b"".join([
        f"--{boundary}\r\nContent-Disposition: form-data; name=\"image\"; filename=\"i.png\"\r\n"
        f"Content-Type: image/png\r\n\r\n".encode(), image, b"\r\n",
        part.format("params", PARAMS).encode(), part.format("priority", priority).encode(),
        f"--{boundary}--\r\n".encode(),
    ])
    status, job = call(connection, "POST", "/v1/jobs", key, body,
                       {"content-type": f"multipart/form-data; boundary={boundary}"})
    assert status == 201, job
    return job


def seconds(timestamp):
    return datetime.datetime.fromisoformat(timestamp.replace("Z", "+00:00")).timestamp()


def run(covec, database_url):
    with server(covec, database_url) as connect:
        connection = connect()
        backlog = [submit(connection, "a", "batch")["id"] for _ in range(BACKLOG)]
        while True:
            jobs = [call(connection, "GET", f"/v1/jobs/{id}", "a")[1] for id in backlog[:3]]
            done = [job for job in jobs if job["status"] == "succeeded"]
            if len(done) >= 2:
                break
            time.sleep(0.05)
        earlier = statistics.mean(seconds(j["completed_at"]) - seconds(j["started_at"]) for j in done)
        time.sleep(random.uniform(0, earlier))
        job = submit(connection, "b", "interactive")
        estimate = job.get("estimated_start_at")
        while job["status"] in ("queued", "running"):
            time.sleep(0.02)
            job = call(connection, "GET", f"/v1/jobs/{job['id']}", "b")[1]
        assert job["status"] == "succeeded", job
        arrived, done = seconds(job["created_at"]), seconds(job["completed_at"])
        latency = done - arrived
        listing = call(connection, "GET", "/v1/jobs?limit=100", "a")[1]["items"]
        meanwhile = [j for j in listing if j["completed_at"] and seconds(j["started_at"]) < done
                     and seconds(j["completed_at"]) > arrived] + [job]
        duration = statistics.mean(seconds(j["completed_at"]) - seconds(j["started_at"])
                                   for j in meanwhile)
        error = seconds(estimate) - seconds(job["started_at"]) if estimate else None
        return latency, duration, error


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("covec")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--database-url")
    args = parser.parse_args()
    ratios = []
    for index in range(args.runs):
        latency, duration, error = run(args.covec, args.database_url)
        ratios.append(latency / duration)
        estimate = f", start estimated {error:+.2f} s off" if error is not None else ""
        print(f"run {index + 1}: job duration D {duration:.2f} s, interactive job of b behind "
              f"{BACKLOG} batch jobs of a done in {latency:.2f} s = {latency / duration:.2f} D{estimate}")
    print(f"L / D over {args.runs} runs: median {statistics.median(ratios):.2f}, "
          f"max {max(ratios):.2f} (issue: at most 2)")


if __name__ == "__main__":
    main()
