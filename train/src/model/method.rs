//! The methods of the paper's tables: independent switches (FG, PS, the inner loop, the
//! EMD, θ trained) with named presets.

use gman_core::spec::schema::Emd;
use serde::{Deserialize, Serialize};

/// When the inner loop of Algorithm 1 (the EMD's adaptation) runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum InnerLoop {
    /// Never (the A3C baselines and the `gman-noemd` control).
    Off,
    /// At evaluation only: trained without it, adapted at test time (`gman-nometa`).
    EvalOnly,
    /// In training and at evaluation, so θ and φ are meta-learned through it (GMAN).
    Meta,
}

/// A navigation method: independent switches. The rows of the paper's Tables 2 and 3 are
/// the named presets of [`Method::PRESETS`] (`--method a3c`, `gman`, ...); a new variant is
/// one line there plus the maths of its new switch.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Method {
    /// Uses the pre-trained feature generator G (FG); otherwise G is zero and x_t carries
    /// nothing.
    pub fg: bool,
    /// Feeds the PS module's prediction to the policy (the † rows).
    pub ps: bool,
    /// When the inner loop runs.
    pub inner: InnerLoop,
    /// What scores generated features in the inner loop (D, or the cosine similarity).
    pub emd: Emd,
    /// The outer loop updates G's θ (the FG baselines keep the pre-trained generator frozen,
    /// as the paper's "FG" row).
    pub train_theta: bool,
}

/// One preset: its name on the command line and in files, its switches, its help text.
type Preset = (&'static str, Method, &'static str);

const fn m(fg: bool, ps: bool, inner: InnerLoop, emd: Emd, train_theta: bool) -> Method {
    Method {
        fg,
        ps,
        inner,
        emd,
        train_theta,
    }
}

use Emd::{CosSim, Discriminator as D};
use InnerLoop::{EvalOnly, Meta, Off};

#[allow(non_upper_case_globals)]
impl Method {
    /// The paper's rows, in `--help` order: name, switches
    /// (`fg, ps, inner loop, EMD, θ trained`), help.
    #[rustfmt::skip]
    pub const PRESETS: [Preset; 11] = [
        ("a3c", m(false, false, Off, D, false),
         "A3C baseline: observation, target attributes, previous action → LSTM → actor-critic"),
        ("a3c-fg", m(true, false, Off, D, false),
         "A3C + the pre-trained feature generator's target feature (FG), no adaptation"),
        ("a3c-ps", m(false, true, Off, D, false), "A3C with the PS module (A3C†)"),
        ("a3c-fg-ps", m(true, true, Off, D, false), "A3C + FG + PS"),
        ("gman", m(true, false, Meta, D, true),
         "GMAN: FG + environmental meta discriminator, meta-trained (Algorithm 1)"),
        ("gman-ps", m(true, true, Meta, D, true), "GMAN with the PS module (GMAN†)"),
        ("gman-nometa", m(true, false, EvalOnly, D, false),
         "EMD without meta-learning: trained as A3C + FG, adapted at test time only"),
        ("gman-cossim", m(true, false, Meta, CosSim, true),
         "EMD variant: cosine similarity between x_t and s_t in place of D (paper Table 3), meta-trained like GMAN"),
        ("gman-noemd", m(true, false, Off, D, true),
         "Control without the EMD: θ and the policy trained by the outer loop as in GMAN, but no inner loop runs, in training or at evaluation (differs from a3c-fg only in that θ is trained, from gman only in the adaptation)"),
        ("gman-fixed-g", m(true, false, Meta, D, false),
         "GMAN with G kept at the pre-trained generator by the outer loop: only the inner loop moves θ, per episode (the outer loop meta-trains the policy; the meta-trained G of `gman` drifts off the feature space)"),
        ("gman-noemd-ps", m(true, true, Off, D, true),
         "Control of GMAN† without the EMD: `gman-noemd` with the PS module (differs from gman-ps only in the adaptation)"),
    ];
    /// A3C baseline.
    pub const A3c: Method = Method::PRESETS[0].1;
    /// A3C + FG.
    pub const A3cFg: Method = Method::PRESETS[1].1;
    /// A3C with the PS module (A3C†).
    pub const A3cPs: Method = Method::PRESETS[2].1;
    /// A3C + FG + PS.
    pub const A3cFgPs: Method = Method::PRESETS[3].1;
    /// GMAN (Algorithm 1).
    pub const Gman: Method = Method::PRESETS[4].1;
    /// GMAN with the PS module (GMAN†).
    pub const GmanPs: Method = Method::PRESETS[5].1;
    /// EMD without meta-learning (adapted at test time only).
    pub const GmanNometa: Method = Method::PRESETS[6].1;
    /// The CosSim EMD variant, meta-trained.
    pub const GmanCossim: Method = Method::PRESETS[7].1;
    /// θ trained as in GMAN, no inner loop.
    pub const GmanNoemd: Method = Method::PRESETS[8].1;
    /// GMAN with θ frozen in the outer loop (adapted per episode only).
    pub const GmanFixedG: Method = Method::PRESETS[9].1;
    /// θ trained as in GMAN†, no inner loop (the control of GMAN†).
    pub const GmanNoemdPs: Method = Method::PRESETS[10].1;

    fn preset(self) -> Option<&'static Preset> {
        Method::PRESETS.iter().find(|p| p.1 == self)
    }

    /// The preset name used on the command line and in files; `"custom"` for a combination
    /// of switches that is no preset (such a method cannot be stored in a checkpoint).
    pub fn name(self) -> &'static str {
        self.preset().map_or("custom", |p| p.0)
    }

    /// Parses [`Method::name`].
    pub fn parse(s: &str) -> Option<Method> {
        Method::PRESETS.iter().find(|p| p.0 == s).map(|p| p.1)
    }

    /// Uses the pre-trained feature generator (otherwise G is zero and x_t carries nothing).
    pub fn uses_fg(self) -> bool {
        self.fg
    }

    /// Feeds the PS module's prediction to the policy.
    pub fn uses_ps(self) -> bool {
        self.ps
    }

    /// Runs the inner loop during training (and therefore meta-learns θ and φ through it).
    pub fn adapts_in_training(self) -> bool {
        self.inner == Meta
    }

    /// Scores generated features with the cosine similarity instead of D.
    pub fn uses_cossim(self) -> bool {
        self.emd == CosSim
    }

    /// What scores generated features in the inner loop.
    pub fn emd(self) -> Emd {
        self.emd
    }

    /// Runs the inner loop at evaluation.
    pub fn adapts_at_eval(self) -> bool {
        self.inner != Off
    }

    /// The outer loop updates G's θ (the meta-trained methods and their `gman-noemd`
    /// control; the FG baselines keep the pre-trained generator frozen, as the paper's "FG"
    /// row).
    pub fn trains_generator(self) -> bool {
        self.train_theta
    }
}

impl Serialize for Method {
    /// As its preset name (the form checkpoints store); `"custom"` for a
    /// combination that is no preset, which [`Method::parse`] then refuses on reading.
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl<'de> Deserialize<'de> for Method {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Method, D::Error> {
        let name = String::deserialize(d)?;
        Method::parse(&name)
            .ok_or_else(|| serde::de::Error::custom(format!("unknown method {name:?}")))
    }
}
