//! The model's settings on the command line: one flag per setting of gman-core's
//! [`ModelSpec`], declared once ([`ModelArgs`]) and shared by `gman train`, `gman eval` and
//! `gman emd-report`, each flag an override of a spec the command starts from (a new run's:
//! the paper's settings; an evaluated model's: its own). [`ModelArgs::apply`] writes the given
//! flags into a spec and checks it with [`ModelSpec::validate`].
//!
//! The doc comments below are `gman train`'s help. `gman eval` and `gman emd-report`, whose
//! default is the model's own setting, word the flags as overrides ([`ModelArgs::eval_help`],
//! [`ModelArgs::emd_report_help`]); `gman train` shows the paper's settings as its defaults
//! ([`ModelArgs::train_defaults`]).

use std::sync::OnceLock;

use clap::{Arg, Args};
use gman_core::navigator::memory::AdaptMode;
use gman_core::navigator::{NoiseMode, StepRule};
use gman_core::spec::schema::AdaptLossKind;
use gman_core::spec::{ModelSpec, SpecError};

use super::args::named;

/// The model's settings a command line may set (all optional: a flag not given keeps the
/// setting of the spec it is applied to; a switch given turns its setting on).
#[derive(Clone, Debug, Default, Args)]
pub struct ModelArgs {
    /// Inner learning rates α1 (D) and α2 (θ, φ) (paper: 1e-4).
    #[arg(long)]
    pub inner_lr: Option<f32>,
    /// At most this many inner updates per episode (GMAN variants).
    #[arg(long)]
    pub max_inner: Option<u32>,
    /// α1 alone, D's ascent rate on L_D (default: --inner-lr, the paper's α1 = α2).
    #[arg(long, value_name = "ALPHA1")]
    pub disc_lr: Option<f32>,
    /// D's ascent steps on L_D per inner update (paper: 1).
    #[arg(long, value_name = "N")]
    pub disc_steps: Option<u32>,
    /// The descent step of θ and φ on L_ad: `gradient` (α2 ∇, the paper), `normalized`
    /// (α2 ∇/‖∇‖: --inner-lr is then the step's length) or `per-group` (θ and φ each
    /// normalised to that length). Recorded in the blob.
    #[arg(long, value_parser = named::<StepRule>())]
    pub step_rule: Option<StepRule>,
    /// D restarts with every episode: layer 1 from ω, the output layer (w2, b2) at zero, so
    /// D's first ascent step sets the head from the episode's own buffer; ω then does not
    /// learn across episodes (paper: off, D persists). Recorded in the blob.
    #[arg(long)]
    pub disc_head_reset: bool,
    /// The form of L_ad: `paper` (Eq. 3) or `reference` (‖Σ_t a_t (−D(x_t))‖₂, the
    /// reference implementation's). Recorded in the blob.
    #[arg(long, value_parser = named::<AdaptLossKind>())]
    pub adapt_loss: Option<AdaptLossKind>,
    /// Scale L_D's critic terms by 10, as the reference implementation does (the paper: 1).
    /// Recorded in the blob.
    #[arg(long)]
    pub reference_critic: bool,
    /// The inner loop's descent step on L_ad adapts only the actor head; G stays at θ (the
    /// reference implementation's default, whose G gets no inner gradient; the paper: G and
    /// the head). Recorded in the blob.
    #[arg(long)]
    pub adapt_head_only: bool,
    /// The inner update's commit delay D in steps (0..=63): the update that starts when Ψ
    /// fills takes effect D steps later, the steps between acting on the current parameters
    /// and not recorded in Ψ; what a device that computes the update in slices, or at a lower
    /// priority, runs (see docs/device.md). 0: at once (the paper). Recorded in the blob.
    #[arg(long, value_name = "D")]
    pub commit_delay: Option<u32>,
    /// Adaptation mode of the inner loop (in training and on the device; blobs record it):
    /// `efficient` (per-unit gains and biases, what the microcontroller runs) or `full`
    /// (every parameter). Default: efficient for the mcu preset, full for paper.
    #[arg(long, value_parser = named::<AdaptMode>())]
    pub adapt_mode: Option<AdaptMode>,
    /// Noise z of G at navigation time, in training and wherever the model runs (recorded in
    /// the checkpoint and the blob; a resumed run keeps its own).
    #[arg(long, value_parser = named::<NoiseMode>())]
    pub noise: Option<NoiseMode>,
}

