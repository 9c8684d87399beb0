#!/usr/bin/env python3
"""The checker: holds a chaos run (its history, the database's rows and the bucket's objects
at the end, and every process's log) to the service's promises, and reports the soak's
figures. Standalone on a run directory: `python3 benches/chaos/check.py DIR`.

Promises (README, "Scaling out"):
1. every acknowledged job reaches exactly one terminal state and keeps it: it is terminal at
   the end, never seen in another terminal state, and never seen not ended after it was seen
   ended (on the same replica; on another one after the replicas' follow lag, LAG);
2. a succeeded job's files match the digests stored in its record (and the API never serves
   one that does not: no `corrupt-result`);
3. no job ends twice, nor is saved as succeeded twice: terminal writes per job, counted from
   the logs (a worker's `outcome saved`, a replica's `canceled while queued`, the reaper's
   `workers-lost`), at most one;
4. a deleted job never comes back: nothing shows it after its DELETE was answered (on another
   replica after LAG), and its row is gone or a tombstone at the end;
5. one job per Idempotency-Key: every acknowledgement of a key names one job (a new one only
   after that one was deleted);
6. every completion webhook arrives at least once, signed (Standard Webhooks signature), with
   the job's final state; no delivery is unsigned;
7. SSE sessions (cut at random and resumed with Last-Event-ID, on any replica) get the
   terminal state, exactly once;
8. no covec process exits on its own (a crash)."""

import collections
import json
import os
import sys

TERMINAL = {"succeeded", "failed", "canceled"}
# How far behind another replica's copy of a job may be (the follower's 0.2 s, a heartbeat's
# 0.5 s, and a loaded machine's scheduling): a read on another replica within this of a change
# may still show the state before it.
LAG = 2.0


def load_history(run_dir):
    with open(os.path.join(run_dir, "history.jsonl")) as f:
        return [json.loads(line) for line in f if line.strip()]


def load_logs(run_dir):
    """Every covec JSON log line: (process, message, fields, job_id, level)."""
    entries = []
    logs = os.path.join(run_dir, "logs")
    for name in sorted(os.listdir(logs)):
        if name in ("postgres.log", "moto.log"):
            continue
        process = name.removesuffix(".log")
        with open(os.path.join(logs, name), errors="replace") as f:
            for line in f:
                # A process killed mid-line leaves it unended: the next line starts within it.
                start = line.rfind('{"timestamp"')
                try:
                    entry = json.loads(line[max(start, 0):])
                except ValueError:
                    continue
                fields = entry.get("fields", {})
                job = fields.get("job_id") or (entry.get("span") or {}).get("job_id")
                if not job:
                    for span in entry.get("spans") or []:
                        job = span.get("job_id") or job
                entries.append((process, fields.get("message", ""), fields, job,
                                entry.get("level")))
    return entries


def percentile(values, fraction):
    if not values:
        return None
    values = sorted(values)
    return values[min(len(values) - 1, int(fraction * len(values)))]


class Report:
    def __init__(self):
        self.promises = collections.OrderedDict()
        self.lines = []

    def promise(self, name, checked, violations):
        self.promises[name] = (checked, violations)

    def violations(self):
        return sum(len(v) for _, v in self.promises.values())


