"""Depth profiles of coarse-grained fields, averaged over the periodic x-y plane and over time.

Implements Weinhart et al. (2012) Eq. (43): <chi>(z) = (1/(Lx Ly T)) int int int chi_w dx dy dt for
chi_w the Gaussian coarse-grained density (Eq. 13), momentum (Eq. 16) and stress (Eq. 32,
including the flow-base half-line term), with V = p / rho (Eq. 17) and the species-resolved
density / volume fraction used for segregation (Thornton et al., 002 §3).  The plane average is
exact for a Gaussian and the line integrals of Eq. (32) are evaluated in closed form (error
functions); see :mod:`granflow.coarse._kernels` for the formulas.

Conventions
-----------
* Stress is **compressive positive** (sigma = -sigma_Cauchy of Eq. 32), so sigma_zz > 0 under
  gravity and, in steady uniform flow down +x, d(stress_xz)/dz = rho g_x, i.e. stress_xz < 0
  (the paper plots -sigma_xz) and the local friction is mu = -stress_xz / stress_zz.
* ``stress_ab`` for ab in xx, yy, zz, xy, xz, yz: force component a, line (branch) direction b;
  the momentum balance of a depth profile involves stress_xz, stress_yz, stress_zz.  The
  antisymmetric partners (yx, zx, zy; tangential forces make them differ by < 5 %) are not
  computed.  Total = contact (flow-flow pairs, segment r_i -> r_j) + base (flow-base pairs,
  by default the segment from r_i to the contact point and then straight down into the base:
  any path from r_i to infinity keeps the momentum balance exact, and this one never enters the
  flow above the contact and keeps every contact's contribution bounded; see ``base_line`` and
  physics.md §4) + kinetic (sum m v v g -
  rho V V per snapshot, i.e. fluctuations about the snapshot's V(z)).
* Kernel: Gaussian of width w (default 0.25) truncated at ``cutoff`` * w (default 4, where the
  Gaussian has dropped to 3.4e-4 of its peak) and renormalised to unit mass, so mass and
  momentum balance hold exactly.  Profiles are point values at z_k = z_min + k dz.
* Averages: velocity is <p>/<rho> (ratio of time-averaged fields, Eq. 43 applied to Eq. 17);
  every other variable is the plain mean over snapshots.  Base (``fixed``) particles carry no
  mass: they enter only through the base stress.
* Time windows: with ``window_length`` set, snapshots are also summed per window
  k = floor((t - t_first) / window_length) and the dataset holds per-window profiles as
  ``<name>_window`` with dim ``time_window`` (plus ``window_n_snapshots``,
  ``window_time_start``); spreads of derived quantities are the std over windows
  (:mod:`granflow.coarse.derived`).
"""

from __future__ import annotations

import math
from typing import Iterable, Mapping

import numpy as np
import xarray as xr

from .. import units as U
from . import _kernels as K

#: Default Gaussian coarse-graining width (004 §7: w = 0.25 d).
DEFAULT_WIDTH = 0.25
#: Default kernel cutoff in units of w.
DEFAULT_CUTOFF = 4.0

_COMP = ("x", "y", "z")

#: Paths of a flow-base contact's stress (``base_line``) and what each means; the description
#: is stored in every profile's ``cg_base_line_description`` attribute.
BASE_LINES = {
    "contact_then_down": (K.BASE_CONTACT_THEN_DOWN,
                          "flow-base contact stress spread on the segment from the flow particle's "
                          "centre to the contact point, then straight down (-z) into the base; "
                          "exactly zero above the highest flow-base contact (+ kernel cutoff)"),
    "down": (K.BASE_DOWN, "flow-base contact stress spread straight down (-z) from the flow "
                          "particle's centre (only the xz, yz, zz components are nonzero)"),
    "through_contact": (K.BASE_THROUGH_CONTACT,
                        "half-line from the flow particle's centre through the contact point to "
                        "infinity (Weinhart et al. 2012 Sec. 3 literally; adds a stress plateau "
                        "above upward-pointing contacts)"),
}
DEFAULT_BASE_LINE = "contact_then_down"
_BASE_LINE_ALIASES = {"contact": "through_contact"}

SNAPSHOT_KEYS = ("pos", "vel", "mass", "diameter", "species", "fixed", "contact_i", "contact_j",
                 "contact_force", "contact_rij", "contact_point")


