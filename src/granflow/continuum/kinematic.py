"""Local-equilibrium (kinematic- and diffusive-wave) limit of the shallow-layer equations.

Weinhart et al. (2012) Eq. (34b, c) relaxes the depth-averaged velocity towards the steady flow
rule on a time scale set by the friction closure (d mu / d F).  Where that relaxation is fast
against the time a perturbation takes to travel its own length, the momentum balance is local:

    g h (sin(theta) - mu(h, F) cos(theta)) - d(K g cos(theta) h^2 / 2)/dx = 0
    =>  mu(h, F) = tan(theta) - K dh/dx                                            (LE)

(inertia alpha h u^2 dropped), so that u(x, t) follows from h(x, t) alone and only the mass
balance (34a) is left:

    dh/dt + d(h u_e(h, dh/dx))/dx = 0,   u_e = F_e sqrt(g h cos(theta)),
    mu(h, F_e) = tan(theta) - K dh/dx.                                              (KW)

With ``diffusive=False`` the K dh/dx term is dropped: the *kinematic wave* dh/dt + d(h u_s(h))/dx
= 0 with the steady flow rule u_s(h) of the closures (F_s of :meth:`FlowClosures.steady_froude`);
its waves travel at c = d(h u_s)/dh (5/2 u_s for a flow rule F = beta h / hstop) and steepen
into shocks at the front.  With ``diffusive=True`` (default) the pressure gradient enters the
friction balance: the *diffusive wave*, the kinematic wave with a diffusivity
K h du_e/dmu (Savage & Hutter-type thin-layer limits; e.g. Saingier, Deboeuf & Lagree 2016,
Phys. Fluids 28, 053302, for a granular flow rule).  No parameter beyond the library's
mu(h, F) and K; alpha drops out with the inertia.  This is an extension of the paper (its
Eq. (34) keeps the inertia); :func:`shallow_layer` solves the full equations.

Inversion of the friction law: F_e at each face by vectorised bisection of mu(h, F) = target on
[0, F_max] (mu increases with F for Eq. 50 with beta, A > 0); a face whose target lies below
mu(h, 0) is arrested (F_e = 0); one above mu(h, F_max) is counted in ``n_faces_accelerating``
and held at F_max.

Scheme (finite volumes on a uniform periodic grid of cell averages): the flux at face i+1/2 is
h_f u_e(h_f, (h_(i+1) - h_i)/dx) with h_f the upwind (i) cell's MUSCL-minmod reconstruction at
the face (the flow goes downslope, u_e >= 0: a layer driven upslope is refused); second-order
SSP Runge-Kutta (Heun); the time step obeys both the advective limit dt <= cfl dx / max c and
the diffusive limit dt <= cfl dx^2 / (2 max D), c and D by finite differences of the face flux
in h and in dh/dx.  Cell averages change only by flux differences: mass is conserved to
round-off, and a uniform layer stays uniform bit for bit.

Tests: exact mass conservation and uniform steady flow; the Rankine-Hugoniot speed of the
kinematic shock; the travel speed c = d(h u_s)/dh and the decay rate D k^2 of a small periodic
mode of the diffusive wave (linear theory).

Example::

    import numpy as np
    from granflow.continuum import FlowClosures, local_equilibrium_layer
    from granflow.fitting.flow_rule import mu_eq50

    c = FlowClosures(theta=26.0, mu=lambda h, F: mu_eq50(h, F, 17.7, 32.8, 3.355, 0.196, 0.04))
    x = np.arange(200) + 0.5
    h0 = 6.0 + 3.0 * np.exp(-((x - 50.0) / 8.0) ** 2)
    res = local_equilibrium_layer(c, x, h0, t_end=20.0)
    res.h.sel(t=20.0).plot()
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr

from ..engine.species import check_range
from .closures import FlowClosures
from .output import finish
from .shallow import _cell_spacing, _layer_dataset, _minmod, _output_times

EQ_KINEMATIC = ("Weinhart et al. 2012 Eq. (34a) with the local equilibrium mu(h, F) = tan(theta) "
                "(kinematic wave: inertia and pressure gradient of Eq. 34b dropped)")
EQ_DIFFUSIVE = ("Weinhart et al. 2012 Eq. (34a) with the local equilibrium mu(h, F) = tan(theta) "
                "- K dh/dx (diffusive wave: inertia of Eq. 34b dropped)")


def equilibrium_froude(closures: FlowClosures, h, mu_target, *, F_max: float = 50.0,
                       iterations: int = 64):
    """F_e >= 0 with mu(h, F_e) = mu_target, element-wise (vectorised bisection).

    Returns (F_e, arrested, accelerating): F_e = 0 where mu_target <= mu(h, 0) (``arrested``),
    F_e = F_max where mu_target > mu(h, F_max) (``accelerating``)."""
    h, target = np.broadcast_arrays(np.asarray(h, float), np.asarray(mu_target, float))
    lo = np.zeros(h.shape)
    hi = np.full(h.shape, float(F_max))
    mu0 = np.asarray(closures.mu(h, lo), float)
    mumax = np.asarray(closures.mu(h, hi), float)
    arrested = ~(target > mu0)
    accelerating = target > mumax
    for _ in range(int(iterations)):
        mid = 0.5 * (lo + hi)
        above = np.asarray(closures.mu(h, mid), float) > target
        hi = np.where(above, mid, hi)
        lo = np.where(above, lo, mid)
    F = 0.5 * (lo + hi)
    F = np.where(arrested, 0.0, np.where(accelerating, float(F_max), F))
    return F, arrested, accelerating


class LocalEquilibriumSolver:
    """Explicit finite-volume solver of the (KW) equation (module docstring); use
    :func:`local_equilibrium_layer`."""

    def __init__(self, closures: FlowClosures, dx: float, *, diffusive: bool = True,
                 cfl: float = 0.4, F_max: float = 50.0):
        self.c = closures
        self.dx = float(dx)
        self.diffusive = bool(diffusive)
        self.cfl = check_range("cfl", cfl, 0.0, 1.0, lo_open=True)
        self.F_max = float(F_max)
        self.gc = closures.g_cos
        self.n_arrested = 0
        self.n_accelerating = 0

    def face_flux(self, h_face, grad):
        """h_f u_e(h_f, grad) at the faces (grad = dh/dx across the face)."""
        target = self.c.tan_theta - (self.c.K * grad if self.diffusive else 0.0)
        F, arr, acc = equilibrium_froude(self.c, h_face, target, F_max=self.F_max)
        self._last = (int(arr.sum()), int(acc.sum()))
        hf = np.maximum(h_face, 0.0)
        return hf * F * np.sqrt(self.gc * hf)

    def _faces(self, h):
        """Face i+1/2 (i = 0..n-1, periodic): upwind reconstruction and gradient."""
        hm = np.roll(h, 1)
        hp = np.roll(h, -1)
        slope = _minmod(h - hm, hp - h)
        return h + 0.5 * slope, (hp - h) / self.dx

    def rhs(self, h):
        hf, grad = self._faces(h)
        flux = self.face_flux(hf, grad)
        return -(flux - np.roll(flux, 1)) / self.dx

    def stable_dt(self, h):
        hf, grad = self._faces(h)
        f0 = self.face_flux(hf, grad)
        eps_h = 1e-6 * max(1.0, float(np.max(hf)))
        c = (self.face_flux(hf + eps_h, grad) - f0) / eps_h
        dt = self.cfl * self.dx / max(float(np.max(np.abs(c))), 1e-300)
        if self.diffusive:
            eps_g = 1e-6
            D = -(self.face_flux(hf, grad + eps_g) - f0) / eps_g
            Dmax = float(np.max(np.abs(D)))
            if Dmax > 0:
                dt = min(dt, self.cfl * self.dx ** 2 / (2.0 * Dmax))
        return dt

    def step(self, h, dt):
        """One SSP-RK2 (Heun) step."""
        h1 = h + dt * self.rhs(h)
        a1, c1 = self._last
        h2 = 0.5 * (h + h1 + dt * self.rhs(h1))
        a2, c2 = self._last
        self.n_arrested = max(self.n_arrested, a1, a2)
        self.n_accelerating = max(self.n_accelerating, c1, c2)
        return h2


def local_equilibrium_layer(closures: FlowClosures, x, h0, t_end: float, *,
                            diffusive: bool = True, times=None, n_out: int = 51,
                            cfl: float = 0.4, F_max: float = 50.0, check: bool = True,
                            extrapolate: bool = False,
                            max_steps: int = 2_000_000) -> xr.Dataset:
    """Solve the local-equilibrium (kinematic/diffusive-wave) layer from h0(x) on the cell
    centres ``x`` (uniform spacing, periodic domain of length n dx) to ``t_end``.

    ``diffusive``: keep the pressure gradient in the friction balance (diffusive wave, default)
    or drop it (kinematic wave).  ``times``: output times (default ``n_out`` equally spaced in
    [0, t_end]).  ``check``: run the library's evaluators on the initial state (fitted range /
    (h, F) hull, unless ``extrapolate``).  Returns h(t, x), u_bar(t, x) (the equilibrium
    velocity at the cell centres), mass(t) and the fraction of cells outside the closure's
    fitted ranges, with CF attributes and the closures' status.
    """
    x = np.asarray(x, float)
    dx = _cell_spacing(x)
    h = np.broadcast_to(np.asarray(h0, float), x.shape).copy()
    if not (np.all(np.isfinite(h)) and np.all(h > 0)):
        raise ValueError("h0 must be finite and > 0 everywhere (a wet periodic layer)")
    times = _output_times(times, t_end, n_out)
    if not closures.tan_theta > 0:
        raise ValueError(f"theta = {closures.theta!r} is out of range: the local-equilibrium "
                         "layer flows downslope, allowed (0, 90) degrees")
    check_range("F_max", F_max, 0.0, math.inf, lo_open=True)
    solver = LocalEquilibriumSolver(closures, dx, diffusive=diffusive, cfl=cfl, F_max=F_max)
    gc = closures.g_cos

    def centre_velocity(hh):
        grad = (np.roll(hh, -1) - np.roll(hh, 1)) / (2 * dx)
        target = closures.tan_theta - (closures.K * grad if diffusive else 0.0)
        F, _, _ = equilibrium_froude(closures, hh, target, F_max=F_max)
        return F * np.sqrt(gc * hh)

    if check:
        closures.check(h, centre_velocity(h) / np.sqrt(gc * h), extrapolate=extrapolate)
    rng = closures.fitted_ranges()
    out_h, out_u, out_frac = [], [], []

    def record():
        u = centre_velocity(h)
        out_h.append(h.copy())
        out_u.append(u)
        if rng is None:
            out_frac.append(np.nan)
        else:
            F = u / np.sqrt(gc * h)
            bad = (h < rng["h"][0]) | (h > rng["h"][1]) | (F < rng["F"][0]) | (F > rng["F"][1])
            out_frac.append(float(np.mean(bad)))

    t, k, steps = 0.0, 0, 0
    while k < times.size and times[k] <= t + 1e-12 * max(1.0, t):
        record()
        k += 1
    while k < times.size:
        dt = min(solver.stable_dt(h), times[k] - t)
        h = solver.step(h, dt)
        t = times[k] if abs(times[k] - (t + dt)) <= 1e-12 * max(1.0, t) else t + dt
        steps += 1
        if steps > max_steps:
            raise RuntimeError(f"more than {max_steps} time steps")
        if not (np.all(np.isfinite(h)) and np.all(h > 0)):
            raise RuntimeError(f"local-equilibrium solution lost positivity at t = {t:g}")
        while k < times.size and times[k] <= t + 1e-12 * max(1.0, t):
            record()
            k += 1
    H = np.array(out_h)
    ds = _layer_dataset(x, times, H, out_u, out_frac, dx,
                        "depth-averaged velocity in local equilibrium u_e(h, dh/dx)",
                        "fraction of cells with (h, F) outside the closure's fitted "
                        "ranges (NaN for synthetic closures)")
    ds.attrs.update(closures.attrs(), equation=EQ_DIFFUSIVE if diffusive else EQ_KINEMATIC,
                    bc="periodic", cfl=cfl, dx=dx, F_max=float(F_max), n_steps=steps,
                    n_faces_arrested_max=solver.n_arrested,
                    n_faces_accelerating_max=solver.n_accelerating,
                    scheme="upwind MUSCL-minmod face depth, equilibrium flux by bisection of "
                           "mu(h, F), SSP-RK2")
    kind = "diffusive_wave" if diffusive else "kinematic_wave"
    return finish(ds, kind, f"{kind.replace('_', '-')} layer (local equilibrium of Eq. 34)",
                  "Depth-averaged granular flow h(x, t) in local equilibrium with the closure "
                  "relations' friction law (mass balance of Weinhart et al. 2012 Eq. 34).")
