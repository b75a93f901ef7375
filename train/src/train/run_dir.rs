//! A run directory's files besides the checkpoint: the learning curve `metrics.csv` (kept
//! consistent with the checkpoint on resume) and the lock that keeps a second trainer out.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

/// Columns of `metrics.csv`, one row per update.
pub(crate) const CSV_HEADER: &str = "update,episodes,env_steps,success_rate,mean_reward,mean_steps,policy_loss,value_loss,entropy,grad_norm,adaptations,rollbacks,disc_gap,adapt_loss,elapsed_s";

/// Path of the run's checkpoint.
pub fn checkpoint_path(out: &Path) -> PathBuf {
    out.join("checkpoint.ckpt")
}

/// Number of columns of `metrics.csv`.
fn csv_columns() -> usize {
    CSV_HEADER.split(',').count()
}

/// What `repair_csv` kept and dropped.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct CsvRepair {
    /// Rows kept (without the header), in order: one per update `1..=update` that had a
    /// well-formed row.
    pub rows: Vec<String>,
    /// 1-based line numbers of malformed rows (wrong column count, a value that is not a
    /// number) and of duplicate or out-of-order updates, dropped.
    pub dropped: Vec<usize>,
    /// Updates `1..=update` that have no well-formed row.
    pub missing: u64,
}

/// Keeps the well-formed rows of a `metrics.csv` text for updates `1..=update`, in order,
/// dropping (and listing) malformed, duplicate and out-of-order rows; rows after `update`
/// (written after the checkpoint a run resumes from) are dropped silently. The header line
/// may be absent (its first data row is then kept, not skipped).
pub(crate) fn repair_csv(text: &str, update: u64) -> CsvRepair {
    let mut r = CsvRepair::default();
    let mut last = 0u64;
    for (i, line) in text.lines().enumerate() {
        if line == CSV_HEADER || line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split(',').collect();
        let u = f[0].parse::<u64>().ok();
        let numeric = f[1..].iter().all(|v| v.parse::<f64>().is_ok());
        match u {
            Some(u) if u > update && f.len() == csv_columns() && numeric => {}
            Some(u) if f.len() == csv_columns() && numeric && u > last && u <= update => {
                last = u;
                r.rows.push(line.to_string());
            }
            // A partial last row written when the process was killed is normal when it lies
            // after the checkpoint; anything else malformed is reported.
            Some(u) if u > update => {}
            _ => r.dropped.push(i + 1),
        }
    }
    r.missing = update - r.rows.len() as u64;
    r
}

/// Rewrites `metrics.csv` atomically (temporary file, fsync, rename) keeping only the rows up
/// to `update` (so a resumed run continues the file where its checkpoint was written), with
/// malformed and duplicate rows dropped and counted in a warning, then opens it for appending.
pub(crate) fn open_csv(out: &Path, update: u64) -> Result<File> {
    let path = out.join("metrics.csv");
    let mut keep = vec![CSV_HEADER.to_string()];
    if update > 0 && path.exists() {
        let text = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
        let r = repair_csv(&String::from_utf8_lossy(&text), update);
        if !r.dropped.is_empty() {
            let shown: Vec<String> = r.dropped.iter().take(10).map(|l| l.to_string()).collect();
            eprintln!(
                "warning: {}: dropped {} malformed or duplicate row(s) at or before update {update} (line {}{})",
                path.display(),
                r.dropped.len(),
                shown.join(", "),
                if r.dropped.len() > 10 { ", ..." } else { "" }
            );
        }
        if r.missing > 0 {
            eprintln!(
                "warning: {}: {} of the {update} updates before the checkpoint have no row; the learning curve has a gap there",
                path.display(),
                r.missing
            );
        }
        keep.extend(r.rows);
    }
    crate::optim::checkpoint::write_atomic(&path, |f| {
        let mut w = std::io::BufWriter::new(f);
        for l in &keep {
            writeln!(w, "{l}")?;
        }
        w.flush()
    })?;
    OpenOptions::new()
        .append(true)
        .open(&path)
        .with_context(|| format!("opening {} for appending", path.display()))
}

/// An exclusive lock on a run directory, held while a trainer writes into it (released when
/// dropped, or by the OS when the process dies). See [`lock_run_dir`].
#[derive(Debug)]
pub struct RunLock {
    file: Option<File>,
    key: PathBuf,
}

impl Drop for RunLock {
    fn drop(&mut self) {
        if self.file.take().is_some() {
            if let Ok(mut held) = held_locks().lock() {
                held.retain(|k| k != &self.key);
            }
        }
    }
}

fn held_locks() -> &'static std::sync::Mutex<Vec<PathBuf>> {
    static HELD: std::sync::OnceLock<std::sync::Mutex<Vec<PathBuf>>> = std::sync::OnceLock::new();
    HELD.get_or_init(Default::default)
}

/// Name of the lock file in a run directory.
pub(crate) const LOCK_FILE: &str = ".lock";

/// Takes an exclusive advisory lock (`flock`, through `fs4`) on `RUN_DIR/.lock`, so that a
/// second trainer writing into the same run directory is refused with a clear error instead
/// of interleaving `metrics.csv` and checkpoints. Taking it again in the same process (the
/// CLI holds it while pre-training, then [`train`](super::trainer::train) asks for it) returns a guard that does
/// nothing. After the lock is taken, stale temporary files of atomic writes
/// (`.NAME.tmp.PID`, left by a process that was killed) are removed from the directory and
/// its `fg/` and `ps/` subdirectories, with a note on stderr.
pub fn lock_run_dir(out: &Path) -> Result<RunLock> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let key = out
        .canonicalize()
        .with_context(|| format!("resolving {}", out.display()))?;
    let mut held = held_locks()
        .lock()
        .map_err(|_| anyhow::anyhow!("run-directory lock registry poisoned"))?;
    if held.contains(&key) {
        return Ok(RunLock { file: None, key });
    }
    let path = out.join(LOCK_FILE);
    let file = OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .with_context(|| format!("creating lock file {}", path.display()))?;
    let locked = fs4::fs_std::FileExt::try_lock_exclusive(&file)
        .with_context(|| format!("locking {}", path.display()))?;
    if !locked {
        bail!(
            "{} is in use by another trainer (lock {} is held); wait for it to finish, or use another --out",
            out.display(),
            path.display()
        );
    }
    held.push(key.clone());
    drop(held);
    remove_stale_temporaries(out);
    Ok(RunLock {
        file: Some(file),
        key,
    })
}

/// Removes `.NAME.tmp.PID` files (temporaries of [`crate::optim::checkpoint::write_atomic`])
/// of other processes from `dir`, `dir/fg` and `dir/ps`. Only called with the run
/// directory's lock held, so no other writer can be using them.
fn remove_stale_temporaries(dir: &Path) {
    let me = std::process::id().to_string();
    let (mut n, mut bytes) = (0usize, 0u64);
    for d in [dir.to_path_buf(), dir.join("fg"), dir.join("ps")] {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let Some((stem, pid)) = name.rsplit_once(".tmp.") else {
                continue;
            };
            if !stem.starts_with('.')
                || pid.is_empty()
                || !pid.bytes().all(|b| b.is_ascii_digit())
                || pid == me
            {
                continue;
            }
            let len = e.metadata().map(|m| m.len()).unwrap_or(0);
            if std::fs::remove_file(e.path()).is_ok() {
                n += 1;
                bytes += len;
            }
        }
    }
    if n > 0 {
        eprintln!(
            "note: removed {n} stale temporary file(s) ({bytes} bytes) left in {} by killed runs",
            dir.display()
        );
    }
}
