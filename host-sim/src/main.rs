//! `gman`: command line of gman-rs (see `cli.rs`).
use std::process::ExitCode;

use clap::Parser;

mod cli;
mod cli_bench;
mod cli_nav;

fn main() -> ExitCode {
    match cli::run(cli::Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
