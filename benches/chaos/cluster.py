"""The processes under test and the servers they use, each in its host's namespace
(netns.py): PostgreSQL (its data directory on a small tmpfs the harness mounted: the disk the
disk-full fault fills) and moto's S3 server on the `srv` host, API replicas (`covec serve
--workers 0`) and workers (`covec worker`). Every process logs to a file of its own under the
run directory (covec's as JSON lines), appended across restarts."""

import json
import os
import signal
import subprocess
import threading
import time

PG_PORT = 5432
S3_PORT = 9000
API_PORT = 8080
OPS_PORT = 9090
BUCKET = "chaos"
WEBHOOK_SECRET = "whsec_MfKQ9r8GKYqrTwjUPD8ILPZIo2LaLaSw"


def pg_bin(program):
    versions = sorted(p for p in os.listdir("/usr/lib/postgresql")
                      if os.path.exists(f"/usr/lib/postgresql/{p}/bin/initdb"))
    return f"/usr/lib/postgresql/{versions[-1]}/bin/{program}" if versions else program


def as_postgres(argv):
    """PostgreSQL refuses to run as root: as the `postgres` user through setpriv (which execs,
    so the process started is the server itself)."""
    if os.geteuid() == 0:
        return ["setpriv", "--reuid=postgres", "--regid=postgres", "--init-groups", *argv]
    return argv


class Process:
    """One long-running process: started, killed, paused, restarted; its RSS sampled."""

    def __init__(self, name, argv, log_path, env=None):
        self.name, self.argv, self.log_path, self.env = name, argv, log_path, env
        self.popen = None
        self.incarnation = 0
        self.started_at = None
        self.expected_exit = False

    def start(self):
        log = open(self.log_path, "a")
        self.popen = subprocess.Popen(self.argv, stdout=log, stderr=subprocess.STDOUT,
                                      env=self.env, start_new_session=True)
        log.close()
        self.incarnation += 1
        self.started_at = time.monotonic()
        self.expected_exit = False

    @property
    def pid(self):
        return self.popen.pid if self.popen else None

    def alive(self):
        return self.popen is not None and self.popen.poll() is None

    def send(self, sig):
        if self.alive():
            os.kill(self.popen.pid, sig)

    def kill9(self):
        self.expected_exit = True
        self.send(signal.SIGKILL)
        self.popen.wait()

    def stop(self, sig=signal.SIGTERM, timeout=30):
        self.expected_exit = True
        self.send(sig)
        try:
            self.popen.wait(timeout)
        except subprocess.TimeoutExpired:
            self.send(signal.SIGKILL)
            self.popen.wait()

    def rss_kib(self):
        """VmRSS of the process (and of its children, for PostgreSQL's backends)."""
        if not self.alive():
            return None
        total = 0
        for pid in [self.popen.pid, *children(self.popen.pid)]:
            try:
                with open(f"/proc/{pid}/status") as f:
                    for line in f:
                        if line.startswith("VmRSS:"):
                            total += int(line.split()[1])
            except OSError:
                pass
        return total


def children(pid):
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            return [int(child) for child in f.read().split()]
    except OSError:
        return []


