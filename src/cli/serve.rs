//! `covec serve`: run the HTTP vectorisation service; `covec worker`: run its jobs only, on
//! the shared PostgreSQL backend. Both take the storage, job and input options ([`JobArgs`]).

use std::io::IsTerminal;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::{Args, ValueEnum};

use covec::service::{
    self, Config, ConnectionLimits, InputLimits, QueueConfig, RecordsAt, Scheduling,
    SignedUrlConfig, WebhookConfig,
};

/// Storage, job slots and what one job may take: shared by `serve` and `worker`. Every option
/// also reads an environment variable (shown in `--help`); flags win.
#[derive(Args, Debug)]
pub struct JobArgs {
    /// Directory for the job database and results (created if missing); with --database-url
    /// it holds the job files only, and only without --object-store.
    #[arg(long, env = "COVEC_DATA_DIR", default_value_os_t = Config::default().data_dir)]
    data_dir: PathBuf,
    /// Keep results and other job files in this S3-compatible bucket (`s3://bucket/prefix`)
    /// instead of the data directory; credentials, region and endpoint come from the usual
    /// AWS_* variables (AWS_ENDPOINT and AWS_ALLOW_HTTP=true for a local server).
    #[arg(long, env = "COVEC_OBJECT_STORE")]
    object_store: Option<String>,
    /// Keep job records, the queue and idempotency keys in this PostgreSQL database
    /// (`postgres://user:password@host:port/db`; TLS by libpq's `sslmode` and `sslrootcert`),
    /// shared by API replicas and `covec worker`s, instead of SQLite in the data directory.
    #[arg(long, env = "COVEC_DATABASE_URL", hide_env_values = true)]
    database_url: Option<String>,
    /// Keep job records and the queue in this process's memory instead (`covec serve` only):
    /// nothing but the job files survives a restart. For trials and tests.
    #[arg(long, env = "COVEC_IN_MEMORY", conflicts_with = "database_url")]
    in_memory: bool,
    /// Jobs run at once; the pipeline threads are shared out among them. With
    /// --database-url, `covec serve --workers 0` runs no job (an API replica).
    #[arg(long, env = "COVEC_WORKERS", default_value_t = QueueConfig::default().workers)]
    workers: usize,
    /// Pipeline threads in total [default: number of cores].
    #[arg(long, env = "COVEC_THREADS")]
    threads: Option<usize>,
    /// Largest image (also albedo, masks, label map), in pixels.
    #[arg(long, env = "COVEC_MAX_PIXELS", default_value_t = InputLimits::default().max_pixels)]
    max_pixels: u64,
    /// Most masks per job.
    #[arg(long, env = "COVEC_MAX_MASKS", default_value_t = InputLimits::default().max_masks)]
    max_masks: usize,
    /// Largest `params.paths`.
    #[arg(long, env = "COVEC_MAX_PATHS", default_value_t = InputLimits::default().max_paths)]
    max_paths: u32,
    /// Largest `params.max_size` (working size, long side).
    #[arg(long, env = "COVEC_MAX_SIZE", default_value_t = InputLimits::default().max_size)]
    max_size: u32,
    /// Largest total iteration budget of one job.
    #[arg(long, env = "COVEC_MAX_ITERATIONS", default_value_t = InputLimits::default().max_iterations)]
    max_iterations: u64,
    /// Largest total of a job's decoded inputs (image, albedo, masks), in bytes.
    #[arg(long, env = "COVEC_MAX_DECODED_BYTES", default_value_t = InputLimits::default().max_decoded_bytes)]
    max_decoded_bytes: u64,
    /// Requests that decode their inputs at once; others wait their turn.
    #[arg(long, env = "COVEC_DECODE_SLOTS", default_value_t = InputLimits::default().decode_slots)]
    decode_slots: usize,
    /// Longest wait for a decode slot, in seconds; then 503 `decode-busy`.
    #[arg(long, env = "COVEC_DECODE_WAIT", default_value_t = InputLimits::default().decode_wait.as_secs())]
    decode_wait: u64,
    /// Wall-clock limit of one job, in seconds; then it fails with code `time-limit`.
    #[arg(long, env = "COVEC_JOB_TIME_LIMIT", default_value_t = QueueConfig::default().job_time_limit.as_secs())]
    job_time_limit: u64,
    /// How long results are kept after a job ends, in seconds.
    #[arg(long, env = "COVEC_RETENTION", default_value_t = QueueConfig::default().retention.as_secs())]
    retention: u64,
    /// With --database-url: seconds a worker's claim on a job holds without a heartbeat; a job
    /// whose worker vanished runs again elsewhere after this long.
    #[arg(long, env = "COVEC_LEASE_SECONDS", default_value_t = QueueConfig::default().lease.as_secs())]
    lease_seconds: u64,
    /// Seconds after which a job's files with no job record are removed as left over from an
    /// interrupted submission (at start too when --database-url is given: other replicas may
    /// be admitting jobs meanwhile).
    #[arg(long, env = "COVEC_ORPHAN_AGE", default_value_t = QueueConfig::default().orphan_age.as_secs())]
    orphan_age: u64,
    /// Seconds running jobs may finish after SIGTERM before they are re-queued for the next start.
    #[arg(long, env = "COVEC_SHUTDOWN_GRACE", default_value_t = Config::default().shutdown_grace.as_secs())]
    shutdown_grace: u64,
    /// Seconds a batch job waits before it counts as interactive (so batch work is never
    /// starved by interactive work).
    #[arg(long, env = "COVEC_BATCH_AGE", default_value_t = Scheduling::default().batch_age.as_secs())]
    batch_age: u64,
    /// Most jobs one key may have waiting (then 429 `key-queue-full`); 0: only --max-queued.
    #[arg(long, env = "COVEC_MAX_QUEUED_PER_KEY", default_value_t = 0)]
    max_queued_per_key: usize,
    /// Most jobs of one key running at once (its others wait); 0: no limit.
    #[arg(long, env = "COVEC_MAX_RUNNING_PER_KEY", default_value_t = 0)]
    max_running_per_key: usize,
    /// Submissions one key may make per minute, in a burst of as many (then 429
    /// `rate-limited`); 0: no limit. Counted by each API process on its own.
    #[arg(long, env = "COVEC_RATE_PER_KEY", default_value_t = 0)]
    rate_per_key: u32,
    /// Other limits for particular keys, comma-separated `KEY:LIMIT=N` (LIMIT `queued`,
    /// `running` or `rate`; N 0 for none; KEY an API key, or an X-Client-Key without keys),
    /// e.g. `batchkey:queued=500,batchkey:running=1,webkey:rate=600`.
    #[arg(
        long,
        env = "COVEC_KEY_LIMITS",
        value_delimiter = ',',
        hide_env_values = true
    )]
    key_limits: Vec<String>,
}

