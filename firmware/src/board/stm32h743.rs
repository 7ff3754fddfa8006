//! STM32H743 board (placeholder until written).
