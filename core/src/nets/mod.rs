//! The three networks of GMAN: the feature generator G ([`generator`]), the discriminator D
//! ([`discriminator`]) and the LSTM actor-critic navigation policy π ([`policy`]).

pub mod discriminator;
pub mod generator;
pub mod policy;