impl JobArgs {
    /// The settings these options give, over `config`; an error names a malformed
    /// `--key-limits` entry.
    fn apply(self, config: &mut Config) -> Result<(), String> {
        let defaults = QueueConfig::default();
        config.data_dir = self.data_dir;
        config.object_store = self.object_store;
        config.records = match (self.database_url, self.in_memory) {
            (Some(url), _) => RecordsAt::Database(url),
            (None, true) => RecordsAt::Memory,
            (None, false) => RecordsAt::DataDir,
        };
        config.queue.workers = self.workers;
        config.queue.threads = self.threads.unwrap_or(defaults.threads);
        config.queue.job_time_limit = Duration::from_secs(self.job_time_limit);
        config.queue.retention = Duration::from_secs(self.retention);
        config.queue.lease = Duration::from_secs(self.lease_seconds);
        config.queue.orphan_age = Duration::from_secs(self.orphan_age);
        config.limits = InputLimits {
            max_body_bytes: config.limits.max_body_bytes,
            max_pixels: self.max_pixels,
            max_masks: self.max_masks,
            max_paths: self.max_paths,
            max_size: self.max_size,
            max_iterations: self.max_iterations,
            max_decoded_bytes: self.max_decoded_bytes,
            decode_slots: self.decode_slots.max(1),
            decode_wait: Duration::from_secs(self.decode_wait),
        };
        config.shutdown_grace = Duration::from_secs(self.shutdown_grace);
        let scheduling = &mut config.queue.scheduling;
        scheduling.batch_age = Duration::from_secs(self.batch_age);
        scheduling.limits.queued = (self.max_queued_per_key > 0).then_some(self.max_queued_per_key);
        scheduling.limits.running =
            (self.max_running_per_key > 0).then_some(self.max_running_per_key);
        scheduling.limits.per_minute = std::num::NonZeroU32::new(self.rate_per_key);
        for entry in self
            .key_limits
            .iter()
            .filter(|entry| !entry.trim().is_empty())
        {
            scheduling.override_limit(entry)?;
        }
        Ok(())
    }
}

