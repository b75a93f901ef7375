//! Network sizes: the [`Dims`] of a model and the two named presets.
//!
//! Sizes are compile-time constants: a preset is a type implementing [`Preset`] whose
//! [`Preset::DIMS`] is a `const`, and every buffer the core needs has a length given by a
//! `const fn` of those dims (see [`crate::memory`]), so a firmware can declare its storage
//! statically, e.g. `static mut`-free with `[f32; gman_core::memory::arena_len(&Mcu::DIMS, ..)]`.
//! Declaring another size takes a few lines:
//!
//! ```
//! use gman_core::preset::{Dims, Preset};
//! /// A smaller model for a Cortex-M0+ class part.
//! pub struct Tiny;
//! impl Preset for Tiny {
//!     const DIMS: Dims = Dims { gen_hidden: 64, disc_hidden: 32, lstm_hidden: 32, embed: 32, ..Dims::MCU };
//! }
//! assert_eq!(Tiny::DIMS.feat, 512);
//! ```

use crate::NUM_ACTIONS;

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

    /// Number of map cells `map_rows * map_cols` (0: no map).
    pub const fn map_cells(&self) -> usize {
        self.map_rows * self.map_cols
    }

    /// Floats of one spatial observation: `map_cells * feat`, cell-major (cell `c`'s
    /// embedding is `map[c * feat..(c + 1) * feat]`, cells in row-major order, row 0 at the
    /// top of the view, column 0 at the left).
    pub const fn map_len(&self) -> usize {
        self.map_cells() * self.feat
    }

    /// Outputs of the per-cell layer over the whole map, `map_cells * cell_embed`.
    pub const fn cell_out(&self) -> usize {
        self.map_cells() * self.cell_embed
    }

    /// Input width of the per-cell layer: a cell's embedding and its element-wise product
    /// with x_t, `2 feat`.
    pub const fn cell_in(&self) -> usize {
        2 * self.feat
    }

    /// Parameters of the per-cell layer (0 without a map).
    pub const fn cell_params(&self) -> usize {
        if self.map_cells() == 0 {
            0
        } else {
            self.cell_embed * self.cell_in() + self.cell_embed
        }
    }

    /// Input width of G: `noise + attr`.
    pub const fn gen_in(&self) -> usize {
        self.noise + self.attr
    }

    /// Input width of the fusion layer: observation, generated feature, their element-wise
    /// product, attribute vector, previous action probabilities, PS input and the per-cell
    /// layer's outputs over the map.
    pub const fn fuse_in(&self) -> usize {
        3 * self.feat + self.attr + NUM_ACTIONS + self.ps + self.cell_out()
    }

    /// Number of parameters of G (θ).
    pub const fn gen_params(&self) -> usize {
        self.gen_hidden * self.gen_in() + self.gen_hidden + self.feat * self.gen_hidden + self.feat
    }

    /// Number of parameters of D (ω).
    pub const fn disc_params(&self) -> usize {
        self.disc_hidden * self.feat + 2 * self.disc_hidden + 1
    }

    /// Number of parameters of the policy (φ).
    pub const fn policy_params(&self) -> usize {
        let e = self.embed;
        let h = self.lstm_hidden;
        e * self.fuse_in()
            + e
            + 4 * h * e
            + 4 * h * h
            + 4 * h
            + NUM_ACTIONS * h
            + NUM_ACTIONS
            + h
            + 1
            + self.cell_params()
    }

    /// Multiply-accumulates of one navigation step: G, fusion, LSTM and heads (D only runs
    /// in the inner update).
    pub const fn macs_per_step(&self) -> usize {
        self.gen_hidden * self.gen_in()
            + self.feat * self.gen_hidden
            + self.embed * self.fuse_in()
            + 4 * self.lstm_hidden * (self.embed + self.lstm_hidden)
            + (NUM_ACTIONS + 1) * self.lstm_hidden
            + self.map_cells() * self.cell_embed * self.cell_in()
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
