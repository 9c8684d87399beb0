#!/usr/bin/env python3
"""Status-poll latency on the shared backend with both workers busy (issue 14): one API replica
and two `covec worker --threads 1` (shared_backend.py) on the caller's PostgreSQL; two long jobs
keep the workers busy while 16 client threads poll `GET /v1/jobs/{id}` at 500 polls/s in all
(each on its own keep-alive connection, on a fixed schedule) for `--seconds`. Prints p50, p99
and max latency, then cancels the jobs.

    python3 benches/service/poll_latency.py BIN --database-url postgres://… [--seconds 20]
"""

import argparse
import http.client
import json
import os
import statistics
import threading
import time

from shared_backend import cluster, request, status, submit

IMAGE = os.path.join(os.path.dirname(__file__), "../../tests/fixtures/photo96_face_hopper.png")
LONG = json.dumps({"paths": 64, "max_size": 96, "iterations": {
    "structure": 100000, "reconstruction": 100000, "refine_rounds": 5, "refine": 100000,
    "polish": 100000}})
THREADS = 16
RATE = 500


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("covec")
    parser.add_argument("--database-url", required=True)
    parser.add_argument("--seconds", type=float, default=20)
    args = parser.parse_args()
    extra = ["--max-iterations", "100000000"]
    with cluster(args.covec, args.database_url, 2, extra) as (host, port):
        control = http.client.HTTPConnection(host, port)
        jobs = [submit(control, IMAGE, LONG), submit(control, IMAGE, LONG)]
        while any(status(control, job) != "running" for job in jobs):
            time.sleep(0.1)
        latencies = []
        lock = threading.Lock()
        start = time.monotonic() + 0.5
        interval = THREADS / RATE

        def poll(index):
            connection = http.client.HTTPConnection(host, port)
            mine = []
            n = 0
            while True:
                due = start + index * interval / THREADS + n * interval
                if due - start > args.seconds:
                    break
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                sent = time.monotonic()
                code, _ = request(connection, "GET", f"/v1/jobs/{jobs[n % 2]}")
                assert code == 200
                mine.append(time.monotonic() - sent)
                n += 1
            with lock:
                latencies.extend(mine)

        threads = [threading.Thread(target=poll, args=(i,)) for i in range(THREADS)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        ms = sorted(1000 * value for value in latencies)
        p99 = ms[int(0.99 * (len(ms) - 1))]
        print(f"{len(ms)} polls in {args.seconds:.0f} s ({len(ms) / args.seconds:.0f}/s), both workers "
              f"busy: p50 {statistics.median(ms):.2f} ms, p99 {p99:.2f} ms, max {ms[-1]:.2f} ms")
        # A new connection: the server closed the idle one meanwhile.
        control = http.client.HTTPConnection(host, port)
        for job in jobs:
            request(control, "POST", f"/v1/jobs/{job}/cancel")


if __name__ == "__main__":
    main()
