#!/usr/bin/env python3
"""The layering rule of ARCHITECTURE.md, enforced: no header or source of a lower layer includes
one of a higher layer, and the include graph has no cycles.

Layers, bottom to top (a file may include its own layer and those below):
  core  <  forcefields  <  integrators  <  engine/deck  <  engine/io  <  engine/observe
  <  engine/scene  <  engine/domain  <  engine/run  <  engine/main.cpp (the command line)  <  python (the module)

Usage: check_layers.py [REPO]   (exit 0 clean, 1 with one line per violation)
"""
import os
import re
import sys

LAYERS = ["core", "forcefields", "integrators", "engine/deck", "engine/io", "engine/observe",
          "engine/scene", "engine/domain", "engine/run", "engine/main.cpp", "python"]


def layer(path):
    for k, prefix in enumerate(LAYERS):
        if path == prefix or path.startswith(prefix + "/"):
            return k
    return None


def main():
    repo = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), ".."))
    include = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)
    graph, problems = {}, []
    for top in ("engine", "forcefields", "integrators", "python"):
        for root, _, names in os.walk(os.path.join(repo, top)):
            for name in names:
                if not name.endswith((".hpp", ".cpp", ".h")):
                    continue
                rel = os.path.relpath(os.path.join(root, name), repo)
                k = layer(rel)
                if k is None:
                    problems.append(f"{rel}: in no layer (engine/ files belong in a subfolder: {', '.join(LAYERS)})")
                    continue
                with open(os.path.join(repo, rel), encoding="utf-8") as f:
                    targets = include.findall(f.read())
                graph[rel] = [t for t in targets if layer(t) is not None]
                for t in targets:
                    kt = layer(t)
                    if kt is not None and kt > k:
                        problems.append(f"{rel}: includes {t}, a higher layer ({LAYERS[kt]} above {LAYERS[k]})")
    # cycles (depth-first search, colouring)
    state = {}

    def visit(n, stack):
        state[n] = 1
        for m in graph.get(n, []):
            if state.get(m) == 1:
                problems.append("include cycle: " + " -> ".join(stack[stack.index(m):] + [m]))
            elif m in graph and state.get(m) is None:
                visit(m, stack + [m])
        state[n] = 2

    for n in sorted(graph):
        if state.get(n) is None:
            visit(n, [n])
    for p in problems:
        print(p)
    print(f"{len(graph)} files checked, {len(problems)} violations")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
