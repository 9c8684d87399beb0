#!/usr/bin/env python3
"""Memory and start-up with many stored job records (issue 20, bounded records).

Starts `covec serve` on a scratch data directory, runs one small job to success, stops the
server, copies that job's row N times (new ids) straight into `jobs.sqlite3` as the store writes
it, each copy's results already expired (`data_removed`), starts the server again and measures:
start-up time, then the server's RSS after reading every 1000th record one by one and listing
the first 100 pages of 100, with the peak (VmHWM) over the whole run. Standard library only.

    python3 benches/service/many_records.py target/release/covec [--records 1000000]
"""

import argparse
import http.client
import json
import os
import sqlite3
import tempfile

from many_jobs import free_port, get, one_finished_job, start, stop

SEED_BATCH = 50_000


def seed(data, copies):
    """Copies the one job's row `copies` times, results removed; returns the copies' ids."""
    db = sqlite3.connect(os.path.join(data, "jobs.sqlite3"))
    record, owner, status, created, completed = db.execute(
        "SELECT record, owner, status, created_at, completed_at FROM jobs"
    ).fetchone()
    template = json.loads(record)
    template["data_removed"] = True
    ids = [f"job_{n:032x}" for n in range(1, copies + 1)]
    for start_at in range(0, copies, SEED_BATCH):
        rows = []
        for job_id in ids[start_at : start_at + SEED_BATCH]:
            template["id"] = job_id
            rows.append((job_id, json.dumps(template), owner, status, created, completed))
        db.executemany(
            "INSERT INTO jobs (id, record, owner, status, created_at, completed_at)"
            " VALUES (?, ?, ?, ?, ?, ?)",
            rows,
        )
        db.commit()
    return ids


def memory(pid):
    """(VmRSS, VmHWM) of the process, in MiB."""
    with open(f"/proc/{pid}/status") as status:
        fields = dict(line.split(":", 1) for line in status)
    return tuple(int(fields[name].split()[0]) / 1024 for name in ("VmRSS", "VmHWM"))


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("binary")
    parser.add_argument("--records", type=int, default=1_000_000)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="covec-many-records-") as data:
        port = free_port()
        server, _ = start(args.binary, data, port)
        one_finished_job(port)
        stop(server)
        ids = seed(data, args.records)
        size = os.path.getsize(os.path.join(data, "jobs.sqlite3")) / 2**20
        server, startup = start(args.binary, data, port)
        try:
            print(f"{args.records + 1} stored records ({size:.0f} MiB of SQLite): ready {startup:.2f} s after start")
            rss, _ = memory(server.pid)
            print(f"RSS once ready: {rss:.0f} MiB")
            conn = http.client.HTTPConnection("127.0.0.1", port)
            for job_id in ids[::1000]:
                get(conn, f"/v1/jobs/{job_id}")
            cursor = ""
            for _ in range(100):
                conn.request("GET", f"/v1/jobs?limit=100{cursor}")
                page = json.loads(conn.getresponse().read())
                cursor = f"&cursor={page['next_cursor']}"
            conn.request("GET", "/metrics")
            held = next(
                line.split()[1]
                for line in conn.getresponse().read().decode().splitlines()
                if line.startswith("covec_jobs_in_memory ")
            )
            rss, peak = memory(server.pid)
            print(
                f"after {len(ids[::1000])} reads and 100 pages: RSS {rss:.0f} MiB, peak (VmHWM) "
                f"{peak:.0f} MiB; jobs held in memory: {held}"
            )
        finally:
            stop(server)


if __name__ == "__main__":
    main()
