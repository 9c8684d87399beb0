"""The clients: steady mixed traffic on the API replicas, every operation written to the
history with its start and end (wall-clock seconds), and the webhook receiver.

Operations: submissions (with and without Idempotency-Key, some with a webhook, some batch;
a keyed submission that got no answer is retried with the same key, as a client would), status
polls (a fixed rate, for the latency figures), listings, cancels, deletes, edits, result
downloads, replays of an acknowledged key, and SSE streams cut at random and resumed with
Last-Event-ID on any replica."""

import base64
import hashlib
import heapq
import hmac
import http.client
import http.server
import json
import random
import struct
import threading
import time
import uuid
import zlib

TERMINAL = {"succeeded", "failed", "canceled"}


class History:
    """Append-only JSON lines; every record gets `t0`/`t1` (wall-clock seconds)."""

    def __init__(self, path):
        self.file = open(path, "a")
        self.lock = threading.Lock()

    def record(self, **fields):
        line = json.dumps(fields, separators=(",", ":"))
        with self.lock:
            self.file.write(line + "\n")

    def close(self):
        with self.lock:
            self.file.flush()
            self.file.close()


class Response:
    def __init__(self, status=None, headers=None, body=b"", error=None):
        self.status, self.headers, self.body, self.error = status, headers or {}, body, error

    def json(self):
        try:
            return json.loads(self.body)
        except ValueError:
            return None


def call(address, method, path, body=None, headers=None, timeout=15):
    host, port = address
    try:
        connection = http.client.HTTPConnection(host, port, timeout=timeout)
        connection.request(method, path, body=body, headers=headers or {})
        response = connection.getresponse()
        data = response.read()
        connection.close()
        return Response(response.status, {k.lower(): v for k, v in response.getheaders()}, data)
    except (OSError, http.client.HTTPException) as error:
        return Response(error=f"{type(error).__name__}: {error}")


def tiny_png(size, seed):
    """A size² RGB PNG: a ground, a darker square and a lighter disc, colours from `seed`."""
    rng = random.Random(seed)
    ground = tuple(rng.randrange(120, 230) for _ in range(3))
    square = tuple(rng.randrange(10, 110) for _ in range(3))
    disc = tuple(rng.randrange(150, 255) for _ in range(3))
    x0, y0 = rng.randrange(0, size // 2), rng.randrange(0, size // 2)
    cx, cy, r = rng.randrange(size), rng.randrange(size), rng.randrange(size // 6, size // 3)

    def pixel(x, y):
        if (x - cx) ** 2 + (y - cy) ** 2 < r * r:
            return disc
        if x0 <= x < x0 + size // 2 and y0 <= y < y0 + size // 2:
            return square
        return ground

    rows = b"".join(b"\0" + b"".join(bytes(pixel(x, y)) for x in range(size))
                    for y in range(size))

    def chunk(kind, data):
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data)))

    header = struct.pack(">IIBBBBB", size, size, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(rows))
            + chunk(b"IEND", b""))


def multipart(fields):
    boundary = uuid.uuid4().hex
    parts = []
    for name, value in fields:
        if isinstance(value, bytes):
            parts.append(f"--{boundary}\r\nContent-Disposition: form-data; name=\"{name}\"; "
                         f"filename=\"{name}.png\"\r\nContent-Type: image/png\r\n\r\n".encode()
                         + value + b"\r\n")
        else:
            parts.append(f"--{boundary}\r\nContent-Disposition: form-data; name=\"{name}\""
                         f"\r\n\r\n{value}\r\n".encode())
    body = b"".join(parts) + f"--{boundary}--\r\n".encode()
    return body, f"multipart/form-data; boundary={boundary}"


def verify_signature(secret, headers, body):
    """Standard Webhooks: `v1,` + base64(HMAC-SHA256(key, id.timestamp.body)); the key is the
    base64 after `whsec_`. Any of the space-separated signatures may match."""
    key = base64.b64decode(secret.removeprefix("whsec_"))
    msg_id, timestamp = headers.get("webhook-id", ""), headers.get("webhook-timestamp", "")
    expected = base64.b64encode(hmac.new(key, f"{msg_id}.{timestamp}.".encode() + body,
                                         hashlib.sha256).digest()).decode()
    given = headers.get("webhook-signature", "").split()
    return any(sig.startswith("v1,") and hmac.compare_digest(sig[3:], expected) for sig in given)


