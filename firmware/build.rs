//! Linker set-up of the firmware image: cortex-m-rt's `link.x` and defmt's `defmt.x`, the
//! board's memory layout, and (QEMU) the interrupt names.
//!
//! Board memory:
//! - QEMU (default): the top-level `memory.x`. The linker runs in the workspace root, where it
//!   finds that file first, so cortex-m-rt's `link.x` is used as it is.
//! - STM32H743: `boards/stm32h743/memory.x`. Because the linker would still find the
//!   top-level `memory.x` first (the current directory comes before the search path), this
//!   board links with `link-stm32h743.x`: cortex-m-rt's generated `link.x` (from its build
//!   directory; `links = "cortex-m-rt"` makes cargo run its build script before this one)
//!   with `INCLUDE memory.x` replaced by `INCLUDE memory-stm32h743.x`.

use std::{env, fs, path::Path, path::PathBuf};

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
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rustc-link-arg-bins=--nmagic");
    match (qemu, h7) {
        (true, false) => {
            let memory = manifest.join("..").join("memory.x");
            println!("cargo:rerun-if-changed={}", memory.display());
            let device = manifest.join("device-qemu.x");
            println!("cargo:rerun-if-changed={}", device.display());
            fs::copy(&device, out.join("device.x")).expect("copy device.x");
            println!("cargo:rustc-link-arg-bins=-Tlink.x");
        }
        (false, true) => {
            let memory = manifest.join("boards").join("stm32h743").join("memory.x");
            println!("cargo:rerun-if-changed={}", memory.display());
            fs::copy(&memory, out.join("memory-stm32h743.x")).expect("copy memory.x");
            let link = cortex_m_rt_link_x(&out);
            let text = fs::read_to_string(&link).expect("read cortex-m-rt link.x");
            assert!(
                text.contains("INCLUDE memory.x"),
                "cortex-m-rt's link.x no longer includes memory.x: update firmware/build.rs"
            );
            let text = text.replace("INCLUDE memory.x", "INCLUDE memory-stm32h743.x");
            fs::write(out.join("link-stm32h743.x"), text).expect("write link script");
            println!("cargo:rustc-link-arg-bins=-Tlink-stm32h743.x");
        }
        _ => panic!(
            "select exactly one board: default (board-qemu) or \
             `--no-default-features --features board-stm32h743`"
        ),
    }
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
}

/// cortex-m-rt's generated `link.x` in the same build directory (the newest, if several).
fn cortex_m_rt_link_x(out: &Path) -> PathBuf {
    let build = out
        .parent()
        .and_then(Path::parent)
        .expect("OUT_DIR is <target>/build/<pkg>/out");
    let mut best: Option<(std::time::SystemTime, PathBuf)> = None;
    for e in fs::read_dir(build).expect("read build dir").flatten() {
        let name = e.file_name();
        if !name.to_string_lossy().starts_with("cortex-m-rt-") {
            continue;
        }
        let p = e.path().join("out").join("link.x");
        if let Ok(m) = fs::metadata(&p).and_then(|m| m.modified()) {
            if best.as_ref().is_none_or(|(t, _)| m > *t) {
                best = Some((m, p));
            }
        }
    }
    best.map(|(_, p)| p).expect(
        "cortex-m-rt's link.x not found (its build script runs first: links = \"cortex-m-rt\")",
    )
}
