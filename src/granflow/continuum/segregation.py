"""Segregation and diffusive remixing in depth: Thornton et al. T-eq. (27) in z.

For a uniform bidisperse layer (no variation along the slope), T-eq. (27) for the
small-particle volume fraction phi(z, t) on 0 <= z <= h is

    dphi/dt = d/dz ( S q(phi) + D dphi/dz ),   no flux through base and surface,

with the segregation velocity scale S (small particles move down), the diffusivity D and

* the symmetric flux q = phi (1 - phi) (Gray & Chugunov 2006; Thornton T-eq. 27), or
* the asymmetric flux q = A phi (1 - phi) (1 - kappa phi) of seed 001 (Gajjar & Gray 2014,
  Eq. 2.9), A(kappa) normalising the largest flux to 1/4.

On scaled depth zeta = z/h and time t_hat = t D / h^2 it becomes
dphi/dt_hat = d/dzeta (Ps q + dphi/dzeta) with the Peclet number Ps = S h / D: the steady state
is T-eq. (28) (:func:`granflow.fitting.phi_teq28`) or the asymmetric profile
(:func:`granflow.fitting.segregation.phi_asymmetric`), and the *time* scale is h^2 / D, which
the steady profile alone does not give.  Here D comes from the self-diffusion of tagged
particles in z measured in steady particle runs (library closure ``diffusivity``:
D = c_D (u_bar/h) d_mean^2, :func:`granflow.closures.evaluate.diffusivity`) and Ps from the
library's segregation closures.

Numerics: finite volumes on ``n`` cells (central flux of S q, cell Peclet number Ps/n << 1),
no-flux faces at both ends, so the mean of phi is conserved to round-off; time integration
with ``scipy.integrate.solve_ivp`` (BDF, tridiagonal Jacobian sparsity).

The particle runs record the segregation indicator s(t) = z_com(small) - z_com(all)
(:mod:`granflow.steady.segregation`); for a layer of uniform bulk density the model gives
s(t) = h (int_0^1 zeta phi dzeta / phi0 - 1/2) (:func:`indicator`).

Example::

    from granflow.continuum import segregation_layer
    res = segregation_layer(Ps=10.0, D=0.02, h=8.0, phi0=0.5, t_end=400.0)
    res.phi.sel(t=400.0).plot(); float(res.t_half)
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr
from scipy import sparse
from scipy.integrate import solve_ivp

from .. import units as U
from ..fitting.segregation import asymmetric_flux_amplitude
from .output import finish

EQ = "Thornton et al. T-eq. (27) in z (Gray & Chugunov 2006 segregation-remixing)"
FLUXES = ("symmetric", "asymmetric")


def flux_function(flux: str = "symmetric", kappa: float = 0.0):
    """q(phi) of the segregation flux (module docstring)."""
    if flux == "symmetric":
        return lambda p: p * (1.0 - p)
    if flux == "asymmetric":
        A = asymmetric_flux_amplitude(kappa)
        return lambda p: A * p * (1.0 - p) * (1.0 - kappa * p)
    raise ValueError(f"flux = {flux!r} is unknown: allowed {list(FLUXES)}")


def indicator(phi, zeta, h: float, phi0: float | None = None):
    """s = h (int zeta phi dzeta / int phi dzeta - 1/2): the small particles' centre of mass
    above the layer's (uniform bulk density), for cell averages phi on cell centres zeta."""
    phi = np.asarray(phi, float)
    w = np.full(np.shape(zeta), 1.0 / np.size(zeta))
    mean = phi @ w if phi0 is None else phi0
    return h * ((phi * zeta) @ w / mean - 0.5)


