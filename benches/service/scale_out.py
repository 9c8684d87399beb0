#!/usr/bin/env python3
"""Throughput of the shared backend with N workers (issue 14): one API replica and N
`covec worker --threads 1` (shared_backend.py) on the caller's PostgreSQL; submits every PNG
under the image folders as a 64-path job, waits for all to succeed and prints jobs per minute.

    python3 benches/service/scale_out.py BIN --database-url postgres://… --workers 2 DIR…
    hyperfine -w 0 -r 3 'python3 benches/service/scale_out.py BIN --database-url URL --workers 1 DIR…' \\
        'python3 benches/service/scale_out.py BIN --database-url URL --workers 2 DIR…'
"""

import argparse
import http.client
import json
import os
import sys
import time

from shared_backend import cluster, status, submit

PARAMS = json.dumps({"paths": 64})


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("covec")
    parser.add_argument("dirs", nargs="+")
    parser.add_argument("--database-url", required=True)
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    images = sorted(os.path.join(d, name) for d in args.dirs for name in os.listdir(d)
                    if name.endswith(".png"))
    with cluster(args.covec, args.database_url, args.workers) as (host, port):
        connection = http.client.HTTPConnection(host, port)
        started = time.monotonic()
        jobs = [submit(connection, image, PARAMS) for image in images]
        # One poll at a time, of the oldest job not seen finished: about 5 requests a second,
        # so the client takes next to nothing from the cores the workers share (polling every
        # pending job every 0.2 s took 3-4 % of the CPU time of a run).
        for job in jobs:
            while (state := status(connection, job)) != "succeeded":
                if state in ("failed", "canceled"):
                    sys.exit(f"job {job} {state}")
                time.sleep(0.2)
        minutes = (time.monotonic() - started) / 60
        print(f"{len(jobs)} jobs, {args.workers} workers: {len(jobs) / minutes:.1f} jobs/min")


if __name__ == "__main__":
    main()