impl ModelArgs {
    /// Writes the settings given into `spec` (`--inner-lr` sets α2, and α1 unless the spec
    /// has its own), then checks the result ([`ModelSpec::validate`]).
    pub fn apply(&self, spec: &mut ModelSpec) -> Result<(), SpecError> {
        self.write(spec);
        spec.validate()
    }

    /// [`ModelArgs::apply`] without the check (for a check of another setting that must not
    /// report these settings' ranges first).
    pub fn write(&self, spec: &mut ModelSpec) {
        let r = &mut spec.inner_rule;
        set(&mut spec.inner_lr, self.inner_lr);
        set(&mut spec.max_inner, self.max_inner);
        if self.disc_lr.is_some() {
            r.disc_lr = self.disc_lr;
        }
        set(&mut r.disc_steps, self.disc_steps);
        set(&mut r.step_rule, self.step_rule);
        r.disc_head_reset |= self.disc_head_reset;
        set(&mut r.adapt_loss, self.adapt_loss);
        r.reference_critic |= self.reference_critic;
        r.head_only |= self.adapt_head_only;
        set(&mut r.commit_delay, self.commit_delay);
        set(&mut spec.adapt_mode, self.adapt_mode);
        set(&mut spec.noise, self.noise);
    }

    /// The flags given, as the command line spells them.
    pub fn given(&self) -> Vec<&'static str> {
        [
            ("--inner-lr", self.inner_lr.is_some()),
            ("--max-inner", self.max_inner.is_some()),
            ("--disc-lr", self.disc_lr.is_some()),
            ("--disc-steps", self.disc_steps.is_some()),
            ("--step-rule", self.step_rule.is_some()),
            ("--disc-head-reset", self.disc_head_reset),
            ("--adapt-loss", self.adapt_loss.is_some()),
            ("--reference-critic", self.reference_critic),
            ("--adapt-head-only", self.adapt_head_only),
            ("--commit-delay", self.commit_delay.is_some()),
            ("--adapt-mode", self.adapt_mode.is_some()),
            ("--noise", self.noise.is_some()),
        ]
        .into_iter()
        .filter_map(|(flag, given)| given.then_some(flag))
        .collect()
    }

    /// `gman train`'s defaults, shown in its help: the paper's settings
    /// ([`ModelSpec::paper`]; `--adapt-mode` follows the preset, `--disc-lr` follows
    /// `--inner-lr`). Applied to the paper's settings they change nothing.
    pub fn train_defaults(a: Arg) -> Arg {
        static DEFAULTS: OnceLock<Vec<(&'static str, String)>> = OnceLock::new();
        let table = DEFAULTS.get_or_init(|| {
            let p = ModelSpec::paper(AdaptMode::Efficient);
            let r = p.inner_rule;
            vec![
                ("inner_lr", p.inner_lr.to_string()),
                ("max_inner", p.max_inner.to_string()),
                ("disc_steps", r.disc_steps.to_string()),
                ("step_rule", r.step_rule.to_string()),
                ("adapt_loss", r.adapt_loss.to_string()),
                ("commit_delay", r.commit_delay.to_string()),
                ("noise", p.noise.to_string()),
            ]
        });
        match table.iter().find(|(id, _)| a.get_id() == *id) {
            Some((_, v)) => a.default_value(v.as_str()),
            None => a,
        }
    }

    /// `gman eval`'s wording of the flags: overrides of the evaluated model's settings.
    pub fn eval_help(a: Arg) -> Arg {
        reword(a, &[EVAL_HELP, OVERRIDE_HELP])
    }

    /// `gman emd-report`'s wording of the flags: overrides of the measured model's settings.
    pub fn emd_report_help(a: Arg) -> Arg {
        reword(a, &[EMD_REPORT_HELP, OVERRIDE_HELP])
    }
}

/// A setting a resumed `gman train` run keeps: its flag, the flag's clap id, and the
/// setting's two values in a pair of `T` as the refusal prints them, when they differ.
pub(super) type Kept<T> = (
    &'static str,
    &'static str,
    fn(&T, &T) -> Option<(String, String)>,
);

/// A [`Kept`] entry over a `$t`: `|c| get` reads the setting (`None`: not compared).
macro_rules! kept {
    ($t:ty: $flag:literal, $id:literal, |$c:ident| $get:expr) => {
        ($flag, $id, |a: &$t, b: &$t| differs(a, b, |$c: &$t| $get))
    };
}
pub(super) use kept;

