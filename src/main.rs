//! The `covec` command line. Without the `service` feature it has every subcommand but the
//! service's own (`serve`, `worker`, `openapi`, `healthcheck`).

use std::process::ExitCode;

use clap::{CommandFactory, Parser, Subcommand};
mod cli;

#[derive(Parser)]
#[command(
    name = "covec",
    version,
    about = "Photographs to layered, editable SVG (COVec)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    Vectorize(cli::vectorize::Args),
    Edit(cli::edit::Args),
    Render(cli::render::Args),
    Eval(cli::eval::Args),
    /// Run the HTTP vectorisation service (jobs API, progress, results; see api/openapi.yaml).
    // Boxed: its many settings make it several times the size of the other variants.
    #[cfg(feature = "service")]
    Serve(Box<cli::serve::ServeArgs>),
    /// Run queued jobs from the shared PostgreSQL backend (`--database-url`), with no HTTP API.
    #[cfg(feature = "service")]
    Worker(cli::serve::WorkerArgs),
    #[cfg(feature = "service")]
    Openapi(cli::openapi::Args),
    /// Ask a running `covec serve` (or a worker's --ops-addr) whether it is alive: exit 0 on
    /// a 2xx answer (for a container's HEALTHCHECK).
    #[cfg(feature = "service")]
    Healthcheck(cli::healthcheck::Args),
    Reference(cli::reference::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    cli::malloc::map_large_buffers();
    let result = match cli.command {
        Command::Vectorize(args) => cli::vectorize(&args),
        Command::Edit(args) => cli::edit::run(&args).map_err(|e| e.to_string()),
        Command::Render(args) => cli::render::run(&args).map_err(|e| e.to_string()),
        Command::Eval(args) => cli::eval(&args),
        #[cfg(feature = "service")]
        Command::Serve(args) => return cli::serve::run(*args),
        #[cfg(feature = "service")]
        Command::Worker(args) => return cli::serve::work(args),
        #[cfg(feature = "service")]
        Command::Openapi(args) => cli::openapi::run(&args),
        #[cfg(feature = "service")]
        Command::Healthcheck(args) => cli::healthcheck::run(&args),
        Command::Reference(args) => cli::reference::run(&args, Cli::command()),
    };
    if let Err(error) = result {
        eprintln!("error: {error}");
        return ExitCode::FAILURE;
    }
    ExitCode::SUCCESS
}
