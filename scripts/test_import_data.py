"""Unit tests of scripts/import_data.py on small fixtures (stdlib unittest).

Run: python3 -m unittest discover -s scripts -p 'test_*.py'
"""

import hashlib
import json
import os
import pickle
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import import_data  # noqa: E402


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
    for split in import_data.SPLITS:
        for room in import_data.ROOMS:
            for kind in import_data.KINDS:
                eps = [
                    {
                        "scene": f"FloorPlan{22 + 2 * i}",
                        "goal_object_type": "Cabinet",
                        "task_data": "Cabinet|+00.58|+00.39|+02.36" if i % 2 == 0
                        else ["Mug|+01.00|+00.90|-00.25", "Mug|+01.50|+00.90|-00.25"],
                        "state": ThorAgentState(0.25 * i, 0.900999248, -1.5, 45 * i, 0),
                    }
                    for i in range(n)
                ]
                with open(os.path.join(d, f"{room}_{split}_{kind}.pkl"), "wb") as f:
                    pickle.dump(eps, f, protocol=3)


class EpisodesTest(unittest.TestCase):
    def test_converts_every_file_with_sorted_keys(self):
        with tempfile.TemporaryDirectory() as t:
            write_gman_fixture(os.path.join(t, "gman"))
            out = os.path.join(t, "data")
            written = import_data.episodes(os.path.join(t, "gman"), out)
            self.assertEqual(len(written), 16)
            p = os.path.join(out, "episodes", "val", "kitchen_unseen.jsonl")
            lines = open(p, encoding="utf-8").read().splitlines()
            self.assertEqual(len(lines), 3)
            first = json.loads(lines[0])
            self.assertEqual(first["target_ids"], ["Cabinet|+00.58|+00.39|+02.36"])
            self.assertEqual(first["target_kind"], "unseen")
            self.assertEqual(first["room"], "kitchen")
            self.assertEqual(first["split"], "val")
            self.assertEqual(json.loads(lines[1])["target_ids"][1], "Mug|+01.50|+00.90|-00.25")
            # The byte layout of the published files: sorted keys, ", " and ": ".
            self.assertTrue(lines[1].startswith(
                '{"room": "kitchen", "scene": "FloorPlan24", "split": "val", '
                '"start": {"horizon": 0, "rotation": 45, "x": 0.25, "y": 0.900999248, '
                '"z": -1.5}, "target": "Cabinet"'), lines[1])

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
            self.assertIn(f"{want}  attributes.json\n", open(sums).read())
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
