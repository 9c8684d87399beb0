//! The `covec` command line.

use clap::{Parser, Subcommand};
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
}

fn main() {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Vectorize(args) => cli::vectorize::run(args),
    };
    if let Err(error) = result {
        eprintln!("error: {error}");
        std::process::exit(1);
    }
}