def _f64(a, shape=None):
    a = np.ascontiguousarray(a, dtype=np.float64)
    if shape is not None and a.shape != shape:
        a = a.reshape(shape)
    return a


class DepthProfileAccumulator:
    """Accumulate x-y-plane and time averaged coarse-grained depth profiles snapshot by snapshot.

    Parameters
    ----------
    z_min, z_max, dz : the z grid z_k = z_min + k dz, k = 0 .. round((z_max - z_min)/dz).
    width : Gaussian coarse-graining width w (d).
    Lx, Ly : periodic box lengths (the plane average divides by Lx Ly).
    n_species : number of flow species (``species`` values 0 .. n_species-1).
    window_length : time-window length for spread estimates (None: one window).
    cutoff : kernel truncation in units of w (default 4).
    base_line : where a flow-base contact's stress goes (:data:`BASE_LINES`; every choice
        satisfies the momentum balance exactly):
        ``"contact_then_down"`` (default) the segment from the flow particle's centre to the
        contact point, then straight down into the base (bounded: the depth integral of the
        stress is the half-branch virial f_a r_b);
        ``"down"`` straight down from the flow particle's centre; ``"through_contact"`` (alias
        ``"contact"``) the literal half-line for every contact, which on a rough base points
        *up* for flow particles sitting below the base particle they touch and then leaves a
        stress plateau through the whole flow (kept to reproduce old profiles only).

    Only sums are stored (no trajectories); :meth:`state_dict` / :meth:`from_state_dict`
    checkpoint them.
    """

    def __init__(self, z_min, z_max, dz, width=DEFAULT_WIDTH, Lx=20.0, Ly=10.0, n_species=1,
                 window_length=None, cutoff=DEFAULT_CUTOFF, base_line=DEFAULT_BASE_LINE):
        if dz <= 0 or z_max <= z_min:
            raise ValueError("need dz > 0 and z_max > z_min")
        if width <= 0 or cutoff <= 0:
            raise ValueError("need width > 0 and cutoff > 0")
        base_line = _BASE_LINE_ALIASES.get(base_line, base_line)
        if base_line not in BASE_LINES:
            raise ValueError(f"base_line = {base_line!r}: allowed {sorted(BASE_LINES)}")
        if window_length is not None and window_length <= 0:
            raise ValueError("window_length must be positive")
        self.z_min = float(z_min)
        self.dz = float(dz)
        self.nz = int(round((float(z_max) - self.z_min) / self.dz)) + 1
        self.z_max = self.z_min + (self.nz - 1) * self.dz
        self.width = float(width)
        self.cutoff = float(cutoff)
        self.Lx = float(Lx)
        self.Ly = float(Ly)
        self.n_species = int(n_species)
        self.window_length = None if window_length is None else float(window_length)
        self.base_line = base_line
        self.ncol = K.n_columns(self.n_species)
        self.t_first = None
        self.t_last = None
        self.n_snapshots = 0
        self.n_upward_base = 0
        self.n_degenerate_base = 0
        self.species_diameter_sum = np.zeros(self.n_species)
        self.species_count = np.zeros(self.n_species)
        self._windows: dict[int, dict] = {}
        self._buf = np.zeros((self.nz, self.ncol))
        self._step = np.zeros((self.nz, 12))
        self._coef = np.zeros((0, 12))
        self._has = np.zeros(0, dtype=np.int8)
        self._m_sub = K.table_substeps(self.dz, self.width)
        self._tab = K.cdf_table(self.width, self.cutoff, self.dz, self._m_sub)

    @property
    def z(self) -> np.ndarray:
        """The z grid."""
        return self.z_min + self.dz * np.arange(self.nz)

    def _window_index(self, time: float) -> int:
        if self.window_length is None:
            return 0
        return int(math.floor((time - self.t_first) / self.window_length + 1e-9))

    def add_snapshot(self, time, pos, vel, mass, diameter, species, fixed, contact_i, contact_j,
                     contact_force, contact_rij, contact_point):
        """Coarse-grain one snapshot and add it to the running sums (see module docstring)."""
        pos = _f64(pos)
        n = pos.shape[0]
        vel = _f64(vel)
        mass = _f64(mass)
        diameter = _f64(diameter)
        species = np.ascontiguousarray(species, dtype=np.int64)
        fixed = np.ascontiguousarray(fixed, dtype=np.bool_)
        ci = np.ascontiguousarray(contact_i, dtype=np.int64)
        cj = np.ascontiguousarray(contact_j, dtype=np.int64)
        m = ci.shape[0]
        force = _f64(contact_force, (m, 3))
        rij = _f64(contact_rij, (m, 3))
        cpoint = _f64(contact_point, (m, 3))
        flow = ~fixed
        if flow.any():
            sp = species[flow]
            if sp.min() < 0 or sp.max() >= self.n_species:
                raise ValueError(f"species outside 0..{self.n_species - 1}")
            self.species_diameter_sum += np.bincount(sp, weights=diameter[flow],
                                                     minlength=self.n_species)
            self.species_count += np.bincount(sp, minlength=self.n_species)
        time = float(time)
        if self.t_first is None:
            self.t_first = time
        self.t_last = time if self.t_last is None else max(self.t_last, time)
        k = self._window_index(time)
        win = self._windows.get(k)
        if win is None:
            win = {"sums": np.zeros((self.nz, self.ncol)), "count": 0, "time_sum": 0.0}
            self._windows[k] = win
        if self._coef.shape[0] < n:
            self._coef = np.zeros((n, 12))
            self._has = np.zeros(n, dtype=np.int8)
        n_up, n_deg = K.coarse_grain_snapshot(
            pos, vel, mass, diameter, species, fixed, ci, cj, force, rij, cpoint,
            self.width, self.cutoff, self.z_min, self.dz, self.n_species,
            1.0 / (self.Lx * self.Ly), BASE_LINES[self.base_line][0],
            self._tab, self._m_sub, self._buf, self._step, self._coef[:n], self._has[:n],
            win["sums"])
        win["count"] += 1
        win["time_sum"] += time
        self.n_snapshots += 1
        self.n_upward_base += int(n_up)
        self.n_degenerate_base += int(n_deg)

    # ------------------------------------------------------------------ checkpointing
    _SCALARS = ("z_min", "dz", "nz", "width", "cutoff", "Lx", "Ly", "n_species", "window_length",
                "base_line", "t_first", "t_last", "n_snapshots", "n_upward_base",
                "n_degenerate_base")

    def state_dict(self) -> dict:
        """Everything needed to continue accumulating (numpy arrays and plain scalars)."""
        keys = sorted(self._windows)
        state = {name: getattr(self, name) for name in self._SCALARS}
        for name in ("window_length", "t_first", "t_last"):  # None -> NaN (npz friendly)
            if state[name] is None:
                state[name] = float("nan")
        state["species_diameter_sum"] = self.species_diameter_sum.copy()
        state["species_count"] = self.species_count.copy()
        state["window_index"] = np.array(keys, dtype=np.int64)
        state["window_count"] = np.array([self._windows[k]["count"] for k in keys], dtype=np.int64)
        state["window_time_sum"] = np.array([self._windows[k]["time_sum"] for k in keys])
        state["window_sums"] = (np.stack([self._windows[k]["sums"] for k in keys]) if keys
                                else np.zeros((0, self.nz, self.ncol)))
        return state

    @classmethod
    def from_state_dict(cls, state: Mapping) -> "DepthProfileAccumulator":
        """Rebuild an accumulator from :meth:`state_dict` output."""
        def scalar(name):
            v = state[name]
            if isinstance(v, np.ndarray):
                v = v.item()
            return v

        wl = scalar("window_length")
        nz = int(scalar("nz"))
        z_min = float(scalar("z_min"))
        dz = float(scalar("dz"))
        acc = cls(z_min, z_min + (nz - 1) * dz, dz, width=scalar("width"), Lx=scalar("Lx"),
                  Ly=scalar("Ly"), n_species=int(scalar("n_species")),
                  window_length=None if wl is None or math.isnan(float(wl)) else wl,
                  cutoff=scalar("cutoff"), base_line=str(scalar("base_line")))
        if acc.nz != nz:
            raise ValueError("inconsistent grid in state dict")
        tf = scalar("t_first")
        acc.t_first = None if tf is None or math.isnan(float(tf)) else float(tf)
        tl = scalar("t_last")
        acc.t_last = None if tl is None or math.isnan(float(tl)) else float(tl)
        acc.n_snapshots = int(scalar("n_snapshots"))
        acc.n_upward_base = int(scalar("n_upward_base"))
        acc.n_degenerate_base = int(scalar("n_degenerate_base"))
        acc.species_diameter_sum = np.array(state["species_diameter_sum"], dtype=float)
        acc.species_count = np.array(state["species_count"], dtype=float)
        sums = np.asarray(state["window_sums"], dtype=float)
        for idx, k in enumerate(np.asarray(state["window_index"]).tolist()):
            acc._windows[int(k)] = {"sums": sums[idx].copy(),
                                    "count": int(state["window_count"][idx]),
                                    "time_sum": float(state["window_time_sum"][idx])}
        return acc

    # ------------------------------------------------------------------ output
    def total_sums(self) -> tuple[np.ndarray, int]:
        """Sums over all windows and the snapshot count."""
        total = np.zeros((self.nz, self.ncol))
        count = 0
        for k in sorted(self._windows):
            total += self._windows[k]["sums"]
            count += self._windows[k]["count"]
        return total, count

    def small_species(self) -> int | None:
        """Index of the species with the smaller mean diameter (2-species runs), else None."""
        if self.n_species != 2:
            return None
        mean_d = np.where(self.species_count > 0,
                          self.species_diameter_sum / np.maximum(self.species_count, 1), np.inf)
        return int(np.argmin(mean_d))

    def to_dataset(self, attrs: Mapping | None = None) -> xr.Dataset:
        """Mean profiles (dim ``z``; per-species ones ``species`` x ``z``) as an xarray Dataset.

        With ``window_length`` set, per-window profiles ``<name>_window`` (dim ``time_window``
        first) are included.  Global ``attrs`` (e.g. provenance) are passed through and the
        coarse-graining parameters are added as ``cg_*`` attributes.
        """
        if self.n_snapshots == 0:
            raise ValueError("no snapshots accumulated")
        total, count = self.total_sums()
        fields = _fields_from_sums(total / count, self.n_species, self.small_species())
        z = self.z
        data_vars = {}
        for name, (arr, dims, vattrs) in fields.items():
            data_vars[name] = (dims, arr, vattrs)
        coords = {"z": ("z", z, U.cf(U.LENGTH, "height above the base plane z = 0",
                                     axis="Z", positive="up")),
                  "species": ("species", np.arange(self.n_species, dtype=np.int32),
                              U.cf(U.DIMENSIONLESS, "flow particle species index"))}
        if self.window_length is not None:
            keys = sorted(self._windows)
            per = [_fields_from_sums(self._windows[k]["sums"] / self._windows[k]["count"],
                                     self.n_species, self.small_species()) for k in keys]
            for name, (_, dims, vattrs) in fields.items():
                stacked = np.stack([p[name][0] for p in per])
                va = dict(vattrs)
                va["long_name"] = vattrs["long_name"] + " (per time window)"
                data_vars[name + "_window"] = (("time_window",) + dims, stacked, va)
            coords["time_window"] = ("time_window", np.array(keys, dtype=np.int64),
                                     U.cf(U.DIMENSIONLESS, "time window index"))
            data_vars["window_n_snapshots"] = (
                "time_window", np.array([self._windows[k]["count"] for k in keys], dtype=np.int64),
                U.cf(U.DIMENSIONLESS, "number of snapshots in the time window"))
            data_vars["window_time_start"] = (
                "time_window", self.t_first + self.window_length * np.array(keys, dtype=float),
                U.cf(U.TIME, "start time of the time window"))
            data_vars["window_mean_time"] = (
                "time_window", np.array([self._windows[k]["time_sum"] / self._windows[k]["count"]
                                         for k in keys]),
                U.cf(U.TIME, "mean snapshot time in the time window"))
        ds = xr.Dataset(data_vars, coords=coords)
        gattrs = dict(attrs or {})
        gattrs.update({
            "cg_kernel": "Gaussian, truncated and renormalised",
            "cg_width": self.width,
            "cg_cutoff_in_widths": self.cutoff,
            "cg_dz": self.dz,
            "cg_Lx": self.Lx,
            "cg_Ly": self.Ly,
            "cg_base_line": self.base_line,
            "cg_base_line_description": BASE_LINES[self.base_line][1],
            "cg_stress_sign":
                "compressive positive (sigma = -sigma_Cauchy of Weinhart 2012 Eq. 32)",
            "cg_n_snapshots": int(count),
            "cg_time_first": float(self.t_first),
            "cg_time_last": float(self.t_last),
            "cg_window_length": -1.0 if self.window_length is None else self.window_length,
            # flow-base contacts whose contact point lies above the flow particle's centre
            "cg_n_upward_base_contacts": int(self.n_upward_base),
            "cg_n_degenerate_base_contacts": int(self.n_degenerate_base),
        })
        small = self.small_species()
        if small is not None:
            gattrs["cg_small_species"] = small
        ds.attrs.update(gattrs)
        return ds


