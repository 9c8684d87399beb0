#!/usr/bin/env python3
"""Holds src/ to its module layering (docs/design.md, "Code map").

Reads every `crate::…` and `super::…` path outside `#[cfg(test)]` code of both crates in src/:
the library (lib.rs and its modules) and the binary (main.rs and cli/, which sit on top of the
library and reach it only as `covec::…`). Resolves each path to the file that defines it, and
fails if
  - a top-level module of the library imports one of a higher layer (LAYERS below), or
  - the files of either crate import each other in a cycle (a parent `mod.rs` naming its own
    children does not count: that is how Rust declares them).
  - a module of the service imports one of a higher service layer (SERVICE_LAYERS below).
Prints the edges it refuses and exits 1; prints a one-line summary and exits 0 otherwise.
`--self-test` checks that it does refuse: an upward import and a cycle, each injected into a
copy of src/.
"""
import re
import sys
from pathlib import Path

# Bottom to top; a module may import its own layer's modules only within itself.
LAYERS = [
    ["scene", "simd"],
    ["geom"],
    ["render", "opaque"],
    ["imageio", "optim", "svg", "pdf"],
    ["synth"],
    ["perceptual", "decompose", "output"],
    ["edit"],
    ["pipeline"],
    ["eval"],
    ["web"],
    ["service"],
]
RANK = {name: rank for rank, names in enumerate(LAYERS) for name in names}

# The service's own layers, bottom to top (docs/design.md, "The service"): what a job is, where
# records and files are kept (and the records' seam), the service core with the queue's seam to
# its backend, the backends (one folder each, implementing both seams: `backend/mod.rs` is the
# one place that chooses among them), and the HTTP edge (the handlers, `error.rs` turning domain
# errors into problems, and the service root with the router). A module may import its own
# layer or a lower one.
SERVICE_LAYERS = [
    ["model", "view", "rate", "fair", "conn"],
    ["store"],
    ["inputs", "telemetry"],
    ["job", "runner", "queue", "webhooks", "derived"],
    ["backend"],
    ["error", "auth", "signed", "submit", "download", "jobs", "events", "results", "edits", "ops", "limits",
     "openapi", "fuzzing", "state", "serve", ""],
]
SERVICE_RANK = {name: rank for rank, names in enumerate(SERVICE_LAYERS) for name in names}

SRC = Path(__file__).resolve().parent.parent / "src"


# The binary crate's files: its root and the modules it declares.
BINARY = ("main.rs", "cli")


def module_of(src: Path, path: Path) -> tuple:
    parts = list(path.relative_to(src).with_suffix("").parts)
    if parts[-1] in ("mod", "lib", "main"):
        parts.pop()
    return tuple(parts)


def in_binary(src: Path, path: Path) -> bool:
    return path.relative_to(src).parts[0] in BINARY


def code_of(path: Path) -> str:
    text = path.read_text()
    cut = text.find("#[cfg(test)]")
    if cut >= 0:
        text = text[:cut]
    text = re.sub(r"//[^\n]*", "", text)
    return text


def paths_in(code: str):
    """Every `crate::a::b` / `super::a` path, braces expanded one level."""
    # Not `pub(super)` / `pub(crate)`: a visibility, not a path.
    for m in re.finditer(r"(?<!\()\b(crate|super)((?:::\w+)*)(?:::\{([^}]*)\})?", code):
        head = [m.group(1)] + [p for p in m.group(2).split("::") if p]
        if m.group(3) is None:
            yield head
        else:
            for item in m.group(3).split(","):
                item = item.strip().split(" as ")[0].strip()
                if item:
                    yield head + [p for p in item.split("::") if p and p != "self"]


