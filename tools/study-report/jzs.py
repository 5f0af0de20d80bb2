"""JZS Bayes factor of a one-sample or paired t test, and Jeffreys' evidence categories.

BF10 is Rouder et al. (2009), eq. 1, with the Cauchy prior on the effect size scaled by
rscale (R BayesFactor's ttestBF default "medium" = sqrt(2)/2). A paired design is the
one-sample test of the differences. The integral over g is taken on u = log g, where the
integrand is smooth and has a single mode, in log space so t = 10, n = 100 (BF ~ 1e13)
does not overflow.
"""
import math

import numpy as np

RSCALE_MEDIUM = math.sqrt(2) / 2


def _log_integrand(u, t, n, rscale):
    """log of the integrand of eq. 1 over u = log g (the dg = g du factor included),
    divided by the null likelihood (1 + t^2/nu)^(-(nu+1)/2)."""
    nu = n - 1
    a = 1.0 + n * rscale * rscale * math.exp(u)
    return (-0.5 * math.log(a)
            - 0.5 * (nu + 1) * (math.log1p(t * t / (a * nu)) - math.log1p(t * t / nu))
            - 0.5 * math.log(2 * math.pi) - 0.5 * u - 0.5 * math.exp(-u))


def log_bf10(t, n, rscale=RSCALE_MEDIUM):
    """Natural log of the JZS BF10 for a one-sample t statistic t from n observations."""
    if n < 2:
        raise ValueError(f"a t test needs at least 2 observations, got {n}")
    if not (rscale > 0 and math.isfinite(rscale)):
        raise ValueError(f"rscale must be positive, got {rscale}")
    if not math.isfinite(t):
        raise ValueError(f"t must be finite, got {t}")
    from scipy import integrate, optimize      # here: error paths of the tools stay quick
    f = lambda u: -_log_integrand(u, t, n, rscale)
    # the mode, first on a coarse grid (the integrand is unimodal in u), then refined
    grid = np.arange(-20.0, 40.0, 0.25)
    u0 = grid[int(np.argmin([f(u) for u in grid]))]
    mode = optimize.minimize_scalar(f, bounds=(u0 - 0.25, u0 + 0.25), method="bounded",
                                    options={"xatol": 1e-9}).x
    peak = -f(mode)
    # The integrand falls like exp(-exp(-u)/2) below the mode and like exp(-u) above it:
    # 40 units either side leave less than 1e-15 of the mass out.
    val, err = integrate.quad(lambda u: math.exp(-f(u) - peak), mode - 40, mode + 40,
                              points=[mode], epsabs=0, epsrel=1e-11, limit=400)
    return peak + math.log(val)


def bf10(t, n, rscale=RSCALE_MEDIUM):
    return math.exp(log_bf10(t, n, rscale))


def paired_t(x, y):
    """t statistic and n of the paired differences x - y."""
    d = np.asarray(x, float) - np.asarray(y, float)
    n = len(d)
    if n < 2:
        raise ValueError(f"a paired t test needs at least 2 pairs, got {n}")
    sd = d.std(ddof=1)
    if sd == 0:
        return (0.0 if d.mean() == 0 else math.copysign(math.inf, d.mean())), n
    return d.mean() / (sd / math.sqrt(n)), n


# Jeffreys (1961), with the labels of Lee & Wagenmakers (2013): (lower bound of BF10, label).
_CATEGORIES = [(100, "extreme evidence for H1"), (30, "very strong evidence for H1"),
               (10, "strong evidence for H1"), (3, "moderate evidence for H1"),
               (1, "anecdotal evidence for H1")]


def jeffreys_category(bf):
    """Evidence category of a BF10 (for H1 above 1, for H0 below 1, "no evidence" at 1)."""
    if bf == 1:
        return "no evidence"
    if bf > 1:
        for lo, label in _CATEGORIES:
            if bf > lo or lo == 1:
                return label
    inv = 1 / bf
    for lo, label in _CATEGORIES:
        if inv > lo or lo == 1:
            return label.replace("H1", "H0")
    raise AssertionError("unreachable")
