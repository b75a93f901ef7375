//! Training checkpoints: a versioned, checksummed binary container of JSON metadata, named f32
//! tensors and opaque byte blobs (optimiser state, RNG state, ...), written atomically.
//!
//! # File layout (all integers little-endian)
//! ```text
//! offset 0   magic            8 bytes  "GMANCKPT"
//!        8   version          u32      (FORMAT_VERSION)
//!       12   flags            u32      (0)
//!       16   payload length   u64
//!       24   CRC-32 (IEEE) of the payload
//!       28   payload:
//!              metadata   u32 length + UTF-8 JSON text
//!              tensors    u32 count, then per tensor: u16 name length + UTF-8 name,
//!                         u32 rows, u32 cols, rows*cols f32
//!              blobs      u32 count, then per blob: u16 name length + UTF-8 name,
//!                         u64 length + bytes
//! ```
//!
//! # Atomic writes
//! [`Checkpoint::save`] writes to a temporary file in the destination directory, flushes it to
//! disk (`fsync`), renames it over the final name and syncs the directory. A crash or error at
//! any point leaves either the old file or the new one under the final name, never a partial
//! file; on error the temporary file is removed.
//!
//! The container is generic (the feature-generator and PS pre-training store their networks
//! here; the navigation trainer stores its parameters, Adam state and RNG state for a
//! bit-for-bit `--resume`).

use std::fs::{self, File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use gman_core::blob::crc32::crc32;
use thiserror::Error;

use super::params::{Param, ParamSet};

/// First bytes of every checkpoint file.
pub const MAGIC: [u8; 8] = *b"GMANCKPT";
/// Format version written and read by this build.
pub const FORMAT_VERSION: u32 = 1;
/// Length of the fixed header before the payload.
pub const HEADER_LEN: usize = 28;

/// Why a checkpoint could not be read or written. Every variant names the file.
#[derive(Debug, Error)]
pub enum CheckpointError {
    /// The file does not exist.
    #[error("{path}: checkpoint file not found")]
    Missing {
        /// The file.
        path: PathBuf,
    },
    /// Any other I/O failure.
    #[error("{path}: {op}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What was being done.
        op: &'static str,
        /// The I/O error.
        #[source]
        source: io::Error,
    },
    /// The file does not start with [`MAGIC`].
    #[error("{path}: not a gman checkpoint (bad magic bytes)")]
    BadMagic {
        /// The file.
        path: PathBuf,
    },
    /// The file has a format version this build does not read.
    #[error("{path}: checkpoint format version {found} is not supported (this build reads version {expected})")]
    UnsupportedVersion {
        /// The file.
        path: PathBuf,
        /// Version in the file.
        found: u32,
        /// Version this build reads.
        expected: u32,
    },
    /// The file ends early.
    #[error(
        "{path}: truncated checkpoint: {what} needs {needed} bytes but only {available} are left"
    )]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Which part.
        what: &'static str,
        /// Bytes needed.
        needed: u64,
        /// Bytes present.
        available: u64,
    },
    /// The payload checksum does not match (the file was corrupted).
    #[error("{path}: checkpoint corrupted: CRC-32 of the payload is {computed:08x}, header says {stored:08x}")]
    Checksum {
        /// The file.
        path: PathBuf,
        /// CRC in the header.
        stored: u32,
        /// CRC of the bytes read.
        computed: u32,
    },
    /// The checksum matched but the content is inconsistent (a writer bug or an
    /// incompatible producer).
    #[error("{path}: malformed checkpoint: {what}")]
    Malformed {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// A tensor or blob the caller needs is not in the checkpoint (or has the wrong shape).
    #[error("{path}: {what}")]
    MissingEntry {
        /// The file.
        path: PathBuf,
        /// What is missing.
        what: String,
    },
}

/// A checkpoint in memory.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Checkpoint {
    /// JSON metadata (free-form; see the producers).
    pub metadata: serde_json::Value,
    /// Named tensors.
    pub tensors: ParamSet,
    /// Named opaque byte blobs.
    pub blobs: Vec<(String, Vec<u8>)>,
    /// The file it was loaded from (for messages); `None` when built in memory.
    pub path: Option<PathBuf>,
}

fn label(path: Option<&Path>) -> PathBuf {
    path.map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from("<memory>"))
}

impl Checkpoint {
    /// An empty checkpoint with the given metadata.
    pub fn new(metadata: serde_json::Value) -> Checkpoint {
        Checkpoint {
            metadata,
            ..Default::default()
        }
    }

