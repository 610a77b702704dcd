"""Self-diffusion of tagged particles normal to the base, and the diffusivity closure.

The segregation-remixing equation (Thornton et al. T-eq. 27) needs, besides Ps = S h / D, the
diffusivity D itself: it sets the time scale h^2 / D of segregation.  It is measured in steady
particle runs from the mean squared displacement of every flow particle in z,

    MSD(tau) = < (z_i(t + tau) - z_i(t))^2 >_{i, t}  ->  2 D tau,

fitted over lags ``tau_fit`` (after the short-time ballistic/caged regime, well before the
finite depth bounds the displacements: 2 D tau << h^2), averaged over time origins in the steady
window.  Its standard error comes from splitting the particles into independent groups (batch
means over groups of particles, each with its own fit).

Scaling (:func:`fit_diffusivity`): shear-induced self-diffusion scales as D ~ shear rate x d^2
(Savage & Dai 1993; Utter & Behringer 2004; Fan et al. 2014, D = 0.042 gamma_dot d^2 in
bidisperse heap flows, with d the local mean diameter).  In a depth-averaged model the shear-rate
scale is u_bar / h, so the closure stored in a library (kind ``diffusivity``) is

    D = c_D (u_bar / h) d_mean^2,

c_D fitted by weighted least squares over the runs (Birge-inflated covariance, ensemble drawn
from it, held-out z per run: :func:`granflow.fitting.forms.fit_forms`); evaluate it with
``lib.closures.diffusivity(u_bar, h, d_mean=...)``.

:class:`TracerObserver` records z of every flow particle at a fixed interval during a run (a
few MB for a small chute) so the MSD can be computed afterwards over the window found steady.
"""

from __future__ import annotations

import math

import numpy as np

from ..fitting.forms import Form, fit_forms
from ..fitting.result import data_range, failed_fit

DIFFUSIVITY_EQ = "self-diffusion D = c_D (u_bar/h) d^2 (shear-rate scaling; Fan et al. 2014)"


class TracerObserver:
    """Record the heights z of all flow particles every ``every``-th sample (and the time)."""

    name = "tracers"

    def __init__(self, every: int = 1):
        self.every = max(1, int(every))
        self._calls = 0
        self.times: list[float] = []
        self.z: list[np.ndarray] = []
        self.diameter = None

    def sample(self, system):
        self._calls += 1
        if (self._calls - 1) % self.every:
            return
        # in identity order: the engine may re-sort large systems (ParticleSystem.ids)
        order = system.id_order()
        flow = order[~system.fixed[order]]
        if self.diameter is None:
            self.diameter = 2.0 * system.radius[flow]
        self.times.append(float(system.time))
        self.z.append(system.pos[flow, 2].copy())

    def state_dict(self) -> dict:
        n = len(self.diameter) if self.diameter is not None else 0
        return {"times": np.asarray(self.times, float),
                "z": np.asarray(self.z, float).reshape(-1, n),
                "diameter": np.zeros(0) if self.diameter is None else self.diameter,
                "observer_calls": np.int64(self._calls), "every": np.int64(self.every)}

    def load_state_dict(self, state: dict):
        self._calls = int(state["observer_calls"])
        self.every = int(state["every"])
        self.times = [float(t) for t in np.asarray(state["times"])]
        self.z = list(np.asarray(state["z"], float))
        d = np.asarray(state["diameter"], float)
        self.diameter = d if d.size else None

    def arrays(self):
        return np.asarray(self.times), np.asarray(self.z), self.diameter


def _window(t, z, t_from: float):
    """The samples at t >= t_from (times, heights) and their sample interval."""
    t = np.asarray(t, float)
    z = np.asarray(z, float)
    keep = t >= t_from - 1e-9
    t, z = t[keep], z[keep]
    if t.size < 3:
        raise ValueError(f"too few samples after t = {t_from}: {t.size}")
    return t, z, float(np.median(np.diff(t)))


def msd_z(t, z, t_from: float, lags):
    """Mean squared z-displacement at the given lags (in time units, multiples of the sample
    interval) over all particles and time origins in [t_from, t_end]: array (len(lags), n)
    per particle."""
    t, z, dt = _window(t, z, t_from)
    out = []
    for lag in lags:
        k = int(round(lag / dt))
        if k < 1 or k >= t.size:
            raise ValueError(f"lag {lag} outside the window (sample interval {dt}, "
                             f"{t.size} samples)")
        out.append(np.mean((z[k:] - z[:-k]) ** 2, axis=0))
    return np.asarray(out)


