"""What the shared-backend benchmarks (scale_out.py, poll_latency.py) share: one API replica
(`covec serve --workers 0`) and N `covec worker --threads 1` on the caller's PostgreSQL and a
scratch data directory, stopped and cleaned up after (jobs table emptied); and a submission.
Standard library only."""

import contextlib
import http.client
import json
import os
import signal
import subprocess
import tempfile
import uuid


@contextlib.contextmanager
def cluster(covec, database_url, workers, extra=()):
    """Yields (host, port) of the API replica while the workers run."""
    data = tempfile.mkdtemp(prefix="covec-bench-")
    common = ["--data-dir", data, "--database-url", database_url, *extra]
    log = open(os.path.join(data, "log"), "w")
    api = subprocess.Popen([covec, "serve", "--addr", "127.0.0.1:0", "--workers", "0", *common],
                           stdout=subprocess.PIPE, stderr=log, text=True)
    host, port = api.stdout.readline().strip().rsplit("/", 1)[1].split(":")
    processes = [api] + [subprocess.Popen([covec, "worker", "--threads", "1", *common],
                                          stdout=subprocess.DEVNULL, stderr=log)
                         for _ in range(workers)]
    try:
        yield host, int(port)
    finally:
        for process in processes:
            process.send_signal(signal.SIGTERM)
        for process in processes:
            process.wait()
        subprocess.run(["psql", database_url, "-Xq", "-c", "DELETE FROM jobs"], check=True)
        subprocess.run(["rm", "-rf", data], check=True)


def request(connection, method, path, body=None, headers=None):
    """(status, body) of one request on a keep-alive connection."""
    connection.request(method, path, body=body, headers=headers or {})
    response = connection.getresponse()
    return response.status, response.read()


def submit(connection, image_path, params):
    """Submits the PNG at `image_path` with `params` (JSON text); returns the job id."""
    boundary = uuid.uuid4().hex
    with open(image_path, "rb") as f:
        image = f.read()
    body = b"".join([
        f"--{boundary}\r\nContent-Disposition: form-data; name=\"image\"; filename=\"i.png\"\r\n"
        f"Content-Type: image/png\r\n\r\n".encode(), image, b"\r\n",
        f"--{boundary}\r\nContent-Disposition: form-data; name=\"params\"\r\n"
        f"Content-Type: application/json\r\n\r\n{params}\r\n--{boundary}--\r\n".encode(),
    ])
    status, reply = request(connection, "POST", "/v1/jobs", body,
                            {"content-type": f"multipart/form-data; boundary={boundary}"})
    assert status == 201, reply
    return json.loads(reply)["id"]


def status(connection, job):
    """The job's status."""
    return json.loads(request(connection, "GET", f"/v1/jobs/{job}")[1])["status"]
