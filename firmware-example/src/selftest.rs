//! The computation the firmware runs, shared verbatim with the host-side parity test
//! (`tests/tests/firmware_qemu.rs` includes this file), so x86 and Cortex-M4F execute the same
//! source on the same blob and must print the same bits.
//!
//! It parses and validates the `Mcu` int8 blob in place, generates target features
//! x = G(SE(y), z) for a few seeded noise draws in the parameter-efficient mode (int8 base
//! weights, per-unit gains and biases in RAM), scores them with D, and takes one closed-form
//! gradient of the WGAN-GP loss L_D (Eq. 1) against synthetic observations.

use gman_core::blob::{Blob, TensorId};
use gman_core::nets::discriminator::{DiscGrads, DiscScratch, Discriminator, LdConfig};
use gman_core::nets::generator::{Generator, GeneratorCache};
use gman_core::nn::dense::{Dense, DenseGrads};
use gman_core::rng::{fill_gaussian, uniform, Xoshiro128};
use gman_core::Dims;

/// The firmware's model ([`crate::episode::DIMS`]: `Mcu` with the 3 x 3 map).
const D: Dims = crate::episode::DIMS;
const K: usize = 4;
const H: usize = D.gen_hidden;
const F: usize = D.feat;
const DH: usize = D.disc_hidden;
/// Floats of scratch [`run`] needs: K generated and K synthetic observation features.
pub const SCRATCH_LEN: usize = 2 * K * F;

