//! gman-render: the pictures of gman-rs, drawn with plotters. [`scene`] draws the top-down
//! map of a scene of the simulator (gman-sim) with an episode's path, to a PNG file
//! ([`draw_scene`]) or to RGB pixels ([`draw_scene_rgb`], the Python environment's video
//! frames); [`register_plot_font`] finds the font every plot of the `gman` command line
//! writes its labels in. The layer above the simulator for drawing only: the model, the
//! trainer and the command line are elsewhere (`ARCHITECTURE.md` draws the crates).

#![warn(missing_docs)]
#![forbid(unsafe_code)]

pub mod scene;

pub use scene::{draw_scene, draw_scene_rgb, register_plot_font};
