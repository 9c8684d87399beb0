//! An S3-compatible server for the object-store tests: moto's `moto_server` (PyPI;
//! scripts/setup-s3.sh installs it), either started on a free loopback port and killed on drop,
//! or the one scripts/test.sh started for the shared-backend pass (`COVEC_TEST_S3_ENDPOINT`).
//! Requests from here are signed with curl's SigV4 (moto refuses unsigned object reads).

use std::net::TcpStream;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

pub struct S3Server {
    /// None for the server scripts/test.sh owns.
    child: Option<Child>,
    pub endpoint: String,
}

impl S3Server {
    pub fn start() -> Self {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let child = Command::new("moto_server")
            .args(["-H", "127.0.0.1", "-p", &port.to_string()])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("moto_server (scripts/setup-s3.sh installs it)");
        let started = Instant::now();
        while TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(
                started.elapsed() < Duration::from_secs(30),
                "moto_server did not start"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        Self {
            child: Some(child),
            endpoint: format!("http://127.0.0.1:{port}"),
        }
    }

    /// The server of the shared-backend pass, if this run has one.
    pub fn shared() -> Option<Self> {
        let endpoint = std::env::var("COVEC_TEST_S3_ENDPOINT").ok()?;
        Some(Self {
            child: None,
            endpoint,
        })
    }

    /// What `covec serve` needs to reach this server.
    pub fn env(&self) -> Vec<(String, String)> {
        [
            ("AWS_ENDPOINT", self.endpoint.as_str()),
            ("AWS_ALLOW_HTTP", "true"),
            ("AWS_ACCESS_KEY_ID", "test"),
            ("AWS_SECRET_ACCESS_KEY", "test"),
            ("AWS_REGION", "us-east-1"),
        ]
        .into_iter()
        .map(|(name, value)| (name.to_owned(), value.to_owned()))
        .collect()
    }

    /// One request with curl; the response body, or None on an HTTP error (404 included).
    pub fn curl(&self, method: &str, path: &str, body: Option<&[u8]>) -> Option<Vec<u8>> {
        let mut command = Command::new("curl");
        command
            .args(["-sf", "--max-time", "60"])
            .args(["--aws-sigv4", "aws:amz:us-east-1:s3", "--user", "test:test"])
            .args(["-X", method, &format!("{}{path}", self.endpoint)]);
        if body.is_some() {
            // Without a content type curl sends a form, which moto would parse as one.
            command
                .args(["-H", "content-type: application/octet-stream"])
                .args(["--data-binary", "@-"])
                .stdin(Stdio::piped());
        }
        command.stdout(Stdio::piped());
        let mut child = command.spawn().expect("curl");
        if let Some(body) = body {
            use std::io::Write;
            child.stdin.take().unwrap().write_all(body).unwrap();
        }
        let output = child.wait_with_output().unwrap();
        output.status.success().then_some(output.stdout)
    }

    /// Keys in `bucket` under `prefix`.
    pub fn keys(&self, bucket: &str, prefix: &str) -> Vec<String> {
        let listing = self
            .curl(
                "GET",
                &format!("/{bucket}?list-type=2&prefix={prefix}"),
                None,
            )
            .expect("listing the bucket");
        String::from_utf8(listing)
            .unwrap()
            .split("<Key>")
            .skip(1)
            .map(|rest| rest.split("</Key>").next().unwrap().to_owned())
            .collect()
    }
}

impl Drop for S3Server {
    fn drop(&mut self) {
        if let Some(child) = &mut self.child {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// A TCP relay on loopback in front of a server that can go down (every open connection cut,
/// every new one closed at once, as a stopped server's host does) and come back, the server's
/// data kept: an object store out for a while.
pub struct Relay {
    pub endpoint: String,
    down: std::sync::Arc<std::sync::atomic::AtomicBool>,
    open: std::sync::Arc<std::sync::Mutex<Vec<TcpStream>>>,
}

impl Relay {
    /// A relay to `endpoint` (`http://host:port`).
    pub fn start(endpoint: &str) -> Self {
        use std::sync::atomic::Ordering;
        let target = endpoint.trim_start_matches("http://").to_owned();
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let relay = Self {
            endpoint: format!("http://{}", listener.local_addr().unwrap()),
            down: Default::default(),
            open: Default::default(),
        };
        let (down, open) = (relay.down.clone(), relay.open.clone());
        std::thread::spawn(move || {
            for client in listener.incoming().flatten() {
                if down.load(Ordering::SeqCst) {
                    continue;
                }
                let Ok(server) = TcpStream::connect(&target) else {
                    continue;
                };
                let mut streams = open.lock().unwrap();
                streams.extend([client.try_clone().unwrap(), server.try_clone().unwrap()]);
                for (mut from, mut to) in [
                    (client.try_clone().unwrap(), server.try_clone().unwrap()),
                    (server, client),
                ] {
                    std::thread::spawn(move || {
                        let _ = std::io::copy(&mut from, &mut to);
                        let _ = to.shutdown(std::net::Shutdown::Both);
                    });
                }
            }
        });
        relay
    }

    /// Cuts every connection and refuses new ones until [`Relay::up`].
    pub fn down(&self) {
        self.down.store(true, std::sync::atomic::Ordering::SeqCst);
        for stream in self.open.lock().unwrap().drain(..) {
            let _ = stream.shutdown(std::net::Shutdown::Both);
        }
    }

    pub fn up(&self) {
        self.down.store(false, std::sync::atomic::Ordering::SeqCst);
    }
}
