//! The HDF5 access of the offline data: the `hdf5-metno` bindings to the system HDF5 library
//! with the `offline` feature, a stub that explains how to get them without it.

#[cfg(feature = "offline")]
pub use real::{write_datasets, H5File};
#[cfg(not(feature = "offline"))]
pub use stub::H5File;

/// Message of every HDF5 operation in a build without the `offline` feature.
#[cfg(not(feature = "offline"))]
pub const NEEDS_FEATURE: &str = "this build of gman cannot read HDF5 files: rebuild with \
     `cargo build --release --features offline` (needs the system HDF5 library, Debian: \
     `apt-get install libhdf5-dev pkg-config`)";

#[cfg(feature = "offline")]
mod real {
    use std::path::{Path, PathBuf};

    use anyhow::{anyhow, bail, Context, Result};

    /// An open HDF5 file of datasets named by state key.
    pub struct H5File {
        path: PathBuf,
        file: hdf5::File,
    }

    impl std::fmt::Debug for H5File {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.debug_struct("H5File").field("path", &self.path).finish()
        }
    }

    impl H5File {
        /// Opens `path` read-only; errors name the file.
        pub fn open(path: &Path) -> Result<H5File> {
            super::super::check_file(path)?;
            let file = hdf5::File::open(path)
                .map_err(|e| anyhow!("{}: cannot open as HDF5: {e}", path.display()))?;
            Ok(H5File {
                path: path.to_path_buf(),
                file,
            })
        }

        /// The file's path.
        pub fn path(&self) -> &Path {
            &self.path
        }

        fn dataset(&self, key: &str) -> Result<hdf5::Dataset> {
            self.file
                .dataset(key)
                .map_err(|_| anyhow!("{}: no dataset {key:?}", self.path.display()))
        }

        /// Checks that dataset `key` exists, is a float dataset and has one of `shapes`.
        pub fn check(&self, key: &str, shapes: &[&[usize]]) -> Result<()> {
            let ds = self.dataset(key)?;
            let shape = ds.shape();
            if !shapes.contains(&shape.as_slice()) {
                let expected: Vec<String> = shapes.iter().map(|s| format!("{s:?}")).collect();
                bail!(
                    "{}: dataset {key:?} has shape {shape:?}, expected {}",
                    self.path.display(),
                    expected.join(" or ")
                );
            }
            let dt = ds
                .dtype()
                .with_context(|| format!("{}: dataset {key:?}", self.path.display()))?;
            if !(dt.is::<f32>() || dt.is::<f64>()) {
                bail!(
                    "{}: dataset {key:?} is not a float dataset (expected f32)",
                    self.path.display()
                );
            }
            Ok(())
        }

        /// The names of the datasets (and groups) at the file's root, sorted.
        pub fn names(&self) -> Result<Vec<String>> {
            let mut v = self
                .file
                .member_names()
                .map_err(|e| anyhow!("{}: cannot list datasets: {e}", self.path.display()))?;
            v.sort();
            Ok(v)
        }

        /// Shape and element size in bytes of dataset `key` (HDF5 metadata only).
        pub fn shape_and_size(&self, key: &str) -> Result<(Vec<usize>, usize)> {
            let ds = self.dataset(key)?;
            let dt = ds
                .dtype()
                .with_context(|| format!("{}: dataset {key:?}", self.path.display()))?;
            Ok((ds.shape(), dt.size()))
        }

        /// Reads dataset `key` as f32 values in storage (C) order; f64 data is converted.
        pub fn read(&self, key: &str) -> Result<Vec<f32>> {
            let ds = self.dataset(key)?;
            let at = || format!("{}: reading dataset {key:?}", self.path.display());
            let dt = ds.dtype().with_context(at)?;
            if dt.is::<f64>() {
                let v = ds.read_raw::<f64>().with_context(at)?;
                Ok(v.into_iter().map(|x| x as f32).collect())
            } else {
                ds.read_raw::<f32>().with_context(at)
            }
        }
    }

    /// Writes a new HDF5 file (replacing any) with one f32 dataset per `(name, shape, data)`,
    /// contiguous and uncompressed like the files h5py writes by default.
    pub fn write_datasets<'a>(
        path: &Path,
        datasets: impl IntoIterator<Item = (&'a str, &'a [usize], &'a [f32])>,
    ) -> Result<()> {
        let file = hdf5::File::create(path)
            .map_err(|e| anyhow!("{}: cannot create: {e}", path.display()))?;
        for (name, shape, data) in datasets {
            let n: usize = shape.iter().product();
            if n != data.len() {
                bail!(
                    "{}: dataset {name:?}: {} values for shape {shape:?}",
                    path.display(),
                    data.len()
                );
            }
            let ds = file
                .new_dataset::<f32>()
                .shape(shape)
                .create(name)
                .map_err(|e| anyhow!("{}: dataset {name:?}: {e}", path.display()))?;
            ds.write_raw(data)
                .map_err(|e| anyhow!("{}: dataset {name:?}: {e}", path.display()))?;
        }
        file.close()
            .map_err(|e| anyhow!("{}: cannot close: {e}", path.display()))
    }
}

#[cfg(not(feature = "offline"))]
mod stub {
    use std::path::{Path, PathBuf};

    use anyhow::{bail, Result};

    use super::NEEDS_FEATURE;

    /// Stand-in for an HDF5 file: every operation fails with [`NEEDS_FEATURE`].
    #[derive(Debug)]
    pub struct H5File {
        path: PathBuf,
    }

    impl H5File {
        /// Fails: this build has no HDF5 support.
        pub fn open(path: &Path) -> Result<H5File> {
            bail!("{}: {NEEDS_FEATURE}", path.display())
        }

        /// The file's path.
        pub fn path(&self) -> &Path {
            &self.path
        }

        /// Fails: this build has no HDF5 support.
        pub fn check(&self, _key: &str, _shapes: &[&[usize]]) -> Result<()> {
            bail!("{}: {NEEDS_FEATURE}", self.path.display())
        }

        /// Fails: this build has no HDF5 support.
        pub fn names(&self) -> Result<Vec<String>> {
            bail!("{}: {NEEDS_FEATURE}", self.path.display())
        }

        /// Fails: this build has no HDF5 support.
        pub fn shape_and_size(&self, _key: &str) -> Result<(Vec<usize>, usize)> {
            bail!("{}: {NEEDS_FEATURE}", self.path.display())
        }

        /// Fails: this build has no HDF5 support.
        pub fn read(&self, _key: &str) -> Result<Vec<f32>> {
            bail!("{}: {NEEDS_FEATURE}", self.path.display())
        }
    }
}
