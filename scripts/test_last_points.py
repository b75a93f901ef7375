"""Unit tests of host-sim/scripts/last_points.py (the mean of a run's last curve points)."""

import importlib.util
import json
import tempfile
import unittest
from pathlib import Path

_PATH = Path(__file__).resolve().parent.parent / "host-sim" / "scripts" / "last_points.py"
_SPEC = importlib.util.spec_from_file_location("last_points", _PATH)
last_points = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(last_points)


def _eval(sr_unseen, sr_seen):
    row = lambda sr: {"episodes": 4000, "sr": sr, "spl": sr / 4, "epa": 1.0, "dts": 0.5}
    return {"split": "val", "results": {"unseen": row(sr_unseen), "seen": row(sr_seen)}}


class LastPoints(unittest.TestCase):
    def _sweep(self, d: Path):
        run = d / "runs" / "gman-s2"
        (run / "curve").mkdir(parents=True)
        # k10000000 sorts before k2000000 as text: the order must be numeric
        for k, (u, s) in {1000000: (1, 1), 2000000: (2, 2), 3000000: (10, 20),
                          8770000: (12, 22), 10000000: (14, 30)}.items():
            (run / "curve" / f"k{k}.json").write_text(json.dumps(_eval(u, s)))
        (d / "gman").mkdir()
        (d / "gman" / "s2.json").write_text(json.dumps(_eval(14, 30)))
        # an unfinished run is skipped
        (d / "runs" / "a3c-s1" / "curve").mkdir(parents=True)
        (d / "runs" / "a3c-s1" / "curve" / "k1000000.json").write_text(json.dumps(_eval(5, 5)))

    def test_mean_of_the_last_points_in_step_order(self):
        with tempfile.TemporaryDirectory() as t:
            d = Path(t)
            self._sweep(d)
            self.assertEqual(last_points.main(["x", str(d), "3"]), 0)
            got = json.loads((d / "gman-last3" / "s2.json").read_text())
            self.assertAlmostEqual(got["results"]["unseen"]["sr"], 12.0)
            self.assertAlmostEqual(got["results"]["seen"]["sr"], 24.0)
            self.assertAlmostEqual(got["results"]["seen"]["spl"], 6.0)
            self.assertEqual(got["split"], "val")
            self.assertFalse((d / "a3c-last3").exists())

    def test_too_few_points_skips_the_run(self):
        with tempfile.TemporaryDirectory() as t:
            d = Path(t)
            self._sweep(d)
            self.assertEqual(last_points.main(["x", str(d), "6"]), 0)
            self.assertFalse((d / "gman-last6").exists())

    def test_a_broken_file_names_itself(self):
        with tempfile.TemporaryDirectory() as t:
            d = Path(t)
            self._sweep(d)
            bad = d / "runs" / "gman-s2" / "curve" / "k8770000.json"
            bad.write_text("{")
            with self.assertRaises(SystemExit) as e:
                last_points.main(["x", str(d)])
            self.assertIn("k8770000.json", str(e.exception))


if __name__ == "__main__":
    unittest.main()
