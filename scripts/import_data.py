#!/usr/bin/env python3
"""Build the GMAN benchmark data directory from the public GMAN, ALFRED and rl_ai2thor
repositories, and check a data directory against the committed checksums.

Standard library only (Python >= 3.8).

    # the whole directory (val split only) from three clones, then the checksum check
    python3 scripts/import_data.py build --gman GMAN --alfred ALFRED --rl-ai2thor RL --out DIR
    # is DIR the data of the documented results? (every file in data/SHA256SUMS)
    python3 scripts/import_data.py check DIR

The parts, each also a command of its own (see `--help` and docs/data.md):

* `episodes`: GMAN's `test_val_split/{room}_val_{seen|unseen}.pkl` (pickled dicts with
  `scene`, `goal_object_type`, `task_data` and a `ThorAgentState` `state`, read by a restricted
  unpickler that builds no foreign classes) -> `episodes/val/{room}_{seen|unseen}.jsonl`.
* `attributes`: GMAN's `data/attributes/40_attribute.mat` (one 1 x 45 double per category,
  MAT-file version 5) and the split of the official episodes -> `attributes.json`.
* `scenes`: ALFRED's `gen/layouts/FloorPlanN-{layout.npy,objects.json,openable.json}` (and, for
  val scenes, the val episodes' starts and goal instances) -> `scenes/{train,val}/FloorPlanN.json`.
* `objects-thor5`: rl_ai2thor's `dev/data/objects_metadata_samples/FloorPlanN_physics.json`
  (AI2-THOR 5.0 object metadata) -> `objects_thor5/FloorPlanN.json`.

Only the train and val scenes and the val episodes are written: the test split (scenes 21,
23, 25, 27, 29 of each room type and their episodes) is held back and never read.
"""

import argparse
import ast
import hashlib
import json
import os
import pickle
import re
import shutil
import struct
import sys
import zlib

ROOMS = ["kitchen", "living_room", "bedroom", "bathroom"]
KINDS = ["seen", "unseen"]
SPLITS = ["val"]  # the test split is held back: never read, never written
HERE = os.path.dirname(os.path.abspath(__file__))
SUMS = os.path.normpath(os.path.join(HERE, "..", "data", "SHA256SUMS"))
DATA_README = os.path.normpath(os.path.join(HERE, "..", "data", "README.md"))
GRID_SIZE = 0.25
# FloorPlan number -> room: 1-30 kitchens, 201-230 living rooms, 301-330 bedrooms, 401-430 baths.
ROOM_BASE = {0: "kitchen", 2: "living_room", 3: "bedroom", 4: "bathroom"}
TRAIN_IDS = list(range(1, 21))
VAL_IDS = [22, 24, 26, 28, 30]
TEST_IDS = [21, 23, 25, 27, 29]
LAYOUT_SOURCE = ("ALFRED gen/layouts (ai2thor 2.1): reachable grid, object inventory, "
                 "openable object ids")
ATTR_SOURCE = "GMAN data/attributes/40_attribute.mat"
THOR5_SOURCE = ("AI2-THOR 5.0.0 default scene state (controller.reset(scene).metadata['objects']),"
                " as dumped in Kajiih/rl_ai2thor, MIT licence")

# The official category split of the GMAN val/test episodes (the paper's Sec. 5.1; GMAN's
# `datasets/constants.py` for the training targets). `attributes` checks every val episode's
# target against it, so a different GMAN checkout is an error, not a silently different split.
TRAIN_TARGETS_BY_ROOM = {
    "bathroom": ["Sink", "Bathtub", "LightSwitch", "ShowerCurtain"],
    "bedroom": ["Book", "AlarmClock", "Mug", "Chair"],
    "kitchen": ["Microwave", "Fridge", "GarbageCan", "Bowl", "Cabinet", "Pan", "Toaster"],
    "living_room": ["Pillow", "Television", "GarbageCan", "FloorLamp", "Shelf", "Laptop", "Sofa",
                    "Box", "SideTable"],
}
TARGETS_BY_ROOM = {
    "bathroom": {"seen": ["Bathtub", "LightSwitch", "ShowerCurtain", "Sink"],
                 "unseen": ["Drawer", "Faucet", "ShowerDoor", "Toilet", "ToiletPaper"]},
    "bedroom": {"seen": ["AlarmClock", "Book", "Chair", "DeskLamp", "Mug"],
                "unseen": ["ArmChair", "DeskLamp", "Drawer"]},
    "kitchen": {"seen": ["Bowl", "Cabinet", "Fridge", "GarbageCan", "Microwave", "Pan", "Toaster"],
                "unseen": ["CoffeeMachine", "Drawer", "Faucet", "Kettle", "Plate", "Pot",
                           "StoveBurner"]},
    "living_room": {"seen": ["Box", "FloorLamp", "GarbageCan", "HousePlant", "Laptop", "Pillow",
                             "Shelf", "SideTable", "Sofa", "Television"],
                    "unseen": ["ArmChair", "DeskLamp", "Drawer", "Plate"]},
}
SPLIT_NOTE = (
    "train_targets_by_room is the training target list of the GMAN code (24 seen). "
    "'seen'/'unseen' and by_room are the target types of the GMAN val/test episodes; the 12 "
    "unseen categories must never appear as objects in training scenes. DeskLamp and HousePlant "
    "are test targets listed as seen (they occur in training scenes but are not training "
    "targets); DeskLamp is also an unseen target in living rooms.")


