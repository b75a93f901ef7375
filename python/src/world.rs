//! Worlds: loaded once per (data directory, world seed, domain shift) and shared for the process; the names of splits and rewards.

use super::*;

/// (data directory, world seed, domain shift's bits).
pub(crate) type WorldKey = (Option<PathBuf>, u64, u32);

pub(crate) fn worlds() -> &'static Mutex<HashMap<WorldKey, &'static World>> {
    static W: OnceLock<Mutex<HashMap<WorldKey, &'static World>>> = OnceLock::new();
    W.get_or_init(|| Mutex::new(HashMap::new()))
}

/// The world of `data` (None: the built-in synthetic world) and `seed`. Worlds are immutable
/// after loading (their per-scene tables are built lazily behind `OnceLock`s), so one copy
/// per key serves every environment of the process; it lives until the process ends.
pub(crate) fn world_of(
    py: Python<'_>,
    data: Option<&str>,
    seed: u64,
    domain_shift: f32,
) -> PyResult<&'static World> {
    let shift = DomainShift::new(domain_shift)
        .map_err(|e| value_err(format!("domain_shift = {domain_shift}: {e}")))?;
    let key: WorldKey = (
        data.map(|d| std::fs::canonicalize(d).unwrap_or_else(|_| PathBuf::from(d))),
        seed,
        shift.get().to_bits(),
    );
    if let Some(w) = worlds().lock().expect("world cache").get(&key) {
        return Ok(w);
    }
    let world = match &key.0 {
        Some(dir) => {
            if !dir.is_dir() {
                return Err(PyFileNotFoundError::new_err(format!(
                    "data directory {} does not exist",
                    dir.display()
                )));
            }
            let dir = dir.clone();
            py.detach(move || {
                let mut w = World::load_with_seed(&dir, seed)?;
                w.set_domain_shift(shift)?;
                Ok::<World, anyhow::Error>(w)
            })
            .map_err(|e| chain_err(e.context(format!("loading data {}", data.unwrap_or("")))))?
        }
        None => py
            .detach(move || {
                let mut w = World::synthetic(seed);
                w.set_domain_shift(shift).map(|()| w)
            })
            .map_err(chain_err)?,
    };
    let leaked: &'static World = Box::leak(Box::new(world));
    worlds()
        .lock()
        .expect("world cache")
        .entry(key)
        .or_insert(leaked);
    Ok(leaked)
}

pub(crate) fn parse_split(s: &str) -> PyResult<Split> {
    Split::parse(s).map_err(|_| {
        PyValueError::new_err(format!(
            "split must be \"train\", \"val\" or \"test\", got {s:?}"
        ))
    })
}

pub(crate) fn parse_reward(s: &str) -> PyResult<RewardKind> {
    s.parse::<RewardKind>().map_err(|e| {
        PyValueError::new_err(format!(
            "reward {s:?}: {e} (one of navigation, distance, similarity, mixed)"
        ))
    })
}
