"""Unit tests of scripts/gen_docs.py (generated tables and quoted figures) on a small tree the
tests write: the check passes on current parts, fails naming the file and line when a figure
differs from its result files, and `write` regenerates the parts."""

import json
import os
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import gen_docs  # noqa: E402


def _result(sr_unseen, sr_seen):
    row = lambda sr: {"episodes": 4000, "sr": sr, "spl": sr / 4, "epa": 5.0, "dts": 1.0}
    return {"split": "val", "results": {"unseen": row(sr_unseen), "seen": row(sr_seen)}}


def _tree(t):
    runs = {"gman": [(18.0, 24.0), (20.0, 26.0), (16.0, 22.0)], "a3c": [(12.0, 13.0), (10.0, 11.0),
                                                                        (11.0, 15.0)],
            "random": [(10.375, 9.375)]}
    for row, seeds in runs.items():
        d = os.path.join(t, "results", "paper", row)
        os.makedirs(d)
        for i, (u, s) in enumerate(seeds, 1):
            with open(os.path.join(d, f"s{i}.json"), "w") as f:
                json.dump(_result(u, s), f)
    os.makedirs(os.path.join(t, "results", "paper", "models"))
    with open(os.path.join(t, "results", "paper", "models", "gman-s2.gman"), "wb") as f:
        f.write(b"\0" * 1234)
    os.makedirs(os.path.join(t, "host-sim", "scripts"))
    with open(os.path.join(t, "host-sim", "scripts", "paper-tables.sh"), "w") as f:
        f.write('main_rows() {\n  run gman gman "$1" --inner-lr 0.01\n  run a3c a3c "$1"\n}\n')


def _doc(t, body):
    p = os.path.join(t, "README.md")
    with open(p, "w") as f:
        f.write(body)
    return p


def _read(p):
    with open(p, encoding="utf-8") as f:
        return f.read()


class Stats(unittest.TestCase):
    def test_mean_std_and_t_match_hand_computations(self):
        m, s = gen_docs.mean_std([16.0, 18.0, 20.0])
        self.assertEqual((m, s), (18.0, 2.0))
        # Welch: (18 - 11) / sqrt(4/3 + 1/3)
        self.assertAlmostEqual(gen_docs.welch_t([16.0, 18.0, 20.0], [10.0, 11.0, 12.0]),
                               7.0 / (5.0 / 3.0) ** 0.5)
        # paired: differences 6, 7, 8 -> mean 7, std 1 -> 7 / (1 / sqrt 3)
        self.assertAlmostEqual(gen_docs.paired_t([16.0, 18.0, 20.0], [10.0, 11.0, 12.0]),
                               7.0 * 3 ** 0.5)
        self.assertEqual(gen_docs.t_cell(gen_docs.welch_t([1.0], [2.0, 3.0])), "-")


