#!/usr/bin/env python3
"""Results tables and quoted figures in the docs, generated from the kept result files.

Standard library only (Python >= 3.8). A Markdown file holds generated parts between markers
(HTML comments: invisible when rendered); this script regenerates each part from the
evaluation JSON files it names (`gman eval --json`, e.g. `results/paper/ROW/sS.json`) and
either compares (`check`, what CI runs) or rewrites them (`write`):

    python3 scripts/gen_docs.py check            # exit 1 naming every part that differs
    python3 scripts/gen_docs.py write            # regenerate every part in place

Block parts, one marker line before and `<!-- /gen -->` after:

* `<!-- gen:table RUN... -->`: what `gman table --markdown --runs RUN...` prints (a row per
  RUN, a directory of JSON files or one file: mean ± sample std of SR, SPL, EPA, DTS on unseen
  and seen targets; then each row's SR against the first row's, Welch's t and paired t).
* `<!-- gen:seeds ROW[=LABEL] | ... -->`: each seed's val SR, unseen / seen, of every ROW
  (`results/paper/ROW/sS.json`), with the paper's SR for the rows the paper has.
* `<!-- gen:results ROW[=LABEL] | ... -->`: the paper's and this implementation's SR / SPL
  (mean ± std of the SR, mean of the SPL) side by side, and the number of seeds.
* `<!-- gen:gman ARGS -->`: what `gman ARGS` prints (a read-only command such as
  `shift-report --markdown`); not generated here: host-sim/tests/docs.rs runs the binary and
  compares (`GMAN_UPDATE_DOCS=1` rewrites the part).
* `<!-- gen:models DIR -->`: every `ROW-sS.gman` blob of DIR with its size, its `gman train`
  flags (from the `run` lines of host-sim/scripts/paper-tables.sh) and its run's val figures.

Inline figures: `<!-- fig:RUN:SPLIT:METRIC[:pm|mean|std|n] -->18.09 ± 1.94<!-- /fig -->`
(RUN as above, SPLIT `unseen` or `seen`, METRIC `sr`, `spl`, `epa` or `dts`; `pm` (default)
writes `mean ± std`, `mean`, `std`, `n` the number of files; `diff=RUN2`, `welch=RUN2` and
`paired=RUN2` the difference of the means to RUN2's, Welch's t and the paired t; two decimals).

RUN paths are relative to the repository root. Files scanned: ARCHITECTURE.md, docs/*.md and
every README.md of the repository (outside `target/` and hidden directories).
"""

import argparse
import glob
import json
import math
import os
import re
import sys

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
METRICS = ["sr", "spl", "epa", "dts"]
HEADS = ["SR(%)", "SPL(%)", "EPA(%)", "DTS(m)"]
SPLITS = ["unseen", "seen"]
KEPT = "results/paper"

# The paper's means (Zhang et al., ECCV 2022, Tables 2 and 3): SR / SPL unseen, SR / SPL seen,
# and how the paper's row differs from ours where it does.
PAPER = {
    "a3c": (21.50, 9.36, 31.37, 14.19, ""),
    "a3c-fg": (23.20, 8.87, 34.20, 15.11, ""),
    "gman": (28.03, 13.02, 39.30, 15.61, ""),
    "a3c-ps": (32.70, 20.30, 48.80, 26.85, ""),
    "a3c-fg-ps": (34.20, 19.64, 50.73, 26.38, ""),
    "gman-ps": (48.83, 25.09, 57.80, 28.41, ""),
    "gman-cossim": (46.47, 24.20, 53.63, 24.66, "with PS"),
    "gman-nometa": (41.93, 21.13, 53.47, 25.68, "with PS"),
}

BLOCK = re.compile(r"^<!-- gen:(\w+) (.*?) -->\n(.*?)^<!-- /gen -->$", re.M | re.S)
FIG = re.compile(r"<!-- fig:([^ ]+?) -->(.*?)<!-- /fig -->", re.S)


class GenError(Exception):
    """A marker or result file that cannot be read; the message names it."""


