"""Velocity shape factor alpha = mean(u^2) / u_bar^2 closures.

* Measured: :func:`alpha_by_theta` gives the mean and spread of measured alpha per inclination.
* Rough bases (lambda >= 5/6), Weinhart et al. (2012) Eq. (54): the velocity gradient is the
  Bagnold one, u_B(z) = (5/3) u_bar (1 - ((h - z)/h)^(3/2)) (54a), in the bulk; constant (linear
  velocity) in the top 5 d; and in a basal layer of thickness b_lambda it rises linearly from 1/3
  to 1 of the Bagnold gradient at z = b_lambda, with no slip (54b). The layer thickness is
  ``b_lambda = d_lambda hstop(theta; 1) / h`` (54c); d_lambda is fitted (paper Table 2:
  d = 5.105 for lambda = 5/6, 6.678 for 1, 13.75 for 2). alpha does not depend on the velocity
  scale, so only the profile shape enters. Where b_lambda >= h the basal layer fills the flow.
* Smooth bases (lambda <= 2/3): constant alpha(lambda) (Eq. 55). :func:`alpha_eq55` evaluates the
  model profiles of Eq. (55); the PDF text reads "5/3 - (1 - z/h)^2", which does not reproduce
  Table 2, whereas u/u_bar = (3/2)(1 - (1 - z/h)^2) (mean 1) gives alpha = 1.200 for lambda = 2/3
  and 0.16 + 0.84 (3/2)(1 - (1 - z/h)^2) gives 1.141 for lambda = 1/2 (Table 2: 1.201, 1.142),
  so those forms are used. :func:`fit_alpha_constant` fits the constant to measured alphas.

Fits: weighted least squares (:mod:`.forms`): d_lambda with a joint bootstrap over the hstop
fit (unconditional stderr), falling back to a constant alpha when d_lambda is not identified;
the constant of Eq. (55) as a weighted mean. Error: Eq. (49) of alpha - alpha_fit.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import integrate

from .hstop import HSTOP_PARAMS, hstop_eq45
from .forms import Form, _parts, fit_forms
from .result import FitResult, data_range, failed_fit, finite_mask

EQ54 = "Weinhart et al. 2012 Eq. (54)"
EQ55 = "Weinhart et al. 2012 Eq. (55)"
ALPHA_PARAMS = ("d_lambda", "alpha_constant")
SURFACE_LAYER = 5.0  # d; linear velocity in the top 5 particle diameters (Eq. 54b)


def alpha_by_theta(theta, alpha) -> pd.DataFrame:
    """Measured alpha grouped by inclination: columns theta, alpha_mean, alpha_std, n."""
    frame = pd.DataFrame({"theta": np.asarray(theta, float), "alpha": np.asarray(alpha, float)})
    frame = frame[np.isfinite(frame["theta"]) & np.isfinite(frame["alpha"])]
    g = frame.groupby("theta")["alpha"]
    return pd.DataFrame({"alpha_mean": g.mean(), "alpha_std": g.std(ddof=1),
                         "n": g.size()}).reset_index()


def velocity_profile_eq54(zeta, h, b_lambda, surface_layer: float = SURFACE_LAYER):
    """Eq. (54) velocity profile shape u(z) (arbitrary scale) at scaled heights zeta = z/h in [0, 1].

    ``h`` and ``b_lambda`` broadcast against each other; the result has their shape plus the
    trailing axis of ``zeta``.
    """
    h = np.asarray(h, dtype=float)[..., None]
    b = np.asarray(b_lambda, dtype=float)[..., None]
    z = np.asarray(zeta, dtype=float) * h
    full = b >= h  # basal layer fills the flow: u ~ z/3 + z^2/(3 b)
    bl = np.where(full, h, b)
    safe_b = np.where(b > 0, b, 1.0)

    def uB(zz):
        return 1.0 - np.clip(1.0 - zz / h, 0.0, None) ** 1.5

    def duB(zz):
        return 1.5 / h * np.sqrt(np.clip(1.0 - zz / h, 0.0, None))

    g0 = np.where(full, 1.0, duB(bl))
    base = g0 * (z / 3.0 + z * z / (3.0 * safe_b))
    u_b = g0 * (bl / 3.0 + bl * bl / (3.0 * safe_b))
    zt = np.maximum(h - surface_layer, bl)
    bulk = u_b + uB(z) - uB(bl)
    u_t = u_b + uB(zt) - uB(bl)
    top = u_t + duB(zt) * (z - zt)
    u = np.where(z < bl, base, np.where(z < zt, bulk, top))
    return np.where(full, base, u)


def alpha_eq54(h, hstop1, d_lambda, n: int = 2001, surface_layer: float = SURFACE_LAYER):
    """Eq. (54) shape factor for flow height h, hstop(theta; 1) and basal-layer coefficient d_lambda.

    Integrated with Simpson's rule on ``n`` points over the depth (relative accuracy ~1e-8).
    """
    h = np.asarray(h, dtype=float)
    b = np.asarray(d_lambda, dtype=float) * np.asarray(hstop1, dtype=float) / h
    zeta = np.linspace(0.0, 1.0, n | 1)
    u = velocity_profile_eq54(zeta, h, b, surface_layer)
    m1 = integrate.simpson(u, x=zeta, axis=-1)
    m2 = integrate.simpson(u * u, x=zeta, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = m2 / (m1 * m1)
    return out[()] if np.ndim(out) == 0 else out


def _eq55_profile(lam):
    shape = lambda z: 1.5 * (1.0 - (1.0 - z) ** 2)  # noqa: E731 (mean 1 over [0, 1])
    if math.isclose(lam, 2.0 / 3.0, abs_tol=1e-6):
        return shape
    if math.isclose(lam, 0.5, abs_tol=1e-6):
        return lambda z: 0.16 + 0.84 * shape(z)
    if lam == 0:
        return lambda z: np.ones_like(z)
    raise ValueError(f"Eq. (55) gives profiles for lambda = 0, 1/2, 2/3 only, not {lam}")


def alpha_eq55(lam: float, n: int = 2001) -> float:
    """Eq. (55) model shape factor for lambda in {0, 1/2, 2/3} (1.0, 1.1411, 1.2000)."""
    z = np.linspace(0.0, 1.0, n | 1)
    u = _eq55_profile(float(lam))(z)
    return float(integrate.simpson(u * u, x=z) / integrate.simpson(u, x=z) ** 2)


def fit_alpha_basal_layer(theta, h, alpha, hstop1, *, lam=None, contact_law=None,
                          min_points: int = 2, d: float = 1.0, sigma=None, ids=None,
                          selection: str = "", n_bootstrap: int = 200, seed: int = 0,
                          sigma_parts=None) -> FitResult:
    """Fit d_lambda of Eq. (54) to measured alpha of steady runs (theta in degrees, h in d).

    ``hstop1``: FitResult (or mapping delta1, delta2, A) of hstop(theta; lambda = 1); with a
    bootstrap ensemble the stderr of d_lambda is unconditional (joint bootstrap, see
    :func:`granflow.fitting.flow_rule.joint_bootstrap`).  Runs outside (delta1, delta2) of
    lambda = 1 are dropped.  ``sigma``: standard errors of alpha.  When d_lambda is not
    identified the reduced form is a constant alpha over the fitted range (as Eq. 55 for
    smooth bases).
    """
    from .flow_rule import joint_bootstrap

    coords = dict(lam=lam, contact_law=contact_law)
    h1 = hstop1
    if isinstance(hstop1, FitResult):
        if hstop1.state == "failed":
            return failed_fit("alpha", EQ54, ALPHA_PARAMS, "hstop(theta; 1) fit is not usable",
                              0, **coords)
        hstop1 = hstop1.params
    p1 = {k: float(hstop1[k]) for k in HSTOP_PARAMS}
    theta, h, alpha = (np.asarray(x, dtype=float).ravel() for x in (theta, h, alpha))
    ids = np.asarray(ids if ids is not None else np.arange(theta.size)).astype(str)
    hs = hstop_eq45(theta, d=d, **p1)
    m = finite_mask(theta, h, alpha) & np.isfinite(hs) & (hs > 0)
    n = int(m.sum())
    if n < min_points:
        return failed_fit("alpha", EQ54, ALPHA_PARAMS, f"too few steady runs: {n}, need "
                          f"{min_points}", n, **coords)
    th_m, h_m, y = theta[m], h[m], alpha[m]
    x = np.vstack([h_m, hs[m]])
    s = None if sigma is None else np.asarray(sigma, dtype=float).ravel()[m]
    forms = [
        Form("eq54", lambda xx, dl: alpha_eq54(xx[0], xx[1], dl), ("d_lambda",),
             lambda xx, yy: [5.0], "Eq. (54) basal-layer model, b = d_lambda hstop(theta; 1)/h",
             bounds={"d_lambda": (0.0, 1e4)}, min_points=min_points),
        Form("constant", lambda xx, a: a + 0.0 * xx[0], ("alpha_constant",),
             lambda xx, yy: [float(np.mean(yy))],
             "alpha = constant over the fitted range (d_lambda not identified)",
             min_points=max(min_points, 3)),
    ]

    def x_of(p):
        hsb = hstop_eq45(th_m, *p, d)
        return np.vstack([h_m, np.where(np.isfinite(hsb) & (hsb > 0), hsb, np.nan)])

    boot = None
    if isinstance(h1, FitResult) and h1.ensemble and n_bootstrap > 0:
        def boot(form, lsq, batch=0):
            if form.name == "constant":  # does not depend on hstop: plain case bootstrap
                return _case_bootstrap_mean(y, n_bootstrap, seed, batch)
            return joint_bootstrap(form, x_of, y, h1, s, n_bootstrap, seed, batch)
    return fit_forms("alpha", EQ54, ALPHA_PARAMS, forms, x, y, sigma=s, ids=ids[m],
                     coords=coords, structure_x=h_m / hs[m],
                     valid_range={"theta": data_range(th_m), "h": data_range(h_m)},
                     extra={"hstop1": p1}, error_measure="Eq. (49) of alpha - alpha_fit",
                     selection=selection, seed=seed, bootstrap=boot,
                     sigma_parts=_parts(sigma_parts, m))


def _case_bootstrap_mean(y, n_boot, seed, batch=0):
    rng = np.random.default_rng(seed if batch == 0 else [seed, batch])
    return tuple((float(np.mean(y[rng.integers(0, y.size, y.size)])),) for _ in range(n_boot))


def fit_alpha_constant(alpha, *, theta=None, h=None, lam=None, contact_law=None,
                       min_points: int = 2, sigma=None, ids=None, selection: str = "",
                       seed: int = 0, sigma_parts=None) -> FitResult:
    """Constant alpha(lambda) for smooth bases (lambda <= 2/3, Eq. 55): the weighted mean of
    measured alpha (unweighted without ``sigma``), its standard error from the (Birge-inflated)
    covariance.  ``theta`` and ``h`` set the valid range.
    """
    coords = dict(lam=lam, contact_law=contact_law)
    alpha = np.asarray(alpha, dtype=float).ravel()
    n_all = alpha.size
    theta = np.full(n_all, np.nan) if theta is None else np.asarray(theta, float).ravel()
    h = np.full(n_all, np.nan) if h is None else np.asarray(h, float).ravel()
    ids = np.asarray(ids if ids is not None else np.arange(n_all)).astype(str)
    m = np.isfinite(alpha)
    n = int(m.sum())
    if n < min_points:
        return failed_fit("alpha", EQ55, ALPHA_PARAMS, f"too few steady runs: {n}, need "
                          f"{min_points}", n, "standard error of the mean", **coords)
    rng = {}
    if np.isfinite(theta[m]).any():
        rng["theta"] = data_range(theta[m])
    if np.isfinite(h[m]).any():
        rng["h"] = data_range(h[m])
    s = None if sigma is None else np.asarray(sigma, dtype=float).ravel()[m]
    forms = [Form("eq55", lambda xx, a: a + 0.0 * xx, ("alpha_constant",),
                  lambda xx, yy: [float(np.mean(yy))], "constant alpha(lambda) (Eq. 55)",
                  min_points=min_points)]
    sx = theta[m] if np.isfinite(theta[m]).all() else np.zeros(n)  # zeros: no structure test
    return fit_forms("alpha", EQ55, ALPHA_PARAMS, forms, np.arange(n, dtype=float), alpha[m],
                     sigma=s, ids=ids[m], coords=coords, valid_range=rng, structure_x=sx,
                     error_measure="Eq. (49) of alpha - alpha_constant", selection=selection,
                     seed=seed, sigma_parts=_parts(sigma_parts, m))


def fit_alpha(theta, h, alpha, lam: float, hstop1=None, *, contact_law=None,
              constant_up_to: float = 2.0 / 3.0, sigma=None, ids=None, selection: str = "",
              n_bootstrap: int = 200, seed: int = 0, sigma_parts=None) -> FitResult:
    """alpha closure for basal roughness ``lam``: constant for lam <= 2/3, Eq. (54) otherwise."""
    if lam <= constant_up_to + 1e-9:
        return fit_alpha_constant(alpha, theta=theta, h=h, lam=lam, contact_law=contact_law,
                                  sigma=sigma, ids=ids, selection=selection, seed=seed,
                                  sigma_parts=sigma_parts)
    if hstop1 is None:
        return failed_fit("alpha", EQ54, ALPHA_PARAMS, "Eq. (54) needs hstop(theta; 1)", 0,
                          lam=lam, contact_law=contact_law)
    return fit_alpha_basal_layer(theta, h, alpha, hstop1, lam=lam, contact_law=contact_law,
                                 sigma=sigma, ids=ids, selection=selection,
                                 n_bootstrap=n_bootstrap, seed=seed, sigma_parts=sigma_parts)