class ImportError_(Exception):
    """A clear error about an input file."""


# ---------------------------------------------------------------------------------------------
# Episodes (GMAN pickles)


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


def read_episodes(gman):
    """The val episodes of a GMAN clone: {(room, kind): [episode dicts]}."""
    out = {}
    for room in ROOMS:
        for kind in KINDS:
            src = os.path.join(gman, "test_val_split", f"{room}_val_{kind}.pkl")
            raw = load_pickle(src)
            if not isinstance(raw, list):
                raise ImportError_(f"{src}: expected a list of episodes")
            out[(room, kind)] = [convert_episode(e, room, "val", kind, f"{src} episode {i}")
                                 for i, e in enumerate(raw)]
    return out


def write_episodes(eps, out):
    written = []
    d = os.path.join(out, "episodes", "val")
    os.makedirs(d, exist_ok=True)
    for (room, kind), lines in sorted(eps.items()):
        p = os.path.join(d, f"{room}_{kind}.jsonl")
        with open(p, "w", encoding="utf-8", newline="\n") as f:
            f.write("".join(json.dumps(e, sort_keys=True) + "\n" for e in lines))
        written.append(p)
    return written


def episodes(gman, out):
    """Writes the val episode files; returns the paths written."""
    return write_episodes(read_episodes(gman), out)


# ---------------------------------------------------------------------------------------------
# attributes.json (GMAN's MAT file)

_MAT_TYPES = {1: "b", 2: "B", 3: "h", 4: "H", 5: "i", 6: "I", 7: "f", 9: "d", 12: "q", 13: "Q"}


def _mat_element(buf, i, where):
    """(type, payload, next offset) of the MAT v5 data element at `i` (small format too)."""
    if i + 8 > len(buf):
        raise ImportError_(f"{where}: truncated data element at byte {i}")
    typ, size = struct.unpack_from("<II", buf, i)
    if typ >> 16:  # small data element: size in the upper half, payload in the next 4 bytes
        return typ & 0xFFFF, buf[i + 4:i + 4 + (typ >> 16)], i + 8
    end = i + 8 + size
    if end > len(buf):
        raise ImportError_(f"{where}: data element at byte {i} runs past the end")
    return typ, buf[i + 8:end], (end + 7) // 8 * 8


def read_mat(path):
    """The real numeric variables of a MAT-file version 5: {name: (dims, [values])}
    (column-major values, as MATLAB stores them). Compressed elements are inflated."""
    try:
        with open(path, "rb") as f:
            buf = f.read()
    except FileNotFoundError:
        raise ImportError_(f"missing file {path}") from None
    if len(buf) < 128 or not buf[:6] == b"MATLAB" or buf[126:128] != b"IM":
        raise ImportError_(f"{path}: not a little-endian MAT-file version 5")
    out, i = {}, 128
    while i < len(buf):
        typ, data, i = _mat_element(buf, i, path)
        if typ == 15:  # miCOMPRESSED
            try:
                data = zlib.decompress(data)
            except zlib.error as e:
                raise ImportError_(f"{path}: bad compressed element ({e})") from None
            typ, data, _ = _mat_element(data, 0, path)
        if typ != 14:  # not a matrix
            continue
        parts, k = [], 0
        while k < len(data):
            t, d, k = _mat_element(data, k, path)
            parts.append((t, d))
        if len(parts) < 4:
            raise ImportError_(f"{path}: matrix element with {len(parts)} parts")
        flags = struct.unpack_from("<I", parts[0][1])[0]
        if flags & 0xFF not in (6, 7, 8, 9, 10, 11, 12, 13, 14, 15) or flags & 0x800:
            continue  # not a real numeric array
        dims = list(struct.unpack(f"<{len(parts[1][1]) // 4}i", parts[1][1]))
        name = parts[2][1].decode("ascii")
        t, d = parts[3]
        if t not in _MAT_TYPES:
            raise ImportError_(f"{path}: variable {name} has data type {t}")
        fmt = _MAT_TYPES[t]
        n = len(d) // struct.calcsize(fmt)
        out[name] = (dims, [float(v) for v in struct.unpack(f"<{n}{fmt}", d)])
    return out


