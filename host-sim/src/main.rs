//! `gman`: command line of gman-rs (see `cli.rs`).
use std::process::ExitCode;

use clap::Parser;

mod cli;
mod cli_bench;
mod cli_nav;

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
    match cli::run(cli::Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
