//! Navigation models: the methods of the paper's tables and their parameters, what a
//! checkpoint or blob holds of them, and what every episode of a model does first
//! ([`episode`]: the navigator started on a target, the PS input, the map grid), in training
//! ([`crate::train`]) and in evaluation ([`crate::eval`]) alike.
//!
//! This folder imports neither: training and evaluation build on it.
pub mod episode;
mod load;
mod method;
mod nav_model;
mod record;

pub use gman_core::spec::{InnerRule, ModelSpec, Named};
pub use load::{load_model, load_model_with_ps, model_from_blob};
pub use method::{InnerLoop, Method};
#[cfg(test)]
pub(crate) use nav_model::host_arena_len;
pub use nav_model::{NavModel, K};
pub use record::{DimsMeta, ModelMeta};
