#!/usr/bin/env python3
"""The documentation says what is true of the repository.

    test_docs.py deck-keys   every key the deck parser reads is documented in docs/decks.md, and every
                             key documented there is read by the parser
    test_docs.py paths       every repository path named in README.md, ARCHITECTURE.md and docs/**.md
                             exists, and every `docs/design.md §N` cited anywhere names a section

Each check first runs on a copy with a known defect (a documented key removed, a path that does not
exist, a section that does not exist) and must find it, so that a checker that finds nothing fails.
Nothing is skipped silently: path-like text that is not a repository path must match one of the
EXTERNAL forms below, each with its reason, and the counts are printed."""
import glob
import os
import re
import subprocess
import sys

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

# ---------------------------------------------------------------------------------------------
# Deck keys

# The files that read deck keys (engine/scene/*.cpp: every section; the monitor reads [monitor]).
KEY_SOURCES = ["engine/scene/*.cpp", "engine/observe/monitor.cpp"]

# DeckTable's accessors (engine/deck/deck.hpp) whose first argument is a key.
ACCESSORS = ("number", "integer", "string", "name", "boolean", "vector3", "bool3", "integers", "strings",
             "numbers", "string_map", "value_lists", "table", "array_of_tables", "has", "has_retired", "maybe_number",
             "maybe_integer")

# Helpers that pass a key on to an accessor: name -> index of the key argument. A call of one of
# these with string literals in that argument reads those keys.
HELPERS = {
    "read": 1,            # force_registry.cpp: read(table, "key", kind[, fallback])
    "claim_types": 1,     # force_registry.cpp: claim_types(table, "bond_types", ...)
    "interval": 0,        # scene.cpp, read_output: interval("xyz_interval", fallback)
    "warn_if_longer": 0,  # scene.cpp, read_output
    "threshold": 0,       # monitor.cpp: threshold("violation", ...)
    "switchable": 0,      # monitor.cpp: switchable("energy_error", ...)
    r"finish_kspace<\w+>": 7,  # kspace_deck.cpp: finish_kspace<Term>(name, level, t, sc, real, charges, p, "kmax", ...)
}

# Accessor calls whose key is not a literal: (file name, the argument as written) -> where the
# keys it can take come from. Any other non-literal key is an error: this test could not see it.
INDIRECT_KEYS = {
    ("force_registry.cpp", "key"): "the helpers read and claim_types (HELPERS)",
    ("force_registry.cpp", "kind.types_key"): "TypeKind's bond_types, angle_types, dihedral_types, improper_types, "
                                              "read by claim_types",
    ("force_registry.cpp", "range_key"): "check_box_for_pairs: cutoff or sigma, read directly",
    ("scene.cpp", "key"): "the lambdas interval and warn_if_longer (HELPERS), check_initial_state's literal list",
    ("scene.cpp", "table"): "check_integrator's refused_at: observables and output, read directly",
    ("scene.cpp", "out.key"): "read_output's outputs whose options warn without them: h5md and state, read directly",
    ("monitor.cpp", "key"): "the lambdas threshold and switchable (HELPERS)",
    ("scene_sources.cpp", "file_key"): "lammps_data or xyz, read directly",
    ("kspace_deck.cpp", "key"): "read_triple's kmax and mesh, read at the callers' literal keys",
    ("scene_sources.cpp", "key"): "lookup's atom_types, bond_types, ... maps, read directly",
    ("thermostat_deck.cpp", "sc.types[k].name"): "[thermostat.scale] TYPE: a particle type name",
    ("thermostat_deck.cpp", "tb"): "[thermostat.scale] TYPE: a particle type name",
    ("part_load.cpp", "type_name"): "[thermostat.scale] TYPE: a particle type name, as thermostat_deck.cpp reads it",
    ("stage_deck.cpp", "key"): "kSceneKeys and kStageTables: top-level tables, each documented in its section",
}

# Placeholders the reference uses for names the deck chooses.
PLACEHOLDERS = {"NAME", "TYPE"}

# Keys the extractor must find (one per form it handles): if a form stops being recognised, the
# test fails here instead of passing with fewer keys.
SENTINELS = {"units": "accessor", "D0": "read helper", "A3": "read over a literal array", "bond_types":
             "claim_types", "xyz_interval": "interval lambda", "energy_runaway": "switchable lambda",
             "action_drift": "threshold lambda", "checkpoint_every": "has_retired", "scale": "table accessor"}

STRING = re.compile(r'"((?:[^"\\]|\\.)*)"')


