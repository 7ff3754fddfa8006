//! The `visco` command. Each subcommand lives in its own module under `src/cli/`.
#![forbid(unsafe_code)]

mod cli;

fn main() -> std::process::ExitCode {
    quiet_on_closed_pipe();
    cli::run()
}

/// Output into a closed pipe (`visco diagnose … | head`) ends the program as a pipe's reader
/// expects, with the shell's status for SIGPIPE (128 + 13) and no panic message: Rust ignores
/// SIGPIPE, so `print!` into a closed pipe panics instead of the process ending silently.
fn quiet_on_closed_pipe() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let msg = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or("");
        if msg.starts_with("failed printing to stdout") && msg.contains("Broken pipe") {
            std::process::exit(141);
        }
        default(info)
    }));
}