/// The setting `get` of `a` and `b` when both have it and they differ.
pub(super) fn differs<C, T: PartialEq + std::fmt::Debug>(
    a: &C,
    b: &C,
    get: impl Fn(&C) -> Option<T>,
) -> Option<(String, String)> {
    match (get(a), get(b)) {
        (Some(x), Some(y)) if x != y => Some((format!("{x:?}"), format!("{y:?}"))),
        _ => None,
    }
}

/// The model's settings a resumed `gman train` run keeps, in the order a resume checks them,
/// before the run's own (`train_config`'s `KEPT`): given on `--resume`, a flag must agree
/// with the stored setting. `--adapt-mode` is the run's (its default is the preset's);
/// `--noise` is not compared (a resumed run keeps its own).
#[rustfmt::skip]
pub(super) const KEPT: &[Kept<ModelSpec>] = &[
    kept!(ModelSpec: "--inner-lr", "inner_lr", |c| Some(c.inner_lr)),
    kept!(ModelSpec: "--max-inner", "max_inner", |c| Some(c.max_inner)),
    kept!(ModelSpec: "--disc-lr", "disc_lr", |c| Some(c.inner_rule.disc_lr)),
    kept!(ModelSpec: "--disc-steps", "disc_steps", |c| Some(c.inner_rule.disc_steps)),
    kept!(ModelSpec: "--step-rule", "step_rule", |c| Some(c.inner_rule.step_rule)),
    kept!(ModelSpec: "--disc-head-reset", "disc_head_reset", |c| Some(c.inner_rule.disc_head_reset)),
    kept!(ModelSpec: "--adapt-loss", "adapt_loss", |c| Some(c.inner_rule.adapt_loss)),
    kept!(ModelSpec: "--reference-critic", "reference_critic", |c| Some(c.inner_rule.reference_critic)),
    kept!(ModelSpec: "--adapt-head-only", "adapt_head_only", |c| Some(c.inner_rule.head_only)),
    kept!(ModelSpec: "--commit-delay", "commit_delay", |c| Some(c.inner_rule.commit_delay)),
];

/// `*to = v` when `v` is given.
fn set<T>(to: &mut T, v: Option<T>) {
    if let Some(v) = v {
        *to = v;
    }
}

