//! Reliability ("no panic, no hang, no silent wrong result, no lost run data"): each case as a
//! reproduction through the built `gman` binary or the library, with crafted blobs,
//! checkpoints, data files and run directories in temporary directories.

mod common;
#[path = "../../core/tests/common/mod.rs"]
mod core_common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use gman_host_sim::optim::checkpoint::Checkpoint;
use gman_host_sim::sim::{Split, World};

/// Held while this process has HDF5 files open and while it starts a child: HDF5 locks the
/// files it opens, and a child started meanwhile would inherit the open file (and its lock)
/// for as long as it runs, so that another test's `gman` could not open it.
static HDF5_OR_SPAWN: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn spawn_lock() -> std::sync::MutexGuard<'static, ()> {
    HDF5_OR_SPAWN
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn gman(args: &[&str]) -> (bool, String, String) {
    let child = {
        let _l = spawn_lock();
        Command::new(env!("CARGO_BIN_EXE_gman"))
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("run gman")
    };
    let out = child.wait_with_output().expect("run gman");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Runs gman, killing it (and failing) after `secs`: for cases that used to hang.
fn gman_within(secs: u64, args: &[&str]) -> (bool, String) {
    let mut child = {
        let _l = spawn_lock();
        Command::new(env!("CARGO_BIN_EXE_gman"))
            .args(args)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("run gman")
    };
    let t0 = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut err = String::new();
            std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
            return (status.success(), err);
        }
        if t0.elapsed() > Duration::from_secs(secs) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("gman {args:?} still running after {secs} s (hang)");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A fresh directory under the system's temporary directory, removed when the test passes
/// (kept, and named on stderr, when it fails).
struct TmpDir(PathBuf);

impl std::ops::Deref for TmpDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl Drop for TmpDir {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("kept {} for inspection", self.0.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

fn tmp(name: &str) -> TmpDir {
    let d = std::env::temp_dir().join(format!("gman-rel-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    TmpDir(d)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A short synthetic A3C run of `updates` updates (checkpoint every update) in `dir`.
fn train_run(dir: &Path, updates: u32) {
    train_run_with(dir, updates, &[]);
}

/// [`train_run`] with more flags.
fn train_run_with(dir: &Path, updates: u32, extra: &[&str]) {
    let u = updates.to_string();
    let mut args = vec![
        "train",
        "--method",
        "a3c",
        "--config",
        "tiny",
        "--min-steps",
        "12",
        "--workers",
        "1",
        "--updates",
        &u,
        "--checkpoint-every",
        "1",
        "--quiet",
        "--out",
        s(dir),
    ];
    args.extend_from_slice(extra);
    let (ok, _, err) = gman(&args);
    assert!(ok, "{err}");
}

fn resume(dir: &Path, updates: u32, extra: &[&str]) -> (bool, String) {
    let u = updates.to_string();
    let mut args = vec!["train", "--resume", s(dir), "--updates", &u, "--quiet"];
    args.extend_from_slice(extra);
    let (ok, _, err) = gman(&args);
    assert!(!err.contains("panicked"), "{err}");
    (ok, err)
}

/// Loads `dir/checkpoint.ckpt`, lets `edit` change it, saves it (a valid CRC again).
fn edit_checkpoint(dir: &Path, edit: impl FnOnce(&mut Checkpoint)) {
    let path = dir.join("checkpoint.ckpt");
    let mut ck = Checkpoint::load(&path).unwrap();
    edit(&mut ck);
    ck.save(&path).unwrap();
}

/// A valid v2 blob header with these dims and no tensors (core's test helper, flag bit 0).
fn header_only_blob(dims: [u64; 8]) -> Vec<u8> {
    core_common::header_only_blob(dims, 1)
}

/// Case 3: `gman eval --agent` on a header-only blob with huge dims panicked with "capacity
/// overflow" (allocation from the header's dims); `inspect` accepted it.
#[test]
fn case03_header_only_blobs_are_typed_errors() {
    let d = tmp("blob");
    for (name, dims, needle) in [
        ("max.gman", [u32::MAX as u64; 8], "dimensions too large"),
        ("big.gman", [1 << 20; 8], "missing"),
        ("mcu.gman", [45, 45, 256, 512, 64, 64, 64, 0], "missing"),
    ] {
        let p = d.join(name);
        std::fs::write(&p, header_only_blob(dims)).unwrap();
        let (ok, _, e) = gman(&["eval", "--agent", s(&p), "--episodes", "1", "--quiet"]);
        assert!(!ok && e.contains(name) && e.contains(needle), "{name}: {e}");
        assert!(!e.contains("panicked"), "{e}");
    }
    let (ok, _, e) = gman(&["inspect", s(&d.join("max.gman"))]);
    assert!(!ok && e.contains("dimensions too large"), "{e}");
}

/// Case 4: `--min-start-actions 30` on the synthetic world busy-looped forever.
#[test]
fn case04_unsatisfiable_min_start_actions_is_an_error() {
    let d = tmp("minstart");
    let (ok, e) = gman_within(
        120,
        &[
            "train",
            "--method",
            "a3c",
            "--config",
            "tiny",
            "--min-start-actions",
            "30",
            "--updates",
            "1",
            "--quiet",
            "--out",
            s(&d.join("run")),
        ],
    );
    assert!(!ok && e.contains("--min-start-actions"), "{e}");
    // The bounded sampler returns the same episodes as before when the setting can be met.
    let w = World::synthetic(gman_host_sim::sim::DEFAULT_WORLD_SEED);
    use rand::SeedableRng;
    let mut r1 = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let mut r2 = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    for _ in 0..20 {
        assert_eq!(
            w.try_sample_train_episode_min(&mut r1, 1).unwrap(),
            w.sample_train_episode_min(&mut r2, 1)
        );
    }
}

/// Cases 5 and 8: a checkpoint with NaN weights. `eval` printed a normal table and exited 0;
/// `export` wrote a valid blob with the NaN quantised to 0.
#[test]
fn case05_case08_nan_weights_fail_eval_and_export() {
    let d = tmp("nan");
    let run = d.join("run");
    train_run(&run, 1);
    edit_checkpoint(&run, |ck| {
        // A policy weight: every method uses it at every step.
        ck.tensors.get_mut("FuseW").unwrap().data[0] = f32::NAN;
    });
    let ckpt = run.join("checkpoint.ckpt");
    let json = d.join("eval.json");
    let (ok, stdout, e) = gman(&[
        "eval",
        "--agent",
        s(&ckpt),
        "--episodes",
        "2",
        "--quiet",
        "--json",
        s(&json),
    ]);
    assert!(!ok, "eval of a NaN model exited 0: {stdout}");
    assert!(stdout.contains("FAILED: 16 of 16 episodes"), "{stdout}");
    assert!(
        e.contains("16 of 16 episodes") && !e.contains("panicked"),
        "{e}"
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["failed_episodes"], 16);
    assert_eq!(v["failures"].as_array().unwrap().len(), 10);
    // The healthy model evaluates with no failure and says so in the JSON.
    let ok_run = d.join("ok");
    train_run(&ok_run, 1);
    let (ok, stdout, e) = gman(&[
        "eval",
        "--agent",
        s(&ok_run.join("checkpoint.ckpt")),
        "--episodes",
        "1",
        "--quiet",
        "--json",
        s(&json),
    ]);
    assert!(ok && !stdout.contains("FAILED"), "{e}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["failed_episodes"], 0);

    let blob = d.join("m.gman");
    let (ok, _, e) = gman(&[
        "export",
        "--ckpt",
        s(&ckpt),
        "--preset",
        "mcu",
        "--out",
        s(&blob),
    ]);
    assert!(!ok && e.contains("non-finite"), "{e}");
    assert!(!blob.exists());
}

/// Case 6: stored settings of a checkpoint (with a valid CRC) were trained on unchecked.
#[test]
fn case06_resume_validates_stored_settings() {
    let d = tmp("settings");
    let base = d.join("base");
    train_run(&base, 1);
    let copy = |name: &str| {
        let p = d.join(name);
        std::fs::create_dir_all(&p).unwrap();
        std::fs::copy(base.join("checkpoint.ckpt"), p.join("checkpoint.ckpt")).unwrap();
        std::fs::copy(base.join("metrics.csv"), p.join("metrics.csv")).unwrap();
        p
    };
    type Edit = Box<dyn FnOnce(&mut Checkpoint)>;
    let cases: Vec<(&str, Edit, &str)> = vec![
        (
            "inner",
            Box::new(|ck| ck.metadata["inner_lr"] = serde_json::json!(-1.0)),
            "inner_lr",
        ),
        (
            "adamlr",
            Box::new(|ck| ck.metadata["trainer"]["adam"]["lr"] = serde_json::json!(-0.001)),
            "lr",
        ),
        (
            "method",
            Box::new(|ck| ck.metadata["method"] = serde_json::json!("a3c-fg")),
            "method is \"a3c-fg\" but was \"a3c\"",
        ),
        (
            "entropy",
            Box::new(|ck| ck.metadata["trainer"]["a3c"]["entropy"] = serde_json::json!(-5.0)),
            "entropy",
        ),
        (
            "adamstate",
            Box::new(|ck| {
                let b = &mut ck.blobs.iter_mut().find(|(n, _)| n == "adam").unwrap().1;
                let n = b.len();
                b[n - 4..].copy_from_slice(&f32::NAN.to_le_bytes());
            }),
            "non-finite",
        ),
        (
            "workers",
            Box::new(|ck| ck.metadata["trainer"]["workers"] = serde_json::json!(0)),
            "workers",
        ),
    ];
    for (name, edit, needle) in cases {
        let p = copy(name);
        edit_checkpoint(&p, edit);
        let (ok, e) = resume(&p, 2, &[]);
        assert!(!ok && e.contains(needle), "{name}: {e}");
    }
    // The untouched copy resumes.
    let p = copy("untouched");
    let (ok, e) = resume(&p, 2, &[]);
    assert!(ok, "{e}");
}

/// Case 7: a synthetic-world run continued on `--data` or with another `--world-seed`.
#[test]
fn case07_resume_refuses_another_world() {
    let d = tmp("world");
    let run = d.join("run");
    train_run(&run, 1);
    let (ok, e) = resume(&run, 2, &["--world-seed", "7"]);
    assert!(
        !ok && e.contains("synthetic world") && e.contains("--world-seed"),
        "{e}"
    );
    if let Some(data) = common::data_dir() {
        let (ok, e) = resume(&run, 2, &["--data", s(&data)]);
        assert!(!ok && e.contains("trained on the synthetic world"), "{e}");
    }
    let v = Checkpoint::load(&run.join("checkpoint.ckpt"))
        .unwrap()
        .metadata;
    assert_eq!(v["trainer"]["world"]["kind"], "synthetic");
    let (ok, e) = resume(&run, 2, &[]);
    assert!(ok, "{e}");
}

/// The domain shift is part of the world: recorded in the checkpoint (only when it is not
/// the default), and a resume under another level is refused naming the flag to give.
#[test]
fn resume_refuses_another_domain_shift() {
    let d = tmp("shift");
    let run = d.join("run");
    train_run_with(&run, 1, &["--domain-shift", "0.5"]);
    let v = Checkpoint::load(&run.join("checkpoint.ckpt"))
        .unwrap()
        .metadata;
    assert_eq!(v["trainer"]["world"]["domain_shift"], 0.5);
    let (ok, e) = resume(&run, 2, &[]);
    assert!(
        !ok && e.contains("domain shift 0.5") && e.contains("--domain-shift 0.5"),
        "{e}"
    );
    let (ok, e) = resume(&run, 2, &["--domain-shift", "0.5"]);
    assert!(ok, "{e}");
    // the default level is not written: checkpoints at S = 1 are what they were
    let plain = d.join("plain");
    train_run(&plain, 1);
    let v = Checkpoint::load(&plain.join("checkpoint.ckpt"))
        .unwrap()
        .metadata;
    assert!(v["trainer"]["world"].get("domain_shift").is_none(), "{v}");
    for bad in ["-1", "3.5", "nan", "x"] {
        let flag = format!("--domain-shift={bad}");
        let (ok, _, e) = gman(&["eval", "--episodes", "1", &flag, "--quiet"]);
        assert!(!ok && e.contains("domain shift"), "{bad}: {e}");
    }
}

/// Case 9: data files accepted without a message. Each malformed copy of a small piece of the
/// official data is refused with the file (and line) named; the unmodified copy loads.
#[test]
fn case09_malformed_data_files_are_refused() {
    let Some(data) = common::data_dir() else {
        return;
    };
    // The official data loads with every check on: 8000 episodes.
    let w = World::load(&data).unwrap();
    assert_eq!(w.episodes(Split::Val, None).unwrap().len(), 8000);

    let make = |name: &str| small_data_copy(&format!("data-{name}")).expect("data present");
    let load = |d: &Path| -> Result<usize, String> {
        World::load(d)
            .and_then(|w| w.episodes(Split::Val, None))
            .map(|e| e.len())
            .map_err(|e| format!("{e:#}"))
    };
    let ok = make("ok");
    assert_eq!(load(&ok), Ok(24));

    let rewrite = |path: &Path, f: &dyn Fn(String) -> String| {
        let t = std::fs::read_to_string(path).unwrap();
        std::fs::write(path, f(t)).unwrap();
    };
    let first_line = |path: &Path, f: &dyn Fn(&mut serde_json::Value)| {
        let t = std::fs::read_to_string(path).unwrap();
        let mut lines: Vec<String> = t.lines().map(String::from).collect();
        let mut v: serde_json::Value = serde_json::from_str(&lines[0]).unwrap();
        f(&mut v);
        lines[0] = v.to_string();
        std::fs::write(path, lines.join("\n") + "\n").unwrap();
    };
    let ep = |d: &Path, f: &str| d.join("episodes/val").join(f);

    // Attribute values outside [0, 1].
    for bad in ["5", "-3", "1e30"] {
        let d = make(&format!("attr{bad}"));
        let p = d.join("attributes.json");
        let mut v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
        v["categories"]["Bathtub"][0] = serde_json::from_str(bad).unwrap();
        std::fs::write(&p, v.to_string()).unwrap();
        let e = load(&d).unwrap_err();
        assert!(e.contains("attributes.json") && e.contains("[0, 1]"), "{e}");
    }
    // An empty and a missing episode file, an unknown room file.
    let d = make("empty");
    std::fs::write(ep(&d, "kitchen_seen.jsonl"), "").unwrap();
    let e = load(&d).unwrap_err();
    assert!(
        e.contains("kitchen_seen.jsonl") && e.contains("no episode"),
        "{e}"
    );
    let d = make("missing");
    std::fs::remove_file(ep(&d, "kitchen_seen.jsonl")).unwrap();
    let e = load(&d).unwrap_err();
    assert!(
        e.contains("kitchen_seen.jsonl") && e.contains("missing"),
        "{e}"
    );
    let d = make("garage");
    std::fs::copy(ep(&d, "kitchen_seen.jsonl"), ep(&d, "garage_seen.jsonl")).unwrap();
    let e = load(&d).unwrap_err();
    assert!(e.contains("garage_seen.jsonl"), "{e}");
    // An episode whose room disagrees with its scene (and with its file).
    let d = make("room");
    first_line(&ep(&d, "bathroom_seen.jsonl"), &|v| {
        v["scene"] = "FloorPlan22".into()
    });
    let e = load(&d).unwrap_err();
    assert!(
        e.contains("bathroom_seen.jsonl line 1") && e.contains("disagrees"),
        "{e}"
    );
    // A "seen" target that is an unseen category.
    let d = make("seenunseen");
    first_line(&ep(&d, "bathroom_seen.jsonl"), &|v| {
        v["target"] = "Toilet".into()
    });
    let e = load(&d).unwrap_err();
    assert!(
        e.contains("line 1") && e.contains("not among the seen targets"),
        "{e}"
    );
    // A start 0.13 m off the grid.
    let d = make("grid");
    first_line(&ep(&d, "bathroom_seen.jsonl"), &|v| {
        let x = v["start"]["x"].as_f64().unwrap();
        v["start"]["x"] = (x + 0.13).into();
    });
    let e = load(&d).unwrap_err();
    assert!(e.contains("line 1") && e.contains("grid"), "{e}");
    // Empty and unknown target_ids.
    let d = make("noids");
    first_line(&ep(&d, "bathroom_seen.jsonl"), &|v| {
        v["target_ids"] = serde_json::json!([])
    });
    let e = load(&d).unwrap_err();
    assert!(
        e.contains("line 1") && e.contains("target_ids is empty"),
        "{e}"
    );
    let d = make("badid");
    first_line(&ep(&d, "bathroom_seen.jsonl"), &|v| {
        v["target_ids"] = serde_json::json!(["Bathtub|+9.99|+0.00|+9.99"])
    });
    let e = load(&d).unwrap_err();
    assert!(e.contains("line 1") && e.contains("target id"), "{e}");
    // An object at x = 1e300.
    let d = make("far");
    rewrite(&d.join("scenes/val/FloorPlan426.json"), &|t| {
        let mut v: serde_json::Value = serde_json::from_str(&t).unwrap();
        v["objects"][0]["x"] = serde_json::from_str("1e300").unwrap();
        v.to_string()
    });
    let e = load(&d).unwrap_err();
    assert!(e.contains("FloorPlan426.json"), "{e}");
    // Through the CLI: a non-zero exit and the file and line.
    let d = make("cli");
    first_line(&ep(&d, "bedroom_unseen.jsonl"), &|v| {
        v["target"] = "Bowl".into()
    });
    let (ok, _, e) = gman(&["eval", "--data", s(&d), "--quiet"]);
    assert!(!ok && e.contains("bedroom_unseen.jsonl line 1"), "{e}");
}

/// Case 10: flags that do not apply were ignored silently; values that give a wrong result
/// were accepted.
#[test]
fn case10_flags_that_do_not_apply() {
    let (ok, _, e) = gman(&["eval", "--episodes", "0", "--quiet"]);
    assert!(!ok && e.contains("--episodes 0"), "{e}");
    let (ok, _, e) = gman(&[
        "eval",
        "--agent",
        "x{seed}.ckpt",
        "--seeds",
        "1,1",
        "--quiet",
    ]);
    assert!(!ok && e.contains("seed 1 twice"), "{e}");
    let (ok, _, e) = gman(&[
        "eval",
        "--agent",
        "random",
        "--inner-lr",
        "0.1",
        "--episodes",
        "1",
        "--quiet",
    ]);
    assert!(ok && e.contains("--inner-lr is ignored"), "{e}");
    let (ok, _, e) = gman(&[
        "eval",
        "--agent",
        "oracle",
        "--max-inner",
        "2",
        "--episodes",
        "1",
        "--quiet",
    ]);
    assert!(ok && e.contains("--max-inner is ignored"), "{e}");
    let d = tmp("flags");
    let (ok, _, e) = gman(&[
        "train",
        "--workers",
        "1000",
        "--out",
        s(&d.join("w")),
        "--quiet",
    ]);
    assert!(!ok && e.contains("--workers 1000"), "{e}");
    let run = d.join("run");
    train_run(&run, 1);
    let (ok, e) = resume(&run, 2, &["--preset", "paper"]);
    assert!(
        !ok && e.contains("--preset paper") && e.contains("not the paper preset"),
        "{e}"
    );
    let (ok, e) = resume(&run, 2, &["--fg", "whatever.ckpt"]);
    assert!(ok && e.contains("--fg is ignored"), "{e}");
    assert!(e.contains("(mcu)"), "{e}");
}

/// Case 11: two trainers into one `--out` both exited 0 and interleaved `metrics.csv`.
#[test]
fn case11_second_trainer_on_a_run_dir_is_refused() {
    let d = tmp("lock");
    let run = d.join("run");
    train_run(&run, 1);
    // A writer in this process holds the lock: the binary is refused, the files untouched.
    let before = std::fs::read(run.join("metrics.csv")).unwrap();
    {
        let _lock = gman_host_sim::train::run_dir::lock_run_dir(&run).unwrap();
        let (ok, e) = resume(&run, 3, &[]);
        assert!(!ok && e.contains("in use by another trainer"), "{e}");
        assert_eq!(std::fs::read(run.join("metrics.csv")).unwrap(), before);
    }
    // Two real processes: the second one started while the first runs is refused.
    let first = Command::new(env!("CARGO_BIN_EXE_gman"))
        .args([
            "train",
            "--resume",
            s(&run),
            "--updates",
            "100000",
            "--quiet",
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut first = KillOnDrop(first);
    let t0 = Instant::now();
    // Wait until the first one writes (it holds the lock from its start).
    while std::fs::read(run.join("metrics.csv")).unwrap().len() <= before.len() {
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "first trainer wrote nothing"
        );
        assert!(first.0.try_wait().unwrap().is_none(), "first trainer ended");
        std::thread::sleep(Duration::from_millis(50));
    }
    let (ok, e) = resume(&run, 100000, &[]);
    assert!(!ok && e.contains("in use by another trainer"), "{e}");
    let _ = first.0.kill();
    let _ = first.0.wait();
    // After the first one is gone, the lock is free again.
    let (ok, e) = resume(&run, 2, &[]);
    assert!(ok || e.contains("already"), "{e}");
}

struct KillOnDrop(std::process::Child);
impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Cases 12, 13, 14: metrics.csv was rewritten in place on resume, corrupt rows were kept
/// (and `plot` failed later), and stale `.checkpoint.ckpt.tmp.PID` files were never removed.
#[test]
fn case12_13_14_metrics_repair_atomic_rewrite_and_stale_temporaries() {
    let d = tmp("csv");
    let run = d.join("run");
    train_run(&run, 3);
    let csv = run.join("metrics.csv");
    let text = std::fs::read_to_string(&csv).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 4);
    let (header, r1, r2, r3) = (lines[0], lines[1], lines[2], lines[3]);
    // No header, a duplicate, a partial row at or below the checkpoint's update (3), garbage,
    // and a row after the checkpoint.
    let corrupt = format!(
        "{r1}\n{r2}\n{r1}\n{}\n3,zz\n{r3}\n{}\n",
        &r2[..r2.len() / 2],
        r3.replacen("3,", "4,", 1)
    );
    std::fs::write(&csv, &corrupt).unwrap();
    // plot names the first bad line instead of failing late.
    let (ok, _, e) = gman(&["plot", "--run", s(&run), "--png", s(&d.join("p.png"))]);
    assert!(!ok && e.contains("metrics.csv line 1"), "{e}");
    // Stale temporaries of killed writers.
    let stale = run.join(".checkpoint.ckpt.tmp.999999");
    std::fs::write(&stale, vec![0u8; 1000]).unwrap();
    let keep = run.join("notes.tmp.txt");
    std::fs::write(&keep, "mine").unwrap();
    #[cfg(unix)]
    let inode = {
        use std::os::unix::fs::MetadataExt;
        std::fs::metadata(&csv).unwrap().ino()
    };
    // Resume to the same update: only the repair and the rewrite happen.
    let (ok, e) = resume(&run, 3, &[]);
    assert!(ok, "{e}");
    assert!(e.contains("dropped 3 malformed or duplicate row(s)"), "{e}");
    assert!(
        e.contains("removed 1 stale temporary file(s) (1000 bytes)"),
        "{e}"
    );
    assert!(!stale.exists() && keep.exists());
    let repaired = std::fs::read_to_string(&csv).unwrap();
    assert_eq!(repaired, format!("{header}\n{r1}\n{r2}\n{r3}\n"));
    #[cfg(unix)]
    {
        // Rewritten through a temporary file and a rename, not truncated in place.
        use std::os::unix::fs::MetadataExt;
        assert_ne!(std::fs::metadata(&csv).unwrap().ino(), inode);
    }
    assert!(std::fs::read_dir(&run).unwrap().all(|e| {
        let n = e.unwrap().file_name().to_string_lossy().into_owned();
        !(n.starts_with('.') && n.contains(".tmp."))
    }));
    // A row lost at or before the checkpoint is reported as a gap, and training goes on.
    std::fs::write(&csv, format!("{header}\n{r1}\n{r3}\n")).unwrap();
    let (ok, e) = resume(&run, 4, &[]);
    assert!(
        ok && e.contains("1 of the 3 updates before the checkpoint have no row"),
        "{e}"
    );
    let (ok, _, e) = gman(&["plot", "--run", s(&run), "--png", s(&d.join("p.png"))]);
    assert!(ok, "{e}");
}

/// `gman plot` reads a run's curve from `metrics.csv.gz` when there is no `metrics.csv` (what
/// the results folder keeps of a finished run), and names the file when it is not gzip.
#[test]
fn plot_reads_a_compressed_curve_and_names_a_corrupt_one() {
    use std::io::Write;
    let d = tmp("plotgz");
    let run = d.join("run");
    train_run(&run, 3);
    let csv = run.join("metrics.csv");
    let text = std::fs::read(&csv).unwrap();
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    enc.write_all(&text).unwrap();
    let gz = run.join("metrics.csv.gz");
    std::fs::write(&gz, enc.finish().unwrap()).unwrap();
    std::fs::remove_file(&csv).unwrap();
    let png = d.join("p.png");
    let (ok, _, e) = gman(&["plot", "--run", s(&run), "--png", s(&png)]);
    assert!(ok, "{e}");
    assert!(std::fs::metadata(&png).unwrap().len() > 1000);
    std::fs::write(&gz, b"not gzip").unwrap();
    let (ok, _, e) = gman(&["plot", "--run", s(&run), "--png", s(&png)]);
    assert!(!ok && e.contains("metrics.csv.gz"), "{e}");
    std::fs::remove_file(&gz).unwrap();
    let (ok, _, e) = gman(&["plot", "--run", s(&run), "--png", s(&png)]);
    assert!(
        !ok && e.contains("metrics.csv") && e.contains("metrics.csv.gz"),
        "{e}"
    );
}

/// `gman eval` runs on every core: the results are the same, in the same order, with one
/// worker thread or two.
#[test]
fn eval_results_do_not_depend_on_the_thread_count() {
    use gman_host_sim::eval::agent::NavAgent;
    use gman_host_sim::model::load_model;
    use gman_host_sim::sim::{evaluate, EvalConfig};
    let world = World::synthetic(gman_host_sim::sim::DEFAULT_WORLD_SEED);
    let episodes = world.episodes(Split::Val, Some(3)).unwrap();
    let model = std::sync::Arc::new(
        load_model(
            Path::new(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/models/gman-mcu-int8-seed1.gman"
            )),
            None,
        )
        .unwrap(),
    );
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let results = pool.install(|| {
            evaluate(
                &world,
                &episodes,
                |_| Box::new(NavAgent::new(model.clone())),
                &EvalConfig::default(),
            )
        });
        serde_json::to_string(&results).unwrap()
    };
    let one = run(1);
    assert_eq!(one, run(2));
    assert_eq!(one, run(2));
}

// ---- Second pass: panics, data loss, silent wrong results, resource bounds. ----

/// Outputs may not overwrite inputs: `export --ckpt X --out X` replaced a training
/// checkpoint by a blob, `eval --agent m.gman --json m.gman` the model by its report (also
/// through a symlink to the input).
#[test]
fn outputs_never_overwrite_inputs() {
    let d = tmp("overwrite");
    let run = d.join("run");
    train_run(&run, 1);
    let ck = run.join("checkpoint.ckpt");
    let before = std::fs::read(&ck).unwrap();
    let (ok, _, e) = gman(&["export", "--ckpt", s(&ck), "--out", s(&ck)]);
    assert!(!ok && e.contains("same file"), "{e}");
    let link = d.join("link.gman");
    std::os::unix::fs::symlink(&ck, &link).unwrap();
    let (ok, _, e) = gman(&["export", "--ckpt", s(&ck), "--out", s(&link)]);
    assert!(!ok && e.contains("same file"), "{e}");
    assert_eq!(std::fs::read(&ck).unwrap(), before, "checkpoint changed");
    let m = d.join("m.gman");
    let (ok, _, e) = gman(&["export", "--ckpt", s(&ck), "--out", s(&m)]);
    assert!(ok, "{e}");
    let blob = std::fs::read(&m).unwrap();
    let (ok, _, e) = gman(&[
        "eval",
        "--agent",
        s(&m),
        "--json",
        s(&m),
        "--episodes",
        "1",
        "--quiet",
    ]);
    assert!(!ok && e.contains("same file"), "{e}");
    assert_eq!(std::fs::read(&m).unwrap(), blob, "model changed");
    // `inspect` names the rule that verified the blob: v5 covers the header.
    let (ok, out, e) = gman(&["inspect", s(&m)]);
    assert!(
        ok && out.contains("format v5") && out.contains("header and payload"),
        "{out}{e}"
    );
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/gman-mcu-int8-seed1.gman");
    let (ok, out, e) = gman(&["inspect", s(&shipped)]);
    assert!(ok && out.contains("payload only"), "{out}{e}");
    // A flipped header bit of an exported blob (α2's exponent) is refused.
    let mut bad = blob.clone();
    let h = gman_core::blob::Blob::parse(&blob).unwrap();
    let hlen = blob.len() - h.header().payload_len() as usize;
    bad[hlen / 2] ^= 0x40;
    let badp = d.join("bad.gman");
    std::fs::write(&badp, &bad).unwrap();
    let (ok, _, e) = gman(&["inspect", s(&badp)]);
    assert!(!ok, "a tampered header was accepted: {e}");
    let (ok, _, e) = gman(&["eval", "--agent", s(&badp), "--episodes", "1", "--quiet"]);
    assert!(!ok && !e.contains("panicked"), "{e}");
}

/// Resume forgot the run's target: a run asked for N updates and stopped early was resumed
/// to the config default; `--updates` below the checkpoint's update did nothing, with
/// success.
#[test]
fn resume_continues_to_the_stored_target() {
    let d = tmp("target");
    let run = d.join("run");
    train_run(&run, 2);
    let ck = run.join("checkpoint.ckpt");
    let v = Checkpoint::load(&ck).unwrap().metadata;
    assert_eq!(v["trainer"]["target_updates"], 2);
    // As if the run had been asked for 4 and killed after update 2.
    edit_checkpoint(&run, |c| c.metadata["trainer"]["target_updates"] = 4.into());
    let (ok, _, e) = gman(&["train", "--resume", s(&run), "--quiet"]);
    assert!(ok && e.contains("target: update 4"), "{e}");
    let v = Checkpoint::load(&ck).unwrap().metadata;
    assert_eq!(v["trainer"]["update"], 4, "{e}");
    let (ok, e) = resume(&run, 3, &[]);
    assert!(
        !ok && e.contains("already at update 4") && e.contains("--updates 3"),
        "{e}"
    );
    let (ok, e) = resume(&run, 5, &[]);
    assert!(ok && e.contains("target: update 5"), "{e}");
    let v = Checkpoint::load(&ck).unwrap().metadata;
    assert_eq!(v["trainer"]["update"], 5);
}

/// Nonsense and unbounded numbers are refused with the range in the message, before
/// anything runs (`--min-steps 4294967295` grew memory until the allocator aborted;
/// `--cell-embed 100000` took 11.5 GB).
#[test]
fn nonsense_and_unbounded_flags_are_refused() {
    let d = tmp("bounds");
    let out = d.join("run");
    for (flags, needle) in [
        (&["--max-steps", "0"][..], "1..=10000"),
        (&["--max-steps", "4294967295"][..], "1..=10000"),
        (&["--min-steps", "4294967295"][..], "1..=10000"),
        (&["--min-steps", "0"][..], "1..=10000"),
        (&["--inner-lr", "1e30"][..], "0..=1"),
        (&["--lr", "1e30"][..], "(0, 1]"),
        (&["--map", "3x3", "--cell-embed", "100000"][..], "1024"),
        (&["--map", "20x20"][..], "1..=16"),
        (&["--updates", "18446744073709551615"][..], "at most"),
    ] {
        let mut args = vec![
            "train", "--method", "a3c", "--config", "tiny", "--quiet", "--out",
        ];
        args.push(s(&out));
        args.extend_from_slice(flags);
        let (ok, e) = gman_within(60, &args);
        assert!(!ok && e.contains(needle), "{flags:?}: {e}");
        assert!(!e.contains("panicked"), "{e}");
    }
    for flag in ["--max-steps-other", "--max-steps-living-room"] {
        let (ok, _, e) = gman(&["eval", "--agent", "random", flag, "0", "--episodes", "1"]);
        assert!(!ok && e.contains(flag) && e.contains("1..="), "{e}");
    }
}

/// A model whose map is finer than 7 x 7, evaluated on offline data, panicked in the
/// pooling of the stored 7 x 7 feature maps; eval and emd-report refuse it like train does.
#[cfg(feature = "offline")]
#[test]
fn offline_eval_refuses_a_map_finer_than_7x7() {
    let d = tmp("map8");
    let data = d.join("data");
    let (ok, _, e) = gman(&["make-offline-fixture", "--out", s(&data)]);
    assert!(ok, "{e}");
    let run = d.join("run");
    let (ok, _, e) = gman(&[
        "train",
        "--method",
        "a3c",
        "--config",
        "tiny",
        "--map",
        "8x8",
        "--cell-embed",
        "2",
        "--min-steps",
        "8",
        "--workers",
        "1",
        "--updates",
        "1",
        "--quiet",
        "--out",
        s(&run),
    ]);
    assert!(ok, "{e}");
    let ck = run.join("checkpoint.ckpt");
    let (ok, _, e) = gman(&[
        "eval",
        "--data",
        s(&data),
        "--split",
        "val",
        "--agent",
        s(&ck),
        "--episodes",
        "1",
        "--quiet",
    ]);
    assert!(
        !ok && e.contains("at most 7 rows") && !e.contains("panicked"),
        "{e}"
    );
    let (ok, _, e) = gman(&[
        "emd-report",
        "--data",
        s(&data),
        "--split",
        "val",
        "--agent",
        s(&ck),
        "--episodes",
        "1",
    ]);
    assert!(
        !ok && e.contains("at most 7 rows") && !e.contains("panicked"),
        "{e}"
    );
}

/// `make-offline-fixture --out DIR` wrote into an existing data directory, through the
/// symlinks of the README's layout, over the user's real feature maps and graphs.
#[cfg(feature = "offline")]
#[test]
fn offline_fixture_never_writes_into_user_data() {
    let d = tmp("fixture-out");
    let real = d.join("real-FloorPlan22");
    std::fs::create_dir_all(&real).unwrap();
    std::fs::write(real.join("graph.json"), "mine").unwrap();
    std::fs::write(real.join("resnet18_featuremap.hdf5"), "mine").unwrap();
    let data = d.join("data");
    std::fs::create_dir_all(&data).unwrap();
    std::fs::write(data.join("attributes.json"), "mine").unwrap();
    std::os::unix::fs::symlink(&real, data.join("FloorPlan22")).unwrap();
    for extra in [&[][..], &["--force"][..]] {
        let mut args = vec!["make-offline-fixture", "--out", s(&data)];
        args.extend_from_slice(extra);
        let (ok, _, e) = gman(&args);
        assert!(!ok && e.contains("not empty"), "{extra:?}: {e}");
    }
    for f in ["graph.json", "resnet18_featuremap.hdf5"] {
        assert_eq!(std::fs::read_to_string(real.join(f)).unwrap(), "mine");
    }
    assert_eq!(
        std::fs::read_to_string(data.join("attributes.json")).unwrap(),
        "mine"
    );
    // A new directory is written; writing it again needs --force, which clears it without
    // following a link placed inside it.
    let fx = d.join("fx");
    let (ok, _, e) = gman(&["make-offline-fixture", "--out", s(&fx)]);
    assert!(ok, "{e}");
    let (ok, _, e) = gman(&["make-offline-fixture", "--out", s(&fx)]);
    assert!(!ok && e.contains("--force"), "{e}");
    std::os::unix::fs::symlink(&real, fx.join("mine")).unwrap();
    let (ok, _, e) = gman(&["make-offline-fixture", "--out", s(&fx), "--force"]);
    assert!(ok, "{e}");
    assert_eq!(
        std::fs::read_to_string(real.join("graph.json")).unwrap(),
        "mine"
    );
    assert!(!fx.join("mine").exists());
}

/// A copy of the official val data with the first three episodes of each file, or `None`
/// (test skipped) without the data.
fn small_data_copy(name: &str) -> Option<TmpDir> {
    let data = common::data_dir()?;
    let d = tmp(&format!("small-{name}"));
    std::fs::copy(data.join("attributes.json"), d.join("attributes.json")).unwrap();
    std::fs::create_dir_all(d.join("scenes/val")).unwrap();
    std::fs::create_dir_all(d.join("episodes/val")).unwrap();
    for f in std::fs::read_dir(data.join("scenes/val")).unwrap() {
        let f = f.unwrap().path();
        std::fs::copy(&f, d.join("scenes/val").join(f.file_name().unwrap())).unwrap();
    }
    for f in std::fs::read_dir(data.join("episodes/val")).unwrap() {
        let f = f.unwrap().path();
        let text = std::fs::read_to_string(&f).unwrap();
        let head: String = text.lines().take(3).map(|l| format!("{l}\n")).collect();
        std::fs::write(d.join("episodes/val").join(f.file_name().unwrap()), head).unwrap();
    }
    Some(d)
}

/// Rewrites line `line` (1-based) of `path` with `f` applied to its JSON.
fn edit_line(path: &Path, line: usize, f: &dyn Fn(&mut serde_json::Value)) {
    let t = std::fs::read_to_string(path).unwrap();
    let mut lines: Vec<String> = t.lines().map(String::from).collect();
    let mut v: serde_json::Value = serde_json::from_str(&lines[line - 1]).unwrap();
    f(&mut v);
    lines[line - 1] = v.to_string();
    std::fs::write(path, lines.join("\n") + "\n").unwrap();
}

/// Episode files: a repeated line was weighted twice without a word, `"split": "test"` in a
/// val file and a start height of 1e300 were accepted.
#[test]
fn episode_files_repeats_split_and_height() {
    let Some(ok) = small_data_copy("ep-ok") else {
        return;
    };
    let w = World::load(&ok).unwrap();
    assert_eq!(w.repeated_episodes_warning(Split::Val, None).unwrap(), None);
    // The official files repeat 247 of their 8000 lines: counted, all of them evaluated.
    let data = common::data_dir().unwrap();
    let real = World::load(&data).unwrap();
    let warn = real
        .repeated_episodes_warning(Split::Val, None)
        .unwrap()
        .unwrap();
    assert!(warn.starts_with("247 of the 8000 episodes"), "{warn}");
    assert_eq!(real.episodes(Split::Val, None).unwrap().len(), 8000);

    // A line repeated (the same fields written in another order counts too).
    let d = small_data_copy("ep-dup").unwrap();
    let f = d.join("episodes/val/bathroom_seen.jsonl");
    let text = std::fs::read_to_string(&f).unwrap();
    let first: serde_json::Value = serde_json::from_str(text.lines().next().unwrap()).unwrap();
    let mut reordered = serde_json::to_string_pretty(&first)
        .unwrap()
        .replace('\n', " ");
    reordered.push('\n');
    std::fs::write(&f, format!("{text}{reordered}")).unwrap();
    let w = World::load(&d).unwrap();
    let warn = w
        .repeated_episodes_warning(Split::Val, None)
        .unwrap()
        .unwrap();
    assert!(
        warn.starts_with("1 of the 25 episodes")
            && warn.contains("bathroom_seen.jsonl 1")
            && warn.contains("line 4 = line 1"),
        "{warn}"
    );
    let (ok_run, _, e) = gman(&["eval", "--data", s(&d), "--agent", "random", "--quiet"]);
    assert!(ok_run && e.contains("warning: 1 of the 25 episodes"), "{e}");

    let load = |d: &Path| -> Result<usize, String> {
        World::load(d)
            .and_then(|w| w.episodes(Split::Val, None))
            .map(|e| e.len())
            .map_err(|e| format!("{e:#}"))
    };
    // `"split": "test"` inside a val file.
    let d = small_data_copy("ep-split").unwrap();
    edit_line(&d.join("episodes/val/kitchen_unseen.jsonl"), 2, &|v| {
        v["split"] = "test".into()
    });
    let e = load(&d).unwrap_err();
    assert!(
        e.contains("kitchen_unseen.jsonl line 2") && e.contains("split \"test\" disagrees"),
        "{e}"
    );
    // A start height of 1e300 (inf as f32) and of -5000 m.
    for bad in ["1e300", "-5000"] {
        let d = small_data_copy(&format!("ep-y{bad}")).unwrap();
        edit_line(&d.join("episodes/val/bedroom_seen.jsonl"), 3, &|v| {
            v["start"]["y"] = serde_json::from_str(bad).unwrap()
        });
        let e = load(&d).unwrap_err();
        // 1e300 does not fit an f32: the exact JSON reader refuses the number itself
        assert!(
            e.contains("bedroom_seen.jsonl line 3")
                && (e.contains("start y") || e.contains("number out of range")),
            "{bad}: {e}"
        );
    }
}

/// A checkpoint whose model settings were edited so that the tensors still fit (a 3 x 3 map
/// relabelled 1 x 9, the adaptation mode switched) was evaluated and resumed with the new
/// meaning.
#[test]
fn checkpoint_settings_that_disagree_with_the_trained_tensors_are_refused() {
    let d = tmp("meta-vs-tensors");
    let run = d.join("run");
    let (ok, _, err) = gman(&[
        "train",
        "--method",
        "a3c",
        "--config",
        "tiny",
        "--map",
        "3x3",
        "--cell-embed",
        "2",
        "--min-steps",
        "12",
        "--workers",
        "1",
        "--updates",
        "1",
        "--quiet",
        "--out",
        s(&run),
    ]);
    assert!(ok, "{err}");
    let ck = run.join("checkpoint.ckpt");
    let original = std::fs::read(&ck).unwrap();
    let mode = Checkpoint::load(&ck).unwrap().metadata["adapt_mode"].clone();
    let other_mode = if mode == "full" { "efficient" } else { "full" };
    type Edit = Box<dyn Fn(&mut Checkpoint)>;
    let edits: Vec<(&str, Edit, &str)> = vec![
        (
            "1x9",
            Box::new(|c: &mut Checkpoint| {
                c.metadata["dims"]["map_rows"] = 1.into();
                c.metadata["dims"]["map_cols"] = 9.into();
            }),
            "dims.map_cols is 9 but was 3",
        ),
        (
            "mode",
            Box::new(move |c: &mut Checkpoint| c.metadata["adapt_mode"] = other_mode.into()),
            "adapt_mode",
        ),
    ];
    for (name, edit, needle) in edits {
        std::fs::write(&ck, &original).unwrap();
        edit_checkpoint(&run, edit);
        let (ok, _, e) = gman(&["eval", "--agent", s(&ck), "--episodes", "1", "--quiet"]);
        assert!(
            !ok && e.contains(needle) && e.contains("changed after training wrote it"),
            "{name}: {e}"
        );
        let (ok, e) = resume(&run, 2, &[]);
        assert!(!ok && e.contains(needle), "{name}: {e}");
    }
    // Unedited, both work.
    std::fs::write(&ck, &original).unwrap();
    let (ok, _, e) = gman(&["eval", "--agent", s(&ck), "--episodes", "1", "--quiet"]);
    assert!(ok, "{e}");
    let (ok, e) = resume(&run, 2, &[]);
    assert!(ok, "{e}");
}

/// Adam's step count and the episode counters wrapped at u64::MAX (a panic in a debug
/// build, NaN steps and counts restarting at 0 in a release build).
#[test]
fn counters_near_u64_max_are_errors_not_wraps() {
    let d = tmp("counters");
    let run = d.join("run");
    train_run(&run, 1);
    let ck = run.join("checkpoint.ckpt");
    let original = std::fs::read(&ck).unwrap();
    for (field, needle) in [
        ("episodes", "episode counter"),
        ("env_steps", "environment step counter"),
    ] {
        std::fs::write(&ck, &original).unwrap();
        edit_checkpoint(&run, |c| {
            c.metadata["trainer"][field] = (u64::MAX - 1).into();
        });
        let (ok, e) = resume(&run, 2, &[]);
        assert!(!ok && e.contains(needle) && e.contains("u64::MAX"), "{e}");
    }
    std::fs::write(&ck, &original).unwrap();
    edit_checkpoint(&run, |c| {
        let adam = c.blobs.iter_mut().find(|(n, _)| n == "adam").unwrap();
        // Magic (4 bytes), version (u32), then t (u64).
        adam.1[8..16].copy_from_slice(&u64::MAX.to_le_bytes());
    });
    let (ok, e) = resume(&run, 2, &[]);
    assert!(
        !ok && e.contains("Adam's step count") && e.contains("u64::MAX"),
        "{e}"
    );
    // The checkpoint was not overwritten with wrapped values.
    let v = Checkpoint::load(&ck).unwrap().metadata;
    assert_eq!(v["trainer"]["update"], 1);
}

/// A checkpoint of a build that did not store the run's target trained on to the preset's
/// count (4000 after a killed `--updates 200` run), or did nothing and reported success
/// when that count was below the checkpoint's update.
#[test]
fn resume_of_a_checkpoint_without_a_stored_target_asks_for_updates() {
    let d = tmp("no-target");
    let run = d.join("run");
    train_run(&run, 2);
    edit_checkpoint(&run, |c| {
        c.metadata["trainer"]
            .as_object_mut()
            .unwrap()
            .remove("target_updates");
    });
    let (ok, _, e) = gman(&["train", "--resume", s(&run), "--quiet"]);
    assert!(
        !ok && e.contains("predates stored targets")
            && e.contains("at update 2")
            && e.contains("give --updates"),
        "{e}"
    );
    let ck = run.join("checkpoint.ckpt");
    assert_eq!(
        Checkpoint::load(&ck).unwrap().metadata["trainer"]["update"],
        2
    );
    let (ok, e) = resume(&run, 3, &[]);
    assert!(ok && e.contains("target: update 3"), "{e}");
    let v = Checkpoint::load(&ck).unwrap().metadata;
    assert_eq!(v["trainer"]["update"], 3);
    assert_eq!(v["trainer"]["target_updates"], 3);
}

/// Rewrites every dataset of the HDF5 file `path`, with `edit` applied to each (by name).
#[cfg(feature = "offline")]
fn edit_h5(path: &Path, edit: impl Fn(&str, &mut Vec<f32>)) {
    use gman_host_sim::sim::offline::h5;
    let _l = spawn_lock();
    let f = h5::H5File::open(path).unwrap();
    let mut all = Vec::new();
    for n in f.names().unwrap() {
        let (shape, _) = f.shape_and_size(&n).unwrap();
        let mut v = f.read(&n).unwrap();
        edit(&n, &mut v);
        all.push((n, shape, v));
    }
    drop(f);
    h5::write_datasets(
        path,
        all.iter()
            .map(|(n, sh, v)| (n.as_str(), sh.as_slice(), v.as_slice())),
    )
    .unwrap();
}

/// The sorted dataset names of the HDF5 file `path`.
#[cfg(feature = "offline")]
fn h5_names(path: &Path) -> Vec<String> {
    let _l = spawn_lock();
    let f = gman_host_sim::sim::offline::h5::H5File::open(path).unwrap();
    f.names().unwrap()
}

/// [`write_fixture`](gman_host_sim::sim::offline::fixture::write_fixture) under the lock.
#[cfg(feature = "offline")]
fn fixture_at(dir: &Path) {
    let _l = spawn_lock();
    gman_host_sim::sim::offline::fixture::write_fixture(dir, 1).unwrap();
}

/// A short A3C run on the offline data `data` (1 update) in `run`.
#[cfg(feature = "offline")]
fn offline_train_run(data: &Path, run: &Path) {
    let (ok, _, e) = gman(&[
        "train",
        "--data",
        s(data),
        "--method",
        "a3c",
        "--config",
        "tiny",
        "--max-steps",
        "30",
        "--min-steps",
        "20",
        "--workers",
        "1",
        "--updates",
        "1",
        "--quiet",
        "--out",
        s(run),
    ]);
    assert!(ok, "{e}");
}

/// Resume onto changed offline data was accepted: the fingerprint covered `attributes.json`
/// only, not the graphs, grids, visibility or feature files under `FloorPlanN/`.
#[cfg(feature = "offline")]
#[test]
fn offline_resume_onto_changed_scene_files_is_refused_naming_them() {
    let d = tmp("offline-fp");
    let data = d.join("data");
    fixture_at(&data);
    let run = d.join("run");
    offline_train_run(&data, &run);
    let ck = run.join("checkpoint.ckpt");
    let w = &Checkpoint::load(&ck).unwrap().metadata["trainer"]["world"];
    assert_eq!(w["fingerprint_rule"], 2);
    assert!(
        w["files"]["FloorPlan22/resnet18_featuremap.hdf5"].is_string(),
        "{w}"
    );
    assert!(
        w["files"]["FloorPlan22/att_in_view_v2.hdf5"].is_string(),
        "{w}"
    );
    // The same data (moved elsewhere) resumes.
    let moved = d.join("moved");
    std::fs::rename(&data, &moved).unwrap();
    let (ok, e) = resume(&run, 2, &["--data", s(&moved)]);
    assert!(ok, "{e}");
    let data = moved;

    let graph = data.join("FloorPlan1/graph.json");
    let g = std::fs::read_to_string(&graph).unwrap();
    std::fs::write(&graph, format!("{g}\n")).unwrap();
    let (ok, e) = resume(&run, 3, &["--data", s(&data)]);
    assert!(!ok && e.contains("FloorPlan1/graph.json changed"), "{e}");
    std::fs::write(&graph, g).unwrap();

    // One value of one feature map (the first dataset, always in the sample).
    let feats = data.join("FloorPlan2/resnet18_featuremap.hdf5");
    let saved = std::fs::read(&feats).unwrap();
    let first = h5_names(&feats)[0].clone();
    edit_h5(&feats, |n, v| {
        if n == first {
            v[100] += 0.5;
        }
    });
    let (ok, e) = resume(&run, 3, &["--data", s(&data)]);
    assert!(
        !ok && e.contains("FloorPlan2/resnet18_featuremap.hdf5 changed")
            && !e.contains("graph.json"),
        "{e}"
    );
    std::fs::write(&feats, &saved).unwrap();
    // Another visibility file (same content under another name) is another world.
    for scene in ["FloorPlan1", "FloorPlan2", "FloorPlan22"] {
        let sd = data.join(scene);
        std::fs::copy(sd.join("visible_object_map.json"), sd.join("vis2.json")).unwrap();
    }
    let (ok, e) = resume(
        &run,
        3,
        &["--data", s(&data), "--visible-file", "vis2.json"],
    );
    assert!(!ok && e.contains("FloorPlan1/vis2.json is new"), "{e}");
    let (ok, e) = resume(&run, 3, &["--data", s(&data)]);
    assert!(ok, "{e}");

    // A checkpoint of an older build (rule 1: attributes.json only): resumable with a warning
    // when that rule matches, refused when it does not.
    let rule1 = gman_host_sim::sim::data::fingerprint(&data).unwrap();
    let old_world = |fp: &str| {
        let fp = fp.to_string();
        move |c: &mut Checkpoint| {
            let w = c.metadata["trainer"]["world"].as_object_mut().unwrap();
            w.remove("files");
            w.remove("fingerprint_rule");
            w.insert("fingerprint".into(), fp.into());
        }
    };
    edit_checkpoint(&run, old_world(&rule1));
    let (ok, e) = resume(&run, 4, &["--data", s(&data)]);
    assert!(
        ok && e.contains("older build") && e.contains("rule 1"),
        "{e}"
    );
    let w = &Checkpoint::load(&ck).unwrap().metadata["trainer"]["world"];
    assert_eq!(
        w["fingerprint_rule"], 2,
        "the resumed run stores the new rule"
    );
    edit_checkpoint(&run, old_world("0123456789abcdef"));
    let (ok, e) = resume(&run, 5, &["--data", s(&data)]);
    assert!(!ok && e.contains("0123456789abcdef"), "{e}");
}

/// Offline loader gaps: a second copy of a scene under a zero-padded name, NaN and 3e38 in
/// feature files, a link loop and a device file reported as "missing file", and targets
/// visible from no state counted nowhere.
#[cfg(feature = "offline")]
#[test]
fn offline_loader_gaps_are_named() {
    let d = tmp("offline-gaps");
    let data = d.join("data");
    fixture_at(&data);
    let load = |d: &Path| {
        let _l = spawn_lock();
        World::load(d).map(|_| ()).map_err(|e| format!("{e:#}"))
    };
    let eval = |d: &Path| {
        let (ok, _, e) = gman(&[
            "eval",
            "--data",
            s(d),
            "--split",
            "val",
            "--agent",
            "oracle",
            "--quiet",
        ]);
        assert!(!e.contains("panicked"), "{e}");
        (ok, e)
    };
    let copy_of = |name: &str| {
        let c = d.join(name);
        let _ = std::fs::remove_dir_all(&c);
        copy_tree(&data, &c);
        c
    };
    let (ok, e) = eval(&data);
    assert!(ok && !e.contains("warning"), "{e}");

    // FloorPlan022 beside FloorPlan22; FloorPlan022 alone.
    let c = copy_of("dup");
    copy_tree(&c.join("FloorPlan22"), &c.join("FloorPlan022"));
    let e = load(&c).unwrap_err();
    assert!(
        e.contains("twice") && e.contains("FloorPlan022") && e.contains("FloorPlan22 "),
        "{e}"
    );
    std::fs::remove_dir_all(c.join("FloorPlan22")).unwrap();
    let e = load(&c).unwrap_err();
    assert!(
        e.contains("leading zero") && e.contains("FloorPlan022"),
        "{e}"
    );

    // NaN and 3e38 in a feature map, 3e38 in a PS target: the file and the key.
    for (file, bad) in [
        ("resnet18_featuremap.hdf5", f32::NAN),
        ("resnet18_featuremap.hdf5", 3e38),
        ("att_in_view_v2.hdf5", 3e38),
    ] {
        let c = copy_of("values");
        let path = c.join("FloorPlan22").join(file);
        let key = h5_names(&path)[3].clone();
        edit_h5(&path, |n, v| {
            if n == key {
                v[7] = bad;
            }
        });
        let (ok, e) = eval(&c);
        assert!(
            !ok && e.contains(&format!("FloorPlan22/{file}"))
                && e.contains(&format!("dataset {key:?}"))
                && e.contains("index 7"),
            "{file} {bad}: {e}"
        );
    }
    // Training reads the training scenes up front: NaN in one is named too.
    let c = copy_of("train-nan");
    edit_h5(&c.join("FloorPlan1/resnet18_featuremap.hdf5"), |_, v| {
        v[0] = f32::NAN
    });
    let (ok, _, e) = gman(&[
        "train",
        "--data",
        s(&c),
        "--method",
        "a3c",
        "--config",
        "tiny",
        "--updates",
        "1",
        "--quiet",
        "--out",
        s(&d.join("nan-run")),
    ]);
    assert!(
        !ok && e.contains("FloorPlan1/resnet18_featuremap.hdf5") && !e.contains("panicked"),
        "{e}"
    );

    // A link loop, a device file, a broken link, a directory.
    #[cfg(unix)]
    {
        let c = copy_of("links");
        let g = c.join("FloorPlan2/graph.json");
        std::fs::remove_file(&g).unwrap();
        std::os::unix::fs::symlink("graph.json", &g).unwrap();
        let e = load(&c).unwrap_err();
        assert!(
            e.contains("symbolic link loop") && e.contains("graph.json"),
            "{e}"
        );
        std::fs::remove_file(&g).unwrap();
        std::os::unix::fs::symlink("/dev/null", &g).unwrap();
        let e = load(&c).unwrap_err();
        assert!(
            e.contains("not a regular file") && e.contains("graph.json"),
            "{e}"
        );
        std::fs::remove_file(&g).unwrap();
        std::os::unix::fs::symlink("nowhere.json", &g).unwrap();
        let e = load(&c).unwrap_err();
        assert!(e.contains("broken symbolic link"), "{e}");
        std::fs::remove_file(&g).unwrap();
        std::fs::create_dir(&g).unwrap();
        let e = load(&c).unwrap_err();
        assert!(e.contains("is a directory"), "{e}");
        // An optional file that is a loop is not "absent".
        std::fs::remove_dir(&g).unwrap();
        std::fs::copy(data.join("FloorPlan2/graph.json"), &g).unwrap();
        let a = c.join("FloorPlan2/att_in_view_v2.hdf5");
        std::os::unix::fs::symlink("att_in_view_v2.hdf5", &a).unwrap();
        let e = load(&c).unwrap_err();
        assert!(
            e.contains("symbolic link loop") && e.contains("att_in_view_v2"),
            "{e}"
        );
    }

    // Every instance of the val scene's objects visible from no state: its episodes cannot
    // succeed, and eval says how many.
    let c = copy_of("invisible");
    let vis = c.join("FloorPlan22/visible_object_map.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&vis).unwrap()).unwrap();
    let ep = std::fs::read_to_string(c.join("episodes/val/kitchen_seen.jsonl")).unwrap();
    let target: serde_json::Value = serde_json::from_str(ep.lines().next().unwrap()).unwrap();
    let target = target["target"].as_str().unwrap().to_string();
    let mut emptied = 0;
    for (id, keys) in v.as_object_mut().unwrap() {
        if id.split('|').next() == Some(target.as_str()) {
            *keys = serde_json::json!([]);
            emptied += 1;
        }
    }
    assert!(emptied > 0);
    std::fs::write(&vis, v.to_string()).unwrap();
    let (ok, e) = eval(&c);
    assert!(
        ok && e.contains("cannot succeed") && e.contains(&target) && e.contains("FloorPlan22"),
        "{e}"
    );
}

/// Copies a directory tree (files and folders).
#[cfg(feature = "offline")]
fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        if e.file_type().unwrap().is_dir() {
            copy_tree(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}
