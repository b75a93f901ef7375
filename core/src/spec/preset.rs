//! Network sizes: the [`Dims`] of a model and the two named presets.
//!
//! Sizes are compile-time constants: a preset is a type implementing [`Preset`] whose
//! [`Preset::DIMS`] is a `const`, and every buffer the core needs has a length given by a
//! `const fn` of those dims (see [`crate::navigator::memory`]), so a firmware can declare its storage
//! statically, e.g. `static mut`-free with `[f32; gman_core::navigator::memory::arena_len(&Mcu::DIMS, ..)]`.
//! Declaring another size takes a few lines:
//!
//! ```
//! use gman_core::spec::preset::{Dims, Preset};
//! /// A smaller model for a Cortex-M0+ class part.
//! pub struct Tiny;
//! impl Preset for Tiny {
//!     const DIMS: Dims = Dims { gen_hidden: 64, disc_hidden: 32, lstm_hidden: 32, embed: 32, ..Dims::MCU };
//! }
//! assert_eq!(Tiny::DIMS.feat, 512);
//! ```

use crate::NUM_ACTIONS;

/// Largest inner-loop rate (α1, α2) a blob, an encoder or
/// [`Navigator::new`](crate::navigator::Navigator::new) accepts. The paper's rates are 1e-4;
/// a rate above this makes every adaptation step diverge (and is what a flipped exponent bit
/// turns 0.01 into).
pub const MAX_INNER_RATE: f32 = 1.0;

/// `?` for `Option` in a `const fn`.
macro_rules! tri {
    ($e:expr) => {
        match $e {
            Some(v) => v,
            None => return None,
        }
    };
}
pub(crate) use tri;

/// Every size of the GMAN networks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Dims {
    /// Width of the semantic embedding SE(y) (attribute vector): 45.
    pub attr: usize,
    /// Width of the generator's noise z: 45.
    pub noise: usize,
    /// Hidden width of G.
    pub gen_hidden: usize,
    /// Width of observation embeddings s_t and generated features x_t: 512.
    pub feat: usize,
    /// Hidden width of D.
    pub disc_hidden: usize,
    /// Hidden width of the policy's LSTM cell.
    pub lstm_hidden: usize,
    /// Width of the fused input embedding fed to the LSTM.
    pub embed: usize,
    /// Width of the optional PS input (predicted semantic embedding of the view): 0 when the
    /// policy has no PS input, otherwise `attr`.
    pub ps: usize,
    /// Rows of the spatial observation map (the view split into `map_rows x map_cols`
    /// sectors, each a `feat`-wide embedding, like the reference's 7 x 7 ResNet map); 0 with
    /// `map_cols` 0: no map, the policy sees the pooled embedding only.
    pub map_rows: usize,
    /// Columns of the spatial observation map (0: no map).
    pub map_cols: usize,
    /// Channels of the shared per-cell layer (the reference's 1 x 1 convolution to 64)
    /// applied to every map cell; 0 without a map.
    pub cell_embed: usize,
}

impl Dims {
    /// The paper's sizes (Sec. 5.1 and the reference implementation): G 90 → 4096 → 512,
    /// D 512 → 1024 → 1, LSTM hidden 512.
    pub const PAPER: Dims = Dims {
        attr: 45,
        noise: 45,
        gen_hidden: 4096,
        feat: 512,
        disc_hidden: 1024,
        lstm_hidden: 512,
        embed: 512,
        ps: 0,
        map_rows: 0,
        map_cols: 0,
        cell_embed: 0,
    };

    /// Microcontroller sizes: G hidden 256, D hidden 64, LSTM hidden 64, same interfaces.
    pub const MCU: Dims = Dims {
        attr: 45,
        noise: 45,
        gen_hidden: 256,
        feat: 512,
        disc_hidden: 64,
        lstm_hidden: 64,
        embed: 64,
        ps: 0,
        map_rows: 0,
        map_cols: 0,
        cell_embed: 0,
    };

    /// The same sizes with a PS input of width `attr` (the "dagger" variants of the paper).
    pub const fn with_ps(self) -> Dims {
        Dims {
            ps: self.attr,
            ..self
        }
    }

    /// The same sizes with a spatial observation map of `rows x cols` cells and a per-cell
    /// layer of `cell_embed` channels (`(0, 0, 0)`: no map).
    pub const fn with_map(self, rows: usize, cols: usize, cell_embed: usize) -> Dims {
        Dims {
            map_rows: rows,
            map_cols: cols,
            cell_embed,
            ..self
        }
    }