def attributes(gman, eps, out):
    """Writes `attributes.json`: the 45-d vectors of GMAN's MAT file (8 decimals) and the
    split, checked against the val episodes `eps`."""
    src = os.path.join(gman, "data", "attributes", "40_attribute.mat")
    cats = {}
    for name, (dims, vals) in read_mat(src).items():
        if len(vals) != 45:
            raise ImportError_(f"{src}: variable {name} has {len(vals)} values (dims {dims}), "
                               "expected 45")
        cats[name] = [round(v, 8) for v in vals]
    if len(cats) != 40:
        raise ImportError_(f"{src}: {len(cats)} category variables, expected 40")
    for (room, kind), lines in eps.items():
        for n, e in enumerate(lines):
            if e["target"] not in TARGETS_BY_ROOM[room][kind]:
                raise ImportError_(f"{room}_val_{kind}.pkl episode {n}: target {e['target']} "
                                   f"is not a {kind} {room} target of the official split")
            if e["target"] not in cats:
                raise ImportError_(f"{src}: no attribute vector for target {e['target']}")
    seen = sorted({c for r in TARGETS_BY_ROOM.values() for c in r["seen"]})
    unseen = sorted({c for r in TARGETS_BY_ROOM.values() for c in r["unseen"]})
    doc = {
        "categories": cats,
        "dim": 45,
        "source": ATTR_SOURCE,
        "split": {"by_room": TARGETS_BY_ROOM, "note": SPLIT_NOTE, "seen": seen,
                  "train_targets_by_room": TRAIN_TARGETS_BY_ROOM, "unseen": unseen},
    }
    p = os.path.join(out, "attributes.json")
    _write_json(p, doc, indent=1, sort_keys=True)
    return p, cats


# ---------------------------------------------------------------------------------------------
# scenes/ (ALFRED's layouts)


def read_npy(path):
    """A 2-D array of a NumPy `.npy` file (format 1.0-3.0, C order, little-endian float or
    integer) as a list of rows."""
    try:
        with open(path, "rb") as f:
            buf = f.read()
    except FileNotFoundError:
        raise ImportError_(f"missing file {path}") from None
    if buf[:6] != b"\x93NUMPY" or len(buf) < 10:
        raise ImportError_(f"{path}: not a .npy file")
    major = buf[6]
    if major == 1:
        (hlen,), start = struct.unpack_from("<H", buf, 8), 10
    else:
        (hlen,), start = struct.unpack_from("<I", buf, 8), 12
    try:
        head = ast.literal_eval(buf[start:start + hlen].decode("latin1"))
        descr, order, shape = head["descr"], head["fortran_order"], tuple(head["shape"])
    except (ValueError, SyntaxError, KeyError, TypeError) as e:
        raise ImportError_(f"{path}: bad .npy header ({e})") from None
    fmts = {"<f8": "d", "<f4": "f", "<i8": "q", "<i4": "i"}
    if descr not in fmts or order or len(shape) != 2:
        raise ImportError_(f"{path}: expected a 2-D C-order array of {sorted(fmts)}, got "
                           f"{descr} shape {shape} fortran_order {order}")
    n = shape[0] * shape[1]
    data = buf[start + hlen:]
    if len(data) < n * struct.calcsize(fmts[descr]):
        raise ImportError_(f"{path}: {len(data)} data bytes for shape {shape}")
    vals = [float(v) for v in struct.unpack_from(f"<{n}{fmts[descr]}", data)]
    return [vals[r * shape[1]:(r + 1) * shape[1]] for r in range(shape[0])]


