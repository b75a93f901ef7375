#!/usr/bin/env python3
"""Lists the import graph of a crate's top-level modules and the circles in it.

    scripts/module_cycles.py SRC_DIR        e.g. scripts/module_cycles.py core/src

Every `.rs` file under SRC_DIR but `lib.rs` is a module, named by its path (`nn/batch/kind.rs`
is `nn::batch::kind`, `navigator/mod.rs` is `navigator`). An edge `a -> b` is any
`crate::...` path in `a`'s code (a `use` line, a path inside an expression, each member of a
`use crate::{...}` group, nested groups included) whose longest prefix naming a module is
`b`, and so is a `use child::...` line of a directory module's `mod.rs` naming one of its
own files; a name a module re-exports from one of its own files (`pub use step::X;` in a
`mod.rs`, `crate::navigator::X`) counts as an edge to that file, a name `lib.rs` re-exports
(`crate::Dims`) as an edge to the module the name comes from, a name `lib.rs` defines
itself as an edge to `lib`. `super::` inside a file's nested modules (its tests) names the
file itself and is no edge; a directory module's files name one another by `crate::`
paths. Comments (doc links included), strings and character literals are skipped. Prints
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


def group_members(text):
    """The members of the `{...}` group `text` starts with, as written (nested groups kept)."""
    members, depth, item = [], 0, ""
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
            members.append(item)
            item = ""
        else:
            item += ch
    members.append(item)
    return [m.strip() for m in members if m.strip()]


def expand(path):
    """The plain paths (lists of segments) of `path`, its groups expanded."""
    path = re.sub(r"\s+", "", path)
    m = re.match(r"((?:\w+::)*)(\{.*)?", path)
    prefix = [p for p in m.group(1).split("::") if p]
    if not m.group(2):
        seg = re.match(r"\w+", path[len(m.group(1)) :])
        return [prefix + ([seg.group(0)] if seg else [])]
    out = []
    for member in group_members(m.group(2)):
        for tail in expand(member):
            out.append(prefix + tail)
    return out


def module_name(rel):
    """`nn/batch/mod.rs` -> `nn::batch`, `nn/dense.rs` -> `nn::dense`."""
    parts = rel[:-3].split(os.sep)
    if parts[-1] == "mod":
        parts = parts[:-1]
    return "::".join(parts)


def reexports(src, name):
    """Names a module file re-exports from its own child modules: name -> child module."""
    names = {}
    code = strip(src)
    for m in re.finditer(r"pub use (?:self::)?(\w+)::(\{[^;]*\}|\w+)\s*;", code, re.S):
        child, rest = m.group(1), m.group(2)
        items = group_members(rest) if rest.startswith("{") else [rest]
        for it in items:
            h = re.match(r"(\w+)", it)
            if h:
                names[h.group(1)] = (name + "::" if name else "") + child
    return names


def root_names(lib_src, modules):
    """Names at the crate root: re-exports -> their module, own items -> `lib`."""
    names = {}
    for m in re.finditer(r"pub use ((?:\w+::)+)(\{[^}]*\}|\w+)\s*;", strip(lib_src), re.S):
        path, rest = m.group(1).rstrip(":").split("::"), m.group(2)
        items = group_members(rest) if rest.startswith("{") else [rest]
        mod = next(
            ("::".join(path[:i]) for i in range(len(path), 0, -1) if "::".join(path[:i]) in modules),
            path[0],
        )
        for it in items:
            h = re.match(r"(\w+)", it)
            if h:
                names[h.group(1)] = mod
    for m in re.finditer(r"pub (?:const|static|fn|struct|enum|type|trait) (\w+)", lib_src):
        names.setdefault(m.group(1), "lib")
    return names


def resolve(segs, modules, roots, exports):
    """The module a `crate::` path (its segments) leads to, or `?name`."""
    if not segs:
        return None
    if segs[0] in roots and segs[0] not in modules:
        return roots[segs[0]]
    best = None
    for i in range(len(segs), 0, -1):
        cand = "::".join(segs[:i])
        if cand in modules:
            best, rest = cand, segs[i:]
            break
    if best is None:
        return "?" + segs[0]
    if rest and rest[0] in exports.get(best, {}):
        return exports[best][rest[0]]
    return best


def edges(path, name, modules, roots, exports):
    code = strip(open(path, encoding="utf-8").read())
    out = {}
    # A directory module's own `use child::...` (and `pub use`) lines name its files.
    for m in re.finditer(r"\buse\s+(?:self::)?(\w+)::", code):
        child = (name + "::" if name else "") + m.group(1)
        if child in modules:
            out.setdefault(child, []).append(code.count("\n", 0, m.start()) + 1)
    for m in re.finditer(r"\bcrate::", code):
        rest = code[m.end() :]
        if rest.startswith("{"):
            depth, j = 0, 0
            for j, ch in enumerate(rest):
                depth += ch == "{"
                depth -= ch == "}"
                if depth == 0:
                    break
            paths = expand(rest[: j + 1])
        else:
            h = re.match(r"(?:\w+::)*\{?", rest)
            text = h.group(0)
            if text.endswith("{"):
                depth, j = 0, len(text) - 1
                for j in range(len(text) - 1, len(rest)):
                    depth += rest[j] == "{"
                    depth -= rest[j] == "}"
                    if depth == 0:
                        break
                paths = expand(rest[: j + 1])
            else:
                w = re.match(r"(?:\w+::)*\w+", rest)
                paths = [w.group(0).split("::")] if w else []
        line = code.count("\n", 0, m.start()) + 1
        for segs in paths:
            target = resolve(segs, modules, roots, exports)
            if target:
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
    files = sorted(
        os.path.relpath(os.path.join(d, f), src)
        for d, _, fs in os.walk(src)
        for f in fs
        if f.endswith(".rs")
    )
    files = [f for f in files if f != "lib.rs"]
    names = {f: module_name(f) for f in files}
    modules = set(names.values())
    roots = root_names(open(os.path.join(src, "lib.rs"), encoding="utf-8").read(), modules)
    exports = {}
    for f, name in names.items():
        exports[name] = reexports(open(os.path.join(src, f), encoding="utf-8").read(), name)
    graph = {}
    for f in files:
        mod = names[f]
        e = edges(os.path.join(src, f), mod, modules, roots, exports)
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