def _fields_from_sums(mean, n_species, small):
    """Named profile arrays (with dims and CF attrs) from mean buffer columns (nz, ncol)."""
    S = n_species
    col_sm = K.N_BASIC
    col_sv = K.N_BASIC + S
    col_c = K.N_BASIC + 2 * S
    col_b = col_c + 6
    out = {}
    rho = mean[:, 0]
    out["density"] = (rho, ("z",), U.cf(U.DENSITY, "coarse-grained mass density of the flow"))
    with np.errstate(invalid="ignore", divide="ignore"):
        for a, c in enumerate(_COMP):
            p = mean[:, 1 + a]
            out[f"momentum_{c}"] = (p, ("z",), U.cf(U.DENSITY + " " + U.VELOCITY,
                                                    f"coarse-grained momentum density, {c}"))
        for a, c in enumerate(_COMP):
            v = np.where(rho > 0, mean[:, 1 + a] / np.where(rho > 0, rho, 1.0), np.nan)
            out[f"velocity_{c}"] = (v, ("z",), U.cf(U.VELOCITY, f"velocity p/rho, {c}"))
        for t_idx, ab in enumerate(K.STRESS_NAMES):
            kin = mean[:, 4 + t_idx]
            con = mean[:, col_c + t_idx]
            bas = mean[:, col_b + t_idx]
            tot = con + bas + kin
            out[f"stress_{ab}"] = (tot, ("z",), U.cf(
                U.STRESS, f"total stress {ab} (compressive positive)"))
            out[f"stress_contact_{ab}"] = (con, ("z",), U.cf(
                U.STRESS, f"flow-flow contact stress {ab} (compressive positive)"))
            out[f"stress_base_{ab}"] = (bas, ("z",), U.cf(
                U.STRESS, f"flow-base contact stress {ab} (half-line term, compressive positive)"))
            out[f"stress_kinetic_{ab}"] = (kin, ("z",), U.cf(
                U.STRESS, f"kinetic stress {ab} (velocity fluctuations)"))
        vf_s = mean[:, col_sv:col_sv + S].T
        out["volume_fraction"] = (vf_s.sum(axis=0), ("z",), U.cf(
            U.DIMENSIONLESS, "solid volume fraction of the flow"))
        out["species_density"] = (mean[:, col_sm:col_sm + S].T.copy(), ("species", "z"),
                                  U.cf(U.DENSITY, "coarse-grained mass density per species"))
        out["species_volume_fraction"] = (
            vf_s.copy(), ("species", "z"),
            U.cf(U.DIMENSIONLESS, "solid volume fraction per species"))
        if S == 2 and small is not None:
            tot = vf_s.sum(axis=0)
            phi = np.where(tot > 0, vf_s[small] / np.where(tot > 0, tot, 1.0), np.nan)
            out["small_particle_fraction"] = (phi, ("z",), U.cf(
                U.DIMENSIONLESS, "small-particle fraction phi of the solid volume",
                small_species=int(small)))
    return out