/// How log lines are written to stderr.
#[derive(Clone, Copy, Debug, Default, ValueEnum)]
enum LogFormat {
    /// One human-readable line per event (coloured on a terminal).
    #[default]
    Text,
    /// One JSON object per line, for log collectors (fields, span fields and the target).
    Json,
}

/// Logging, shared by `serve` and `worker`; `COVEC_LOG` filters (e.g. `info,covec=debug`).
#[derive(Args, Debug)]
struct LogArgs {
    /// Log line format on stderr.
    #[arg(long, env = "COVEC_LOG_FORMAT", value_enum, default_value_t)]
    log_format: LogFormat,
}

/// The variable `covec serve --addr` reads, and so the address `covec healthcheck` asks.
pub const ADDR_ENV: &str = "COVEC_ADDR";

/// Every option also reads an environment variable (shown in `--help`); flags win.
#[derive(Args, Debug)]
pub struct ServeArgs {
    /// Address to listen on.
    #[arg(long, env = ADDR_ENV, default_value_t = Config::default().addr)]
    addr: SocketAddr,
    #[command(flatten)]
    jobs: JobArgs,
    #[command(flatten)]
    log: LogArgs,
    /// Most jobs waiting for a worker; more get 503 with Retry-After.
    #[arg(long, env = "COVEC_MAX_QUEUED", default_value_t = QueueConfig::default().max_queued)]
    max_queued: usize,
    /// How long a job's record is kept after the job ends, in seconds (results go earlier,
    /// after --retention); then the job answers 410 Gone, for as long again, then 404.
    #[arg(long, env = "COVEC_RECORD_RETENTION", default_value_t = QueueConfig::default().record_retention.as_secs())]
    record_retention: u64,
    /// Seconds an Idempotency-Key holds after its job was created; a reuse after that creates
    /// a new job.
    #[arg(long, env = "COVEC_IDEMPOTENCY_WINDOW", default_value_t = QueueConfig::default().idempotency_window.as_secs())]
    idempotency_window: u64,
    /// Largest request body, in bytes.
    #[arg(long, env = "COVEC_MAX_BODY_BYTES", default_value_t = InputLimits::default().max_body_bytes)]
    max_body_bytes: u64,
    /// Accepted API keys, comma-separated; none means no authentication, which is refused on
    /// an address other than loopback unless --allow-anonymous.
    #[arg(
        long,
        env = "COVEC_API_KEYS",
        value_delimiter = ',',
        hide_env_values = true
    )]
    api_keys: Vec<String>,
    /// Serve without API keys on an address other hosts can reach (anyone who reaches it can
    /// read every job): for a trusted network or a proxy that authenticates.
    #[arg(long, env = "COVEC_ALLOW_ANONYMOUS")]
    allow_anonymous: bool,
    /// The key signed result URLs are signed with (any string, 32 random bytes or more); every
    /// API replica needs the same. Default: a random one per process.
    #[arg(long, env = "COVEC_SIGNED_URL_SECRET", hide_env_values = true)]
    signed_url_secret: Option<String>,
    /// Seconds a signed result URL works (up to a quarter longer, so polls get stable URLs).
    #[arg(long, env = "COVEC_SIGNED_URL_TTL", default_value_t = Config::default().signed_urls.lifetime.as_secs())]
    signed_url_ttl: u64,
    /// Also serve `/healthz`, `/readyz` and `/metrics` on this address (for probes and
    /// scraping), and `/metrics` only there.
    #[arg(long, env = "COVEC_OPS_ADDR")]
    ops_addr: Option<SocketAddr>,
    /// Origins allowed by CORS, comma-separated; `*` allows any.
    #[arg(long, env = "COVEC_CORS_ORIGINS", value_delimiter = ',')]
    cors_origins: Vec<String>,
    /// Seconds a client may take to send a request's headers; also how long an idle connection
    /// stays open.
    #[arg(long, env = "COVEC_HEADER_READ_TIMEOUT", default_value_t = ConnectionLimits::default().header_read_timeout.as_secs())]
    header_read_timeout: u64,
    /// Longest pause, in seconds, while a client sends a request body; then the request fails.
    #[arg(long, env = "COVEC_BODY_READ_TIMEOUT", default_value_t = ConnectionLimits::default().body_read_timeout.as_secs())]
    body_read_timeout: u64,
    /// Most open connections; a new one beyond it closes the oldest idle or half-sent one.
    /// Keep it well below `ulimit -n`: jobs need files too.
    #[arg(long, env = "COVEC_MAX_CONNECTIONS", default_value_t = ConnectionLimits::default().max_connections)]
    max_connections: usize,
    /// Longest `Prefer: wait=N` honoured on a submission, in seconds; 0 ignores it.
    #[arg(long, env = "COVEC_MAX_WAIT", default_value_t = Config::default().max_wait.as_secs())]
    max_wait: u64,
    /// Webhook signing secret (Standard Webhooks `whsec_<base64>`); needed with webhook hosts.
    #[arg(long, env = "COVEC_WEBHOOK_SECRET", hide_env_values = true)]
    webhook_secret: Option<String>,
    /// Hosts webhooks may be sent to, comma-separated (`*.example.com` for subdomains); none
    /// (the default) refuses every webhook.
    #[arg(long, env = "COVEC_WEBHOOK_HOSTS", value_delimiter = ',')]
    webhook_hosts: Vec<String>,
    /// Also allow webhooks to loopback addresses (for tests; never in production).
    #[arg(long, env = "COVEC_WEBHOOK_ALLOW_LOOPBACK")]
    webhook_allow_loopback: bool,
    /// Attempts per webhook event, the first included.
    #[arg(long, env = "COVEC_WEBHOOK_ATTEMPTS", default_value_t = WebhookConfig::default().max_attempts)]
    webhook_attempts: u32,
    /// Seconds before the first webhook retry; each later retry waits twice as long.
    #[arg(long, env = "COVEC_WEBHOOK_FIRST_RETRY", default_value_t = WebhookConfig::default().first_retry.as_secs())]
    webhook_first_retry: u64,
}

