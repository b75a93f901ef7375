#!/usr/bin/env python3
"""How an agent's episodes end, from `gman eval --episodes-out FILE.jsonl` files.

    python3 host-sim/scripts/episode-stats.py random.jsonl a3c-s1.jsonl ...

For each file and target kind (seen, unseen): SR; the share of episodes ended by Done (the
rest hit the step limit); SR among Done episodes (Done precision); the share in which the
target was ever visible, and SR among those (how often a visible target is claimed); the
mean step of the first sight of the target; the mean episode length; the mean distance to
success (DTS, metres) of failed Done episodes (where the agent stops when it is wrong).
Standard library only.
"""
import json
import sys


def stats(rows):
    n = len(rows)
    if n == 0:
        return None
    m = [r["metrics"] for r in rows]
    done = [x for x in m if x.get("done_called")]
    seen = [x for x in m if x.get("target_first_visible") is not None]
    wrong = [x for x in done if not x["success"]]

    def mean(xs):
        return sum(xs) / len(xs) if xs else float("nan")

    return {
        "episodes": n,
        "sr": 100 * mean([x["success"] for x in m]),
        "done_rate": 100 * len(done) / n,
        "sr_given_done": 100 * mean([x["success"] for x in done]),
        "target_seen": 100 * len(seen) / n,
        "sr_given_seen": 100 * mean([x["success"] for x in seen]),
        "first_seen_step": mean([x["target_first_visible"] for x in seen]),
        "length": mean([x["path_length"] for x in m]),
        "done_step": mean([x["path_length"] for x in done]),
        "dts_wrong_done": mean([x["dts"] for x in wrong]),
    }


COLS = [
    ("sr", "SR"),
    ("done_rate", "Done%"),
    ("sr_given_done", "SR|Done"),
    ("target_seen", "seen%"),
    ("sr_given_seen", "SR|seen"),
    ("first_seen_step", "1st sight"),
    ("length", "length"),
    ("done_step", "Done at"),
    ("dts_wrong_done", "DTS wrong"),
]


def main(paths):
    if not paths:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    head = "| file | kind | " + " | ".join(c[1] for c in COLS) + " |"
    print(head)
    print("|" + "---|" * (len(COLS) + 2))
    for p in paths:
        try:
            with open(p) as f:
                rows = [json.loads(line) for line in f if line.strip()]
        except (OSError, ValueError) as e:
            print(f"{p}: {e}", file=sys.stderr)
            return 1
        for kind in ("seen", "unseen"):
            s = stats([r for r in rows if r.get("kind") == kind])
            if s is None:
                continue
            cells = " | ".join(f"{s[k]:.1f}" for k, _ in COLS)
            print(f"| {p} | {kind} | {cells} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
