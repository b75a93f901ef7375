//! Times gman-core's blocked dense kernels for a few block shapes, compiled for AVX2 and for
//! AVX2 with AVX-512VL's 32 vector registers (same operations, same bits), on the layer
//! shapes of the `mcu` trainer. A measurement aid for `train/src/simd.rs`.
//!
//! ```sh
//! cargo run --release -p gman-host-sim --example kernel_shapes
//! ```

#[cfg(target_arch = "x86_64")]
mod x86 {
    use gman_core::nn::batch::{matmul_acc_blocked, outer_acc_batch_blocked};
    use gman_core::nn::matrix::MatRef;
    use std::time::Instant;

    macro_rules! mm {
        ($name:ident, $feat:literal, $r:literal, $b:literal) => {
            #[target_feature(enable = $feat)]
            unsafe fn $name(w: &MatRef<'_>, x: &[&[f32]], n: usize, y: &mut [f32]) {
                matmul_acc_blocked::<$r, $b>(w, x, n, y).unwrap();
            }
        };
    }
    macro_rules! op {
        ($name:ident, $feat:literal, $r:literal, $c:literal) => {
            #[target_feature(enable = $feat)]
            unsafe fn $name(dw: &mut [f32], dy: &[f32], x: &[&[f32]], n: usize) {
                outer_acc_batch_blocked::<$r, $c>(dw, dy, x, n, 1.0).unwrap();
            }
        };
    }
    /// `gman_host_sim::simd`'s AVX2 table (what the host runs).
    unsafe fn mm_host(w: &MatRef<'_>, x: &[&[f32]], n: usize, y: &mut [f32]) {
        let k = gman_host_sim::simd::avx2().expect("AVX2");
        let lens: Vec<usize> = x.iter().map(|s| s.len() / n).collect();
        gman_core::nn::batch::matmul_acc(&w.with_kernels(k), x, &lens, n, y).unwrap();
    }
    mm!(mm_a42, "avx2", 4, 2);
    mm!(mm_a24, "avx2", 2, 4);
    mm!(mm_a81, "avx2", 8, 1);
    mm!(mm_v42, "avx2,avx512f,avx512vl", 4, 2);
    mm!(mm_v44, "avx2,avx512f,avx512vl", 4, 4);
    mm!(mm_v24, "avx2,avx512f,avx512vl", 2, 4);
    mm!(mm_v46, "avx2,avx512f,avx512vl", 4, 6);
    mm!(mm_v63, "avx2,avx512f,avx512vl", 6, 3);
    mm!(mm_v83, "avx2,avx512f,avx512vl", 8, 3);
    op!(op_a24, "avx2", 2, 4);
    op!(op_a42, "avx2", 4, 2);
    op!(op_v24, "avx2,avx512f,avx512vl", 2, 4);
    op!(op_v44, "avx2,avx512f,avx512vl", 4, 4);
    op!(op_v28, "avx2,avx512f,avx512vl", 2, 8);
    op!(op_v48, "avx2,avx512f,avx512vl", 4, 3);

    fn randv(n: usize, s: u32) -> Vec<f32> {
        (0..n)
            .map(|i| {
                ((i as u32).wrapping_mul(2654435761).wrapping_add(s) >> 8) as f32 / 16777216.0 - 0.5
            })
            .collect()
    }

    type MmFn = unsafe fn(&MatRef<'_>, &[&[f32]], usize, &mut [f32]);
    type OpFn = unsafe fn(&mut [f32], &[f32], &[&[f32]], usize);

    pub fn main() {
        let vl = std::is_x86_feature_detected!("avx512vl");
        if !vl {
            println!("no AVX-512VL: the `vl` blocks are skipped");
        }
        // (name, rows, segment lengths, n)
        let mut shapes: Vec<(&str, usize, Vec<usize>, usize)> = Vec::new();
        for n in [1usize, 4, 16, 64] {
            shapes.push(("G l2 512x256", 512, vec![256], n));
            shapes.push(("G l1 256x(45+45)", 256, vec![45, 45], n));
            shapes.push(("fuse 64x(512x3+45+6)", 64, vec![512, 512, 512, 45, 6], n));
            shapes.push(("lstm 256x64", 256, vec![64], n));
        }
        let mms: [(&str, MmFn); 10] = [
            ("host", mm_host),
            ("avx2 4x2", mm_a42),
            ("avx2 2x4", mm_a24),
            ("avx2 8x1", mm_a81),
            ("vl 4x2", mm_v42),
            ("vl 4x4", mm_v44),
            ("vl 2x4", mm_v24),
            ("vl 4x6", mm_v46),
            ("vl 6x3", mm_v63),
            ("vl 8x3", mm_v83),
        ];
        let ops: [(&str, OpFn); 6] = [
            ("avx2 2x4", op_a24),
            ("avx2 4x2", op_a42),
            ("vl 2x4", op_v24),
            ("vl 4x4", op_v44),
            ("vl 2x8", op_v28),
            ("vl 4x3", op_v48),
        ];
        for (name, rows, lens, n) in &shapes {
            let cols: usize = lens.iter().sum();
            let wd = randv(rows * cols, 1);
            let w = MatRef::f32(*rows, cols, &wd).unwrap();
            let xs: Vec<Vec<f32>> = lens
                .iter()
                .enumerate()
                .map(|(i, l)| randv(l * n, 7 + i as u32))
                .collect();
            let x: Vec<&[f32]> = xs.iter().map(|v| &v[..]).collect();
            let macs = (rows * cols * n) as f64;
            let mut reference: Option<Vec<u32>> = None;
            for (k, f) in &mms {
                if !vl && k.starts_with("vl") {
                    continue;
                }
                let mut y = vec![0.0f32; rows * n];
                let reps = (4e7 / macs).ceil() as usize;
                let mut s = f64::INFINITY;
                for _ in 0..7 {
                    let t = Instant::now();
                    for _ in 0..reps {
                        y.fill(0.0);
                        unsafe { f(&w, &x, *n, &mut y) };
                    }
                    s = s.min(t.elapsed().as_secs_f64());
                }
                let bits: Vec<u32> = y.iter().map(|v| v.to_bits()).collect();
                let same = reference.get_or_insert_with(|| bits.clone()) == &bits;
                println!(
                    "matmul {name:24} n={n} {k:10} {:6.1} GMAC/s {}",
                    macs * reps as f64 / s / 1e9,
                    if same { "" } else { "DIFFERENT BITS" }
                );
            }
            let dy = randv(rows * n, 3);
            let mut reference: Option<Vec<u32>> = None;
            for (k, f) in &ops {
                if !vl && k.starts_with("vl") {
                    continue;
                }
                let mut dw = vec![0.0f32; rows * cols];
                let reps = (4e7 / macs).ceil() as usize;
                let mut s = f64::INFINITY;
                for _ in 0..7 {
                    let t = Instant::now();
                    for _ in 0..reps {
                        unsafe { f(&mut dw, &dy, &x, *n) };
                    }
                    s = s.min(t.elapsed().as_secs_f64());
                }
                dw.fill(0.0);
                unsafe { f(&mut dw, &dy, &x, *n) };
                let bits: Vec<u32> = dw.iter().map(|v| v.to_bits()).collect();
                let same = reference.get_or_insert_with(|| bits.clone()) == &bits;
                println!(
                    "outer  {name:24} n={n} {k:10} {:6.1} GMAC/s {}",
                    macs * reps as f64 / s / 1e9,
                    if same { "" } else { "DIFFERENT BITS" }
                );
            }
        }
    }
}

fn main() {
    #[cfg(target_arch = "x86_64")]
    x86::main();
}