# The Standard Webhooks reference example: the receiver's check, checked.
assert verify_signature("whsec_MfKQ9r8GKYqrTwjUPD8ILPZIo2LaLaSw",
                        {"webhook-id": "msg_p5jXN8AQM9LWM0D4loKWxJek",
                         "webhook-timestamp": "1614265330",
                         "webhook-signature": "v1,g0hM9SsE+OTPJTGt/tmIKtSyZlE3uFJELVlNIOLJ1OE="},
                        b'{"test": 2432232314}')


class WebhookReceiver:
    """Records every delivery (verified or not) and fails some attempts on purpose (503), so
    deliveries are retried."""

    def __init__(self, ip, port, secret, history, fail_rate=0.15):
        receiver = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_POST(self):
                t0 = time.time()
                length = int(self.headers.get("content-length", 0))
                body = self.rfile.read(length)
                headers = {k.lower(): v for k, v in self.headers.items()}
                fail = receiver.rng.random() < fail_rate
                signed = verify_signature(secret, headers, body)
                try:
                    message = json.loads(body)
                except ValueError:
                    message = {}
                data = message.get("data", {}) if isinstance(message, dict) else {}
                history.record(op="webhook", t0=t0, t1=time.time(), job=data.get("id"),
                               type=message.get("type"), job_status=data.get("status"),
                               webhook_id=headers.get("webhook-id"),
                               signed=signed, answered=503 if fail else 204)
                if signed and not fail and message.get("type") == "job.completed":
                    receiver.completed[data.get("id")] = data.get("status")
                self.send_response(503 if fail else 204)
                self.send_header("content-length", "0")
                self.end_headers()

            def log_message(self, *args):
                pass

        self.rng = random.Random(7)
        self.completed = {}
        self.server = http.server.ThreadingHTTPServer((ip, port), Handler)
        self.server.daemon_threads = True
        self.url = f"http://{ip}:{port}/hook"
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    def start(self):
        self.thread.start()

    def stop(self):
        self.server.shutdown()


