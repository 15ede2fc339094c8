#!/usr/bin/python3
"""Unit checks of tools/engines.py, the library the benchmark tools share to run stiffmd and LAMMPS.

Usage: test_engines_tool.py   (no binary; < 1 s)

Checks whole_steps_t_end's rounding (a multiple of h stays, anything else goes up to the next
multiple), the thermo parser on tiny files (types, column names and order, a row cut short, an empty
run, a missing file), the command lines, the run environment, and run_stiffmd's handling of exit codes.
"""
import math
import os
import sys
import tempfile

from checklist import finish, test

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tools"))
import engines  # noqa: E402


@test
def whole_steps_t_end_rounds_up_to_a_multiple_of_h():
    assert engines.whole_steps_t_end(10, 0.25) == "10.0"
    assert engines.whole_steps_t_end("1", "0.1") == repr(10 * 0.1)  # 1/0.1 is 10 up to an ulp: not 11 steps
    assert engines.whole_steps_t_end(1.0, 0.3) == repr(4 * 0.3)
    assert engines.whole_steps_t_end(5, 1 / 3) == repr(15 * (1 / 3))
    assert float(engines.whole_steps_t_end(100, 1 / 256)) == 100.0


def write(text):
    fd, path = tempfile.mkstemp(suffix=".csv")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    return path


@test
def read_thermo_gives_float_columns_in_header_order():
    path = write("step,time,total,potential_fast-bonds,action_1\n0,0,-1.5,2,nan\n10,0.5,-1.25,3,inf\n")
    try:
        th = engines.read_thermo(path)
    finally:
        os.remove(path)
    assert list(th) == ["step", "time", "total", "potential_fast-bonds", "action_1"], list(th)
    assert th["step"].dtype == float and th["step"].shape == (2,)
    assert list(th["total"]) == [-1.5, -1.25]
    assert math.isnan(th["action_1"][0]) and math.isinf(th["action_1"][1])


@test
def read_thermo_one_row_and_no_rows_give_1d_arrays():
    path = write("step,time\n0,0\n")
    try:
        assert engines.read_thermo(path)["time"].shape == (1,)
    finally:
        os.remove(path)
    path = write("step,time\n")
    try:
        th = engines.read_thermo(path)
    finally:
        os.remove(path)
    assert list(th) == ["step", "time"] and th["time"].shape == (0,)


@test
def read_thermo_stops_at_a_row_cut_short():
    for last in ("20,1.0", "20,1.0,-"):
        path = write("step,time,total\n0,0,-1.5\n10,0.5,-1.25\n" + last)
        try:
            th = engines.read_thermo(path)
        finally:
            os.remove(path)
        assert list(th["step"]) == [0.0, 10.0], (last, th)


@test
def read_thermo_missing_file():
    missing = os.path.join(tempfile.gettempdir(), "engines_test_no_such_dir", "thermo.csv")
    assert engines.read_thermo(missing, missing_ok=True) == {}
    try:
        engines.read_thermo(missing)
    except FileNotFoundError:
        pass
    else:
        raise AssertionError("a missing thermo.csv must raise without missing_ok")


@test
def command_lines():
    assert engines.stiffmd_command("sm", "d.toml", "out", ["a=1", "b=2"]) == \
        ["sm", "run", "d.toml", "-o", "out", "--no-progress", "--set", "a=1", "--set", "b=2"]
    assert engines.lammps_command("lmp", "in.x", "log") == \
        ["lmp", "-in", "in.x", "-log", "log", "-screen", "none", "-echo", "none", "-nocite"]
    assert engines.lammps_command("lmp", "in.x", "log", echo=True) == \
        ["lmp", "-in", "in.x", "-log", "log", "-screen", "none", "-nocite"]


@test
def engine_env_threads():
    os.environ["OMP_NUM_THREADS"] = "7"
    os.environ.pop("OMP_WAIT_POLICY", None)
    assert engines.engine_env(1)["OMP_NUM_THREADS"] == "1"
    assert engines.engine_env(None)["OMP_NUM_THREADS"] == "7"
    assert engines.engine_env(2)["OMP_WAIT_POLICY"] == "passive"
    os.environ["OMP_WAIT_POLICY"] = "active"
    assert engines.engine_env(2)["OMP_WAIT_POLICY"] == "active"


@test
def run_stiffmd_exit_codes():
    # A script stands in for the binary, stopping as stiffmd does on a numerical failure.
    fd, script = tempfile.mkstemp(suffix=".sh")
    with os.fdopen(fd, "w") as f:
        f.write('#!/bin/sh\necho "error: it blew up" >&2\nexit 3\n')
    os.chmod(script, 0o755)
    try:
        r = engines.run_stiffmd(script, "deck.toml", "out", ["x=1"], accept=(0, 3))
        assert r.code == 3 and "blew up" in r.stderr, r
        assert r.cmd[-2:] == ["--set", "x=1"], r.cmd
        try:
            engines.run_stiffmd(script, "deck.toml", "out")
        except engines.RunFailed as e:
            assert "exit 3" in str(e) and "blew up" in str(e), e
        else:
            raise AssertionError("exit 3 outside accept must raise RunFailed")
        messages = []
        engines.run_stiffmd(script, "deck.toml", "out", fail=messages.append)
        assert len(messages) == 1 and messages[0].startswith("stiffmd failed (exit 3)"), messages
    finally:
        os.remove(script)
    r = engines.run_engine(["/bin/sh", "-c", "sleep 5"], timeout=0.2)
    assert r.code == engines.TIMEOUT, r


if __name__ == "__main__":
    finish()