def load_run(root, run):
    """[(file name, {split: {metric: value}})] of a run directory (its *.json, name order) or
    one JSON file."""
    path = os.path.join(root, run)
    if os.path.isdir(path):
        files = sorted(glob.glob(os.path.join(path, "*.json")))
    elif os.path.isfile(path):
        files = [path]
    else:
        raise GenError(f"{run}: no such result directory or file")
    if not files:
        raise GenError(f"{run}: no *.json result files")
    out = []
    for f in files:
        try:
            with open(f, encoding="utf-8") as fh:
                j = json.load(fh)
            vals = {s: {m: float(j["results"][s][m]) for m in METRICS} for s in SPLITS}
            out.append((os.path.basename(f), vals, j.get("split", "?")))
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise GenError(f"{os.path.relpath(f, root)}: not an evaluation JSON ({e})") from None
    return out


def mean_std(v):
    m = sum(v) / len(v)
    s = math.sqrt(sum((x - m) ** 2 for x in v) / (len(v) - 1)) if len(v) > 1 else 0.0
    return m, s


def welch_t(a, b):
    if len(a) < 2 or len(b) < 2:
        return math.nan
    (ma, sa), (mb, sb) = mean_std(a), mean_std(b)
    se = math.sqrt(sa * sa / len(a) + sb * sb / len(b))
    return (ma - mb) / se if se > 0 else math.nan


def paired_t(a, b):
    if len(a) != len(b) or len(a) < 2:
        return math.nan
    m, s = mean_std([x - y for x, y in zip(a, b)])
    return m / (s / math.sqrt(len(a))) if s > 0 else math.nan


def t_cell(t):
    return f"{t:.2f}" if math.isfinite(t) else "-"


def column(files, split, metric):
    return [v[split][metric] for _, v, _ in files]


def gen_table(root, args):
    """`gman table --markdown --runs ARGS`, byte for byte."""
    runs = args.split()
    rows = []
    for r in runs:
        files = load_run(root, r)
        name = f"{os.path.basename(r.rstrip('/'))} [{files[-1][2]} x{len(files)}]"
        rows.append((name, files))
    heads = [f"{h} {s}" for s in SPLITS for h in HEADS]
    out = [f"| method | {' | '.join(heads)} |", "|---|" + "---:|" * 8]
    for name, files in rows:
        cells = []
        for s in SPLITS:
            for m in METRICS:
                mu, sd = mean_std(column(files, s, m))
                cells.append(f"{mu:.2f}±{sd:.2f}" if len(files) > 1 else f"{mu:.2f}")
        out.append(f"| {name} | {' | '.join(cells)} |")
    if len(rows) > 1:
        first_name, first = rows[0]
        out += ["", f"SR against {first_name} (difference of the means, Welch's t; paired t over "
                "the same seeds):", ""]
        for name, files in rows[1:]:
            paired = [f for f, _, _ in files] == [f for f, _, _ in first]
            parts = []
            for s in SPLITS:
                a, b = column(first, s, "sr"), column(files, s, "sr")
                d = mean_std(a)[0] - mean_std(b)[0]
                p = f", paired t {t_cell(paired_t(a, b))}" if paired else ""
                parts.append(f"{s} {d:+.2f} (t {t_cell(welch_t(a, b))}{p})")
            out.append(f"* {name} {' '.join(parts)}")
    return "\n".join(out)


def row_specs(args):
    """`ROW[=LABEL] | ...` -> [(row, label)]."""
    specs = []
    for part in args.split("|"):
        part = part.strip()
        if not part:
            continue
        row, _, label = part.partition("=")
        specs.append((row.strip(), label.strip() or row.strip()))
    if not specs:
        raise GenError("no rows named")
    return specs


def _paper_base(row):
    return row.replace("-adaptoff", "") if row.endswith("-adaptoff") else row


def gen_seeds(root, args):
    specs = row_specs(args)
    loaded = [(label, row, load_run(root, f"{KEPT}/{row}")) for row, label in specs]
    n = max(len(f) for _, _, f in loaded)
    head = "| method | " + " | ".join(f"seed {i + 1}" for i in range(n))
    out = [head + " | paper unseen / seen SR |", "|---|" + "---:|" * (n + 1)]
    for label, row, files in loaded:
        by_seed = {f: v for f, v, _ in files}
        cells = []
        for i in range(n):
            v = by_seed.get(f"s{i + 1}.json")
            cells.append(f"{v['unseen']['sr']:.2f} / {v['seen']['sr']:.2f}" if v else "")
        p = PAPER.get(row)
        paper = f"{p[0]:.2f} / {p[2]:.2f}" + (f" ({p[4]})" if p[4] else "") if p else ""
        out.append(f"| {label} | {' | '.join(cells)} | {paper} |")
    return "\n".join(out)


