"""The segregation flux measured in a particle run's transient, and T-eq. (27)'s two rates from it.

Thornton et al. T-eq. (27) in z (no variation along the slope, no bulk normal velocity) says the
small particles' volume flux through the level z is

    J(z, t) = - c(z) [ S phi (1 - phi) + D_r dphi/dz ]        (upward positive)

with phi the small particles' share of the solid volume, c the solid volume fraction, S the
segregation velocity scale and D_r the remixing diffusivity.  The steady profile (T-eq. 28)
fixes only their ratio Ps = S h / D_r; the time a mixed layer takes to segregate needs one of
them.  granflow's model (:func:`granflow.continuum.segregation_layer`) takes D_r to be the
tagged particles' self-diffusivity (:mod:`granflow.coarse.diffusion`) and S = Ps D / h.

Here both are measured *directly* from the transient of a run recorded with tracers
(:class:`granflow.coarse.diffusion.TracerObserver`: z and diameter of every flow particle at a
fixed interval), without the steady profile and without the self-diffusivity:

* :func:`concentration_fields`: at each sample and on a z grid, the small-particle volume below
  z per unit base area, C(z, t) = sum_small v_i H(z - z_i) / A (H smoothed to an error function
  of ``width``), and the Gaussian coarse-grained small and total solid volume fractions
  c phi and c (Weinhart et al. 2012 Eq. 13 with the particle volume for the mass);
* :func:`fit_segregation_flux`: mass conservation in z gives J = -dC/dt exactly (no flux
  through the base); J / c is regressed on (-phi (1 - phi), -dphi/dz) over the interior levels
  and the transient's samples (ordinary least squares); standard errors from contiguous time
  blocks (batch means).  The explained variance says how much of the measured flux T-eq. (27)'s
  form accounts for.

Nondimensional units (d = g = m = 1): S in d / (d/g)^(1/2), D_r in d^2 / (d/g)^(1/2).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import erf

FLUX_EQ = "J = -c (S phi (1 - phi) + D_r dphi/dz) (Thornton et al. T-eq. 27 in z)"


def concentration_fields(z, diameter, z_grid, *, area: float, width: float = 0.5):
    """C (small volume below each level per base area), c phi and c on ``z_grid`` for heights
    ``z`` of shape (samples, particles); the small particles are those of the smallest diameter.

    Returns three arrays of shape (samples, levels)."""
    z = np.atleast_2d(np.asarray(z, float))
    d = np.asarray(diameter, float)
    zg = np.asarray(z_grid, float)
    if z.shape[1] != d.size:
        raise ValueError(f"z has {z.shape[1]} particles, diameter {d.size}")
    if not (math.isfinite(area) and area > 0):
        raise ValueError(f"area = {area!r} is out of range: allowed (0, inf)")
    if not (math.isfinite(width) and width > 0):
        raise ValueError(f"width = {width!r} is out of range: allowed (0, inf)")
    v = math.pi / 6.0 * d ** 3
    small = d <= d.min() * (1.0 + 1e-9)
    vs = np.where(small, v, 0.0)
    cum = np.empty((z.shape[0], zg.size))
    ns = np.empty_like(cum)
    n = np.empty_like(cum)
    norm = 1.0 / (math.sqrt(2.0 * math.pi) * width * area)
    for k, zk in enumerate(z):
        u = (zg[:, None] - zk[None, :]) / width
        cum[k] = 0.5 * (1.0 + erf(u / math.sqrt(2.0))) @ vs / area
        ker = np.exp(-0.5 * u * u) * norm
        ns[k] = ker @ vs
        n[k] = ker @ v
    return cum, ns, n


def fit_segregation_flux(t, z_grid, cum_small, c_small, c_all, *, lag: float, t_from: float,
                         t_to: float, n_blocks: int = 8) -> dict:
    """S and D_r of T-eq. (27) regressed on the flux J = -dC/dt (module docstring).

    ``t`` sample times (uniform), ``z_grid`` the levels (only those given are used: pass the
    interior), the fields of :func:`concentration_fields`; ``lag``: the half-width of the
    central time difference (and of the window the fields are averaged over); only samples
    whose window lies in [t_from, t_to] are used.  Returns S, D_r, their stderrs, the
    explained variance r2 of J / c, the Peclet number S h / D_r per unit depth (``S_over_D``)
    and the counts."""
    t = np.asarray(t, float)
    zg = np.asarray(z_grid, float)
    C, cs, ca = (np.asarray(a, float) for a in (cum_small, c_small, c_all))
    if C.shape != (t.size, zg.size) or cs.shape != C.shape or ca.shape != C.shape:
        raise ValueError("fields must have shape (samples, levels) = "
                         f"({t.size}, {zg.size})")
    if t.size < 3:
        raise ValueError(f"too few samples: {t.size}")
    dt = float(np.median(np.diff(t)))
    k = int(round(lag / dt))
    if k < 1:
        raise ValueError(f"lag = {lag!r} is out of range: allowed >= the sample interval {dt:g}")
    if n_blocks < 2:
        raise ValueError(f"n_blocks = {n_blocks} is out of range: allowed >= 2")
    centres = [i for i in range(k, t.size - k)
               if t[i - k] >= t_from - 1e-9 and t[i + k] <= t_to + 1e-9]
    if len(centres) < n_blocks:
        raise ValueError(f"[{t_from:g}, {t_to:g}] holds {len(centres)} samples with a window of "
                         f"+-{lag:g}: need at least n_blocks = {n_blocks}")
    rows_X, rows_y = [], []
    for i in centres:
        J = -(C[i + k] - C[i - k]) / (t[i + k] - t[i - k])
        c_s = cs[i - k:i + k + 1].mean(axis=0)
        c_a = ca[i - k:i + k + 1].mean(axis=0)
        phi = c_s / c_a
        rows_X.append(np.column_stack([-phi * (1.0 - phi), -np.gradient(phi, zg)]))
        rows_y.append(J / c_a)
    X = np.stack(rows_X)              # (samples, levels, 2)
    y = np.stack(rows_y)              # (samples, levels)

    def ols(sel):
        XX = X[sel].reshape(-1, 2)
        yy = y[sel].reshape(-1)
        coef = np.linalg.lstsq(XX, yy, rcond=None)[0]
        return coef, XX, yy

    coef, XX, yy = ols(slice(None))
    resid = yy - XX @ coef
    total = float(np.sum((yy - yy.mean()) ** 2))
    r2 = 1.0 - float(resid @ resid) / total if total > 0 else math.nan
    blocks = np.array_split(np.arange(len(centres)), int(n_blocks))
    per = np.array([ols(b)[0] for b in blocks])
    se = per.std(axis=0, ddof=1) / math.sqrt(len(blocks))
    S, D = (float(c) for c in coef)
    return {"S": S, "S_stderr": float(se[0]), "D_r": D, "D_r_stderr": float(se[1]),
            "S_over_D": S / D if D != 0 else math.nan, "r2": r2,
            "n_samples": len(centres), "n_levels": int(zg.size), "lag": k * dt,
            "t_from": float(t[centres[0] - k]), "t_to": float(t[centres[-1] + k]),
            "z_from": float(zg[0]), "z_to": float(zg[-1]), "n_blocks": int(n_blocks),
            "equation": FLUX_EQ}


def segregation_flux_from_tracers(t, z, diameter, *, area: float, z_from: float, z_to: float,
                                  t_from: float, t_to: float, dz: float = 0.25,
                                  width: float = 0.5, lag: float = 4.0,
                                  n_blocks: int = 8) -> dict:
    """:func:`fit_segregation_flux` on the fields of :func:`concentration_fields` from tracer
    records (times ``t``, heights ``z`` (samples, particles), diameters) over the levels
    [z_from, z_to] in steps of ``dz``."""
    if not z_to - z_from >= 4 * dz:
        raise ValueError(f"[z_from, z_to] = [{z_from:g}, {z_to:g}] is out of range: allowed at "
                         f"least 4 dz = {4 * dz:g} thick")
    t = np.asarray(t, float)
    keep = (t >= t_from - 1e-9) & (t <= t_to + 1e-9)
    zg = np.arange(z_from, z_to + 1e-9, dz)
    C, cs, ca = concentration_fields(np.asarray(z)[keep], diameter, zg, area=area, width=width)
    out = fit_segregation_flux(t[keep], zg, C, cs, ca, lag=lag, t_from=t_from, t_to=t_to,
                               n_blocks=n_blocks)
    out.update(width=float(width), dz=float(dz))
    return out


def level_fluxes(t, z, diameter, *, area: float, levels, windows, width: float = 0.5,
                 gradient_half_width: float = 2.0) -> list[dict]:
    """The measured flux at each level over each time window, with what T-eq. (27) needs to
    predict it: J / c (J from a straight-line fit of C(z, t) over the window: the mean flux, its
    stderr from the fit's residuals), the window-mean phi and dphi/dz (a straight line through
    the window-mean phi over +-``gradient_half_width``).  One row per (window, level)."""
    t = np.asarray(t, float)
    lv = np.asarray(levels, float)
    fine = np.arange(lv.min() - gradient_half_width - width,
                     lv.max() + gradient_half_width + width + 1e-9, 0.25)
    rows = []
    for a, b in windows:
        w = (t >= a - 1e-9) & (t <= b + 1e-9)
        if w.sum() < 3:
            raise ValueError(f"window [{a:g}, {b:g}] holds {int(w.sum())} samples: need >= 3")
        C, cs, ca = concentration_fields(np.asarray(z)[w], diameter, fine, area=area,
                                         width=width)
        tw = t[w]
        phi = cs.mean(axis=0) / ca.mean(axis=0)
        for z0 in lv:
            j = int(np.argmin(np.abs(fine - z0)))
            coef, cov = np.polyfit(tw, C[:, j], 1, cov=True)
            near = np.abs(fine - z0) <= gradient_half_width + 1e-9
            c = float(ca[:, j].mean())
            rows.append({"t_from": float(a), "t_to": float(b), "z": float(z0),
                         "J_over_c": float(-coef[0] / c),
                         "J_over_c_stderr": float(math.sqrt(cov[0, 0]) / c),
                         "phi": float(phi[j]),
                         "dphi_dz": float(np.polyfit(fine[near], phi[near], 1)[0]), "c": c})
    return rows
