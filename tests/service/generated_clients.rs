//! Clients generated from api/openapi.yaml in two ecosystems, each run through a whole job
//! against a real `covec serve` (docs/api.md, "Generated clients"): openapi-python-client
//! (PyPI) and openapi-typescript with openapi-fetch (npm). Generation must print no warning.
//! `scripts/setup-clients.sh` installs the generators: a Python virtual environment
//! (`COVEC_CLIENTS_VENV`, default `~/.cache/covec/clients-venv`) and `tests/clients/node_modules`.
#![cfg(all(feature = "cli", feature = "service"))]

use crate::service_support;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use service_support::{DataDir, Server};

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// The photo both flows submit (96², so a job takes well under a second at their settings).
fn image() -> PathBuf {
    Path::new(ROOT).join("tests/fixtures/photo96_scene_coffee.png")
}

fn venv() -> PathBuf {
    std::env::var_os("COVEC_CLIENTS_VENV")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(&std::env::var_os("HOME").expect("HOME")).join(".cache/covec/clients-venv")
        })
}

/// `command`'s output, which must be a success; the message shows what it printed.
fn run(command: &mut Command, what: &str) -> Output {
    let output = command
        .output()
        .unwrap_or_else(|error| panic!("{what}: {error} (run scripts/setup-clients.sh)"));
    assert!(
        output.status.success(),
        "{what} failed:\n{}\n{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    output
}

/// Everything a generator printed, which must hold no warning.
fn assert_no_warning(output: &Output, generator: &str) {
    let printed = format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(
        !printed.to_lowercase().contains("warn"),
        "{generator} warned:\n{printed}"
    );
}

#[test]
fn the_python_client_runs_a_whole_job() {
    let dir = DataDir::new("clients-python");
    let server = Server::start(&dir.0, &[]);
    let out = dir.0.join("python-client");
    let generated = run(
        Command::new(venv().join("bin/openapi-python-client"))
            .args(["generate", "--meta", "none", "--path"])
            .arg(Path::new(ROOT).join("api/openapi.yaml"))
            .arg("--config")
            .arg(Path::new(ROOT).join("api/openapi-python-client.yaml"))
            .arg("--output-path")
            .arg(out.join("covec_client")),
        "openapi-python-client generate",
    );
    assert_no_warning(&generated, "openapi-python-client");
    let flow = run(
        Command::new(venv().join("bin/python"))
            .arg(Path::new(ROOT).join("tests/clients/flow.py"))
            .arg(&server.base)
            .arg(image())
            .env("PYTHONPATH", &out),
        "the Python client's flow",
    );
    assert!(String::from_utf8_lossy(&flow.stdout).contains("python client: ok"));
    server.stop();
}

#[test]
fn the_typescript_client_runs_a_whole_job() {
    let dir = DataDir::new("clients-typescript");
    let server = Server::start(&dir.0, &[]);
    let clients = Path::new(ROOT).join("tests/clients");
    let work = dir.0.join("typescript-client");
    std::fs::create_dir_all(&work).unwrap();
    for file in ["flow.ts", "tsconfig.json", "package.json"] {
        std::fs::copy(clients.join(file), work.join(file)).unwrap();
    }
    std::os::unix::fs::symlink(clients.join("node_modules"), work.join("node_modules")).unwrap();
    let generated = run(
        Command::new("node")
            .arg(clients.join("node_modules/openapi-typescript/bin/cli.js"))
            .arg(Path::new(ROOT).join("api/openapi.yaml"))
            .arg("-o")
            .arg(work.join("covec.d.ts"))
            // A member with a default may be left out of a request (the server fills it in).
            .args(["--default-non-nullable", "false"]),
        "openapi-typescript",
    );
    assert_no_warning(&generated, "openapi-typescript");
    run(
        Command::new("node")
            .arg(clients.join("node_modules/typescript/bin/tsc"))
            .arg("-p")
            .arg(work.join("tsconfig.json")),
        "tsc (the flow type-checked against the generated types)",
    );
    let flow = run(
        Command::new("node")
            .arg(work.join("out/flow.js"))
            .arg(&server.base)
            .arg(image()),
        "the TypeScript client's flow",
    );
    assert!(String::from_utf8_lossy(&flow.stdout).contains("typescript client: ok"));
    server.stop();
}
