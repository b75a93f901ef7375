//! Prints the RAM and flash each preset and adaptation mode needs, from the core's own
//! `const fn` size accounting: `cargo run -p gman-core --example memory_table`.

use gman_core::navigator::memory::{int8_weight_bytes, AdaptMode, Footprint, NavLayout};
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
        // Full: one layout (the footprints coincide); Efficient: the microcontroller's
        // compact layout and the hosts' fast one.
        for (mode, fp) in [
            (AdaptMode::Full, Footprint::Fast),
            (AdaptMode::Efficient, Footprint::Compact),
            (AdaptMode::Efficient, Footprint::Fast),
        ] {
            let l = NavLayout::new_with(&d, mode, 20, fp);
            let label = match (mode, fp) {
                (AdaptMode::Efficient, Footprint::Fast) => "Efficient, fast (hosts)",
                _ => match mode {
                    AdaptMode::Full => "Full",
                    AdaptMode::Efficient => "Efficient",
                },
            };
            let f32_bytes = 4 * (d.gen_params() + d.disc_params() + d.policy_params());
            println!(
                "| {name} | {label} | {:.1} | {:.1} | {} | {:.1} | {:.1} |",
                l.total_bytes() as f64 / 1024.0,
                (4 * l.psi) as f64 / 1024.0,
                l.gen_params + l.actor_params,
                int8_weight_bytes(&d) as f64 / 1024.0,
                f32_bytes as f64 / 1024.0,
            );
        }
    }
    println!();
    println!("RAM arena by part (KiB, k = 20):");
    println!();
    println!("| preset | mode | G params | D params | actor params | fixed biases | gradients | Psi | activations and scratch | total |");
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    let kib = |floats: usize| (4 * floats) as f64 / 1024.0;
    for (name, d) in [
        ("paper", Dims::PAPER),
        ("paper + 7x7 map (64 ch)", Dims::PAPER.with_map(7, 7, 64)),
        ("mcu", Dims::MCU),
        ("mcu + 3x3 map (8 ch)", Dims::MCU.with_map(3, 3, 8)),
    ] {
        for (mode, fp, label) in [
            (AdaptMode::Full, Footprint::Fast, "Full"),
            (AdaptMode::Efficient, Footprint::Compact, "Efficient"),
            (
                AdaptMode::Efficient,
                Footprint::Fast,
                "Efficient, fast (hosts)",
            ),
        ] {
            let l = NavLayout::new_with(&d, mode, 20, fp);
            println!(
                "| {name} | {label} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} |",
                kib(l.gen_params),
                kib(l.disc_params),
                kib(l.actor_params),
                kib(l.fixed_biases),
                kib(l.grads),
                kib(l.psi),
                kib(l.work),
                l.total_bytes() as f64 / 1024.0,
            );
        }
    }
}
