//! The documentation cannot drift from the code: the command-line reference is what the binary
//! generates, and every default the guides state in prose is the code's own value. Editing a
//! default in the code (or in the docs) fails here until both agree.
#![cfg(all(feature = "cli", feature = "service"))]

use std::process::Command;
use std::time::Duration;

use covec::Params;
use covec::service::{Config, InputLimits, QueueConfig, WebhookConfig};

fn doc(name: &str) -> String {
    let path = format!("{}/{name}", env!("CARGO_MANIFEST_DIR"));
    std::fs::read_to_string(&path).unwrap_or_else(|error| panic!("{path}: {error}"))
}

/// `text` appears in `file`; the message says which default it states.
fn states(file: &str, what: &str, text: &str) -> Option<String> {
    (!doc(file).contains(text)).then(|| format!("{file} should state {what} as `{text}`"))
}

/// Whole hours or days, as the prose writes them.
fn hours(duration: Duration) -> u64 {
    duration.as_secs() / 3600
}

#[test]
fn the_cli_reference_is_the_generated_one() {
    let output = Command::new(env!("CARGO_BIN_EXE_covec"))
        .arg("reference")
        .output()
        .unwrap();
    assert!(output.status.success());
    assert!(
        String::from_utf8(output.stdout).unwrap() == doc("docs/cli-reference.md"),
        "docs/cli-reference.md differs from what the code generates; regenerate it with \
         `cargo run -- reference -o docs/cli-reference.md`"
    );
}

#[test]
fn the_guides_state_the_defaults_of_the_code() {
    let params = Params::default();
    let iterations = &params.iterations;
    let queue = QueueConfig::default();
    let config = Config::default();
    let limits = InputLimits::default();
    let webhooks = WebhookConfig::default();
    let failures: Vec<String> = [
        // The pipeline (docs/design.md's table of defaults).
        states(
            "docs/design.md",
            "the path budget",
            &format!("| paths | {} |", params.paths),
        ),
        states(
            "docs/design.md",
            "the working size",
            &format!("| working size (long side) | {} |", params.max_size),
        ),
        states(
            "docs/design.md",
            "the structure iterations",
            &format!("| `structure` iterations | {} |", iterations.structure),
        ),
        states(
            "docs/design.md",
            "the reconstruction iterations",
            &format!(
                "| `reconstruct` iterations | {} |",
                iterations.reconstruction
            ),
        ),
        states(
            "docs/design.md",
            "the refinement",
            &format!(
                "| `refine` rounds × iterations | {} × {} |",
                iterations.refine_rounds, iterations.refine
            ),
        ),
        states(
            "docs/design.md",
            "the polish iterations",
            &format!("| `polish` iterations | {} |", iterations.polish),
        ),
        states(
            "docs/cli.md",
            "the working size",
            &format!("long side {} by default", params.max_size),
        ),
        // The service's settings.
        states(
            "docs/api.md",
            "the longest wait",
            &format!("`--max-wait`, {} by default", config.max_wait.as_secs()),
        ),
        states(
            "docs/api.md",
            "the idempotency window",
            &format!(
                "A key holds for {} hours (`--idempotency-window`)",
                hours(queue.idempotency_window)
            ),
        ),
        states(
            "docs/api.md",
            "the retention",
            &format!(
                "Results are removed {} h after the job ends (`--retention`)",
                hours(queue.retention)
            ),
        ),
        states(
            "docs/api.md",
            "the record retention",
            &format!(
                "The job record stays {} days (`--record-retention`)",
                hours(queue.record_retention) / 24
            ),
        ),
        states(
            "docs/api.md",
            "the webhook attempts",
            &format!("`--webhook-attempts` ({})", webhooks.max_attempts),
        ),
        states(
            "docs/operations.md",
            "the retention",
            &format!("`--retention` ({} h)", hours(queue.retention)),
        ),
        states(
            "docs/operations.md",
            "the record retention",
            &format!(
                "`--record-retention` ({} days)",
                hours(queue.record_retention) / 24
            ),
        ),
        states(
            "docs/operations.md",
            "the idempotency window",
            &format!(
                "`--idempotency-window` ({} h)",
                hours(queue.idempotency_window)
            ),
        ),
        states(
            "docs/operations.md",
            "the job slots",
            &format!("the default (`--workers {}`", queue.workers),
        ),
        states(
            "docs/api.md",
            "the body limit in the example",
            &format!("\"max_body_bytes\": {}", limits.max_body_bytes),
        ),
        states(
            "docs/api.md",
            "the pixel limit in the example",
            &format!("\"max_pixels\": {}", limits.max_pixels),
        ),
        states(
            "docs/api.md",
            "the path and size limits in the example",
            &format!(
                "\"max_paths\": {}, \"max_size\": {}",
                limits.max_paths, limits.max_size
            ),
        ),
        states(
            "docs/api.md",
            "the smallest budget and working size in the example",
            &format!(
                "\"min_paths\": {}, \"min_size\": {}",
                covec::pipeline::MIN_PATHS,
                covec::pipeline::MIN_SIZE
            ),
        ),
        states(
            "docs/api.md",
            "the default budget in the example",
            &format!("\"defaults\": {{\"paths\": {}", params.paths),
        ),
    ]
    .into_iter()
    .flatten()
    .collect();
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
