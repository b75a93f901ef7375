//! The `int8-activations` feature: with it a blob flagged
//! [`FLAG_INT8_ACTIVATIONS`](gman_core::spec::schema::FLAG_INT8_ACTIVATIONS) runs the integer path;
//! without it (`cargo test -p gman-core --no-default-features --test int8_feature`, which CI
//! runs) the same blob is refused with a typed error, never run on the f32 path.

mod common;
use common::*;
use gman_core::blob::Blob;
use gman_core::navigator::NavWeights;
use gman_core::spec::schema::{TensorId, FLAG_INT8_ACTIVATIONS};
use gman_core::{Dims, Error};

#[test]
fn an_int8_activation_blob_runs_only_where_the_feature_is_built() {
    let dims = Dims::MCU;
    let bytes = seeded_blob(&dims, 3, true, FLAG_INT8_ACTIVATIONS);
    let blob = Blob::parse(&bytes).expect("parse");
    let w = NavWeights::from_blob(&blob, &dims);
    if cfg!(feature = "int8-activations") {
        let w = w.expect("the integer path is built");
        assert!(w
            .get(TensorId::all_for(&dims).next().unwrap())
            .int8_activations());
    } else {
        match w {
            Err(Error::Config { what }) => assert!(what.contains("int8-activations"), "{what}"),
            other => panic!(
                "expected a configuration error, got {:?}",
                other.map(|_| ())
            ),
        }
    }
    // A blob without the flag never takes the integer path; it needs the f32-activation
    // kernels (the feature `f32-activations`), else it is refused naming the feature.
    let plain = seeded_blob(&dims, 3, true, 0);
    let blob = Blob::parse(&plain).expect("parse");
    let f32_path = gman_core::nn::qkernel::F32_ACTIVATIONS;
    match NavWeights::from_blob(&blob, &dims) {
        Ok(w) => {
            assert!(f32_path, "refused only without the feature");
            assert!(TensorId::all_for(&dims).all(|id| !w.get(id).int8_activations()));
        }
        Err(Error::Config { what }) => {
            assert!(!f32_path, "{what}");
            assert!(what.contains("`f32-activations`"), "{what}");
        }
        Err(e) => panic!("expected a configuration error, got {e:?}"),
    }
}