def segregation_layer(Ps: float, D: float, h: float, phi0: float = 0.5, t_end: float = 400.0,
                      *, flux: str = "symmetric", kappa: float = 0.0, phi_initial=None,
                      n: int = 200, n_out: int = 201, rtol: float = 1e-8,
                      atol: float = 1e-10, S_shape=None, D_shape=None) -> xr.Dataset:
    """phi(z, t) from a mixed start (phi = phi0) or ``phi_initial`` (cell averages on n cells).

    Ps: Peclet number (> 0: small particles sink); D: diffusivity (d^2 per time unit); h: layer
    depth.  Returns phi(t, z), the indicator s(t) (:func:`indicator`), the half-segregation time
    t_half (s first reaches half its final value; the final value is the steady state's
    indicator, computed on the same grid) and the steady indicator s_steady.

    ``S_shape``, ``D_shape``: optional depth dependence of the two rates, functions of the
    scaled height zeta = z / h (arrays in, positive arrays out) multiplying S = Ps D / h and D
    at each cell face: S(z) = (Ps D / h) S_shape(z / h), D(z) = D D_shape(z / h) (e.g. a
    segregation velocity that grows as the overburden pressure falls, measured with
    :func:`granflow.coarse.segregation_flux.level_fluxes`).  Either flux; the steady
    state is then exact too (:func:`steady_profile_shaped`).
    """
    for name, v, lo in (("D", D, 0.0), ("h", h, 0.0), ("t_end", t_end, 0.0)):
        if not (math.isfinite(v) and v > lo):
            raise ValueError(f"{name} = {v!r} is out of range: allowed ({lo}, inf)")
    if not math.isfinite(Ps):
        raise ValueError(f"Ps = {Ps!r} must be finite")
    if not 0.0 < phi0 < 1.0:
        raise ValueError(f"phi0 = {phi0!r} is out of range: allowed (0, 1)")
    if not 0.0 <= kappa < 1.0:
        raise ValueError(f"kappa = {kappa!r} is out of range: allowed [0, 1)")
    if n < 8:
        raise ValueError(f"n = {n} is out of range: allowed >= 8")
    shaped = S_shape is not None or D_shape is not None
    s_face, d_face = _face_shapes(S_shape, D_shape, n)
    zeta = (np.arange(n) + 0.5) / n
    phi_init = np.full(n, phi0) if phi_initial is None else np.asarray(phi_initial, float)
    if phi_init.shape != (n,):
        raise ValueError(f"phi_initial must hold n = {n} cell averages")
    times = np.linspace(0.0, t_end, int(n_out))
    phi = _evolve(Ps, D, h, phi_init, times, flux, kappa, rtol=rtol, atol=atol,
                  s_face=s_face, d_face=d_face)
    s = np.array([indicator(p, zeta, h, phi0) for p in phi])
    steady = (steady_profile_shaped(Ps, phi0, n, S_shape, D_shape, flux=flux, kappa=kappa)
              if shaped else
              steady_profile(Ps, phi0, n, flux=flux, kappa=kappa))
    s_inf = float(indicator(steady, zeta, h, phi0))
    s_start = float(s[0])
    t_half = half_time(times, s, s_start, s_inf)
    ds = xr.Dataset(
        {"phi": (("t", "z"), phi, U.cf(U.DIMENSIONLESS, "small-particle volume fraction phi "
                                                        "(cell average)")),
         "indicator": ("t", s, U.cf(U.LENGTH, "small-particle centre of mass minus the "
                                              "layer's, s(t)")),
         "phi_steady": ("z", steady, U.cf(U.DIMENSIONLESS, "steady phi on the same grid")),
         "indicator_steady": ((), s_inf, U.cf(U.LENGTH, "s of the steady profile")),
         "t_half": ((), t_half, U.cf(U.TIME, "time s(t) first reaches half the way from its "
                                              "start to the steady value"))},
        coords={"t": ("t", times, U.cf(U.TIME, "time since the mixed start")),
                "z": ("z", zeta * h, U.cf(U.LENGTH, "height above the base (cell centre)",
                                          axis="Z", positive="up")),
                "zeta": ("z", zeta, U.cf(U.DIMENSIONLESS, "scaled height z/h"))})
    ds.attrs.update(equation=EQ, flux=flux, kappa=kappa, Ps=Ps, D=D, h=h, phi0=phi0,
                    segregation_velocity_S=Ps * D / h, time_scale_h2_over_D=h * h / D,
                    n_cells=n, solver="finite volumes + scipy solve_ivp BDF")
    return finish(ds, "segregation_layer", "segregation-remixing model (T-eq. 27 in z)",
                  "Small-particle volume fraction phi(z, t) of a bidisperse granular layer from "
                  "the segregation-remixing equation (Thornton et al. T-eq. 27) with a "
                  f"{flux} segregation flux.")


