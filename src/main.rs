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
    Eval(cli::eval::Args),
}

fn main() {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Vectorize(args) => cli::vectorize::run(args).map_err(|e| e.to_string()),
        Command::Eval(args) => cli::eval::run(args).map_err(|e| e.to_string()),
    };
    if let Err(error) = result {
        eprintln!("error: {error}");
        std::process::exit(1);
    }
}