/// Runs the self-test on `blob`, reporting each result line through `out`: G, D and L_D,
/// then, for a blob with int8 activations and a gman-core with the integer path, the integer
/// kernels (two frames one after the other, not nested, for the stack; an image without the
/// integer path compiles that part out).
///
/// `scratch` holds the self-test's sample buffers (at least [`SCRATCH_LEN`] floats): the
/// firmware lends it the navigator's arena, which is not in use yet, so that the self-test's
/// stack stays below the navigator's.
pub fn run(
    blob_bytes: &[u8],
    scratch: &mut [f32],
    out: &mut dyn FnMut(core::fmt::Arguments<'_>),
) -> gman_core::Result<()> {
    networks(blob_bytes, scratch, out)?;
    let blob = Blob::parse(blob_bytes)?;
    let act8 = blob.header().flags() & gman_core::spec::schema::FLAG_INT8_ACTIVATIONS != 0;
    if gman_core::nn::qkernel::INT8_ACTIVATIONS && act8 {
        int8_kernels(&blob, out)?;
    }
    Ok(())
}

#[inline(never)]
fn networks(
    blob_bytes: &[u8],
    scratch: &mut [f32],
    out: &mut dyn FnMut(core::fmt::Arguments<'_>),
) -> gman_core::Result<()> {
    let have = scratch.len();
    let (fake, real) = scratch
        .get_mut(..SCRATCH_LEN)
        .ok_or(gman_core::ShapeError {
            what: "self-test scratch",
            expected: SCRATCH_LEN,
            actual: have,
        })?
        .split_at_mut(K * F);
    fake.fill(0.0);
    real.fill(0.0);
    let blob = Blob::parse(blob_bytes)?;
    blob.check_dims(&D)?;
    out(format_args!(
        "blob: {} bytes, {} tensors",
        blob.len(),
        blob.tensors().count()
    ));

    // Adapted parameters in RAM (Efficient mode): gains start at 1, biases from the blob.
    let mut gain1 = [1.0f32; H];
    let mut b1 = [0.0f32; H];
    let mut gain2 = [1.0f32; F];
    let mut b2 = [0.0f32; F];
    blob.copy_f32(TensorId::GenB1, &mut b1)?;
    blob.copy_f32(TensorId::GenB2, &mut b2)?;
    gain1[0] = 1.0;
    gain2[0] = 1.0;
    let gen = Generator {
        l1: Dense {
            w: blob.matrix(TensorId::GenW1)?,
            b: &b1,
            gain: Some(&gain1),
        },
        l2: Dense {
            w: blob.matrix(TensorId::GenW2)?,
            b: &b2,
            gain: Some(&gain2),
        },
    };
    let mut dgain = [1.0f32; DH];
    let mut db1 = [0.0f32; DH];
    let mut dw2 = [0.0f32; DH];
    let mut db2 = [0.0f32; 1];
    blob.copy_f32(TensorId::DiscB1, &mut db1)?;
    blob.copy_f32(TensorId::DiscW2, &mut dw2)?;
    blob.copy_f32(TensorId::DiscB2, &mut db2)?;
    dgain[0] = 1.0;
    let disc = Discriminator {
        l1: Dense {
            w: blob.matrix(TensorId::DiscW1)?,
            b: &db1,
            gain: Some(&dgain),
        },
        w2: &dw2,
        b2: db2[0],
    };

    let mut rng = Xoshiro128::seed_from_u64(7);
    let mut ds = DiscBuffers::ZERO;
    generate_and_score(&gen, &disc, fake, &mut rng, &mut ds, out)?;
    for (i, v) in real.iter_mut().enumerate() {
        // Synthetic observation features in [0, 1): a fixed, deterministic pattern.
        *v = ((i * 37) % 101) as f32 / 101.0;
    }
    ld_gradient(&disc, real, fake, &mut rng, &mut ds, out)
}

/// D's scratch buffers, shared by the scoring and the gradient of L_D.
struct DiscBuffers {
    u: [f32; DH],
    h: [f32; DH],
    v: [f32; DH],
    w1g: [f32; DH],
    g: [f32; F],
    mix: [f32; F],
}

impl DiscBuffers {
    const ZERO: DiscBuffers = DiscBuffers {
        u: [0.0; DH],
        h: [0.0; DH],
        v: [0.0; DH],
        w1g: [0.0; DH],
        g: [0.0; F],
        mix: [0.0; F],
    };

    fn scratch(&mut self) -> DiscScratch<'_> {
        DiscScratch {
            u: &mut self.u,
            h: &mut self.h,
            v: &mut self.v,
            w1g: &mut self.w1g,
            g: &mut self.g,
            mix: &mut self.mix,
        }
    }
}

/// G on `K` seeded noise draws into `fake`, each scored by D; one line per draw.
fn generate_and_score(
    gen: &Generator<'_>,
    disc: &Discriminator<'_>,
    fake: &mut [f32],
    rng: &mut Xoshiro128,
    ds: &mut DiscBuffers,
    out: &mut dyn FnMut(core::fmt::Arguments<'_>),
) -> gman_core::Result<()> {
    let attr = [0.25f32; D.attr];
    let (mut u1, mut h1, mut u2, mut x) = ([0.0f32; H], [0.0f32; H], [0.0f32; F], [0.0f32; F]);
    for t in 0..K {
        let mut z = [0.0f32; D.noise];
        fill_gaussian(rng, &mut z);
        let mut cache = GeneratorCache {
            u1: &mut u1,
            h1: &mut h1,
            u2: &mut u2,
            x: &mut x,
        };
        gen.forward(&z, &attr, &mut cache)?;
        fake[t * F..(t + 1) * F].copy_from_slice(&x);
        let score = disc.score(&x, &mut ds.scratch())?;
        out(format_args!(
            "x[{}]: x0={:#010x} D(x)={:#010x}",
            t,
            x[0].to_bits(),
            score.to_bits()
        ));
    }
    Ok(())
}

/// One closed-form gradient of L_D (Eq. 1) on `real` against `fake`; one line.
fn ld_gradient(
    disc: &Discriminator<'_>,
    real: &[f32],
    fake: &[f32],
    rng: &mut Xoshiro128,
    ds: &mut DiscBuffers,
    out: &mut dyn FnMut(core::fmt::Arguments<'_>),
) -> gman_core::Result<()> {
    let eps = [uniform(rng), uniform(rng), uniform(rng), uniform(rng)];
    let (mut g_gain, mut g_b1, mut g_w2, mut g_b2) =
        ([0.0f32; DH], [0.0f32; DH], [0.0f32; DH], 0.0f32);
    let mut grads = DiscGrads {
        l1: DenseGrads::Gain {
            gain: &mut g_gain,
            b: &mut g_b1,
        },
        w2: &mut g_w2,
        b2: &mut g_b2,
    };
    let ld = disc.ld_loss(
        real,
        fake,
        &eps,
        LdConfig::default(),
        &mut ds.scratch(),
        Some(&mut grads),
    )?;
    out(format_args!(
        "L_D={:#010x} penalty={:#010x} dgain0={:#010x} dw2_0={:#010x}",
        ld.loss.to_bits(),
        ld.penalty.to_bits(),
        g_gain[0].to_bits(),
        g_w2[0].to_bits()
    ));
    Ok(())
}

/// The integer kernels of the int8-activation path on the blob's G layer-2 weights
/// (512 x 256 int8): the Cortex-M4F's `SXTB16` / `SMLAD` kernel (`qkernel::dots_i8_dsp`; on
/// the host, its plain-Rust model) against the portable one, integer for integer, on input
/// blocks of every awkward length and offset (odd columns, unaligned rows, odd row counts,
/// the extremes ±127); then the whole driver, bit for bit. A mismatch is an error; the
/// checksum line is compared with the host's.
#[inline(never)]
fn int8_kernels(
    blob: &Blob<'_>,
    out: &mut dyn FnMut(core::fmt::Arguments<'_>),
) -> gman_core::Result<()> {
    use gman_core::nn::matrix::Weights;
    use gman_core::nn::qkernel::{self, QCOLS, QWORDS};
    let w = blob.matrix(TensorId::GenW2)?;
    let Weights::I8 { q, .. } = w.weights() else {
        return Err(gman_core::Error::Config {
            what: "self-test: G's layer 2 is not int8",
        });
    };
    let cols = w.cols();
    let mut lcg = 0x2545_f491u32;
    let mut next = move || {
        lcg = lcg.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        lcg >> 8
    };
    let (mut cases, mut sum) = (0u32, 0u32);
    for &(rows, col0, len) in &[
        (1usize, 0usize, 1usize),
        (2, 0, 8),
        (3, 1, 5),
        (7, 3, 45),
        (8, 0, 256),
        (13, 77, 179),
        (64, 0, 256),
        (64, 5, 200),
        (33, 250, 6),
        (17, 128, 128),
    ] {
        let mut xq = [0i8; QCOLS];
        for v in &mut xq[..len] {
            *v = (next() % 255) as i8;
        }
        xq[0] = -127;
        xq[len - 1] = 127;
        let mut xp = [0u32; QWORDS];
        let packed = qkernel::pack_dsp(&xq[..len], &mut xp);
        let qr = &q[..rows * cols];
        let (mut a, mut b) = ([0i32; 64], [0i32; 64]);
        qkernel::dots_i8(qr, cols, col0, &xq[..len], &mut a[..rows]);
        qkernel::dots_i8_dsp(
            qr,
            cols,
            col0,
            &xq[..len],
            &xp[..packed / 2],
            &mut b[..rows],
        );
        if a[..rows] != b[..rows] {
            return Err(gman_core::Error::Config {
                what: "self-test: the DSP int8 kernel differs from the portable one",
            });
        }
        for v in &b[..rows] {
            sum = sum.rotate_left(5) ^ (*v as u32);
        }
        cases += 1;
    }
    // The driver: y += W x on three segments, one with negative values.
    let mut x = [0.0f32; 256];
    for (i, v) in x.iter_mut().enumerate() {
        *v = ((i * 53) % 97) as f32 / 97.0 - if i >= 200 { 0.5 } else { 0.0 };
    }
    let segs: [&[f32]; 3] = [&x[..45], &x[45..200], &x[200..]];
    let (mut yp, mut yd) = ([0.0f32; 512], [0.0f32; 512]);
    qkernel::matvec_acc_int8_portable(&w, &segs, &mut yp)?;
    qkernel::matvec_acc_int8_dsp(&w, &segs, &mut yd)?;
    if yp.map(f32::to_bits) != yd.map(f32::to_bits) {
        return Err(gman_core::Error::Config {
            what: "self-test: the DSP int8 driver differs from the portable one",
        });
    }
    out(format_args!(
        "int8 kernels: {} cases agree, checksum={:#010x}, y0={:#010x}",
        cases,
        sum,
        yd[0].to_bits()
    ));
    Ok(())
}
