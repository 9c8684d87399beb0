//! `covec openapi`: the service's API document (OpenAPI 3.1 YAML), generated from its code.

use std::path::PathBuf;

use clap::Args as ClapArgs;

/// Print the HTTP service's OpenAPI document, or write it (`-o api/openapi.yaml`).
#[derive(ClapArgs, Debug)]
pub struct Args {
    /// Write the document here instead of standard output.
    #[arg(short, long)]
    output: Option<PathBuf>,
}

pub fn run(args: &Args) -> Result<(), String> {
    let document = covec::service::openapi_document();
    match &args.output {
        Some(path) => std::fs::write(path, document)
            .map_err(|error| format!("cannot write {}: {error}", path.display())),
        None => {
            print!("{document}");
            Ok(())
        }
    }
}
