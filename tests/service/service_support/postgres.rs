//! A throwaway PostgreSQL for the shared-backend tests: `initdb` in a temporary directory and
//! `postgres` on a free loopback port, stopped and removed on drop. The server binaries come
//! from Debian's `postgresql` package (scripts/setup-postgres.sh installs it); as root they
//! run as the `postgres` user (through `setpriv`), since PostgreSQL refuses to run as root.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use super::DataDir;

pub struct Postgres {
    child: Child,
    /// `postgres://…` for `--database-url`.
    pub url: String,
    port: u16,
    dir: DataDir,
    /// Server settings beyond the test defaults (`-c name=value` pairs).
    settings: Vec<String>,
}

/// The directory holding `initdb` and `postgres`: Debian's newest version, else `PATH`.
fn bin_dir() -> Option<PathBuf> {
    let mut versions: Vec<PathBuf> = std::fs::read_dir("/usr/lib/postgresql")
        .ok()?
        .filter_map(|entry| Some(entry.ok()?.path().join("bin")))
        .filter(|bin| bin.join("initdb").exists())
        .collect();
    versions.sort();
    versions.pop()
}

/// A command for a PostgreSQL binary, as the `postgres` user when this process is root.
fn command(program: &str) -> Command {
    let program = bin_dir().map_or_else(|| PathBuf::from(program), |bin| bin.join(program));
    // SAFETY: a plain syscall with no arguments.
    if unsafe { libc::geteuid() } == 0 {
        // setpriv execs the program itself: the child is the server, and signals reach it.
        let mut command = Command::new("setpriv");
        command
            .args(["--reuid=postgres", "--regid=postgres", "--init-groups"])
            .arg(program);
        command
    } else {
        Command::new(program)
    }
}

fn chown_to_postgres(path: &Path) {
    // SAFETY: as in `command`.
    if unsafe { libc::geteuid() } == 0 {
        let status = Command::new("chown")
            .args(["-R", "postgres"])
            .arg(path)
            .status()
            .unwrap();
        assert!(status.success(), "chown {}", path.display());
    }
}

impl Postgres {
    pub fn start() -> Self {
        Self::start_with(|_| Vec::new())
    }

