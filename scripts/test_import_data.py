"""Unit tests of scripts/import_data.py on small fixtures the tests write (stdlib unittest),
and, when the project's data directory is beside the checkout, a rebuild of it from sources
made out of it, compared with data/SHA256SUMS.

Run: python3 -m unittest discover -s scripts -p 'test_*.py'
"""

import hashlib
import json
import os
import pickle
import shutil
import struct
import sys
import tempfile
import unittest
import zlib

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import import_data  # noqa: E402

SHARED = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "data",
                      "gman")


class ThorAgentState:
    """Pickled like GMAN's class of the same name (module __main__)."""

    def __init__(self, x, y, z, rotation, horizon):
        self.x, self.y, self.z, self.rotation, self.horizon = x, y, z, rotation, horizon


ThorAgentState.__module__ = "__main__"


def _fake_main():
    # pickle looks the class up by module and name while dumping.
    sys.modules["__main__"].ThorAgentState = ThorAgentState


def write_gman_fixture(root, n=3):
    _fake_main()
    d = os.path.join(root, "test_val_split")
    os.makedirs(d)
    for room in import_data.ROOMS:
        for kind in import_data.KINDS:
            target = import_data.TARGETS_BY_ROOM[room][kind][0]
            eps = [
                {
                    "scene": f"FloorPlan{22 + 2 * i}",
                    "goal_object_type": target,
                    "task_data": f"{target}|+00.58|+00.39|+02.36" if i % 2 == 0
                    else [f"{target}|+01.00|+00.90|-00.25", f"{target}|+01.50|+00.90|-00.25"],
                    "state": ThorAgentState(0.25 * i, 0.900999248, -1.5, 45 * i, 0),
                }
                for i in range(n)
            ]
            with open(os.path.join(d, f"{room}_val_{kind}.pkl"), "wb") as f:
                pickle.dump(eps, f, protocol=3)


def _text(path):
    with open(path, encoding="utf-8") as f:
        return f.read()


def _json(path):
    return json.loads(_text(path))


def _mat_elem(typ, payload):
    pad = (-len(payload)) % 8
    return struct.pack("<II", typ, len(payload)) + payload + b"\0" * pad


def write_mat(path, variables, compress=()):
    """A MAT-file version 5 of 1 x N double rows, as MATLAB's `save` writes them (the names in
    `compress` as miCOMPRESSED elements)."""
    out = bytearray(b"MATLAB 5.0 MAT-file, fixture".ljust(116, b" ") + b"\0" * 8)
    out += struct.pack("<H", 0x0100) + b"IM"
    for name, vals in variables.items():
        body = (_mat_elem(6, struct.pack("<II", 6, 0))
                + _mat_elem(5, struct.pack("<ii", 1, len(vals)))
                + _mat_elem(1, name.encode())
                + _mat_elem(9, struct.pack(f"<{len(vals)}d", *vals)))
        elem = _mat_elem(14, body)
        out += _mat_elem(15, zlib.compress(elem)) if name in compress else elem
    with open(path, "wb") as f:
        f.write(bytes(out))


def write_npy(path, rows):
    """A NumPy 1.0 `.npy` of an N x 2 float64 array (what `np.save` writes)."""
    head = "{'descr': '<f8', 'fortran_order': False, 'shape': (%d, 2), }" % len(rows)
    head = head.ljust(118 - 1) + "\n"
    data = struct.pack(f"<{2 * len(rows)}d", *[v for r in rows for v in r])
    with open(path, "wb") as f:
        f.write(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(head)) + head.encode() + data)


def thor5_meta(objects):
    """rl_ai2thor's `{objectId: metadata}` for our object records (full precision fields)."""
    return {
        o["id"]: {
            "objectType": o["type"], "objectId": o["id"], "name": o["type"] + "_1",
            "position": {"x": o["x"], "y": o["y"], "z": o["z"]},
            "axisAlignedBoundingBox": {
                "center": dict(zip("xyz", o["aabb_center"])),
                "size": dict(zip("xyz", o["aabb_size"])),
                "cornerPoints": [],
            },
            "parentReceptacles": None if o["parent"] is None else [o["parent"]],
        }
        for o in objects
    }