    /// Adds every tensor of `set` (fails on a duplicate name).
    pub fn add_tensors(&mut self, set: &ParamSet) -> anyhow::Result<()> {
        for p in &set.tensors {
            self.tensors.push(p.clone())?;
        }
        Ok(())
    }

    /// Adds a blob (replacing one of the same name).
    pub fn add_blob(&mut self, name: &str, bytes: Vec<u8>) {
        self.blobs.retain(|(n, _)| n != name);
        self.blobs.push((name.to_string(), bytes));
    }

    /// A blob by name, or an error naming the file.
    pub fn blob(&self, name: &str) -> Result<&[u8], CheckpointError> {
        self.blobs
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, b)| b.as_slice())
            .ok_or_else(|| CheckpointError::MissingEntry {
                path: label(self.path.as_deref()),
                what: format!("blob {name:?} not in checkpoint"),
            })
    }

    /// A tensor by name with a required shape, or an error naming the file.
    pub fn tensor(&self, name: &str, rows: usize, cols: usize) -> Result<&Param, CheckpointError> {
        let missing = |what: String| CheckpointError::MissingEntry {
            path: label(self.path.as_deref()),
            what,
        };
        let p = self.tensors.get(name).ok_or_else(|| {
            missing(format!(
                "tensor {name:?} not in checkpoint (have: {})",
                self.tensors.names()
            ))
        })?;
        if p.rows != rows || p.cols != cols {
            return Err(missing(format!(
                "tensor {name:?} has shape {}x{}, expected {rows}x{cols}",
                p.rows, p.cols
            )));
        }
        Ok(p)
    }

    /// Copies the named tensors into a new [`ParamSet`] (shapes checked against `like`).
    pub(crate) fn params_like(&self, like: &ParamSet) -> Result<ParamSet, CheckpointError> {
        let mut out = ParamSet::new();
        for p in &like.tensors {
            let t = self.tensor(&p.name, p.rows, p.cols)?;
            out.tensors.push(t.clone());
        }
        Ok(out)
    }

    /// The encoded file contents.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut payload = Vec::new();
        let meta = self.metadata.to_string();
        payload.extend_from_slice(&(meta.len() as u32).to_le_bytes());
        payload.extend_from_slice(meta.as_bytes());
        payload.extend_from_slice(&(self.tensors.tensors.len() as u32).to_le_bytes());
        for p in &self.tensors.tensors {
            put_name(&mut payload, &p.name);
            payload.extend_from_slice(&(p.rows as u32).to_le_bytes());
            payload.extend_from_slice(&(p.cols as u32).to_le_bytes());
            payload.reserve(4 * p.data.len());
            for v in &p.data {
                payload.extend_from_slice(&v.to_le_bytes());
            }
        }
        payload.extend_from_slice(&(self.blobs.len() as u32).to_le_bytes());
        for (n, b) in &self.blobs {
            put_name(&mut payload, n);
            payload.extend_from_slice(&(b.len() as u64).to_le_bytes());
            payload.extend_from_slice(b);
        }
        let mut out = Vec::with_capacity(HEADER_LEN + payload.len());
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
        out.extend_from_slice(&0u32.to_le_bytes());
        out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        out.extend_from_slice(&crc32(&payload).to_le_bytes());
        out.extend_from_slice(&payload);
        out
    }

    /// Decodes file contents; `path` only labels errors.
    pub fn from_bytes(bytes: &[u8], path: Option<&Path>) -> Result<Checkpoint, CheckpointError> {
        let p = label(path);
        let payload = Self::checked_payload(bytes, &p)?;
        let (metadata, tensors, blobs) = Self::parse_payload(payload, &p)?;
        Ok(Checkpoint {
            metadata,
            tensors,
            blobs,
            path: path.map(Path::to_path_buf),
        })
    }

    /// The header's checks (magic, version, flags, length, CRC-32), in this order; returns the
    /// payload.
    fn checked_payload<'b>(bytes: &'b [u8], p: &Path) -> Result<&'b [u8], CheckpointError> {
        let p = p.to_path_buf();
        let trunc = |what, needed: usize, available: usize| CheckpointError::Truncated {
            path: p.clone(),
            what,
            needed: needed as u64,
            available: available as u64,
        };
        if bytes.len() < MAGIC.len() || bytes[..MAGIC.len()] != MAGIC {
            if bytes.len() < MAGIC.len() && MAGIC.starts_with(bytes) {
                return Err(trunc("magic", MAGIC.len(), bytes.len()));
            }
            return Err(CheckpointError::BadMagic { path: p });
        }
        if bytes.len() < HEADER_LEN {
            return Err(trunc("header", HEADER_LEN, bytes.len()));
        }
        let version = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
        if version != FORMAT_VERSION {
            return Err(CheckpointError::UnsupportedVersion {
                path: p,
                found: version,
                expected: FORMAT_VERSION,
            });
        }
        let flags = u32::from_le_bytes([bytes[12], bytes[13], bytes[14], bytes[15]]);
        if flags != 0 {
            return Err(CheckpointError::Malformed {
                path: p,
                what: format!("unknown header flags {flags:#x}"),
            });
        }
        let mut l8 = [0u8; 8];
        l8.copy_from_slice(&bytes[16..24]);
        let plen = u64::from_le_bytes(l8);
        let stored = u32::from_le_bytes([bytes[24], bytes[25], bytes[26], bytes[27]]);
        let avail = (bytes.len() - HEADER_LEN) as u64;
        if plen > avail {
            return Err(CheckpointError::Truncated {
                path: p,
                what: "payload",
                needed: plen,
                available: avail,
            });
        }
        if plen < avail {
            return Err(CheckpointError::Malformed {
                path: p,
                what: format!("{} bytes after the payload", avail - plen),
            });
        }
        let payload = &bytes[HEADER_LEN..];
        let computed = crc32(payload);
        if computed != stored {
            return Err(CheckpointError::Checksum {
                path: p,
                stored,
                computed,
            });
        }
        Ok(payload)
    }

    /// The payload: metadata, tensors, blobs, nothing after them.
    #[allow(clippy::type_complexity)]
    fn parse_payload(
        payload: &[u8],
        p: &Path,
    ) -> Result<(serde_json::Value, ParamSet, Vec<(String, Vec<u8>)>), CheckpointError> {
        let mut r = Cursor {
            b: payload,
            pos: 0,
            path: p,
        };
        let mlen = r.u32("metadata length")? as usize;
        let meta_text = std::str::from_utf8(r.take(mlen, "metadata")?)
            .map_err(|_| r.malformed("metadata is not UTF-8".into()))?;
        let metadata: serde_json::Value = serde_json::from_str(meta_text)
            .map_err(|e| r.malformed(format!("metadata is not JSON: {e}")))?;
        let nt = r.u32("tensor count")?;
        let mut tensors = ParamSet::new();
        for _ in 0..nt {
            let name = r.name()?;
            let rows = r.u32("tensor rows")? as usize;
            let cols = r.u32("tensor cols")? as usize;
            let n = rows
                .checked_mul(cols)
                .and_then(|n| n.checked_mul(4))
                .ok_or_else(|| r.malformed(format!("tensor {name:?}: shape overflows")))?;
            let raw = r.take(n, "tensor data")?;
            let data = raw
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            tensors
                .push(Param {
                    name: name.clone(),
                    rows,
                    cols,
                    data,
                })
                .map_err(|e| r.malformed(e.to_string()))?;
        }
        let nb = r.u32("blob count")?;
        let mut blobs: Vec<(String, Vec<u8>)> = Vec::new();
        for _ in 0..nb {
            let name = r.name()?;
            let len = r.u64("blob length")?;
            let len = usize::try_from(len).map_err(|_| r.malformed("blob too long".into()))?;
            let b = r.take(len, "blob data")?.to_vec();
            if blobs.iter().any(|(n, _)| *n == name) {
                return Err(r.malformed(format!("blob {name:?} twice")));
            }
            blobs.push((name, b));
        }
        if r.pos != payload.len() {
            return Err(r.malformed(format!(
                "{} unread bytes at the end of the payload",
                payload.len() - r.pos
            )));
        }
        Ok((metadata, tensors, blobs))
    }

    /// Reads and decodes a checkpoint file.
    pub fn load(path: &Path) -> Result<Checkpoint, CheckpointError> {
        let bytes = fs::read(path).map_err(|e| {
            if e.kind() == io::ErrorKind::NotFound {
                CheckpointError::Missing {
                    path: path.to_path_buf(),
                }
            } else {
                CheckpointError::Io {
                    path: path.to_path_buf(),
                    op: "cannot read",
                    source: e,
                }
            }
        })?;
        Checkpoint::from_bytes(&bytes, Some(path))
    }

    /// Writes the checkpoint atomically (see the module docs).
    pub fn save(&self, path: &Path) -> Result<(), CheckpointError> {
        let bytes = self.to_bytes();
        write_atomic(path, |f| f.write_all(&bytes))
    }
}

