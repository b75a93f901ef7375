//! Method recipes: a name for a method preset together with model settings, for
//! `gman train --method NAME`. A recipe is shorthand, expanded on the command line before it
//! is parsed: its base method replaces the name, and its settings' flags go in front of the
//! user's, each one only where the user did not give that flag (so an explicit flag wins).
//! The run then records the base method and the settings like any other run: its checkpoint,
//! its blob and its evaluation hold nothing a recipe-less command line could not write.

use std::ffi::OsString;

/// One recipe: its name, the method preset it builds on, the settings' flags, what it is.
pub struct Recipe {
    /// The name `--method` takes.
    pub name: &'static str,
    /// The [`Method`](gman_host_sim::model::Method) preset it builds on.
    pub base: &'static str,
    /// The model settings' flags (`ModelArgs`), each flag followed by its value if it has one.
    pub flags: &'static [&'static str],
    /// One line for `gman train --help`.
    pub help: &'static str,
}

/// Every recipe.
pub const RECIPES: [Recipe; 1] = [Recipe {
    name: "gman-ref",
    base: "gman-fixed-g",
    flags: &[
        "--noise",
        "zero",
        "--disc-lr",
        "0",
        "--adapt-head-only",
        "--adapt-loss",
        "reference",
        "--inner-lr",
        "0.01",
    ],
    help: "the reference implementation as released: z = 0, G frozen in both loops, D at its pre-trained weights (α1 = 0), the inner step on the actor head only, on the reference's L_ad = ‖Σ_t a_t (−D(x_t))‖₂, α2 = 0.01",
}];

/// The `gman train --help` lines of the recipes.
pub fn help() -> String {
    RECIPES
        .iter()
        .map(|r| {
            format!(
                "`--method {}` is `--method {} {}`: {}",
                r.name,
                r.base,
                r.flags.join(" "),
                r.help
            )
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// `args` (the whole command line, program name first) with a `gman train --method RECIPE`
/// expanded; any other command line unchanged.
pub fn expand(args: Vec<OsString>) -> Vec<OsString> {
    if args.get(1).and_then(|a| a.to_str()) != Some("train") {
        return args;
    }
    let text: Vec<Option<&str>> = args.iter().map(|a| a.to_str()).collect();
    // The recipe and where its name stands (`--method NAME` or `--method=NAME`).
    let found = text.iter().enumerate().find_map(|(i, a)| {
        let (name, at) = match *a {
            Some("--method") => (text.get(i + 1).copied().flatten()?, i + 1),
            Some(s) => (s.strip_prefix("--method=")?, i),
            None => return None,
        };
        RECIPES.iter().find(|r| r.name == name).map(|r| (r, at))
    });
    let Some((recipe, at)) = found else {
        return args;
    };
    let given = |flag: &str| {
        text.iter().flatten().any(|a| {
            *a == flag
                || a.strip_prefix(flag)
                    .is_some_and(|rest| rest.starts_with('='))
        })
    };
    let mut out: Vec<OsString> = args[..2].to_vec();
    let mut flags = recipe.flags.iter().peekable();
    while let Some(&flag) = flags.next() {
        let value = flags.next_if(|v| !v.starts_with("--")).copied();
        if !given(flag) {
            out.push(flag.into());
            out.extend(value.map(OsString::from));
        }
    }
    for (i, a) in args.iter().enumerate().skip(2) {
        if i == at {
            out.push(if text[i].is_some_and(|s| s.starts_with("--method=")) {
                format!("--method={}", recipe.base).into()
            } else {
                recipe.base.into()
            });
        } else {
            out.push(a.clone());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(args: &[&str]) -> Vec<String> {
        expand(args.iter().map(OsString::from).collect())
            .into_iter()
            .map(|a| a.into_string().unwrap())
            .collect()
    }

    #[test]
    fn a_recipe_expands_to_its_base_and_settings() {
        let out = run(&["gman", "train", "--method", "gman-ref", "--seed", "3"]);
        let mut want = vec!["gman", "train"];
        want.extend_from_slice(RECIPES[0].flags);
        want.extend(["--method", "gman-fixed-g", "--seed", "3"]);
        assert_eq!(out, want);
        let eq = run(&["gman", "train", "--method=gman-ref"]);
        assert_eq!(eq.last().unwrap(), "--method=gman-fixed-g");
    }

    #[test]
    fn an_explicit_flag_wins_over_the_recipe() {
        let out = run(&["gman", "train", "--inner-lr=0.5", "--method", "gman-ref"]);
        assert!(!out.contains(&"0.01".to_string()), "{out:?}");
        assert!(out.contains(&"--inner-lr=0.5".to_string()));
        assert!(out.contains(&"--noise".to_string()));
    }

    #[test]
    fn other_command_lines_are_unchanged() {
        for args in [
            &["gman", "train", "--method", "gman"][..],
            &["gman", "eval", "--method", "gman-ref"],
            &["gman"],
        ] {
            assert_eq!(run(args), args);
        }
    }
}
