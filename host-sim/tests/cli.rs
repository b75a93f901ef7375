//! The `gman` command line: eval JSON, scene PNG and clear errors on bad input.

mod common;

use std::path::PathBuf;
use std::process::Command;

fn gman(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_gman"))
        .args(args)
        .output()
        .expect("run gman");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gman-cli-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Trains `method` for two updates of the tiny configuration into `run`.
fn train_tiny(method: &str, run: &std::path::Path) {
    let (ok, _, err) = gman(&[
        "train",
        "--method",
        method,
        "--config",
        "tiny",
        "--workers",
        "1",
        "--updates",
        "2",
        "--quiet",
        "--out",
        run.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
}

#[test]
fn eval_synthetic_writes_json() {
    let d = tmp("eval");
    let json = d.join("out.json");
    let (ok, stdout, stderr) = gman(&[
        "eval",
        "--agent",
        "oracle",
        "--episodes",
        "5",
        "--quiet",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("Unseen Objects") && stdout.contains("SPL(%)"));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["split"], "val");
    assert_eq!(v["agent"], "oracle");
    assert_eq!(v["episodes"], 40);
    for k in ["seen", "unseen"] {
        assert_eq!(v["results"][k]["episodes"], 20);
        assert_eq!(v["results"][k]["sr"], 100.0);
        assert_eq!(v["results"][k]["spl"], 100.0);
        assert!(v["results"][k]["epa"].as_f64().unwrap() > 0.0);
        assert_eq!(v["results"][k]["dts"], 0.0);
    }
    assert_eq!(v["by_room"].as_object().unwrap().len(), 4);
    assert!(v["by_room"]["living_room"]["unseen"]["sr"].is_number());
}

#[test]
fn eval_real_data_random() {
    let Some(data) = common::data_dir() else {
        return;
    };
    let d = tmp("evalreal");
    let json = d.join("r.json");
    let (ok, _, stderr) = gman(&[
        "eval",
        "--data",
        data.to_str().unwrap(),
        "--split",
        "val",
        "--agent",
        "random",
        "--episodes",
        "20",
        "--seed",
        "1",
        "--quiet",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["episodes"], 160);
    assert!(v["results"]["unseen"]["sr"].as_f64().unwrap() < 50.0);
}

#[test]
fn clear_errors_on_bad_input() {
    let (ok, _, e) = gman(&["eval", "--data", "/nonexistent/gman-data", "--quiet"]);
    assert!(!ok && e.contains("/nonexistent/gman-data"), "{e}");
    assert!(!e.contains("panicked"));
    let (ok, _, e) = gman(&["eval", "--split", "bogus", "--quiet"]);
    assert!(!ok && e.contains("unknown split"), "{e}");
    let (ok, _, e) = gman(&["eval", "--agent", "does-not-exist.bin", "--quiet"]);
    assert!(!ok && e.contains("does-not-exist.bin"), "{e}");
    // A file that is neither a checkpoint nor a weight blob: a clear error naming it.
    let d = tmp("model");
    let model = d.join("model.bin");
    std::fs::write(&model, b"x").unwrap();
    let (ok, _, e) = gman(&["eval", "--agent", model.to_str().unwrap(), "--quiet"]);
    assert!(
        !ok && e.contains("model.bin") && e.contains("not a gman checkpoint"),
        "{e}"
    );
    assert!(!e.contains("panicked"));
    // A corrupted weight blob: the blob decoder's typed error.
    let blob = d.join("bad.gman");
    std::fs::write(&blob, b"GMAN\x01garbage").unwrap();
    let (ok, _, e) = gman(&["eval", "--agent", blob.to_str().unwrap(), "--quiet"]);
    assert!(
        !ok && e.contains("bad.gman") && !e.contains("panicked"),
        "{e}"
    );

    if let Some(data) = common::data_dir() {
        let data = data.to_str().unwrap();
        // The test split is held back: a clear error naming the missing directory.
        let (ok, _, e) = gman(&["eval", "--data", data, "--split", "test", "--quiet"]);
        assert!(!ok && e.contains("scenes/test"), "{e}");
        let (ok, _, e) = gman(&[
            "scene",
            "--data",
            data,
            "--scene",
            "FloorPlan999",
            "--png",
            "/tmp/x.png",
        ]);
        assert!(
            !ok && e.contains("FloorPlan999") && e.contains("FloorPlan22"),
            "{e}"
        );
        // Malformed JSON: the error names the file.
        let bad = tmp("bad");
        std::fs::copy(
            format!("{data}/attributes.json"),
            bad.join("attributes.json"),
        )
        .unwrap();
        std::fs::create_dir_all(bad.join("scenes/val")).unwrap();
        std::fs::write(bad.join("scenes/val/FloorPlan1.json"), "{ not json").unwrap();
        let (ok, _, e) = gman(&["eval", "--data", bad.to_str().unwrap(), "--quiet"]);
        assert!(!ok && e.contains("FloorPlan1.json"), "{e}");
        assert!(!e.contains("panicked"));
    }
}

#[test]
fn test_split_loads_when_present() {
    // A copy of the layout with the val data renamed to test: `--split test` simply works.
    let Some(data) = common::data_dir() else {
        return;
    };
    let d = tmp("testsplit");
    std::fs::copy(data.join("attributes.json"), d.join("attributes.json")).unwrap();
    for (sub, ext) in [("scenes", "json"), ("episodes", "jsonl")] {
        std::fs::create_dir_all(d.join(sub).join("test")).unwrap();
        for f in std::fs::read_dir(data.join(sub).join("val")).unwrap() {
            let f = f.unwrap().path();
            if f.extension().is_some_and(|e| e == ext) {
                let text = std::fs::read_to_string(&f)
                    .unwrap()
                    .replace("\"split\": \"val\"", "\"split\": \"test\"");
                std::fs::write(d.join(sub).join("test").join(f.file_name().unwrap()), text)
                    .unwrap();
            }
        }
    }
    let (ok, stdout, e) = gman(&[
        "eval",
        "--data",
        d.to_str().unwrap(),
        "--split",
        "test",
        "--agent",
        "oracle",
        "--episodes",
        "10",
        "--quiet",
    ]);
    assert!(ok, "{e}");
    assert!(stdout.contains("(test)"));
}

#[test]
fn scene_png_is_written() {
    let d = tmp("png");
    let png = d.join("s.png");
    let (ok, _, e) = gman(&[
        "scene",
        "--scene",
        "Synthetic-kitchen-val-0",
        "--png",
        png.to_str().unwrap(),
        "--episode",
        "0",
    ]);
    assert!(ok, "{e}");
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    if let Some(data) = common::data_dir() {
        let png = d.join("fp22.png");
        let (ok, _, e) = gman(&[
            "scene",
            "--data",
            data.to_str().unwrap(),
            "--scene",
            "FloorPlan22",
            "--png",
            png.to_str().unwrap(),
            "--episode",
            "3",
        ]);
        assert!(ok, "{e}");
        assert!(std::fs::metadata(&png).unwrap().len() > 1000);
    }
}

/// The flags of the ceiling diagnostics, the spatial map and the adaptation mode: impossible
/// combinations are refused before anything is loaded or trained.
#[test]
fn train_refuses_impossible_flag_combinations() {
    let d = tmp("train-flags");
    let out = d.join("run");
    let o = out.to_str().unwrap();
    for (args, needle) in [
        (vec!["--map", "3y3"], "ROWSxCOLS"),
        (vec!["--map", "0x3"], "ROWSxCOLS"),
        (vec!["--map", "3x3", "--cell-embed", "0"], "--cell-embed"),
        (
            vec!["--method", "gman", "--privileged-feature"],
            "--privileged-feature",
        ),
        (
            vec!["--method", "gman", "--meta-order", "2"],
            "--adapt-mode full",
        ),
        (vec!["--objective", "imitate"], "objective"),
        (vec!["--adapt-mode", "half"], "adapt-mode"),
    ] {
        let mut a = vec!["train", "--config", "tiny", "--out", o];
        a.extend(args.iter());
        let (ok, _, err) = gman(&a);
        assert!(!ok, "{args:?} was accepted");
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(!out.join("checkpoint.ckpt").exists());
    }
}

#[test]
fn emd_report_measures_a_gman_model() {
    let d = tmp("emd");
    let run = d.join("run");
    train_tiny("gman", &run);
    let ckpt = run.join("checkpoint.ckpt");
    let (png, json) = (d.join("fig3.png"), d.join("emd.json"));
    let (ok, stdout, err) = gman(&[
        "emd-report",
        "--agent",
        ckpt.to_str().unwrap(),
        "--episodes",
        "10",
        "--inner-lr",
        "1",
        "--png",
        png.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(stdout.contains("% closed"), "{stdout}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["inner_lr"], 1.0);
    let adapted =
        v["seen"]["episodes"].as_u64().unwrap() + v["unseen"]["episodes"].as_u64().unwrap();
    assert!(adapted > 0, "no adapted episode: {v}");
    // at α = 1 the inner loop moves G's output
    let moved = v["seen"]["moved"]
        .as_f64()
        .unwrap()
        .max(v["unseen"]["moved"].as_f64().unwrap());
    assert!(moved > 0.0, "{v}");
    assert!(std::fs::metadata(&png).unwrap().len() > 1000);
    // the probe flags: D's head reset each episode, every adapted episode's vectors dumped
    let dump = d.join("records.json");
    let (ok, stdout, err) = gman(&[
        "emd-report",
        "--agent",
        ckpt.to_str().unwrap(),
        "--episodes",
        "10",
        "--inner-lr",
        "1",
        "--disc-head-reset",
        "--dump",
        dump.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(stdout.contains("best point toward it closes"), "{stdout}");
    let recs: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&dump).unwrap()).unwrap();
    let recs = recs.as_array().unwrap();
    assert_eq!(recs.len() as u64, adapted, "one record per adapted episode");
    assert_eq!(recs[0]["initial"].as_array().unwrap().len(), 512);
    // a missing model is a clear error naming it
    let (ok, _, err) = gman(&[
        "emd-report",
        "--agent",
        d.join("nope.ckpt").to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("nope.ckpt"), "{err}");
}

/// `gman train --noise zero` reaches the model: the checkpoint exports to a blob whose flags
/// say zero noise (the default run's blob would not).
/// `gman export` of the run directory's checkpoint to `blob`, then what `gman inspect` prints
/// of it.
fn export_and_inspect(run: &std::path::Path, blob: &std::path::Path) -> String {
    let (ok, _, err) = gman(&[
        "export",
        "--ckpt",
        run.join("checkpoint.ckpt").to_str().unwrap(),
        "--out",
        blob.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let (ok, stdout, err) = gman(&["inspect", blob.to_str().unwrap()]);
    assert!(ok, "{err}");
    stdout
}

#[test]
fn train_noise_flag_reaches_the_blob() {
    let d = tmp("noise");
    let run = d.join("run");
    let (ok, _, err) = gman(&[
        "train",
        "--method",
        "gman",
        "--config",
        "tiny",
        "--workers",
        "1",
        "--updates",
        "1",
        "--noise",
        "zero",
        "--quiet",
        "--out",
        run.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let stdout = export_and_inspect(&run, &d.join("m.gman"));
    assert!(stdout.contains("zero noise"), "{stdout}");
    let (ok, _, err) = gman(&["train", "--noise", "none", "--out", run.to_str().unwrap()]);
    assert!(!ok && err.contains("--noise"), "{err}");
}

/// `--method gman-ref` trains gman-fixed-g with the reference's settings, which the exported
/// blob records; an explicit flag wins over the recipe's.
#[test]
fn gman_ref_recipe_reaches_the_blob() {
    let d = tmp("gman-ref");
    for (name, extra, want) in [
        ("ref", &[][..], "inner_lr=1e-2"),
        ("ref-lr", &["--inner-lr", "0.5"][..], "inner_lr=5e-1"),
    ] {
        let run = d.join(name);
        let mut args = vec!["train", "--method", "gman-ref", "--config", "tiny"];
        args.extend_from_slice(extra);
        args.extend(["--workers", "1", "--updates", "1", "--quiet", "--out"]);
        args.push(run.to_str().unwrap());
        let (ok, stdout, err) = gman(&args);
        assert!(ok, "{err}");
        assert!(
            stdout.contains("gman-fixed-g") || err.contains("gman-fixed-g"),
            "{stdout}{err}"
        );
        let stdout = export_and_inspect(&run, &d.join(format!("{name}.gman")));
        for setting in [
            "noise=zero",
            "disc_lr=0e0",
            "head_only=true",
            "adapt_loss=reference",
            want,
        ] {
            assert!(stdout.contains(setting), "{setting}: {stdout}");
        }
    }
}

#[test]
fn demo_writes_summary_pictures_and_intervals() {
    let d = tmp("demo");
    let out = d.join("demo");
    let (ok, stdout, stderr) = gman(&[
        "demo",
        "--updates",
        "20",
        "--episodes",
        "10",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("[95% CI]"), "{stdout}");
    assert!(stdout.contains("80 val episodes per agent"), "{stdout}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(v["split"], "val");
    assert_eq!(v["updates"], 20);
    let agents = v["agents"].as_array().unwrap();
    let names: Vec<&str> = agents
        .iter()
        .map(|a| a["agent"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["random", "a3c-fg", "gman"]);
    for a in agents {
        assert_eq!(a["episodes"], 80);
        for k in ["unseen", "seen"] {
            let r = &a[k];
            assert_eq!(r["episodes"], 40);
            let n = r["successes"].as_f64().unwrap();
            let sr = r["sr"]["value"].as_f64().unwrap();
            assert!((sr - 100.0 * n / 40.0).abs() < 1e-9, "{r}");
            let (lo, hi) = (
                r["sr"]["lo"].as_f64().unwrap(),
                r["sr"]["hi"].as_f64().unwrap(),
            );
            // A Wilson interval of 40 trials is never narrower than a few percent and always
            // holds the rate.
            assert!(lo <= sr && sr <= hi && hi - lo > 5.0, "{r}");
            let spl = &r["spl"];
            assert!(spl["lo"].as_f64().unwrap() <= spl["value"].as_f64().unwrap());
            assert!(spl["value"].as_f64().unwrap() <= spl["hi"].as_f64().unwrap());
        }
    }
    assert!(v["gman_vs_a3c_fg_distinguishable"].is_boolean());
    assert_eq!(v["verdict"].as_array().unwrap().len(), 3);
    for png in ["curve.png", "episode.png"] {
        let bytes = std::fs::read(out.join(png)).unwrap();
        assert_eq!(&bytes[1..4], b"PNG", "{png}");
    }
    assert!(stdout.contains("target/release/gman"), "{stdout}");
}

#[test]
fn ps_variant_blob_evaluates_with_its_ps_module() {
    let d = tmp("psblob");
    let run = d.join("run");
    train_tiny("a3c-ps", &run);
    let ckpt = run.join("checkpoint.ckpt");
    let blob = d.join("m.gman");
    let (ok, _, err) = gman(&[
        "export",
        "--ckpt",
        ckpt.to_str().unwrap(),
        "--quant",
        "f32",
        "--out",
        blob.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let eval = |agent: &PathBuf, ps: Option<&PathBuf>, json: &str| {
        let out = d.join(json);
        let mut args = vec![
            "eval",
            "--agent",
            agent.to_str().unwrap(),
            "--episodes",
            "3",
            "--quiet",
            "--json",
            out.to_str().unwrap(),
        ];
        if let Some(p) = ps {
            args.extend(["--ps", p.to_str().unwrap()]);
        }
        let (ok, _, err) = gman(&args);
        (ok, err, out)
    };
    // without its PS module the blob is refused, naming the flag
    let (ok, err, _) = eval(&blob, None, "none.json");
    assert!(!ok && err.contains("--ps"), "{err}");
    // a checkpoint carries its own
    let (ok, err, _) = eval(&ckpt, Some(&ckpt), "twice.json");
    assert!(!ok && err.contains("carries its own PS module"), "{err}");
    // the blob with the PS tensors of its checkpoint scores what the checkpoint scores
    let (ok, err, from_blob) = eval(&blob, Some(&ckpt), "blob.json");
    assert!(ok, "{err}");
    let (ok, err, from_ckpt) = eval(&ckpt, None, "ckpt.json");
    assert!(ok, "{err}");
    let read = |p: &PathBuf| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
    };
    let (b, c) = (read(&from_blob), read(&from_ckpt));
    assert_eq!(b["results"], c["results"]);
    assert_eq!(b["by_room"], c["by_room"]);
    // training keeps the PS module frozen: the pre-trained ps.ckpt serves as well
    let (ok, err, from_pretrained) = eval(&blob, Some(&run.join("ps").join("ps.ckpt")), "p.json");
    assert!(ok, "{err}");
    assert_eq!(read(&from_pretrained)["results"], c["results"]);
    // and another PS module gives other episodes (the PS input reaches the policy)
    let other = d.join("other");
    let (ok, _, err) = gman(&[
        "pretrain-ps",
        "--seed",
        "7",
        "--iters",
        "5",
        "--out",
        other.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(ok, "{err}");
    // the PS module the blob's model holds is the one given, bit for bit (a short run's
    // episodes barely depend on it, so the results above alone would not tell)
    use gman_host_sim::model::{load_model, load_model_with_ps};
    let w1 = |ps: Option<&PathBuf>, from: &PathBuf| -> Vec<f32> {
        let m = match ps {
            Some(p) => load_model_with_ps(from, None, Some(p)).unwrap(),
            None => load_model(from, None).unwrap(),
        };
        let ps = m.ps.expect("a PS module");
        ps.params.tensor("PsW1").unwrap().data.clone()
    };
    let trained = w1(None, &ckpt);
    assert_eq!(w1(Some(&ckpt), &blob), trained);
    assert_eq!(w1(Some(&run.join("ps").join("ps.ckpt")), &blob), trained);
    assert_ne!(w1(Some(&other.join("ps.ckpt")), &blob), trained);
    let _ = std::fs::remove_dir_all(&d);
}

/// Writes an evaluation JSON with SR `u` / `s` (unseen / seen) and fixed other metrics.
fn eval_json(path: &std::path::Path, u: f64, s: f64) {
    let split =
        |sr: f64| serde_json::json!({"episodes": 4, "sr": sr, "spl": 1.0, "epa": 2.0, "dts": 0.5});
    let j = serde_json::json!({"split": "val", "results": {"unseen": split(u), "seen": split(s)}});
    std::fs::write(path, j.to_string()).unwrap();
}

/// `gman table`: mean ± std per row, Welch's and the paired t against the first row, the
/// Markdown form, the spread picture, and clear errors on bad input.
#[test]
fn table_summarises_rows_and_draws_their_spread() {
    let d = tmp("table");
    // b's name is longer than the method column's default width
    let (a, b) = (d.join("a"), d.join("b-a-row-whose-name-is-long"));
    std::fs::create_dir_all(&a).unwrap();
    std::fs::create_dir_all(&b).unwrap();
    // a: unseen 1, 2, 3 (mean 2, std 1); b: 3, 5, 7 (mean 5, std 2); Welch's t of a - b is
    // -3 / sqrt(1/3 + 4/3) = -2.32; the differences -2, -3, -4 give a paired t of -5.20.
    for (i, (x, y)) in [(1.0, 3.0), (2.0, 5.0), (3.0, 7.0)].into_iter().enumerate() {
        eval_json(&a.join(format!("s{}.json", i + 1)), x, 10.0 + x);
        eval_json(&b.join(format!("s{}.json", i + 1)), y, 10.0 + y);
    }
    let png = d.join("spread.png");
    let (ok, stdout, err) = gman(&[
        "table",
        "--runs",
        a.to_str().unwrap(),
        b.to_str().unwrap(),
        "--png",
        png.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(
        stdout.contains("a [val x3]") && stdout.contains("2.00±1.00"),
        "{stdout}"
    );
    assert!(stdout.contains("5.00±2.00"), "{stdout}");
    assert!(
        stdout.contains("unseen  -3.00 (t -2.32, paired t -5.20)"),
        "{stdout}"
    );
    // the header and every row put their column bars at the same places
    let bars = |l: &str| -> Vec<usize> {
        l.chars()
            .enumerate()
            .filter(|&(_, c)| c == '|')
            .map(|(i, _)| i)
            .collect()
    };
    let lines: Vec<&str> = stdout.lines().take_while(|l| !l.starts_with('(')).collect();
    assert_eq!(lines.len(), 4, "{stdout}");
    assert!(lines.iter().all(|l| bars(l) == bars(lines[0])), "{stdout}");
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "not a PNG");
    assert!(
        stdout.contains(&format!("wrote {}", png.display())),
        "{stdout}"
    );

    let (ok, stdout, err) = gman(&["table", "--markdown", "--runs", a.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(stdout.contains("| a [val x3] | 2.00±1.00 |"), "{stdout}");

    // Bad input: a malformed file, a missing metric, an empty directory, an unwritable PNG.
    let bad = d.join("bad.json");
    std::fs::write(&bad, "{ not json").unwrap();
    let (ok, _, err) = gman(&["table", "--runs", bad.to_str().unwrap()]);
    assert!(!ok && err.contains("bad.json"), "{err}");
    let partial = d.join("partial.json");
    std::fs::write(
        &partial,
        r#"{"split": "val", "results": {"unseen": {"sr": 1}}}"#,
    )
    .unwrap();
    let (ok, _, err) = gman(&["table", "--runs", partial.to_str().unwrap()]);
    assert!(
        !ok && err.contains("partial.json") && err.contains("results.unseen.spl"),
        "{err}"
    );
    let empty = d.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let (ok, _, err) = gman(&["table", "--runs", empty.to_str().unwrap()]);
    assert!(!ok && err.contains("no .json"), "{err}");
    let nowhere = d.join("no-such-dir").join("x.png");
    let (ok, _, err) = gman(&[
        "table",
        "--runs",
        a.to_str().unwrap(),
        "--png",
        nowhere.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("x.png"), "{err}");
}

/// A blob whose checksum skips its header (format v2 here) loads with a warning naming the
/// file and the risk (`inspect`, `eval`); `upgrade-blob IN OUT` rewrites it in format v5,
/// refuses OUT = IN, and the upgraded blob evaluates to the same JSON, without the warning.
#[test]
fn legacy_blob_warns_and_upgrade_blob_evaluates_identically() {
    let old = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/models/gman-mcu-int8-seed1.gman"
    );
    let d = tmp("upgrade");
    let new = d.join("upgraded.gman");
    let new_s = new.to_str().unwrap();
    let warned = |stderr: &str, path: &str| {
        stderr.contains("warning:")
            && stderr.contains(path)
            && stderr.contains("checksums the payload only")
            && stderr.contains("upgrade-blob")
    };
    let (ok, out, err) = gman(&["inspect", old]);
    assert!(ok, "{err}");
    assert!(out.contains("format v2"), "{out}");
    assert!(
        warned(&err, old),
        "inspect of a v2 blob: no warning:\n{err}"
    );

    let (ok, _, err) = gman(&["upgrade-blob", old, old]);
    assert!(!ok && err.contains("same file"), "{err}");
    let (ok, out, err) = gman(&["upgrade-blob", old, new_s]);
    assert!(ok, "{err}");
    assert!(
        out.contains("format v2") && out.contains("format v5"),
        "{out}"
    );
    let (ok, out, err) = gman(&["inspect", new_s]);
    assert!(ok, "{err}");
    assert!(
        out.contains("format v5") && !err.contains("warning"),
        "{out}{err}"
    );
    for setting in [
        "D ascent steps per inner update 1",
        "descent step rule",
        "D head reset off",
        "adaptation loss",
        "L_D critic scale",
        "head-only adaptation",
        "commit delay 0 steps",
        "int8 activations",
        "compact Ψ",
        "settings by key: adapt=true emd=discriminator",
        "commit_delay=0 int8_activations=false compact_psi=false",
    ] {
        assert!(
            out.contains(setting),
            "inspect does not name `{setting}`:\n{out}"
        );
    }
    // A v4 blob with a flag bit this build does not know (checksum recomputed): refused,
    // naming the bit.
    let v4 = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/models/gman-thor5-map3-b16-mcu-int8-seed3.gman"
    );
    let unknown = d.join("unknown-bit.gman");
    std::fs::write(&unknown, with_flag_bit(&std::fs::read(v4).unwrap(), 22)).unwrap();
    let (ok, _, err) = gman(&["inspect", unknown.to_str().unwrap()]);
    assert!(!ok && err.contains("unknown model flag bit 22"), "{err}");
    // A v5 blob naming a setting this build does not know (checksum recomputed): refused by
    // every command, naming it.
    let unknown = d.join("unknown-setting.gman");
    let renamed = with_setting_renamed(&std::fs::read(&new).unwrap(), b"adapt", b"warp_");
    std::fs::write(&unknown, renamed).unwrap();
    let unknown = unknown.to_str().unwrap();
    for args in [
        &["inspect", unknown][..],
        &["eval", "--agent", unknown, "--episodes", "1", "--quiet"],
    ] {
        let (ok, _, err) = gman(args);
        assert!(
            !ok && err.contains("unknown model setting `warp_`"),
            "{args:?}: {err}"
        );
    }
    // Only the header changed: every tensor record is the old payload's.
    let (a, b) = (std::fs::read(old).unwrap(), std::fs::read(&new).unwrap());
    let (pa, pb) = (
        gman_core::blob::Blob::parse(&a).unwrap(),
        gman_core::blob::Blob::parse(&b).unwrap(),
    );
    let pl = pa.header().payload_len() as usize;
    assert_eq!(pl, pb.header().payload_len() as usize);
    assert_eq!(a[a.len() - pl..], b[b.len() - pl..]);

    let eval = |model: &str, json: &std::path::Path| {
        let (ok, _, err) = gman(&[
            "eval",
            "--agent",
            model,
            "--episodes",
            "3",
            "--quiet",
            "--json",
            json.to_str().unwrap(),
        ]);
        assert!(ok, "{err}");
        let mut v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap();
        // The agent is named by its path; everything else must be the same.
        v.as_object_mut().unwrap().remove("agent");
        (v, err)
    };
    let (va, err_a) = eval(old, &d.join("old.json"));
    let (vb, err_b) = eval(new_s, &d.join("new.json"));
    assert!(
        warned(&err_a, old),
        "eval of a v2 blob: no warning:\n{err_a}"
    );
    assert_eq!(
        err_a.matches("checksums the payload only").count(),
        1,
        "one warning:\n{err_a}"
    );
    assert!(!err_b.contains("checksums the payload only"), "{err_b}");
    assert_eq!(va, vb, "the upgraded blob evaluates differently");
    let _ = std::fs::remove_dir_all(&d);
}

/// The format v5 blob `v5` with its setting key `from` renamed `to` (the same length) and
/// its checksum recomputed (the last varint of the header, over every header byte before
/// it and the payload).
fn with_setting_renamed(v5: &[u8], from: &[u8], to: &[u8]) -> Vec<u8> {
    let blob = gman_core::blob::Blob::parse(v5).unwrap();
    let pl = blob.header().payload_len() as usize;
    assert_eq!(
        (v5[4], from.len()),
        (5, to.len()),
        "a v5 blob, a same-length key"
    );
    let end = v5.len() - pl;
    let mut crc_at = end - 1;
    while v5[crc_at - 1] & 0x80 != 0 {
        crc_at -= 1;
    }
    let mut head = v5[..crc_at].to_vec();
    let at = head
        .windows(from.len())
        .position(|w| w == from)
        .expect("the key in the header");
    head[at..at + to.len()].copy_from_slice(to);
    let payload = &v5[end..];
    let mut crc =
        gman_core::blob::crc32::crc32_update(gman_core::blob::crc32::crc32(&head), payload);
    while crc >= 0x80 {
        head.push(crc as u8 | 0x80);
        crc >>= 7;
    }
    head.push(crc as u8);
    head.extend_from_slice(payload);
    head
}

/// A format v4 blob with flag bit `bit` also set and its checksum recomputed (the header's
/// fields are LEB128 varints: magic, version, 8 dims, 3 map dims, then the flags; the
/// checksum is the last field, over every header byte before it and the payload).
fn with_flag_bit(v4: &[u8], bit: u32) -> Vec<u8> {
    fn varint(b: &[u8], at: &mut usize) -> u64 {
        let (mut v, mut shift) = (0u64, 0);
        loop {
            let byte = b[*at];
            *at += 1;
            v |= u64::from(byte & 0x7f) << shift;
            if byte & 0x80 == 0 {
                return v;
            }
            shift += 7;
        }
    }
    fn put(mut v: u64, out: &mut Vec<u8>) {
        while v >= 0x80 {
            out.push(v as u8 | 0x80);
            v >>= 7;
        }
        out.push(v as u8);
    }
    let blob = gman_core::blob::Blob::parse(v4).unwrap();
    let pl = blob.header().payload_len() as usize;
    assert_eq!(v4[4], 4, "a v4 blob");
    let mut at = 5;
    for _ in 0..11 {
        varint(v4, &mut at);
    }
    let start = at;
    let flags = varint(v4, &mut at);
    let mut head = v4[..start].to_vec();
    put(flags | 1 << bit, &mut head);
    // The checksum is the last varint before the payload: back over its continuation bytes.
    let end = v4.len() - pl;
    let mut crc_at = end - 1;
    while crc_at > at && v4[crc_at - 1] & 0x80 != 0 {
        crc_at -= 1;
    }
    head.extend_from_slice(&v4[at..crc_at]);
    let payload = &v4[end..];
    let crc = gman_core::blob::crc32::crc32_update(gman_core::blob::crc32::crc32(&head), payload);
    put(crc.into(), &mut head);
    head.extend_from_slice(payload);
    head
}

#[test]
fn export_makes_the_destination_directory() {
    // As the documented loops do: `--out /tmp/kq/NAME.gman` on a machine without /tmp/kq.
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let src = root.join("host-sim/models/gman-map3-b16-mcu-int8-seed1.gman");
    let out = tmp("export-mkdir").join("a/b/c.gman");
    let (ok, _, err) = gman(&[
        "export",
        "--blob",
        src.to_str().unwrap(),
        "--activations",
        "int8",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let (ok, stdout, err) = gman(&["inspect", out.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(stdout.contains("checksum OK"), "{stdout}");
}