def check(run_dir):
    history = load_history(run_dir)
    with open(os.path.join(run_dir, "final", "jobs.json")) as f:
        rows = {row["id"]: row for row in json.load(f)}
    with open(os.path.join(run_dir, "final", "objects.json")) as f:
        objects = json.load(f)
    logs = load_logs(run_dir)
    report = Report()
    by_op = collections.defaultdict(list)
    for record in history:
        by_op[record["op"]].append(record)

    acked = collections.defaultdict(list)
    for record in by_op["ack"]:
        acked[record["job"]].append(record)
    deletes = {}
    for record in by_op["delete"]:
        if record.get("status") == 204:
            deletes.setdefault(record["job"], record)
    final = {job: row["status"] for job, row in rows.items() if not row["deleted"]}

    # Observations: (t0, t1, replica, status, what).
    seen = collections.defaultdict(list)
    for op in ("get", "poll", "cancel", "submit"):
        for record in by_op[op]:
            if record.get("job_status") and record.get("job"):
                seen[record["job"]].append((record["t0"], record["t1"], record["replica"],
                                            record["job_status"], op))
    for record in by_op["ack"]:
        seen[record["job"]].append((record["t0"], record["t1"], record["replica"],
                                    record["job_status"], "submit"))
    for record in by_op["listed"]:
        for job, status in record["jobs"]:
            seen[job].append((record["t0"], record["t1"], record["replica"], status, "list"))
    for record in by_op["sse_event"]:
        seen[record["job"]].append((record["t0"], record["t1"], record["replica"],
                                    record["job_status"], "sse"))
    for record in by_op["webhook"]:
        if record.get("type") == "job.completed" and record.get("job"):
            seen[record["job"]].append((record["t0"], record["t1"], "webhook",
                                        record["job_status"], "webhook"))

    # 1. Every acknowledged job ends once and keeps it.
    violations = []
    stale_reads = 0
    for job in sorted(set(acked) | set(final)):
        deleted = job in deletes or (job in rows and rows[job]["deleted"])
        if not deleted:
            status = final.get(job)
            if status is None:
                violations.append(f"{job}: acknowledged, never deleted, and not in the database")
                continue
            if status not in TERMINAL:
                violations.append(f"{job}: still {status} at the end")
                continue
        observations = sorted(seen.get(job, []))
        first_end = {}
        for t0, t1, replica, status, what in observations:
            if status in TERMINAL:
                if not deleted and status != final.get(job):
                    violations.append(f"{job}: seen {status} ({what}, {replica}) but ended "
                                      f"{final.get(job)}")
                first_end.setdefault(replica, t1)
                first_end.setdefault("any", t1)
        for t0, t1, replica, status, what in observations:
            if status in TERMINAL:
                continue
            if replica in first_end and t0 > first_end[replica]:
                violations.append(f"{job}: seen {status} on {replica} ({what}) after it was "
                                  f"seen ended there")
            elif "any" in first_end and t0 > first_end["any"]:
                if t0 > first_end["any"] + LAG:
                    violations.append(f"{job}: seen {status} on {replica} ({what}) "
                                      f"{t0 - first_end['any']:.1f} s after it was seen ended")
                else:
                    stale_reads += 1
    report.promise("every acknowledged job ends exactly once and keeps its end",
                   len(set(acked) | set(final)), violations)

    # 2. Stored digests.
    violations = []
    checked = 0
    for job, row in rows.items():
        if row["deleted"] or row["status"] != "succeeded" or row.get("data_removed"):
            continue
        checksums = row.get("checksums") or {}
        if not checksums:
            violations.append(f"{job}: succeeded without digests")
        for name, expected in checksums.items():
            checked += 1
            actual = objects["digests"].get(f"covec/jobs/{job}/{name}")
            if actual is None:
                violations.append(f"{job}/{name}: missing from the bucket")
            elif actual != expected:
                violations.append(f"{job}/{name}: stored digest {expected[:12]}…, "
                                  f"object {actual[:12]}…")
    for op in ("result", "edit_svg"):
        for record in by_op[op]:
            checked += 1
            if record.get("code") == "corrupt-result":
                violations.append(f"{record['job']}: {op} answered corrupt-result")
    report.promise("a succeeded job's files match their stored digests", checked, violations)

    # 3. Terminal writes per job, from the logs.
    writes = collections.defaultdict(list)
    pipeline_successes = collections.Counter()
    fenced = []
    for process, message, fields, job, level in logs:
        if message == "outcome saved" and fields.get("status") in TERMINAL:
            writes[job].append((process, fields["status"]))
        elif message == "canceled while queued":
            writes[job].append((process, "canceled"))
        elif message == "a worker's lease expired" and fields.get("status") == "failed":
            writes[job].append((process, "failed"))
        elif message == "finished" and fields.get("outcome") == "succeeded":
            pipeline_successes[job] += 1
        if "fenced" in message or message.startswith("the lease expired before"):
            fenced.append((process, job, message))
    violations = []
    for job, made in writes.items():
        if len(made) > 1:
            violations.append(f"{job}: {len(made)} terminal writes {made}")
    unlogged = [job for job, status in final.items()
                if status in TERMINAL and job not in writes and job in acked]
    report.promise("no job ends twice (terminal writes per job, from the logs)",
                   len(writes), violations)
    report.fenced = fenced
    report.unlogged = unlogged
    report.reruns = sum(1 for n in pipeline_successes.values() if n > 1)

    # 4. Deleted jobs stay deleted.
    violations = []
    came_back_within_lag = 0
    for job, deletion in deletes.items():
        after = deletion["t1"]
        # Not SSE events: a stream open before the delete may still pass on its last change.
        shown = [(t0, replica, what) for t0, _, replica, _, what in seen.get(job, [])
                 if t0 > after and what not in ("webhook", "sse")]
        for op in ("result", "edit", "edit_svg"):
            shown += [(r["t0"], r["replica"], op) for r in by_op[op]
                      if r["job"] == job and r["t0"] > after and r.get("status") in (200, 201)]
        shown += [(r["t0"], r["replica"], "sse") for r in by_op["sse"]
                  if r["job"] == job and r["t0"] > after and r.get("status") == 200
                  and r.get("events")]
        for t0, replica, what in shown:
            if replica == deletion["replica"] or t0 > after + LAG:
                violations.append(f"{job}: shown by {what} on {replica} {t0 - after:.1f} s "
                                  f"after its DELETE was answered")
            else:
                came_back_within_lag += 1
        if job in rows and not rows[job]["deleted"]:
            violations.append(f"{job}: its row is live again at the end")
    leftovers = {key.split("/")[2] for key in objects["keys"]} & set(deletes)
    report.promise("a deleted job never comes back", len(deletes), violations)
    report.deleted_leftovers = len(leftovers)

    # 5. One job per Idempotency-Key. A deleted job frees its key: a second job is right
    # when the first is a tombstone at the end and a DELETE of it began (answered or not:
    # its tombstone may commit before the answer, or without one reaching the client) before
    # the second job's submission was answered.
    violations = []
    keys = collections.defaultdict(list)
    for record in by_op["ack"]:
        if record.get("key"):
            keys[record["key"]].append(record)
    delete_began = collections.defaultdict(list)
    for record in by_op["delete"]:
        delete_began[record["job"]].append(record["t0"])
    for key, records in keys.items():
        jobs = []
        for record in sorted(records, key=lambda r: r["t0"]):
            if record["job"] in jobs:
                continue
            for earlier in jobs:
                tombstone = earlier in rows and rows[earlier]["deleted"] or earlier not in rows
                freed = tombstone and any(t0 < record["t1"] for t0 in delete_began[earlier])
                if not freed:
                    violations.append(f"{key}: jobs {earlier} and {record['job']}")
            jobs.append(record["job"])
    live_keys = collections.Counter(row["idempotency_key"] for row in rows.values()
                                    if row["idempotency_key"] and not row["deleted"])
    violations += [f"{key}: {n} live rows" for key, n in live_keys.items() if n > 1]
    report.promise("one job per Idempotency-Key", len(keys), violations)

    # 6. Completion webhooks.
    violations = []
    delivered = collections.defaultdict(list)
    for record in by_op["webhook"]:
        if not record.get("signed"):
            violations.append(f"{record.get('job')}: a delivery with a bad signature")
        if record.get("type") == "job.completed" and record.get("answered") == 204:
            delivered[record["job"]].append(record)
    hooked = {job for job, records in acked.items() if any(r.get("webhook") for r in records)}
    owed = [job for job in hooked if job not in deletes and final.get(job) in TERMINAL]
    for job in owed:
        if not delivered.get(job):
            violations.append(f"{job}: ended {final[job]}, no completion webhook received")
    duplicates = sum(max(0, len(v) - 1) for v in delivered.values())
    report.promise("every completion webhook arrives at least once, signed", len(owed),
                   violations)
    report.webhook_duplicates = duplicates
    report.webhook_attempts = len(by_op["webhook"])

    # 7. SSE sessions.
    violations = []
    sessions = collections.defaultdict(list)
    for record in by_op["sse"]:
        sessions[record["session"]].append(record)
    ends = {r["session"]: r for r in by_op["sse_end"]}
    resumed = 0
    checked = 0
    for session, records in sessions.items():
        job = records[0]["job"]
        if len(records) > 1:
            resumed += 1
        if job in deletes or final.get(job) not in TERMINAL:
            continue
        checked += 1
        completed = sum(r.get("completed", 0) for r in records)
        if session not in ends:
            violations.append(f"session {session} ({job}, {len(records)} connections): still "
                              f"open at the end, job ended {final[job]}")
        elif completed != 1:
            violations.append(f"session {session} ({job}, {len(records)} connections): "
                              f"{completed} completed events ({ends[session]['outcome']}), "
                              f"job ended {final[job]}")
    report.promise("SSE streams resumed with Last-Event-ID miss no terminal state", checked,
                   violations)
    report.sse_sessions, report.sse_resumed = len(sessions), resumed

    # 8. Crashes.
    violations = [f"{r['process']} exited on its own (status {r['code']})"
                  for r in by_op["exit"] if r["process"] not in ("postgres", "moto")]
    processes = {name for r in by_op["rss"] for name in r["processes"]} - {"postgres", "moto"}
    report.promise("no covec process exits on its own", len(processes), violations)
    report.other_exits = [f"{r['process']} (status {r['code']})" for r in by_op["exit"]
                          if r["process"] in ("postgres", "moto")]

    violations = [f"{r['kind']}: {r['error']}" for r in by_op["harness_error"]]
    report.promise("the harness injected every fault it meant to", len(by_op["fault"]),
                   violations)

    report.stale_reads = stale_reads
    report.deleted_within_lag = came_back_within_lag
    report.history = history
    report.by_op = by_op
    return report


