#!/usr/bin/env python3
"""The workspace's structure (issue #37): the crate graph and its layers, no circle between
files, crates or folders, and no source file over 600 lines outside tests.

    python3 tools/structure/check.py [--graph]

Crates and their dependencies come from `cargo metadata` (normal and build dependencies: what a
crate's code may import). Files: every `use`, and every path written out, that starts with
`crate::`, `super::` or `self::` is an edge from the file to the file of the module it names
(the deepest module of the path that is a file); comments, `$crate` in macros and a file's
`#[cfg(test)] mod tests` are not read. A path that starts with one of the file's own submodules,
and `include!`, are edges too. Folders: a file's edge, and a crate's dependency, is an edge
between the folders holding them, unless one folder holds the other (a module's folder and its
parent's are one room). Prints one line per check, `structure: N
passed, M failed, 0 not applicable`, and exits 1 on a failure.
"""
import json
import os
import re
import subprocess
import sys

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
MAX_LINES = 600

# The layers, bottom up (docs/design.md): a crate may depend only on crates of a lower layer,
# or of its own layer where the table says so (services never on each other).
LAYERS = [
    ("protocol", ["protocol"]),
    ("shared", ["shared"]),
    ("services", ["services"]),
    ("modules", ["modules"]),
    ("drivers", ["drivers"]),
    ("boards", ["boards"]),
    ("images", ["firmware-8318", "firmware-8350"]),
    ("PC programs", ["client", "remodaq", "utility"]),
    ("tools", ["tools", "fuzz"]),
]
# Same-layer dependencies allowed: shared's network part on shared; a board on another board
# (the QEMU board's bootloader on its board crate); the PC programs on the client library.
SAME_LAYER_OK = {"shared", "boards", "PC programs", "tools"}


def layer_of(path):
    rel = os.path.relpath(path, ROOT).split(os.sep)[0]
    for i, (name, dirs) in enumerate(LAYERS):
        if rel in dirs:
            return i, name
    return None, rel


