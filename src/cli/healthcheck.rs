//! `covec healthcheck`: asks a running covec whether it is alive, for a container's
//! HEALTHCHECK (the image carries no curl) or any supervisor that runs a command.
//!
//! Exit 0 on a 2xx answer; otherwise one line on stderr and a non-zero exit, within `--timeout`
//! whatever the server does (refuses, stalls, answers slowly).

use std::error::Error as _;
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr};
use std::time::Duration;

use axum::body::Bytes;
use http_body_util::Empty;
use hyper::Uri;
use hyper_util::client::legacy::Client;
use hyper_util::rt::TokioExecutor;

use covec::service::{Config, LIVENESS_PATH};

use super::serve::ADDR_ENV;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The URL to ask (http://), e.g. a worker's probe address `http://127.0.0.1:9090/healthz`
    /// (its --ops-addr). Default: /healthz at --addr.
    #[arg(long)]
    url: Option<String>,
    /// The address `covec serve` listens on (its --addr, read from the same variable), asked
    /// when no --url is given; an unspecified IP (0.0.0.0, ::) is asked on loopback.
    #[arg(long, env = ADDR_ENV, default_value_t = Config::default().addr)]
    addr: SocketAddr,
    /// Seconds to wait for the answer, connecting included.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u64).range(1..))]
    timeout: u64,
}

pub fn run(args: &Args) -> Result<(), String> {
    let url = args.url.clone().unwrap_or_else(|| liveness_url(args.addr));
    let uri: Uri = url
        .parse()
        .map_err(|error| format!("--url {url:?}: {error}"))?;
    if uri.scheme_str() != Some("http") || uri.host().is_none() {
        return Err(format!(
            "--url {url:?}: give an http:// URL with a host (the probe asks the local process)"
        ));
    }
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|error| format!("cannot start the async runtime: {error}"))?;
    let timeout = Duration::from_secs(args.timeout);
    let answer = runtime.block_on(async { tokio::time::timeout(timeout, status(uri)).await });
    // Nothing left running may hold the exit back (a name lookup on a blocking thread, say).
    runtime.shutdown_background();
    match answer {
        Err(_) => Err(format!("{url}: no answer within {} s", args.timeout)),
        Ok(Err(error)) => Err(format!("{url}: {error}")),
        Ok(Ok(status)) if status.is_success() => Ok(()),
        Ok(Ok(status)) => Err(format!("{url}: answered {status}")),
    }
}

/// `/healthz` at `addr`; a server listening on an unspecified IP answers on loopback.
fn liveness_url(addr: SocketAddr) -> String {
    let ip = match addr.ip() {
        IpAddr::V4(ip) if ip.is_unspecified() => IpAddr::V4(Ipv4Addr::LOCALHOST),
        IpAddr::V6(ip) if ip.is_unspecified() => IpAddr::V6(Ipv6Addr::LOCALHOST),
        ip => ip,
    };
    format!("http://{}{LIVENESS_PATH}", SocketAddr::new(ip, addr.port()))
}

/// The status of a GET of `uri`, or why there is none (the error's causes joined on one line).
async fn status(uri: Uri) -> Result<hyper::StatusCode, String> {
    let client = Client::builder(TokioExecutor::new()).build_http::<Empty<Bytes>>();
    match client.get(uri).await {
        Ok(response) => Ok(response.status()),
        Err(error) => {
            let mut text = error.to_string();
            let mut cause = error.source();
            while let Some(inner) = cause {
                text = format!("{text}: {inner}");
                cause = inner.source();
            }
            Err(text)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unspecified_addresses_are_asked_on_loopback() {
        let url = |addr: &str| liveness_url(addr.parse().unwrap());
        assert_eq!(url("0.0.0.0:8080"), "http://127.0.0.1:8080/healthz");
        assert_eq!(url("[::]:9090"), "http://[::1]:9090/healthz");
        assert_eq!(url("10.1.2.3:80"), "http://10.1.2.3:80/healthz");
    }
}
