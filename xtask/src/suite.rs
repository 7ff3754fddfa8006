//! `cargo xtask test`: the one command that runs every test on a fresh machine.
//!
//! 1. Installs what it needs (the Cortex-M targets with `rustup target add`, QEMU with
//!    `apt-get`), failing loudly when it cannot — never skipping.
//! 2. Checks formatting.
//! 3. Builds the identification core for `thumbv7em-none-eabihf` (no_std, no heap).
//! 4. Runs every host test of the workspace (core, protocol, host tools, end-to-end).
//! 5. Runs the firmware's tests: both boards build, no panic path is linked, the QEMU image
//!    boots, SysTick is calibrated, replay under QEMU is bit-identical to the host; the same
//!    for the fixed-point (Q31.32) build on the Cortex-M3, with its instruction counts and
//!    its error against f64.
//! 6. The independent reference simulator (refsim/, Python): a venv in target/refsim-venv
//!    with numpy, scipy and pytest from PyPI, its closed-form tests, then one recording per
//!    class (discrete beds only, for time) generated and diagnosed by visco (`tests/concealed_refsim.rs`, figures printed).

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
    step("firmware tests (QEMU)", firmware::firmware_tests)?;
    step(
        "refsim: closed forms and the concealed suite on its recordings",
        refsim_tests,
    )?;
    eprintln!("all tests passed in {:.0} s", t.elapsed().as_secs_f64());
    Ok(())
}

/// Runs a program from the workspace root, failing loudly.
fn run_in_root(program: &str, args: &[&str], env: &[(&str, &str)]) -> Result<()> {
    let status = Command::new(program)
        .current_dir(firmware::root())
        .args(args)
        .envs(env.iter().copied())
        .status()
        .map_err(|e| format!("{program} {}: {e}", args.join(" ")))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("`{program} {}` failed: {status}", args.join(" ")))
    }
}

/// refsim's venv (target/refsim-venv, its own so that no other Python step is disturbed),
/// its closed-form tests, and the reduced independent suite: one seed per class.
fn refsim_tests() -> Result<()> {
    let root = firmware::root();
    let venv = root.join("target/refsim-venv");
    let python = venv.join("bin/python");
    if !python.exists() {
        run_in_root("python3", &["-m", "venv", "target/refsim-venv"], &[])?;
    }
    let py = python.to_string_lossy().into_owned();
    run_in_root(
        &py,
        &[
            "-m",
            "pip",
            "install",
            "-q",
            "-r",
            "refsim/requirements.txt",
        ],
        &[],
    )?;
    run_in_root(&py, &["-m", "pytest", "-q", "refsim/tests"], &[])?;
    let dir = root.join("target/refsim-ci");
    if dir.exists() {
        std::fs::remove_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    let dir_s = dir.to_string_lossy().into_owned();
    run_in_root(
        &py,
        &[
            "-m",
            "refsim",
            "generate",
            "--out",
            &dir_s,
            "--seeds",
            "1",
            "--jobs",
            "2",
            "--discrete-only",
        ],
        &[],
    )?;
    cargo_env(
        &[
            "test",
            "-p",
            "visco",
            "--test",
            "concealed_refsim",
            "--",
            "--ignored",
            "--nocapture",
        ],
        &[("VISCO_REFSIM_DIR", &dir_s)],
    )
}

fn cargo_env(args: &[&str], env: &[(&str, &str)]) -> Result<()> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    run_in_root(&cargo, args, env)
}