class Cluster:
    def __init__(self, net, run_dir, covec, pg_dir, apis, workers, lease):
        self.net, self.run_dir, self.covec, self.pg_dir = net, run_dir, covec, pg_dir
        self.lease = lease
        self.logs = os.path.join(run_dir, "logs")
        os.makedirs(self.logs, exist_ok=True)
        self.srv_ip = net.ips["srv"]
        self.database_url = f"postgres://covec@{self.srv_ip}:{PG_PORT}/postgres"
        self.s3_endpoint = f"http://{self.srv_ip}:{S3_PORT}"
        self.postgres = Process("postgres", net.exec("srv") + as_postgres([
            pg_bin("postgres"), "-D", os.path.join(pg_dir, "data"), "-p", str(PG_PORT),
            "-h", self.srv_ip, "-k", pg_dir,
            "-c", "fsync=off", "-c", "synchronous_commit=off", "-c", "full_page_writes=off",
            "-c", "max_wal_size=64MB", "-c", "min_wal_size=32MB",
            "-c", "max_connections=200"]), os.path.join(self.logs, "postgres.log"))
        self.moto = Process("moto", net.exec("srv") + [
            "moto_server", "-H", self.srv_ip, "-p", str(S3_PORT)],
            os.path.join(self.logs, "moto.log"))
        self.apis = [self.covec_process(name, "api") for name in apis]
        self.workers = [self.covec_process(name, "worker") for name in workers]
        self.lock = threading.Lock()

    def env(self):
        env = dict(os.environ)
        env.update({"AWS_ENDPOINT": self.s3_endpoint, "AWS_ALLOW_HTTP": "true",
                    "AWS_ACCESS_KEY_ID": "test", "AWS_SECRET_ACCESS_KEY": "test",
                    "AWS_REGION": "us-east-1", "COVEC_LOG": "info,tower_http=info"})
        return env

    def covec_process(self, host, kind):
        ip = self.net.ips[host]
        common = ["--data-dir", os.path.join(self.run_dir, "data", host),
                  "--database-url", self.database_url,
                  "--object-store", f"s3://{BUCKET}/covec",
                  "--lease-seconds", str(self.lease), "--log-format", "json"]
        if kind == "api":
            # Reached only inside the harness's own network namespaces: no keys needed.
            argv = [self.covec, "serve", "--addr", f"{ip}:{API_PORT}", "--workers", "0",
                    "--allow-anonymous", "--max-queued", "400",
                    "--webhook-secret", WEBHOOK_SECRET,
                    "--webhook-hosts", self.net.ips["cli"],
                    "--webhook-attempts", "8", "--webhook-first-retry", "1", *common]
        else:
            argv = [self.covec, "worker", "--workers", "1", "--threads", "1",
                    "--ops-addr", f"{ip}:{OPS_PORT}", *common]
        process = Process(host, self.net.exec(host) + argv,
                          os.path.join(self.logs, f"{host}.log"), self.env())
        process.kind = kind
        process.ip = ip
        return process

    def api_url(self, name):
        return self.net.ips[name], API_PORT

    def all(self):
        return [self.postgres, self.moto, *self.apis, *self.workers]

    def covecs(self):
        return [*self.apis, *self.workers]

    # --- the servers ---

    def init_postgres(self):
        data = os.path.join(self.pg_dir, "data")
        if os.geteuid() == 0:
            subprocess.run(["chown", "-R", "postgres", self.pg_dir], check=True)
        subprocess.run(as_postgres([pg_bin("initdb"), "-D", data, "-U", "covec", "--auth=trust",
                                    "-E", "UTF8", "--no-sync"]),
                       check=True, capture_output=True)
        with open(os.path.join(data, "pg_hba.conf"), "a") as f:
            f.write(f"host all all {self.net.ips['srv'].rsplit('.', 1)[0]}.0/24 trust\n")

    def start_postgres(self):
        self.postgres.start()
        self.wait_postgres()

    def wait_postgres(self, timeout=60):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            ready = subprocess.run([pg_bin("pg_isready"), "-q", "-h", self.srv_ip, "-p",
                                    str(PG_PORT)]).returncode == 0
            if ready:
                return True
            if not self.postgres.alive():
                return False
            time.sleep(0.2)
        return False

    def restart_postgres(self):
        """Fast shutdown (every connection cut), then start again on the same data."""
        self.postgres.stop(signal.SIGINT)
        self.start_postgres()

    def start_moto(self):
        self.moto.start()
        deadline = time.monotonic() + 60
        while True:
            try:
                s3 = self.s3()
                s3.create_bucket(Bucket=BUCKET)
                return
            except Exception:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.3)

    def s3(self):
        import boto3
        from botocore.config import Config
        return boto3.client("s3", endpoint_url=self.s3_endpoint, region_name="us-east-1",
                            aws_access_key_id="test", aws_secret_access_key="test",
                            config=Config(retries={"max_attempts": 5}, connect_timeout=5,
                                          read_timeout=30))

    def psql_json(self, sql):
        """Rows of `sql` as JSON objects (the query is wrapped in json_agg)."""
        out = subprocess.run(["psql", self.database_url, "-XAtq", "-c",
                              f"SELECT coalesce(json_agg(q), '[]') FROM ({sql}) q"],
                             capture_output=True, text=True, check=True, timeout=120)
        return json.loads(out.stdout)

    # --- covec processes ---

    def start_covec(self, process):
        process.start()

    def wait_ready(self, process, timeout=60):
        """Until the process answers /readyz (an API replica's port or a worker's ops port)."""
        import http.client
        port = API_PORT if process.kind == "api" else OPS_PORT
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                connection = http.client.HTTPConnection(process.ip, port, timeout=2)
                connection.request("GET", "/readyz")
                if connection.getresponse().status == 200:
                    return True
            except OSError:
                pass
            if not process.alive():
                return False
            time.sleep(0.2)
        return False
