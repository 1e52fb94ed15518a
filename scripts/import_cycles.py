#!/usr/bin/env python3
"""Import circles between the files of each crate: which source files reach each other through
`crate::` / `super::` paths (use lines and inline paths alike), as strongly connected components
of the file graph. Prints each circle and a count; exit status 0 always (a report, not a check).

    python3 scripts/import_cycles.py            # every crate under crates/ and the binary in src/
"""
import os
import re
import sys

ROOT = os.environ.get("REPO", os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))


def module_files(src):
    """module path (tuple) -> file, for one crate's src directory."""
    mods = {}
    for dirpath, _, files in os.walk(src):
        for f in files:
            if not f.endswith(".rs"):
                continue
            rel = os.path.relpath(os.path.join(dirpath, f), src)
            parts = rel[:-3].split(os.sep)
            if parts[-1] in ("lib", "main"):
                parts = parts[:-1]
            elif parts[-1] == "mod":
                parts = parts[:-1]
            mods[tuple(parts)] = os.path.join(dirpath, f)
    return mods


def strip_tests(text):
    # drop `#[cfg(test)] mod tests { ... }` blocks: tests may reach anywhere
    out, i = [], 0
    for m in re.finditer(r"#\[cfg\(test\)\]\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+\w+\s*\{", text):
        if m.start() < i:
            continue
        out.append(text[i:m.start()])
        depth, j = 1, m.end()
        while j < len(text) and depth:
            depth += {"{": 1, "}": -1}.get(text[j], 0)
            j += 1
        i = j
    out.append(text[i:])
    return "".join(out)


def reexports(mod, text, mods):
    """item name -> module, for the `pub use child::{Item, ...}` lines of a facade file."""
    out = {}
    text = re.sub(r"//[^\n]*", "", strip_tests(text))
    for m in re.finditer(r"pub use (?:self::|crate::)?([a-z_][\w:]*?)::(\{[^}]*\}|\w+)\s*;", text, re.S):
        path = list(mod) + m.group(1).split("::") if not m.group(0).startswith("pub use crate::") else m.group(1).split("::")
        target = None
        for k in range(len(path), 0, -1):
            if tuple(path[:k]) in mods:
                target = tuple(path[:k])
                break
        if target is None:
            continue
        items = m.group(2)
        names = [t.strip() for t in items.strip("{}").split(",")] if items.startswith("{") else [items]
        for n in names:
            n = n.split(" as ")[-1].strip()
            if n and n != "self":
                out[n] = target
    return out


ROOT_ITEMS = {}


def references(mod, text, mods):
    """The modules a file refers to through crate:: / super:: paths (an item a facade
    re-exports counts as a reference to the module that defines it; a file's own `pub use`
    re-exports are its facade, not a use)."""
    text = re.sub(r"//[^\n]*", "", strip_tests(text))
    text = re.sub(r"pub use [^;]*;", "", text)
    found = set()
    # expand `use crate::{a, b::c}` groups one level
    for m in re.finditer(r"\b(crate|super)((?:::super)*)::(\{[^}]*\}|[A-Za-z_][\w:]*)", text):
        base = [] if m.group(1) == "crate" else list(mod[:-1] if mod else [])
        if m.group(1) == "super":
            base = list(mod[:-1])
            base = base[: len(base) - m.group(2).count("super")]
        tails = [m.group(3)]
        if tails[0].startswith("{"):
            tails = [t.strip() for t in tails[0][1:-1].split(",") if t.strip()]
        for t in tails:
            path = base + [p for p in t.split("::") if p and p != "self"]
            # the longest prefix that is a module file
            for k in range(len(path), 0, -1):
                if tuple(path[:k]) in mods:
                    target = tuple(path[:k])
                    rest = path[k:]
                    # an item re-exported by that module (a facade) belongs to its source
                    if rest and rest[0] in ROOT_ITEMS.get(target, {}):
                        target = ROOT_ITEMS[target][rest[0]]
                    found.add(target)
                    break
            else:
                root = ROOT_ITEMS.get((), {})
                found.add(root.get(path[0], ()) if path else ())
    # bare paths to child modules (`file::load` in lib.rs, `run::Plan` in channel/mod.rs)
    for m in re.finditer(r"(?<![:\w])([a-z_][a-z0-9_]*)::", text):
        child = tuple(mod) + (m.group(1),)
        if child in mods:
            found.add(child)
    found.discard(mod)
    return found


def sccs(graph):
    index, low, stack, on, out, n = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = n[0]
        n[0] += 1
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
            out.append(comp)

    sys.setrecursionlimit(10000)
    for v in graph:
        if v not in index:
            visit(v)
    return out


def main():
    crates = [os.path.join(ROOT, "crates", c, "src") for c in sorted(os.listdir(os.path.join(ROOT, "crates")))]
    crates.append(os.path.join(ROOT, "src"))
    total_files, total_circles = 0, 0
    for src in crates:
        mods = module_files(src)
        ROOT_ITEMS.clear()
        for mod, path in mods.items():
            with open(path, encoding="utf-8") as f:
                ROOT_ITEMS[mod] = reexports(mod, f.read(), mods)
        graph = {}
        for mod, path in mods.items():
            with open(path, encoding="utf-8") as f:
                graph[mod] = references(mod, f.read(), mods) & set(mods)
        for comp in sccs(graph):
            if len(comp) > 1:
                names = sorted(os.path.relpath(mods[m], ROOT) for m in comp)
                total_circles += 1
                total_files += len(comp)
                print(f"circle of {len(comp)}: " + ", ".join(names))
    print(f"{total_circles} circles, {total_files} files in circles")


if __name__ == "__main__":
    main()
