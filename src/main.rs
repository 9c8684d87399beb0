//! The `covec` command line.

use clap::{Parser, Subcommand};

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
enum Command {}

fn main() {
    let cli = Cli::parse();
    match cli.command {}
}