def self_diffusivity(t, z, t_from: float, *, tau_fit=(2.0, 10.0), n_lags: int = 9,
                     n_groups: int = 10, seed: int = 0) -> dict:
    """D from MSD(tau) = 2 D tau + c fitted over ``tau_fit`` (module docstring).

    Returns D, D_stderr (batch means over ``n_groups`` random particle groups), the lags and
    the mean MSD, the window and the particle count.
    """
    lags = np.linspace(tau_fit[0], tau_fit[1], int(n_lags))
    per = msd_z(t, z, t_from, lags)                     # (lags, particles)
    n = per.shape[1]

    def slope(cols):
        y = per[:, cols].mean(axis=1)
        return 0.5 * np.polyfit(lags, y, 1)[0]

    D = float(slope(slice(None)))
    rng = np.random.default_rng(seed)
    groups = np.array_split(rng.permutation(n), int(n_groups))
    vals = np.array([slope(g) for g in groups if len(g)])
    se = float(np.std(vals, ddof=1) / math.sqrt(len(vals))) if len(vals) > 1 else math.nan
    tt = np.asarray(t)
    return {"D": D, "D_stderr": se, "lags": lags.tolist(), "msd": per.mean(axis=1).tolist(),
            "t_from": float(t_from), "t_to": float(tt[-1]), "n_particles": int(n),
            "tau_fit": [float(tau_fit[0]), float(tau_fit[1])]}


def fit_diffusivity(D, D_stderr, u_bar, h, *, d_mean=1.0, theta=None, contact_law=None,
                    ids=None, selection: str = "", seed: int = 0):
    """Fit D = c_D (u_bar/h) d_mean^2 to per-run diffusivities (FitResult kind
    ``diffusivity``; valid ranges of h, u_bar and theta)."""
    D, s, u, hh = (np.asarray(a, float).ravel() for a in (D, D_stderr, u_bar, h))
    dm = np.broadcast_to(np.asarray(d_mean, float), D.shape)
    x = u / hh * dm ** 2
    ok = np.isfinite(D) & np.isfinite(x) & (x > 0)
    n = int(ok.sum())
    ids = np.asarray(ids if ids is not None else np.arange(D.size)).astype(str)
    coords = dict(contact_law=contact_law)
    if n < 2:
        return failed_fit("diffusivity", DIFFUSIVITY_EQ, ("c_D",), f"too few runs: {n}", n,
                          **coords)
    form = Form("scaled", lambda xx, c: c * xx, ("c_D",),
                lambda xx, yy: [float(np.sum(xx * yy) / np.sum(xx * xx))],
                "D = c_D (u_bar/h) d^2", min_points=2)
    rng = {"h": data_range(hh[ok]), "u_bar": data_range(u[ok])}
    if theta is not None:
        rng["theta"] = data_range(np.asarray(theta, float).ravel()[ok])
    return fit_forms("diffusivity", DIFFUSIVITY_EQ, ("c_D",), [form], x[ok], D[ok],
                     sigma=s[ok], ids=ids[ok], coords=coords, valid_range=rng,
                     error_measure="Eq. (49) of D - D_fit", selection=selection, seed=seed)


def self_diffusivity_profile(t, z, t_from: float, edges, *, tau_fit=(2.0, 10.0),
                             n_lags: int = 9) -> list[dict]:
    """D in z per height band: the MSD over ``tau_fit`` of the displacements that *start* in
    each band [edges[i], edges[i+1]) (every time origin after ``t_from``), fitted as
    :func:`self_diffusivity`.  A particle leaves its band within the lag (rms sqrt(2 D tau),
    ~0.7 d at D = 0.024, tau = 10), so bands narrower than ~2 d blur into their neighbours."""
    t, z, dt = _window(t, z, t_from)
    lags = np.linspace(tau_fit[0], tau_fit[1], int(n_lags))
    ks = [int(round(lag / dt)) for lag in lags]
    if ks[0] < 1 or ks[-1] >= t.size:
        raise ValueError(f"tau_fit = {tau_fit} is out of range: allowed within the window "
                         f"({dt:g} ... {t[-1] - t[0]:g})")
    edges = np.asarray(edges, float)
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        msd, count = [], []
        for k in ks:
            z0 = z[:-k]
            m = (z0 >= a) & (z0 < b)
            dz = (z[k:] - z0)[m]
            msd.append(float(np.mean(dz ** 2)) if dz.size else math.nan)
            count.append(int(dz.size))
        D = 0.5 * float(np.polyfit(lags, msd, 1)[0]) if min(count) > 0 else math.nan
        out.append({"z_from": float(a), "z_to": float(b), "D": D, "n": int(min(count))})
    return out