    /// A server that takes TLS connections only, with a certificate for `localhost` signed by
    /// a throwaway CA; the CA's PEM file, for `sslrootcert`.
    pub fn start_tls_only() -> (Self, PathBuf) {
        let mut ca_path = PathBuf::new();
        let postgres = Self::start_with(|dir| {
            let ca_params = {
                let mut params = rcgen::CertificateParams::new(Vec::<String>::new()).unwrap();
                params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
                params
            };
            let ca =
                rcgen::CertifiedIssuer::self_signed(ca_params, rcgen::KeyPair::generate().unwrap())
                    .unwrap();
            let key = rcgen::KeyPair::generate().unwrap();
            let certificate = rcgen::CertificateParams::new(vec!["localhost".to_owned()])
                .unwrap()
                .signed_by(&key, &ca)
                .unwrap();
            ca_path = dir.join("ca.pem");
            std::fs::write(&ca_path, ca.pem()).unwrap();
            std::fs::write(dir.join("server.crt"), certificate.pem()).unwrap();
            let key_path = dir.join("server.key");
            std::fs::write(&key_path, key.serialize_pem()).unwrap();
            // PostgreSQL refuses a key file others can read.
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&key_path, std::fs::Permissions::from_mode(0o600)).unwrap();
            std::fs::write(
                dir.join("pg_hba.conf"),
                "hostssl all all 127.0.0.1/32 trust\nhostnossl all all 127.0.0.1/32 reject\n",
            )
            .unwrap();
            chown_to_postgres(dir);
            ["ssl=on", "ssl_cert_file", "ssl_key_file", "hba_file"]
                .iter()
                .zip(["", "server.crt", "server.key", "pg_hba.conf"])
                .map(|(name, file)| match file {
                    "" => name.to_string(),
                    file => format!("{name}={}", dir.join(file).display()),
                })
                .collect()
        });
        (postgres, ca_path)
    }

    /// Starts a server with the settings `settings(dir)` returns, after writing into `dir` the
    /// files they name.
    fn start_with(settings: impl FnOnce(&Path) -> Vec<String>) -> Self {
        let dir = DataDir::plain("postgres");
        chown_to_postgres(&dir.0);
        let data = dir.0.join("data");
        let initdb = command("initdb")
            .arg("-D")
            .arg(&data)
            .args(["-U", "covec", "--auth=trust", "-E", "UTF8", "--no-sync"])
            .stdout(Stdio::null())
            .output()
            .expect("initdb (scripts/setup-postgres.sh installs PostgreSQL)");
        assert!(
            initdb.status.success(),
            "initdb: {}",
            String::from_utf8_lossy(&initdb.stderr)
        );
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let settings = settings(&dir.0);
        let postgres = Self {
            child: spawn_server(&dir.0, port, &settings),
            url: format!("postgres://covec@127.0.0.1:{port}/postgres"),
            port,
            dir,
            settings,
        };
        postgres.wait_ready();
        postgres
    }

    /// Stops the server (fast shutdown: connections are cut) and starts it again on the same
    /// port and data; returns once it accepts connections.
    pub fn restart(&mut self) {
        self.stop();
        self.start_again();
    }

    /// Starts the stopped server again; returns once it accepts connections.
    pub fn start_again(&mut self) {
        self.child = spawn_server(&self.dir.0, self.port, &self.settings);
        self.wait_ready();
    }

    /// Stops the server (fast shutdown: connections are cut).
    pub fn stop(&mut self) {
        // SIGINT: PostgreSQL's fast shutdown.
        // SAFETY: a signal to our own child.
        unsafe {
            libc::kill(self.child.id() as i32, libc::SIGINT);
        }
        let started = Instant::now();
        while started.elapsed() < Duration::from_secs(10) {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    fn wait_ready(&self) {
        let started = Instant::now();
        loop {
            let ready = Command::new("pg_isready")
                .args(["-q", "-h", "127.0.0.1", "-p", &self.port.to_string()])
                .status()
                .is_ok_and(|status| status.success());
            if ready {
                return;
            }
            assert!(
                started.elapsed() < Duration::from_secs(30),
                "postgres did not start"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// One SQL statement through `psql`; its rows, one per line, columns `|`-separated.
    pub fn query(&self, sql: &str) -> String {
        let output = Command::new("psql")
            .args([&self.url, "-XAtq", "-c", sql])
            .output()
            .expect("psql");
        assert!(
            output.status.success(),
            "{sql}: {}",
            String::from_utf8_lossy(&output.stderr)
        );
        String::from_utf8(output.stdout).unwrap()
    }
}

impl Drop for Postgres {
    fn drop(&mut self) {
        self.stop();
    }
}

/// `postgres` on `port` for the cluster in `dir/data` with `settings`, logging to
/// `dir/postgres.log`.
fn spawn_server(dir: &Path, port: u16, settings: &[String]) -> Child {
    let log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(dir.join("postgres.log"))
        .unwrap();
    command("postgres")
        .arg("-D")
        .arg(dir.join("data"))
        .args(["-p", &port.to_string(), "-h", "127.0.0.1", "-k"])
        .arg(dir)
        // A test database: speed over durability.
        .args(["-c", "fsync=off", "-c", "synchronous_commit=off"])
        .args(["-c", "full_page_writes=off"])
        .args(settings.iter().flat_map(|setting| ["-c", setting]))
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .expect("postgres")
}

/// A `covec worker` process, killed on drop.
pub struct Worker {
    child: Child,
    /// `http://host:port` of its probes and metrics, when started with `--ops-addr`.
    pub ops_url: Option<String>,
}

impl Worker {
    /// Starts `covec worker --data-dir DIR ARGS…`, logging to `log_path`; with
    /// `--ops-addr` among the arguments, waits for the address it prints.
    pub fn start(data_dir: &Path, log_path: &Path, args: &[&str]) -> Self {
        let log = std::fs::File::create(log_path).unwrap();
        let mut child = Command::new(env!("CARGO_BIN_EXE_covec"))
            .args(["worker", "--data-dir"])
            .arg(data_dir)
            .args(args)
            .env("COVEC_LOG", "info")
            .stdout(Stdio::piped())
            .stderr(log)
            .spawn()
            .expect("start covec worker");
        let ops_url = args.contains(&"--ops-addr").then(|| {
            let mut line = String::new();
            std::io::BufRead::read_line(
                &mut std::io::BufReader::new(child.stdout.take().unwrap()),
                &mut line,
            )
            .unwrap();
            let url = line.trim().rsplit(' ').next().unwrap_or_default();
            assert!(url.starts_with("http://"), "covec worker said {line:?}");
            url.to_owned()
        });
        Self { child, ops_url }
    }

    /// SIGKILL: the worker dies at once, mid-job, leaving its lease to expire.
    pub fn kill(mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
