//! Documented shell commands run as written: a scratch root mirroring the checkout through
//! links (`target/NAME/root`), `gman` on `PATH` this build's binary, `../shared` the
//! checkout's neighbour, and the firmware's build directory of its own. A command too long for
//! a test runs at a test budget ([`at_test_budget`]), its other words as written.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The logical command lines (continuations joined, comments and blank lines dropped) of every
/// `sh`/`bash` block of `text`.
pub fn shell_commands(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut body: Option<String> = None;
    for line in text.lines() {
        if let Some(lang) = line.trim().strip_prefix("```") {
            match body.take() {
                Some(b) => out.extend(block_commands(&b)),
                None if matches!(lang, "sh" | "bash" | "shell" | "console") => {
                    body = Some(String::new())
                }
                None => {}
            }
            continue;
        }
        if let Some(b) = body.as_mut() {
            b.push_str(line);
            b.push('\n');
        }
    }
    // A block left open at the end of the text still holds its commands.
    out.extend(body.iter().flat_map(|b| block_commands(b)));
    out
}

/// The logical command lines of one block's body, as [`shell_commands`] reads them.
pub fn block_commands(body: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut pending = String::new();
    for line in body.lines() {
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        let t = t.split(" # ").next().unwrap_or(t).trim_end();
        if let Some(head) = t.strip_suffix('\\') {
            pending.push_str(head.trim_end());
            pending.push(' ');
        } else {
            pending.push_str(t);
            out.push(std::mem::take(&mut pending));
        }
    }
    out
}

/// The `sh` block of `text` whose first command starts with `first`, as written.
pub fn sh_block<'a>(text: &'a str, first: &str) -> Option<&'a str> {
    text.split("```sh\n").skip(1).find_map(|b| {
        let block = b.split("```").next()?;
        block_commands(block)
            .first()
            .is_some_and(|c| c.starts_with(first))
            .then_some(block)
    })
}

/// The checkout, as a canonical path.
pub fn checkout() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .canonicalize()
        .expect("the checkout")
}

#[path = "../../../tests/tests/support/device_tools.rs"]
mod probe;

/// Whether QEMU and the Cortex-M4F target are here; else `test` is skipped, or fails under
/// `GMAN_REQUIRE_QEMU=1` (CI).
pub fn device_tools(test: &str) -> bool {
    probe::device_tools(test, false)
}

#[cfg(unix)]
fn link(from: &Path, to: &Path) {
    let _ = std::fs::remove_file(to);
    std::os::unix::fs::symlink(from, to)
        .unwrap_or_else(|e| panic!("link {} -> {}: {e}", to.display(), from.display()));
}

/// Links every entry of `from` into `to` but those named in `except`.
#[cfg(unix)]
fn mirror(from: &Path, to: &Path, except: &[&str]) {
    for entry in std::fs::read_dir(from).expect("read the checkout") {
        let entry = entry.expect("a directory entry");
        let name = entry.file_name();
        if !except.iter().any(|e| name == *e) {
            link(&entry.path(), &to.join(&name));
        }
    }
}

/// A scratch root where documented commands run as a user runs them from the checkout.
pub struct Scratch {
    /// `target/NAME`: the root's parent (`../shared` links from here).
    pub dir: PathBuf,
    /// `target/NAME/root`: the commands' working directory.
    pub root: PathBuf,
    /// Whether `../shared/data/gman` is there.
    pub have_data: bool,
}

#[cfg(unix)]
impl Scratch {
    /// A fresh `target/NAME/root`: the checkout's entries linked into it but `target`, `runs`
    /// and what the commands write at the root, with firmware-example a real directory of
    /// links, so that a `$PWD/..` from inside it names the scratch root, not the checkout.
    pub fn new(name: &str) -> Scratch {
        let repo = checkout();
        let dir = repo.join("target").join(name);
        let root = dir.join("root");
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(&root).expect("the scratch root");
        mirror(&repo, &root, &["target", "runs", "firmware-example"]);
        let fw = root.join("firmware-example");
        std::fs::create_dir(&fw).expect("the scratch firmware directory");
        mirror(&repo.join("firmware-example"), &fw, &["target"]);
        let shared = repo.join("../shared");
        let have_data = shared.join("data/gman/attributes.json").is_file();
        if have_data {
            link(&shared.canonicalize().unwrap(), &dir.join("shared"));
        }
        Scratch {
            dir,
            root,
            have_data,
        }
    }

    /// Runs `script` with `bash -eo pipefail` in the scratch root (at most 15 minutes);
    /// panics naming `what` with the output when it fails.
    pub fn run(&self, what: &str, script: &str) -> Output {
        let bin = Path::new(env!("CARGO_BIN_EXE_gman")).parent().unwrap();
        let path = format!(
            "{}:{}",
            bin.display(),
            std::env::var("PATH").unwrap_or_default()
        );
        let out = Command::new("timeout")
            .arg("900")
            .args(["bash", "-eo", "pipefail", "-c", script])
            .current_dir(&self.root)
            .env("PATH", &path)
            .env("CARGO_TARGET_DIR", self.dir.join("firmware-target"))
            .env_remove("GMAN_FIRMWARE_BLOB")
            .output()
            .expect("run bash");
        assert!(
            out.status.success(),
            "{what} failed ({:?}):\n{script}\n--- stdout\n{}\n--- stderr\n{}",
            out.status,
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        out
    }
}

/// A documented command at the test's budget: in a `gman train` command `--updates N` becomes
/// `--config tiny --updates 10`; a `gman eval` command gets `--episodes 5` (at most 5 episodes
/// per episode file); without the data directory (`have_data` false) a `--data DIR` goes.
/// Other commands are returned as they are.
pub fn at_test_budget(cmd: &str, have_data: bool) -> String {
    let words: Vec<&str> = cmd.split(' ').collect();
    let train = cmd.contains("gman train ");
    let eval = cmd.contains("gman eval ");
    let mut out = Vec::new();
    let mut i = 0;
    while i < words.len() {
        match words[i] {
            "--updates" if train && i + 1 < words.len() => {
                out.extend(["--config", "tiny", "--updates", "10"]);
                i += 2;
            }
            "--data" if !have_data && (train || eval) && i + 1 < words.len() => i += 2,
            w => {
                out.push(w);
                i += 1;
            }
        }
    }
    let mut line = out.join(" ");
    if eval {
        // Before a loop's `; done` when the command ends one.
        match line.strip_suffix("; done") {
            Some(head) => line = format!("{head} --episodes 5; done"),
            None => line.push_str(" --episodes 5"),
        }
    }
    line
}