class Traffic:
    def __init__(self, apis, history, webhook_url, in_fault, seed, rate, job_params, long_params,
                 poll_rate=20):
        """`apis`: name -> (host, port); `in_fault()`: whether a fault window is open now."""
        self.apis = apis
        self.history = history
        self.webhook_url = webhook_url
        self.in_fault = in_fault
        self.rng = random.Random(seed)
        self.rate = rate
        self.job_params = job_params
        self.long_params = long_params
        self.poll_rate = poll_rate
        self.stopping = threading.Event()
        self.lock = threading.Lock()
        self.jobs = {}           # id -> {"key":..., "webhook": bool, "deleted": bool, ...}
        self.keys = {}           # key -> (fields) to replay
        self.actions = []        # heap of (due, seq, action, job)
        self.action_seq = 0
        self.action_ready = threading.Condition(self.lock)
        self.streams = threading.Semaphore(6)
        self.threads = []
        self.counter = 0
        self.sessions = 0

    # --- plumbing ---

    def replica(self):
        name = self.rng.choice(sorted(self.apis))
        return name, self.apis[name]

    def op(self, op, replica, method, path, body=None, headers=None, timeout=15, **fields):
        t0 = time.time()
        response = call(self.apis[replica], method, path, body, headers, timeout)
        t1 = time.time()
        record = dict(op=op, t0=t0, t1=t1, replica=replica, status=response.status,
                      in_fault=self.in_fault(), **fields)
        if response.error:
            record["error"] = response.error
        if response.status in (200, 201, 202) and "json" in response.headers.get(
                "content-type", ""):
            view = response.json()
            if isinstance(view, dict) and str(view.get("id", "")).startswith("job_"):
                record["job_status"] = view.get("status")
        if response.status and response.status >= 500:
            problem = response.json() or {}
            record["code"] = problem.get("code")
            record["retry_after"] = response.headers.get("retry-after")
        self.history.record(**record)
        return response, record

    def schedule(self, delay, action, job):
        with self.lock:
            self.action_seq += 1
            heapq.heappush(self.actions, (time.time() + delay, self.action_seq, action, job))
            self.action_ready.notify()

    def spawn(self, target, *args):
        thread = threading.Thread(target=target, args=args, daemon=True)
        thread.start()
        self.threads.append(thread)
        return thread

    def start(self):
        self.spawn(self.submitter)
        self.spawn(self.poller)
        self.spawn(self.lister)
        for _ in range(4):
            self.spawn(self.action_runner)

    def stop(self):
        self.stopping.set()
        with self.lock:
            self.action_ready.notify_all()

    def sessions_open(self):
        return 6 - self.streams._value

    def outstanding(self):
        with self.lock:
            return sum(1 for job in self.jobs.values()
                       if not job["deleted"] and job.get("seen") not in TERMINAL)

    # --- submissions ---

    def submitter(self):
        next_at = time.time()
        while not self.stopping.is_set():
            next_at += 1.0 / self.rate
            delay = next_at - time.time()
            if delay > 0:
                self.stopping.wait(delay)
            if self.stopping.is_set():
                return
            if self.outstanding() > 60:
                # The cluster is behind (a fault): a steady client waits rather than flood it.
                next_at = time.time() + 1
                continue
            self.submit_new()

    def submit_new(self):
        with self.lock:
            self.counter += 1
            n = self.counter
        rng = self.rng
        long_job = rng.random() < 0.15
        params = dict(self.long_params if long_job else self.job_params, seed=n)
        fields = [("image", tiny_png(32, n)), ("params", json.dumps(params))]
        webhook = rng.random() < 0.3
        if webhook:
            fields.append(("webhook", self.webhook_url))
            if rng.random() < 0.5:
                fields.append(("webhook_events", "started,completed"))
        if rng.random() < 0.1:
            fields.append(("priority", "batch"))
        key = f"key-{n}-{uuid.uuid4().hex[:8]}" if rng.random() < 0.5 else None
        body, content_type = multipart(fields)
        headers = {"content-type": content_type}
        if key:
            headers["idempotency-key"] = key
        job = self.submit(body, headers, key, webhook)
        if job is None:
            return
        with self.lock:
            if key:
                self.keys[key] = (body, headers)
        roll = rng.random()
        if roll < 0.08:
            self.schedule(rng.uniform(0, 3), "cancel", job)
        elif roll < 0.16:
            self.schedule(rng.uniform(0, 6), "delete", job)
        if key and rng.random() < 0.15:
            self.schedule(rng.uniform(0.5, 20), "replay", job)
        if rng.random() < 0.25:
            self.schedule(0, "sse", job)
        self.schedule(rng.uniform(2, 8), "check", job)

    def submit(self, body, headers, key, webhook, replay_of=None):
        """One submission; keyed ones are retried (same key, same body, any replica) until
        acknowledged or 8 tries. Returns the job id acknowledged, if any."""
        tries = 8 if key else 1
        for attempt in range(tries):
            replica, _ = self.replica()
            response, record = self.op("submit", replica, "POST", "/v1/jobs", body, headers,
                                       timeout=30, key=key, attempt=attempt,
                                       webhook=webhook, replay_of=replay_of)
            if response.status in (200, 201, 202):
                view = response.json()
                job = view["id"]
                self.history.record(op="ack", t0=record["t0"], t1=record["t1"], job=job,
                                    key=key, replica=replica,
                                    replayed=response.headers.get("idempotent-replayed") == "true",
                                    job_status=view["status"], webhook=webhook)
                with self.lock:
                    known = self.jobs.setdefault(job, {"key": key, "webhook": webhook,
                                                       "deleted": False, "seen": None})
                    known["seen"] = view["status"]
                return job
            if response.status is not None and response.status < 500 and response.status != 429:
                return None
            if self.stopping.is_set():
                return None
            time.sleep(min(8.0, 0.5 * 2 ** attempt) * (0.5 + self.rng.random()))
        return None

    # --- actions on known jobs ---

    def action_runner(self):
        while True:
            with self.lock:
                while not self.stopping.is_set():
                    if self.actions and self.actions[0][0] <= time.time():
                        break
                    wait = (self.actions[0][0] - time.time()) if self.actions else 1.0
                    self.action_ready.wait(max(0.01, min(wait, 1.0)))
                if self.stopping.is_set():
                    return
                _, _, action, job = heapq.heappop(self.actions)
            getattr(self, f"do_{action}")(job)

    def do_cancel(self, job):
        replica, _ = self.replica()
        self.op("cancel", replica, "POST", f"/v1/jobs/{job}/cancel", job=job)

    def do_delete(self, job):
        replica, _ = self.replica()
        response, _ = self.op("delete", replica, "DELETE", f"/v1/jobs/{job}", job=job)
        if response.status in (204, 404):
            with self.lock:
                self.jobs[job]["deleted"] = True
        elif response.status is None or response.status >= 500:
            self.schedule(2, "delete", job)

    def do_replay(self, job):
        key = self.jobs[job]["key"]
        body, headers = self.keys[key]
        self.submit(body, headers, key, self.jobs[job]["webhook"], replay_of=job)

    def do_check(self, job):
        """Polls a job until it ends (then maybe downloads, edits or deletes it)."""
        with self.lock:
            if self.jobs[job]["deleted"]:
                return
        replica, _ = self.replica()
        response, _ = self.op("get", replica, "GET", f"/v1/jobs/{job}", job=job)
        view = response.json() if response.status == 200 else None
        if view:
            self.observe(job, view["status"])
        if response.status == 404:
            return
        if not view or view["status"] not in TERMINAL:
            self.schedule(self.rng.uniform(1, 4), "check", job)
            return
        if view["status"] != "succeeded":
            return
        rng = self.rng
        if rng.random() < 0.5:
            self.op("result", replica, "GET", f"/v1/jobs/{job}/svg", job=job)
        if rng.random() < 0.15:
            self.schedule(rng.uniform(0, 3), "edit", job)
        if rng.random() < 0.08:
            self.schedule(rng.uniform(0, 10), "delete", job)

    def do_edit(self, job):
        replica, _ = self.replica()
        body = json.dumps({"changes": [{"at": {"x": 8, "y": 8}, "color": "#2060c0"}]})
        response, _ = self.op("edit", replica, "POST", f"/v1/jobs/{job}/edits", body,
                              {"content-type": "application/json"}, job=job)
        if response.status == 201:
            edit = response.json()["id"]
            self.op("edit_svg", replica, "GET", f"/v1/jobs/{job}/edits/{edit}/svg", job=job,
                    edit=edit)

    def observe(self, job, status):
        with self.lock:
            known = self.jobs.get(job)
            if known is not None:
                known["seen"] = status

    # --- SSE ---

    def do_sse(self, job):
        if not self.streams.acquire(blocking=False):
            return
        self.spawn(self.follow, job)

    def follow(self, job):
        """One SSE session: connect, read events, cut the stream at random and resume with
        Last-Event-ID on any replica, until `completed` (or the job is gone)."""
        try:
            with self.lock:
                self.sessions += 1
                session = self.sessions
            last_id, completed, outcome = None, 0, "gave up"
            # Sessions go on after the traffic stops, until their job ends (the harness waits
            # for them before it collects the final state).
            deadline = time.time() + 600
            while time.time() < deadline:
                replica, address = self.replica()
                headers = {"accept": "text/event-stream"}
                if last_id:
                    headers["last-event-id"] = last_id
                cut_after = self.rng.choice([None, None, 1, 2, 3])
                t0 = time.time()
                events, status, error, ended = self.stream(address, job, headers, cut_after,
                                                           session, replica)
                for event in events:
                    last_id = event["id"] or last_id
                    if event["event"] == "completed":
                        completed += 1
                self.history.record(op="sse", t0=t0, t1=time.time(), replica=replica, job=job,
                                    session=session, status=status, error=error,
                                    resumed_from=headers.get("last-event-id"),
                                    events=len(events), cut=ended == "cut",
                                    completed=sum(e["event"] == "completed" for e in events),
                                    in_fault=self.in_fault())
                if completed:
                    outcome = "completed"
                    break
                if status is not None and 400 <= status < 500:
                    outcome = f"answered {status}"
                    break
                time.sleep(self.rng.uniform(0.1, 1.0))
            self.history.record(op="sse_end", t0=time.time(), t1=time.time(), job=job,
                                session=session, outcome=outcome, completed=completed)
        finally:
            self.streams.release()

    def stream(self, address, job, headers, cut_after, session, replica):
        events = []
        try:
            connection = http.client.HTTPConnection(*address, timeout=30)
            connection.request("GET", f"/v1/jobs/{job}/events", headers=headers)
            response = connection.getresponse()
            if response.status != 200:
                response.read()
                return events, response.status, None, "status"
            event = {"id": None, "event": None, "data": []}
            while True:
                line = response.fp.readline()
                if not line:
                    return events, 200, None, "eof"
                line = line.decode().rstrip("\r\n")
                if line.startswith(":"):
                    continue
                if line == "":
                    if event["event"]:
                        data = json.loads("\n".join(event["data"]))
                        event["status"] = data.get("status")
                        del event["data"]
                        events.append(event)
                        self.history.record(op="sse_event", t0=time.time(), t1=time.time(),
                                            replica=replica, job=job, session=session,
                                            event=event["event"], id=event["id"],
                                            job_status=event["status"])
                        self.observe(job, event["status"])
                        if event["event"] == "completed":
                            return events, 200, None, "completed"
                        if cut_after is not None and len(events) >= cut_after:
                            connection.close()
                            return events, 200, None, "cut"
                    event = {"id": None, "event": None, "data": []}
                    continue
                name, _, value = line.partition(":")
                value = value[1:] if value.startswith(" ") else value
                if name == "id":
                    event["id"] = value
                elif name == "event":
                    event["event"] = value
                elif name == "data":
                    event["data"].append(value)
        except (OSError, http.client.HTTPException, ValueError) as error:
            return events, 200 if events else None, f"{type(error).__name__}: {error}", "error"

    # --- polls and listings ---

    def poller(self):
        """GET /v1/jobs/{id} of recent jobs at a fixed rate on keep-alive connections, one
        per replica: the status-poll latency."""
        connections = {}
        interval = 1.0 / self.poll_rate
        next_at = time.time()
        while not self.stopping.is_set():
            next_at += interval
            delay = next_at - time.time()
            if delay > 0:
                time.sleep(delay)
            else:
                next_at = time.time()
            with self.lock:
                recent = list(self.jobs)[-50:]
            if not recent:
                continue
            job = self.rng.choice(recent)
            replica = self.rng.choice(sorted(self.apis))
            t0 = time.time()
            status, error, view, code, retry_after = None, None, None, None, None
            try:
                connection = connections.get(replica)
                if connection is None:
                    connection = http.client.HTTPConnection(*self.apis[replica], timeout=15)
                    connections[replica] = connection
                connection.request("GET", f"/v1/jobs/{job}")
                response = connection.getresponse()
                body = response.read()
                status = response.status
                if status == 200:
                    view = json.loads(body)
                elif status >= 500:
                    problem = json.loads(body) if body.startswith(b"{") else {}
                    code, retry_after = problem.get("code"), response.getheader("retry-after")
            except (OSError, http.client.HTTPException, ValueError) as e:
                error = f"{type(e).__name__}: {e}"
                connections.pop(replica, None)
            t1 = time.time()
            record = dict(op="poll", t0=t0, t1=t1, replica=replica, job=job, status=status,
                          in_fault=self.in_fault())
            if error:
                record["error"] = error
            if status and status >= 500:
                record["code"], record["retry_after"] = code, retry_after
            if view:
                record["job_status"] = view["status"]
                self.observe(job, view["status"])
            self.history.record(**record)

    def lister(self):
        while not self.stopping.wait(2.0):
            replica, _ = self.replica()
            status = self.rng.choice([None, None, "running", "succeeded", "queued"])
            query = "?limit=50" + (f"&status={status}" if status else "")
            response, record = self.op("list", replica, "GET", f"/v1/jobs{query}",
                                       filter=status, timeout=15)
            if response.status == 200:
                items = response.json()["items"]
                self.history.record(op="listed", t0=record["t0"], t1=record["t1"],
                                    replica=replica,
                                    jobs=[[item["id"], item["status"]] for item in items])