def steady_profile(Ps: float, phi0: float, n: int, *, flux: str = "symmetric",
                   kappa: float = 0.0):
    """Cell averages on n cells of the steady no-flux profile with mean phi0 (T-eq. 28 for the
    symmetric flux; the asymmetric profile of :func:`granflow.fitting.segregation.
    phi_asymmetric` otherwise), integrated exactly over each cell by Gauss-Legendre."""
    from ..fitting.segregation import phi_asymmetric, phi_teq28

    xg, wg = np.polynomial.legendre.leggauss(8)
    edges = np.linspace(0.0, 1.0, n + 1)
    pts = edges[:-1, None] + (edges[1:, None] - edges[:-1, None]) * 0.5 * (xg[None, :] + 1.0)
    if flux == "symmetric":
        vals = phi_teq28(pts, Ps, phi0)
    else:
        vals = np.reshape(phi_asymmetric(pts.ravel(), Ps, phi0, kappa), pts.shape)
    return 0.5 * vals @ wg


def half_time(t, s, s_start: float, s_final: float) -> float:
    """First time s(t) crosses s_start + (s_final - s_start)/2 (linear interpolation; NaN if
    never)."""
    t = np.asarray(t, float)
    s = np.asarray(s, float)
    target = s_start + 0.5 * (s_final - s_start)
    sign = np.sign(s_final - s_start)
    if sign == 0:
        return math.nan
    past = np.nonzero(sign * (s - target) >= 0)[0]
    if past.size == 0:
        return math.nan
    k = int(past[0])
    if k == 0:
        return float(t[0])
    return float(t[k - 1] + (target - s[k - 1]) * (t[k] - t[k - 1]) / (s[k] - s[k - 1]))


