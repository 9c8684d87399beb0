//! The HTTP guide's client examples (docs/api.md), run as written against a real `covec serve`: the batch
//! scripts (shell with curl and jq, Python with requests) against a server that requires an API
//! key — every image written, a re-run answered from the idempotency keys, a wrong key failing
//! the batch — and the webhook verification recipe inside a receiver of real deliveries.
//! scripts/setup-clients.sh installs curl, jq and python3-requests.
#![cfg(all(feature = "cli", feature = "service"))]

use crate::service_support;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use base64::Engine;
use serde_json::{Value, json};
use service_support::{DataDir, QUICK_PARAMS, Server, test_png};

const KEY: &str = "readme-client-key";
const IMAGES: [&str; 2] = ["first", "second"];

/// The body of the code block tagged `lang` that contains `marker` in the HTTP guide
/// (docs/api.md).
fn clients_example(lang: &str, marker: &str) -> String {
    let guide = include_str!("../../docs/api.md");
    let start = format!("```{lang}\n");
    guide
        .split(&start)
        .skip(1)
        .map(|block| block.split("\n```").next().unwrap())
        .find(|body| body.contains(marker))
        .unwrap_or_else(|| panic!("no {lang} example with {marker}"))
        .to_owned()
}

/// A folder with photos/ holding the test images, where the examples run.
fn workspace(dir: &DataDir) -> PathBuf {
    let root = dir.0.join("client");
    std::fs::create_dir_all(root.join("photos")).unwrap();
    for (index, name) in IMAGES.iter().enumerate() {
        let png = test_png(32 + 8 * index as u32);
        std::fs::write(root.join("photos").join(format!("{name}.png")), png).unwrap();
    }
    root
}

/// Runs `program script args…` in `cwd` with the server's URL and `key` in the environment.
fn run(
    program: &str,
    script: &Path,
    args: &[&str],
    cwd: &Path,
    server: &Server,
    key: &str,
) -> Output {
    Command::new(program)
        .arg(script)
        .args(args)
        .current_dir(cwd)
        .env("COVEC_URL", &server.base)
        .env("COVEC_KEY", key)
        .output()
        .unwrap_or_else(|error| panic!("{program}: {error} (scripts/setup-clients.sh installs it)"))
}

fn report(output: &Output) -> String {
    format!(
        "status {}\nstdout:\n{}\nstderr:\n{}",
        output.status,
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    )
}

fn assert_svgs(out: &Path) {
    for name in IMAGES {
        let svg = std::fs::read_to_string(out.join(format!("{name}.svg")))
            .unwrap_or_else(|error| panic!("{name}.svg: {error}"));
        assert!(
            svg.starts_with("<svg") || svg.starts_with("<?xml"),
            "{name}.svg: {svg:.80}"
        );
    }
}

/// A keyed server on `dir`, and the HTTP guide's batch example in `language` written to `file` in
/// a fresh workspace (checked to stay under 20 lines, as the issue asks).
fn batch_example(dir: &DataDir, language: &str, file: &str) -> (Server, PathBuf, PathBuf) {
    let server = Server::start(&dir.0, &["--workers", "2", "--api-keys", KEY]);
    let root = workspace(dir);
    let script = root.join(file);
    let example = clients_example(language, "Idempotency-Key");
    let lines = example.lines().count();
    assert!(lines < 20, "the {language} example has {lines} lines");
    std::fs::write(&script, example).unwrap();
    (server, root, script)
}

#[tokio::test]
async fn the_shell_batch_example_vectorises_a_folder_once() {
    let dir = DataDir::new("readme-shell");
    let (server, root, script) = batch_example(&dir, "bash", "batch.sh");

    let first = run("bash", &script, &[], &root, &server, KEY);
    assert!(first.status.success(), "{}", report(&first));
    assert_svgs(&root.join("out"));
    assert_eq!(dir.jobs_with_files(), IMAGES.len());
    // A re-run makes no new job: the idempotency keys answer with the finished ones.
    let again = run("bash", &script, &[], &root, &server, KEY);
    assert!(again.status.success(), "{}", report(&again));
    assert_eq!(dir.jobs_with_files(), IMAGES.len());

    let refused = run("bash", &script, &[], &root, &server, "not-the-key");
    assert!(!refused.status.success(), "{}", report(&refused));
}

