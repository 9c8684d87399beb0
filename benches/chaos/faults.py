"""The faults, injected one at a time on a fixed schedule, each written to the history with
its window (from injection to heal, plus a recovery margin in which polls do not count for the
latency figures):

- `partition`: a worker running a job is cut off from PostgreSQL (packets dropped, both ways)
  or from the object store, for its lease and more, then healed: its lease expires, another
  worker takes the job, and whatever the first one writes after the heal must be refused;
- `store-outage`: the object store stops answering (SIGSTOP of moto: connections hang) or
  refuses connections (a reset for every connection, as a stopped server's host), then back;
- `pause`: a worker running a job gets SIGSTOP for its lease and more, then SIGCONT;
- `kill-api`, `kill-worker`: SIGKILL, then started again;
- `pg-restart`: PostgreSQL's fast shutdown (every connection cut) and start;
- `disk-full`: the filesystem under PostgreSQL's data directory is filled to the last byte,
  held, then freed (and PostgreSQL started again if it stopped)."""

import errno
import json
import os
import signal
import threading
import time

from cluster import PG_PORT, S3_PORT

KINDS = ["partition", "store-outage", "pause", "kill-api", "kill-worker", "pg-restart",
         "disk-full"]

RECOVERY = 10.0


class JobTracker:
    """Which job each worker runs now, from the tail of its JSON log."""

    def __init__(self, workers):
        self.workers = workers
        self.offsets = {w.name: 0 for w in workers}
        self.current = {w.name: None for w in workers}
        self.lock = threading.Lock()

    def poll(self):
        for worker in self.workers:
            try:
                with open(worker.log_path) as f:
                    f.seek(self.offsets[worker.name])
                    lines = f.readlines()
                    if lines and not lines[-1].endswith("\n"):
                        lines.pop()
                    self.offsets[worker.name] += sum(len(line.encode()) for line in lines)
            except OSError:
                continue
            for line in lines:
                try:
                    entry = json.loads(line)
                except ValueError:
                    continue
                message = entry.get("fields", {}).get("message", "")
                job = (entry.get("span") or {}).get("job_id")
                with self.lock:
                    if message == "started" and job:
                        self.current[worker.name] = job
                    elif message == "finished" or "outcome" in message:
                        self.current[worker.name] = None

    def busy(self):
        with self.lock:
            return [(name, job) for name, job in self.current.items() if job]

    def forget(self, name):
        with self.lock:
            self.current[name] = None


class Faults:
    def __init__(self, cluster, net, history, lease, store_outage, rng):
        self.cluster, self.net, self.history = cluster, net, history
        self.lease = lease
        self.outage_seconds = store_outage
        self.rng = rng
        self.tracker = JobTracker(cluster.workers)
        self.window_until = 0.0
        self.open = 0
        self.lock = threading.Lock()
        self.counts = {}

    def in_fault(self):
        with self.lock:
            return self.open > 0 or time.time() < self.window_until

    def begin(self):
        with self.lock:
            self.open += 1

    def end(self):
        with self.lock:
            self.open -= 1
            self.window_until = max(self.window_until, time.time() + RECOVERY)

    def inject(self, kind, index):
        self.tracker.poll()
        t0 = time.time()
        self.begin()
        try:
            details = getattr(self, kind.replace("-", "_"))(index)
        finally:
            self.end()
        self.counts[kind] = self.counts.get(kind, 0) + 1
        self.history.record(op="fault", kind=kind, t0=t0, t1=time.time(), **details)
        return details

    def busy_worker(self, exclude=None):
        """A worker running a job now (waiting up to 10 s for one), else any."""
        candidates = [w for w in self.cluster.workers if w.name != exclude]
        deadline = time.time() + 10
        while time.time() < deadline:
            self.tracker.poll()
            busy = [(name, job) for name, job in self.tracker.busy()
                    if name != exclude and self.worker(name).alive()]
            if busy:
                name, job = self.rng.choice(busy)
                return self.worker(name), job
            time.sleep(0.2)
        return self.rng.choice(candidates), None

    def worker(self, name):
        return next(w for w in self.cluster.workers if w.name == name)

    # --- the faults ---

    def partition(self, index):
        target = "postgres" if index % 2 == 0 else "store"
        worker, job = self.busy_worker()
        port = PG_PORT if target == "postgres" else S3_PORT
        hold = self.lease + 8
        self.net.block(worker.name, self.cluster.srv_ip, port, mode="drop")
        time.sleep(hold)
        self.net.heal(worker.name)
        # Time for the stale worker to come back and try its writes.
        time.sleep(4)
        return {"worker": worker.name, "job": job, "target": target, "held": hold}

    def store_outage(self, index):
        flavour = "hang" if index % 2 == 0 else "refuse"
        if flavour == "hang":
            self.cluster.moto.send(signal.SIGSTOP)
            time.sleep(self.outage_seconds)
            self.cluster.moto.send(signal.SIGCONT)
        else:
            self.net.block("srv", None, S3_PORT, mode="reject", inbound=True)
            time.sleep(self.outage_seconds)
            self.net.heal("srv")
        return {"flavour": flavour, "held": self.outage_seconds}

    def pause(self, index):
        worker, job = self.busy_worker()
        hold = self.lease + 5
        worker.send(signal.SIGSTOP)
        time.sleep(hold)
        worker.send(signal.SIGCONT)
        time.sleep(2)
        return {"worker": worker.name, "job": job, "held": hold}

    def kill_api(self, index):
        # The first replica is never killed: its memory is watched over the whole run.
        api = self.cluster.apis[1 + index % (len(self.cluster.apis) - 1)]
        api.kill9()
        time.sleep(1)
        api.start()
        ready = self.cluster.wait_ready(api)
        return {"process": api.name, "ready": ready}

    def kill_worker(self, index):
        # Nor the first worker.
        worker, job = self.busy_worker(exclude=self.cluster.workers[0].name)
        worker.kill9()
        self.tracker.forget(worker.name)
        time.sleep(1)
        worker.start()
        ready = self.cluster.wait_ready(worker)
        return {"process": worker.name, "job": job, "ready": ready}

    def pg_restart(self, index):
        t0 = time.time()
        self.cluster.restart_postgres()
        return {"down_s": round(time.time() - t0, 2)}

    def disk_full(self, index, hold=20):
        filler = os.path.join(self.cluster.pg_dir, "filler")
        written = 0
        # Unbuffered: every write meets the full disk itself.
        with open(filler, "wb", buffering=0) as f:
            for size in (1 << 20, 65536, 4096, 512):
                chunk = b"\0" * size
                while True:
                    try:
                        f.write(chunk)
                        written += size
                    except OSError as error:
                        if error.errno != errno.ENOSPC:
                            raise
                        break
        stats = os.statvfs(self.cluster.pg_dir)
        free = stats.f_bavail * stats.f_frsize
        time.sleep(hold)
        os.remove(filler)
        restarted = False
        if not self.cluster.wait_postgres(timeout=20):
            if self.cluster.postgres.alive():
                self.cluster.postgres.stop(signal.SIGINT)
            self.cluster.start_postgres()
            restarted = True
        return {"filled_mib": written >> 20, "free_bytes": free, "held": hold,
                "postgres_restarted": restarted}
