//! The documentation's commands against the product: every shell block in README.md, docs/ and
//! the crates' READMEs is either run by a test or listed here with the reason it is not (a new
//! command fails until it is one or the other); the tables that `scripts/gen_docs.py` generates
//! are what `gman table` prints; the README's random row is what its command prints.

mod common;

use common::scratch::{block_commands, sh_block, shell_commands};

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn gman(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_gman"))
        .args(args)
        .current_dir(root())
        .output()
        .expect("run gman");
    assert!(
        out.status.success(),
        "gman {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The Markdown files whose commands a user is told to run.
fn doc_files() -> Vec<PathBuf> {
    let r = root();
    let mut v = vec![
        r.join("README.md"),
        r.join("results/paper/README.md"),
        r.join("results/paper/models/README.md"),
        r.join("host-sim/models/README.md"),
    ];
    for dir in ["docs", "."] {
        let base = r.join(dir);
        for e in std::fs::read_dir(&base).unwrap().flatten() {
            let p = e.path();
            if dir == "docs" && p.extension().is_some_and(|x| x == "md") {
                v.push(p);
            } else if dir == "." && p.is_dir() && p.join("README.md").is_file() {
                v.push(p.join("README.md"));
            }
        }
    }
    v.sort();
    v.dedup();
    v
}

/// Each documented command, by the start of its line: the test that runs it, or why the tests
/// do not run it as written. A command must start with one of these prefixes.
const CLASSIFIED: &[(&str, &str)] = &[
    // Run by tests.
    ("cargo run --release -p gman-host-sim --bin gman -- demo", "run: host-sim/tests/cli.rs runs `gman demo` on a short budget; the full demo takes 1-2 min in a release build"),
    ("cargo test --workspace", "run: CI's test step"),
    ("gman export --blob host-sim/models/gman-map3-b16-mcu-int8-seed5.gman --activations int8", "run as written: blocks_run_as_written"),
    ("(cd firmware-example && GMAN_FIRMWARE_BLOB=$PWD/../gman-map3-b16-mcu-int8act-seed5.gman", "run as written: blocks_run_as_written"),
    ("cargo build --profile speed --features kernel-table", "run as written: blocks_run_as_written"),
    ("qemu-system-arm -M mps2-an386 -nographic -icount shift=0 -semihosting-config enable=on,target=native -kernel /tmp/tb-int8", "run as written: blocks_run_as_written"),
    ("gman train --data ../shared/data/gman --method gman --map 3x3", "run: host-sim/tests/readme_device.rs (README's device sequence, at --config tiny --updates 10)"),
    ("gman export --ckpt runs/gman/checkpoint.ckpt --preset mcu", "run: host-sim/tests/readme_device.rs"),
    ("(cd firmware-example && GMAN_FIRMWARE_BLOB=$PWD/../gman.gman cargo run --release)", "run: host-sim/tests/readme_device.rs"),
    ("python3 scripts/import_data.py build", "run on fixtures: scripts/test_import_data.py (the clones need the network)"),
    ("python/ci.sh", "run: CI's Python step"),
    ("pip install ./python", "run: python/ci.sh"),
    ("cargo run --release -p gman-host-sim --features offline --bin gman -- make-offline-fixture", "run: host-sim/tests/offline.rs (make-offline-fixture in both namings)"),
    ("cargo run --release -p gman-host-sim --features offline --bin gman -- eval --data /tmp/", "run: host-sim/tests/offline.rs (the oracle scores 100 on each fixture)"),
    // Too long for CI.
    ("gman train ", "too long for CI: minutes to hours of training (the trainer is tested on short runs)"),
    ("mpirun ", "too long for CI: training under MPI (CI's MPI step runs short runs)"),
    ("srun ", "a cluster's job script"),
    ("./gman train", "a cluster's job script"),
    ("KEEP=results/paper DATA=", "too long for CI: the whole reference-budget sweep (hours per run on 2 cores)"),
    ("target/release/gman train", "too long for CI: training on the offline data"),
    ("nice -n 5 gman eval", "run at a test budget (5 episodes per file): blocks_run_at_the_test_budget"),
    ("gman bench", "a benchmark: minutes, and its numbers are the machine's"),
    ("for m in results/shift/models/", "too long for CI: `gman emd-report` of every kept GMAN model of the domain-shift study (2000 val episodes each; `gman emd-report` itself: host-sim/tests/cli.rs)"),
    ("b=$(basename $m .gman)", "part of the loop above"),
    ("gman emd-report --data ../shared/data/gman --object-layout thor5 --domain-shift $S", "part of the loop above"),
    ("DATA=../shared/data/gman nice -n 10 bash host-sim/scripts/shift-step0.sh", "too long for CI: two 8000-episode evaluations of every kept gman and gman-ref blob of the domain-shift study (`gman eval --inner-lr 0` itself: host-sim/tests/cli.rs)"),
    // Need what CI does not have.
    ("git clone ", "needs the network"),
    ("apt-get install", "a system package"),
    ("module load", "a cluster's environment"),
    ("target/release/gman eval --data thor", "needs the AI2THOR offline data (a download)"),
    ("mkdir thor", "needs the AI2THOR offline data (a download)"),
    ("ln -s /path/to/your/copy", "needs the AI2THOR offline data (a download)"),
    // The device's and the kernels' commands: the firmware tests build and run the firmware.
    ("(cd firmware-example", "device: tests/tests/firmware_qemu.rs builds and runs the firmware"),
    ("cd firmware-example", "device: tests/tests/firmware_qemu.rs"),
    ("cargo run --release", "device: tests/tests/firmware_qemu.rs"),
    ("cargo build", "a build step of the commands around it"),
    ("GMAN_FIRMWARE_BLOB=", "device: tests/tests/firmware_qemu.rs"),
    ("qemu-system-arm ", "device: tests/tests/firmware_qemu.rs"),
    ("gman export ", "export: host-sim's export tests; the blob it reads comes from training"),
    ("for s in 1 2 3; do", "run: blocks_run_at_the_test_budget"),
    ("--out /tmp/psi", "run: blocks_run_at_the_test_budget (part of its loop)"),
    ("done", "run: blocks_run_at_the_test_budget (part of its loop)"),
    // Shell syntax of the job scripts.
    ("RUN=", "a cluster's job script"),
    ("if ", "a cluster's job script"),
    ("else", "a cluster's job script"),
    ("fi", "a cluster's job script"),
    ("M=(", "a cluster's job script"),
    ("m=", "a cluster's job script"),
    ("ps=(", "a cluster's job script"),
];

#[test]
fn every_documented_shell_command_is_run_by_a_test_or_says_why_not() {
    let mut unclassified = Vec::new();
    let mut n = 0;
    for f in doc_files() {
        let text = std::fs::read_to_string(&f).unwrap();
        for cmd in shell_commands(&text) {
            n += 1;
            if !CLASSIFIED.iter().any(|(p, _)| cmd.starts_with(p)) {
                unclassified.push(format!(
                    "{}: {cmd}",
                    f.strip_prefix(root()).unwrap_or(&f).display()
                ));
            }
        }
    }
    assert!(n > 30, "only {n} documented commands found");
    assert!(
        unclassified.is_empty(),
        "documented commands neither run by a test nor listed with a reason in \
         host-sim/tests/docs.rs:\n{}",
        unclassified.join("\n")
    );
}

/// The `sh` blocks run as written, whole, in a scratch root (`common::scratch`): the file and
/// the start of the block's first command. They build and run the firmware, so they need QEMU
/// (skipped without it unless `GMAN_REQUIRE_QEMU=1`, as in CI).
const RUN_AS_WRITTEN: &[(&str, &str)] = &[
    (
        "docs/kernels.md",
        "gman export --blob host-sim/models/gman-map3-b16-mcu-int8-seed5.gman --activations int8",
    ),
    ("docs/kernels.md", "cd firmware-example"),
];

/// The `sh` blocks run at the test's budget (`common::scratch::at_test_budget`: evaluations
/// of 5 episodes per file, training of 10 tiny updates), every other word as written, in a
/// scratch root with the data (skipped without `../shared/data/gman`).
const RUN_AT_TEST_BUDGET: &[(&str, &str)] = &[
    (
        "docs/kernels.md",
        "for s in 1 2 3; do gman export --blob host-sim/models/gman-map3-b16-mcu-int8-seed$s.gman",
    ),
    ("docs/kernels.md", "for s in 1 2 3; do"),
];

/// Each listed block (file, start of its first command) as its file has it.
fn listed_blocks(list: &[(&'static str, &str)]) -> Vec<(&'static str, String)> {
    list.iter()
        .map(|(file, first)| {
            let text = std::fs::read_to_string(root().join(file)).unwrap();
            let block = sh_block(&text, first)
                .unwrap_or_else(|| panic!("{file}: no sh block starting with {first:?}"));
            (*file, block.to_string())
        })
        .collect()
}

#[cfg(unix)]
#[test]
fn blocks_run_as_written() {
    use common::scratch::{device_tools, Scratch};
    let blocks = listed_blocks(RUN_AS_WRITTEN);
    if !device_tools("docs::blocks_run_as_written") {
        return;
    }
    let s = Scratch::new("docs-blocks");
    for (file, block) in &blocks {
        s.run(&format!("{file}'s block"), block);
    }
}

#[cfg(unix)]
#[test]
fn blocks_run_at_the_test_budget() {
    use common::scratch::{at_test_budget, Scratch};
    let scripts: Vec<(&str, String)> = listed_blocks(RUN_AT_TEST_BUDGET)
        .into_iter()
        .map(|(file, block)| {
            let cmds = block_commands(&block);
            let script: Vec<String> = cmds.iter().map(|c| at_test_budget(c, true)).collect();
            (file, script.join("\n"))
        })
        .collect();
    let s = Scratch::new("docs-budget");
    if !s.have_data {
        eprintln!("SKIPPED docs::blocks_run_at_the_test_budget: no ../shared/data/gman");
        return;
    }
    for (file, script) in &scripts {
        let out = s.run(&format!("{file}'s block at the test budget"), script);
        let stdout = String::from_utf8_lossy(&out.stdout);
        if script.contains("gman eval ") {
            assert!(
                stdout.contains("mean ± std over seeds [1, 2, 3]"),
                "{file}: no evaluation over the three seeds:\n{stdout}"
            );
        }
    }
}

#[test]
fn shell_commands_join_continuations_and_drop_comments() {
    let text = "x\n```sh\n# a comment\ngman eval \\\n  --agent random   # trailing\n\n```\n```text\ngman no\n```\n";
    assert_eq!(shell_commands(text), ["gman eval --agent random"]);
}

/// A generated part of a doc: `<!-- gen:KIND ARGS -->`, its body, `<!-- /gen -->`.
struct Part<'a> {
    /// The marker's arguments.
    args: Vec<&'a str>,
    /// Where the body stands in the doc's text.
    body: std::ops::Range<usize>,
}

/// Every `<!-- gen:KIND ... -->` part of `text`, in order.
fn generated_parts<'a>(text: &'a str, kind: &str) -> Vec<Part<'a>> {
    let open = format!("<!-- gen:{kind} ");
    let mut parts = Vec::new();
    let mut from = 0;
    while let Some(i) = text[from..].find(&open) {
        let args_start = from + i + open.len();
        let end = args_start + text[args_start..].find(" -->\n").expect("marker end");
        let body_start = end + " -->\n".len();
        let body_end = body_start + text[body_start..].find("<!-- /gen -->").expect("part end");
        parts.push(Part {
            args: text[args_start..end].split_whitespace().collect(),
            body: body_start..body_end,
        });
        from = body_end;
    }
    parts
}

/// Every `<!-- gen:table RUNS -->` part of the docs is what `gman table --markdown --runs RUNS`
/// prints (the Python generator and the Rust table agree, to the last digit).
#[test]
fn generated_tables_are_what_gman_table_prints() {
    let mut checked = 0;
    for f in doc_files() {
        let text = std::fs::read_to_string(&f).unwrap();
        for part in generated_parts(&text, "table") {
            let mut args = vec!["table", "--markdown", "--runs"];
            args.extend(&part.args);
            assert_eq!(
                gman(&args),
                &text[part.body],
                "{}: gen:table {}",
                f.display(),
                part.args.join(" ")
            );
            checked += 1;
        }
    }
    assert!(checked >= 2, "only {checked} generated tables found");
}

/// Every `<!-- gen:gman ARGS -->` part of the docs is what `gman ARGS` prints now (read-only
/// commands over kept result files, e.g. `shift-report --markdown`). `GMAN_UPDATE_DOCS=1`
/// rewrites the parts instead of failing.
#[test]
fn generated_command_outputs_are_what_gman_prints() {
    let update = std::env::var_os("GMAN_UPDATE_DOCS").is_some_and(|v| v == "1");
    let mut checked = 0;
    let mut stale = Vec::new();
    for f in doc_files() {
        let text = std::fs::read_to_string(&f).unwrap();
        let mut out = String::new();
        let mut copied = 0;
        for part in generated_parts(&text, "gman") {
            let (body, now) = (&text[part.body.clone()], gman(&part.args));
            if now != body {
                stale.push(format!(
                    "{}: gen:gman {}\n--- documented\n{body}--- printed now\n{now}",
                    f.display(),
                    part.args.join(" ")
                ));
            }
            out.push_str(&text[copied..part.body.start]);
            out.push_str(&now);
            copied = part.body.end;
            checked += 1;
        }
        out.push_str(&text[copied..]);
        if update && out != text {
            std::fs::write(&f, out).unwrap();
        }
    }
    assert!(checked >= 1, "no gen:gman parts found");
    assert!(
        update || stale.is_empty(),
        "documented command output differs from what the command prints now \
         (GMAN_UPDATE_DOCS=1 rewrites it):\n{}",
        stale.join("\n")
    );
}

/// The README's random row: `gman eval --data ../shared/data/gman --split val --agent random`
/// gives the figures of `results/paper/random/s1.json`, which the README's table quotes.
#[test]
fn readme_random_row_command_gives_the_kept_figures() {
    let Some(data) = common::data_dir() else {
        return;
    };
    let readme = std::fs::read_to_string(root().join("README.md")).unwrap();
    assert!(
        readme.contains("`gman eval\n--data ../shared/data/gman --split val --agent random`"),
        "the README no longer shows the random row's command"
    );
    let dir = std::env::temp_dir().join(format!("gman-docs-random-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let json = dir.join("random.json");
    let d = data.display().to_string();
    let j = json.display().to_string();
    gman(&[
        "eval", "--data", &d, "--split", "val", "--agent", "random", "--json", &j, "--quiet",
    ]);
    let got: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let kept: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(root().join("results/paper/random/s1.json")).unwrap(),
    )
    .unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(got["results"], kept["results"]);
    assert_eq!(got["by_room"], kept["by_room"]);
}
