"""The Python client (openapi-python-client) through a whole job: limits, a multipart submission
with `Prefer: wait`, a JSON one, every result format, a recolour, a delete.

`python3 flow.py URL IMAGE` with the generated `covec_client` on PYTHONPATH; exits non-zero on
the first thing that is wrong.
"""

import base64
import io
import sys

from covec_client import Client
from covec_client.api.edits import create_edit, get_edit_svg
from covec_client.api.jobs import create_job, delete_job, get_job
from covec_client.api.operations import get_limits
from covec_client.api.results import get_pdf, get_png, get_svg
from covec_client.models import (
    ColorEditRequest,
    Iterations,
    JsonSubmission,
    MultipartSubmission,
    Params,
    Point,
    PointChange,
    Problem,
    Status,
)
from covec_client.types import File

base_url, image_path = sys.argv[1], sys.argv[2]
client = Client(base_url=base_url, raise_on_unexpected_status=True)
image = open(image_path, "rb").read()
quick = Params(
    paths=8,
    max_size=48,
    seed=1,
    iterations=Iterations(structure=3, reconstruction=3, refine_rounds=1, refine=3, polish=3),
)


def check(condition, what):
    if not condition:
        sys.exit(f"python client: {what}")


limits = get_limits.sync(client=client)
check(limits.max_paths >= 8, f"limits: {limits}")

# Multipart: the image as a file part (its name names the downloads), parameters as JSON.
answer = create_job.sync_detailed(
    client=client,
    prefer="wait=60",
    body=MultipartSubmission(
        image=File(payload=io.BytesIO(image), file_name="sample.png", mime_type="image/png"),
        params=quick,
    ),
)
check(answer.status_code == 200, f"multipart submission: {answer.status_code} {answer.content!r}")
job = answer.parsed
check(job.status == Status.SUCCEEDED, f"job {job.id} is {job.status}")
check(job.urls.results.pdf.endswith("/pdf"), "the job lists its PDF")

# JSON with base64.
answer = create_job.sync_detailed(
    client=client,
    body=JsonSubmission(
        image=base64.b64encode(image).decode(), filename="other.png", params=quick
    ),
)
check(answer.status_code == 201, f"JSON submission: {answer.status_code} {answer.content!r}")

files = [
    ("sample.svg", get_svg.sync_detailed(client=client, id=job.id), b"<svg"),
    ("sample-flat.svg", get_svg.sync_detailed(client=client, id=job.id, flatten=True), b"<svg"),
    ("sample.pdf", get_pdf.sync_detailed(client=client, id=job.id), b"%PDF"),
    ("sample.png", get_png.sync_detailed(client=client, id=job.id, width=96), b"\x89PNG"),
]
for name, answer, magic in files:
    check(answer.status_code == 200, f"{name}: {answer.status_code}")
    payload = answer.parsed.payload.read()
    check(magic in payload[:200], f"{name} does not hold {magic!r}")
    disposition = answer.headers.get("content-disposition", "")
    check(f'filename="{name}"' in disposition, f"{name}: Content-Disposition {disposition}")
    check(answer.headers.get("etag"), f"{name} has no ETag")

# A recolour of whatever albedo path is at the centre.
edit = create_edit.sync(
    client=client,
    id=job.id,
    body=ColorEditRequest(changes=[PointChange(at=Point(x=24, y=24), color="#2060c0")]),
)
check(not isinstance(edit, Problem), f"edit: {edit}")
svg = get_edit_svg.sync(client=client, id=job.id, edit_id=edit.id)
check(b"#2060c0" in svg.payload.read(), "the edited SVG has the new colour")

answer = delete_job.sync_detailed(client=client, id=job.id)
check(answer.status_code == 204, f"delete: {answer.status_code}")
gone = get_job.sync(client=client, id=job.id)
check(isinstance(gone, Problem) and gone.code == "job-not-found", f"deleted job: {gone}")
print("python client: ok")