def gen_results(root, args):
    specs = row_specs(args)
    out = ["| method | paper unseen SR / SPL | paper seen SR / SPL | gman-rs unseen SR / SPL "
           "| gman-rs seen SR / SPL | seeds |", "|---|---:|---:|---:|---:|---:|"]
    for row, label in specs:
        files = load_run(root, f"{KEPT}/{row}")
        p = PAPER.get(row)
        paper = [f"{p[0]:.2f} / {p[1]:.2f}", f"{p[2]:.2f} / {p[3]:.2f}"] if p else ["", ""]
        if p and p[4]:
            paper = [c + f" ({p[4]})" for c in paper]
        ours = []
        for s in SPLITS:
            sr, sd = mean_std(column(files, s, "sr"))
            spl = mean_std(column(files, s, "spl"))[0]
            ours.append(f"{sr:.2f}±{sd:.2f} / {spl:.2f}" if len(files) > 1
                        else f"{sr:.2f} / {spl:.2f}")
        seeds = str(len(files)) if len(files) > 1 else ""
        out.append(f"| {label} | {' | '.join(paper)} | {' | '.join(ours)} | {seeds} |")
    return "\n".join(out)


def gen_fig(root, spec):
    parts = spec.split(":")
    if len(parts) not in (3, 4) or parts[1] not in SPLITS or parts[2] not in METRICS:
        raise GenError(f"fig:{spec}: expected fig:RUN:unseen|seen:sr|spl|epa|dts[:pm|mean|std|n]")
    run, split, metric = parts[:3]
    form = parts[3] if len(parts) == 4 else "pm"
    files = load_run(root, run)
    a = column(files, split, metric)
    m, s = mean_std(a)
    kind, _, other = form.partition("=")
    if other:  # against another run: difference of the means, Welch's t, paired t
        files2 = load_run(root, other)
        b = column(files2, split, metric)
        if kind == "diff":
            return f"{m - mean_std(b)[0]:+.2f}"
        if kind == "welch":
            return t_cell(welch_t(a, b))
        if kind == "paired":
            same = [f for f, _, _ in files] == [f for f, _, _ in files2]
            return t_cell(paired_t(a, b) if same else math.nan)
    forms = {"pm": f"{m:.2f} ± {s:.2f}", "mean": f"{m:.2f}", "std": f"{s:.2f}",
             "n": str(len(files))}
    if form not in forms:
        raise GenError(f"fig:{spec}: unknown form {form} (pm, mean, std, n, diff=RUN, "
                       "welch=RUN, paired=RUN)")
    return forms[form]


SWEEP = "host-sim/scripts/paper-tables.sh"
RUN_LINE = re.compile(r'^\s*run (\S+) (\S+) "\$1"(.*)$', re.M)


def sweep_flags(root):
    """{row: `gman train` flags} of the sweep script's `run ROW METHOD "$1" FLAGS` lines."""
    try:
        with open(os.path.join(root, SWEEP), encoding="utf-8") as f:
            text = f.read()
    except OSError as e:
        raise GenError(f"{SWEEP}: {e}") from None
    out = {}
    for row, method, rest in RUN_LINE.findall(text):
        rest = rest.replace('"$R/ps/ps.ckpt"', f"{KEPT}/ps/ps.ckpt").strip()
        out[row] = f"--method {method}" + (f" {rest}" if rest else "")
    return out


def gen_models(root, args):
    """The blobs of a models directory (`ROW-sS.gman`): size, training flags (the sweep
    script's), and the val figures of the run's checkpoint (`results/paper/ROW/sS.json`)."""
    d = args.strip()
    blobs = sorted(glob.glob(os.path.join(root, d, "*.gman")))
    if not blobs:
        raise GenError(f"{d}: no *.gman blobs")
    flags = sweep_flags(root)
    out = ["| model | training flags (`gman train ... --seed S`) | bytes | val unseen SR / SPL "
           "| val seen SR / SPL |", "|---|---|---:|---:|---:|"]
    for b in blobs:
        name = os.path.basename(b)
        m = re.match(r"^(.+)-s(\d+)\.gman$", name)
        if not m or m.group(1) not in flags:
            raise GenError(f"{d}/{name}: not ROW-sS.gman of a row of {SWEEP}")
        row, seed = m.group(1), m.group(2)
        (_, v, _), = load_run(root, f"{KEPT}/{row}/s{seed}.json")
        figs = [f"{v[s]['sr']:.2f} / {v[s]['spl']:.2f}" for s in SPLITS]
        out.append(f"| `{name}` | `{flags[row]}` | {os.path.getsize(b):,} | {' | '.join(figs)} |")
    return "\n".join(out)