def fit_segregation_transient(t, z, phi, *, h: float, phi0: float, z_range=None,
                              flux: str = "symmetric", kappa: float = 0.0, n: int = 100,
                              init_smoothing: float = 0.5, init_modes: int = 3, S0: float = 0.01,
                              D0: float = 0.01, S_shape=None, D_shape=None) -> dict:
    """S and D_r of T-eq. (27) fitted to a measured transient phi(z, t) (least squares).

    ``t`` (times), ``z`` (heights above the base, 0 <= z <= h) and ``phi`` (times, levels): the
    small-particle volume share of a particle run's transient, e.g. from
    :func:`granflow.coarse.segregation_flux.concentration_fields`.  The model starts from the
    measured profile at ``t[0]`` (interpolated onto ``n`` cells, rescaled to the mean
    ``phi0``, so a start that has segregated part-way is the model's start too) and is compared
    with every later profile at the levels inside ``z_range`` (default: all).  The starting
    profile is smoothed with a Gaussian of ``init_smoothing`` (in d; reflected at base and
    surface; 0: none) and corrected by ``init_modes`` cosine modes cos(m pi z / h), m = 1 ...,
    whose amplitudes are fitted with the rates (they keep the mean): a start's long-wave noise
    would otherwise be frozen into the model and bias the rates (S by up to 12 % at a noise of
    0.03 per level without them).  The parameters
    are fitted in log space (both stay positive): Ps = S h / D_r and the time scale h^2 / D_r.
    ``S_shape``, ``D_shape``: depth dependence of the rates as in :func:`segregation_layer`;
    S and D_r are then the rates where the shapes are 1.

    Unlike the flux regression (:func:`granflow.coarse.segregation_flux.fit_segregation_flux`)
    the noise of the measured profile enters only as the residual, not as a regressor (no
    attenuation of D_r by a noisy dphi/dz).  Stderrs from the Jacobian with the residual
    variance, assuming independent residuals: levels closer than the coarse-graining width and
    consecutive times are correlated, so these are lower bounds.  Returns S, D_r, Ps, their
    stderrs, the rms residual, the explained variance r2 of phi over the compared levels,
    ``r2_change`` (the explained share of phi's change since ``t[0]``: r2 also counts the
    profile's spatial structure, which a nearly steady window explains by standing still) and
    ``identified`` (False, with the rates in ``unidentified``, where a rate's stderr is not
    finite or above half of itself: e.g. an interior that hardly changes over the window).
    """
    from scipy.optimize import least_squares

    t = np.asarray(t, float)
    z = np.asarray(z, float)
    phi = np.asarray(phi, float)
    if phi.shape != (t.size, z.size):
        raise ValueError(f"phi must have shape (times, levels) = ({t.size}, {z.size})")
    if t.size < 3 or not np.all(np.diff(t) > 0):
        raise ValueError("t must hold at least 3 increasing times")
    if not (math.isfinite(h) and h > 0):
        raise ValueError(f"h = {h!r} is out of range: allowed (0, inf)")
    if not 0.0 < phi0 < 1.0:
        raise ValueError(f"phi0 = {phi0!r} is out of range: allowed (0, 1)")
    if n < 8:
        raise ValueError(f"n = {n} is out of range: allowed >= 8")
    if init_modes < 0 or not init_smoothing >= 0:
        raise ValueError(f"init_modes = {init_modes!r}, init_smoothing = {init_smoothing!r}: "
                         "allowed >= 0")
    lo, hi = (0.0, h) if z_range is None else (float(z_range[0]), float(z_range[1]))
    sel = (z >= lo) & (z <= hi)
    if sel.sum() < 3:
        raise ValueError(f"z_range = [{lo:g}, {hi:g}] holds {int(sel.sum())} levels: need >= 3")
    if flux not in FLUXES:
        raise ValueError(f"flux = {flux!r} is unknown: allowed {list(FLUXES)}")
    s_face, d_face = _face_shapes(S_shape, D_shape, n)
    zeta_c = (np.arange(n) + 0.5) / n
    init = _smooth_reflecting(np.interp(zeta_c * h, z, phi[0]), init_smoothing * n / h)
    init = np.clip(init * (phi0 / init.mean()), 1e-9, 1.0 - 1e-9)
    obs = phi[1:, sel]

    modes = np.cos(np.pi * np.arange(1, int(init_modes) + 1)[:, None] * zeta_c[None, :])

    def model(x):
        S, D = math.exp(x[0]), math.exp(x[1])
        start = np.clip(init + x[2:] @ modes, 1e-9, 1.0 - 1e-9)
        prof = _evolve(S * h / D, D, h, start, t - t[0], flux, kappa, rtol=1e-6, atol=1e-8,
                       s_face=s_face, d_face=d_face)
        return np.array([np.interp(z[sel], zeta_c * h, p) for p in prof[1:]])

    def resid(x):
        return (model(x) - obs).ravel()

    x0 = np.concatenate([[math.log(S0), math.log(D0)], np.zeros(int(init_modes))])
    fit = least_squares(resid, x0, x_scale=np.concatenate([[1.0, 1.0],
                                                           np.full(int(init_modes), 0.01)]))
    r = fit.fun
    dof = max(r.size - x0.size, 1)
    var = float(r @ r) / dof
    try:
        cov = np.linalg.inv(fit.jac.T @ fit.jac)[:2, :2] * var
        se_log = np.sqrt(np.diag(cov))
        corr = float(cov[0, 1] / (se_log[0] * se_log[1]))
    except np.linalg.LinAlgError:
        se_log, corr = np.array([math.nan, math.nan]), math.nan
    S, D = math.exp(fit.x[0]), math.exp(fit.x[1])
    # log Ps = log S - log D + log h
    se_log_ps = math.sqrt(max(se_log[0] ** 2 + se_log[1] ** 2
                              - 2.0 * corr * se_log[0] * se_log[1], 0.0))
    total = float(np.sum((obs - obs.mean()) ** 2))
    r2 = 1.0 - float(r @ r) / total if total > 0 else math.nan
    # the same against the change since the start: r2 counts the profile's spatial structure,
    # which a window with little evolution explains by standing still
    change = float(np.sum((obs - phi[0, sel][None, :]) ** 2))
    r2_change = 1.0 - float(r @ r) / change if change > 0 else math.nan
    # a rate the data do not pin: no finite stderr, or one above half of itself
    unpinned = [name for name, se in (("S", se_log[0]), ("D_r", se_log[1]))
                if not (math.isfinite(se) and se < 0.5)]
    return {"S": S, "S_stderr": S * float(se_log[0]), "D_r": D, "D_r_stderr": D * float(se_log[1]),
            "Ps": S * h / D, "Ps_stderr": S * h / D * se_log_ps,
            "corr_logS_logD": corr, "rms": math.sqrt(float(r @ r) / r.size), "r2": r2,
            "r2_change": r2_change,
            "n_times": int(t.size - 1), "n_levels": int(sel.sum()), "t_from": float(t[0]),
            "t_to": float(t[-1]), "z_range": [lo, hi], "flux": flux, "kappa": kappa,
            "init_modes": fit.x[2:].tolist(), "success": bool(fit.success),
            "identified": bool(fit.success and not unpinned),
            "unidentified": unpinned, "equation": EQ}


def _smooth_reflecting(p, width_cells: float):
    """``p`` convolved with a Gaussian of ``width_cells`` (mirror images at both ends, so the
    mean is kept)."""
    if width_cells <= 0:
        return p
    from scipy.ndimage import gaussian_filter1d

    return gaussian_filter1d(p, width_cells, mode="reflect")


