#!/usr/bin/env python3
"""tools/check_layers.py: the repository obeys the layering of ARCHITECTURE.md, and the checker
itself catches an upward include, a cycle and a file outside every layer."""
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
TOOL = os.path.join(HERE, "..", "tools", "check_layers.py")


def check(repo):
    r = subprocess.run([sys.executable, TOOL, repo], capture_output=True, text=True)
    return r.returncode, r.stdout


def tree(files):
    d = tempfile.mkdtemp(prefix="layers_")
    for path, text in files.items():
        os.makedirs(os.path.join(d, os.path.dirname(path)), exist_ok=True)
        with open(os.path.join(d, path), "w") as f:
            f.write(text)
    return d


def main():
    code, out = check(os.path.join(HERE, ".."))
    assert code == 0, "the repository breaks its layering:\n" + out
    clean = {"core/box.hpp": "", "forcefields/term.hpp": '#include "core/box.hpp"\n'}
    assert check(tree(clean))[0] == 0
    code, out = check(tree({**clean, "forcefields/bad.hpp": '#include "engine/scene/scene.hpp"\n',
                            "engine/scene/scene.hpp": ""}))
    assert code == 1 and "forcefields/bad.hpp: includes engine/scene/scene.hpp" in out, out
    code, out = check(tree({**clean, "integrators/a.hpp": '#include "integrators/b.hpp"\n',
                            "integrators/b.hpp": '#include "integrators/a.hpp"\n'}))
    assert code == 1 and "include cycle" in out, out
    code, out = check(tree({**clean, "engine/loose.hpp": ""}))
    assert code == 1 and "engine/loose.hpp: in no layer" in out, out
    print("1 passed, 0 failed")


if __name__ == "__main__":
    main()
