//! The visco firmware image: a board, the loop interrupt and the host link around the
//! board-independent library (`visco_firmware`).
//!
//! Boards (exactly one, by cargo feature):
//! - `board-qemu` (default): QEMU `mps2-an500`, see `board/qemu.rs`.
//! - `board-stm32h743`: `--no-default-features --features board-stm32h743`, see
//!   `board/stm32h743.rs`.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
mod app;

#[cfg(all(target_os = "none", feature = "board-qemu"))]
#[path = "board/qemu.rs"]
mod board;

#[cfg(all(
    target_os = "none",
    feature = "board-stm32h743",
    not(feature = "board-qemu")
))]
#[path = "board/stm32h743.rs"]
mod board;

#[cfg(target_os = "none")]
#[cortex_m_rt::entry]
fn main() -> ! {
    app::run()
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "visco-firmware is an embedded image: build it with `cargo xtask firmware` \
         (--target thumbv7em-none-eabihf); the host build is a stub"
    );
}