def soak_figures(report, lines):
    by_op = report.by_op
    run = by_op["run"][0]
    started = run["t0"]
    ops = collections.Counter(r["op"] for r in report.history
                              if r["op"] not in ("run", "end", "rss", "fault", "ack", "listed",
                                                 "sse_event", "sse_end", "exit", "harness_error", "quiesced",
                                                 "settled"))
    lines.append("operations: " + ", ".join(f"{op} {n}" for op, n in sorted(ops.items()))
                 + f"; {sum(ops.values())} in all")
    faults = collections.Counter(r["kind"] for r in by_op["fault"])
    lines.append("faults: " + ", ".join(f"{kind} {n}" for kind, n in sorted(faults.items()))
                 + f"; {sum(faults.values())} in all")
    flavours = collections.Counter(
        f"{r['kind']}:{r.get('target') or r.get('flavour')}" for r in by_op["fault"]
        if r.get("target") or r.get("flavour"))
    if flavours:
        lines.append("  of which: " + ", ".join(f"{k} {n}" for k, n in sorted(flavours.items())))

    polls = [r for r in by_op["poll"] if r.get("status") == 200]
    quiet = [1000 * (r["t1"] - r["t0"]) for r in polls if not r.get("in_fault")]
    noisy = [1000 * (r["t1"] - r["t0"]) for r in polls if r.get("in_fault")]
    if quiet:
        lines.append(f"status polls outside fault windows: {len(quiet)}, p50 "
                     f"{percentile(quiet, 0.5):.2f} ms, p99 {percentile(quiet, 0.99):.2f} ms, "
                     f"max {max(quiet):.1f} ms")
    if noisy:
        lines.append(f"status polls inside fault windows: {len(noisy)}, p50 "
                     f"{percentile(noisy, 0.5):.2f} ms, p99 {percentile(noisy, 0.99):.2f} ms, "
                     f"max {max(noisy):.1f} ms")

    server_errors = collections.Counter()
    for r in report.history:
        status = r.get("status")
        if r["op"] in ("sse",) or not isinstance(status, int) or status < 500:
            continue
        label = f"{status} {r.get('code')}"
        if status == 503:
            label += " with Retry-After" if r.get("retry_after") else " WITHOUT Retry-After"
        server_errors[(label, r.get("in_fault"))] += 1
    if server_errors:
        lines.append("5xx answers: " + "; ".join(
            f"{label} {'in' if in_fault else 'OUTSIDE'} fault windows: {n}"
            for (label, in_fault), n in sorted(server_errors.items())))
    else:
        lines.append("5xx answers: none")
    failures = collections.Counter(
        (r["op"], r["error"].split(":")[0], r.get("in_fault")) for r in report.history
        if r.get("error") and r["op"] not in ("sse", "harness_error"))
    if failures:
        lines.append("no answer: " + "; ".join(
            f"{op} {kind} {'in' if f else 'OUTSIDE'} fault windows: {n}"
            for (op, kind, f), n in sorted(failures.items())))

    samples = by_op["rss"]
    if samples:
        reference_at = started + (300 if run["minutes"] >= 10 else run["warmup"] + 15)
        reference = next((s for s in samples if s["t0"] >= reference_at), samples[0])
        last = samples[-1]
        parts = []
        for name, (incarnation, rss) in last["processes"].items():
            ref = reference["processes"].get(name)
            if not rss or not ref or not ref[1]:
                continue
            at = (reference["t0"] - started) / 60
            end = (last["t0"] - started) / 60
            if ref[0] == incarnation:
                growth = 100.0 * (rss - ref[1]) / ref[1]
                parts.append(f"{name} {ref[1] / 1024:.1f} → {rss / 1024:.1f} MiB "
                             f"({growth:+.1f} %)")
            else:
                parts.append(f"{name} restarted (now {rss / 1024:.1f} MiB)")
        lines.append(f"RSS at {at:.1f} → {end:.1f} min: " + "; ".join(parts))


