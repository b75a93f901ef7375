//! The carve of a navigator's arena into its RAM regions, in the order of
//! [`crate::navigator::memory`]'s arena table.

use crate::adapt::inner::InnerWorkOf;
use crate::error::Result;
use crate::navigator::memory::{
    arena_table, first, region_lens, AdaptMode, Footprint, NUM_REGIONS,
};
use crate::navigator::weights::{LayerGrad, LayerRam, ARENA_TOO_SMALL};
use crate::spec::preset::Dims;

/// A region of the arena as the carve splits it: a mutable or a shared slice.
pub(super) trait Piece: Default {
    fn len(&self) -> usize;
    fn split(self, n: usize) -> (Self, Self);
}

impl Piece for &mut [f32] {
    fn len(&self) -> usize {
        <[f32]>::len(self)
    }
    fn split(self, n: usize) -> (Self, Self) {
        self.split_at_mut(n)
    }
}

impl Piece for &[f32] {
    fn len(&self) -> usize {
        <[f32]>::len(self)
    }
    fn split(self, n: usize) -> (Self, Self) {
        self.split_at(n)
    }
}

/// A group of regions of the arena table (a struct of the `Ram`), told the mode and the
/// inner update's batch after the carve.
pub(super) trait Group {
    fn finish(&mut self, _full: bool, _b: usize) {}
}

impl<T> Group for LayerRam<T> {}

impl<T> Group for LayerGrad<T> {
    fn finish(&mut self, full: bool, _b: usize) {
        self.full = full;
    }
}

impl<T> Group for InnerWorkOf<T> {
    fn finish(&mut self, _full: bool, b: usize) {
        self.b = b;
    }
}

/// The type of a field of the `Ram`: a region (`T`) or a group of regions (`Kind<T>`).
macro_rules! ram_field {
    ($t:ident) => { $t };
    ($t:ident, $kind:ident) => { $kind<$t> };
}

/// Generates, from the arena table ([`crate::navigator::memory`]'s `arena_table`), the `Ram` struct
/// (one field per region or group of regions, in table order) and its carve.
macro_rules! arena_ram {
    (|$d:ident, $full:ident, $g:ident, $k:ident, $b:ident, $map:ident, $gen_in:ident, $fast:ident, $min:ident, $zero:ident|
     $($field:ident $(: $kind:ident)? in $part:ident
        $({ $($sub:ident = $sl:expr;)* })? $(= $len:expr;)?)*) => {
        /// All RAM regions of the navigator, carved from its arena: `T` is `&mut [f32]`, or
        /// `&[f32]` for a read-only view.
        pub(super) struct Ram<T> {
            $(pub(super) $field: ram_field!(T $(, $kind)?),)*
        }

        impl<T: Default> Default for Ram<T> {
            fn default() -> Self {
                Ram { $($field: Default::default(),)* }
            }
        }

        impl<T: Piece> Ram<T> {
            /// Carves the regions of lengths `lens` (the arena table's, in its order) from
            /// `arena`; returns them, what is left of `arena`, and whether it was too short
            /// (then the regions that did not fit are empty).
            pub(super) fn carve_lens(
                arena: T,
                lens: &[usize; NUM_REGIONS],
                full: bool,
                b: usize,
            ) -> (Self, T, bool) {
                let mut rest = arena;
                let mut short = false;
                // The regions in table order (one loop, so that the code stays small), then
                // each to its field.
                let mut parts: [T; NUM_REGIONS] = core::array::from_fn(|i| {
                    let r = core::mem::take(&mut rest);
                    if r.len() < lens[i] {
                        short = true;
                        return T::default();
                    }
                    let (a, tail) = r.split(lens[i]);
                    rest = tail;
                    a
                });
                let mut i = 0;
                let mut next = || {
                    let p = core::mem::take(&mut parts[i]);
                    i += 1;
                    p
                };
                let mut ram = Ram::<T>::default();
                $(
                    $($(ram.$field.$sub = next();)*)?
                    $(first!({ ram.$field = next(); }, $len);)?
                )*
                $($(first!(Group::finish(&mut ram.$field, full, b), $kind);)?)*
                (ram, rest, short)
            }
        }
    };
}

