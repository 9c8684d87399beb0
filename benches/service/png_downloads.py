#!/usr/bin/env python3
"""Large PNG downloads beside status polls on one replica (docs/benchmarks.md, "Downloads under
load").

Starts one `covec serve` (1 worker, `--max-pixels 16777216` so that a square picture may be drawn
4096 px wide), runs N small jobs to success (a 96 px photo each, different seeds), then:

  round 1: N concurrent `GET /v1/jobs/{id}/png?width=4096`, one per job, none stored yet: each is
           drawn (one render at a time per server) and stored;
  round 2: the same N concurrent downloads again, started every 0.5 s for 10 s: each must come
           from storage (its stored copy exists, the same ETag and bytes, and it takes a fraction
           of a render).

A poller asks `GET /v1/jobs/{id}` on a keep-alive connection every 50 ms through both rounds;
the script prints the polls' p50/p99/max per round and each round's download times, and exits 1
if a poll's p99 is 50 ms or more or a second download was not served from storage. Standard
library only.

    python3 benches/service/png_downloads.py target/release/covec [--jobs 20] [--width 4096]
"""

import argparse
import concurrent.futures
import hashlib
import http.client
import json
import os
import signal
import socket
import statistics
import subprocess
import tempfile
import threading
import time

IMAGE = os.path.join(os.path.dirname(__file__), "../../tests/fixtures/photo96_face_hopper.png")
PARAMS = {"max_size": 96, "paths": 32, "iterations": {"structure": 20, "reconstruction": 20,
          "refine": 10, "refine_rounds": 1, "polish": 20}}
POLL_EVERY = 0.05
P99_LIMIT_MS = 50.0
SECOND_ROUND_SECONDS = 10
SECOND_ROUND_EVERY = 0.5


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def request(port, method, path, body=None, headers=None, timeout=600):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    conn.request(method, path, body=body, headers=headers or {})
    response = conn.getresponse()
    data = response.read()
    conn.close()
    return response.status, dict(response.getheaders()), data


def submit(port, seed):
    boundary = "covecbench"
    with open(IMAGE, "rb") as f:
        image = f.read()
    params = json.dumps({**PARAMS, "seed": seed}).encode()
    body = (
        f"--{boundary}\r\nContent-Disposition: form-data; name=\"image\"; filename=\"photo.png\"\r\n"
        "Content-Type: image/png\r\n\r\n".encode() + image
        + f"\r\n--{boundary}\r\nContent-Disposition: form-data; name=\"params\"\r\n"
        "Content-Type: application/json\r\n\r\n".encode() + params
        + f"\r\n--{boundary}--\r\n".encode()
    )
    status, _, data = request(port, "POST", "/v1/jobs", body,
                              {"content-type": f"multipart/form-data; boundary={boundary}"})
    if status != 201:
        raise SystemExit(f"png_downloads: POST /v1/jobs answered {status}: {data[:200]!r}")
    return json.loads(data)["id"]


def wait_succeeded(port, ids):
    for id in ids:
        while True:
            status, _, data = request(port, "GET", f"/v1/jobs/{id}")
            job = json.loads(data)
            if job["status"] == "succeeded":
                break
            if job["status"] in ("failed", "canceled"):
                raise SystemExit(f"png_downloads: job {id} {job['status']}: {job.get('error')}")
            time.sleep(0.2)


class Poller(threading.Thread):
    """Polls one job on a keep-alive connection, recording each poll's latency in `round`."""

    def __init__(self, port, job):
        super().__init__(daemon=True)
        self.port, self.job = port, job
        self.round = "warm-up"
        self.latencies = {}
        self.stop = threading.Event()

    def run(self):
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=30)
        while not self.stop.is_set():
            began = time.perf_counter()
            conn.request("GET", f"/v1/jobs/{self.job}")
            response = conn.getresponse()
            response.read()
            elapsed = time.perf_counter() - began
            if response.status != 200:
                raise SystemExit(f"png_downloads: poll answered {response.status}")
            self.latencies.setdefault(self.round, []).append(elapsed * 1000)
            self.stop.wait(max(0.0, POLL_EVERY - elapsed))