def check(src: Path, binary: bool):
    """The refused edges of one crate, and its file and import counts."""
    files = {
        module_of(src, p): p
        for p in src.rglob("*.rs")
        if in_binary(src, p) == binary and p.name != "tests.rs"
    }
    modules = set(files)
    edges = set()
    for module, path in files.items():
        is_dir_module = path.name in ("mod.rs", "lib.rs", "main.rs")
        for parts in paths_in(code_of(path)):
            if parts[0] == "crate":
                target = list(parts[1:])
            else:
                base = list(module) if is_dir_module else list(module[:-1])
                target = base + parts[1:]
            # The longest prefix naming a module file is the file the item comes from.
            while target and tuple(target) not in modules:
                target.pop()
            target = tuple(target)
            if target == module or not target:
                continue
            if target[: len(module)] == module and is_dir_module:
                continue  # a parent naming its children
            edges.add((module, target))

    bad = []
    for a, b in sorted(edges):
        if binary:
            break  # the binary's modules are subcommands side by side: no layers, no cycles
        ra, rb = RANK.get(a[0]), RANK.get(b[0])
        if ra is None or rb is None:
            bad.append(f"{'::'.join(a)} -> {'::'.join(b)}: module missing from LAYERS")
        elif a[0] != b[0] and rb >= ra:
            bad.append(f"{'::'.join(a)} -> {'::'.join(b)}: imports a layer at or above its own")
        elif a[0] == b[0] == "service":
            sa, sb = (SERVICE_RANK.get(m[1] if len(m) > 1 else "") for m in (a, b))
            if sa is None or sb is None:
                bad.append(f"{'::'.join(a)} -> {'::'.join(b)}: module missing from SERVICE_LAYERS")
            elif sb > sa:
                bad.append(f"{'::'.join(a)} -> {'::'.join(b)}: imports a higher service layer")

    # Cycles among files (depth-first search).
    graph = {m: sorted(b for a, b in edges if a == m) for m in modules}
    state, stack = {}, []

    def visit(node):
        state[node] = "open"
        stack.append(node)
        for nxt in graph.get(node, []):
            if state.get(nxt) == "open":
                cycle = stack[stack.index(nxt):] + [nxt]
                bad.append("cycle: " + " -> ".join("::".join(m) or "crate" for m in cycle))
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = "done"

    for node in sorted(modules):
        if node not in state:
            visit(node)

    return bad, len(modules), len(edges)


def refused(src: Path):
    """What `src` breaks, and its file and import counts."""
    bad, files, imports = [], 0, 0
    for binary in (False, True):
        crate_bad, crate_files, crate_imports = check(src, binary)
        bad += crate_bad
        files += crate_files
        imports += crate_imports
    return bad, files, imports


def self_test() -> int:
    """Injects an upward import (the runner naming the HTTP error type), a cycle (the queue's
    state naming its local backend, which imports it) and a backend named below the backends (the
    queue naming the shared one) into copies of src/: each must be refused."""
    import shutil
    import tempfile

    injections = [
        ("service/runner.rs", "use crate::service::error::ApiError;\n"),
        ("service/queue/state.rs", "use super::local::Local;\n"),
        ("service/queue/mod.rs", "use crate::service::backend::RecordsAt;\n"),
    ]
    for file, line in injections:
        with tempfile.TemporaryDirectory() as tmp:
            copy = Path(tmp) / "src"
            shutil.copytree(SRC, copy)
            path = copy / file
            path.write_text(line + path.read_text())
            bad, _, _ = refused(copy)
            if not bad:
                print(f"check-modules --self-test: `{line.strip()}` in {file} was not refused")
                return 1
            print(f"check-modules --self-test: `{line.strip()}` in {file} refused:", *bad,
                  sep="\n  ")
    return 0


def main() -> int:
    if sys.argv[1:] == ["--self-test"]:
        return self_test()
    bad, files, imports = refused(SRC)
    if bad:
        print("check-modules: the layering is broken:", *bad, sep="\n  ")
        return 1
    print(f"check-modules: {files} files, {imports} imports, layered and acyclic")
    return 0


if __name__ == "__main__":
    sys.exit(main())