GENERATORS = {"table": gen_table, "seeds": gen_seeds, "results": gen_results,
              "models": gen_models}


def process(root, text, where):
    """(new text, [problems]) of one file's text: every part regenerated."""
    problems = []

    def block(m):
        kind, args, old = m.group(1), m.group(2), m.group(3)
        line = text[:m.start()].count("\n") + 1
        if kind == "gman":
            # What `gman ARGS` prints: host-sim/tests/docs.rs runs the binary and compares.
            return m.group(0)
        if kind not in GENERATORS:
            raise GenError(f"{where}:{line}: unknown generated part gen:{kind}")
        try:
            new = GENERATORS[kind](root, args) + "\n"
        except GenError as e:
            raise GenError(f"{where}:{line}: {e}") from None
        if new != old:
            problems.append(f"{where}:{line}: gen:{kind} {args} differs from its result files"
                            + _first_diff(old, new))
        return f"<!-- gen:{kind} {args} -->\n{new}<!-- /gen -->"

    def fig(m):
        spec, old = m.group(1), m.group(2)
        line = text[:m.start()].count("\n") + 1
        try:
            new = gen_fig(root, spec)
        except GenError as e:
            raise GenError(f"{where}:{line}: {e}") from None
        if new != old:
            problems.append(f"{where}:{line}: fig:{spec} says {old!r}, its result files {new!r}")
        return f"<!-- fig:{spec} -->{new}<!-- /fig -->"

    out = BLOCK.sub(block, text)
    out = FIG.sub(fig, out)
    return out, problems


def _first_diff(old, new):
    a, b = old.splitlines(), new.splitlines()
    for i, (x, y) in enumerate(zip(a, b)):
        if x != y:
            return f"\n    line {i + 1} of the part: is   {x}\n    {' ' * len(str(i + 1))}" \
                   f"              want {y}"
    return f"\n    the part has {len(a)} lines, its result files give {len(b)}"


def doc_files(root):
    """README.md, ARCHITECTURE.md, docs/*.md and every README.md below the root (outside
    build and hidden directories)."""
    found = {os.path.join(root, "ARCHITECTURE.md")}
    found.update(glob.glob(os.path.join(root, "docs", "*.md")))
    for d, dirs, files in os.walk(root):
        dirs[:] = [x for x in dirs if x not in ("target", "node_modules") and not x.startswith(".")]
        if "README.md" in files:
            found.add(os.path.join(d, "README.md"))
    return sorted(f for f in found if os.path.isfile(f))


def run(root, write, files=None):
    """Returns the problems (check) or the files rewritten (write)."""
    problems, rewritten = [], []
    for f in files or doc_files(root):
        with open(f, encoding="utf-8") as fh:
            text = fh.read()
        rel = os.path.relpath(f, root)
        new, probs = process(root, text, rel)
        problems += probs
        if write and new != text:
            with open(f, "w", encoding="utf-8", newline="\n") as fh:
                fh.write(new)
            rewritten.append(rel)
    return rewritten if write else problems


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mode", choices=["check", "write"])
    ap.add_argument("files", nargs="*", help="Markdown files (default: the docs, see --help)")
    ap.add_argument("--root", default=ROOT, help="repository root (default: this checkout)")
    a = ap.parse_args(argv)
    try:
        out = run(a.root, a.mode == "write", a.files or None)
    except (GenError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if a.mode == "write":
        print("rewrote " + (", ".join(out) if out else "nothing: every part is current"))
        return 0
    for p in out:
        print(p, file=sys.stderr)
    if out:
        print(f"{len(out)} generated part(s) differ from the result files they quote; "
              "`python3 scripts/gen_docs.py write` regenerates them", file=sys.stderr)
        return 1
    print("ok: every generated table and quoted figure matches its result files")
    return 0


if __name__ == "__main__":
    sys.exit(main())
