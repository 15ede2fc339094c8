#!/usr/bin/python3
"""A faulty LAMMPS data file on N ranks stops every rank with exit 2 and one process's message
(run by ctest, label mpi; docs/parallel.md, "The scene's description"):

    test_data_file_faults.py STIFFMD MPIEXEC NUMPROC_FLAG N CASE

On several ranks a deck whose particles all come from a data file runs on the scene's description:
no rank reads the file whole. Every rank reads the file's structure (its header, masses, every
line's ids, types and atoms) for the description, and its block of molecules for its part; a fault
in a line only one rank reads whole is agreed (every rank exits 2, rank 0 prints the lowest failing
rank's message). Each CASE is inputs/half_melt.toml with one fault put into a copy of
inputs/half_melt.data; the N-rank run must exit 2 within LIMIT seconds and print what one process
prints (which reads the file whole), but for a "rank R: " before it:

    coordinate      the last atom's x is "1.2.3" (read only by the last rank's block)
    image_flag      the last atom's image flag is "x" (the last rank's block)
    velocity        the last atom's velocity is "nan?" (the last rank's block)
    missing_atom    a bond names atom id 99999 (the structure: every rank)
    duplicate_id    two atoms share an id (the structure)
    atom_type       an atom of type 2 of a file that declares 1 atom type (the structure)
    bond_type       a bond of type 3 of a file that declares 1 bond type (the structure)
    duplicate_bond  the last bond given twice (the last rank's block)
    long_bond       the last atom's image flag moved by one box length: its bond spans the box
                    (the last rank's block, as the molecule is made whole)
    zero_bond       the last atom placed on its bonded neighbour (the last rank's block)
    fene_stretch    the last atom moved 1.6 along x: its FENE bond beyond R0 in the initial state
                    (the last rank's block, its bonded terms evaluated on it)
    unnamed_type    the last atom of a second atom type that atom_types does not name (the
                    structure, then the deck's map)
"""
import os
import re
import subprocess
import sys
import tempfile

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
DECK = os.path.join(ROOT, "inputs", "half_melt.toml")
DATA = os.path.join(ROOT, "inputs", "half_melt.data")
LIMIT = 120  # seconds


def environment():
    return dict(os.environ, OMP_NUM_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
                OMPI_MCA_rmaps_base_oversubscribe="1")


def sections(lines):
    """The index of each section keyword's line, and of its entries (the non-blank lines after it)."""
    at = {}
    for k, line in enumerate(lines):
        name = line.split("#")[0].strip()
        if name and not name[0].isdigit() and not name[0] == "-" and k > 0 and not name.endswith(("xhi", "yhi", "zhi")):
            entries = []
            j = k + 1
            while j < len(lines) and not lines[j].strip():
                j += 1
            while j < len(lines) and lines[j].strip():
                entries.append(j)
                j += 1
            at[name] = entries
    return at


def faulty(case, lines):
    at = sections(lines)
    atoms, bonds, velocities = at["Atoms"], at["Bonds"], at["Velocities"]
    last = atoms[-1]
    w = lines[last].split()  # id mol type x y z ix iy iz
    if case == "coordinate":
        w[3] = "1.2.3"
    elif case == "image_flag":
        w[8] = "x"
    elif case == "velocity":
        v = lines[velocities[-1]].split()
        v[2] = "nan?"
        lines[velocities[-1]] = " ".join(v)
        return lines
    elif case == "missing_atom":
        b = lines[bonds[0]].split()
        b[3] = "99999"
        lines[bonds[0]] = " ".join(b)
        return lines
    elif case == "duplicate_id":
        w[0] = lines[atoms[-2]].split()[0]
    elif case == "atom_type":
        w[2] = "2"
    elif case == "bond_type":
        b = lines[bonds[-1]].split()
        b[1] = "3"
        lines[bonds[-1]] = " ".join(b)
        return lines
    elif case == "duplicate_bond":
        lines.insert(bonds[-1] + 1, lines[bonds[-1]])
        n = [k for k, l in enumerate(lines) if l.strip().endswith(" bonds")][0]
        lines[n] = str(int(lines[n].split()[0]) + 1) + " bonds"
        b = lines[bonds[-1] + 1].split()
        b[0] = str(int(b[0]) + 1)
        lines[bonds[-1] + 1] = " ".join(b)
        return lines
    elif case == "long_bond":
        w[6] = str(int(w[6]) + 1)
    elif case == "fene_stretch":
        w[3] = repr(float(w[3]) + 1.6)
    elif case == "zero_bond":
        w[3:6] = lines[atoms[-2]].split()[3:6]
        w[6:9] = lines[atoms[-2]].split()[6:9]
    elif case == "unnamed_type":
        w[2] = "2"
        n = [k for k, l in enumerate(lines) if l.strip().endswith("atom types")][0]
        lines[n] = "2 atom types"
        lines[last] = " ".join(w)
        lines.insert(at["Pair Coeffs"][-1] + 1, "2 1 1 1.12")  # before the Atoms, from the bottom up
        lines.insert(at["Masses"][-1] + 1, "2 1")
        return lines
    else:
        raise SystemExit("unknown case " + case)
    lines[last] = " ".join(w)
    return lines


def error_line(stderr):
    found = [l for l in stderr.splitlines() if l.startswith("error: ")]
    return found[0] if found else ""


def main():
    stiffmd, mpiexec, numproc_flag, n, case = sys.argv[1:6]
    with open(DATA) as f:
        lines = f.read().splitlines()
    with tempfile.TemporaryDirectory() as tmp:
        data = os.path.join(tmp, "faulty.data")
        with open(data, "w") as f:
            f.write("\n".join(faulty(case, lines)) + "\n")
        sets = ["--set", 'import.lammps_data="%s"' % data, "--set", "run.t_end=0.05", "-q", "--no-progress"]
        one = subprocess.run([stiffmd, "run", DECK, "-o", os.path.join(tmp, "one")] + sets, capture_output=True,
                             text=True, timeout=LIMIT, env=environment())
        many = subprocess.run([mpiexec, numproc_flag, n, stiffmd, "run", DECK, "-o", os.path.join(tmp, "many")] + sets,
                              capture_output=True, text=True, timeout=LIMIT, env=environment())
    print("one process:", one.returncode, error_line(one.stderr))
    print(n, "ranks:", many.returncode, error_line(many.stderr))
    ok = one.returncode == 2 and many.returncode == 2
    whole = error_line(one.stderr)
    said = re.sub(r"^error: rank \d+: ", "error: ", error_line(many.stderr))
    ok = ok and whole != "" and said == whole
    # Said once, by rank 0.
    ok = ok and sum(l.startswith("error: ") for l in many.stderr.splitlines()) == 1
    if not ok:
        print("FAILED: expected exit 2 on both and the one process's message\n" + many.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
