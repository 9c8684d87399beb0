#!/usr/bin/env python3
"""Chaos harness for the shared backend: real PostgreSQL, a real S3 server (moto), API
replicas and workers each in a network namespace of its own, steady mixed traffic with faults
on a schedule, every operation and webhook in a history, then a checker (check.py) that holds
the history, the database, the bucket and the logs to the service's promises.

    python3 benches/chaos/chaos.py --covec target/debug/covec --minutes 3 --out DIR

Runs as root (namespaces, nftables, a tmpfs mount). scripts/chaos.sh installs what it needs
and builds covec first. The run directory keeps the history (history.jsonl), every process's
log (logs/), the final state (final/) and the report (report.txt); check.py re-checks it:
`python3 benches/chaos/check.py DIR`. The last line printed includes `violations: N`; the exit
status is 1 when N > 0."""

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import check  # noqa: E402
from cluster import API_PORT, BUCKET, WEBHOOK_SECRET, Cluster  # noqa: E402
from faults import KINDS, Faults  # noqa: E402
from netns import Network, assert_isolated  # noqa: E402
from traffic import History, Traffic, WebhookReceiver  # noqa: E402

HOSTS = ["srv", "cli", "api1", "api2", "w1", "w2", "w3"]
WEBHOOK_PORT = 8099

# A job of under a second on one thread; long ones take a few (the partition and pause
# faults pick a worker running one).
JOB_PARAMS = {"paths": 8, "max_size": 32, "iterations": {
    "structure": 20, "reconstruction": 20, "refine_rounds": 1, "refine": 10, "polish": 10}}
LONG_PARAMS = {"paths": 16, "max_size": 48, "iterations": {
    "structure": 80, "reconstruction": 80, "refine_rounds": 2, "refine": 30, "polish": 30}}


