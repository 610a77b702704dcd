"""An independent estimator of depth profiles, for checking the Gaussian coarse-graining.

Sharp slabs instead of a Gaussian kernel, plain numpy instead of the numba kernels, and no
shared code with :mod:`granflow.coarse`: per snapshot, the plane-averaged fields are binned in
slabs [z_k, z_k + dz) (Irving-Kirkwood with a box kernel, the "volume average" of a slab):

* density: flow mass in the slab / (A dz); velocity: slab momentum / slab mass;
* kinetic stress: sum m (v - V_slab)_a (v - V_slab)_b / (A dz);
* contact stress of a flow-flow pair: f_a r_b times the fraction of the segment r_i -> r_j
  inside the slab, / (A dz) (compressive positive: f on i, r = r_i - r_j);
* base stress of a flow-base pair, along the path of ``base_line = "contact_then_down"``: the
  segment r_i -> contact point c as above (r = r_i - c), plus, for the az components, f_a
  times the length of [z_slab] below z_c, / dz (the vertical line carries f_a per unit depth).

Time averages are taken per time window so that the profile window of a run can be selected
afterwards.  This is the observer interface of :class:`granflow.engine.run.ChuteRun`.
"""

from __future__ import annotations

import math

import numpy as np

AB = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
NAMES = ("xx", "yy", "zz", "xy", "xz", "yz")


def _overlap(lo, hi, edges):
    """Length of [lo, hi] (arrays, lo <= hi) inside each slab [edges[k], edges[k+1])."""
    a = np.maximum(lo[:, None], edges[None, :-1])
    b = np.minimum(hi[:, None], edges[None, 1:])
    return np.clip(b - a, 0.0, None)


class SlabObserver:
    name = "slab_oracle"

    def __init__(self, edges, Lx, Ly, window=10.0, every=4):
        self.edges = np.asarray(edges, dtype=float)
        self.area = Lx * Ly
        self.window = window
        self.every = every
        self.calls = 0
        self.t_first = None
        self.sums = {}

    def state_dict(self):
        return {}

    def load_state_dict(self, state):
        pass

    def sample(self, system):
        self.calls += 1
        if (self.calls - 1) % self.every:
            return
        t = system.time
        if self.t_first is None:
            self.t_first = t
        k = int(math.floor((t - self.t_first) / self.window + 1e-9))
        acc = self.sums.setdefault(k, {"n": 0, "t0": self.t_first + k * self.window})
        nb = len(self.edges) - 1
        dz = np.diff(self.edges)
        vol = self.area * dz
        flow = ~system.fixed
        z = system.pos[flow, 2]
        m = system.mass[flow]
        v = system.vel[flow]
        idx = np.digitize(z, self.edges) - 1
        ok = (idx >= 0) & (idx < nb)
        mass = np.bincount(idx[ok], weights=m[ok], minlength=nb)
        mom = np.stack([np.bincount(idx[ok], weights=(m * v[:, a])[ok], minlength=nb)
                        for a in range(3)])
        V = np.where(mass > 0, mom / np.where(mass > 0, mass, 1.0), 0.0)
        dv = v[ok] - V[:, idx[ok]].T
        kin = np.stack([np.bincount(idx[ok], weights=m[ok] * dv[:, a] * dv[:, b], minlength=nb)
                        for a, b in AB]) / vol
        c = system.contacts()
        ci, cj, f, rij, cp = (c[k_] for k_ in ("contact_i", "contact_j", "contact_force",
                                                "contact_rij", "contact_point"))
        fixed = np.append(system.fixed, True)  # wall partner j = -1 -> index N
        cj = np.where(cj < 0, len(system.fixed), cj)
        ff = ~fixed[ci] & ~fixed[cj]
        fb = ~fixed[ci] & fixed[cj]
        con = np.zeros((6, nb))
        if ff.any():
            zi = system.pos[ci[ff], 2]
            zj = system.pos[cj[ff], 2]
            r = np.column_stack([rij[ff, 0], rij[ff, 1], zi - zj])
            frac = _overlap(np.minimum(zi, zj), np.maximum(zi, zj), self.edges) / \
                np.maximum(np.abs(zi - zj), 1e-300)[:, None]
            flat = np.abs(zi - zj) < 1e-12
            if flat.any():  # horizontal pair: all of it in the slab holding z_i
                frac[flat] = 0.0
                kk = np.digitize(zi[flat], self.edges) - 1
                good = (kk >= 0) & (kk < nb)
                frac[np.nonzero(flat)[0][good], kk[good]] = 1.0
            for q, (a, b) in enumerate(AB):
                con[q] = (f[ff, a] * r[:, b]) @ frac
        con /= vol
        bas = np.zeros((6, nb))
        if fb.any():
            zi = system.pos[ci[fb], 2]
            r = system.pos[ci[fb]] - cp[fb]  # r_i - c (contact point relative to stored r_i)
            zc = zi - r[:, 2]
            seg = _overlap(np.minimum(zi, zc), np.maximum(zi, zc), self.edges)
            frac = seg / np.maximum(np.abs(r[:, 2]), 1e-300)[:, None]
            below = _overlap(np.full_like(zc, -1e9), zc, self.edges)
            for q, (a, b) in enumerate(AB):
                bas[q] = (f[fb, a] * r[:, b]) @ frac
                if b == 2:
                    bas[q] += f[fb, a] @ below
        bas /= vol
        for name, val in (("mass", mass / vol), ("mom", mom / vol), ("kin", kin), ("con", con),
                          ("bas", bas)):
            acc[name] = acc.get(name, 0.0) + val
        acc["n"] += 1

    def profiles(self, t_from):
        """Time-averaged slab fields over the windows starting at or after ``t_from``."""
        keep = [a for a in self.sums.values() if a["t0"] >= t_from - 1e-9 and a["n"]]
        n = sum(a["n"] for a in keep)
        out = {k: sum(a[k] for a in keep) / n for k in ("mass", "mom", "kin", "con", "bas")}
        out["velocity_x"] = out["mom"][0] / np.where(out["mass"] > 0, out["mass"], np.nan)
        out["n_snapshots"] = n
        return out


def slab_mean(z, f, edges):
    """Mean of a profile f(z) (grid z) over each slab."""
    f = np.asarray(f, dtype=float)
    out = np.full(len(edges) - 1, np.nan)
    for k in range(len(edges) - 1):
        sel = (z >= edges[k]) & (z < edges[k + 1])
        if sel.any():
            out[k] = np.mean(f[sel])
    return out