def write_sources(root, attrs, scenes, thor5, episodes=None):
    """GMAN, ALFRED and rl_ai2thor trees: `attrs` {name: 45 floats}, `scenes` {num: scene dict},
    `thor5` {num: object records}; returns the three roots."""
    gman, alfred, rl = (os.path.join(root, n) for n in ("GMAN", "alfred", "rl_ai2thor"))
    if episodes is None:
        write_gman_fixture(gman)
    else:
        _fake_main()
        os.makedirs(os.path.join(gman, "test_val_split"))
        for (room, kind), eps in episodes.items():
            with open(os.path.join(gman, "test_val_split", f"{room}_val_{kind}.pkl"), "wb") as f:
                pickle.dump(eps, f, protocol=3)
    os.makedirs(os.path.join(gman, "data", "attributes"))
    write_mat(os.path.join(gman, "data", "attributes", "40_attribute.mat"), attrs,
              compress=list(attrs)[:2])
    lay = os.path.join(alfred, "gen", "layouts")
    os.makedirs(lay)
    for num, s in scenes.items():
        write_npy(os.path.join(lay, f"FloorPlan{num}-layout.npy"), s["reachable"][::-1])
        with open(os.path.join(lay, f"FloorPlan{num}-objects.json"), "w") as f:
            json.dump(s["object_types"] + ["CounterTop", "Window"], f, indent=4)
        openable = {o["id"]: [0.0, 0.0, 90, 30] for o in s["known_objects"]}
        openable["CounterTop|+00.69|+00.95|-02.48"] = [0.5, -1.75, 180, 30]
        with open(os.path.join(lay, f"FloorPlan{num}-openable.json"), "w") as f:
            json.dump(openable, f, indent=4)
    meta = os.path.join(rl, "dev", "data", "objects_metadata_samples")
    os.makedirs(meta)
    for num, objs in thor5.items():
        with open(os.path.join(meta, f"FloorPlan{num}_physics.json"), "w") as f:
            json.dump(thor5_meta(objs), f, indent=4)
    return gman, alfred, rl


def small_sources(root):
    """Sources for every train and val scene with a few objects each."""
    names = sorted({c for r in import_data.TARGETS_BY_ROOM.values() for k in r.values() for c in k})
    extra = ["BathtubBasin", "Cabinet", "Painting", "SinkBasin", "TowelHolder", "Box", "Chair"]
    names = sorted(set(names) | set(extra))
    names += [f"Unused{i}" for i in range(40 - len(names))]
    attrs = {n: [((i * 7 + j) % 30) / 30.0 for j in range(45)] for i, n in enumerate(names)}
    scenes, thor5 = {}, {}
    for _, num in import_data.scene_ids():
        scenes[num] = {
            "reachable": [[0.25 * i, -0.5] for i in range(4)] + [[-1.0, 1.25]],
            "object_types": ["Cabinet", "Fridge"],
            "known_objects": [{"id": "Cabinet|+00.68|+00.50|-02.20"},
                              {"id": "Fridge|-02.10|+00.00|+01.07"}],
        }
        thor5[num] = [{"type": "Fridge", "id": "Fridge|-02.10|+00.00|+01.07", "x": -2.1000004,
                       "y": 0.0, "z": 1.07, "aabb_center": [-2.1, 0.9, 1.070000123],
                       "aabb_size": [0.7, 1.8, 0.7], "parent": None},
                      {"type": "Apple", "id": "Apple|-00.47|+01.15|+00.48", "x": -0.46515396,
                       "y": 1.15122521, "z": 0.47574010, "aabb_center": [-0.4652, 1.1567, 0.4757],
                       "aabb_size": [0.106, 0.1135, 0.106],
                       "parent": "CounterTop|-00.08|+01.15|00.00"}]
    return write_sources(root, attrs, scenes, thor5)


