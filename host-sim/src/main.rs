//! `gman`: command line of gman-rs (see `cli/mod.rs`).
use std::process::ExitCode;

use clap::{CommandFactory, FromArgMatches};

mod cli;

/// Restores the default action of SIGPIPE, so that `gman inspect m.gman | head` ends quietly
/// like any Unix tool instead of panicking in `println!` (Rust ignores SIGPIPE by default,
/// which turns a closed pipe into an error on every write).
#[cfg(unix)]
fn default_sigpipe() {
    // SAFETY: called once at the start of `main`, before any thread exists; `signal` with
    // `SIG_DFL` only resets the disposition of one signal.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

#[cfg(not(unix))]
fn default_sigpipe() {}

fn main() -> ExitCode {
    default_sigpipe();
    gman_host_sim::progress::install(&cli::progress::TerminalBars);
    let matches =
        cli::Cli::command().get_matches_from(cli::recipes::expand(std::env::args_os().collect()));
    let parsed = cli::Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    match cli::run(parsed, &matches) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
