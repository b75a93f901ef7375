#!/usr/bin/env python3
"""Lists the import graph of a crate's top-level modules and the circles in it.

    scripts/module_cycles.py SRC_DIR        e.g. scripts/module_cycles.py core/src

Every `SRC_DIR/*.rs` file but `lib.rs` is a module. An edge `a -> b` is any `crate::b...`
path in `a.rs`'s code (a `use` line, a path inside an expression, each member of a
`use crate::{...}` group); a path to a name `lib.rs` re-exports (`crate::Dims`) counts as
an edge to the module the name comes from, a name `lib.rs` defines itself as an edge to
`lib`. `super::` inside a file's nested modules (its tests) names the file itself and is no
edge. Comments (doc links included), strings and character literals are skipped. Prints
each module's imports, then each circle found (a strongly connected component of more than
one module); exits 1 when there is one, else 0.
"""
import os
import re
import sys


def strip(src):
    """`src` with comments, strings and character literals blanked (newlines kept)."""
    out = []
    i, n = 0, len(src)
    while i < n:
        c = src[i]
        if src.startswith("//", i):
            j = src.find("\n", i)
            j = n if j < 0 else j
            i = j
            continue
        if src.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if src.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif src.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append(re.sub(r"[^\n]", " ", src[i:j]))
            i = j
            continue
        prev_word = i > 0 and (src[i - 1].isalnum() or src[i - 1] == "_")
        m = re.match(r'b?r(#*)"', src[i : i + 10]) if c in "rb" and not prev_word else None
        if m:
            close = '"' + m.group(1)
            j = src.find(close, i + m.end())
            j = n if j < 0 else j + len(close)
            out.append(re.sub(r"[^\n]", " ", src[i:j]))
            i = j
            continue
        if c == '"':
            j = i + 1
            while j < n and src[j] != '"':
                j += 2 if src[j] == "\\" else 1
            j += 1
            out.append(re.sub(r"[^\n]", " ", src[i:j]))
            i = j
            continue
        if c == "'":
            m = re.match(r"'(\\(x..|u\{[0-9a-fA-F]+\}|.)|[^\\'])'", src[i : i + 12])
            if m:
                out.append(" " * m.end())
                i += m.end()
                continue
        out.append(c)
        i += 1
    return "".join(out)


def group_heads(text):
    """The first path segment of each member of a `{...}` group (nested groups flattened)."""
    heads, depth, item = [], 0, ""
    for ch in text:
        if ch == "{":
            depth += 1
            if depth == 1:
                continue
        elif ch == "}":
            depth -= 1
            if depth == 0:
                break
        if ch == "," and depth == 1:
            heads.append(item)
            item = ""
        else:
            item += ch
    heads.append(item)
    out = []
    for h in heads:
        h = h.strip()
        m = re.match(r"(\w+)", h)
        if m:
            out.append(m.group(1))
    return out


def root_names(lib_src, modules):
    """Names at the crate root: re-exports -> their module, own items -> `lib`."""
    names = {}
    for m in re.finditer(r"pub use (\w+)::(\{[^}]*\}|\w+)\s*;", lib_src, re.S):
        mod, rest = m.group(1), m.group(2)
        items = group_heads(rest) if rest.startswith("{") else [rest]
        for it in items:
            names[it] = mod
    for m in re.finditer(r"pub (?:const|static|fn|struct|enum|type|trait) (\w+)", lib_src):
        names.setdefault(m.group(1), "lib")
    return names


def edges(path, modules, roots):
    code = strip(open(path, encoding="utf-8").read())
    out = {}
    for m in re.finditer(r"\bcrate::", code):
        rest = code[m.end() :]
        if rest.startswith("{"):
            heads = group_heads(rest)
        else:
            h = re.match(r"(\w+)", rest)
            heads = [h.group(1)] if h else []
        line = code.count("\n", 0, m.start()) + 1
        for h in heads:
            if h in modules:
                target = h
            elif h in roots:
                target = roots[h]
            else:
                target = "?" + h
            out.setdefault(target, []).append(line)
    return out


def circles(graph):
    """Strongly connected components with more than one node (Tarjan)."""
    index, low, stack, on, comps = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                comps.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return comps


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    src = sys.argv[1]
    files = sorted(f for f in os.listdir(src) if f.endswith(".rs"))
    modules = {f[:-3] for f in files if f != "lib.rs"}
    roots = root_names(open(os.path.join(src, "lib.rs"), encoding="utf-8").read(), modules)
    graph = {}
    for f in files:
        if f == "lib.rs":
            continue
        mod = f[:-3]
        e = edges(os.path.join(src, f), modules, roots)
        e.pop(mod, None)
        graph[mod] = sorted(e)
        shown = ", ".join(f"{t} (line {e[t][0]})" for t in sorted(e))
        print(f"{mod} -> {shown or '(nothing)'}")
    unknown = sorted({t for ts in graph.values() for t in ts if t.startswith("?")})
    if unknown:
        print("unresolved crate:: names:", ", ".join(u[1:] for u in unknown))
    comps = circles(graph)
    for c in comps:
        print("circle:", " ".join(c))
    if comps:
        sys.exit(1)
    print("ok: no circle")


if __name__ == "__main__":
    main()
