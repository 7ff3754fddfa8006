//! The `visco` command. Each subcommand lives in its own module under `src/cli/`.
#![forbid(unsafe_code)]

mod cli;

fn main() -> std::process::ExitCode {
    cli::run()
}
