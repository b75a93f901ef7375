//! Progress of the long computations (evaluation, pre-training, training) as a trait, so
//! that the library draws nothing itself: the program that runs them installs its [`Bars`]
//! once ([`install`]; the `gman` binary draws terminal bars), and a computation asked to show
//! progress (`progress: true` in its settings) reports to a bar of that maker. Without a
//! maker, or when progress is not wanted (`--quiet`), reports go to [`NoProgress`].

use std::sync::OnceLock;

/// One progress display: a count of steps toward a length, and a message.
pub trait Progress: Send + Sync {
    /// Moves the count to `pos`.
    fn set_position(&self, pos: u64);
    /// Adds `n` to the count.
    fn inc(&self, n: u64);
    /// Shows `msg` beside the count.
    fn set_message(&self, msg: String);
    /// The computation is done: the display goes away.
    fn finish(&self);
}

/// The progress that shows nothing.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoProgress;

impl Progress for NoProgress {
    fn set_position(&self, _pos: u64) {}
    fn inc(&self, _n: u64) {}
    fn set_message(&self, _msg: String) {}
    fn finish(&self) {}
}

/// Which computation a bar follows (the maker chooses its look from this).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BarKind<'a> {
    /// Evaluation: one step per episode.
    Eval,
    /// Pre-training (FG or PS): one step per iteration.
    Pretrain,
    /// Training of the method `method`: one step per update.
    Train {
        /// The method's name.
        method: &'a str,
    },
}

/// Makes the progress displays of a program.
pub trait Bars: Send + Sync {
    /// A display of `len` steps following a computation of `kind`.
    fn bar(&self, kind: BarKind<'_>, len: u64) -> Box<dyn Progress>;
}

static BARS: OnceLock<&'static dyn Bars> = OnceLock::new();

/// Installs the program's maker of progress displays (once; a second call is ignored and
/// returns false).
pub fn install(bars: &'static dyn Bars) -> bool {
    BARS.set(bars).is_ok()
}

/// A display of `len` steps of a computation of `kind` from the installed maker, or
/// [`NoProgress`] when `show` is false or no maker is installed.
pub(crate) fn bar(kind: BarKind<'_>, len: u64, show: bool) -> Box<dyn Progress> {
    match BARS.get() {
        Some(b) if show => b.bar(kind, len),
        _ => Box::new(NoProgress),
    }
}
