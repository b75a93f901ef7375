//! `gman train` under `mpirun` (`--features mpi`; needs OpenMPI's `mpirun` on the PATH):
//!
//! * 2 ranks x 1 worker write the same checkpoint, byte for byte, as one process with 2
//!   workers, for a3c and gman (tiny config), and so does a resume of each;
//! * a resume whose ranks x --workers differs from the run's worker count is refused;
//! * a rank whose parameters diverge stops the run with a clear error, and a rank that dies
//!   ends the job non-zero; in both the last checkpoint stays loadable.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use gman_host_sim::train::run_dir::checkpoint_path;
use gman_host_sim::train::state::TrainState;

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gman-mpi-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Runs `cmd` to its end (at most 5 minutes: a hang fails the test), returns (ok, stderr).
fn run(mut cmd: Command) -> (bool, String) {
    cmd.stdout(Stdio::null()).stderr(Stdio::piped());
    let mut child = cmd.spawn().expect("spawning (is mpirun installed?)");
    let start = Instant::now();
    loop {
        if let Some(_status) = child.try_wait().unwrap() {
            let out = child.wait_with_output().unwrap();
            return (
                out.status.success(),
                String::from_utf8_lossy(&out.stderr).into_owned(),
            );
        }
        if start.elapsed() > Duration::from_secs(300) {
            let _ = child.kill();
            panic!("{cmd:?} did not end within 5 minutes");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn gman(args: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_gman"));
    c.args(args);
    c
}

fn mpirun(ranks: usize, args: &[&str], env: &[(&str, &str)]) -> Command {
    let mut c = Command::new("mpirun");
    c.args([
        "-n",
        &ranks.to_string(),
        "--oversubscribe",
        "--allow-run-as-root",
    ]);
    for (k, v) in env {
        c.args(["-x", &format!("{k}={v}")]);
    }
    c.arg(env!("CARGO_BIN_EXE_gman")).args(args);
    c
}

fn train_args<'a>(method: &'a str, fg: &'a str, out: &'a str, workers: &'a str) -> Vec<&'a str> {
    vec![
        "train",
        "--method",
        method,
        "--config",
        "tiny",
        "--updates",
        "3",
        "--workers",
        workers,
        "--batch-envs",
        "2",
        "--min-steps",
        "10",
        "--max-steps",
        "30",
        "--fg",
        fg,
        "--quiet",
        "--out",
        out,
    ]
}

fn pretrained_fg(dir: &Path) -> String {
    let fg = dir.join("fg");
    let (ok, e) = run(gman(&[
        "pretrain-fg",
        "--iters",
        "3",
        "--quiet",
        "--out",
        fg.to_str().unwrap(),
    ]));
    assert!(ok, "pretrain-fg: {e}");
    fg.join("fg.ckpt").to_str().unwrap().to_string()
}

fn same_file(a: &Path, b: &Path) -> bool {
    std::fs::read(a).unwrap() == std::fs::read(b).unwrap()
}

#[test]
fn two_ranks_match_one_process_bit_for_bit() {
    let d = tmp("same");
    let fg = pretrained_fg(&d);
    for method in ["a3c", "gman"] {
        let one = d.join(format!("{method}-one"));
        let two = d.join(format!("{method}-two"));
        let (o1, t1) = (one.to_str().unwrap(), two.to_str().unwrap());
        let (ok, e) = run(gman(&train_args(method, &fg, o1, "2")));
        assert!(ok, "{method} in one process: {e}");
        let (ok, e) = run(mpirun(2, &train_args(method, &fg, t1, "1"), &[]));
        assert!(ok, "{method} on 2 ranks: {e}");
        assert!(e.contains("mpi: 2 ranks"), "{e}");
        assert!(
            same_file(&checkpoint_path(&one), &checkpoint_path(&two)),
            "{method}: 2 ranks x 1 worker differ from 1 process x 2 workers"
        );
        // A resume on the same ranks continues with the same bits.
        fn resume(dir: &str) -> Vec<&str> {
            vec!["train", "--resume", dir, "--updates", "5", "--quiet"]
        }
        let (ok, e) = run(gman(&resume(o1)));
        assert!(ok, "{e}");
        let (ok, e) = run(mpirun(2, &resume(t1), &[]));
        assert!(ok, "{e}");
        assert!(same_file(&checkpoint_path(&one), &checkpoint_path(&two)));
        assert_eq!(TrainState::load(&checkpoint_path(&two)).unwrap().update, 5);
    }
    // 2 ranks x 2 workers is not the run's 2 workers: refused unless asked for.
    let two = d.join("a3c-two");
    let t = two.to_str().unwrap();
    let args = [
        "train",
        "--resume",
        t,
        "--updates",
        "6",
        "--workers",
        "2",
        "--quiet",
    ];
    let (ok, e) = run(mpirun(2, &args, &[]));
    assert!(!ok && e.contains("--workers (x ranks) 4 conflicts"), "{e}");
    let mut changed = args.to_vec();
    changed.push("--change-workers");
    let (ok, e) = run(mpirun(2, &changed, &[]));
    assert!(ok, "{e}");
    let (st, meta) = TrainState::load_with_settings(&checkpoint_path(&two)).unwrap();
    assert_eq!((st.update, meta.run.workers), (6, 4));
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn diverging_or_dying_ranks_end_the_job_with_the_checkpoint_intact() {
    let d = tmp("fault");
    let fg = pretrained_fg(&d);
    for (fault, want) in [
        ("perturb:1:2", "the ranks diverged at update 2"),
        ("exit:1:2", ""),
    ] {
        let out = d.join(fault.replace(':', "-"));
        let o = out.to_str().unwrap();
        let mut args = train_args("a3c", &fg, o, "1");
        args[6] = "6"; // --updates
        args.extend(["--checkpoint-every", "1"]);
        args.extend(["--rank-check-every", "1"]);
        let (ok, e) = run(mpirun(2, &args, &[("GMAN_DIST_FAULT", fault)]));
        assert!(!ok, "{fault}: the job must fail: {e}");
        assert!(e.contains(want), "{fault}: {e}");
        let st = TrainState::load(&checkpoint_path(&out)).unwrap();
        assert!(
            (1..6).contains(&st.update),
            "{fault}: checkpoint at {}",
            st.update
        );
    }
    let _ = std::fs::remove_dir_all(&d);
}
