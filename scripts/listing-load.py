#!/usr/bin/env python3
"""Listing under load (issue 13, item 6): a data directory with many stored jobs, listers
hammering `GET /v1/jobs?status=running`, and the latency of `GET /v1/jobs/{id}` meanwhile.

    scripts/listing-load.py --covec target/release/covec --jobs 100000 --listers 10

Builds the data directory directly in SQLite (the record of one real quick job, copied under
new ids, all terminal), starts `covec serve` on it, and prints the start time, one listing's
latency and the GET latencies (p50, p99, max) with and without listers. Loopback only.
"""

import argparse
import http.client
import json
import os
import shutil
import socket
import struct
import sqlite3
import subprocess
import tempfile
import threading
import time
import uuid
import zlib


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def request(port, path, method="GET", body=None, headers=None):
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    connection.request(method, path, body=body, headers=headers or {})
    response = connection.getresponse()
    data = response.read()
    connection.close()
    return response.status, data


def start(covec, data_dir):
    port = free_port()
    started = time.monotonic()
    process = subprocess.Popen(
        [covec, "serve", "--addr", f"127.0.0.1:{port}", "--data-dir", data_dir],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
    )
    process.stdout.readline()
    while True:
        try:
            if request(port, "/healthz")[0] == 200:
                break
        except OSError:
            time.sleep(0.05)
    return process, port, time.monotonic() - started


def tiny_png(size):
    """A size² RGB PNG: a dark square on a light ground."""
    def chunk(kind, data):
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data)))
    rows = b"".join(
        b"\0" + b"".join(bytes((30, 40, 160) if size // 4 <= x < size // 2 and size // 4 <= y < size // 2
                                else (220, 200, 180)) for x in range(size))
        for y in range(size))
    header = struct.pack(">IIBBBBB", size, size, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(rows))
            + chunk(b"IEND", b""))


def template_record(covec, work):
    """One real record: a 16 px job run to completion."""
    data_dir = os.path.join(work, "template")
    process, port, _ = start(covec, data_dir)
    try:
        png = tiny_png(16)
        boundary = "b"
        params = json.dumps({"paths": 8, "max_size": 16, "iterations": {
            "structure": 2, "reconstruction": 2, "refine_rounds": 1, "refine": 2, "polish": 2}})
        body = (
            f"--{boundary}\r\nContent-Disposition: form-data; name=\"image\"; filename=\"i.png\"\r\n"
            f"Content-Type: image/png\r\n\r\n").encode() + png + (
            f"\r\n--{boundary}\r\nContent-Disposition: form-data; name=\"params\"\r\n\r\n"
            f"{params}\r\n--{boundary}--\r\n").encode()
        status, data = request(port, "/v1/jobs", "POST", body,
                               {"content-type": f"multipart/form-data; boundary={boundary}"})
        assert status == 201, data
        job = json.loads(data)["id"]
        while json.loads(request(port, f"/v1/jobs/{job}")[1])["status"] != "succeeded":
            time.sleep(0.05)
    finally:
        process.terminate()
        process.wait()
    db = sqlite3.connect(os.path.join(data_dir, "jobs.sqlite3"))
    (record,) = db.execute("SELECT record FROM jobs").fetchone()
    return json.loads(record)


def fill(data_dir, record, count):
    os.makedirs(os.path.join(data_dir, "jobs"), exist_ok=True)
    db = sqlite3.connect(os.path.join(data_dir, "jobs.sqlite3"))
    db.execute("CREATE TABLE IF NOT EXISTS jobs (id TEXT PRIMARY KEY, record TEXT NOT NULL)")
    base = int(time.time() * 1000)
    ids = []
    rows = []
    for i in range(count):
        # UUIDv7-shaped ids in creation order.
        millis = base - count + i
        job = "job_" + f"{millis:012x}" + uuid.uuid4().hex[12:]
        ids.append(job)
        record = dict(record, id=job, status=("succeeded", "failed", "canceled")[i % 3])
        rows.append((job, json.dumps(record)))
    db.executemany("INSERT INTO jobs (id, record) VALUES (?, ?)", rows)
    db.commit()
    db.close()
    return ids


def percentile(values, fraction):
    values = sorted(values)
    return values[min(len(values) - 1, int(fraction * len(values)))]


def measure(port, ids, listers, seconds):
    stop = threading.Event()
    lists = []

    def lister():
        while not stop.is_set():
            started = time.monotonic()
            status, _ = request(port, "/v1/jobs?status=running")
            assert status == 200
            lists.append(time.monotonic() - started)

    threads = [threading.Thread(target=lister) for _ in range(listers)]
    for thread in threads:
        thread.start()
    gets = []
    deadline = time.monotonic() + seconds
    i = 0
    while time.monotonic() < deadline:
        started = time.monotonic()
        status, _ = request(port, f"/v1/jobs/{ids[i * 7919 % len(ids)]}")
        assert status == 200
        gets.append(time.monotonic() - started)
        i += 1
    stop.set()
    for thread in threads:
        thread.join()
    return gets, lists


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--covec", required=True)
    parser.add_argument("--jobs", type=int, default=100_000)
    parser.add_argument("--listers", type=int, default=10)
    parser.add_argument("--seconds", type=float, default=10)
    args = parser.parse_args()
    work = tempfile.mkdtemp(prefix="covec-listing-")
    try:
        record = template_record(args.covec, work)
        data_dir = os.path.join(work, "data")
        ids = fill(data_dir, record, args.jobs)
        process, port, startup = start(args.covec, data_dir)
        try:
            print(f"{args.jobs} jobs; server ready in {startup:.2f} s")
            single = []
            for _ in range(20):
                started = time.monotonic()
                request(port, "/v1/jobs?status=running")
                single.append(time.monotonic() - started)
            print(f"one listing (status=running): median {1000 * percentile(single, 0.5):.1f} ms")
            for listers in (0, args.listers):
                gets, lists = measure(port, ids, listers, args.seconds)
                line = (f"GET /v1/jobs/{{id}} with {listers} listers: {len(gets)} requests, "
                        f"p50 {1000 * percentile(gets, 0.5):.2f} ms, "
                        f"p99 {1000 * percentile(gets, 0.99):.2f} ms, max {1000 * max(gets):.1f} ms")
                if lists:
                    line += (f"; listings: {len(lists)}, "
                             f"p50 {1000 * percentile(lists, 0.5):.1f} ms")
                print(line)
        finally:
            process.terminate()
            process.wait()
        process, port, startup = start(args.covec, data_dir)
        process.terminate()
        process.wait()
        print(f"restarted on the same data directory: ready in {startup:.2f} s")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