arena_table!(arena_ram);

/// The lengths of the regions of [`crate::navigator::memory`]'s arena table for `d`, `mode`, `k`,
/// `fp` and zero noise or not, checked against `arena` (too short: an error); returns them and the floats used.
pub(super) fn carve_check(
    arena: &mut [f32],
    d: &Dims,
    mode: AdaptMode,
    k: usize,
    (fp, zero): (Footprint, bool),
) -> Result<([usize; NUM_REGIONS], usize)> {
    let total = arena.len();
    let lens = region_lens(d, mode, k, fp, zero).ok_or(ARENA_TOO_SMALL)?;
    let (_, rest, short) = Ram::carve_lens(arena, &lens, mode == AdaptMode::Full, 1);
    if short {
        return Err(ARENA_TOO_SMALL);
    }
    Ok((lens, total - rest.len()))
}

/// The navigator's arena: its storage and the lengths of the table's regions in it, carved
/// into the `Ram` on every access (the storage may be owned, so the navigator keeps no
/// slices into it).
pub(super) struct Arena<S> {
    pub(super) store: S,
    pub(super) lens: [usize; NUM_REGIONS],
    /// Full mode (the gradients are full weight gradients).
    pub(super) full: bool,
    /// Entries of Ψ per batch of the inner update (at least 1).
    pub(super) b: usize,
}

impl<S: AsRef<[f32]> + AsMut<[f32]>> Arena<S> {
    /// The regions, writable. Not inlined: one copy of the carve in the image.
    #[inline(never)]
    pub(super) fn ram(&mut self) -> Ram<&mut [f32]> {
        Ram::carve_lens(self.store.as_mut(), &self.lens, self.full, self.b).0
    }

    /// The regions, read-only. Not inlined, as [`Arena::ram`].
    #[inline(never)]
    pub(super) fn view(&self) -> Ram<&[f32]> {
        Ram::carve_lens(self.store.as_ref(), &self.lens, self.full, self.b).0
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::navigator::memory::arena_len_with;
    use crate::spec::schema::NoiseMode;
    use std::vec;

    #[test]
    fn carve_uses_exactly_the_documented_layout() {
        for d in [Dims::MCU, Dims::MCU.with_ps(), Dims::PAPER] {
            for mode in [AdaptMode::Full, AdaptMode::Efficient] {
                for (k, fp) in [1usize, 20]
                    .into_iter()
                    .flat_map(|k| [(k, Footprint::Compact), (k, Footprint::Fast)])
                {
                    let n = crate::navigator::memory::arena_len_noise(
                        &d,
                        mode,
                        k,
                        fp,
                        NoiseMode::Gaussian,
                    );
                    assert!(n <= arena_len_with(&d, mode, k, fp));
                    let mut arena = vec![0.0f32; n + 7];
                    let base = arena.as_ptr() as usize;
                    let (lens, used) = carve_check(&mut arena, &d, mode, k, (fp, false)).unwrap();
                    let full = mode == AdaptMode::Full;
                    let (ram, _, short) = Ram::carve_lens(&mut arena[..], &lens, full, 1);
                    assert!(!short);
                    assert_eq!(used, n, "{d:?} {mode:?} k={k} {fp:?}");
                    // Ψ follows the parameters and gradients; the step's work ends the arena.
                    let l = crate::navigator::memory::NavLayout::new_with(&d, mode, k, fp);
                    let at = |s: &[f32]| (s.as_ptr() as usize - base) / 4;
                    let params = l.gen_params + l.disc_params + l.actor_params;
                    assert_eq!(at(ram.psi_s), params + l.fixed_biases + l.grads);
                    assert_eq!(at(ram.gen1.w), 0);
                    assert_eq!(at(ram.cell_prod) + ram.cell_prod.len(), n);
                    let mut small = vec![0.0f32; n - 1];
                    assert!(carve_check(&mut small, &d, mode, k, (fp, false)).is_err());
                }
            }
        }
    }
}