def _read_json(path):
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError:
        raise ImportError_(f"missing file {path}") from None
    except json.JSONDecodeError as e:
        raise ImportError_(f"{path}: bad JSON ({e})") from None


_ID = re.compile(r"^([A-Za-z]+)\|([+-]?\d+\.\d+)\|([+-]?\d+\.\d+)\|([+-]?\d+\.\d+)")


def object_from_id(oid, where):
    """An AI2-THOR 2.x id `Type|+x.xx|+y.yy|+z.zz[|...]` -> {id, type, x, y, z}."""
    m = _ID.match(oid)
    if not m:
        raise ImportError_(f"{where}: object id {oid!r} is not Type|x|y|z")
    return {"id": oid, "type": m.group(1), "x": float(m.group(2)), "y": float(m.group(3)),
            "z": float(m.group(4))}


def scene_ids():
    """(split, FloorPlan number) of every train and val scene (no test scene)."""
    out = []
    for base in (0, 200, 300, 400):
        out += [("train", base + i) for i in TRAIN_IDS]
        out += [("val", base + i) for i in VAL_IDS]
    return out


def scene(alfred, split, num, cats, eps):
    """The scene file of FloorPlan`num` as a dict."""
    name = f"FloorPlan{num}"
    lay = os.path.join(alfred, "gen", "layouts", name)
    rows = read_npy(lay + "-layout.npy")
    if any(len(r) != 2 for r in rows):
        raise ImportError_(f"{lay}-layout.npy: expected rows of [x, z]")
    types = _read_json(lay + "-objects.json")
    openable = _read_json(lay + "-openable.json")
    if not isinstance(types, list) or not isinstance(openable, dict):
        raise ImportError_(f"{lay}-objects.json / -openable.json: expected a list / an object")
    known = [object_from_id(i, lay + "-openable.json") for i in sorted(openable)]
    doc = {
        "grid_size": GRID_SIZE,
        "known_objects": [o for o in known if o["type"] in cats],
        "layout_source": LAYOUT_SOURCE,
        "object_types": sorted(set(types) & set(cats)),
        "reachable": sorted(rows),
        "room": ROOM_BASE[num // 100],
        "scene": name,
    }
    if split == "val":
        mine = [e for lines in eps.values() for e in lines if e["scene"] == name]
        goals = {i for e in mine for i in e["target_ids"]}
        doc["objects"] = [object_from_id(i, f"val episodes of {name}") for i in sorted(goals)]
        doc["reachable_sample"] = sorted({(e["start"]["x"], e["start"]["z"]) for e in mine})
        doc["reachable_sample"] = [list(p) for p in doc["reachable_sample"]]
    return doc


def scenes(alfred, cats, eps, out):
    written = []
    for split, num in scene_ids():
        d = os.path.join(out, "scenes", split)
        os.makedirs(d, exist_ok=True)
        p = os.path.join(d, f"FloorPlan{num}.json")
        _write_json(p, scene(alfred, split, num, cats, eps), indent=1, sort_keys=True)
        written.append(p)
    return written


# ---------------------------------------------------------------------------------------------
# objects_thor5/ (rl_ai2thor's AI2-THOR 5.0 metadata)


def thor5_objects(src):
    """rl_ai2thor's `{objectId: metadata}` -> our object list (4 decimals, id order)."""
    meta = _read_json(src)
    if isinstance(meta, list):  # a plain `metadata["objects"]` list
        meta = {o.get("objectId"): o for o in meta if isinstance(o, dict)}
    if not isinstance(meta, dict):
        raise ImportError_(f"{src}: expected an object of objectId -> metadata")
    out = []
    for oid, o in meta.items():
        try:
            pos, box = o["position"], o["axisAlignedBoundingBox"]
            parents = o.get("parentReceptacles") or []
            out.append({
                "type": o["objectType"], "id": o["objectId"],
                "x": round(pos["x"], 4), "y": round(pos["y"], 4), "z": round(pos["z"], 4),
                "aabb_center": [round(box["center"][k], 4) for k in "xyz"],
                "aabb_size": [round(box["size"][k], 4) for k in "xyz"],
                "parent": parents[0] if parents else None,
            })
        except (KeyError, TypeError) as e:
            raise ImportError_(f"{src}: object {oid} without field {e}") from None
    return sorted(out, key=lambda o: o["id"])


def objects_thor5(rl, out):
    written = []
    d = os.path.join(out, "objects_thor5")
    os.makedirs(d, exist_ok=True)
    for _, num in scene_ids():
        src = os.path.join(rl, "dev", "data", "objects_metadata_samples",
                           f"FloorPlan{num}_physics.json")
        doc = {"scene": f"FloorPlan{num}", "source": THOR5_SOURCE, "objects": thor5_objects(src)}
        p = os.path.join(d, f"FloorPlan{num}.json")
        _write_json(p, doc, indent=0, separators=(",", ":"))
        written.append(p)
    return written


def _write_json(path, doc, **kw):
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        f.write(json.dumps(doc, **kw))


# ---------------------------------------------------------------------------------------------
# Checksums


def sha256(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def read_sums(path):
    sums = {}
    try:
        f = open(path, encoding="utf-8")
    except FileNotFoundError:
        raise ImportError_(f"missing checksum file {path}") from None
    with f:
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


# ---------------------------------------------------------------------------------------------
# Command line


def build(gman, alfred, rl, out):
    """Writes the whole directory; returns the paths written."""
    eps = read_episodes(gman)
    written = write_episodes(eps, out)
    p, cats = attributes(gman, eps, out)
    written.append(p)
    written += scenes(alfred, cats, eps, out)
    written += objects_thor5(rl, out)
    shutil.copyfile(DATA_README, os.path.join(out, "README.md"))
    written.append(os.path.join(out, "README.md"))
    return written


def _need_dir(flag, path, sub):
    if not os.path.isdir(os.path.join(path, sub)):
        raise ImportError_(f"{flag} {path}: no {sub}/ folder (a clone of the right repository?)")


def _refuse_existing(out):
    if os.path.exists(out) and os.listdir(out):
        raise ImportError_(f"--out {out}: exists and is not empty (the import writes a new "
                           "directory; remove it or choose another path)")


def _parser():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    b = sub.add_parser("build", help="the whole data directory, then the checksum check")
    b.add_argument("--gman", required=True, help="clone of github.com/sx-zhang/GMAN")
    b.add_argument("--alfred", required=True, help="clone of github.com/askforalfred/alfred")
    b.add_argument("--rl-ai2thor", required=True, help="clone of github.com/Kajiih/rl_ai2thor")
    b.add_argument("--out", required=True, help="new data directory (must not exist or be empty)")
    b.add_argument("--sums", default=SUMS, help="checksum file (default: data/SHA256SUMS)")
    e = sub.add_parser("episodes", help="official val episodes from a GMAN clone")
    e.add_argument("--gman", required=True, help="clone of github.com/sx-zhang/GMAN")
    e.add_argument("--out", required=True, help="data directory to write into")
    c = sub.add_parser("check", help="compare a data directory with data/SHA256SUMS")
    c.add_argument("data")
    c.add_argument("--sums", default=SUMS, help="checksum file (default: data/SHA256SUMS)")
    c.add_argument("--only", action="append", metavar="PREFIX",
                   help="check only files under PREFIX, e.g. episodes/val (repeatable)")
    s = sub.add_parser("sums", help="write the checksum file of a data directory")
    s.add_argument("data")
    s.add_argument("--out", default=SUMS)
    return ap


def _report(data, sums, only=None):
    ok, problems, n = check(data, sums, only)
    for p in problems:
        print(p, file=sys.stderr)
    if not ok:
        print(f"{data}: {len(problems)} file(s) differ from {sums}", file=sys.stderr)
        return 1
    print(f"ok: {n} files of {data} match {sums}")
    return 0


def main(argv=None):
    a = _parser().parse_args(argv)
    try:
        if a.cmd == "build":
            _need_dir("--gman", a.gman, "test_val_split")
            _need_dir("--alfred", a.alfred, os.path.join("gen", "layouts"))
            _need_dir("--rl-ai2thor", a.rl_ai2thor,
                      os.path.join("dev", "data", "objects_metadata_samples"))
            _refuse_existing(a.out)
            n = len(build(a.gman, a.alfred, a.rl_ai2thor, a.out))
            print(f"wrote {n} files into {a.out}")
            return _report(a.out, a.sums)
        if a.cmd == "episodes":
            _need_dir("--gman", a.gman, "test_val_split")
            for p in episodes(a.gman, a.out):
                print(f"wrote {p}")
        elif a.cmd == "check":
            return _report(a.data, a.sums, a.only)
        else:
            print(f"wrote {a.out}: {write_sums(a.data, a.out)} files")
    except (ImportError_, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