def strip_comments(text):
    """C++ source without // and /* */ comments (string literals kept)."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if c == '"' or c == "'":
            j = i + 1
            while j < n and text[j] != c:
                j += 2 if text[j] == "\\" else 1
            out.append(text[i:j + 1])
            i = j + 1
        elif text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            i = n if j < 0 else j + 2
        else:
            out.append(c)
            i += 1
    return "".join(out)


def call_arguments(text, open_paren):
    """The top-level arguments of the call whose '(' is at open_paren, as written."""
    args, depth, start, i = [], 0, open_paren + 1, open_paren
    pairs = {"(": ")", "[": "]", "{": "}"}
    stack = []
    while i < len(text):
        c = text[i]
        if c in "\"'":
            j = i + 1
            while j < len(text) and text[j] != c:
                j += 2 if text[j] == "\\" else 1
            i = j + 1
            continue
        if c in pairs:
            stack.append(pairs[c])
        elif stack and c == stack[-1]:
            stack.pop()
            if not stack:
                args.append(text[start:i].strip())
                return args
        elif c == "," and len(stack) == 1:
            args.append(text[start:i].strip())
            start = i + 1
        i += 1
    return args


def line_of(text, pos):
    return text.count("\n", 0, pos) + 1


def parser_keys(root):
    """{key: [file:line, ...]} of every key the deck parser reads, and the problems found."""
    keys, problems = {}, []
    files = sorted(f for pattern in KEY_SOURCES for f in glob.glob(os.path.join(root, pattern)))
    if not files:
        problems.append("no source files match " + ", ".join(KEY_SOURCES))
    for path in files:
        name = os.path.basename(path)
        with open(path, encoding="utf-8") as f:
            # std::array<const char*, 5>{"A1", …}[n]: the template's comma is not an argument's.
            code = re.sub(r"std::array<[^<>]*>", "std::array", strip_comments(f.read()))
        found = 0

        def add(literals, pos):
            nonlocal found
            for k in literals:
                keys.setdefault(k, []).append(f"{os.path.relpath(path, root)}:{line_of(code, pos)}")
                found += 1

        for m in re.finditer(r"(?:\.|->)(" + "|".join(ACCESSORS) + r")\s*\(", code):
            args = call_arguments(code, m.end() - 1)
            if not args or not args[0]:
                continue
            literals = STRING.findall(args[0])
            if literals:
                add(literals, m.start())
            elif (name, args[0]) not in INDIRECT_KEYS:
                problems.append(f"{os.path.relpath(path, root)}:{line_of(code, m.start())}: {m.group(1)}({args[0]}, …) "
                                "reads a key this test cannot see; add its form to HELPERS or INDIRECT_KEYS")
        for helper, index in HELPERS.items():
            for m in re.finditer(r"(?<![\w.>:])" + helper + r"\s*\(", code):
                args = call_arguments(code, m.end() - 1)
                if len(args) > index:
                    add(STRING.findall(args[index]), m.start())
        # for (const char* key : {"a", "b"}) t.has(key): a literal list of keys.
        for m in re.finditer(r"for\s*\(\s*const\s+char\s*\*\s*key\s*:\s*\{([^}]*)\}", code):
            add(STRING.findall(m.group(1)), m.start())
        if found == 0 and "DeckTable" in code:
            problems.append(f"{os.path.relpath(path, root)}: reads a DeckTable, but no deck key found")
    for key, form in SENTINELS.items():
        if key not in keys:
            problems.append(f"the extractor no longer finds '{key}' ({form})")
    return keys, problems


def documented_keys(doc_text):
    """Keys the reference documents: the backticked names in the first cell of a table row, split
    at dots (`bond_types.TYPE`), and the names in section headings ([forces.NAME], [[build]])."""
    keys = set()
    for line in doc_text.splitlines():
        if line.startswith("|") and not re.match(r"\|\s*-", line):
            first = line.split("|")[1]
            for token in re.findall(r"`([^`]+)`", first):
                keys.update(part.strip("[] ") for part in token.split("."))
        elif line.startswith("#"):
            for token in re.findall(r"\[+([\w.\-]+)\]+", line):
                keys.update(token.split("."))
    keys.discard("")
    return keys


def deck_key_problems(root, doc_text):
    keys, problems = parser_keys(root)
    documented = documented_keys(doc_text)
    for key in sorted(keys):
        if key not in documented:
            problems.append(f"docs/decks.md lacks the key '{key}' (read at {', '.join(keys[key][:3])})")
    for key in sorted(documented - set(keys) - PLACEHOLDERS):
        if re.fullmatch(r"[A-Za-z_][\w-]*", key) and "-" not in key:
            problems.append(f"docs/decks.md documents '{key}', which the parser does not read")
    return keys, problems


def check_deck_keys():
    with open(os.path.join(ROOT, "docs", "decks.md"), encoding="utf-8") as f:
        doc = f.read()
    keys, problems = deck_key_problems(ROOT, doc)
    assert not problems, "\n".join(problems)
    # The checker finds a key whose row is removed, and a documented key nobody reads.
    for key in ("energy_runaway", "A3", "checkpoint_interval"):
        mutated = "\n".join(l for l in doc.splitlines() if not l.startswith(f"| `{key}`"))
        assert mutated != doc, f"docs/decks.md has no row for {key}"
        _, found = deck_key_problems(ROOT, mutated)
        assert any(f"lacks the key '{key}'" in p for p in found), f"removing {key}'s row went unnoticed: {found}"
    _, found = deck_key_problems(ROOT, doc + "\n| `no_such_key` | number | — | 1 | nothing |\n")
    assert any("'no_such_key'" in p for p in found), found
    print(f"deck keys: {len(keys)} read by the parser, all documented in docs/decks.md")


# ---------------------------------------------------------------------------------------------
# Paths

TOP_DIRS = ("core", "engine", "forcefields", "integrators", "inputs", "tests", "tools", "docs", "python", "cmake")
TOP_FILES = ("README.md", "ARCHITECTURE.md", "CMakeLists.txt")
EXTENSIONS = ("md", "cpp", "hpp", "h", "py", "sh", "toml", "txt", "csv", "png", "json", "data", "in", "xyz",
              "h5", "h5md", "cmake", "bin", "gz", "log", "xml")

# Path-like text that is not a path in this repository, each form with its reason.
EXTERNAL = [
    (r"^/", "an absolute path on the user's machine (system files, /tmp)"),
    (r"^https?://", "a web address"),
    (r"^(build|out|sweeps)/", "a build or run output directory, made by the commands"),
    (r"^(DIR|OUT)/", "a directory the user chooses"),
    (r"^src/", "a file of LAMMPS's source"),
]


def path_candidates(text):
    """(path, kind) of every path-like token: backticked spans, link targets and bare text."""
    found = []
    code_spans = re.findall(r"`([^`\n]+)`", text)
    prose = re.sub(r"`[^`\n]+`", " ", text)
    for target in re.findall(r"\]\(([^)\s]+)\)", prose):
        found.append((target, "link"))
    token = r"[A-Za-z0-9_.*+<>/{}\-]+"
    for span in code_spans:
        for t in re.findall(token, span):
            found.append((t, "code"))
    prose = re.sub(r"\]\([^)\s]+\)", "]", prose)  # link targets are taken above
    for t in re.findall(r"(?<![\w./\-])" + token, prose):
        found.append((t, "text"))
    out = []
    for t, kind in found:
        t = t.rstrip(".,:;")
        if kind == "link":
            if t.startswith("#") or re.match(r"^[a-z]+:", t):
                continue
            out.append((t.split("#")[0], kind))
            continue
        if "/" not in t:
            continue
        first = t.split("/")[0]
        ext = re.search(r"\.([A-Za-z0-9]+)$", t)
        if first in TOP_DIRS or first in TOP_FILES or (ext and ext.group(1) in EXTENSIONS):
            out.append((t, kind))
    return out


def path_exists(root, doc_dir, path, kind):
    base = doc_dir if kind == "link" else root
    if "<" in path or "{" in path:  # a template such as forcefields/<term>.hpp: its directory
        path = path[: min(i for i in (path.find("<"), path.find("{")) if i >= 0)]
        path = path[: path.rfind("/") + 1]
    full = os.path.normpath(os.path.join(base, path))
    if "*" in path:
        return bool(glob.glob(full))
    return os.path.exists(full)


def path_problems(root, docs):
    problems, checked, external = [], 0, {}
    for doc in docs:
        with open(doc, encoding="utf-8") as f:
            text = f.read()
        rel = os.path.relpath(doc, root)
        for path, kind in path_candidates(text):
            reason = next((why for pattern, why in EXTERNAL if re.search(pattern, path)), None)
            if reason and kind != "link":
                external.setdefault(reason, set()).add(path)
                continue
            first = path.split("/")[0]
            if kind != "link" and first not in TOP_DIRS and first not in TOP_FILES:
                problems.append(f"{rel}: '{path}' looks like a path but is in no repository directory; "
                                "fix it or add its form to EXTERNAL")
                continue
            checked += 1
            if not path_exists(root, os.path.dirname(doc), path, kind):
                problems.append(f"{rel}: '{path}' does not exist")
    return problems, checked, external


def design_sections(root):
    with open(os.path.join(root, "docs", "design.md"), encoding="utf-8") as f:
        text = f.read()
    sections = set(re.findall(r"^## §(\d+) ", text, re.M))
    anchors = set(re.findall(r'<a id="s(\d+)"></a>', text))
    rules = set()
    part = text.split('<a id="s11"></a>')[-1]
    for n in re.findall(r"^(\d+)\. ", part, re.M):
        rules.add("11." + n)
    return sections, anchors, rules


def citation_problems(root, files):
    sections, anchors, rules = design_sections(root)
    problems, count = [], 0
    if sections != anchors:
        problems.append(f"docs/design.md: sections {sorted(sections)} and anchors {sorted(anchors)} differ")
    for path in files:
        try:
            with open(os.path.join(root, path), encoding="utf-8") as f:
                text = f.read()
        except (UnicodeDecodeError, FileNotFoundError):
            continue
        for m in re.finditer(r"docs/design\.md (§[\d.a-c§–\-, ]+)", text):
            for ref in re.findall(r"§(\d+(?:\.\d+)?)", m.group(1)):
                count += 1
                ok = ref in rules if "." in ref else ref in sections
                if not ok:
                    problems.append(f"{path}:{line_of(text, m.start())}: cites docs/design.md §{ref}, which does not exist")
    return problems, count


def tracked_files(root):
    r = subprocess.run(["git", "-C", root, "ls-files"], capture_output=True, text=True)
    if r.returncode == 0 and r.stdout.strip():
        return r.stdout.split()
    # Not a git checkout (a source tarball): every file under the code directories.
    return [os.path.relpath(os.path.join(d, f), root) for top in TOP_DIRS
            for d, _, fs in os.walk(os.path.join(root, top)) for f in fs]


def check_paths():
    docs = [os.path.join(ROOT, f) for f in TOP_FILES if f.endswith(".md")]
    docs += sorted(glob.glob(os.path.join(ROOT, "docs", "**", "*.md"), recursive=True))
    problems, checked, external = path_problems(ROOT, docs)
    cites, cited = citation_problems(ROOT, tracked_files(ROOT))
    assert not problems + cites, "\n".join(problems + cites)
    # The checker finds a missing path in each form, and a citation of a section that does not exist.
    import tempfile
    d = tempfile.mkdtemp(prefix="docs_paths_")
    os.makedirs(os.path.join(d, "docs"))
    os.makedirs(os.path.join(d, "engine", "run"))
    open(os.path.join(d, "engine", "run", "checkpoint.hpp"), "w").close()
    bad = os.path.join(d, "docs", "bad.md")
    with open(bad, "w") as f:
        f.write("`engine/checkpoint.*`, engine/whole_molecules.cpp and [x](missing.png) and "
                "`engine/run/checkpoint.*` and `foo/bar.cpp`\n")
    found, n, _ = path_problems(d, [bad])
    for want in ("'engine/checkpoint.*' does not exist", "'engine/whole_molecules.cpp' does not exist",
                 "'missing.png' does not exist", "'foo/bar.cpp' looks like a path"):
        assert any(want in p for p in found), (want, found)
    assert n == 4 and len(found) == 4, (n, found)
    with open(os.path.join(d, "docs", "design.md"), "w") as f:
        f.write('<a id="s1"></a>\n## §1 One\n')
    with open(os.path.join(d, "engine", "run", "checkpoint.hpp"), "w") as f:
        f.write("// docs/design.md §1 and docs/design.md §2\n")
    found, _ = citation_problems(d, ["engine/run/checkpoint.hpp"])
    assert len(found) == 1 and "§2, which does not exist" in found[0], found
    print(f"paths: {checked} repository paths in {len(docs)} documents exist; {cited} citations of "
          f"docs/design.md name existing sections; not repository paths:")
    for reason, paths in sorted(external.items()):
        print(f"  {reason}: {', '.join(sorted(paths))}")


def main():
    what = sys.argv[1] if len(sys.argv) > 1 else "all"
    if what in ("deck-keys", "all"):
        check_deck_keys()
    if what in ("paths", "all"):
        check_paths()
    if what not in ("deck-keys", "paths", "all"):
        sys.exit("usage: test_docs.py [deck-keys | paths | all]")


if __name__ == "__main__":
    main()
