//! Linker set-up of the firmware image: cortex-m-rt's `link.x` and defmt's `defmt.x`, and the
//! board's memory layout and (QEMU) interrupt names.
//!
//! The board's `memory.x` is copied into OUT_DIR, which is on the linker search path. The
//! QEMU board's layout is the top-level `memory.x`; the STM32H743's is
//! `boards/stm32h743/memory.x`.

use std::{env, fs, path::PathBuf};

fn main() {
    let manifest = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets this"));
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets this"));
    let target = env::var("TARGET").unwrap_or_default();
    println!("cargo:rerun-if-changed=build.rs");
    if !target.starts_with("thumb") {
        // Host build: the library for tests, the binary is a stub.
        return;
    }
    let qemu = env::var_os("CARGO_FEATURE_BOARD_QEMU").is_some();
    let h7 = env::var_os("CARGO_FEATURE_BOARD_STM32H743").is_some();
    let memory = match (qemu, h7) {
        (true, false) => manifest.join("..").join("memory.x"),
        (false, true) => manifest.join("boards").join("stm32h743").join("memory.x"),
        _ => panic!(
            "select exactly one board: default (board-qemu) or \
             `--no-default-features --features board-stm32h743`"
        ),
    };
    println!("cargo:rerun-if-changed={}", memory.display());
    fs::copy(&memory, out.join("memory.x")).expect("copy memory.x");
    if qemu {
        let device = manifest.join("device-qemu.x");
        println!("cargo:rerun-if-changed={}", device.display());
        fs::copy(&device, out.join("device.x")).expect("copy device.x");
    }
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
}