#[tokio::test]
async fn the_python_batch_example_vectorises_a_folder_once() {
    let dir = DataDir::new("readme-python");
    let (server, root, script) = batch_example(&dir, "python", "batch.py");

    let first = run(
        "python3",
        &script,
        &["photos", "out", KEY],
        &root,
        &server,
        KEY,
    );
    assert!(first.status.success(), "{}", report(&first));
    assert_svgs(&root.join("out"));
    let stdout = String::from_utf8_lossy(&first.stdout);
    for name in IMAGES {
        assert!(
            stdout.contains(&format!("succeeded  {name}.png")),
            "{stdout}"
        );
    }
    assert_eq!(dir.jobs_with_files(), IMAGES.len());
    let again = run(
        "python3",
        &script,
        &["photos", "out", KEY],
        &root,
        &server,
        KEY,
    );
    assert!(again.status.success(), "{}", report(&again));
    assert_eq!(dir.jobs_with_files(), IMAGES.len());

    let refused = run(
        "python3",
        &script,
        &["photos", "out", "not-the-key"],
        &root,
        &server,
        KEY,
    );
    assert!(!refused.status.success(), "{}", report(&refused));
}

/// A webhook receiver in Python around the HTTP guide's `verify`: it answers 204 to messages that
/// verify (401 to others) and prints, for each, whether it verified and whether the same
/// message with one byte added to the body would have.
const RECEIVER: &str = r#"
import http.server, json, sys
secret = sys.argv[1]
class Hook(http.server.BaseHTTPRequestHandler):
    def do_POST(self):
        body = self.rfile.read(int(self.headers["content-length"]))
        ok, forged = verify(secret, self.headers, body), verify(secret, self.headers, body + b" ")
        print(json.dumps({"ok": ok, "forged": forged, "body": json.loads(body)}), flush=True)
        self.send_response(204 if ok else 401)
        self.end_headers()
    def log_message(self, *args):
        pass
server = http.server.HTTPServer(("127.0.0.1", 0), Hook)
print(server.server_address[1], flush=True)
server.serve_forever()
"#;

/// A child process killed when dropped, so that a failed assertion leaves no receiver running.
struct Killed(std::process::Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[tokio::test]
async fn the_webhook_recipe_verifies_real_deliveries_and_refuses_a_changed_body() {
    let dir = DataDir::new("readme-webhook");
    let script = dir.0.join("receiver.py");
    let recipe = clients_example("python", "def verify(");
    std::fs::write(&script, format!("{recipe}\n{RECEIVER}")).unwrap();
    let secret = format!(
        "whsec_{}",
        base64::engine::general_purpose::STANDARD.encode(b"readme recipe key")
    );
    let mut receiver = Killed(
        Command::new("python3")
            .arg(&script)
            .arg(&secret)
            .stdout(Stdio::piped())
            .spawn()
            .expect("python3 runs"),
    );
    let mut lines = BufReader::new(receiver.0.stdout.take().unwrap()).lines();
    let port = lines.next().unwrap().unwrap();

    let server = Server::start(
        &dir.0.join("data"),
        &["--webhook-secret", &secret, "--webhook-allow-loopback"],
    );
    let submitted = server
        .post_json(
            "/v1/jobs",
            &json!({
                "image": base64::engine::general_purpose::STANDARD.encode(test_png(32)),
                "params": serde_json::from_str::<Value>(QUICK_PARAMS).unwrap(),
                "webhook": format!("http://127.0.0.1:{port}/hook"),
            }),
        )
        .await;
    assert!(submitted.status.is_success(), "{}", submitted.text());
    let id = submitted.json()["id"].as_str().unwrap().to_owned();
    let job = server
        .wait_for(&id, Duration::from_secs(60), |job| {
            job["webhook"]["deliveries"][0]["status"] != "pending"
                && job["webhook"]["deliveries"][0].is_object()
        })
        .await;
    let delivered: Value = serde_json::from_str(&lines.next().unwrap().unwrap()).unwrap();
    assert_eq!(
        job["webhook"]["deliveries"][0]["status"], "delivered",
        "{job}"
    );
    assert_eq!(delivered["ok"], true, "{delivered}");
    assert_eq!(delivered["forged"], false, "{delivered}");
    assert_eq!(delivered["body"]["type"], "job.completed");
    assert_eq!(delivered["body"]["data"]["id"], id.as_str());
}
