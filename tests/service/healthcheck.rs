//! `covec healthcheck`: exit 0 on a 2xx answer; a one-line error and exit 1 on any other
//! answer, a refused connection, a server that never answers, or a URL it cannot ask. Against
//! stand-in servers here, against a real `covec serve` below, and against a worker's
//! `--ops-addr` in tests/service_pg.rs.
#![cfg(all(feature = "cli", feature = "service"))]

use crate::service_support;

use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpListener};
use std::process::{Command, Output};
use std::sync::mpsc;

use service_support::{DataDir, Server};

fn healthcheck(args: &[&str], env: &[(&str, &str)]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_covec"))
        .arg("healthcheck")
        .args(args)
        .env_remove("COVEC_ADDR")
        .envs(env.iter().copied())
        .output()
        .expect("covec runs")
}

/// Fails with exit code 1 and exactly one line on stderr mentioning `needle`.
fn assert_one_line_error(out: &Output, needle: &str) {
    let text = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{text}");
    assert_eq!(text.lines().count(), 1, "{text}");
    assert!(
        text.starts_with("error: ") && text.contains(needle),
        "{text}"
    );
}

/// A server on a free loopback port answering one request with `status_line`; the request
/// line it got comes through the channel.
fn answering(status_line: &'static str) -> (SocketAddr, mpsc::Receiver<String>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let (sender, receiver) = mpsc::channel();
    std::thread::spawn(move || {
        let (stream, _) = listener.accept().unwrap();
        let mut reader = BufReader::new(stream);
        let mut request_line = String::new();
        reader.read_line(&mut request_line).unwrap();
        let mut header = String::new();
        while reader.read_line(&mut header).unwrap() > 2 {
            header.clear();
        }
        let mut stream = reader.into_inner();
        write!(
            stream,
            "HTTP/1.1 {status_line}\r\ncontent-length: 0\r\nconnection: close\r\n\r\n"
        )
        .unwrap();
        let _ = sender.send(request_line.trim_end().to_owned());
    });
    (addr, receiver)
}

#[test]
fn a_2xx_answer_passes_silently() {
    let (addr, request) = answering("200 OK");
    // --url wins over the serve address, which the image's environment always sets.
    let out = healthcheck(
        &["--url", &format!("http://{addr}/readyz")],
        &[("COVEC_ADDR", "0.0.0.0:1")],
    );
    assert!(out.status.success(), "{out:?}");
    assert!(out.stdout.is_empty() && out.stderr.is_empty(), "{out:?}");
    assert_eq!(request.recv().unwrap(), "GET /readyz HTTP/1.1");
}

#[test]
fn without_a_url_it_asks_healthz_at_the_serve_address_on_loopback() {
    let (addr, request) = answering("204 No Content");
    let out = healthcheck(&[], &[("COVEC_ADDR", &format!("0.0.0.0:{}", addr.port()))]);
    assert!(out.status.success(), "{out:?}");
    assert_eq!(request.recv().unwrap(), "GET /healthz HTTP/1.1");
}

#[test]
fn any_other_status_fails() {
    let (addr, _request) = answering("503 Service Unavailable");
    let out = healthcheck(&["--addr", &addr.to_string()], &[]);
    assert_one_line_error(&out, "answered 503 Service Unavailable");
}

#[test]
fn a_refused_connection_fails() {
    let addr = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap();
    let out = healthcheck(&["--url", &format!("http://{addr}/healthz")], &[]);
    assert_one_line_error(&out, "refused");
}

#[test]
fn a_server_that_never_answers_fails_after_the_timeout() {
    // Accepted by the kernel's backlog, never read: the request goes nowhere.
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let out = healthcheck(
        &["--url", &format!("http://{addr}/healthz"), "--timeout", "1"],
        &[],
    );
    assert_one_line_error(&out, "no answer within 1 s");
    drop(listener);
}

#[test]
fn urls_it_cannot_ask_are_refused() {
    let out = healthcheck(&["--url", "https://127.0.0.1:8443/healthz"], &[]);
    assert_one_line_error(&out, "give an http:// URL");
    let out = healthcheck(&["--url", "not a url"], &[]);
    assert_one_line_error(&out, "--url \"not a url\"");
}

#[test]
fn a_running_service_is_healthy() {
    let dir = DataDir::plain("healthcheck-serve");
    let server = Server::start(&dir.0, &[]);
    let out = healthcheck(&["--url", &format!("{}/healthz", server.base)], &[]);
    assert!(out.status.success(), "{out:?}");
    let addr = server.base.trim_start_matches("http://");
    let out = healthcheck(&[], &[("COVEC_ADDR", addr)]);
    assert!(out.status.success(), "{out:?}");
}
