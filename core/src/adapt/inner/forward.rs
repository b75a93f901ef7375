//! G's batched forward pass: the features of Ψ's entries ([`generate`], [`generate_mix`]) and
//! its hidden layer for the backward pass.

use crate::adapt::inner::work::{head, rows, InnerWork};
use crate::error::{check_len, Result};
use crate::nets::generator::Generator;
use crate::nn::activation::{leaky_relu_inplace, sigmoid_inplace};

/// `x_t = G(z_t, attr)` for the `n` noise vectors `zs` (`n x Z`) into `xs` (`n x F`),
/// `w.b` entries at a time.
pub fn generate(
    gen: &Generator<'_>,
    zs: &[f32],
    attr: &[f32],
    xs: &mut [f32],
    w: &mut InnerWork<'_>,
) -> Result<()> {
    w.check()?;
    gen.validate()?;
    let (zd, h, f) = (
        gen.in_dim().saturating_sub(attr.len()),
        gen.hidden(),
        gen.feat(),
    );
    check_len("generator.z+attr", gen.in_dim(), zd + attr.len())?;
    let n = xs.len() / f.max(1);
    check_len("inner.xs", n * f, xs.len())?;
    check_len("inner.zs", n * zd, zs.len())?;
    if w.b > 1 {
        w.fill_attr(attr)?;
    }
    let mut t0 = 0;
    while t0 < n {
        let nb = w.b.min(n - t0);
        let z = rows(zs, zd, t0, nb)?;
        with_rows(w, nb, (Some(z), attr, zd), |w, r| gen_hidden(gen, r, nb, w))?;
        let x = &mut xs[t0 * f..(t0 + nb) * f];
        gen.l2
            .forward_batch(&[head(w.h1, nb * h)], &[h], nb, head(w.u2, nb * f), x)?;
        sigmoid_inplace(x);
        t0 += nb;
    }
    Ok(())
}

/// G's forward pass for the `nb` noise rows `z` (`nb x Z`) with SE(y) `attr` into the first
/// `nb x F` floats of `w.mix`: the x_t of a batch of Ψ's entries, the bits [`generate`]
/// gives them (the pass L_ad's scores and L_D's pass run when Ψ holds no x_t). For
/// `1 <= nb <= w.b` (its callers' batches).
pub(crate) fn generate_mix(
    gen: &Generator<'_>,
    z: &[f32],
    attr: &[f32],
    nb: usize,
    w: &mut InnerWork<'_>,
) -> Result<()> {
    if w.b > 1 {
        w.fill_attr(attr)?;
    }
    // (`z`'s length is checked by G's first layer.)
    let zd = gen.in_dim().saturating_sub(attr.len());
    with_rows(w, nb, (Some(z), attr, zd), |w, r| {
        gen_forward_mix(gen, r, nb, w)
    })
}

/// G's first layer for `nb` rows: noise `z` (`nb x Z`) and attribute rows `ar` (`nb x A`)
/// into `w.u1`, `w.h1` (after the LeakyReLU).
pub(super) fn gen_hidden(
    gen: &Generator<'_>,
    (z, ar): (&[f32], &[f32]),
    nb: usize,
    w: &mut InnerWork<'_>,
) -> Result<()> {
    let h = gen.hidden();
    let (zd, a) = (z.len() / nb.max(1), ar.len() / nb.max(1));
    let hb = head(w.h1, nb * h);
    gen.l1
        .forward_batch(&[z, ar], &[zd, a], nb, head(w.u1, nb * h), hb)?;
    leaky_relu_inplace(hb);
    Ok(())
}

/// G's forward pass for `nb` rows (see [`gen_hidden`]); the features go to `w.mix`.
pub(super) fn gen_forward_mix(
    gen: &Generator<'_>,
    rows: (&[f32], &[f32]),
    nb: usize,
    w: &mut InnerWork<'_>,
) -> Result<()> {
    let (h, f) = (gen.hidden(), gen.feat());
    gen_hidden(gen, rows, nb, w)?;
    check_len("inner.mix", w.b * f, w.mix.len())?;
    let x = &mut w.mix[..nb * f];
    gen.l2
        .forward_batch(&[head(w.h1, nb * h)], &[h], nb, head(w.u2, nb * f), x)?;
    sigmoid_inplace(x);
    Ok(())
}

/// Runs `body` with the noise and attribute rows of a batch of `nb` rows: the noise rows
/// `z` when given (`nb x Z`), else `w.z` (filled by the caller); for one row the caller's
/// `attr` (no copy: the batch-1 buffers have no room for it), else `w.attr`.
pub(super) fn with_rows<R>(
    w: &mut InnerWork<'_>,
    nb: usize,
    (z, attr, zd): (Option<&[f32]>, &[f32], usize),
    body: impl FnOnce(&mut InnerWork<'_>, (&[f32], &[f32])) -> Result<R>,
) -> Result<R> {
    if let (Some(z), 1) = (z, nb) {
        return body(w, (z, attr));
    }
    let (wz, war) = (core::mem::take(&mut w.z), core::mem::take(&mut w.attr));
    let a = attr.len();
    let zr = match z {
        Some(z) => Some(z),
        None => wz.get(..nb * zd),
    };
    let ar = if nb == 1 {
        Some(attr)
    } else {
        war.get(..nb * a)
    };
    let r = match (zr, ar) {
        (Some(zr), Some(ar)) => body(w, (zr, ar)),
        _ => Err(crate::Error::Shape(crate::ShapeError {
            what: "inner.rows",
            expected: nb * (zd + a),
            actual: wz.len() + war.len(),
        })),
    };
    w.z = wz;
    w.attr = war;
    r
}
