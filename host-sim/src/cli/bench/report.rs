//! The report of `gman bench`: every number as JSON, and the Markdown tables.

use serde_json::{json, Value};

use super::firmware::Firmware;
use super::limits::Limits;
use super::navigator::{KernelRow, NavRow};
use super::train::{self, TrainRow};
use super::K;
use gman_core::Dims;

/// Everything one `gman bench` run measured.
pub struct Measured {
    /// This machine's limits.
    pub lim: Limits,
    /// Cache-resident kernel timings.
    pub kernels: Vec<KernelRow>,
    /// Navigator timings.
    pub nav: Vec<NavRow>,
    /// Training throughput.
    pub train: Vec<TrainRow>,
    /// The firmware's figures (`None`: the firmware's output file does not exist).
    pub firmware: Option<Firmware>,
    /// Where the firmware's figures are read from.
    pub firmware_log: String,
    /// Size of the copy arrays (MiB).
    pub stream_mib: usize,
    /// Repetitions per timing.
    pub reps: usize,
}

fn us(s: f64) -> String {
    if s < 1e-3 {
        format!("{:.1} µs", s * 1e6)
    } else {
        format!("{:.3} ms", s * 1e3)
    }
}

fn pct(x: f64) -> String {
    format!("{:.0}%", 100.0 * x)
}

impl Limits {
    /// Peak mul+add of the ISA a kernel set uses.
    fn peak_for(&self, kernels: &str) -> f64 {
        if kernels == "avx2" {
            self.peak_muladd_avx2_gflops.unwrap_or(f64::NAN)
        } else {
            self.peak_muladd_gflops
        }
    }
}

impl NavRow {
    /// GFLOP/s of one step.
    fn gflops(&self) -> f64 {
        2.0 * self.macs as f64 / self.step_s / 1e9
    }

    /// Weight bandwidth of one step (GB/s).
    fn gbs(&self) -> f64 {
        self.weight_bytes as f64 / self.step_s / 1e9
    }
}

fn nav_json(m: &Measured) -> Vec<Value> {
    let lim = &m.lim;
    let fma = lim.peak_fma_gflops.unwrap_or(f64::NAN);
    m.nav
        .iter()
        .map(|r| {
            let (gflops, gbs) = (r.gflops(), r.gbs());
            json!({
                "preset": r.preset, "quant": r.quant, "mode": r.mode,
                "step_us": r.step_s * 1e6, "step_min_us": r.step_min_s * 1e6,
                "adapt_ms": r.adapt_s * 1e3, "adapt_min_ms": r.adapt_min_s * 1e3,
                "macs_per_step": r.macs, "weight_bytes_per_step": r.weight_bytes,
                "gflops": gflops, "weight_gbs": gbs,
                "frac_peak_muladd": gflops / lim.peak_muladd_gflops,
                "frac_peak_fma": gflops / fma,
                "frac_copy_bw": gbs / lim.copy_gbs,
                "frac_read_bw": gbs / lim.read_gbs,
                "adapt_over_step": r.adapt_s / r.step_s,
            })
        })
        .collect()
}

fn kernel_json(m: &Measured) -> Vec<Value> {
    m.kernels
        .iter()
        .map(|r| {
            let g = 2.0 * r.macs as f64 / r.secs / 1e9;
            json!({
                "kernel": r.what, "quant": r.quant, "kernels": r.kernels, "macs": r.macs,
                "us": r.secs * 1e6, "gflops": g,
                "frac_peak_muladd_same_isa": g / m.lim.peak_for(r.kernels),
            })
        })
        .collect()
}

fn firmware_json(m: &Measured) -> Value {
    match &m.firmware {
        Some(f) => json!({
            "source": format!("{} (mcu, {}, Efficient; the firmware's own output)", f.source, f.quant_label()),
            "step_instructions": f.step_instr,
            "adapt_instructions": f.adapt_instr,
            "mhz": f.mhz,
            "step_ms_at_1ipc": f.step_instr / f.mhz / 1e3,
            "adapt_ms_at_1ipc": f.adapt_instr / f.mhz / 1e3,
            "macs_per_step": f.macs,
            "instructions_per_mac": f.step_instr / f.macs,
        }),
        None => json!({ "source": m.firmware_log, "measured": false }),
    }
}

/// Every number as JSON.
pub fn json(m: &Measured, elapsed_s: f64) -> Value {
    let lim = &m.lim;
    json!({
        "threads": 1,
        "navigator_kernels": gman_host_sim::simd::host_kernels_name(),
        "kernels": kernel_json(m),
        "k": K,
        "limits": {
            "copy_gbs": lim.copy_gbs, "copy_mib": m.stream_mib,
            "read_gbs": lim.read_gbs, "read_l3_8mib_gbs": lim.read_l3_gbs,
            "peak_muladd_gflops": lim.peak_muladd_gflops,
            "peak_muladd_avx2_gflops": lim.peak_muladd_avx2_gflops,
            "peak_fma_avx2_gflops": lim.peak_fma_gflops,
        },
        "navigator": nav_json(m),
        "train": train::json(&m.train),
        "firmware_qemu": firmware_json(m),
        "elapsed_s": elapsed_s,
    })
}