    /// The first degenerate size, by field name, or `None` when every width a network needs
    /// is non-zero and the map is consistent: `attr`, `noise`, `gen_hidden`, `feat`,
    /// `disc_hidden`, `lstm_hidden` and `embed` must be at least 1; `map_rows` and
    /// `map_cols` are both 0 (no map) or both non-zero, and `cell_embed` is non-zero exactly
    /// when there is a map. Blobs, encoders and [`Navigator::new`](crate::navigator::Navigator::new)
    /// refuse dims for which this is `Some` (a zero width would make a layer empty and
    /// its kernels divide work into empty chunks).
    pub const fn degenerate_field(&self) -> Option<&'static str> {
        if self.attr == 0 {
            return Some("attr");
        }
        if self.noise == 0 {
            return Some("noise");
        }
        if self.gen_hidden == 0 {
            return Some("gen_hidden");
        }
        if self.feat == 0 {
            return Some("feat");
        }
        if self.disc_hidden == 0 {
            return Some("disc_hidden");
        }
        if self.lstm_hidden == 0 {
            return Some("lstm_hidden");
        }
        if self.embed == 0 {
            return Some("embed");
        }
        if self.map_rows == 0 && self.map_cols != 0 {
            return Some("map_rows");
        }
        if self.map_cols == 0 && self.map_rows != 0 {
            return Some("map_cols");
        }
        if (self.map_rows != 0) != (self.cell_embed != 0) {
            return Some("cell_embed");
        }
        None
    }

    /// Number of map cells `map_rows * map_cols` (0: no map; saturating).
    pub const fn map_cells(&self) -> usize {
        sat(self.map_rows.checked_mul(self.map_cols))
    }

    /// Floats of one spatial observation: `map_cells * feat`, cell-major (cell `c`'s
    /// embedding is `map[c * feat..(c + 1) * feat]`, cells in row-major order, row 0 at the
    /// top of the view, column 0 at the left).
    pub const fn map_len(&self) -> usize {
        sat(self.map_cells().checked_mul(self.feat))
    }

    /// Outputs of the per-cell layer over the whole map, `map_cells * cell_embed`.
    pub const fn cell_out(&self) -> usize {
        sat(self.checked_cell_out())
    }

    /// [`Dims::cell_out`], or `None` when it overflows `usize`.
    pub const fn checked_cell_out(&self) -> Option<usize> {
        tri!(self.map_rows.checked_mul(self.map_cols)).checked_mul(self.cell_embed)
    }

    /// Input width of the per-cell layer: a cell's embedding and its element-wise product
    /// with x_t, `2 feat`.
    pub const fn cell_in(&self) -> usize {
        sat(self.feat.checked_mul(2))
    }

    /// Parameters of the per-cell layer (0 without a map).
    pub const fn cell_params(&self) -> usize {
        sat(self.checked_cell_params())
    }

    /// [`Dims::cell_params`], or `None` when it overflows `usize`.
    pub const fn checked_cell_params(&self) -> Option<usize> {
        if tri!(self.map_rows.checked_mul(self.map_cols)) == 0 {
            return Some(0);
        }
        let w = tri!(self.cell_embed.checked_mul(tri!(self.feat.checked_mul(2))));
        w.checked_add(self.cell_embed)
    }

    /// Input width of G: `noise + attr` (saturates at `usize::MAX` when it does not fit, see
    /// [`Dims::checked_sizes`]).
    pub const fn gen_in(&self) -> usize {
        sat(self.checked_gen_in())
    }

    /// Input width of the fusion layer: observation, generated feature, their element-wise
    /// product, attribute vector, previous action probabilities, PS input and the per-cell
    /// layer's outputs over the map (saturating).
    pub const fn fuse_in(&self) -> usize {
        sat(self.checked_fuse_in())
    }

    /// Number of parameters of G (θ) (saturating).
    pub const fn gen_params(&self) -> usize {
        sat(self.checked_gen_params())
    }

    /// Number of parameters of D (ω) (saturating).
    pub const fn disc_params(&self) -> usize {
        sat(self.checked_disc_params())
    }

    /// Number of parameters of the policy (φ) (saturating).
    pub const fn policy_params(&self) -> usize {
        sat(self.checked_policy_params())
    }

    /// Multiply-accumulates of one navigation step: G, fusion, LSTM and heads (D only runs
    /// in the inner update) (saturating).
    pub const fn macs_per_step(&self) -> usize {
        sat(self.checked_macs_per_step())
    }

    /// [`Dims::gen_in`], or `None` when it overflows `usize`.
    pub const fn checked_gen_in(&self) -> Option<usize> {
        self.noise.checked_add(self.attr)
    }

    /// [`Dims::fuse_in`], or `None` when it overflows `usize`.
    pub const fn checked_fuse_in(&self) -> Option<usize> {
        let v = tri!(self.feat.checked_mul(3));
        let v = tri!(v.checked_add(self.attr));
        let v = tri!(v.checked_add(NUM_ACTIONS));
        let v = tri!(v.checked_add(self.ps));
        v.checked_add(tri!(self.checked_cell_out()))
    }

    /// [`Dims::gen_params`], or `None` when it overflows `usize`.
    pub const fn checked_gen_params(&self) -> Option<usize> {
        let a = tri!(self.gen_hidden.checked_mul(tri!(self.checked_gen_in())));
        let b = tri!(self.feat.checked_mul(self.gen_hidden));
        let v = tri!(a.checked_add(self.gen_hidden));
        let v = tri!(v.checked_add(b));
        v.checked_add(self.feat)
    }

    /// [`Dims::disc_params`], or `None` when it overflows `usize`.
    pub const fn checked_disc_params(&self) -> Option<usize> {
        let a = tri!(self.disc_hidden.checked_mul(self.feat));
        let b = tri!(self.disc_hidden.checked_mul(2));
        let v = tri!(a.checked_add(b));
        v.checked_add(1)
    }

    /// [`Dims::policy_params`], or `None` when it overflows `usize`.
    pub const fn checked_policy_params(&self) -> Option<usize> {
        let e = self.embed;
        let h4 = tri!(self.lstm_hidden.checked_mul(4));
        let mut v = tri!(e.checked_mul(tri!(self.checked_fuse_in())));
        v = tri!(v.checked_add(e));
        v = tri!(v.checked_add(tri!(h4.checked_mul(e))));
        v = tri!(v.checked_add(tri!(h4.checked_mul(self.lstm_hidden))));
        v = tri!(v.checked_add(h4));
        v = tri!(v.checked_add(tri!(self.lstm_hidden.checked_mul(NUM_ACTIONS))));
        v = tri!(v.checked_add(NUM_ACTIONS));
        v = tri!(v.checked_add(self.lstm_hidden));
        v = tri!(v.checked_add(1));
        v.checked_add(tri!(self.checked_cell_params()))
    }

    /// [`Dims::macs_per_step`], or `None` when it overflows `usize`.
    pub const fn checked_macs_per_step(&self) -> Option<usize> {
        let mut v = tri!(self.gen_hidden.checked_mul(tri!(self.checked_gen_in())));
        v = tri!(v.checked_add(tri!(self.feat.checked_mul(self.gen_hidden))));
        v = tri!(v.checked_add(tri!(self.embed.checked_mul(tri!(self.checked_fuse_in())))));
        let lstm_in = tri!(self.embed.checked_add(self.lstm_hidden));
        let h4 = tri!(self.lstm_hidden.checked_mul(4));
        v = tri!(v.checked_add(tri!(h4.checked_mul(lstm_in))));
        v = tri!(v.checked_add(tri!(self.lstm_hidden.checked_mul(NUM_ACTIONS + 1))));
        let cells = tri!(self.checked_cell_out());
        v.checked_add(tri!(cells.checked_mul(tri!(self.feat.checked_mul(2)))))
    }
}

/// The value, or `usize::MAX` for a size that does not fit (never wraps, never panics).
pub(crate) const fn sat(v: Option<usize>) -> usize {
    match v {
        Some(v) => v,
        None => usize::MAX,
    }
}

/// A named set of sizes, fixed at compile time.
pub trait Preset {
    /// The sizes.
    const DIMS: Dims;
    /// A short name (`"paper"`, `"mcu"`).
    const NAME: &'static str = "custom";
}

/// The paper's sizes, see [`Dims::PAPER`].
#[derive(Clone, Copy, Debug)]
pub struct Paper;
impl Preset for Paper {
    const DIMS: Dims = Dims::PAPER;
    const NAME: &'static str = "paper";
}

/// Microcontroller sizes, see [`Dims::MCU`].
#[derive(Clone, Copy, Debug)]
pub struct Mcu;
impl Preset for Mcu {
    const DIMS: Dims = Dims::MCU;
    const NAME: &'static str = "mcu";
}