class BuildTest(unittest.TestCase):
    def test_builds_every_part_of_the_directory_from_the_sources(self):
        with tempfile.TemporaryDirectory() as t:
            gman, alfred, rl = small_sources(t)
            out = os.path.join(t, "data")
            written = import_data.build(gman, alfred, rl, out)
            # 8 episode files, attributes.json, 80 + 20 scenes, 100 objects_thor5 files, README.
            self.assertEqual(len(written), 8 + 1 + 100 + 100 + 1)
            rels = sorted(os.path.relpath(p, out) for p in written)
            self.assertFalse([r for r in rels if "test" in r.split(os.sep)[0:2]], rels)
            test_scenes = [f"FloorPlan{b + n}." for b in (0, 200, 300, 400)
                           for n in import_data.TEST_IDS]
            self.assertFalse([r for r in rels if any(s in r for s in test_scenes)])
            a = _json(os.path.join(out, "attributes.json"))
            self.assertEqual(a["dim"], 45)
            self.assertEqual(len(a["categories"]), 40)
            self.assertEqual(a["categories"]["AlarmClock"][1], round(1 / 30.0, 8))
            self.assertIn("Shelf", a["split"]["by_room"]["living_room"]["seen"])
            self.assertEqual(len(a["split"]["unseen"]), 12)
            tr = _json(os.path.join(out, "scenes", "train", "FloorPlan201.json"))
            self.assertEqual(tr["room"], "living_room")
            self.assertEqual(tr["reachable"][0], [-1.0, 1.25])  # sorted
            # CounterTop and Window are not among the 40 categories.
            self.assertEqual(tr["object_types"], ["Cabinet", "Fridge"])
            self.assertEqual([o["id"] for o in tr["known_objects"]],
                             ["Cabinet|+00.68|+00.50|-02.20", "Fridge|-02.10|+00.00|+01.07"])
            self.assertEqual(tr["known_objects"][0]["z"], -2.2)
            self.assertNotIn("objects", tr)
            va = _json(os.path.join(out, "scenes", "val", "FloorPlan22.json"))
            self.assertEqual(va["reachable_sample"], [[0.0, -1.5]])
            self.assertEqual(va["objects"][0]["type"], "AlarmClock")
            o5 = _json(os.path.join(out, "objects_thor5", "FloorPlan1.json"))
            self.assertEqual([o["id"] for o in o5["objects"]],
                             ["Apple|-00.47|+01.15|+00.48", "Fridge|-02.10|+00.00|+01.07"])
            self.assertEqual(o5["objects"][0]["x"], -0.4652)
            self.assertEqual(o5["objects"][1]["aabb_center"], [-2.1, 0.9, 1.07])
            self.assertEqual(o5["objects"][0]["parent"], "CounterTop|-00.08|+01.15|00.00")
            self.assertTrue(_text(os.path.join(out, "objects_thor5", "FloorPlan1.json"))
                            .startswith('{\n"scene":"FloorPlan1",\n"source":'))
            self.assertEqual(import_data.sha256(os.path.join(out, "README.md")),
                             import_data.sha256(import_data.DATA_README))

    def test_command_refuses_a_non_empty_out_and_names_a_missing_clone(self):
        with tempfile.TemporaryDirectory() as t:
            gman, alfred, rl = small_sources(t)
            args = ["build", "--gman", gman, "--alfred", alfred, "--rl-ai2thor", rl]
            self.assertEqual(import_data.main(args + ["--out", gman]), 2)
            self.assertEqual(import_data.main(["build", "--gman", gman, "--alfred", t,
                                               "--rl-ai2thor", rl, "--out", t + "/x"]), 2)
            # A fixture's files are not the published ones: the build writes, then check says so.
            self.assertEqual(import_data.main(args + ["--out", os.path.join(t, "new")]), 1)

    def test_a_target_outside_the_official_split_is_an_error(self):
        with tempfile.TemporaryDirectory() as t:
            gman, alfred, rl = small_sources(t)
            eps = import_data.read_episodes(gman)
            eps[("kitchen", "seen")][1]["target"] = "Plate"  # an unseen kitchen target
            with self.assertRaises(import_data.ImportError_) as e:
                import_data.attributes(gman, eps, t)
            self.assertIn("kitchen_val_seen.pkl episode 1", str(e.exception))

    def test_bad_mat_and_npy_files_are_named(self):
        with tempfile.TemporaryDirectory() as t:
            p = os.path.join(t, "x.mat")
            write_mat(p, {"Bowl": [0.5] * 44})
            self.assertEqual(import_data.read_mat(p)["Bowl"][0], [1, 44])
            with open(p, "r+b") as f:
                f.truncate(200)
            with self.assertRaises(import_data.ImportError_) as e:
                import_data.read_mat(p)
            self.assertIn("x.mat", str(e.exception))
            q = os.path.join(t, "x.npy")
            with open(q, "wb") as f:
                f.write(b"not numpy")
            with self.assertRaises(import_data.ImportError_) as e:
                import_data.read_npy(q)
            self.assertIn("x.npy", str(e.exception))


def sources_from_data(data, root):
    """The public sources' files, written back from a data directory: what the importer reads,
    in the sources' formats (GMAN pickles and MAT file, ALFRED layouts, rl_ai2thor metadata)."""
    _fake_main()
    attrs = _json(os.path.join(data, "attributes.json"))["categories"]
    scenes, thor5 = {}, {}
    for split, num in import_data.scene_ids():
        scenes[num] = _json(os.path.join(data, "scenes", split, f"FloorPlan{num}.json"))
        thor5[num] = _json(os.path.join(data, "objects_thor5", f"FloorPlan{num}.json"))["objects"]
    episodes = {}
    for room in import_data.ROOMS:
        for kind in import_data.KINDS:
            path = os.path.join(data, "episodes", "val", f"{room}_{kind}.jsonl")
            lines = _text(path).splitlines()
            episodes[(room, kind)] = [
                {"scene": e["scene"], "goal_object_type": e["target"],
                 "task_data": e["target_ids"][0] if len(e["target_ids"]) == 1 else e["target_ids"],
                 "state": ThorAgentState(**e["start"])}
                for e in map(json.loads, lines)
            ]
    return write_sources(root, attrs, scenes, thor5, episodes)


