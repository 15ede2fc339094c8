#!/usr/bin/python3
"""Unit checks of tools/seed_statistics.py (the statistics of tools/trappe_pe.py and tools/cost_vs_eps.py).

Usage: test_seed_statistics.py   (no binary; < 1 s)

Checks the Student-t quantile against tabulated values (t_10 at the two-sided 0.0027 of 3σ ≈ 3.957,
and others from scipy.stats.t.isf 1.10, kept here so that another scipy's answer is checked too), the
limit tending to 3 for many degrees of freedom, and pooled_se / pooled_z / ensemble on a hand-worked
example.
"""
import math
import os
import sys

from checklist import finish, test

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tools"))
import seed_statistics as ss  # noqa: E402

P3 = math.erfc(3 / math.sqrt(2)) / 2  # the one-sided tail of a 3σ normal test, 0.00134990
# dof: x with P(T_dof > x) = P3 (scipy.stats.t.isf(P3, dof), scipy 1.10)
TABLE = {2: 19.20674421144558, 3: 9.218940458700201, 4: 6.620205978448286, 6: 4.904064673686163,
         10: 3.9569366600027562, 20: 3.4221512908691754}


@test
def t_quantile_matches_tabulated_values():
    for dof, x in TABLE.items():
        assert math.isclose(ss.t_quantile(P3, dof), x, rel_tol=1e-8), (dof, ss.t_quantile(P3, dof), x)
        assert math.isclose(ss.sigma_threshold(3.0, dof), x, rel_tol=1e-8), dof
    assert abs(ss.sigma_threshold(3.0, 10) - 3.957) < 5e-4
    # Two-sided 5 % with 10 degrees of freedom: 2.228 (every t table).
    assert abs(ss.t_quantile(0.025, 10) - 2.2281389) < 1e-6


@test
def many_degrees_of_freedom_give_the_normal_limit():
    assert abs(ss.t_quantile(P3, 1e7) - 3.0) < 1e-5
    assert abs(ss.sigma_threshold(2.0, 1e7) - 2.0) < 1e-5


@test
def pooled_standard_error_and_z_by_hand():
    a, b = [1.0, 2.0, 3.0], [2.0, 4.0, 6.0, 8.0]
    # s_a² = 1, s_b² = 20/3; s_p² = (2·1 + 3·20/3)/5 = 22/5; se = √(22/5 · (1/3 + 1/4)) = √(77/30)
    se = math.sqrt(77 / 30)
    assert math.isclose(ss.pooled_se(a, b), se, rel_tol=1e-12)
    assert math.isclose(ss.pooled_z(a, b), (2.0 - 5.0) / se, rel_tol=1e-12)
    assert ss.pooled_z([1.0, 1.0], [2.0, 2.0]) == -math.inf
    assert ss.pooled_z([1.0, 1.0], [1.0, 1.0]) == 0.0
    try:
        ss.pooled_se([1.0], [1.0, 2.0])
        raise AssertionError("a single seed was accepted")
    except ValueError:
        pass
    assert ss.within([1.0, -2.0], 2.0) and not ss.within([1.0, 2.5], 2.0) and not ss.within([float("nan")], 2.0)


@test
def ensemble_is_mean_and_s_over_root_k():
    runs = [{"x": 1.0, "t": 10.0}, {"x": 2.0, "t": 20.0}, {"x": 4.0, "t": 30.0}]
    e = ss.ensemble(runs, ("x",), averaged=("t",))
    s = math.sqrt(((1 - 7 / 3) ** 2 + (2 - 7 / 3) ** 2 + (4 - 7 / 3) ** 2) / 2)
    assert e["seeds"] == 3 and e["per_seed"]["x"] == [1.0, 2.0, 4.0] and e["t"] == 20.0
    assert math.isclose(e["x"][0], 7 / 3) and math.isclose(e["x"][1], s / math.sqrt(3))
    assert ss.ensemble(runs + [None], ("x",)) is None


finish()