fn print_limits(m: &Measured) {
    let lim = &m.lim;
    println!(
        "Machine limits (1 thread, this run): copy {:.1} GB/s ({} MiB arrays, read+write), \
         read {:.1} GB/s (DRAM), {:.1} GB/s (8 MiB, L3); peak f32 mul+add {:.1} GFLOP/s \
         (SSE2, the portable build's ISA), {} (AVX2 without FMA, the AVX2 build's), peak FMA {} \
         (AVX2+FMA)",
        lim.copy_gbs,
        m.stream_mib,
        lim.read_gbs,
        lim.read_l3_gbs,
        lim.peak_muladd_gflops,
        lim.peak_muladd_avx2_gflops
            .map_or("n/a".to_string(), |g| format!("{g:.1} GFLOP/s")),
        lim.peak_fma_gflops
            .map_or("n/a".to_string(), |g| format!("{g:.1} GFLOP/s")),
    );
}

fn print_kernels(m: &Measured) {
    println!(
        "| kernel (512 x 256, cache-resident) | weights | kernels | time (best) | GFLOP/s | % mul+add peak of that ISA |"
    );
    println!("|---|---|---|---:|---:|---:|");
    for r in &m.kernels {
        let g = 2.0 * r.macs as f64 / r.secs / 1e9;
        println!(
            "| {} | {} | {} | {} | {:.1} | {} |",
            r.what,
            r.quant,
            r.kernels,
            us(r.secs),
            g,
            pct(g / m.lim.peak_for(r.kernels)),
        );
    }
}

fn print_navigator(m: &Measured) {
    let lim = &m.lim;
    let fma = lim.peak_fma_gflops.unwrap_or(f64::NAN);
    println!(
        "Navigator rows below use the {} kernels (`GMAN_KERNELS=portable` selects the portable build; same bits).",
        gman_host_sim::simd::host_kernels_name()
    );
    println!();
    println!(
        "| preset | weights | mode | step (median) | adaptation k=20 (median) | adapt/step | \
         MAC/step | GFLOP/s | % mul+add peak | % FMA peak | weight MB/step | GB/s | % copy BW |"
    );
    println!("|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for r in &m.nav {
        let (gflops, gbs) = (r.gflops(), r.gbs());
        println!(
            "| {} | {} | {} | {} | {} | {:.0} | {} | {:.2} | {} | {} | {:.2} | {:.2} | {} |",
            r.preset,
            r.quant,
            r.mode,
            us(r.step_s),
            us(r.adapt_s),
            r.adapt_s / r.step_s,
            r.macs,
            gflops,
            pct(gflops / lim.peak_muladd_gflops),
            pct(gflops / fma),
            r.weight_bytes as f64 / 1e6,
            gbs,
            pct(gbs / lim.copy_gbs),
        );
    }
    print_firmware_row(m);
}

fn print_firmware_row(m: &Measured) {
    match &m.firmware {
        Some(f) => println!(
            "| firmware M4F (QEMU) | {} | Efficient | {:.0} instr ≈ {:.1} ms @{:.0} MHz | {:.1} M instr ≈ {:.0} ms | {:.0} | {} | {:.1} instr/MAC | | | | | |",
            f.quant_label(),
            f.step_instr,
            f.step_instr / f.mhz / 1e3,
            f.mhz,
            f.adapt_instr / 1e6,
            f.adapt_instr / f.mhz / 1e3,
            f.adapt_instr / f.step_instr,
            f.macs,
            f.step_instr / f.macs,
        ),
        None => println!(
            "| firmware M4F (QEMU) | int8 | Efficient | not measured: no {} (written by `cargo test --release -p gman-tests --test firmware_qemu`) | | | {} | | | | | | |",
            m.firmware_log,
            Dims::MCU.macs_per_step(),
        ),
    }
}

/// The Markdown tables.
pub fn print(m: &Measured, elapsed_s: f64) {
    print_limits(m);
    println!();
    print_kernels(m);
    println!();
    print_navigator(m);
    train::print_table(&m.train);
    println!();
    let fw = match &m.firmware {
        Some(f) => format!("firmware row from the firmware's output in {}", f.source),
        None => "no firmware row".to_string(),
    };
    println!(
        "(1 thread for the navigator rows; medians of {} repetitions; {fw}; total {:.0} s)",
        m.reps, elapsed_s
    );
}