def _face_shapes(S_shape, D_shape, n):
    """S_shape and D_shape at the n - 1 interior faces (ones where not given); positive."""
    faces = np.arange(1, n) / n
    out = []
    for name, f in (("S_shape", S_shape), ("D_shape", D_shape)):
        v = np.ones(n - 1) if f is None else np.broadcast_to(
            np.asarray(f(faces), float), (n - 1,)).copy()
        if not np.all(np.isfinite(v) & (v > 0)):
            raise ValueError(f"{name} must be finite and > 0 on 0 < zeta < 1")
        out.append(v)
    return out


def steady_profile_shaped(Ps: float, phi0: float, n: int, S_shape=None, D_shape=None, *,
                          flux: str = "symmetric", kappa: float = 0.0):
    """Cell averages of the steady no-flux profile with depth-dependent rates
    (:func:`segregation_layer`'s ``S_shape``, ``D_shape``): for the symmetric flux
    d logit(phi)/dzeta = -Ps S_shape / D_shape, integrated exactly; for the asymmetric one
    (q = A phi (1 - phi) (1 - kappa phi)) d logit(phi)/dzeta = -A Ps S_shape / D_shape
    (1 - kappa phi), integrated by ``solve_ivp`` (rtol 1e-10).  The constant of integration is
    set by the mean phi0 (bisection); cells of 32 sub-points each.  With both shapes 1 it is
    T-eq. (28) (symmetric) or :func:`steady_profile`'s asymmetric profile."""
    from scipy.optimize import brentq
    from scipy.special import expit

    if flux not in FLUXES:
        raise ValueError(f"flux = {flux!r} is unknown: allowed {list(FLUXES)}")

    m = 32
    zeta = (np.arange(n * m) + 0.5) / (n * m)
    grid = np.linspace(0.0, 1.0, 4 * n * m + 1)
    s_ = np.ones_like(grid) if S_shape is None else np.asarray(S_shape(grid), float)
    d_ = np.ones_like(grid) if D_shape is None else np.asarray(D_shape(grid), float)
    g = Ps * s_ / d_
    G = np.concatenate(([0.0], np.cumsum(0.5 * (g[1:] + g[:-1]) * np.diff(grid))))
    Gz = np.interp(zeta, grid, G)

    if flux == "symmetric":
        def profile(c):
            return expit(c - Gz)
    else:
        A = asymmetric_flux_amplitude(kappa)

        def profile(c):
            sol = solve_ivp(lambda x, u: -A * np.interp(x, grid, g) * (1.0 - kappa * expit(u)),
                            (0.0, 1.0), [c], t_eval=zeta, rtol=1e-10, atol=1e-12)
            return expit(sol.y[0])

    span = 50.0 + abs(G).max() * (1.0 if flux == "symmetric" else A)
    c = brentq(lambda c: float(np.mean(profile(c))) - phi0, -span, span, xtol=1e-13)
    return profile(c).reshape(n, m).mean(axis=1)


def _evolve(Ps, D, h, init, times, flux, kappa, *, rtol, atol, s_face=None, d_face=None):
    """phi (times, cells) of T-eq. (27) on ``init.size`` cells from ``init`` at ``times``
    (from 0): finite volumes, no flux at base and surface, BDF (module docstring); ``s_face``,
    ``d_face``: the rates' shapes at the interior faces (:func:`_face_shapes`)."""
    n = init.size
    q = flux_function(flux, kappa)
    dz = 1.0 / n
    rate = D / h ** 2          # d(t_hat)/dt
    sf = 1.0 if s_face is None else s_face
    df = 1.0 if d_face is None else d_face

    def rhs(_t, p):
        J = Ps * sf * q(0.5 * (p[1:] + p[:-1])) + df * (p[1:] - p[:-1]) / dz  # S q + D phi_z
        J = np.concatenate(([0.0], J, [0.0]))                        # no flux at the ends
        return rate * (J[1:] - J[:-1]) / dz

    jac = sparse.diags([np.ones(n - 1), np.ones(n), np.ones(n - 1)], [-1, 0, 1])
    sol = solve_ivp(rhs, (0.0, float(times[-1])), init, method="BDF", t_eval=times, rtol=rtol,
                    atol=atol, jac_sparsity=jac)
    if sol.status < 0:
        raise RuntimeError(f"segregation model failed: {sol.message}")
    return sol.y.T