@unittest.skipUnless(os.path.isdir(SHARED), f"no data directory at {SHARED}")
class RebuildSharedTest(unittest.TestCase):
    def test_rebuilds_the_published_files_byte_for_byte(self):
        with tempfile.TemporaryDirectory() as t:
            gman, alfred, rl = sources_from_data(SHARED, t)
            out = os.path.join(t, "data")
            import_data.build(gman, alfred, rl, out)
            ok, problems, n = import_data.check(out)
            self.assertEqual(problems, [])
            self.assertEqual(n, 210)


class EpisodesTest(unittest.TestCase):
    def test_converts_every_file_with_sorted_keys(self):
        with tempfile.TemporaryDirectory() as t:
            write_gman_fixture(os.path.join(t, "gman"))
            out = os.path.join(t, "data")
            written = import_data.episodes(os.path.join(t, "gman"), out)
            self.assertEqual(len(written), 8)
            p = os.path.join(out, "episodes", "val", "kitchen_unseen.jsonl")
            lines = _text(p).splitlines()
            self.assertEqual(len(lines), 3)
            first = json.loads(lines[0])
            self.assertEqual(first["target_ids"], ["CoffeeMachine|+00.58|+00.39|+02.36"])
            self.assertEqual(first["target_kind"], "unseen")
            self.assertEqual(first["room"], "kitchen")
            self.assertEqual(first["split"], "val")
            self.assertEqual(json.loads(lines[1])["target_ids"][1],
                             "CoffeeMachine|+01.50|+00.90|-00.25")
            # The byte layout of the published files: sorted keys, ", " and ": ".
            self.assertTrue(lines[1].startswith(
                '{"room": "kitchen", "scene": "FloorPlan24", "split": "val", '
                '"start": {"horizon": 0, "rotation": 45, "x": 0.25, "y": 0.900999248, '
                '"z": -1.5}, "target": "CoffeeMachine"'), lines[1])

    def test_refuses_foreign_classes_and_names_the_file(self):
        with tempfile.TemporaryDirectory() as t:
            p = os.path.join(t, "evil.pkl")
            with open(p, "wb") as f:
                pickle.dump([os.getcwd], f)  # a global other than ThorAgentState
            with self.assertRaises(import_data.ImportError_) as e:
                import_data.load_pickle(p)
            self.assertIn("evil.pkl", str(e.exception))
            with self.assertRaises(import_data.ImportError_) as e:
                import_data.load_pickle(os.path.join(t, "missing.pkl"))
            self.assertIn("missing file", str(e.exception))

    def test_missing_field_is_named(self):
        with self.assertRaises(import_data.ImportError_) as e:
            import_data.convert_episode({"scene": "FloorPlan22"}, "kitchen", "val", "seen", "f.pkl")
        self.assertIn("f.pkl", str(e.exception))


class ChecksumTest(unittest.TestCase):
    def test_sums_then_check_detects_changed_and_missing_files(self):
        with tempfile.TemporaryDirectory() as t:
            data = os.path.join(t, "data")
            os.makedirs(os.path.join(data, "episodes", "val"))
            with open(os.path.join(data, "attributes.json"), "w") as f:
                f.write("{}\n")
            with open(os.path.join(data, "episodes", "val", "a.jsonl"), "w") as f:
                f.write('{"x": 1}\n')
            sums = os.path.join(t, "SHA256SUMS")
            self.assertEqual(import_data.write_sums(data, sums), 2)
            want = hashlib.sha256(b"{}\n").hexdigest()
            self.assertIn(f"{want}  attributes.json\n", _text(sums))
            self.assertEqual(import_data.check(data, sums), (True, [], 2))
            with open(os.path.join(data, "episodes", "val", "a.jsonl"), "a") as f:
                f.write("\n")
            ok, problems, _ = import_data.check(data, sums)
            self.assertFalse(ok)
            self.assertTrue(problems[0].startswith("differs episodes/val/a.jsonl"), problems)
            os.remove(os.path.join(data, "attributes.json"))
            ok, problems, _ = import_data.check(data, sums, only=["attributes.json"])
            self.assertEqual(problems, ["missing attributes.json"])
            # --only limits the check to a prefix.
            ok, problems, n = import_data.check(data, sums, only=["episodes/val"])
            self.assertEqual(n, 1)
            self.assertEqual(import_data.main(["check", data, "--sums", sums]), 1)


if __name__ == "__main__":
    unittest.main()
