//! Prints the RAM and flash each preset and adaptation mode needs, from the core's own
//! `const fn` size accounting: `cargo run -p gman-core --example memory_table`.

use gman_core::memory::{int8_weight_bytes, AdaptMode, NavLayout};
use gman_core::Dims;

fn main() {
    println!("| preset | mode | RAM arena (KiB) | of which Psi (KiB) | adapted params (floats) | int8 weights in flash (KiB) | f32 weights (KiB) |");
    println!("|---|---|---:|---:|---:|---:|---:|");
    for (name, d) in [
        ("paper", Dims::PAPER),
        ("paper + 7x7 map (64 ch)", Dims::PAPER.with_map(7, 7, 64)),
        ("mcu", Dims::MCU),
        ("mcu + 3x3 map (8 ch)", Dims::MCU.with_map(3, 3, 8)),
    ] {
        for mode in [AdaptMode::Full, AdaptMode::Efficient] {
            let l = NavLayout::new(&d, mode, 20);
            let f32_bytes = 4 * (d.gen_params() + d.disc_params() + d.policy_params());
            println!(
                "| {name} | {mode:?} | {:.1} | {:.1} | {} | {:.1} | {:.1} |",
                l.total_bytes() as f64 / 1024.0,
                (4 * l.psi) as f64 / 1024.0,
                l.gen_params + l.actor_params,
                int8_weight_bytes(&d) as f64 / 1024.0,
                f32_bytes as f64 / 1024.0,
            );
        }
    }
}