def main(run_dir):
    report = check(run_dir)
    lines = [f"chaos report: {run_dir}"]
    soak_figures(report, lines)
    lines.append("promises:")
    for name, (checked, violations) in report.promises.items():
        lines.append(f"  {'ok ' if not violations else 'FAIL'} {name}: {checked} checked, "
                     f"{len(violations)} violations")
        for violation in violations[:20]:
            lines.append(f"       {violation}")
        if len(violations) > 20:
            lines.append(f"       … and {len(violations) - 20} more")
    lines.append(f"stale writes refused by the lease fence: {len(report.fenced)}")
    for process, job, message in report.fenced[:10]:
        lines.append(f"  {process} {job}: {message}")
    lines.append(f"jobs run to success more than once in a pipeline (only one saved): "
                 f"{report.reruns}; ended jobs without a logged terminal write: "
                 f"{len(report.unlogged)}")
    lines.append(f"webhook attempts received {report.webhook_attempts}, duplicate completed "
                 f"deliveries (allowed) {report.webhook_duplicates}; SSE sessions "
                 f"{report.sse_sessions}, resumed {report.sse_resumed}")
    lines.append(f"reads within the replicas' lag ({LAG:g} s): ended job shown not ended "
                 f"{report.stale_reads}, deleted job still shown {report.deleted_within_lag}; "
                 f"deleted jobs with files left in the bucket (for the orphan sweep): "
                 f"{report.deleted_leftovers}")
    if report.other_exits:
        lines.append(f"server exits (restarted): {', '.join(report.other_exits)}")
    violations = report.violations()
    operations = sum(1 for r in report.history if r["op"] not in (
        "run", "end", "rss", "fault", "ack", "listed", "sse_event", "sse_end", "exit", "harness_error",
        "quiesced", "settled"))
    lines.append(f"chaos: {operations} operations, {len(report.by_op['fault'])} faults, "
                 f"{len(report.promises)} promises checked, violations: {violations}")
    text = "\n".join(lines)
    with open(os.path.join(run_dir, "report.txt"), "w") as f:
        f.write(text + "\n")
    print(text, flush=True)
    return violations


if __name__ == "__main__":
    sys.exit(1 if main(sys.argv[1]) else 0)
