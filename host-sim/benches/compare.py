#!/usr/bin/env python3
"""Runs `gman bench`, the PyTorch reference and the ONNX Runtime reference in one invocation.

    python3 host-sim/benches/compare.py --python /path/to/venv/bin/python [--reps 15] \
        [--markdown host-sim/BENCHMARKS.md]

`--python` is the interpreter that has PyTorch and/or ONNX Runtime (`python3 -m venv VENV &&
VENV/bin/pip install torch onnx onnxruntime numpy`); a reference whose packages are missing is
skipped with a message. `--gman` selects a built binary; by default the release binary is
built and run through `cargo run --release`. `--markdown FILE` writes the tables into FILE
between the lines `<!-- compare.py: begin -->` and `<!-- compare.py: end -->` (the rest of the
file is kept). Only the standard library is needed here. Never run in CI (timings, downloads).
"""

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
BEGIN, END = "<!-- compare.py: begin -->", "<!-- compare.py: end -->"


def reference(python, script, module, presets, reps):
    """Runs one reference script if `module` imports; returns its JSON or None."""
    if subprocess.run([python, "-c", f"import {module}"], capture_output=True).returncode:
        print(f"{module} not importable by {python}: {script} skipped", file=sys.stderr)
        return None
    cmd = [python, os.path.join(HERE, script), "--reps", str(reps)]
    for p in presets:
        cmd += ["--preset", p]
    return json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)


def tables(rust, torch_res, ort_res, presets):
    """The comparison as Markdown lines."""
    out = []
    best = lambda rows, key: min(rows, key=lambda r: r[key]) if rows else None  # noqa: E731
    out.append("| preset | step | gman-core | ONNX Runtime | PyTorch eager | "
               "ONNX Runtime / gman-core | PyTorch / gman-core |")
    out.append("|---|---|---:|---:|---:|---:|---:|")
    for p in presets:
        rows = [r for r in rust["navigator"] if r["preset"] == p]
        t = torch_res["presets"][p] if torch_res else None
        o = ort_res["presets"][p] if ort_res else None
        for label, quants, okey, tkey in (
            ("f32", ["f32"], "f32_step_us", "step_us"),
            ("int8 weights", ["int8"], "int8_step_us", None),
            ("int8 weights x int8 activations", ["int8-act"], "int8_step_us", None),
        ):
            r = best([r for r in rows if r["quant"] in quants], "step_us")
            if r is None:
                continue
            ov = o[okey] if o else None
            tv = t[tkey] if (t and tkey) else None
            cell = lambda v: f"{v:.1f} µs" if v is not None else "-"  # noqa: E731
            ratio = lambda v: f"{v / r['step_us']:.2f}x" if v is not None else "-"  # noqa: E731
            out.append(f"| {p} | {label} | {r['step_us']:.1f} µs ({r['mode']}) | {cell(ov)} | "
                       f"{cell(tv)} | {ratio(ov)} | {ratio(tv)} |")
    if torch_res:
        out.append("")
        out.append("| preset | adaptation (k = 20) | gman-core fastest | PyTorch eager | "
                   "PyTorch / gman-core |")
        out.append("|---|---|---:|---:|---:|")
        for p in presets:
            rows = [r for r in rust["navigator"] if r["preset"] == p]
            r = best(rows, "adapt_ms")
            t = torch_res["presets"][p]
            out.append(f"| {p} | first order | {r['adapt_ms']:.2f} ms ({r['quant']}, {r['mode']}) "
                       f"| {t['adapt_ms']:.2f} ms | {t['adapt_ms'] / r['adapt_ms']:.2f}x |")
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--python", default=sys.executable, help="interpreter with the references")
    ap.add_argument("--gman", help="path of a built `gman` binary (default: cargo run --release)")
    ap.add_argument("--reps", type=int, default=15)
    ap.add_argument("--train-updates", type=int, default=150)
    ap.add_argument("--preset", action="append", choices=["mcu", "paper"])
    ap.add_argument("--markdown", help="write the tables into this Markdown file (see above)")
    a = ap.parse_args()
    presets = a.preset or ["mcu", "paper"]

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
    ort_res = reference(a.python, "onnx_reference.py", "onnxruntime", presets, a.reps)
    torch_res = reference(a.python, "torch_reference.py", "torch", presets, a.reps)
    versions = ", ".join(x for x in (
        f"ONNX Runtime {ort_res['onnxruntime']}" if ort_res else "",
        f"PyTorch {torch_res['torch']}" if torch_res else "") if x)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    head = [
        f"One run of `python3 host-sim/benches/compare.py --reps {a.reps}"
        f"{''.join(' --preset ' + p for p in a.preset or [])}` on "
        f"{datetime.date.today().isoformat()} ({os.cpu_count()} cores, load average "
        f"{load:.2f} at the end; {versions or 'no reference installed'}): medians of "
        f"{a.reps}, one thread each, batch 1; a ratio above 1 means gman-core is faster. "
        "gman-core's fastest adaptation mode per row; ONNX Runtime's int8 is "
        "`quantize_dynamic` (int8 weights, activations quantised on the fly).",
        "",
    ]
    lines = head + tables(rust, torch_res, ort_res, presets)
    print()
    print("\n".join(lines))
    if a.markdown:
        text = open(a.markdown).read() if os.path.exists(a.markdown) else ""
        block = "\n".join([BEGIN] + lines + [END])
        if BEGIN in text and END in text:
            text = text[:text.index(BEGIN)] + block + text[text.index(END) + len(END):]
        else:
            text = block + "\n\n" + text
        with open(a.markdown, "w") as f:
            f.write(text)
        print(f"wrote the tables into {a.markdown}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
