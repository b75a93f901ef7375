#!/usr/bin/env python3
"""The mean of a run's last N val evaluations, as an evaluation JSON that `gman table` reads.

One checkpoint's val SR moves by several points from one 1 M-step curve point to the next,
so the last point alone is a noisy estimate of where a run ended. For every finished run
RUNS/ROW-sS (one whose OUT/ROW/sS.json exists) this writes OUT/ROW-lastN/sS.json: SR, SPL,
EPA and DTS, unseen and seen, averaged over the run's last N curve points
(RUNS/ROW-sS/curve/k*.json, ordered by their step count). Then

    gman table --runs OUT/gman-last3 OUT/a3c-fg-last3 ...

gives the table and the t tests on those estimates. Usage:

    python3 host-sim/scripts/last_points.py OUT [N]     # N defaults to 3

OUT is the sweep's directory (host-sim/scripts/paper-tables.sh) or a restored copy of
results/paper. Standard library only.
"""

import json
import re
import sys
from pathlib import Path

METRICS = ("sr", "spl", "epa", "dts")
KINDS = ("unseen", "seen")


def curve_points(run: Path) -> list:
    """The run's curve files, ordered by the environment steps they were measured at."""
    pts = []
    for f in (run / "curve").glob("k*.json"):
        m = re.fullmatch(r"k(\d+)\.json", f.name)
        if m:
            pts.append((int(m.group(1)), f))
    return [f for _, f in sorted(pts)]


def average(files: list) -> dict:
    """One evaluation JSON whose results are the means of the files' results."""
    docs = []
    for f in files:
        try:
            docs.append(json.loads(f.read_text()))
        except (OSError, ValueError) as e:
            raise SystemExit(f"{f}: not an evaluation JSON ({e})")
    out = {
        "split": docs[0].get("split", "?"),
        "agent": f"mean of {len(files)} curve points: " + ", ".join(f.name for f in files),
        "results": {},
    }
    for kind in KINDS:
        row = {}
        for m in METRICS:
            try:
                row[m] = sum(d["results"][kind][m] for d in docs) / len(docs)
            except (KeyError, TypeError):
                raise SystemExit(f"results.{kind}.{m} missing in one of {[str(f) for f in files]}")
        row["episodes"] = docs[0]["results"][kind].get("episodes")
        out["results"][kind] = row
    return out


def main(argv: list) -> int:
    if len(argv) not in (2, 3) or argv[1] in ("-h", "--help"):
        print(__doc__.strip(), file=sys.stderr)
        return 2
    out = Path(argv[1])
    n = int(argv[2]) if len(argv) == 3 else 3
    if n < 1:
        raise SystemExit("N must be at least 1")
    runs = out / "runs"
    if not runs.is_dir():
        raise SystemExit(f"{runs}: no such directory (OUT is the sweep's directory)")
    written = 0
    for run in sorted(runs.iterdir()):
        m = re.fullmatch(r"(.+)-s(\d+)", run.name)
        if not m or not (out / m.group(1) / f"s{m.group(2)}.json").exists():
            continue
        pts = curve_points(run)
        if len(pts) < n:
            print(f"{run}: {len(pts)} curve points, fewer than {n}; skipped", file=sys.stderr)
            continue
        dst = out / f"{m.group(1)}-last{n}" / f"s{m.group(2)}.json"
        dst.parent.mkdir(parents=True, exist_ok=True)
        dst.write_text(json.dumps(average(pts[-n:]), indent=2) + "\n")
        written += 1
    print(f"wrote {written} files into {out}/*-last{n}/")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
