//! The terminal progress bars (indicatif, on stderr) of the long commands: gman-train reports
//! progress through its [`Progress`] trait, and `main` installs [`TerminalBars`] as the maker
//! of the displays.

use gman_host_sim::progress::{BarKind, Bars, Progress};
use indicatif::{ProgressBar, ProgressStyle};

/// The bar templates of evaluation, pre-training and training.
const EVAL: &str = "{spinner} eval [{elapsed_precise}] {bar:40} {pos}/{len} episodes ({eta})";
const PRETRAIN: &str = "{bar:30} {pos}/{len} [{elapsed_precise}<{eta_precise}] {msg}";
const TRAIN: &str = "{spinner} train {prefix} [{elapsed_precise}] {bar:30} {pos}/{len} {msg}";

/// Draws every progress display as an indicatif bar.
pub struct TerminalBars;

/// One indicatif bar.
struct Bar(ProgressBar);

impl Progress for Bar {
    fn set_position(&self, pos: u64) {
        self.0.set_position(pos);
    }
    fn inc(&self, n: u64) {
        self.0.inc(n);
    }
    fn set_message(&self, msg: String) {
        self.0.set_message(msg);
    }
    fn finish(&self) {
        self.0.finish_and_clear();
    }
}

impl Bars for TerminalBars {
    fn bar(&self, kind: BarKind<'_>, len: u64) -> Box<dyn Progress> {
        let template = match kind {
            BarKind::Eval => EVAL,
            BarKind::Pretrain => PRETRAIN,
            BarKind::Train { .. } => TRAIN,
        };
        let b = ProgressBar::new(len);
        b.set_style(
            ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        if let BarKind::Train { method } = kind {
            b.set_prefix(method.to_string());
        }
        Box::new(Bar(b))
    }
}
