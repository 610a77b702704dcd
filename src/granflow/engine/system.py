"""The particle system: state arrays, time stepping, energies, contacts and checkpoints.

:class:`ParticleSystem` owns the complete dynamic state of a periodic-x,y, open-z system of
spheres (Weinhart et al. 2012, §2 and §5): positions, velocities, angular velocities, forces and
torques, the Verlet neighbour list and the per-contact history (tangential springs, maximum
overlaps).  Fixed particles (the rough base) have infinite mass, feel no body force and never
move.  Stepping is delegated to the numba kernels in :mod:`granflow.engine.lib.kernels`.

Particle order convention: mobile (flow) particles first, fixed particles last, so that in every
listed pair i < j a flow-base contact has the flow particle as i.  Systems with at least
``kernels.SORT_MIN_MOBILE`` mobile particles are kept in spatial order (re-sorted at every
``SORT_EVERY``-th neighbour-list rebuild, for the caches): the index of a particle then changes
during a run, and :attr:`ParticleSystem.ids` holds each one's identity (its index when the
particles were set); :meth:`ParticleSystem.id_order` gives the permutation back to it.

The whole state round-trips through :meth:`ParticleSystem.state_dict` /
:meth:`ParticleSystem.from_state_dict`, so that a resumed run continues bit for bit.
"""

from __future__ import annotations

import io
import json
import logging
import math
import os
from pathlib import Path

import numba
import numpy as np

from ..provenance import atomic_write_bytes
from .lib import kernels as K
from .lib.hgrid import choose_neighbour_method, hgrid_pairs
from .species import InteractionTable, check_range

log = logging.getLogger(__name__)

#: Maximum overlap allowed, as a fraction of the smaller diameter of the pair (issue guard).
MAX_OVERLAP_FRACTION = 0.05
#: Smallest number of time steps per collision accepted (guard against dt too large for t_c).
MIN_STEPS_PER_COLLISION = 10


class SimulationError(RuntimeError):
    """Raised when a run becomes unphysical (NaN, excessive overlap) or is set up wrongly."""


