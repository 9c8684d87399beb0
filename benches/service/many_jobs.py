#!/usr/bin/env python3
"""Listing and polling with many stored jobs (issue 13, item 6).

Starts `covec serve` on a scratch data directory, runs one small job to success, stops the
server, copies that job's row N times (new ids) straight into `jobs.sqlite3`, starts the server
again and measures: start-up time, listing latencies, and `GET /v1/jobs/{id}` while 10 clients
list without pause. Standard library only.

    python3 benches/service/many_jobs.py target/release/covec [--jobs 100000]
"""

import argparse
import http.client
import json
import os
import secrets
import signal
import socket
import sqlite3
import statistics
import subprocess
import tempfile
import threading
import time
import urllib.request

IMAGE = os.path.join(os.path.dirname(__file__), "../../tests/fixtures/photo96_face_hopper.png")
LISTINGS = [
    "/v1/jobs?status=running",
    "/v1/jobs?status=succeeded",
    "/v1/jobs",
    "/v1/jobs?status=succeeded&limit=100",
]


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start(binary, data, port):
    began = time.perf_counter()
    server = subprocess.Popen(
        [binary, "serve", "--addr", f"127.0.0.1:{port}", "--data-dir", data],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    while True:
        try:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=1)
            return server, time.perf_counter() - began
        except OSError:
            if server.poll() is not None:
                raise SystemExit("many_jobs: the server exited at start")
            time.sleep(0.05)


def stop(server):
    server.send_signal(signal.SIGTERM)
    server.wait(timeout=60)


def get(conn, path):
    began = time.perf_counter()
    conn.request("GET", path)
    response = conn.getresponse()
    response.read()
    if response.status != 200:
        raise SystemExit(f"many_jobs: GET {path} answered {response.status}")
    return time.perf_counter() - began


def one_finished_job(port):
    boundary = "covecbench"
    with open(IMAGE, "rb") as f:
        image = f.read()
    body = (
        f"--{boundary}\r\nContent-Disposition: form-data; name=\"image\"; filename=\"i.png\"\r\n"
        f"Content-Type: image/png\r\n\r\n".encode()
        + image
        + f"\r\n--{boundary}\r\nContent-Disposition: form-data; name=\"params\"\r\n"
        f"Content-Type: application/json\r\n\r\n{{\"paths\":8}}\r\n--{boundary}--\r\n".encode()
    )
    conn = http.client.HTTPConnection("127.0.0.1", port)
    conn.request("POST", "/v1/jobs", body, {"Content-Type": f"multipart/form-data; boundary={boundary}"})
    job = json.loads(conn.getresponse().read())
    while job["status"] in ("queued", "running"):
        time.sleep(0.2)
        conn.request("GET", f"/v1/jobs/{job['id']}")
        job = json.loads(conn.getresponse().read())
    if job["status"] != "succeeded":
        raise SystemExit(f"many_jobs: the seed job ended {job['status']}")
    return job["id"]


def seed(data, copies):
    db = sqlite3.connect(os.path.join(data, "jobs.sqlite3"))
    job_id, record, owner, status = db.execute("SELECT id, record, owner, status FROM jobs").fetchone()
    template = json.loads(record)
    rows = []
    for _ in range(copies):
        template["id"] = "job_" + secrets.token_hex(16)
        rows.append((template["id"], json.dumps(template), owner, status))
    db.executemany("INSERT INTO jobs (id, record, owner, status) VALUES (?, ?, ?, ?)", rows)
    db.commit()
    return job_id


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("binary")
    parser.add_argument("--jobs", type=int, default=100_000)
    parser.add_argument("--listers", type=int, default=10)
    parser.add_argument("--polls", type=int, default=500)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="covec-many-jobs-") as data:
        port = free_port()
        server, _ = start(args.binary, data, port)
        job_id = one_finished_job(port)
        stop(server)
        seed(data, args.jobs)
        server, startup = start(args.binary, data, port)
        try:
            print(f"{args.jobs + 1} stored jobs: ready {startup:.2f} s after start")
            conn = http.client.HTTPConnection("127.0.0.1", port)
            for path in LISTINGS:
                times = [get(conn, path) for _ in range(20)]
                print(f"GET {path}: median {statistics.median(times) * 1e3:.1f} ms, max {max(times) * 1e3:.1f} ms")
            stopping = threading.Event()
            listed = []

            def lister():
                own = http.client.HTTPConnection("127.0.0.1", port)
                count = 0
                while not stopping.is_set():
                    get(own, LISTINGS[count % len(LISTINGS)])
                    count += 1
                listed.append(count)

            threads = [threading.Thread(target=lister) for _ in range(args.listers)]
            for thread in threads:
                thread.start()
            times = sorted(get(conn, f"/v1/jobs/{job_id}") for _ in range(args.polls))
            stopping.set()
            for thread in threads:
                thread.join()
            p99 = times[min(len(times) - 1, int(len(times) * 0.99))]
            print(
                f"GET /v1/jobs/{{id}} with {args.listers} listers: p50 {times[len(times) // 2] * 1e3:.1f} ms, "
                f"p99 {p99 * 1e3:.1f} ms, max {times[-1] * 1e3:.1f} ms ({sum(listed)} listings meanwhile)"
            )
            with open(f"/proc/{server.pid}/status") as status:
                peak = next(line.split()[1] for line in status if line.startswith("VmHWM:"))
            print(f"server peak RSS (VmHWM): {int(peak) / 1024:.0f} MiB")
        finally:
            stop(server)


if __name__ == "__main__":
    main()
