//! `covec reference`: the command line's reference (docs/cli-reference.md), generated from the
//! clap definitions, so every flag, environment variable and default in it is the code's own.

use std::fmt::Write;
use std::path::PathBuf;

use clap::{Arg, ArgAction, Args as ClapArgs, Command};

/// Print the command-line reference as Markdown, or write it (`-o docs/cli-reference.md`).
#[derive(ClapArgs, Debug)]
pub struct Args {
    /// Write the reference here instead of standard output.
    #[arg(short, long)]
    output: Option<PathBuf>,
}

/// `command` is the whole command line (`Cli::command()`), which lives above this module.
pub fn run(args: &Args, command: Command) -> Result<(), String> {
    let text = markdown(command);
    match &args.output {
        Some(path) => std::fs::write(path, text)
            .map_err(|error| format!("cannot write {}: {error}", path.display())),
        None => {
            print!("{text}");
            Ok(())
        }
    }
}

/// The reference: one section per visible subcommand, each with its usage and a table of its
/// arguments (flag, environment variable, default, description).
pub fn markdown(mut command: Command) -> String {
    command.build();
    let mut out = format!(
        "# Command-line reference\n\n\
         Generated from the code by `covec reference -o docs/cli-reference.md`; a test fails while \
         this file differs from what the code generates. `covec help <command>` prints the same.\n\n\
         {}\n",
        text_of(command.get_about())
    );
    let name = command.get_name().to_owned();
    for sub in command.get_subcommands().filter(|sub| !sub.is_hide_set()) {
        section(&mut out, &name, sub);
    }
    out
}

fn section(out: &mut String, parent: &str, command: &Command) {
    let name = format!("{parent} {}", command.get_name());
    let about = text_of(command.get_long_about().or(command.get_about()));
    let usage = command
        .clone()
        .bin_name(&name)
        .render_usage()
        .to_string()
        .trim_start_matches("Usage: ")
        .to_owned();
    write!(out, "\n## `{name}`\n\n{about}\n\n```text\n{usage}\n```\n\n")
        .expect("writing to a String");
    out.push_str("| argument | environment | default | description |\n|---|---|---|---|\n");
    let arguments = command
        .get_arguments()
        .filter(|arg| !arg.is_hide_set() && !matches!(arg.get_id().as_str(), "help" | "version"));
    for arg in arguments {
        let env = arg
            .get_env()
            .map(|env| format!("`{}`", env.to_string_lossy()))
            .unwrap_or_default();
        // A switch's `false` is no default worth stating.
        let defaults: Vec<String> = if arg.get_action().takes_values() {
            arg.get_default_values()
                .iter()
                .map(|value| format!("`{}`", value.to_string_lossy()))
                .collect()
        } else {
            Vec::new()
        };
        writeln!(
            out,
            "| {} | {env} | {} | {} |",
            cell(&format!("`{}`", spelling(arg))),
            defaults.join(", "),
            cell(&description(arg)),
        )
        .expect("writing to a String");
    }
}

/// How the argument is written: `-o, --output <PATH>`, `--flatten`, `<INPUT>...`.
fn spelling(arg: &Arg) -> String {
    let values = arg
        .get_value_names()
        .map(|names| {
            names
                .iter()
                .map(|name| format!("<{name}>"))
                .collect::<Vec<_>>()
                .join(" ")
        })
        .unwrap_or_else(|| format!("<{}>", arg.get_id().as_str().to_uppercase()));
    let repeated = matches!(arg.get_action(), ArgAction::Append)
        || arg
            .get_num_args()
            .is_some_and(|range| range.max_values() > 1);
    let values = if repeated {
        format!("{values}...")
    } else {
        values
    };
    if arg.is_positional() {
        return values;
    }
    let mut names = Vec::new();
    if let Some(short) = arg.get_short() {
        names.push(format!("-{short}"));
    }
    if let Some(long) = arg.get_long() {
        names.push(format!("--{long}"));
    }
    let names = names.join(", ");
    if arg.get_action().takes_values() {
        format!("{names} {values}")
    } else {
        names
    }
}

/// The argument's help, with its possible values when it has a closed set.
fn description(arg: &Arg) -> String {
    let text = text_of(arg.get_long_help().or(arg.get_help()));
    let possible: Vec<String> = arg
        .get_possible_values()
        .iter()
        .filter(|value| !value.is_hide_set())
        .map(|value| format!("`{}`", value.get_name()))
        .collect();
    let mut text = text.trim().to_owned();
    if !possible.is_empty() && arg.get_action().takes_values() {
        if !text.is_empty() && !text.ends_with('.') {
            text.push('.');
        }
        write!(text, " One of {}.", possible.join(", ")).expect("writing to a String");
    }
    text
}

fn text_of(text: Option<&clap::builder::StyledStr>) -> String {
    text.map(|text| text.to_string()).unwrap_or_default()
}

/// A Markdown table cell: one line, with `|` escaped.
fn cell(text: &str) -> String {
    text.split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
        .replace('|', "\\|")
}