def metadata():
    out = subprocess.run(
        ["cargo", "metadata", "--format-version", "1", "--no-deps", "--locked"],
        cwd=ROOT, check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def sccs(graph):
    """Strongly connected components of more than one node (or with a self loop)."""
    index, low, stack, on, result, counter = {}, {}, [], set(), [], [0]
    sys.setrecursionlimit(100000)

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
                result.append(sorted(comp))
    for v in list(graph):
        if v not in index:
            visit(v)
    return result


COMMENT = re.compile(r"//.*$")
PATH = re.compile(r"(?<![$\w:])(crate|super|self)((?:::\w+)+|::\*)")
USE_GROUP = re.compile(r"\buse\s+(crate|super|self)((?:::\w+)*)::\{([^;]*)\};", re.S)
INCLUDE = re.compile(r'include!\(\s*"([^"]+)"\s*\)')
PATH_ATTR = re.compile(r'#\[path\s*=\s*"([^"]+)"\]')
TESTS = re.compile(r"#\[cfg\(test\)\]\s*(pub(\([^)]*\))?\s+)?mod\s+\w+\s*\{", re.S)


def strip(text):
    m = TESTS.search(text)
    if m:
        text = text[:m.start()]
    # Block comments and string literals are rare in paths; line comments are stripped.
    return "\n".join(COMMENT.sub("", line) for line in text.splitlines())


class Crate:
    def __init__(self, name, root_file):
        self.name = name
        self.root = root_file
        self.src = os.path.dirname(root_file)

    def module_file(self, parts):
        """The file of module `parts` (from the crate root), or None."""
        if not parts:
            return self.root
        base = os.path.join(self.src, *parts)
        for candidate in (base + ".rs", os.path.join(base, "mod.rs")):
            if os.path.isfile(candidate):
                return candidate
        return None

    def module_of(self, path):
        """The module path of `path`, a file of this crate's module tree."""
        rel = os.path.relpath(path, self.src)
        if path == self.root:
            return []
        parts = rel[:-3].split(os.sep)
        if parts[-1] == "mod":
            parts = parts[:-1]
        return parts


def crate_files(crate):
    """The files of the crate's module tree (following `mod x;` and `#[path]`)."""
    seen, todo = [], [(crate.root, crate.module_of(crate.root))]
    while todo:
        path, module = todo.pop()
        if path in seen or not os.path.isfile(path):
            continue
        seen.append(path)
        text = open(path, encoding="utf-8").read()
        body = strip(text)
        here = os.path.dirname(path)
        own_dir = here if os.path.basename(path) in ("mod.rs", "lib.rs", "main.rs") or path == crate.root \
            else os.path.join(here, os.path.basename(path)[:-3])
        for m in re.finditer(r'(#\[path\s*=\s*"([^"]+)"\]\s*)?(?:pub(?:\([^)]*\))?\s+)?mod\s+(\w+)\s*;', body):
            name = m.group(3)
            if m.group(2):
                todo.append((os.path.normpath(os.path.join(here, m.group(2))), module + [name]))
                continue
            for c in (os.path.join(own_dir, name + ".rs"), os.path.join(own_dir, name, "mod.rs")):
                if os.path.isfile(c):
                    todo.append((c, module + [name]))
                    break
    return seen


def file_edges(crate, path, module):
    body = strip(open(path, encoding="utf-8").read())
    edges = set()
    here = os.path.dirname(path)

    def resolve(anchor, rest):
        if anchor == "crate":
            base = []
        elif anchor == "self":
            base = list(module)
        else:
            base = list(module)
            while rest and rest[0] == "super":
                rest = rest[1:]
                base = base[:-1]
            base = base[:-1]
        parts = base + rest
        best = None
        for n in range(len(parts), -1, -1):
            f = crate.module_file(parts[:n])
            if f:
                best = f
                break
        if best and best != path:
            edges.add(best)

    for m in USE_GROUP.finditer(body):
        anchor, prefix = m.group(1), [p for p in m.group(2).split("::") if p]
        for item in m.group(3).split(","):
            item = item.strip().split(" as ")[0].strip()
            if not item or item in ("self", "*"):
                resolve(anchor, prefix)
                continue
            first = [p for p in item.split("::") if p and not p.startswith("{")]
            resolve(anchor, prefix + first)
    for m in PATH.finditer(body):
        resolve(m.group(1), [p for p in m.group(2).split("::") if p and p != "*"])
    # A path that starts with one of this file's own submodules (`pub use request::Request`,
    # `reply::decode(..)`): an edge to that submodule.
    for child in re.findall(r"(?:pub(?:\([^)]*\))?\s+)?mod\s+(\w+)\s*;", body):
        if re.search(r"(?<![\w:$])" + child + r"::", body):
            resolve("self", [child])
    for m in INCLUDE.finditer(body):
        target = os.path.normpath(os.path.join(here, m.group(1)))
        if os.path.isfile(target):
            edges.add(target)
    return edges


def main():
    meta = metadata()
    failures, passed = [], [0]

    def check(name, ok, detail=""):
        print(f"structure: {'ok  ' if ok else 'FAIL'} {name}{(': ' + detail) if detail else ''}")
        if ok:
            passed[0] += 1
        else:
            failures.append(name)

    packages = {p["name"]: p for p in meta["packages"]}
    members = [p for p in meta["packages"] if p["id"] in meta["workspace_members"]]
    crate_dir = {p["name"]: os.path.dirname(p["manifest_path"]) for p in members}
    graph, rows = {}, []
    for p in members:
        deps = sorted({d["name"] for d in p["dependencies"]
                       if d["name"] in crate_dir and d.get("kind") in (None, "build")})
        graph[p["name"]] = deps
        rows.append((layer_of(crate_dir[p["name"]])[0] or 0, p["name"], deps))
    if "--graph" in sys.argv:
        print("crate graph (normal and build dependencies inside the workspace), bottom up:")
        for layer, name, deps in sorted(rows):
            print(f"  [{LAYERS[layer][0]}] {name} -> {', '.join(deps) or '-'}")
    cycles = sccs(graph)
    check("no circle between crates", not cycles, "; ".join(" <-> ".join(c) for c in cycles))
    upward = []
    for _, name, deps in rows:
        li, lname = layer_of(crate_dir[name])
        for d in deps:
            di, dname = layer_of(crate_dir[d])
            if li is None or di is None:
                continue
            if di > li or (di == li and lname not in SAME_LAYER_OK):
                upward.append(f"{name} ({lname}) -> {d} ({dname})")
    check("every crate depends only on lower layers (services never on each other)", not upward,
          "; ".join(upward))

    # Files and folders, crate by crate (each target's module tree: lib, bins, examples; tests
    # are not counted).
    file_graph, too_long, seen_files = {}, [], set()
    for p in members:
        for t in p["targets"]:
            if any(k in t["kind"] for k in ("test", "bench")):
                continue
            crate = Crate(t["name"], t["src_path"])
            for f in crate_files(crate):
                module = crate.module_of(f) if f.startswith(crate.src + os.sep) or f == crate.root else []
                file_graph.setdefault(f, set()).update(file_edges(crate, f, module))
                seen_files.add(f)
    for f in sorted(seen_files):
        if "/tests/" in f or f.endswith("/tests.rs"):
            continue
        n = sum(1 for _ in open(f, encoding="utf-8"))
        if n > MAX_LINES:
            too_long.append(f"{os.path.relpath(f, ROOT)} ({n})")
    cycles = sccs({k: sorted(v) for k, v in file_graph.items()})
    rel = lambda fs: " <-> ".join(os.path.relpath(f, ROOT) for f in fs)
    check("no circle between files", not cycles, "; ".join(rel(c) for c in cycles))
    # A folder holds its subfolders: an edge between a folder and one of its own subfolders is
    # inside one room (a module's files and its parent's), not an edge between two folders. The
    # crates' dependencies are edges between their folders too.
    def nested(a, b):
        return a == b or a.startswith(b + os.sep) or b.startswith(a + os.sep)
    folders = {}
    pairs = [(os.path.dirname(f), os.path.dirname(t)) for f, ts in file_graph.items() for t in ts]
    pairs += [(crate_dir[name], crate_dir[d]) for name, deps in graph.items() for d in deps]
    for a, b in pairs:
        if not nested(a, b):
            folders.setdefault(a, set()).add(b)
    cycles = sccs({k: sorted(v) for k, v in folders.items()})
    check("no circle between folders", not cycles, "; ".join(rel(c) for c in cycles))
    check(f"no source file over {MAX_LINES} lines outside tests", not too_long, ", ".join(too_long))
    sizes = sorted(((sum(1 for _ in open(f, encoding="utf-8")), os.path.relpath(f, ROOT)) for f in seen_files
                    if "/tests/" not in f and not f.endswith("/tests.rs")), reverse=True)
    print("largest source files: " + ", ".join(f"{p} {n}" for n, p in sizes[:8]))
    print(f"structure: {passed[0]} passed, {len(failures)} failed, 0 not applicable")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