impl ServeArgs {
    fn config(self) -> Result<Config, String> {
        let mut config = Config {
            addr: self.addr,
            queue: QueueConfig {
                max_queued: self.max_queued,
                record_retention: Duration::from_secs(self.record_retention),
                idempotency_window: Duration::from_secs(self.idempotency_window),
                ..QueueConfig::default()
            },
            limits: InputLimits {
                max_body_bytes: self.max_body_bytes,
                ..InputLimits::default()
            },
            connections: ConnectionLimits {
                header_read_timeout: Duration::from_secs(self.header_read_timeout),
                body_read_timeout: Duration::from_secs(self.body_read_timeout),
                max_connections: self.max_connections,
            },
            api_keys: self
                .api_keys
                .into_iter()
                .filter(|key| !key.is_empty())
                .collect(),
            allow_anonymous: self.allow_anonymous,
            signed_urls: SignedUrlConfig {
                secret: self.signed_url_secret.filter(|secret| !secret.is_empty()),
                lifetime: Duration::from_secs(self.signed_url_ttl),
            },
            ops_addr: self.ops_addr,
            cors_origins: self
                .cors_origins
                .into_iter()
                .filter(|origin| !origin.is_empty())
                .collect(),
            max_wait: Duration::from_secs(self.max_wait),
            webhooks: WebhookConfig {
                secret: self.webhook_secret.filter(|secret| !secret.is_empty()),
                allowed_hosts: self
                    .webhook_hosts
                    .into_iter()
                    .filter(|host| !host.is_empty())
                    .collect(),
                allow_loopback: self.webhook_allow_loopback,
                max_attempts: self.webhook_attempts.max(1),
                first_retry: Duration::from_secs(self.webhook_first_retry),
                ..WebhookConfig::default()
            },
            ..Config::default()
        };
        self.jobs.apply(&mut config)?;
        Ok(config)
    }
}