class ParticleSystem:
    """A set of spheres in a periodic-x,y box with open z, gravity ``gvec`` and contact laws."""

    _ARRAYS = ("pos", "vel", "omega", "force", "torque", "radius", "mass", "inertia", "ptype",
               "fixed", "pi", "pj", "hist_t", "hist_dmax", "pos_ref", "wall_hist", "wall_dmax",
               "wall_rows", "wall_state", "gvec")
    #: Results of the last force evaluation per pair (see ``kernels.pair_pass``), checkpointed
    #: as ``pair_<name>``; the other per-pair arrays are derived from the pair list.
    _PAIR_SAVED = ("crow", "cext", "ridx", "prel", "pstate")

    def __init__(self, Lx, Ly, interactions: InteractionTable, gvec=(0.0, 0.0, -1.0), dt=None,
                 skin=0.2, use_wall=False, wall_type=None, steps_per_collision=50):
        self.Lx = check_range("Lx", Lx, 0.0, math.inf, lo_open=True)
        self.Ly = check_range("Ly", Ly, 0.0, math.inf, lo_open=True)
        self.interactions = interactions
        self.tables = interactions.arrays()
        t_c = interactions.min_collision_time()
        self.dt = float(dt) if dt is not None else t_c / steps_per_collision
        if not (self.dt > 0) or self.dt > t_c / MIN_STEPS_PER_COLLISION:
            raise SimulationError(
                f"dt = {self.dt:g} is too large for the shortest collision time t_c = {t_c:g}: "
                f"allowed (0, t_c/{MIN_STEPS_PER_COLLISION}] = (0, {t_c / MIN_STEPS_PER_COLLISION:g}]"
            )
        self.skin = check_range("skin", skin, 0.0, math.inf, lo_open=True)
        self.gvec = np.asarray(gvec, dtype=np.float64)
        self.use_wall = bool(use_wall)
        self.wall_type = int(wall_type) if wall_type is not None else 0
        #: spatial order of the particles (see the module docstring); tests lower the threshold
        self.sort_min_mobile = K.SORT_MIN_MOBILE
        self.sort_every = K.SORT_EVERY
        #: overlap guard of :meth:`step`, a fraction of the smallest diameter (numerics.max_overlap)
        self.max_overlap_fraction = MAX_OVERLAP_FRACTION
        self.time = 0.0
        self.step_count = 0
        self.n_rebuilds = 0
        self.e_elastic = 0.0
        self.max_overlap = 0.0
        self.e_released = 0.0  # cumulative tangential spring energy released on contact opening
        self._set_particles(np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0, np.int64),
                            np.zeros(0, bool))

    # ---------------------------------------------------------------- particles
    def _set_particles(self, pos, diameter, density, ptype, fixed):
        n = len(diameter)
        self.pos = np.array(pos, dtype=np.float64, copy=True).reshape(n, 3)  # never alias the caller's
        self.vel = np.zeros((n, 3))
        self.omega = np.zeros((n, 3))
        self.force = np.zeros((n, 3))
        self.torque = np.zeros((n, 3))
        self.radius = 0.5 * np.asarray(diameter, dtype=np.float64)
        self.mass = np.asarray(density, dtype=np.float64) * math.pi / 6.0 * (2 * self.radius) ** 3
        self.inertia = 0.4 * self.mass * self.radius**2  # solid sphere: I = m d^2 / 10
        self.ptype = np.array(ptype, dtype=np.int64)  # own, contiguous: sorted in place
        # own, contiguous, writable: one numba specialisation for fresh, restored and base-
        # preparation systems (a broadcast scalar is a stride-0 read-only view: 'A' layout)
        self.fixed = np.array(fixed, dtype=bool)
        self.wall_hist = np.zeros((n, 3))
        self.wall_dmax = np.zeros(n)
        self.wall_rows = np.zeros((n, K.NROW))
        self.wall_state = np.zeros(n, np.uint8)
        self.pi = np.zeros(0, np.uint32)
        self.pj = np.zeros(0, np.uint32)
        self.hist_t = np.zeros((0, 3))
        self.hist_dmax = np.zeros(0)
        self.pos_ref = self.pos.copy()
        self.ids = np.arange(n, dtype=np.int64)
        self._pair = None
        self._coef_src = None
        self._slots_override = None
        # per-thread work rows of the vectorised contact kernel
        self._work = K.work_rows(numba.config.NUMBA_NUM_THREADS)

    def set_particles(self, pos, diameter, density=6.0 / math.pi, ptype=0, fixed=False):
        """Replace all particles. Mobile particles must come before fixed ones."""
        diameter = np.asarray(diameter, dtype=np.float64)
        n = len(diameter)
        density = np.broadcast_to(np.asarray(density, dtype=np.float64), (n,))
        ptype = np.broadcast_to(np.asarray(ptype, dtype=np.int64), (n,))
        fixed = np.broadcast_to(np.asarray(fixed, dtype=bool), (n,))
        if n and np.any(np.diff(fixed.astype(int)) < 0):
            raise ValueError("particles: mobile particles must precede fixed (base) particles")
        if np.any(diameter <= 0):
            raise ValueError("diameter: every particle diameter must be > 0")
        if np.any(ptype < 0) or np.any(ptype >= len(self.interactions.type_names)):
            raise ValueError(f"ptype: allowed 0..{len(self.interactions.type_names) - 1}")
        self._set_particles(pos, diameter, density, ptype, fixed)
        self.pos[:, 0] %= self.Lx
        self.pos[:, 1] %= self.Ly

    def add_particles(self, pos, diameter, density=6.0 / math.pi, ptype=0):
        """Add mobile particles, at rest, to a system that has run: every existing particle
        keeps its state and every contact its tangential-spring history (new layers poured on
        an arrested pile, the staircase of Weinhart et al. 2012 §6: "the height was increased
        by 2 particle heights, if the flow arrested").

        The new particles go after the existing mobile ones and before the fixed ones, in the
        arrays and in identity order (:attr:`ids`: the fixed particles' identities move up).
        The neighbour list is rebuilt with the history carried over and the forces of the new
        state computed, as :meth:`initialize` does.  Positions must not overlap existing
        particles (``engine.chute.top_up_flow`` inserts them so); checked values: finite
        positions, diameters > 0, ``ptype`` a mobile type of the interaction table."""
        diameter = np.asarray(diameter, dtype=np.float64).reshape(-1)
        k = len(diameter)
        pos = np.asarray(pos, dtype=np.float64).reshape(k, 3)
        density = np.broadcast_to(np.asarray(density, dtype=np.float64), (k,))
        ptype = np.broadcast_to(np.asarray(ptype, dtype=np.int64), (k,))
        if k == 0:
            return
        if not np.all(np.isfinite(pos)):
            raise ValueError("pos: every new particle position must be finite")
        if np.any(diameter <= 0) or not np.all(np.isfinite(diameter)):
            raise ValueError("diameter: every new particle diameter must be finite and > 0")
        if not np.all(np.isfinite(density)) or np.any(density <= 0):
            raise ValueError("density: must be finite and > 0")
        ntypes = len(self.interactions.type_names)
        if np.any(ptype < 0) or np.any(ptype >= ntypes):
            raise ValueError(f"ptype: allowed 0..{ntypes - 1}")
        nm = int(np.count_nonzero(~self.fixed))
        if self.fixed[:nm].any():
            raise ValueError("add_particles needs the mobile particles before the fixed ones")
        if not hasattr(self, "_inv_mass"):
            self._cache_inverse()

        def grow(a, new):  # old mobile rows, the new rows, then the fixed rows
            return np.ascontiguousarray(np.concatenate([a[:nm], new, a[nm:]]))

        zeros3 = np.zeros((k, 3))
        radius = 0.5 * diameter
        mass = density * math.pi / 6.0 * diameter**3
        self.pos = grow(self.pos, pos)
        self.pos[:, 0] %= self.Lx
        self.pos[:, 1] %= self.Ly
        for name in ("vel", "omega", "force", "torque", "wall_hist"):
            setattr(self, name, grow(getattr(self, name), zeros3))
        self.radius = grow(self.radius, radius)
        self.mass = grow(self.mass, mass)
        self.inertia = grow(self.inertia, 0.4 * mass * radius**2)
        self.ptype = grow(self.ptype, ptype)
        self.fixed = grow(self.fixed, np.zeros(k, bool))
        self.wall_dmax = grow(self.wall_dmax, np.zeros(k))
        self.wall_rows = grow(self.wall_rows, np.zeros((k, K.NROW)))
        self.wall_state = grow(self.wall_state, np.zeros(k, np.uint8))
        ids = np.where(self.ids >= nm, self.ids + k, self.ids)  # mobile identities are < nm
        self.ids = grow(ids, np.arange(nm, nm + k, dtype=np.int64))
        # the old pairs in the new indices (a monotone map: still sorted by (i, j)), then a
        # fresh list that takes their history over
        old_pi = np.where(self.pi >= nm, self.pi + k, self.pi).astype(np.uint32)
        old_pj = np.where(self.pj >= nm, self.pj + k, self.pj).astype(np.uint32)
        self._mobile_sel = None
        self._cache_inverse()
        self.pi, self.pj, self.hist_t, self.hist_dmax = K.rebuild_pairs(
            self.pos, self.radius, self.fixed, self.Lx, self.Ly, self.skin, self._level_of,
            self._level_cell, old_pi, old_pj, self.hist_t, self.hist_dmax)
        self._index_pairs()
        self.pos_ref = self.pos.copy()
        self.compute_forces()

    @property
    def n(self) -> int:
        return len(self.radius)

    def id_order(self) -> np.ndarray:
        """Indices that put the per-particle arrays in identity order: ``pos[id_order()][k]``
        is the particle that had index k when the particles were set (particles keep their
        identity when the engine re-sorts them, :attr:`ids`)."""
        return np.argsort(self.ids, kind="stable")

    def mobile_selection(self):
        """The mobile particles as an index: ``slice(0, n)`` when they precede the fixed ones
        (the order of :meth:`set_particles`, kept by the spatial sort), else the boolean mask.
        Either selects the same particles in the same order (the same sums, bit for bit); the
        slice saves the mask and its copies at every sample.  Cached per ``fixed`` array (the
        engine never changes it in place)."""
        cached = getattr(self, "_mobile_sel", None)
        if cached is not None and cached[0] is self.fixed:
            return cached[1]
        mobile = ~self.fixed
        n = int(np.count_nonzero(mobile))
        sel = slice(0, n) if not self.fixed[:n].any() else mobile
        self._mobile_sel = (self.fixed, sel)
        return sel

    @property
    def inv_mass(self):
        return np.where(self.fixed, 0.0, 1.0 / np.where(self.mass > 0, self.mass, 1.0))

    @property
    def inv_inertia(self):
        return np.where(self.fixed, 0.0, 1.0 / np.where(self.inertia > 0, self.inertia, 1.0))

    # ---------------------------------------------------------------- stepping
    def initialize(self):
        """Build the neighbour list and the forces of the current state (no history update)."""
        self._cache_inverse()
        self.pi, self.pj, self.hist_t, self.hist_dmax = K.rebuild_pairs(
            self.pos, self.radius, self.fixed, self.Lx, self.Ly, self.skin, self._level_of,
            self._level_cell, np.zeros(0, np.uint32), np.zeros(0, np.uint32), np.zeros((0, 3)),
            np.zeros(0))
        self._index_pairs()
        self.pos_ref = self.pos.copy()
        self.compute_forces()

    def compute_forces(self):
        """Forces, torques, elastic energy and maximum overlap of the current positions and
        springs, without advancing the springs (the initial forces of a run; a state saved
        after a step holds the forces with that step's spring increment, so its ``e_elastic``
        differs from this in the last few digits)."""
        self.e_elastic, self.max_overlap = K.compute_forces(
            self.pos, self.vel, self.omega, self.force, self.torque, self.radius, self._inv_mass,
            self.mass, self._inv_inertia, self.ptype, self.Lx, self.Ly, self.gvec, self.pi,
            self.pj, self.hist_t, self.hist_dmax, *self._pair, self.use_wall,
            self.wall_type, self.wall_hist, self.wall_dmax, self.wall_rows, self.wall_state,
            *self._coefficients(), self._work, self.dt, self.pos_ref, self.skin, self._slots())

    def _index_pairs(self, saved: dict | None = None):
        """Per-pair arrays derived from the pair list (pull index, reduced masses, spring flags)
        and those the pair pass writes (``saved``: restored from a checkpoint)."""
        if not hasattr(self, "_inv_mass"):  # a system never stepped (e.g. run by LAMMPS)
            self._cache_inverse()
        arrays = dict(zip(K.PAIR_ARRAYS, K.pair_index(self.pi, self.pj, self.hist_t,
                                                      self._inv_mass, self.n)))
        for name, value in (saved or {}).items():
            arrays[name] = value
        self._pair = tuple(arrays[name] for name in K.PAIR_ARRAYS)

    def _slots(self) -> int:
        """Runs of pair blocks of the pair pass: the number of threads (``_slots_override``
        for tests: more runs than threads exercise the multi-thread summation on one core)."""
        return int(self._slots_override or numba.get_num_threads())

    def _coefficients(self):
        """(law table, packed coefficient table, all-linear flag) of ``self.tables`` (which
        may be replaced between steps)."""
        if self._coef_src is not self.tables:
            self._coef = K.coefficient_table(*self.tables)
            self._coef_src = self.tables
        return self._coef

    def _pair_array(self, name):
        if self._pair is None:
            self._index_pairs()
        return self._pair[K.PAIR_ARRAYS.index(name)]

    def _cache_inverse(self):
        self._inv_mass = self.inv_mass
        self._inv_inertia = self.inv_inertia
        # neighbour search: hierarchical grid when the size ratio makes it pay (issue 3); the
        # levels follow from the radii alone, so checkpoints need not store them
        method, info = choose_neighbour_method(self.radius, self.skin)
        self.neighbour_method = method
        self._level_of = np.ascontiguousarray(info["level_of"], dtype=np.int64)
        self._level_cell = np.asarray(info["cell_sizes"], dtype=np.float64)
        log.info("neighbour search: %s, d_max/d_min = %.3g, cell sizes %s, particles per level %s",
                 method, info["size_ratio"], [round(c, 4) for c in info["cell_sizes"]],
                 info["level_counts"])

    def step(self, nsteps: int):
        """Advance ``nsteps`` time steps; raise :class:`SimulationError` on NaN or overlap."""
        if nsteps <= 0:
            return
        if not hasattr(self, "_inv_mass"):
            self._cache_inverse()
        if self._pair is None:
            self._index_pairs()
        frac = float(self.max_overlap_fraction)
        max_allowed = frac * 2.0 * float(self.radius.min(initial=0.5))
        (self.pi, self.pj, self.hist_t, self.hist_dmax, self._pair, e_el, max_ov, e_rel, done,
         nreb, status) = K.advance(
            int(nsteps), self.pos, self.vel, self.omega, self.force, self.torque, self.radius,
            self._inv_mass, self.mass, self._inv_inertia, self.ptype, self.fixed, self.Lx,
            self.Ly, self.gvec, self.pi, self.pj, self.hist_t, self.hist_dmax,
            *self._pair, self.pos_ref, self.skin, self._level_of, self._level_cell,
            self.use_wall, self.wall_type, self.wall_hist, self.wall_dmax, self.wall_rows,
            self.wall_state, *self._coefficients(), self._work, self.dt, max_allowed,
            self._slots(), self.inertia, self.ids, int(self.sort_min_mobile),
            int(self.sort_every), int(self.n_rebuilds))
        self.step_count += int(done)
        self.time = self.step_count * self.dt
        self.n_rebuilds += int(nreb)
        self.e_elastic = float(e_el)
        self.max_overlap = float(max_ov)
        self.e_released += float(e_rel)
        if status == 1:
            raise SimulationError(
                f"non-finite positions or forces (NaN/inf) at step {self.step_count}, t = {self.time:.6g}: "
                "check the time step and the contact parameters")
        if status == 2:
            raise SimulationError(
                f"overlap {max_ov:.4g} exceeds {frac:.0%} of the smallest diameter "
                f"at step {self.step_count}, t = {self.time:.6g}: the particles are too soft for "
                "the load (reduce t_c) or the time step is too large")

    # ---------------------------------------------------------------- observables
    def energies(self) -> dict:
        """Kinetic (translational + rotational), elastic and gravitational energy, and the
        cumulative tangential-spring energy released when contacts opened ("released"; it
        becomes internal energy of the particles, Weinhart et al. 2012 Appendix A).

        The gravitational energy is the slope-normal part, sum m |g_z| z over mobile particles:
        the downslope part is not defined in a box periodic in x.
        """
        if not hasattr(self, "_inv_mass"):
            self._cache_inverse()
        et, er = K.kinetic_energy(self.vel, self.omega, self.mass, self.inertia, self._inv_mass)
        mobile = self.mobile_selection()
        e_grav = float(np.sum(self.mass[mobile] * (-self.gvec[2]) * self.pos[mobile, 2]))
        return {"kinetic": et + er, "kinetic_translational": et, "kinetic_rotational": er,
                "elastic": self.e_elastic, "gravitational": e_grav,
                "released": self.e_released}

    def contacts(self) -> dict:
        """Current contacts (for coarse-graining): i, j, force on i, r_i - r_j, contact point.

        Flow-base contacts have the flow particle as i; flat-wall contacts have j = -1.
        """
        ci, cj, f, rij, cp = K.contact_list(
            self.pos, self.radius, self.Lx, self.Ly, self.pi, self.pj, self._pair_array("crow"),
            self._pair_array("cext"), self._pair_array("ridx"), self._pair_array("pstate"),
            self.use_wall, self.wall_rows, self.wall_state)
        return {"contact_i": ci, "contact_j": cj, "contact_force": f, "contact_rij": rij,
                "contact_point": cp}

    @property
    def pair_out(self):
        """Per-pair table of the last force evaluation, (P, 13): force on i (0:3), torque on i
        (3:6), torque on j (6:9), elastic energy (9), overlap (10), normal force (11), spring
        energy released by a contact that opened (12); zeros for pairs without contact."""
        return K.legacy_pair_rows(*(self._pair_array(k) for k in self._PAIR_SAVED))

    @property
    def wall_out(self):
        """Per-particle flat-wall table of the last force evaluation, same columns as
        :attr:`pair_out`."""
        return K.legacy_wall_rows(self.wall_rows, self.wall_state)

    # ---------------------------------------------------------------- checkpoints
    def state_dict(self) -> dict:
        state = {name: getattr(self, name) for name in self._ARRAYS}
        state["ids"] = self.ids
        for name in self._PAIR_SAVED:
            state["pair_" + name] = self._pair_array(name)
        meta = {
            "Lx": self.Lx, "Ly": self.Ly, "dt": self.dt, "skin": self.skin,
            "use_wall": self.use_wall, "wall_type": self.wall_type, "time": self.time,
            "step_count": self.step_count, "n_rebuilds": self.n_rebuilds,
            "e_elastic": self.e_elastic, "max_overlap": self.max_overlap,
            "e_released": self.e_released,
            "sort_min_mobile": int(self.sort_min_mobile), "sort_every": int(self.sort_every),
            "interactions": self.interactions.to_json_dict(),
        }
        state["meta_json"] = np.array(json.dumps(meta))
        return state

    @classmethod
    def from_state_dict(cls, state) -> "ParticleSystem":
        meta = json.loads(str(state["meta_json"]))
        sys_ = cls(meta["Lx"], meta["Ly"], InteractionTable.from_json_dict(meta["interactions"]),
                   gvec=np.asarray(state["gvec"]), dt=meta["dt"], skin=meta["skin"],
                   use_wall=meta["use_wall"], wall_type=meta["wall_type"])
        state = _upgrade_state(dict(state))
        for name in cls._ARRAYS:
            setattr(sys_, name, np.array(state[name]))
        for key in ("time", "step_count", "n_rebuilds", "e_elastic", "max_overlap", "e_released"):
            setattr(sys_, key, meta[key])
        # states written before the spatial order: identity = index, default sorting
        sys_.ids = np.array(state.get("ids", np.arange(len(sys_.radius))), dtype=np.int64)
        sys_.sort_min_mobile = int(meta.get("sort_min_mobile", K.SORT_MIN_MOBILE))
        sys_.sort_every = int(meta.get("sort_every", K.SORT_EVERY))
        sys_._cache_inverse()
        sys_._index_pairs({name: np.array(state["pair_" + name]) for name in cls._PAIR_SAVED})
        return sys_

    def save(self, path, extra: dict | None = None):
        """Write the complete state (plus ``extra`` arrays) atomically as a .npz file."""
        arrays = dict(self.state_dict())
        for key, value in (extra or {}).items():
            arrays["extra__" + key] = np.asarray(value)
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        atomic_write_bytes(path, buf.getvalue())

    @classmethod
    def load(cls, path):
        """Read a state written by :meth:`save`; returns (system, extra dict)."""
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"state file {os.fspath(path)!r} does not exist")
        try:
            with np.load(path, allow_pickle=False) as data:
                state = {k: data[k] for k in data.files}
        except Exception as exc:  # zipfile/numpy errors on a truncated file
            raise ValueError(f"state file {os.fspath(path)!r} is unreadable or truncated: {exc}") from exc
        extra = {k[len("extra__"):]: v for k, v in state.items() if k.startswith("extra__")}
        return cls.from_state_dict(state), extra


def _upgrade_state(state: dict) -> dict:
    """A state written before issue 15 (int64 pairs, 13-column ``pair_out``/``wall_out``) in
    the present layout; it resumes, but not bit for bit with the old engine."""
    if "pair_out" in state and "pair_pstate" not in state:
        out = np.asarray(state.pop("pair_out"))
        live = out[:, 10] != 0.0
        state["pair_crow"] = np.ascontiguousarray(out[:, :9])
        state["pair_cext"] = np.ascontiguousarray(out[:, 9:12])
        state["pair_ridx"] = np.arange(len(out), dtype=np.uint32)
        state["pair_prel"] = np.where(live, 0.0, out[:, 12])
        state["pair_pstate"] = np.where(live, K.CONTACT, K.NO_CONTACT).astype(np.uint8)
        wall = np.asarray(state.pop("wall_out"))
        state["wall_rows"] = np.ascontiguousarray(wall[:, :K.NROW])
        state["wall_state"] = np.where(wall[:, 10] != 0.0, K.CONTACT,
                                       K.NO_CONTACT).astype(np.uint8)
    for name in ("pi", "pj"):
        state[name] = np.asarray(state[name]).astype(np.uint32)
    return state
