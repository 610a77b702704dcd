"""Depth-resolved uniform layer after a change of inclination: a local friction-law column.

The uniform-layer ODE (:mod:`.uniform`, Weinhart et al. 2012 Eq. 34 for a uniform layer) lets
the basal friction follow the depth-averaged velocity at once.  In a layer of particles a change
of the driving force reaches the base by shear: the velocity profile has to adjust, and that
takes a momentum-diffusion time across the depth.  This module solves the simplest
depth-resolved model that uses nothing beyond the same friction closure: a local rheology
(GDR MiDi 2004; Jop, Forterre & Pouliquen 2005, J. Fluid Mech. 541, 167) in a column of
constant height h and density, with no slip at the base (z = 0) and a free surface (z = h)::

    du/dt = g sin(theta) + d/dz [ g cos(theta) (h - z) mu_loc(F_loc) ],
    F_loc(z) = (2/5) h (du/dz) / sqrt(g cos(theta) (h - z)),      mu_loc(F) = mu(h, F),

with ``mu(h, F)`` the library's basal friction (Eq. 50) at the layer's height.  ``F_loc`` is the
Froude number that a Bagnold profile with the local inertial number would have (u_bar =
(2/5) I sqrt(phi g cos) h^(3/2) / d, so F = (2/5) I sqrt(phi) h / d; the volume fraction phi and
d cancel), so the column's steady state is Bagnold's profile at exactly the closure's steady
Froude number, and its depth average obeys Eq. (50) when the profile is Bagnold's.  For
Eq. (50) with gamma = 0 this is the mu(I) rheology of Jop et al. (2005): mu1 = tan(delta1),
mu2 = tan(delta2), I0 = 5 beta d / (2 A sqrt(phi)); Eq. (47)'s offset gamma has no local form
and enters through mu(h, .) at the layer's h.

Linearised about the steady state the column is a diffusion equation with the viscosity
nu(z) = nu_b sqrt(1 - z/h), nu_b = mu'(I) d sqrt(g cos(theta) h / phi).  Its slowest mode,
u' ~ s^(1/4) J_(-1/3)((4/3) sqrt(lambda) s^(3/4)) with s = 1 - z/h, decays at
lambda1 nu_b / h^2 with lambda1 = (3 j / 4)^2 = 1.9593, j = 1.8664 the first zero of
J_(-1/3) (:func:`slowest_mode_eigenvalue`; the next modes 13.99 and 37.13), while the
uniform-layer ODE linearised about the same state relaxes in tau_ODE = (2/5) h^2 / nu_b.
Their ratio is a number, the same for every closure:

    tau_column / tau_ODE = 5 / (2 lambda1) = 1.276     (:data:`LINEAR_TAU_RATIO`),

so the depth structure alone makes a layer relax 28 % more slowly than the depth-averaged
friction law says.  :func:`column_layer` solves the nonlinear column (finite volumes in z,
``scipy.integrate.solve_ivp`` BDF with a tridiagonal Jacobian pattern) from a Bagnold profile
with the given depth-averaged velocity; :func:`granflow.continuum.switch_prediction` with
``model="column"`` runs it over the closure ensemble.

What it leaves out: slip at the base, density changes (h is constant), elasticity of the
contact network, non-local effects of thin layers (the reason Eq. 47 has gamma) and the
stop-and-go of layers near hstop.  Its diffusion coefficient is positive wherever mu(h, F)
increases with F (Eq. 50 always does), so the one-dimensional column is well posed; the
ill-posedness of mu(I) in two dimensions (Barker et al. 2015, J. Fluid Mech. 779, 794) does not
arise.  A layer that stops (tan(theta) below mu(h, 0)) creeps through the regularisation of the
yield stress rather than arresting.

Against particle runs it was not fitted on (``tests/test_continuum_slow.py``, continuum-soft
switch runs, measured 2026-11-28): e-folding times 33.3, 33.6, 22.1, 15.2 against the particles'
47.9, 42.8, 27.1, 28.3 (H = 10 up, H = 10 down, H = 8 up, H = 6 up), where the ODE gives
26.7, 27.2, 17.8, 12.2: errors -31, -22, -18, -47 % against -44, -37, -34, -57 %.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import xarray as xr
from scipy import optimize, sparse, special
from scipy.integrate import solve_ivp

from .. import units as U
from .closures import FlowClosures
from .output import finish
from .uniform import _check_inputs, linear_relaxation_time, stall_guard

EQ = ("local friction-law column: du/dt = g sin(theta) + d/dz[g cos(theta) (h - z) "
      "mu(h, F_loc)], F_loc = (2/5) h (du/dz) / sqrt(g cos(theta) (h - z)); no slip at z = 0, "
      "free surface at z = h")

#: right-hand-side evaluations after which the column is declared stalled: the library
#: ensembles of the switch comparisons need at most ~10,000 (measured 2026-11-28, every fifth
#: member of continuum-soft's friction ensemble at the five switch states)
MAX_RHS_CALLS = 50_000

#: shear-rate scale of the yield-stress regularisation, relative to u0 / h: friction is
#: mu * tanh(shear / (EPS_SHEAR * |u0| / h)) (below it the column creeps instead of arresting)
EPS_SHEAR = 1e-4


@functools.lru_cache(maxsize=1)
def slowest_mode_eigenvalue() -> float:
    """lambda1 = (3 j / 4)^2, j the first positive zero of the Bessel function J_(-1/3): the
    slowest decay rate, in units of nu_b / h^2, of du/dt = d/dz(nu_b sqrt(1 - z/h) du/dz)
    with u(0) = 0 and no stress at z = h (module docstring)."""
    j = optimize.brentq(lambda x: special.jv(-1.0 / 3.0, x), 1.0, 2.5, xtol=1e-15,
                        rtol=4 * np.finfo(float).eps)
    return (0.75 * j) ** 2


#: e-folding time of the linearised column over that of the linearised uniform-layer ODE, the
#: same for every friction law (module docstring): 5 / (2 lambda1)
LINEAR_TAU_RATIO = 2.5 / slowest_mode_eigenvalue()


def bagnold_cell_profile(h: float, u_bar: float, n_z: int) -> np.ndarray:
    """Cell averages, on ``n_z`` equal cells over [0, h], of the Bagnold profile
    u(z) = (5/3) u_bar (1 - (1 - z/h)^(3/2)) (depth average exactly ``u_bar``)."""
    zeta = np.linspace(0.0, 1.0, int(n_z) + 1)
    prim = zeta + 0.4 * (1.0 - zeta) ** 2.5       # integral of 1 - (1 - zeta)^(3/2)
    return (5.0 / 3.0) * float(u_bar) * np.diff(prim) * int(n_z)


def linear_column_eigenvalues(n_z: int, k: int = 3) -> np.ndarray:
    """The ``k`` slowest decay rates (units nu_b / h^2) of the column's linearised operator as
    :func:`column_layer` discretises it (``n_z`` cells): they converge to
    :func:`slowest_mode_eigenvalue` and the higher zeros of J_(-1/3)."""
    from scipy.linalg import eigh_tridiagonal

    n = int(n_z)
    dz = 1.0 / n
    faces = np.arange(n + 1) * dz                     # face i lies below cell i
    c = np.sqrt(np.maximum(1.0 - faces, 0.0))         # viscosity on faces (0 at the surface)
    # base face: u = 0 half a cell below the first centre
    cond = np.empty(n + 1)
    cond[0] = c[0] / (0.5 * dz)
    cond[1:] = c[1:] / dz
    cond[-1] = 0.0
    diag = (cond[:-1] + cond[1:]) / dz
    off = -cond[1:-1] / dz
    w = eigh_tridiagonal(diag, off, eigvals_only=True, select="i", select_range=(0, k - 1))
    return np.asarray(w)


def column_layer(closures: FlowClosures, h: float, u0: float, t_end: float, *,
                 n_z: int = 64, n_out: int = 401, rtol: float = 1e-7,
                 atol: float = 1e-10) -> xr.Dataset:
    """The column of the module docstring, height ``h``, started from a Bagnold profile with
    depth-averaged velocity ``u0``, at ``closures.theta``.

    Returns a Dataset with ``u_bar`` and ``froude`` on ``t`` (``n_out`` points in [0, t_end]),
    ``u(t, z)`` (cell centres), the scalars ``u_steady`` (the closure's steady velocity, NaN
    when it has none) and ``tau_linear`` (:data:`LINEAR_TAU_RATIO` times the uniform-layer
    ODE's linearised e-folding time).
    """
    h, u0, t_end = float(h), float(u0), float(t_end)
    _check_inputs(h, u0, t_end)
    n = int(n_z)
    if not 8 <= n <= 4096:
        raise ValueError(f"n_z = {n_z!r} is out of range: allowed 8 ... 4096")
    gc, gs = closures.g_cos, closures.g_cos * closures.tan_theta
    dz = h / n
    faces = np.arange(n + 1) * dz
    depth = np.maximum(h - faces, 0.0)                 # h - z on the faces
    lever = gc * depth                                 # g cos (h - z): pressure / (rho phi)
    with np.errstate(divide="ignore"):
        f_scale = np.where(depth > 0, 0.4 * h / np.sqrt(gc * np.where(depth > 0, depth, 1.0)),
                           0.0)
    spacing = np.full(n + 1, dz)
    spacing[0] = 0.5 * dz                              # base: u = 0 at z = 0
    eps = EPS_SHEAR * max(abs(u0), 1e-3) / h
    h_faces = np.full(n, h)

    def face_stress(u):
        du = np.empty(n + 1)
        du[0] = u[0]
        du[1:-1] = np.diff(u)
        du[-1] = 0.0
        shear = du / spacing
        F = np.abs(shear[:-1]) * f_scale[:-1]
        mu = np.asarray(closures.mu(h_faces, F), float)
        tau = np.zeros(n + 1)
        tau[:-1] = lever[:-1] * mu * np.tanh(shear[:-1] / eps)   # the surface face: tau = 0
        return tau

    stalled = stall_guard("column model", MAX_RHS_CALLS, t_end)

    def rhs(t, u):
        stalled(t)
        tau = face_stress(u)
        return gs + (tau[1:] - tau[:-1]) / dz

    pattern = sparse.diags([np.ones(n - 1), np.ones(n), np.ones(n - 1)], [-1, 0, 1])
    t_eval = np.linspace(0.0, t_end, int(n_out))
    y0 = bagnold_cell_profile(h, u0, n)
    sol = solve_ivp(rhs, (0.0, t_end), y0, method="BDF", t_eval=t_eval, rtol=rtol,
                    atol=atol, jac_sparsity=pattern)
    if sol.status < 0:
        raise RuntimeError(f"column model failed: {sol.message}")
    u = sol.y.T
    u_bar = u.mean(axis=1)
    F_inf = closures.steady_froude(h)
    u_inf = F_inf * math.sqrt(gc * h) if math.isfinite(F_inf) else math.nan
    z = (np.arange(n) + 0.5) * dz
    ds = xr.Dataset(
        {"u_bar": ("t", u_bar, U.cf(U.VELOCITY, "depth-averaged downslope velocity u_bar")),
         "froude": ("t", u_bar / math.sqrt(gc * h),
                    U.cf(U.DIMENSIONLESS, "Froude number u_bar / sqrt(g h cos(theta))")),
         "u": (("t", "z"), u, U.cf(U.VELOCITY, "downslope velocity (cell average)")),
         "u_steady": ((), u_inf, U.cf(U.VELOCITY, "steady velocity: mu(h, F) = tan(theta)")),
         "tau_linear": ((), LINEAR_TAU_RATIO * linear_relaxation_time(closures, h), U.cf(
             U.TIME, "e-folding time of the slowest mode of the linearised column"))},
        coords={"t": ("t", sol.t, U.cf(U.TIME, "time since the change of inclination")),
                "z": ("z", z, U.cf(U.LENGTH, "height above the base (cell centre)"))})
    ds.attrs.update(closures.attrs(), h=h, u0=u0, equation=EQ, n_z=n,
                    initial_profile="Bagnold: u = (5/3) u0 (1 - (1 - z/h)^(3/2))",
                    linear_tau_ratio=LINEAR_TAU_RATIO,
                    solver="scipy solve_ivp BDF (tridiagonal Jacobian pattern), finite volumes",
                    rtol=rtol, atol=atol, yield_regularisation=f"tanh(shear / {eps:.3g})")
    return finish(ds, "column_layer", "depth-resolved layer after a change of inclination",
                  "Velocity profile of a uniform granular layer whose local friction is the "
                  "closure library's basal friction law mu(h, F) at the local Bagnold Froude "
                  "number (a mu(I)-type column), after a change of inclination.")