def download(port, id, width):
    began = time.perf_counter()
    status, headers, data = request(port, "GET", f"/v1/jobs/{id}/png?width={width}")
    if status != 200:
        raise SystemExit(f"png_downloads: PNG of {id} answered {status}: {data[:200]!r}")
    return time.perf_counter() - began, headers.get("ETag") or headers.get("etag"), hashlib.sha256(data).hexdigest(), len(data)


def percentile(values, q):
    values = sorted(values)
    return values[min(len(values) - 1, int(len(values) * q))]


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("covec")
    parser.add_argument("--jobs", type=int, default=20)
    parser.add_argument("--width", type=int, default=4096)
    args = parser.parse_args()

    data_dir = tempfile.mkdtemp(prefix="covec-png-load-")
    port = free_port()
    server = subprocess.Popen(
        [args.covec, "serve", "--addr", f"127.0.0.1:{port}", "--data-dir", data_dir,
         "--workers", "1", "--max-pixels", str(args.width * args.width)],
        stdout=subprocess.PIPE, stderr=open(os.path.join(data_dir, "serve.log"), "w"))
    server.stdout.readline()
    failed = []
    try:
        began = time.perf_counter()
        ids = [submit(port, seed) for seed in range(args.jobs)]
        wait_succeeded(port, ids)
        print(f"{args.jobs} jobs succeeded in {time.perf_counter() - began:.1f} s")
        poller = Poller(port, ids[0])
        poller.start()
        time.sleep(2)
        results = {}
        with concurrent.futures.ThreadPoolExecutor(args.jobs) as pool:
            for round in ("first", "second"):
                poller.round = round
                began = time.perf_counter()
                # The second round is short: started again every SECOND_ROUND_EVERY seconds for
                # SECOND_ROUND_SECONDS, so that the polls beside it are enough to have a p99.
                repeats = 0
                while True:
                    started = time.perf_counter()
                    results[round] = list(pool.map(lambda id: download(port, id, args.width), ids))
                    repeats += 1
                    if round == "first" or time.perf_counter() - began >= SECOND_ROUND_SECONDS:
                        break
                    time.sleep(max(0.0, SECOND_ROUND_EVERY - (time.perf_counter() - started)))
                wall = time.perf_counter() - began
                times = [r[0] for r in results[round]]
                polls = poller.latencies.get(round, [])
                p99 = percentile(polls, 0.99)
                print(f"round {round}: {args.jobs} concurrent PNGs {args.width} px wide "
                      f"({results[round][0][3] / 1e6:.1f} MB each), {repeats}× in {wall:.1f} s; "
                      f"per download (last time) median {statistics.median(times):.2f} s, max "
                      f"{max(times):.2f} s; {len(polls)} polls p50 {percentile(polls, 0.5):.1f} ms, "
                      f"p99 {p99:.1f} ms, max {max(polls):.1f} ms")
                if p99 >= P99_LIMIT_MS:
                    failed.append(f"round {round}: polls p99 {p99:.1f} ms >= {P99_LIMIT_MS} ms")
        poller.stop.set()
        stored = 0
        for id, first, second in zip(ids, results["first"], results["second"]):
            name = os.path.join(data_dir, "jobs", id, "derived")
            on_disk = [os.path.join(d, f) for d, _, fs in os.walk(name) for f in fs
                       if f == f"png-{args.width}.png"]
            same = first[1:] == second[1:]
            if on_disk and same:
                stored += 1
            else:
                failed.append(f"{id}: stored copy {on_disk}, same ETag and bytes {same}")
        slowest_second = max(r[0] for r in results["second"])
        print(f"second round: {stored} of {args.jobs} from storage (stored copy present, same "
              f"ETag and bytes); slowest {slowest_second:.2f} s")
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(timeout=120)
    if failed:
        for line in failed:
            print(f"png_downloads: FAILED {line}")
        raise SystemExit(1)
    print("png_downloads: ok")


if __name__ == "__main__":
    main()
