#!/usr/bin/env python3
"""Checks what `cargo` does not: no import circle between the files of a folder in `src/`
(a type in the wrong file), and every relative link of the Markdown docs pointing at a file
that exists. Exits 1 naming each problem. Run from the repository's root:
`python3 scripts/check_structure.py`.

A file's imports are its `use crate::…`/`use super::…` lines and the `crate::…`/`super::…`
paths in its code (comments and `#[cfg(test)] mod tests` left out), each resolved to the
module file it names. A child using its parent module (`super::X` from `a/b.rs` into
`a/mod.rs`) is the parent's own part, not a circle; a circle is two or more sibling files
(or folders) that reach each other.
"""
import glob
import os
import re
import sys


def modules():
    mods = {}
    for path in glob.glob("src/**/*.rs", recursive=True):
        parts = path[len("src/"):-len(".rs")].split("/")
        if parts[-1] == "mod":
            parts = parts[:-1]
        if parts in (["lib"], ["main"]) or parts[0] == "cli":
            continue
        mods[tuple(parts)] = path
    return mods


def resolve(mods, current, segments):
    if segments[0] == "crate":
        base, rest = [], segments[1:]
    elif segments[0] in ("super", "self"):
        base, rest = list(current), segments
        while rest and rest[0] == "super":
            base, rest = base[:-1], rest[1:]
        if rest and rest[0] == "self":
            rest = rest[1:]
    else:
        return None
    full = base + rest
    for k in range(len(full), 0, -1):
        if tuple(full[:k]) in mods:
            return tuple(full[:k])
    return None


def expand(prefix, text):
    """`a::{b, c::{d}}` → `a::b`, `a::c::d`."""
    m = re.match(r"^([\w:]*?)\{(.*)\}$", text)
    if not m:
        return [prefix + text]
    items, depth, cur = [], 0, ""
    for ch in m.group(2):
        depth += ch == "{"
        depth -= ch == "}"
        if ch == "," and depth == 0:
            items.append(cur)
            cur = ""
        else:
            cur += ch
    if cur:
        items.append(cur)
    out = []
    for item in items:
        out += expand(prefix + m.group(1), item)
    return out


def imports(mods):
    edges = {}
    for module, path in mods.items():
        src = open(path, encoding="utf-8").read()
        cut = src.find("#[cfg(test)]\nmod tests")
        if cut >= 0:
            src = src[:cut]
        src = re.sub(r"//[^\n]*", "", src)
        deps = set()
        for u in re.finditer(r"\buse\s+([^;]+);", src, re.S):
            for e in expand("", re.sub(r"\s+", "", u.group(1))):
                e = re.sub(r"\bas\w+$", "", e)
                segs = [s for s in e.split("::") if s]
                if segs:
                    r = resolve(mods, module, segs)
                    if r is not None:
                        deps.add(r)
        for u in re.finditer(r"\b((?:crate|super)(?:::\w+)+)", src):
            r = resolve(mods, module, u.group(1).split("::"))
            if r is not None:
                deps.add(r)
        deps.discard(module)
        # A parent module is not a sibling: its children may use it.
        edges[module] = {d for d in deps if not (len(d) < len(module) and module[: len(d)] == d)}
    return edges


def circles(edges):
    """Tarjan's strongly connected components of more than one module."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]
    sys.setrecursionlimit(10000)

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
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
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def broken_links():
    files = ["README.md", "CHANGELOG.md"] + glob.glob("docs/**/*.md", recursive=True)
    bad = []
    for f in files:
        if not os.path.exists(f):
            continue
        text = re.sub(r"```.*?```", "", open(f, encoding="utf-8").read(), flags=re.S)
        for m in re.finditer(r"\]\(([^)\s]+)\)", text):
            link = m.group(1)
            if re.match(r"^(https?:|mailto:|#)", link):
                continue
            target = link.split("#")[0]
            if target and not os.path.exists(os.path.normpath(os.path.join(os.path.dirname(f), target))):
                bad.append(f"{f}: broken link ({link})")
    return bad


def main():
    problems = []
    edges = imports(modules())
    for comp in circles(edges):
        names = ["::".join(c) for c in comp]
        pairs = [
            f"{'::'.join(a)} → {'::'.join(b)}" for a in comp for b in sorted(edges[a]) if b in comp
        ]
        problems.append(f"import circle between {', '.join(names)}: {'; '.join(pairs)}")
    problems += broken_links()
    for p in problems:
        print(p, file=sys.stderr)
    if problems:
        sys.exit(1)
    print(f"structure: {len(edges)} modules, no import circle; Markdown links resolve")


if __name__ == "__main__":
    main()
