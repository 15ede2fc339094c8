"""Statistics of settings run with independent thermostat seeds from one common start, shared by
tools/trappe_pe.py and tools/cost_vs_eps.py.

A setting (a method at a step) runs K seeds from the same state for the same length; a run's value
of an observable is its time average, one draw of a random variable whose law any correct sampler
of the same dynamics from that start reproduces. The setting's value is the mean over its seeds,
its error the seed-to-seed spread: honest whatever the observable's relaxation time, unlike block
errors within one run of a drifting series.

  ensemble(per_seed, observables)   per observable the mean over seeds, s/√K and the per-seed values
  pooled_se(a, b), pooled_z(a, b)   the two-sample (pooled-variance) standard error of mean(a) − mean(b)
                                    and that difference over it: Student's t with K_a + K_b − 2
                                    degrees of freedom when both samples are normal with one variance
  t_quantile(p, dof)                x with P(T_dof > x) = p (scipy.stats.t.isf)
  sigma_threshold(sigma, dof)       the |t| limit with the two-sided false-alarm rate of a sigma-σ
                                    normal test: 2 Φ(−sigma) (0.0027 at 3σ)
"""
import math

import numpy as np


def ensemble(per_seed, observables, averaged=()):
    """A setting's statistics from its runs with independent seeds (dicts with the observables): per
    observable [mean over seeds, s/√K], the per-seed values under "per_seed", the means of the keys
    `averaged` (e.g. the temperature, the CPU seconds); None when any seed blew up (None)."""
    if any(r is None for r in per_seed):
        return None
    k = len(per_seed)
    out = {"seeds": k, "per_seed": {o: [r[o] for r in per_seed] for o in observables}}
    for key in averaged:
        out[key] = float(np.mean([r[key] for r in per_seed]))
    for o in observables:
        v = np.array(out["per_seed"][o], dtype=float)
        out[o] = [float(v.mean()), float(v.std(ddof=1) / math.sqrt(k)) if k > 1 else float("nan")]
    return out


def pooled_se(a, b):
    """The standard error of mean(a) − mean(b) from the pooled variance,
    s_p² = ((K_a−1) s_a² + (K_b−1) s_b²) / (K_a + K_b − 2), se = s_p √(1/K_a + 1/K_b)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    k, kr = len(a), len(b)
    if k < 2 or kr < 2:
        raise ValueError(f"pooled_se: need at least 2 values per sample, got {k} and {kr}")
    sp2 = ((k - 1) * a.var(ddof=1) + (kr - 1) * b.var(ddof=1)) / (k + kr - 2)
    return math.sqrt(sp2 * (1.0 / k + 1.0 / kr))


def pooled_z(a, b):
    """(mean(a) − mean(b)) / pooled_se(a, b); ±inf for a nonzero difference of two constant samples."""
    se = pooled_se(a, b)
    d = float(np.mean(a) - np.mean(b))
    return d / se if se > 0 else (0.0 if d == 0 else math.copysign(math.inf, d))


# ------------------------------------------------------------------------- Student's t quantile

def t_quantile(p, dof):
    """x with P(T_dof > x) = p (scipy.stats.t.isf; python3-scipy is installed by tools/setup.sh)."""
    from scipy.stats import t
    return float(t.isf(p, dof))


def sigma_threshold(sigma, dof):
    """The |t| limit whose two-sided tail probability under Student's t with dof degrees of freedom is
    that of a sigma-σ normal test, 2 Φ(−sigma) = erfc(sigma/√2) (0.0027 at 3σ): the limit that makes
    "sigma σ" keep its false-alarm rate when the error is estimated from dof degrees of freedom."""
    return t_quantile(0.5 * math.erfc(sigma / math.sqrt(2.0)), dof)


def within(zs, limit):
    """Every |z| ≤ limit (a NaN fails)."""
    return all(abs(z) <= limit for z in zs)
