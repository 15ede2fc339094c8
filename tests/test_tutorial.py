"""docs/tutorial.md runs as written: its ```sh and ```python blocks, in order, each must succeed.

    test_tutorial.py STIFFMD

Run in a scratch directory that looks like the repository root to the commands: `build/` holds the
stiffmd under test, `inputs/` and `tools/` are the repository's; `out/` is the scratch's own. The
```toml blocks are excerpts of inputs/polymer_study.toml: each must appear in the deck as written
(ignoring comments), so that the tutorial shows the deck that runs."""
import os
import pathlib
import re
import shutil
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent
TUTORIAL = ROOT / "docs" / "tutorial.md"
DECK = ROOT / "inputs" / "polymer_study.toml"


def blocks(text):
    return re.findall(r"^```(\w+)\n(.*?)^```$", text, flags=re.S | re.M)


def without_comments(toml):
    lines = [re.sub(r"\s*#.*$", "", line).rstrip() for line in toml.splitlines()]
    return [line for line in lines if line]


def main():
    stiffmd = pathlib.Path(sys.argv[1]).resolve()
    found = blocks(TUTORIAL.read_text(encoding="utf-8"))
    deck = "\n".join(without_comments(DECK.read_text(encoding="utf-8")))
    for language, body in found:
        if language == "toml" and "\n".join(without_comments(body)) not in deck:
            print(f"FAIL: a toml excerpt of the tutorial is not in {DECK.name} as written:\n{body}")
            return 1
    runnable = [(language, body) for language, body in found if language in ("sh", "python")]
    if len(runnable) < 5:
        print(f"FAIL: only {len(runnable)} sh/python blocks found in {TUTORIAL}")
        return 1
    with tempfile.TemporaryDirectory(prefix="stiffmd_tutorial_") as tmp:
        root = pathlib.Path(tmp)
        (root / "build").mkdir()
        os.symlink(stiffmd, root / "build" / "stiffmd")
        for name in ("inputs", "tools"):
            os.symlink(ROOT / name, root / name)
        env = dict(os.environ, OMP_WAIT_POLICY="passive")
        for k, (language, body) in enumerate(runnable, 1):
            cmd = ["bash", "-euo", "pipefail", "-c", body] if language == "sh" else ["/usr/bin/python3", "-c", body]
            r = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True, timeout=600)
            print(f"--- block {k} ({language}): exit {r.returncode}\n{body.strip()}\n{r.stdout[-1500:]}")
            if r.returncode != 0:
                print(f"FAIL: block {k} exited {r.returncode}:\n{r.stderr[-3000:]}")
                return 1
    print(f"OK: {len(runnable)} blocks of {TUTORIAL.name} ran")
    return 0


if __name__ == "__main__":
    sys.exit(main())