def parse_args():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--covec", required=True)
    parser.add_argument("--minutes", type=float, default=3)
    parser.add_argument("--out", required=True)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--lease", type=int, default=5, help="--lease-seconds of every process")
    parser.add_argument("--rate", type=float, default=0.6, help="submissions per second")
    parser.add_argument("--store-outage", type=float, default=None,
                        help="seconds the object store is down [60; 15 under 10 minutes]")
    parser.add_argument("--cycles", type=int, default=None,
                        help="rounds of every fault kind [5 per hour, at least 1]")
    parser.add_argument("--inner", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--prefix", help=argparse.SUPPRESS)
    return parser.parse_args()


def outer(args):
    """Makes the namespaces and the tmpfs, runs the harness inside the client's namespace,
    and removes everything after, whatever happened."""
    run_dir = os.path.abspath(args.out)
    os.makedirs(run_dir, exist_ok=True)
    prefix = f"cvc{os.getpid()}"
    net = Network(prefix, HOSTS)
    pg_dir = os.path.join(run_dir, "pgfs")
    os.makedirs(pg_dir, exist_ok=True)
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256m", "tmpfs", pg_dir], check=True)
    try:
        net.create()
        argv = [sys.executable, os.path.abspath(__file__), "--inner", "--prefix", prefix,
                *sys.argv[1:]]
        inner = subprocess.Popen(net.exec("cli") + argv)
        try:
            return inner.wait()
        except KeyboardInterrupt:
            inner.send_signal(signal.SIGINT)
            return inner.wait()
    finally:
        net.destroy()
        subprocess.run(["umount", "-l", pg_dir], check=False)


def inner(args):
    assert_isolated()
    run_dir = os.path.abspath(args.out)
    net = Network(args.prefix, HOSTS)
    cluster = Cluster(net, run_dir, os.path.abspath(args.covec), os.path.join(run_dir, "pgfs"),
                      apis=["api1", "api2"], workers=["w1", "w2", "w3"], lease=args.lease)
    duration = args.minutes * 60
    store_outage = args.store_outage or (60.0 if args.minutes >= 10 else 15.0)
    cycles = args.cycles or max(1, round(5 * args.minutes / 60))
    warmup = 60.0 if args.minutes >= 10 else 15.0
    rng = random.Random(args.seed)
    history = History(os.path.join(run_dir, "history.jsonl"))
    started = time.time()
    history.record(op="run", t0=started, t1=started, minutes=args.minutes, lease=args.lease,
                   rate=args.rate, store_outage=store_outage, cycles=cycles, warmup=warmup,
                   seed=args.seed)

    print(f"chaos: {args.minutes:g} min, {cycles} round(s) of {len(KINDS)} fault kinds, "
          f"store outage {store_outage:g} s, lease {args.lease} s; run directory {run_dir}",
          flush=True)
    cluster.init_postgres()
    cluster.start_postgres()
    cluster.start_moto()
    for process in cluster.covecs():
        process.start()
    for process in cluster.covecs():
        if not cluster.wait_ready(process):
            raise SystemExit(f"chaos: {process.name} did not get ready (see its log)")

    receiver = WebhookReceiver(net.ips["cli"], WEBHOOK_PORT, WEBHOOK_SECRET, history)
    receiver.start()
    faults = Faults(cluster, net, history, args.lease, store_outage, rng)
    traffic = Traffic({api.name: (api.ip, API_PORT) for api in cluster.apis}, history,
                      receiver.url, faults.in_fault, args.seed, args.rate, JOB_PARAMS,
                      LONG_PARAMS)
    stop_monitor = threading.Event()
    monitor = threading.Thread(target=watch, args=(cluster, faults, history, stop_monitor),
                               daemon=True)
    monitor.start()
    traffic.start()

    # The schedule: `cycles` rounds of every kind (each round in its own random order), evenly
    # spread between the warm-up and a quiet tail.
    schedule = []
    for cycle in range(cycles):
        kinds = list(KINDS)
        rng.shuffle(kinds)
        schedule += [(kind, cycle) for kind in kinds]
    span = duration - warmup - 10
    every = span / len(schedule)
    for i, (kind, cycle) in enumerate(schedule):
        at = started + warmup + i * every
        while time.time() < at:
            time.sleep(min(1.0, at - time.time()))
        try:
            details = faults.inject(kind, cycle)
        except Exception as error:  # a harness failure: reported, and the run goes on
            details = {"harness_error": f"{type(error).__name__}: {error}"}
            history.record(op="harness_error", t0=time.time(), t1=time.time(), kind=kind,
                           error=details["harness_error"])
        print(f"chaos: {time.time() - started:6.0f} s  {kind:12} {json.dumps(details)}",
              flush=True)
    while time.time() < started + duration:
        time.sleep(1)

    print("chaos: traffic stopped; waiting for every job to end", flush=True)
    traffic.stop()
    for host in HOSTS:
        net.heal(host)
    cluster.moto.send(signal.SIGCONT)
    quiesce(cluster, traffic, receiver, history)
    stop_monitor.set()
    monitor.join()
    collect(cluster, run_dir)
    receiver.stop()
    for process in cluster.covecs():
        process.stop()
    cluster.moto.stop()
    cluster.postgres.stop(signal.SIGINT)
    history.record(op="end", t0=time.time(), t1=time.time())
    history.close()
    violations = check.main(run_dir)
    return 1 if violations else 0


def watch(cluster, faults, history, stop):
    """Restarts a process that exited on its own (a crash: written to the history), and
    samples every process's RSS every 30 s."""
    last_rss = 0.0
    while not stop.wait(1.0):
        for process in cluster.all():
            if process.alive() or process.expected_exit or process.popen is None:
                continue
            if process is cluster.postgres and faults.in_fault():
                continue  # the disk-full fault starts it again itself
            code = process.popen.poll()
            history.record(op="exit", t0=time.time(), t1=time.time(), process=process.name,
                           code=code, incarnation=process.incarnation)
            print(f"chaos: {process.name} exited on its own (status {code}); restarting",
                  flush=True)
            if process is cluster.postgres:
                cluster.start_postgres()
            else:
                process.start()
        if time.time() - last_rss >= 30:
            last_rss = time.time()
            history.record(op="rss", t0=last_rss, t1=last_rss, processes={
                p.name: [p.incarnation, p.rss_kib()] for p in cluster.all()})


def quiesce(cluster, traffic, receiver, history, timeout=300):
    """Waits until no job is queued or running, every SSE session has ended and every
    completion webhook owed has come, or `timeout`."""
    deadline = time.time() + timeout
    live = None
    while time.time() < deadline:
        try:
            live = cluster.psql_json(
                "SELECT count(*) AS n FROM jobs WHERE status IN ('queued', 'running') "
                "AND NOT deleted")[0]["n"]
        except Exception as error:  # PostgreSQL may be coming back
            print(f"chaos: waiting for the database: {error}", flush=True)
            time.sleep(2)
            continue
        if live == 0:
            break
        time.sleep(2)
    history.record(op="quiesced", t0=time.time(), t1=time.time(), live=live)
    # SSE sessions and webhook deliveries still under way.
    deadline = time.time() + 150
    while time.time() < deadline:
        with traffic.lock:
            hooked = {job for job, known in traffic.jobs.items() if known["webhook"]}
        try:
            ended = {row["id"] for row in cluster.psql_json(
                "SELECT id FROM jobs WHERE status IN ('succeeded', 'failed', 'canceled') "
                "AND NOT deleted")}
        except Exception:
            time.sleep(2)
            continue
        owed = (hooked & ended) - set(receiver.completed)
        sessions = traffic.sessions_open()
        if not owed and sessions == 0:
            break
        time.sleep(2)
    history.record(op="settled", t0=time.time(), t1=time.time(), webhooks_owed=len(owed),
                   sessions_open=sessions)


def collect(cluster, run_dir):
    """The database's rows and the bucket's objects, for the checker."""
    final = os.path.join(run_dir, "final")
    os.makedirs(final, exist_ok=True)
    rows = cluster.psql_json(
        "SELECT id, status, deleted, attempts, idempotency_key, owner, "
        "record -> 'checksums' AS checksums, (record ->> 'data_removed')::boolean "
        "AS data_removed FROM jobs")
    with open(os.path.join(final, "jobs.json"), "w") as f:
        json.dump(rows, f)
    s3 = cluster.s3()
    keys = []
    for page in s3.get_paginator("list_objects_v2").paginate(Bucket=BUCKET,
                                                             Prefix="covec/jobs/"):
        keys += [item["Key"] for item in page.get("Contents", [])]
    wanted = set()
    for row in rows:
        if row["status"] == "succeeded" and not row["deleted"] and row["checksums"]:
            wanted |= {f"covec/jobs/{row['id']}/{name}" for name in row["checksums"]}
    import hashlib
    from concurrent.futures import ThreadPoolExecutor

    def digest(key):
        try:
            body = s3.get_object(Bucket=BUCKET, Key=key)["Body"].read()
            return key, hashlib.sha256(body).hexdigest()
        except s3.exceptions.NoSuchKey:
            return key, None

    with ThreadPoolExecutor(4) as pool:
        digests = dict(pool.map(digest, sorted(wanted)))
    with open(os.path.join(final, "objects.json"), "w") as f:
        json.dump({"keys": keys, "digests": digests}, f)


def main():
    args = parse_args()
    if os.geteuid() != 0:
        raise SystemExit("chaos: run as root (network namespaces, nftables, tmpfs)")
    sys.exit(inner(args) if args.inner else outer(args))


if __name__ == "__main__":
    main()