/// A flag's help and value name in one command, by its id.
type Wording = (&'static str, &'static str, Option<&'static str>);

/// `a` with the help and value name of the first entry for its id in `tables` (unchanged
/// when none has one).
fn reword(a: Arg, tables: &[&[Wording]]) -> Arg {
    match tables
        .iter()
        .flat_map(|t| t.iter())
        .find(|e| a.get_id() == e.0)
    {
        Some(&(_, help, value)) => {
            let a = a.help(help);
            match value {
                Some(v) => a.value_name(v),
                None => a,
            }
        }
        None => a,
    }
}

/// `gman eval`'s own wording of the flags it has always had.
const EVAL_HELP: &[Wording] = &[
    (
        "inner_lr",
        "Override the model's inner-loop rate α (α1 = α2) at evaluation (default: the rate the \
         model was trained with, which checkpoints and blobs store and `gman inspect` shows; a \
         blob of format v1, which has no field for it, runs the paper's 1e-4)",
        Some("ALPHA"),
    ),
    (
        "max_inner",
        "Override the cap on inner updates per episode at evaluation (default: the model's, 4)",
        Some("N"),
    ),
    (
        "adapt_head_only",
        "At evaluation, the inner loop's descent step adapts only the actor head; G stays at θ \
         (the reference implementation's default)",
        None,
    ),
];

/// `gman emd-report`'s own wording of the flags it has always had.
const EMD_REPORT_HELP: &[Wording] = &[
    (
        "inner_lr",
        "Override the inner-loop rate α (α1 = α2)",
        Some("ALPHA"),
    ),
    (
        "max_inner",
        "Override the cap on inner updates per episode",
        Some("N"),
    ),
    (
        "adapt_head_only",
        "The descent step adapts only the actor head (G stays at θ; the reference's default)",
        None,
    ),
];

/// The wording of the other flags as overrides, for both commands.
const OVERRIDE_HELP: &[Wording] = &[
    (
        "disc_lr",
        "Override α1 alone (D's ascent rate on L_D)",
        None,
    ),
    (
        "disc_steps",
        "Override D's ascent steps per inner update",
        None,
    ),
    (
        "step_rule",
        "Override the descent step rule (`gradient` or `normalized`)",
        None,
    ),
    (
        "disc_head_reset",
        "D restarts with every episode (layer 1 from ω, the output layer at zero): D starts \
         with no opinion and its first ascent step on L_D sets the head from the episode's \
         buffer",
        None,
    ),
    (
        "adapt_loss",
        "Override the form of L_ad: `paper` (Eq. 3) or `reference` (the reference \
         implementation's)",
        None,
    ),
    (
        "reference_critic",
        "Scale L_D's critic terms by 10, as the reference implementation does (the paper: 1)",
        None,
    ),
    (
        "commit_delay",
        "Override the inner update's commit delay D (steps from Ψ filling to the update taking \
         effect, 0..=63; default: the model's, 0 for models trained without it), e.g. to \
         measure what a device's delay costs a model. An experiment on the host: like every \
         override here it replaces what the model records. A device runs the blob's own delay \
         (the C API's `gman_options.settings.commit_delay` may only add one to a blob that \
         records none)",
        None,
    ),
    (
        "adapt_mode",
        "Override the adaptation mode of the inner loop (default: the mode the model was \
         trained in, which blobs record)",
        None,
    ),
    (
        "noise",
        "Override the noise z of G at navigation time (default: the model's)",
        None,
    ),
];

#[cfg(test)]
mod tests {
    use super::*;
    use clap::{Command, CommandFactory, FromArgMatches};

    fn parse(cmd: Command, args: &[&str]) -> ModelArgs {
        let m = cmd.try_get_matches_from(args).unwrap();
        ModelArgs::from_arg_matches(&m).unwrap()
    }

    /// `gman train`'s defaults applied to the paper's settings change nothing.
    #[test]
    fn train_defaults_are_the_paper_settings() {
        let cmd = ModelArgs::augment_args(Command::new("t")).mut_args(ModelArgs::train_defaults);
        let args = parse(cmd, &["t"]);
        for mode in [AdaptMode::Full, AdaptMode::Efficient] {
            let mut spec = ModelSpec::paper(mode);
            assert_eq!(args.apply(&mut spec), Ok(()));
            assert_eq!(spec, ModelSpec::paper(mode));
        }
        let none = parse(ModelArgs::augment_args(Command::new("t")), &["t"]);
        assert!(none.given().is_empty());
    }

    /// Every flag writes its setting, and the result is checked.
    #[test]
    fn apply_writes_every_setting_and_checks_the_ranges() {
        let flags = [
            "t",
            "--inner-lr",
            "0.5",
            "--max-inner",
            "7",
            "--disc-lr",
            "0.05",
            "--disc-steps",
            "5",
            "--step-rule",
            "per-group",
            "--disc-head-reset",
            "--adapt-loss",
            "reference",
            "--reference-critic",
            "--adapt-head-only",
            "--commit-delay",
            "17",
            "--adapt-mode",
            "efficient",
            "--noise",
            "zero",
        ];
        let args = parse(ModelArgs::augment_args(Command::new("t")), &flags);
        assert_eq!(args.given().len(), 12);
        let mut spec = ModelSpec::paper(AdaptMode::Full);
        assert_eq!(args.apply(&mut spec), Ok(()));
        // The flags give EVERY_SETTING_CHANGED's values (the flag-settable ones), but the
        // mode, which starts Full here.
        let c = ModelSpec::EVERY_SETTING_CHANGED;
        let expected = ModelSpec {
            noise: c.noise,
            inner_lr: c.inner_lr,
            max_inner: c.max_inner,
            adapt_mode: AdaptMode::Efficient,
            inner_rule: c.inner_rule,
            ..ModelSpec::paper(AdaptMode::Full)
        };
        assert_eq!(spec, expected);
        let bad = parse(
            ModelArgs::augment_args(Command::new("t")),
            &["t", "--commit-delay", "64"],
        );
        assert_eq!(
            bad.apply(&mut ModelSpec::paper(AdaptMode::Full)),
            Err(SpecError::CommitDelay(64))
        );
    }

    /// `gman train`, `gman eval` and `gman emd-report` take every flag of the group.
    #[test]
    fn every_model_command_takes_every_setting() {
        let group = ModelArgs::augment_args(Command::new("t"));
        let cli = super::super::Cli::command();
        for name in ["train", "eval", "emd-report"] {
            let sub = cli.find_subcommand(name).unwrap();
            for arg in group.get_arguments() {
                assert!(
                    sub.get_arguments()
                        .any(|a| a.get_id() == arg.get_id() && a.get_long() == arg.get_long()),
                    "gman {name} has no --{}",
                    arg.get_long().unwrap_or("?")
                );
            }
        }
    }
}
