// The TypeScript client (openapi-typescript types + openapi-fetch) through a whole job: limits,
// a multipart submission with `Prefer: wait`, a JSON one, every result format, a recolour, a
// delete. `node flow.js URL IMAGE` after tsc; exits non-zero on the first thing that is wrong.
import { readFileSync } from "node:fs";
import createClient from "openapi-fetch";
import type { paths } from "./covec.js";

const [baseUrl, imagePath] = process.argv.slice(2);
const covec = createClient<paths>({ baseUrl });
const image = readFileSync(imagePath);
const quick = {
  paths: 8,
  max_size: 48,
  seed: 1,
  iterations: { structure: 3, reconstruction: 3, refine_rounds: 1, refine: 3, polish: 3 },
};

function check(condition: unknown, what: string): asserts condition {
  if (!condition) {
    throw new Error(`typescript client: ${what}`);
  }
}

const limits = await covec.GET("/v1/limits");
check(limits.data && limits.data.max_paths >= 8, `limits: ${JSON.stringify(limits.error)}`);

// Multipart: the image as a file part (its name names the downloads), parameters as JSON.
const submitted = await covec.POST("/v1/jobs", {
  params: { header: { Prefer: "wait=60" } },
  body: { image: "", params: quick },
  bodySerializer(body) {
    const form = new FormData();
    form.append("image", new Blob([image], { type: "image/png" }), "sample.png");
    form.append("params", new Blob([JSON.stringify(body.params)], { type: "application/json" }));
    return form;
  },
});
check(submitted.response.status === 200, `multipart submission: ${submitted.response.status}`);
const job = submitted.data!;
check(job.status === "succeeded", `job ${job.id} is ${job.status}`);
check(job.urls.results?.pdf, "the job lists its PDF");

// JSON with base64.
const json = await covec.POST("/v1/jobs", {
  body: { image: image.toString("base64"), filename: "other.png", params: quick },
});
check(json.response.status === 201 && json.data?.id, `JSON submission: ${json.response.status}`);

const path = { id: job.id };
const files: Array<[string, Promise<{ data?: ArrayBuffer; response: Response }>, string]> = [
  ["sample.svg", covec.GET("/v1/jobs/{id}/svg", { params: { path }, parseAs: "arrayBuffer" }), "<svg"],
  [
    "sample-flat.svg",
    covec.GET("/v1/jobs/{id}/svg", {
      params: { path, query: { flatten: true } },
      parseAs: "arrayBuffer",
    }),
    "<svg",
  ],
  ["sample.pdf", covec.GET("/v1/jobs/{id}/pdf", { params: { path }, parseAs: "arrayBuffer" }), "%PDF"],
  [
    "sample.png",
    covec.GET("/v1/jobs/{id}/png", {
      params: { path, query: { width: 96 } },
      parseAs: "arrayBuffer",
    }),
    "\x89PNG",
  ],
];
for (const [name, request, magic] of files) {
  const { data, response } = await request;
  check(response.status === 200 && data, `${name}: ${response.status}`);
  const text = Buffer.from(data).toString("latin1");
  check(text.includes(magic), `${name} does not hold ${JSON.stringify(magic)}`);
  const disposition = response.headers.get("content-disposition") ?? "";
  check(disposition.includes(`filename="${name}"`), `${name}: Content-Disposition ${disposition}`);
  const etag = response.headers.get("etag");
  check(etag, `${name} has no ETag`);
}

// A recolour of whatever albedo path is at the centre.
const edit = await covec.POST("/v1/jobs/{id}/edits", {
  params: { path },
  body: { changes: [{ at: { x: 24, y: 24 }, color: "#2060c0" }] },
});
check(edit.response.status === 201 && edit.data, `edit: ${JSON.stringify(edit.error)}`);
const edited = await covec.GET("/v1/jobs/{id}/edits/{edit_id}/svg", {
  params: { path: { id: job.id, edit_id: edit.data.id } },
  parseAs: "text",
});
check(edited.data?.includes("#2060c0"), "the edited SVG has the new colour");

const deleted = await covec.DELETE("/v1/jobs/{id}", { params: { path } });
check(deleted.response.status === 204, `delete: ${deleted.response.status}`);
const gone = await covec.GET("/v1/jobs/{id}", { params: { path } });
check(gone.response.status === 404 && gone.error?.code === "job-not-found", "deleted job is gone");
console.log("typescript client: ok");
