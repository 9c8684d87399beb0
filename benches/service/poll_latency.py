#!/usr/bin/env python3
"""Status-poll latency on the shared backend with both workers busy (issue 14): one API replica
(`covec serve --workers 0`) and two `covec worker --threads 1` on one PostgreSQL database (the
caller's, `--database-url`); two long jobs keep the workers busy while 16 client threads poll
`GET /v1/jobs/{id}` at 500 polls/s in all (each on its own keep-alive connection, on a fixed
schedule) for `--seconds`. Prints p50, p99 and max latency; then cancels the jobs, stops the
processes and empties the jobs table. Standard library only.

    python3 benches/service/poll_latency.py BIN --database-url postgres://… [--seconds 20]
"""

import argparse
import http.client
import json
import os
import signal
import statistics
import subprocess
import tempfile
import threading
import time
import uuid

IMAGE = os.path.join(os.path.dirname(__file__), "../../tests/fixtures/photo96_face_hopper.png")
LONG = json.dumps({"paths": 64, "max_size": 96, "iterations": {
    "structure": 100000, "reconstruction": 100000, "refine_rounds": 5, "refine": 100000,
    "polish": 100000}})
THREADS = 16
RATE = 500


def request(connection, method, path, body=None, headers=None):
    connection.request(method, path, body=body, headers=headers or {})
    response = connection.getresponse()
    return response.status, response.read()


def submit(connection):
    boundary = uuid.uuid4().hex
    with open(IMAGE, "rb") as f:
        image = f.read()
    body = b"".join([
        f"--{boundary}\r\nContent-Disposition: form-data; name=\"image\"; filename=\"i.png\"\r\n"
        f"Content-Type: image/png\r\n\r\n".encode(), image, b"\r\n",
        f"--{boundary}\r\nContent-Disposition: form-data; name=\"params\"\r\n"
        f"Content-Type: application/json\r\n\r\n{LONG}\r\n--{boundary}--\r\n".encode(),
    ])
    status, reply = request(connection, "POST", "/v1/jobs", body,
                            {"content-type": f"multipart/form-data; boundary={boundary}"})
    assert status == 201, reply
    return json.loads(reply)["id"]


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("covec")
    parser.add_argument("--database-url", required=True)
    parser.add_argument("--seconds", type=float, default=20)
    args = parser.parse_args()
    data = tempfile.mkdtemp(prefix="covec-poll-")
    common = ["--data-dir", data, "--database-url", args.database_url,
              "--max-iterations", "100000000"]
    log = open(os.path.join(data, "log"), "w")
    api = subprocess.Popen([args.covec, "serve", "--addr", "127.0.0.1:0", "--workers", "0", *common],
                           stdout=subprocess.PIPE, stderr=log, text=True)
    host, port = api.stdout.readline().strip().rsplit("/", 1)[1].split(":")
    workers = [subprocess.Popen([args.covec, "worker", "--threads", "1", *common],
                                stdout=subprocess.DEVNULL, stderr=log) for _ in range(2)]
    try:
        control = http.client.HTTPConnection(host, int(port))
        jobs = [submit(control), submit(control)]
        while any(json.loads(request(control, "GET", f"/v1/jobs/{job}")[1])["status"] != "running"
                  for job in jobs):
            time.sleep(0.1)
        latencies = []
        lock = threading.Lock()
        start = time.monotonic() + 0.5
        interval = THREADS / RATE

        def poll(index):
            connection = http.client.HTTPConnection(host, int(port))
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
                status, _ = request(connection, "GET", f"/v1/jobs/{jobs[n % 2]}")
                assert status == 200
                mine.append(time.monotonic() - sent)
                n += 1
            with lock:
                latencies.extend(mine)

        threads = [threading.Thread(target=poll, args=(i,)) for i in range(THREADS)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        latencies.sort()
        ms = [1000 * value for value in latencies]
        p99 = ms[int(0.99 * (len(ms) - 1))]
        print(f"{len(ms)} polls in {args.seconds:.0f} s ({len(ms) / args.seconds:.0f}/s), both workers "
              f"busy: p50 {statistics.median(ms):.2f} ms, p99 {p99:.2f} ms, max {ms[-1]:.2f} ms")
        # A new connection: the server closed the idle one meanwhile.
        control = http.client.HTTPConnection(host, int(port))
        for job in jobs:
            request(control, "POST", f"/v1/jobs/{job}/cancel")
    finally:
        for process in [api, *workers]:
            process.send_signal(signal.SIGTERM)
        for process in [api, *workers]:
            process.wait()
        subprocess.run(["psql", args.database_url, "-Xq", "-c", "DELETE FROM jobs"], check=True)
        subprocess.run(["rm", "-rf", data], check=True)


if __name__ == "__main__":
    main()
