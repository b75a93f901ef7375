//! Errors as Python exceptions, the size limits, the panic guard and numpy arrays made once.

use super::*;

pub(crate) fn borrow_err(e: numpy::BorrowError) -> PyErr {
    PyRuntimeError::new_err(format!(
        "an output array of the environment is borrowed elsewhere: {e}"
    ))
}

pub(crate) fn value_err(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// `anyhow` chain as one message.
pub(crate) fn chain_err(e: anyhow::Error) -> PyErr {
    PyValueError::new_err(format!("{e:#}"))
}

/// Most environments in one batch (`num_envs`).
pub(crate) const MAX_ENVS: usize = 1 << 16;
/// Most floats of one batch's observation arrays, `num_envs * (512 + 2 * 45 + map cells *
/// 512)`: 2^28 floats, 1 GiB.
pub(crate) const MAX_BATCH_FLOATS: usize = 1 << 28;
/// Longest episode (`max_steps`): `info["steps"]` is an int32.
pub(crate) const MAX_STEPS: u32 = i32::MAX as u32;

/// The text of a caught panic's payload.
pub(crate) fn panic_text(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".to_string())
}

/// Runs `f`, turning a Rust panic into a `RuntimeError` naming `what`. A last resort: the
/// argument checks are meant to make every panic unreachable, so one is a bug of gman.
pub(crate) fn guard<T>(what: &str, f: impl FnOnce() -> PyResult<T>) -> PyResult<T> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).unwrap_or_else(|p| {
        Err(PyRuntimeError::new_err(format!(
            "{what}: internal error in gman (a Rust panic: {}); please report it",
            panic_text(p.as_ref())
        )))
    })
}

/// A zeroed vector of `n` elements, or a `MemoryError` naming `what` (instead of the abort
/// of a failed allocation).
pub(crate) fn try_filled<T: Clone>(n: usize, v: T, what: &str) -> PyResult<Vec<T>> {
    let mut out = Vec::new();
    out.try_reserve_exact(n)
        .map_err(|_| PyMemoryError::new_err(format!("{what}: cannot allocate {n} elements")))?;
    out.resize(n, v);
    Ok(out)
}

/// A 1-d numpy array of `n` copies of `v`, allocated fallibly (see [`try_filled`]).
pub(crate) fn arr1<'py, T: Element + Clone>(
    py: Python<'py>,
    n: usize,
    v: T,
    what: &str,
) -> PyResult<Bound<'py, PyArray1<T>>> {
    Ok(PyArray1::from_vec(py, try_filled(n, v, what)?))
}

/// A 2-d numpy array of `a x b` copies of `v`, allocated fallibly.
pub(crate) fn arr2<'py, T: Element + Clone>(
    py: Python<'py>,
    [a, b]: [usize; 2],
    v: T,
    what: &str,
) -> PyResult<Bound<'py, PyArray2<T>>> {
    let n = a.checked_mul(b).ok_or_else(|| too_large(what))?;
    arr1(py, n, v, what)?.reshape([a, b])
}

/// A 3-d numpy array of `a x b x c` copies of `v`, allocated fallibly.
pub(crate) fn arr3<'py, T: Element + Clone>(
    py: Python<'py>,
    [a, b, c]: [usize; 3],
    v: T,
    what: &str,
) -> PyResult<Bound<'py, PyArray3<T>>> {
    let n = a
        .checked_mul(b)
        .and_then(|n| n.checked_mul(c))
        .ok_or_else(|| too_large(what))?;
    arr1(py, n, v, what)?.reshape([a, b, c])
}

pub(crate) fn too_large(what: &str) -> PyErr {
    PyMemoryError::new_err(format!("{what}: the array's size overflows"))
}
