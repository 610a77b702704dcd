"""One-dimensional depth-averaged shallow-layer solver: Weinhart et al. (2012) Eq. (34).

Solves, on an inclined flat base (b = 0) with constant depth-averaged density (Eq. 52 depends on
theta only, so rho_bar cancels),

    dh/dt + d(h u)/dx = 0                                                         (34a)
    d(h u)/dt + d(alpha h u^2 + K g cos(theta) h^2 / 2)/dx
        = g h (sin(theta) - mu(h, F) cos(theta) u/|u|)                            (34b, c)

with F = |u| / sqrt(g h cos(theta)) and the closures mu(h, F) (Eq. 50), alpha(h) (Eq. 54/55)
and K (Eq. 53) of a :class:`~granflow.continuum.FlowClosures` (a closure library or synthetic).

Scheme (finite volumes on a uniform grid of cell averages):

* Strang splitting: half a friction step, a full transport step, half a friction step.
* Transport: MUSCL reconstruction of (h, u) with the minmod limiter, HLL fluxes with the wave
  speeds alpha u -+ c, c = sqrt(alpha (alpha - 1) u^2 + K g cos(theta) h) (the eigenvalues of
  the flux Jacobian at fixed alpha; Einfeldt-type min/max over both sides; alpha u + 2c at a
  dry neighbour, the speed of a wet/dry front), second-order SSP Runge-Kutta
  (Heun), time step from the CFL number (default 0.4).  Cell averages of h change only by flux
  differences, so mass is conserved to round-off on a periodic domain.  Faces with h below
  ``h_dry`` are dry (u = 0 there).
* Friction: in each wet cell du/dt = g cos(theta) (tan(theta) - mu(h, F) sign(u)) at fixed h
  (the transport step leaves the source out), four RK4 sub-steps per half step; a cell whose
  velocity would change sign while friction can hold it (tan(theta) <= mu(h, 0)) comes to rest
  (u = 0), as in the uniform-layer ODE.  Consequences: a uniform layer stays uniform (equal
  fluxes) and follows the ODE of :mod:`granflow.continuum.uniform` to the RK4 error; a steady
  uniform flow (mu(h, F) = tan(theta)) stays steady to round-off.
* Boundaries: ``periodic`` (the particle chute) or ``open`` (zero-gradient ghost cells, for
  the dam break).
* Optional depth-averaged viscous stress (``viscosity`` nu > 0; default 0: Eq. 34 as the paper
  writes it): d(h u)/dt gains d(nu h^(3/2) du/dx)/dx, the term of the depth-averaged
  mu(I)-rheology of Gray & Edwards (2014, J. Fluid Mech. 755, 503), with
  nu = (2/9) (L sqrt(g) / beta) sin(theta) / sqrt(cos(theta)) (tan(zeta2) - tan(theta)) /
  (tan(theta) - tan(zeta1)) = (2/9) tan(theta) sqrt(g cos(theta)) hstop(theta) / beta
  (:meth:`FlowClosures.gray_edwards_viscosity` takes it from the closures' own steady flow
  rule).  Discretised in conservative form inside the transport step (face viscous fluxes
  nu h_f^(3/2) (u_R - u_L) / dx, h_f the mean of the two cells, zero at a dry face), so
  momentum is still changed only by flux differences and by friction; the time step also
  obeys the diffusive limit dt <= cfl dx^2 / max(nu h^(1/2)).  A uniform layer has du/dx = 0:
  the term vanishes and the uniform limit and steady flows are unchanged.

Tests: exact mass conservation, steady uniform flow, agreement with the uniform-layer ODE, and
the Coulomb-friction dam break of Mangeney et al. (2000) (:func:`granflow.continuum.exact.
mangeney_dam_break`, checked against tilupy's independent implementation).

Example::

    import numpy as np
    from granflow.continuum import FlowClosures, shallow_layer

    c = FlowClosures.coulomb(theta=30.0, mu=np.tan(np.radians(20.0)))
    x = np.linspace(-50, 50, 401)[:-1] + 0.125          # cell centres, dx = 0.25
    res = shallow_layer(c, x, h0=np.where(x < 0, 4.0, 0.0), u0=0.0, t_end=5.0, bc="open")
    res.h.sel(t=5.0).plot()
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr

from .. import units as U
from ..engine.species import check_range
from .closures import FlowClosures
from .output import finish

EQ = "Weinhart et al. 2012 Eq. (34a-c), flat base"
VISCOUS = (" + depth-averaged viscous stress d(nu h^(3/2) du/dx)/dx (Gray & Edwards 2014, "
           "J. Fluid Mech. 755, 503)")
BCS = ("periodic", "open")


def _minmod(a, b):
    return np.where(a * b > 0, np.sign(a) * np.minimum(np.abs(a), np.abs(b)), 0.0)


class _Tabulated:
    """alpha(h) tabulated on a log grid (alpha of Eq. 54 integrates a profile per call)."""

    def __init__(self, fn, h_max):
        hs = np.geomspace(1e-3 * max(h_max, 1e-3), 4.0 * max(h_max, 1e-3), 400)
        vals = np.asarray(fn(hs), float)
        if vals.shape != hs.shape:
            vals = np.broadcast_to(vals, hs.shape)
        self.const = bool(np.all(vals == vals[0]))
        self.lh = np.log(hs)
        self.vals = np.where(np.isfinite(vals), vals, 1.0)

    def __call__(self, h):
        h = np.asarray(h, float)
        if self.const:
            return np.full(h.shape, self.vals[0])
        return np.interp(np.log(np.maximum(h, 1e-300)), self.lh, self.vals)


def _ghost(a, bc, n=2):
    if bc == "periodic":
        return np.concatenate([a[-n:], a, a[:n]])
    return np.concatenate([np.full(n, a[0]), a, np.full(n, a[-1])])


def _cell_spacing(x) -> float:
    """Spacing of the cell centres ``x`` (1-D, at least 4, uniform and increasing) or
    ValueError naming what is wrong."""
    if x.size < 4 or x.ndim != 1:
        raise ValueError(f"x must hold at least 4 cell centres, got shape {x.shape}")
    dxs = np.diff(x)
    dx = float(np.mean(dxs))
    if not (dx > 0 and np.allclose(dxs, dx, rtol=1e-9, atol=0)):
        raise ValueError("x must be uniformly spaced and increasing")
    return dx


def _output_times(times, t_end: float, n_out: int):
    """The output times: ``n_out`` equally spaced in [0, t_end] or ``times`` (checked)."""
    if not (math.isfinite(t_end) and t_end > 0):
        raise ValueError(f"t_end = {t_end!r} is out of range: allowed (0, inf)")
    times = np.linspace(0.0, t_end, int(n_out)) if times is None else np.asarray(times, float)
    if times.ndim != 1 or times.size < 1 or np.any(np.diff(times) <= 0) or times[0] < 0 \
            or times[-1] > t_end * (1 + 1e-12):
        raise ValueError("times must increase within [0, t_end]")
    return times


def _layer_dataset(x, times, H, u, frac, dx, u_long_name, frac_long_name) -> xr.Dataset:
    """h(t, x), u_bar(t, x), mass(t) and the fitted-range fraction(t) with CF attributes."""
    return xr.Dataset(
        {"h": (("t", "x"), H, U.cf(U.LENGTH, "flow height h (cell average)")),
         "u_bar": (("t", "x"), np.array(u), U.cf(U.VELOCITY, u_long_name)),
         "mass": ("t", H.sum(axis=1) * dx, U.cf(
             "d2", "integral of h dx over the domain (volume per unit width)")),
         "fraction_outside_fitted_range": ("t", np.array(frac), U.cf(
             U.DIMENSIONLESS, frac_long_name))},
        coords={"t": ("t", times, U.cf(U.TIME, "time")),
                "x": ("x", x, U.cf(U.LENGTH, "downslope position (cell centre)", axis="X"))})


class ShallowLayerSolver:
    """Explicit finite-volume solver of Eq. (34) (module docstring); use :func:`shallow_layer`."""

    def __init__(self, closures: FlowClosures, dx: float, n: int, *, bc="periodic", cfl=0.4,
                 h_dry=1e-6, h_scale=1.0, n_substeps=4, viscosity=0.0):
        if bc not in BCS:
            raise ValueError(f"bc = {bc!r} is unknown: allowed {list(BCS)}")
        # a string or None is named too (not Python's TypeError from a comparison)
        cfl = check_range("cfl", cfl, 0.0, 0.5, lo_open=True)
        self.nu = check_range("viscosity", viscosity, 0.0, math.inf, hi_open=True)
        self.c = closures
        self.dx = float(dx)
        self.n = int(n)
        self.bc = bc
        self.cfl = float(cfl)
        self.h_dry = float(h_dry)
        self.k = closures.K * closures.g_cos
        self.alpha = _Tabulated(closures.alpha, h_scale)
        self.n_sub = int(n_substeps)
        self.n_rest = 0  # cell-steps brought to rest by friction

    # ------------------------------------------------------------------ transport
    def _speeds(self, h, u, a):
        c2 = np.maximum(a * (a - 1.0) * u * u + self.k * h, 0.0)
        c = np.sqrt(c2)
        return a * u - c, a * u + c

    def _flux(self, h, u, a):
        return h * u, a * h * u * u + 0.5 * self.k * h * h

    def rhs(self, h, m):
        """-(dF/dx) of the transport part for cell averages h, m = h u."""
        wet = h > self.h_dry
        u = np.where(wet, m / np.where(wet, h, 1.0), 0.0)
        hg, ug = _ghost(h, self.bc), _ghost(u, self.bc)
        dh = _minmod(hg[1:-1] - hg[:-2], hg[2:] - hg[1:-1])
        du = _minmod(ug[1:-1] - ug[:-2], ug[2:] - ug[1:-1])
        hc, uc = hg[1:-1], ug[1:-1]                     # n + 2 cells (one ghost each side)
        hL, hR = hc[:-1] + 0.5 * dh[:-1], hc[1:] - 0.5 * dh[1:]   # n + 1 faces
        uL, uR = uc[:-1] + 0.5 * du[:-1], uc[1:] - 0.5 * du[1:]
        uL = np.where(hL > self.h_dry, uL, 0.0)
        uR = np.where(hR > self.h_dry, uR, 0.0)
        aL, aR = self.alpha(hL), self.alpha(hR)
        sL1, sR1 = self._speeds(hL, uL, aL)
        sL2, sR2 = self._speeds(hR, uR, aR)
        sL = np.minimum(sL1, sL2)
        sR = np.maximum(sR1, sR2)
        # dry bed on one side: the front moves at u + 2c (Toro's wet/dry HLL speeds)
        dryR, dryL = hR <= self.h_dry, hL <= self.h_dry
        sR = np.where(dryR, aL * uL + 2.0 * (aL * uL - sL1), sR)
        sL = np.where(dryL, aR * uR - 2.0 * (sR2 - aR * uR), sL)
        f1L, f2L = self._flux(hL, uL, aL)
        f1R, f2R = self._flux(hR, uR, aR)
        mL, mR = hL * uL, hR * uR
        den = np.where(sR - sL > 0, sR - sL, 1.0)
        f1 = (sR * f1L - sL * f1R + sL * sR * (hR - hL)) / den
        f2 = (sR * f2L - sL * f2R + sL * sR * (mR - mL)) / den
        f1 = np.where(sL >= 0, f1L, np.where(sR <= 0, f1R, f1))
        f2 = np.where(sL >= 0, f2L, np.where(sR <= 0, f2R, f2))
        smax = float(np.max(np.maximum(np.abs(sL), np.abs(sR)))) if sL.size else 0.0
        if self.nu > 0:
            # depth-averaged viscous stress (Gray & Edwards 2014): face flux nu h^(3/2) du/dx
            # from the cell averages, zero at a face with a dry side
            hf = 0.5 * (hc[:-1] + hc[1:])
            dry_face = (hc[:-1] <= self.h_dry) | (hc[1:] <= self.h_dry)
            g = np.where(dry_face, 0.0, self.nu * hf * np.sqrt(hf) * (uc[1:] - uc[:-1])
                         / self.dx)
            f2 = f2 - g
        return -(f1[1:] - f1[:-1]) / self.dx, -(f2[1:] - f2[:-1]) / self.dx, smax

    def max_speed(self, h, m):
        wet = h > self.h_dry
        u = np.where(wet, m / np.where(wet, h, 1.0), 0.0)
        s1, s2 = self._speeds(h, u, self.alpha(h))
        return float(np.max(np.maximum(np.abs(s1), np.abs(s2))))

    # ------------------------------------------------------------------ friction
    def friction(self, h, m, dt):
        """Integrate du/dt = source at fixed h over dt in the wet cells (RK4 sub-steps)."""
        wet = h > self.h_dry
        if not wet.any():
            return m
        hw = h[wet]
        u = m[wet] / hw
        c = self.c
        mu0 = np.asarray(c.mu(hw, np.zeros_like(hw)), float)
        holds = abs(c.tan_theta) <= mu0
        tau = dt / self.n_sub
        for _ in range(self.n_sub):
            k1 = c.acceleration(hw, u)
            k2 = c.acceleration(hw, u + 0.5 * tau * k1)
            k3 = c.acceleration(hw, u + 0.5 * tau * k2)
            k4 = c.acceleration(hw, u + tau * k3)
            new = u + tau / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
            stop = holds & (u != 0) & (np.sign(new) != np.sign(u))
            self.n_rest += int(np.count_nonzero(stop))
            u = np.where(stop, 0.0, new)
        out = m.copy()
        out[wet] = hw * u
        out[~wet] = 0.0
        return out

    # ------------------------------------------------------------------ stepping
    def step(self, h, m, dt):
        m = self.friction(h, m, 0.5 * dt)
        r1h, r1m, _ = self.rhs(h, m)
        h1, m1 = h + dt * r1h, m + dt * r1m
        r2h, r2m, _ = self.rhs(h1, m1)
        h2 = 0.5 * (h + h1 + dt * r2h)
        m2 = 0.5 * (m + m1 + dt * r2m)
        neg = h2 < 0
        if neg.any():  # round-off below zero at a dry front
            h2 = np.where(neg, 0.0, h2)
            m2 = np.where(neg, 0.0, m2)
        return h2, self.friction(h2, m2, 0.5 * dt)

    def stable_dt(self, h, m):
        s = self.max_speed(h, m)
        dt = self.cfl * self.dx / s if s > 0 else math.inf
        if self.nu > 0:
            # diffusive limit of the viscous term: du/dt ~ nu h^(1/2) d2u/dx2
            diff = self.nu * math.sqrt(float(np.max(h))) if h.size else 0.0
            if diff > 0:
                dt = min(dt, self.cfl * self.dx * self.dx / diff)
        return dt


def shallow_layer(closures: FlowClosures, x, h0, u0, t_end: float, *, bc: str = "periodic",
                  times=None, n_out: int = 51, cfl: float = 0.4, h_dry: float = 1e-6,
                  check: bool = True, extrapolate: bool = False,
                  max_steps: int = 10_000_000, viscosity: float = 0.0) -> xr.Dataset:
    """Solve Eq. (34) from h0(x), u0(x) on cell centres ``x`` (uniform spacing) to ``t_end``.

    ``bc``: ``periodic`` (domain length = n dx) or ``open``.  ``times``: output times (default
    ``n_out`` equally spaced in [0, t_end]); the time step is shortened to hit them.  ``check``:
    run the library's evaluators on the initial wet state (fitted range / (h, F) hull, unless
    ``extrapolate``).  Returns h(t, x), u_bar(t, x), mass(t) = sum h dx and, per output time,
    the fraction of wet cells whose (h, F) lie outside the closure's fitted ranges.
    ``viscosity``: the coefficient nu of the depth-averaged viscous stress d(nu h^(3/2)
    du/dx)/dx (module docstring; 0, the default: Eq. 34 without it; e.g.
    ``closures.gray_edwards_viscosity(h_ref)``).
    """
    x = np.asarray(x, float)
    n = x.size
    dx = _cell_spacing(x)
    h = np.broadcast_to(np.asarray(h0, float), x.shape).copy()
    u = np.broadcast_to(np.asarray(u0, float), x.shape).copy()
    if not (np.all(np.isfinite(h)) and np.all(h >= 0)):
        raise ValueError("h0 must be finite and >= 0 everywhere")
    if not np.all(np.isfinite(u)):
        raise ValueError("u0 must be finite")
    times = _output_times(times, t_end, n_out)
    wet = h > h_dry
    gc = closures.g_cos
    if check and wet.any():
        closures.check(h[wet], np.abs(u[wet]) / np.sqrt(gc * h[wet]), extrapolate=extrapolate)
    m = np.where(wet, h * u, 0.0)
    solver = ShallowLayerSolver(closures, dx, n, bc=bc, cfl=cfl, h_dry=h_dry,
                                h_scale=float(h.max()) if h.max() > 0 else 1.0,
                                viscosity=viscosity)
    rng = closures.fitted_ranges()
    out_h, out_u, out_frac = [], [], []
    t, k, steps = 0.0, 0, 0

    def record():
        w = h > h_dry
        uu = np.where(w, m / np.where(w, h, 1.0), 0.0)
        out_h.append(h.copy())
        out_u.append(np.where(w, uu, np.nan))
        if rng is None or not w.any():
            out_frac.append(np.nan)
        else:
            F = np.abs(uu[w]) / np.sqrt(gc * h[w])
            bad = (h[w] < rng["h"][0]) | (h[w] > rng["h"][1]) | (F < rng["F"][0]) | \
                (F > rng["F"][1])
            out_frac.append(float(np.mean(bad)))

    while k < times.size and times[k] <= t + 1e-12 * max(1.0, t):
        record()
        k += 1
    while k < times.size:
        dt = min(solver.stable_dt(h, m), times[k] - t)
        if not math.isfinite(dt):  # nothing moves: the state is constant
            dt = times[k] - t
        h, m = solver.step(h, m, dt)
        t = times[k] if abs(times[k] - (t + dt)) <= 1e-12 * max(1.0, t) else t + dt
        steps += 1
        if steps > max_steps:
            raise RuntimeError(f"more than {max_steps} time steps")
        if not (np.all(np.isfinite(h)) and np.all(np.isfinite(m))):
            raise RuntimeError(f"shallow-layer solution became non-finite at t = {t:g}")
        while k < times.size and times[k] <= t + 1e-12 * max(1.0, t):
            record()
            k += 1
    H = np.array(out_h)
    ds = _layer_dataset(x, times, H, out_u, out_frac, dx,
                        "depth-averaged velocity u_bar = (h u)/h (NaN in dry cells)",
                        "fraction of wet cells with (h, F) outside the closure's "
                        "fitted ranges (NaN for synthetic closures)")
    ds.attrs.update(closures.attrs(), equation=EQ if solver.nu == 0 else EQ + VISCOUS,
                    bc=bc, cfl=cfl, dx=dx, h_dry=h_dry, viscosity=solver.nu,
                    n_steps=steps, n_cells_brought_to_rest=solver.n_rest,
                    scheme="MUSCL-minmod + HLL, SSP-RK2, Strang-split RK4 friction"
                    + ("" if solver.nu == 0 else ", central viscous fluxes"))
    return finish(ds, "shallow_layer", "shallow-layer solution (Eq. 34)",
                  "Depth-averaged granular flow h(x, t), u(x, t) from the shallow-layer "
                  "equations of Weinhart et al. 2012 Eq. 34 with closure relations.")
