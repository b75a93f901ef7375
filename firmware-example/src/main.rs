//! gman-rs firmware example for a Cortex-M4F (QEMU `mps2-an386`).
//!
//! Today it exercises the foundation kernels of gman-core straight from a weight blob in
//! flash: it parses and validates the embedded `Mcu` int8 blob (no copy of the weights),
//! generates target features x = G(SE(y), z) for a few noise draws in the parameter-efficient
//! mode (int8 base weights, per-unit gains and biases in RAM), scores them with D, and takes
//! one closed-form gradient of the WGAN-GP loss L_D (Eq. 1) against synthetic observations.
//! It prints every result's bits through semihosting and exits QEMU with success, or with
//! failure on any error, panic or fault. The navigator loop (reset/step) replaces this once
//! the navigator exists.
#![no_std]
#![no_main]

use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::{debug, hprintln};
use panic_semihosting as _;

mod selftest;

static BLOB: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/model.gman"));

#[entry]
fn main() -> ! {
    match run() {
        Ok(()) => {
            hprintln!("OK");
            debug::exit(debug::EXIT_SUCCESS);
        }
        Err(e) => {
            hprintln!("ERROR: {}", e);
            debug::exit(debug::EXIT_FAILURE);
        }
    }
    loop {
        cortex_m::asm::wfi();
    }
}

fn run() -> gman_core::Result<()> {
    selftest::run(BLOB, &mut |line| hprintln!("{}", line))
}

#[exception]
unsafe fn HardFault(_ef: &ExceptionFrame) -> ! {
    hprintln!("HardFault");
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}
