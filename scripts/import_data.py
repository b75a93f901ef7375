#!/usr/bin/env python3
"""Build the GMAN benchmark data directory from a clone of the public GMAN repository, and
check a data directory against the committed checksums.

Standard library only (Python >= 3.8).

    # the official val/test episodes from a clone of https://github.com/sx-zhang/GMAN
    python3 scripts/import_data.py episodes --gman PATH/TO/GMAN --out DATA_DIR
    # is DATA_DIR the data of the documented results? (every file in data/SHA256SUMS)
    python3 scripts/import_data.py check DATA_DIR

`episodes` reads `test_val_split/{room}_{val|test}_{seen|unseen}.pkl` (Python pickles of
dicts with `scene`, `goal_object_type`, `task_data` and a `ThorAgentState` `state`; they are
read with a restricted unpickler that builds no foreign classes) and writes
`episodes/{val|test}/{room}_{seen|unseen}.jsonl`, one JSON object a line with sorted keys:
`room`, `scene`, `split`, `start` {horizon, rotation, x, y, z}, `target`, `target_ids`,
`target_kind`. See docs/data.md.
"""

import argparse
import hashlib
import json
import os
import pickle
import sys

ROOMS = ["kitchen", "living_room", "bedroom", "bathroom"]
KINDS = ["seen", "unseen"]
SPLITS = ["val", "test"]
SUMS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "data", "SHA256SUMS")


class ImportError_(Exception):
    """A clear error about an input file."""


class _State:
    """Stands in for the pickled `ThorAgentState`: keeps its attributes only."""

    def __init__(self, *args, **kwargs):
        self.__dict__["_args"] = args

    def __setstate__(self, state):
        if isinstance(state, tuple) and len(state) == 2:
            state = state[0] or state[1]
        if not isinstance(state, dict):
            raise pickle.UnpicklingError("ThorAgentState without a dict state")
        self.__dict__.update(state)


class _Unpickler(pickle.Unpickler):
    """Allows only the one class the episode files use; everything else is refused."""

    def find_class(self, module, name):
        if name == "ThorAgentState":
            return _State
        raise pickle.UnpicklingError(f"refusing to load {module}.{name}")


def load_pickle(path):
    try:
        with open(path, "rb") as f:
            return _Unpickler(f).load()
    except FileNotFoundError:
        raise ImportError_(f"missing file {path}") from None
    except (pickle.UnpicklingError, EOFError, ValueError) as e:
        raise ImportError_(f"{path}: not an episode pickle ({e})") from None


def convert_episode(raw, room, split, kind, where):
    """One GMAN episode dict -> the JSON object of our episode files."""
    try:
        st = raw["state"]
        st = st.__dict__ if isinstance(st, _State) else st
        ids = raw["task_data"]
        ids = [ids] if isinstance(ids, str) else list(ids)
        return {
            "room": room,
            "scene": raw["scene"],
            "split": split,
            "start": {k: st[k] for k in ("horizon", "rotation", "x", "y", "z")},
            "target": raw["goal_object_type"],
            "target_ids": ids,
            "target_kind": kind,
        }
    except (KeyError, TypeError) as e:
        raise ImportError_(f"{where}: episode without field {e}") from None


def episodes(gman, out, splits=SPLITS):
    """Writes the episode files of `splits`; returns the paths written."""
    written = []
    for split in splits:
        for room in ROOMS:
            for kind in KINDS:
                src = os.path.join(gman, "test_val_split", f"{room}_{split}_{kind}.pkl")
                raw = load_pickle(src)
                if not isinstance(raw, list):
                    raise ImportError_(f"{src}: expected a list of episodes")
                lines = [
                    json.dumps(convert_episode(e, room, split, kind, f"{src} episode {i}"),
                               sort_keys=True)
                    for i, e in enumerate(raw)
                ]
                d = os.path.join(out, "episodes", split)
                os.makedirs(d, exist_ok=True)
                p = os.path.join(d, f"{room}_{kind}.jsonl")
                with open(p, "w", encoding="utf-8", newline="\n") as f:
                    f.write("".join(line + "\n" for line in lines))
                written.append(p)
    return written


def sha256(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def read_sums(path):
    sums = {}
    with open(path, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            line = line.rstrip("\n")
            if not line:
                continue
            parts = line.split("  ", 1)
            if len(parts) != 2 or len(parts[0]) != 64:
                raise ImportError_(f"{path} line {n}: not `SHA256  relative/path`")
            sums[parts[1]] = parts[0]
    return sums


def check(data, sums_path=SUMS, only=None):
    """Compares `data` with the checksum file (only the files under the prefixes `only`, if
    given); returns (ok, problems, checked)."""
    sums = read_sums(sums_path)
    problems, checked = [], 0
    for rel, want in sorted(sums.items()):
        p = os.path.join(data, rel)
        if only and not any(rel == o or rel.startswith(o.rstrip("/") + "/") for o in only):
            continue
        if not os.path.isfile(p):
            problems.append(f"missing {rel}")
            continue
        checked += 1
        got = sha256(p)
        if got != want:
            problems.append(f"differs {rel} (sha256 {got}, expected {want})")
    return not problems, problems, checked


def write_sums(data, out):
    rels = []
    for root, _, files in os.walk(data):
        for f in files:
            rels.append(os.path.relpath(os.path.join(root, f), data).replace(os.sep, "/"))
    with open(out, "w", encoding="utf-8", newline="\n") as f:
        for rel in sorted(rels):
            f.write(f"{sha256(os.path.join(data, rel))}  {rel}\n")
    return len(rels)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("episodes", help="official val/test episodes from a GMAN clone")
    e.add_argument("--gman", required=True, help="clone of github.com/sx-zhang/GMAN")
    e.add_argument("--out", required=True, help="data directory to write into")
    e.add_argument("--split", choices=SPLITS, action="append",
                   help="split to write (repeatable; default: val and test)")
    c = sub.add_parser("check", help="compare a data directory with data/SHA256SUMS")
    c.add_argument("data")
    c.add_argument("--sums", default=SUMS, help="checksum file (default: data/SHA256SUMS)")
    c.add_argument("--only", action="append", metavar="PREFIX",
                   help="check only files under PREFIX, e.g. episodes/val (repeatable)")
    s = sub.add_parser("sums", help="write the checksum file of a data directory")
    s.add_argument("data")
    s.add_argument("--out", default=SUMS)
    a = ap.parse_args(argv)
    try:
        if a.cmd == "episodes":
            if not os.path.isdir(os.path.join(a.gman, "test_val_split")):
                raise ImportError_(f"--gman {a.gman}: no test_val_split/ folder (a GMAN clone?)")
            for p in episodes(a.gman, a.out, a.split or SPLITS):
                print(f"wrote {p}")
        elif a.cmd == "check":
            ok, problems, n = check(a.data, a.sums, a.only)
            for p in problems:
                print(p, file=sys.stderr)
            if not ok:
                print(f"{a.data}: {len(problems)} file(s) differ from {a.sums}", file=sys.stderr)
                return 1
            print(f"ok: {n} files of {a.data} match {a.sums}")
        else:
            print(f"wrote {a.out}: {write_sums(a.data, a.out)} files")
    except (ImportError_, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