class Check(unittest.TestCase):
    def test_current_parts_pass_and_a_changed_figure_fails_naming_file_and_line(self):
        with tempfile.TemporaryDirectory() as t:
            _tree(t)
            body = ("# x\n\n<!-- gen:table results/paper/gman results/paper/a3c "
                    "results/paper/random -->\n<!-- /gen -->\n\nGMAN: "
                    "<!-- fig:results/paper/gman:unseen:sr -->?<!-- /fig -->.\n")
            p = _doc(t, body)
            self.assertEqual(gen_docs.run(t, write=False, files=[p]) != [], True)
            self.assertEqual(gen_docs.run(t, write=True, files=[p]), ["README.md"])
            text = _read(p)
            self.assertIn("| gman [val x3] | 18.00±2.00 | 4.50±0.50 | 5.00±0.00 | 1.00±0.00 | "
                          "24.00±2.00 |", text)
            self.assertIn("| random [val x1] | 10.38 | 2.59 |", text)
            self.assertIn("* a3c [val x3] unseen +7.00 (t 5.42, paired t 4.58) seen +11.00", text)
            self.assertIn("* random [val x1] unseen +7.62 (t -) seen +14.62 (t -)", text)
            self.assertIn("GMAN: <!-- fig:results/paper/gman:unseen:sr -->18.00 ± 2.00<!-- /fig -->",
                          text)
            self.assertEqual(gen_docs.run(t, write=False, files=[p]), [])
            g, a3c = "results/paper/gman", "results/paper/a3c"
            self.assertEqual(gen_docs.gen_fig(t, f"{g}:unseen:sr:diff={a3c}"), "+7.00")
            self.assertEqual(gen_docs.gen_fig(t, f"{g}:unseen:sr:welch={a3c}"), "5.42")
            self.assertEqual(gen_docs.gen_fig(t, f"{g}:unseen:sr:paired={a3c}"), "4.58")
            self.assertEqual(gen_docs.gen_fig(t, f"{g}:seen:spl:n"), "3")
            # A table cell edited by hand: named with the file, the line, the cell's line.
            _doc(t, text.replace("18.00±2.00", "18.10±2.00", 1))
            problems = gen_docs.run(t, write=False, files=[p])
            self.assertEqual(len(problems), 1)
            self.assertTrue(problems[0].startswith("README.md:3: gen:table"), problems)
            self.assertIn("18.10±2.00", problems[0])
            # A result file changed under a quoted figure.
            _doc(t, text)
            with open(os.path.join(t, "results", "paper", "gman", "s1.json"), "w") as f:
                json.dump(_result(21.0, 24.0), f)
            problems = gen_docs.run(t, write=False, files=[p])
            self.assertTrue(any("fig:results/paper/gman:unseen:sr says '18.00 ± 2.00'" in q
                                for q in problems), problems)
            self.assertEqual(gen_docs.main(["check", p, "--root", t]), 1)

    def test_every_readme_is_scanned(self):
        with tempfile.TemporaryDirectory() as t:
            for d in ["results/paper/models", "target/x", ".git/y", "docs"]:
                os.makedirs(os.path.join(t, d))
                _doc(t, "")
                with open(os.path.join(t, d, "README.md"), "w") as f:
                    f.write("")
            rel = [os.path.relpath(f, t) for f in gen_docs.doc_files(t)]
            self.assertEqual(rel, ["README.md", "docs/README.md",
                                   "results/paper/models/README.md"])

    def test_seeds_results_and_models_parts(self):
        with tempfile.TemporaryDirectory() as t:
            _tree(t)
            seeds = gen_docs.gen_seeds(t, "gman=GMAN | a3c | random").splitlines()
            self.assertEqual(seeds[2], "| GMAN | 18.00 / 24.00 | 20.00 / 26.00 | 16.00 / 22.00 | "
                                       "28.03 / 39.30 |")
            self.assertEqual(seeds[4], "| random | 10.38 / 9.38 |  |  |  |")
            res = gen_docs.gen_results(t, "random | gman=GMAN").splitlines()
            self.assertEqual(res[2], "| random |  |  | 10.38 / 2.59 | 9.38 / 2.34 |  |")
            self.assertEqual(res[3], "| GMAN | 28.03 / 13.02 | 39.30 / 15.61 | 18.00±2.00 / 4.50 | "
                                     "24.00±2.00 / 6.00 | 3 |")
            models = gen_docs.gen_models(t, "results/paper/models").splitlines()
            self.assertEqual(models[2], "| `gman-s2.gman` | `--method gman --inner-lr 0.01` | 1,234 "
                                        "| 20.00 / 5.00 | 26.00 / 6.50 |")

    def test_bad_markers_and_missing_results_are_errors_naming_the_place(self):
        with tempfile.TemporaryDirectory() as t:
            _tree(t)
            p = _doc(t, "a\n<!-- gen:table results/paper/nope -->\n<!-- /gen -->\n")
            with self.assertRaises(gen_docs.GenError) as e:
                gen_docs.run(t, write=False, files=[p])
            self.assertIn("README.md:2", str(e.exception))
            self.assertIn("results/paper/nope", str(e.exception))
            p = _doc(t, "<!-- gen:plot x -->\n<!-- /gen -->\n")
            with self.assertRaises(gen_docs.GenError) as e:
                gen_docs.run(t, write=False, files=[p])
            self.assertIn("unknown generated part gen:plot", str(e.exception))
            p = _doc(t, "<!-- fig:results/paper/gman:both:sr -->1<!-- /fig -->\n")
            self.assertEqual(gen_docs.main(["check", p, "--root", t]), 2)


if __name__ == "__main__":
    unittest.main()
