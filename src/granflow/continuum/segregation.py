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
                      atol: float = 1e-10) -> xr.Dataset:
    """phi(z, t) from a mixed start (phi = phi0) or ``phi_initial`` (cell averages on n cells).

    Ps: Peclet number (> 0: small particles sink); D: diffusivity (d^2 per time unit); h: layer
    depth.  Returns phi(t, z), the indicator s(t) (:func:`indicator`), the half-segregation time
    t_half (s first reaches half its final value; the final value is the steady state's
    indicator, computed on the same grid) and the steady indicator s_steady.
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
    q = flux_function(flux, kappa)
    dz = 1.0 / n
    zeta = (np.arange(n) + 0.5) * dz
    rate = D / h ** 2          # d(t_hat)/dt

    def rhs(t, phi):
        qf = q(0.5 * (phi[1:] + phi[:-1]))               # interior faces
        J = Ps * qf + (phi[1:] - phi[:-1]) / dz           # flux S q + D dphi/dz (scaled)
        J = np.concatenate(([0.0], J, [0.0]))            # no flux at base and surface
        return rate * (J[1:] - J[:-1]) / dz

    jac = sparse.diags([np.ones(n - 1), np.ones(n), np.ones(n - 1)], [-1, 0, 1])
    phi_init = np.full(n, phi0) if phi_initial is None else np.asarray(phi_initial, float)
    if phi_init.shape != (n,):
        raise ValueError(f"phi_initial must hold n = {n} cell averages")
    times = np.linspace(0.0, t_end, int(n_out))
    sol = solve_ivp(rhs, (0.0, t_end), phi_init, method="BDF", t_eval=times, rtol=rtol,
                    atol=atol, jac_sparsity=jac)
    if sol.status < 0:
        raise RuntimeError(f"segregation model failed: {sol.message}")
    phi = sol.y.T
    s = np.array([indicator(p, zeta, h, phi0) for p in phi])
    steady = steady_profile(Ps, phi0, n, flux=flux, kappa=kappa)
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
