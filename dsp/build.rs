//! Emits `cfg(gman_dsp)` for targets with the Armv7E-M / Armv8-M DSP extension (SXTB16,
//! SMLAD): `rustc` does not expose Arm's `dsp` target feature to `cfg` on stable.

fn main() {
    println!("cargo:rustc-check-cfg=cfg(gman_dsp)");
    println!("cargo:rerun-if-env-changed=TARGET");
    let target = std::env::var("TARGET").unwrap_or_default();
    // thumbv7em-none-eabi(hf) (Cortex-M4/M7) and thumbv8m.main-none-eabi(hf) with DSP
    // (Cortex-M33/M35P/M55 usually have it; `.main` alone does not guarantee it, so only the
    // v7E-M targets, which always have it, are enabled).
    if target.starts_with("thumbv7em-") {
        println!("cargo:rustc-cfg=gman_dsp");
    }
}