/// `covec worker`: runs queued jobs from the PostgreSQL backend, with no HTTP API.
#[derive(Args, Debug)]
pub struct WorkerArgs {
    /// Serve `/healthz`, `/readyz` and `/metrics` on this address, for probes and scraping
    /// (the address is printed on stdout); none by default.
    #[arg(long, env = "COVEC_OPS_ADDR")]
    ops_addr: Option<SocketAddr>,
    #[command(flatten)]
    jobs: JobArgs,
    #[command(flatten)]
    log: LogArgs,
}

/// Logs to stderr (`COVEC_LOG` filters) and a multi-threaded runtime, or the exit code.
fn start(command: &str, log: &LogArgs) -> Result<tokio::runtime::Runtime, ExitCode> {
    let logs = tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("COVEC_LOG")
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,tower_http=info")),
        )
        .with_writer(std::io::stderr);
    match log.log_format {
        LogFormat::Text => logs.with_ansi(std::io::stderr().is_terminal()).init(),
        LogFormat::Json => logs.json().init(),
    }
    super::malloc::limit_arenas();
    tokio::runtime::Runtime::new().map_err(|error| {
        eprintln!("covec {command}: cannot start the async runtime: {error}");
        ExitCode::FAILURE
    })
}

pub fn work(args: WorkerArgs) -> ExitCode {
    let runtime = match start("worker", &args.log) {
        Ok(runtime) => runtime,
        Err(code) => return code,
    };
    let mut config = Config::default();
    if let Err(error) = args.jobs.apply(&mut config) {
        eprintln!("covec worker: --key-limits: {error}");
        return ExitCode::FAILURE;
    }
    let serving = service::work(config, args.ops_addr, |addr| {
        println!("covec worker: probes and metrics on http://{addr}");
    });
    match runtime.block_on(serving) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("covec worker: {error}");
            ExitCode::FAILURE
        }
    }
}

pub fn run(args: ServeArgs) -> ExitCode {
    let runtime = match start("serve", &args.log) {
        Ok(runtime) => runtime,
        Err(code) => return code,
    };
    let config = match args.config() {
        Ok(config) => config,
        Err(error) => {
            eprintln!("covec serve: --key-limits: {error}");
            return ExitCode::FAILURE;
        }
    };
    let result = runtime.block_on(service::serve(config, |addr| {
        // The one line on stdout: scripts (and the integration tests) read the bound address.
        println!("covec serve: listening on http://{addr}");
    }));
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("covec serve: {error}");
            ExitCode::FAILURE
        }
    }
}