def coarse_grain_profiles(snapshots: Iterable[Mapping], z_min, z_max, dz, width=DEFAULT_WIDTH,
                          Lx=None, Ly=None, n_species=1, window_length=None,
                          cutoff=DEFAULT_CUTOFF, base_line=DEFAULT_BASE_LINE,
                          attrs=None) -> xr.Dataset:
    """Depth-profile dataset from saved snapshots.

    Each snapshot is a mapping with ``time`` and the :data:`SNAPSHOT_KEYS` arrays (the interface
    of :meth:`DepthProfileAccumulator.add_snapshot`); ``Lx``/``Ly`` default to the first
    snapshot's ``Lx``/``Ly`` entries.
    """
    acc = None
    for snap in snapshots:
        if acc is None:
            lx = Lx if Lx is not None else snap["Lx"]
            ly = Ly if Ly is not None else snap["Ly"]
            acc = DepthProfileAccumulator(z_min, z_max, dz, width=width, Lx=lx, Ly=ly,
                                          n_species=n_species, window_length=window_length,
                                          cutoff=cutoff, base_line=base_line)
        acc.add_snapshot(snap["time"], *(snap[k] for k in SNAPSHOT_KEYS))
    if acc is None:
        raise ValueError("no snapshots given")
    return acc.to_dataset(attrs)
