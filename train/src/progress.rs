//! The progress bars of the long commands (evaluation, pre-training, training): one place
//! for how a bar is made, hidden when not wanted (`--quiet`).

use indicatif::{ProgressBar, ProgressStyle};

/// A bar of `len` steps drawn with the indicatif `template`, or a hidden bar when `show` is
/// false.
pub fn bar(len: u64, template: &str, show: bool) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let b = ProgressBar::new(len);
    b.set_style(
        ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    b
}

/// The template of the pre-training bars.
pub const PRETRAIN: &str = "{bar:30} {pos}/{len} [{elapsed_precise}<{eta_precise}] {msg}";
