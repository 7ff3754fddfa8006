//! `cargo xtask test`: the one command that runs every test on a fresh machine.
//!
//! 1. Installs what it needs (the Cortex-M targets with `rustup target add`, QEMU with
//!    `apt-get`), failing loudly when it cannot — never skipping.
//! 2. Checks formatting.
//! 3. Builds the identification core for `thumbv7em-none-eabihf` (no_std, no heap).
//! 4. Runs every host test of the workspace (core, protocol, host tools, end-to-end), and
//!    compares the core's closed-loop digests with the committed `xtask/core-digests.txt`.
//! 5. Runs the firmware's tests: both boards build, no panic path is linked, the QEMU image
//!    boots, SysTick is calibrated, replay under QEMU is bit-identical to the host; the same
//!    for the fixed-point (Q31.32) build on the Cortex-M3, with its instruction counts and
//!    its error against f64.

use crate::firmware::{self, Result};
use std::process::Command;
use std::time::Instant;

fn step(name: &str, f: impl FnOnce() -> Result<()>) -> Result<()> {
    let t = Instant::now();
    eprintln!("==> {name}");
    let r = f();
    match &r {
        Ok(()) => eprintln!("<== {name}: ok ({:.1} s)", t.elapsed().as_secs_f64()),
        Err(e) => eprintln!("<== {name}: FAILED: {e}"),
    }
    r
}

fn cargo(args: &[&str]) -> Result<()> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let status = Command::new(&cargo)
        .current_dir(firmware::root())
        .args(args)
        .status()
        .map_err(|e| format!("{cargo} {}: {e}", args.join(" ")))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("`cargo {}` failed: {status}", args.join(" ")))
    }
}

/// Everything, in order; stops at the first failure.
pub fn run_all() -> Result<()> {
    let t = Instant::now();
    step(
        "install the Cortex-M targets and QEMU",
        firmware::ensure_tools,
    )?;
    step("formatting (cargo fmt --check)", || {
        cargo(&["fmt", "--all", "--", "--check"])
    })?;
    step(
        "visco-core builds for thumbv7em-none-eabihf (no_std)",
        || {
            cargo(&[
                "build",
                "--release",
                "-p",
                "visco-core",
                "--target",
                "thumbv7em-none-eabihf",
            ])
        },
    )?;
    step("host tests (cargo test)", || {
        cargo(&["test", "--workspace", "--exclude", "visco-firmware"])
    })?;
    step(
        "core digests equal to xtask/core-digests.txt (bit-identical core)",
        || crate::digest::check(&firmware::core_digest_lines()?),
    )?;
    step("firmware tests (QEMU)", firmware::firmware_tests)?;
    eprintln!("all tests passed in {:.0} s", t.elapsed().as_secs_f64());
    Ok(())
}
