#!/usr/bin/env python3
"""Lists every `unsafe` block of the given Rust sources that no `// SAFETY:` comment explains.

    scripts/safety_comments.py DIR...     e.g. scripts/safety_comments.py dsp/src ffi/src host-sim/src

An `unsafe {` block (or `unsafe impl`) is explained when a `SAFETY` comment stands on its own
line or on one of the 8 lines above it (a comment may cover a short run of blocks that share
one reason). `unsafe fn` declarations are left out: their contract is a `# Safety` section of
their docs, and each call is a block. Exits 1 when any block is unexplained, else 0.
"""
import os
import re
import sys

BLOCK = re.compile(r"\bunsafe\s*(\{|impl\b)")
WINDOW = 8


def unexplained(path):
    out = []
    with open(path, encoding="utf-8") as f:
        lines = f.read().split("\n")
    for i, line in enumerate(lines):
        code = line.split("//", 1)[0]
        if not BLOCK.search(code):
            continue
        context = lines[max(0, i - WINDOW): i + 1]
        if not any("SAFETY" in c for c in context):
            out.append((i + 1, line.strip()))
    return out


def main(argv):
    if not argv:
        sys.exit("usage: safety_comments.py DIR...")
    bad = []
    for d in argv:
        for root, _, files in os.walk(d):
            for name in sorted(files):
                if name.endswith(".rs"):
                    p = os.path.join(root, name)
                    bad += [(p, n, s) for n, s in unexplained(p)]
    for p, n, s in bad:
        print(f"{p}:{n}: unsafe without a SAFETY comment: {s}")
    if bad:
        sys.exit(1)
    print(f"ok: every unsafe block under {' '.join(argv)} says why it is sound")


if __name__ == "__main__":
    main(sys.argv[1:])