fn put_name(out: &mut Vec<u8>, name: &str) {
    // Names are short identifiers; longer ones are cut at a char boundary below 64 KiB.
    let mut end = name.len().min(u16::MAX as usize);
    while !name.is_char_boundary(end) {
        end -= 1;
    }
    out.extend_from_slice(&(end as u16).to_le_bytes());
    out.extend_from_slice(&name.as_bytes()[..end]);
}

struct Cursor<'a> {
    b: &'a [u8],
    pos: usize,
    path: &'a Path,
}

impl<'a> Cursor<'a> {
    fn malformed(&self, what: String) -> CheckpointError {
        CheckpointError::Malformed {
            path: self.path.to_path_buf(),
            what,
        }
    }
    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], CheckpointError> {
        let avail = self.b.len() - self.pos;
        if n > avail {
            // The CRC matched, so the header's payload length itself was consistent: a
            // record claiming more bytes than the payload has is malformed, not truncated.
            return Err(self.malformed(format!(
                "{what} needs {n} bytes but the payload has {avail} left"
            )));
        }
        let s = &self.b[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    fn u32(&mut self, what: &'static str) -> Result<u32, CheckpointError> {
        let s = self.take(4, what)?;
        Ok(u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
    }
    fn u64(&mut self, what: &'static str) -> Result<u64, CheckpointError> {
        let s = self.take(8, what)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(s);
        Ok(u64::from_le_bytes(a))
    }
    fn name(&mut self) -> Result<String, CheckpointError> {
        let s = self.take(2, "name length")?;
        let n = u16::from_le_bytes([s[0], s[1]]) as usize;
        let raw = self.take(n, "name")?;
        std::str::from_utf8(raw)
            .map(str::to_string)
            .map_err(|_| self.malformed("a name is not UTF-8".into()))
    }
}

/// Writes a file atomically: `write` fills a temporary file in the destination directory,
/// which is then flushed to disk, renamed over `path`, and the directory synced. If `write`
/// (or any step) fails, the temporary file is removed and `path` is left as it was.
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut File) -> io::Result<()>,
) -> Result<(), CheckpointError> {
    let io_err = |op, source| CheckpointError::Io {
        path: path.to_path_buf(),
        op,
        source,
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let file_name = path.file_name().ok_or_else(|| CheckpointError::Malformed {
        path: path.to_path_buf(),
        what: "not a file path".into(),
    })?;
    let tmp = dir.join(format!(
        ".{}.tmp.{}",
        file_name.to_string_lossy(),
        std::process::id()
    ));
    let result = (|| {
        let mut f = OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(true)
            .open(&tmp)
            .map_err(|e| io_err("cannot create temporary file", e))?;
        write(&mut f).map_err(|e| io_err("cannot write", e))?;
        f.flush().map_err(|e| io_err("cannot write", e))?;
        f.sync_all().map_err(|e| io_err("cannot sync", e))?;
        drop(f);
        fs::rename(&tmp, path).map_err(|e| io_err("cannot rename temporary file", e))
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
        return result;
    }
    // Make the rename durable. Directories cannot be opened for syncing everywhere; a
    // failure here does not undo the (already atomic) rename.
    if let Ok(d) = File::open(&dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use gman_core::rng::Xoshiro128;

    use crate::optim::params::Init;

    fn sample() -> Checkpoint {
        let mut rng = Xoshiro128::seed_from_u64(7);
        let mut set = ParamSet::new();
        set.add("GenW1", 4, 3, Init::Normal(0.02), &mut rng)
            .unwrap();
        set.add("GenB1", 4, 1, Init::Const(0.5), &mut rng).unwrap();
        let mut c = Checkpoint::new(serde_json::json!({"kind": "test", "iters": 3}));
        c.add_tensors(&set).unwrap();
        c.add_blob("rng", vec![1, 2, 3, 255]);
        c.add_blob("empty", vec![]);
        c
    }

    #[test]
    fn bytes_round_trip_is_exact() {
        let c = sample();
        let b = c.to_bytes();
        let back = Checkpoint::from_bytes(&b, None).unwrap();
        assert_eq!(back, c);
        assert_eq!(back.to_bytes(), b);
        assert!(back.tensor("GenW1", 3, 4).is_err());
        assert!(back.tensor("GenW9", 4, 3).is_err());
        assert_eq!(back.blob("rng").unwrap(), &[1, 2, 3, 255]);
        assert!(back.blob("adam").is_err());
    }

    #[test]
    fn every_single_byte_flip_and_truncation_is_rejected() {
        let b = sample().to_bytes();
        for i in 0..b.len() {
            let mut m = b.clone();
            m[i] ^= 0x40;
            assert!(
                Checkpoint::from_bytes(&m, None).is_err(),
                "flip at {i} accepted"
            );
        }
        for n in 0..b.len() {
            assert!(
                Checkpoint::from_bytes(&b[..n], None).is_err(),
                "truncation to {n} accepted"
            );
        }
    }
}
