#!/usr/bin/env python3
"""Runs `gman bench` and the PyTorch reference in one invocation and prints the speed-ups.

    python3 host-sim/benches/compare.py --python /path/to/venv/bin/python [--reps 15]

`--python` is the interpreter that has PyTorch (`python3 -m venv VENV && VENV/bin/pip install
torch numpy`); when it cannot import torch the script says so and exits 0. `--gman` selects a
built binary; by default the release binary is built and run through `cargo run --release`.
Only the standard library is needed here. Never run in CI (timings, large download).
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
MSG = "PyTorch not installed: pip install torch numpy (in a venv) to run the comparison"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--python", default=sys.executable, help="interpreter with PyTorch")
    ap.add_argument("--gman", help="path of a built `gman` binary (default: cargo run --release)")
    ap.add_argument("--reps", type=int, default=15)
    ap.add_argument("--train-updates", type=int, default=150)
    ap.add_argument("--preset", action="append", choices=["mcu", "paper"])
    a = ap.parse_args()
    presets = a.preset or ["mcu", "paper"]

    probe = subprocess.run([a.python, "-c", "import torch"], capture_output=True)
    if probe.returncode != 0:
        print(MSG)
        return 0

    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "rust.json")
        cmd = [a.gman] if a.gman else [
            "cargo", "run", "--quiet", "--release", "-p", "gman-host-sim", "--bin", "gman", "--"]
        cmd += ["bench", "--reps", str(a.reps), "--train-updates", str(a.train_updates),
                "--json", out]
        for p in presets:
            cmd += ["--preset", p]
        subprocess.run(cmd, cwd=ROOT, check=True)  # prints the full table
        with open(out) as f:
            rust = json.load(f)
    ref_cmd = [a.python, os.path.join(HERE, "torch_reference.py"), "--reps", str(a.reps)]
    for p in presets:
        ref_cmd += ["--preset", p]
    torch_res = json.loads(subprocess.run(ref_cmd, check=True, capture_output=True,
                                          text=True).stdout)

    print()
    print(f"Rust (gman-core) against PyTorch {torch_res['torch']} eager, 1 thread, batch 1, "
          "f32 unless noted; speed-up = PyTorch time / Rust time (goal: >= 10x)")
    print()
    print("| preset | what | PyTorch | Rust f32 Full (same maths) | speed-up | Rust fastest "
          "(weights, mode) | speed-up |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for p in presets:
        t = torch_res["presets"][p]
        rows = [r for r in rust["navigator"] if r["preset"] == p]
        same = next((r for r in rows if r["quant"] == "f32" and r["mode"] == "Full"), None)
        for what, tk, rk, unit, scale in (
            ("step", "step_us", "step_us", "µs", 1.0),
            ("adaptation k=20", "adapt_ms", "adapt_ms", "ms", 1.0),
        ):
            best = min(rows, key=lambda r: r[rk])
            s_same = f"{same[rk] * scale:.1f} {unit}" if same else "-"
            r_same = f"{t[tk] / same[rk]:.2f}x" if same else "-"
            print(f"| {p} | {what} | {t[tk]:.1f} {unit} | {s_same} | {r_same} | "
                  f"{best[rk]:.1f} {unit} ({best['quant']}, {best['mode']}) | "
                  f"{t[tk] / best[rk]:.2f}x |")
        print(f"| {p} | step, PyTorch with autograd recording | {t['step_autograd_us']:.1f} µs "
              "| | | | |")
        print(f"| {p} | adaptation, second order (create_graph) | {t['adapt2_ms']:.1f} ms "
              "| (no counterpart) | | | |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
