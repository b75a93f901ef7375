//! `NavigatorCore`: gman-core's navigator over a blob.

use super::*;

pub(crate) enum AnyNav<'a> {
    Full(Navigator<'a, Full, K>),
    Efficient(Navigator<'a, Efficient, K>),
}

#[ouroboros::self_referencing]
pub(crate) struct NavCell {
    pub(crate) model: Box<NavModel>,
    pub(crate) arena: Vec<f32>,
    #[borrows(model, mut arena)]
    #[not_covariant]
    pub(crate) nav: AnyNav<'this>,
}

pub(crate) fn core_err(e: gman_core::Error) -> PyErr {
    PyValueError::new_err(format!("navigator: {e}"))
}

/// gman-core's navigator over a weight blob, configured as `gman eval` runs it.
#[pyclass(module = "gman._gman", name = "NavigatorCore")]
pub(crate) struct PyNavigator {
    pub(crate) cell: NavCell,
    pub(crate) method: &'static str,
    pub(crate) efficient: bool,
    pub(crate) attr: usize,
    pub(crate) ps: usize,
    pub(crate) map_len: usize,
    pub(crate) map_rows: usize,
    pub(crate) map_cols: usize,
}

impl PyNavigator {
    /// Parses `blob` and builds the navigator ([`PyNavigator::from_blob`]).
    #[allow(clippy::borrowed_box)] // the builder's signature (ouroboros) takes the owner's Box
    pub(crate) fn build(blob: &[u8]) -> PyResult<PyNavigator> {
        let model = model_from_blob(blob, None).map_err(|e| chain_err(e.context("blob")))?;
        let efficient = gman_train::model::episode::eval_mode_is_efficient(&model);
        let method = model.method.name();
        let dims = model.dims;
        let arena = vec![0.0; model.arena_len()];
        let cell = NavCellTryBuilder {
            model: Box::new(model),
            arena,
            nav_builder: |model: &Box<NavModel>, arena: &mut Vec<f32>| -> PyResult<AnyNav<'_>> {
                let w = model.weights().map_err(chain_err)?;
                let cfg = model.nav_config(false);
                Ok(if efficient {
                    AnyNav::Efficient(Navigator::new(w, arena, cfg).map_err(core_err)?)
                } else {
                    AnyNav::Full(Navigator::new(w, arena, cfg).map_err(core_err)?)
                })
            },
        }
        .try_build()?;
        Ok(PyNavigator {
            cell,
            method,
            efficient,
            attr: dims.attr,
            ps: dims.ps,
            map_len: dims.map_len(),
            map_rows: dims.map_rows,
            map_cols: dims.map_cols,
        })
    }
}

#[pymethods]
impl PyNavigator {
    /// Parses `blob` and builds the navigator (the blob's method, inner-loop settings and
    /// adaptation mode, sampled actions: what `gman eval --agent BLOB` runs).
    #[staticmethod]
    fn from_blob(blob: &Bound<'_, PyBytes>) -> PyResult<PyNavigator> {
        guard("Navigator.from_blob", || Self::build(blob.as_bytes()))
    }

    /// Starts an episode: target attribute vector `attr` (float32, 45) and the episode seed.
    fn reset(&mut self, attr: PyReadonlyArray1<'_, f32>, seed: u64) -> PyResult<()> {
        let a = attr.as_slice()?;
        guard("Navigator.reset", || {
            self.cell
                .with_nav_mut(|nav| match nav {
                    AnyNav::Full(n) => n.reset(a, seed),
                    AnyNav::Efficient(n) => n.reset(a, seed),
                })
                .map_err(core_err)
        })
    }

    /// One control step: returns (action, probabilities, value, adapted). The binding reads
    /// its inputs before gman-core's `step_map` runs and writes nothing of the navigator.
    #[pyo3(signature = (obs, map=None, ps=None))]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        obs: PyReadonlyArray1<'py, f32>,
        map: Option<PyReadonlyArray1<'py, f32>>,
        ps: Option<PyReadonlyArray1<'py, f32>>,
    ) -> PyResult<(usize, Bound<'py, PyArray1<f32>>, f32, bool)> {
        let o = obs.as_slice()?;
        let m: &[f32] = match &map {
            Some(m) => m.as_slice()?,
            None => &[],
        };
        let p: &[f32] = match &ps {
            Some(p) => p.as_slice()?,
            None => &[],
        };
        let out = guard("Navigator.step", || {
            self.cell
                .with_nav_mut(|nav| match nav {
                    AnyNav::Full(n) => n.step_map(o, m, p),
                    AnyNav::Efficient(n) => n.step_map(o, m, p),
                })
                .map_err(core_err)
        })?;
        Ok((
            out.action.index(),
            PyArray1::from_slice(py, &out.probs),
            out.value,
            out.adapted,
        ))
    }

    /// Runs the inner update on the buffered steps now; True if it ran.
    fn adapt(&mut self) -> PyResult<bool> {
        guard("Navigator.adapt", || {
            self.cell
                .with_nav_mut(|nav| match nav {
                    AnyNav::Full(n) => n.adapt_now(),
                    AnyNav::Efficient(n) => n.adapt_now(),
                })
                .map_err(core_err)
        })
    }

    /// Length of the PS input the model takes (0: none).
    #[getter]
    fn ps_dim(&self) -> usize {
        self.ps
    }

    /// Steps buffered for the next inner update.
    #[getter]
    fn buffered(&mut self) -> usize {
        self.cell.with_nav_mut(|nav| match nav {
            AnyNav::Full(n) => n.buffered(),
            AnyNav::Efficient(n) => n.buffered(),
        })
    }

    /// The method the blob was trained as (e.g. "gman").
    #[getter]
    fn method(&self) -> &'static str {
        self.method
    }

    /// The adaptation mode ("efficient" or "full").
    #[getter]
    fn mode(&self) -> &'static str {
        if self.efficient {
            "efficient"
        } else {
            "full"
        }
    }

    /// Length of the attribute vector.
    #[getter]
    fn attr_dim(&self) -> usize {
        self.attr
    }

    /// (rows, cols) of the spatial map the model takes ((0, 0) without one).
    #[getter]
    fn map_shape(&self) -> (usize, usize) {
        (self.map_rows, self.map_cols)
    }

    /// Floats of the spatial map (rows * cols * 512).
    #[getter]
    fn map_len(&self) -> usize {
        self.map_len
    }

    /// Every setting of the model, by key (gman-core's `SETTING_KEYS`, the words `gman
    /// inspect` prints): a count or a switch as an `int` or `bool`, a rate as a `float`, a
    /// name as a `str`; `None` for a setting that follows another (`disc_lr` when α1 is α2).
    #[getter]
    fn settings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let spec = self.cell.borrow_model().spec;
        let d = PyDict::new(py);
        for key in SETTING_KEYS {
            match spec.get(key) {
                Some(SettingValue::U32(n)) => d.set_item(key, n)?,
                Some(SettingValue::F32(a)) => d.set_item(key, a)?,
                Some(SettingValue::Name(n)) => d.set_item(key, n)?,
                Some(SettingValue::Bool(b)) => d.set_item(key, b)?,
                None => d.set_item(key, py.None())?,
            }
        }
        Ok(d)
    }
}
