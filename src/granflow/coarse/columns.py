"""Depth-integrated coarse-graining along the slope: h(x, t) and u_bar(x, t) of a long chute.

For comparisons with the shallow-layer equations (Weinhart et al. 2012 Eq. 34) the fields are
integrated over the depth z and the width y exactly and coarse-grained along x with the
Gaussian of Eq. (14) (width w_x, truncated at ``cutoff`` w_x and renormalised, the kernel of
:mod:`granflow.coarse._kernels`, whose CDF it reuses):

    M(x, t) = (1/Ly) sum_i m_i W(x - x_i)           mass per unit bed area   (Eq. 13 in x)
    P(x, t) = (1/Ly) sum_i m_i v_x,i W(x - x_i)     momentum per unit area   (Eq. 16 in x)

on a periodic x grid, as *cell averages* over bins of width dx (the kernel integrated over each
bin with its CDF, periodic images included), so sum_k M_k dx = total flow mass / Ly exactly.
Eq. (34) is written for rho_bar h and rho_bar h u_bar, so h = M / rho_bar and
u_bar = P / M (the mass-weighted depth average; Eq. 33's u_bar is the plain depth mean of V_x,
equal to it where the density is uniform in depth), with rho_bar the depth-averaged density of
the uniform flow (:func:`column_fields`).

Only per-snapshot sums are kept (no trajectories); :class:`ColumnObserver` plugs into a
:class:`granflow.engine.run.ChuteRun` like the depth-profile observer and checkpoints with it.
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr
from numba import njit

from .. import units as U
from ._kernels import kernel_cdf, kernel_norm


@njit(cache=True)
def _bin_weights(x, mass, vx, x0, dx, nx, width, cutoff, out_m, out_p):
    """Add each particle's kernel mass integrated over each periodic bin to out_m, out_p."""
    norm = kernel_norm(cutoff)
    L = nx * dx
    half = cutoff * width
    for i in range(x.shape[0]):
        xi = x[i] - x0
        xi = xi - math.floor(xi / L) * L
        k0 = int(math.floor((xi - half) / dx))
        k1 = int(math.floor((xi + half) / dx))
        g_lo = kernel_cdf(k0 * dx - xi, width, cutoff, norm)
        for k in range(k0, k1 + 1):
            g_hi = kernel_cdf((k + 1) * dx - xi, width, cutoff, norm)
            w = g_hi - g_lo
            g_lo = g_hi
            kk = k % nx
            out_m[kk] += mass[i] * w
            out_p[kk] += mass[i] * vx[i] * w


class ColumnAccumulator:
    """Per-snapshot depth-integrated mass and momentum per unit area in periodic x bins.

    Parameters: ``Lx``, ``Ly`` (box), ``nx`` (bins), ``width`` (Gaussian w_x, default one bin
    width), ``cutoff`` (in widths, default 4).
    """

    def __init__(self, Lx: float, Ly: float, nx: int, width: float | None = None,
                 cutoff: float = 4.0):
        if not (Lx > 0 and Ly > 0 and nx >= 2):
            raise ValueError(f"need Lx, Ly > 0 and nx >= 2, got {Lx}, {Ly}, {nx}")
        self.Lx, self.Ly, self.nx = float(Lx), float(Ly), int(nx)
        self.dx = self.Lx / self.nx
        self.width = float(width) if width is not None else self.dx
        if not self.width > 0 or cutoff <= 0:
            raise ValueError("width and cutoff must be > 0")
        if 2 * cutoff * self.width >= self.Lx:
            raise ValueError(f"kernel support 2 x {cutoff} x {self.width} exceeds Lx = {self.Lx}")
        self.cutoff = float(cutoff)
        self.times: list[float] = []
        self.mass: list[np.ndarray] = []
        self.momentum: list[np.ndarray] = []

    @property
    def x(self) -> np.ndarray:
        return (np.arange(self.nx) + 0.5) * self.dx

    def add_snapshot(self, time, pos, vel, mass, fixed):
        flow = ~np.asarray(fixed, dtype=bool)
        m = np.zeros(self.nx)
        p = np.zeros(self.nx)
        _bin_weights(np.ascontiguousarray(pos[flow, 0], dtype=np.float64),
                     np.ascontiguousarray(mass[flow], dtype=np.float64),
                     np.ascontiguousarray(vel[flow, 0], dtype=np.float64), 0.0, self.dx,
                     self.nx, self.width, self.cutoff, m, p)
        scale = 1.0 / (self.dx * self.Ly)
        self.times.append(float(time))
        self.mass.append(m * scale)
        self.momentum.append(p * scale)

    def state_dict(self) -> dict:
        return {"Lx": self.Lx, "Ly": self.Ly, "nx": self.nx, "width": self.width,
                "cutoff": self.cutoff, "times": np.asarray(self.times, float),
                "mass": np.asarray(self.mass, float).reshape(-1, self.nx),
                "momentum": np.asarray(self.momentum, float).reshape(-1, self.nx)}

    @classmethod
    def from_state_dict(cls, s) -> "ColumnAccumulator":
        def f(k):
            v = s[k]
            return v.item() if isinstance(v, np.ndarray) and v.ndim == 0 else v
        acc = cls(float(f("Lx")), float(f("Ly")), int(f("nx")), float(f("width")),
                  float(f("cutoff")))
        acc.times = [float(t) for t in np.asarray(s["times"])]
        acc.mass = list(np.asarray(s["mass"], float))
        acc.momentum = list(np.asarray(s["momentum"], float))
        return acc

    def to_dataset(self, attrs=None) -> xr.Dataset:
        if not self.times:
            raise ValueError("no snapshots accumulated")
        M = np.asarray(self.mass)
        P = np.asarray(self.momentum)
        with np.errstate(invalid="ignore", divide="ignore"):
            u = np.where(M > 0, P / np.where(M > 0, M, 1.0), np.nan)
        ds = xr.Dataset(
            {"mass_per_area": (("t", "x"), M, U.cf(U.MASS_PER_AREA, "depth-integrated flow mass "
                                                   "per unit bed area M(x, t) (bin average)")),
             "momentum_per_area": (("t", "x"), P, U.cf(
                 U.MASS_PER_AREA + " " + U.VELOCITY,
                 "depth-integrated downslope momentum per unit bed area (bin average)")),
             "u_bar": (("t", "x"), u, U.cf(U.VELOCITY, "mass-weighted depth-averaged velocity "
                                                       "P/M"))},
            coords={"t": ("t", np.asarray(self.times), U.cf(U.TIME, "simulated time")),
                    "x": ("x", self.x, U.cf(U.LENGTH, "downslope position (bin centre)",
                                            axis="X"))})
        ds.attrs.update(dict(attrs or {}), cg_x_kernel="Gaussian, truncated and renormalised, "
                        "integrated over each bin", cg_x_width=self.width, cg_x_dx=self.dx,
                        cg_x_cutoff_in_widths=self.cutoff, cg_Lx=self.Lx, cg_Ly=self.Ly)
        return ds


def column_fields(ds: xr.Dataset, rho_bar: float) -> xr.Dataset:
    """Add h = M / rho_bar (flow height of a layer of depth-averaged density rho_bar)."""
    out = ds.copy()
    out["h"] = ds["mass_per_area"] / float(rho_bar)
    out["h"].attrs = U.cf(U.LENGTH, f"flow height M / rho_bar (rho_bar = {rho_bar:.6g})")
    out.attrs["rho_bar"] = float(rho_bar)
    return out


class ColumnObserver:
    """Run observer: a :class:`ColumnAccumulator` snapshot every ``every``-th sample."""

    name = "columns"

    def __init__(self, acc: ColumnAccumulator, every: int = 1):
        self.acc = acc
        self.every = max(1, int(every))
        self._calls = 0

    def sample(self, system):
        self._calls += 1
        if (self._calls - 1) % self.every:
            return
        self.acc.add_snapshot(system.time, system.pos, system.vel, system.mass, system.fixed)

    def state_dict(self) -> dict:
        return dict(self.acc.state_dict(), observer_calls=np.int64(self._calls))

    def load_state_dict(self, state: dict):
        state = dict(state)
        self._calls = int(state.pop("observer_calls"))
        self.acc = ColumnAccumulator.from_state_dict(state)
