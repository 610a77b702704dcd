"""One LAMMPS snapshot as the particle state granflow's run observers read.

granflow's on-the-fly analysis -- the energy series, the coarse-graining
(:class:`granflow.observers.ProfileObserver` feeding
:class:`granflow.coarse.DepthProfileAccumulator`, Weinhart et al. 2012 Eq. 13-32, 43), the
steady-state monitor and the segregation monitor -- samples a
:class:`granflow.engine.system.ParticleSystem`.  :class:`SnapshotSystem` offers the same
attributes and methods (``time``, ``pos``, ``vel``, ``omega``, ``radius``, ``mass``,
``ptype``, ``fixed``, ``gvec``, ``energies()``, ``contacts()``) filled from a per-atom dump
snapshot and the pair dump snapshot of the same timestep, so that the *same* observer code
coarse-grains a LAMMPS run: one coarse-graining implementation, fed by two engines.

Contacts (as :meth:`ParticleSystem.contacts`): for every touching pair with overlap
delta = r_i + r_j - |r_ij| > 0, i is the flow particle (a flow-base pair listed base-first is
swapped: force and r_ij change sign), the force on i is the normal plus tangential force of
the pair dump, r_ij = r_i - r_j as LAMMPS computed it (minimum image), and the contact point
is r_i - (r_i - delta/2) r_ij / |r_ij| (``granflow.engine`` ``contact_list``).  Base-base
pairs are dropped.

Units: the dumps are converted to granflow's (d = m = g = 1) with a length, mass and gravity
scale (1 for runs written by granflow).
"""

from __future__ import annotations

import math

import numpy as np

from .dump import DumpFormatError, DumpSnapshot
from .inputs import PAIR_COLUMNS
from .species import PairTables, elastic_energy

#: Per-atom columns every ingest needs, by what they are (first found is used).
POSITION_COLUMNS = (("x", "y", "z"), ("xu", "yu", "zu"))
VELOCITY_COLUMNS = ("vx", "vy", "vz")
OMEGA_COLUMNS = ("omegax", "omegay", "omegaz")


class SnapshotSystem:
    """Particle state of one LAMMPS snapshot in granflow units (see the module docstring).

    Parameters
    ----------
    Lx, Ly : periodic box lengths (granflow units).
    gvec : gravity vector (granflow units, |g| = 1 for a chute).
    ptype_of_type : array mapping a LAMMPS type to granflow's type index (flow species
        0 .. S-1, base S); -1 for a type that must not occur.
    base_ptype : granflow type index of the frozen base.
    tables : per-type-pair coefficients (granflow type index) for the elastic energy.
    dt : time step (granflow units); the snapshot time is timestep * dt when ``time_from_step``
        (runs written by granflow), else the dump's ``ITEM: TIME`` (or timestep * dt).
    length, mass_unit, g : the dump's scales (granflow units = dump value / scale).
    z_shift : subtracted from every z after scaling (puts the base top at z = 0).
    interactions : granflow :class:`InteractionTable` (what ``ChuteRun`` reads for t_c).
    pair_columns : names of the pair dump's columns in the order of :data:`PAIR_COLUMNS`.
    """

    def __init__(self, Lx, Ly, gvec, ptype_of_type, base_ptype, tables: PairTables, dt,
                 time_from_step=True, length=1.0, mass_unit=1.0, g=1.0, z_shift=0.0,
                 interactions=None, pair_columns=PAIR_COLUMNS):
        self.Lx = float(Lx)
        self.Ly = float(Ly)
        self.gvec = np.asarray(gvec, dtype=np.float64)
        self.ptype_of_type = np.asarray(ptype_of_type, dtype=np.int64)
        self.base_ptype = int(base_ptype)
        self.tables = tables
        self.dt = float(dt)
        self.time_from_step = bool(time_from_step)
        self.length = float(length)
        self.mass_unit = float(mass_unit)
        self.g = float(g)
        self.time_unit = math.sqrt(self.length / self.g)
        self.z_shift = float(z_shift)
        self.interactions = interactions
        self.pair_columns = tuple(pair_columns)
        self.time = 0.0
        self.step_count = 0
        self.timestep = 0
        self.n_snapshots = 0
        self.max_overlap = 0.0
        self.e_released = 0.0
        self._contacts = None
        self._energies = None

    # ---------------------------------------------------------------- loading
    def load(self, atoms: DumpSnapshot, pairs: DumpSnapshot | None):
        """Fill the state from a per-atom snapshot and the pair snapshot of the same step."""
        if pairs is not None and pairs.timestep != atoms.timestep:
            raise DumpFormatError(f"{pairs.source}: pair snapshot at timestep {pairs.timestep} "
                                  f"does not match the atom snapshot at timestep "
                                  f"{atoms.timestep} ({atoms.source})")
        L, V = self.length, math.sqrt(self.g * self.length)
        ids = atoms.column("id").astype(np.int64)
        order = np.argsort(ids, kind="stable")
        ids = ids[order]
        data = atoms.data[order]
        cols = atoms.columns

        def col(name):
            return data[:, cols.index(name)]

        for names in POSITION_COLUMNS:
            if all(n in cols for n in names):
                pos = np.column_stack([col(n) for n in names])
                break
        else:
            if all(n in cols for n in ("xs", "ys", "zs")):
                lo, hi = atoms.box[:, 0], atoms.box[:, 1]
                pos = lo + np.column_stack([col(n) for n in ("xs", "ys", "zs")]) * (hi - lo)
            else:
                raise DumpFormatError(f"{atoms.source}: snapshot at timestep {atoms.timestep} "
                                      "has no positions (columns x y z, xu yu zu or xs ys zs)")
        for name in VELOCITY_COLUMNS:
            if name not in cols:
                raise DumpFormatError(f"{atoms.source}: snapshot at timestep {atoms.timestep} "
                                      f"has no column {name!r} (need vx vy vz)")
        vel = np.column_stack([col(n) for n in VELOCITY_COLUMNS])
        omega = (np.column_stack([col(n) for n in OMEGA_COLUMNS])
                 if all(n in cols for n in OMEGA_COLUMNS) else np.zeros_like(vel))
        if "diameter" in cols:
            radius = 0.5 * col("diameter")
        elif "radius" in cols:
            radius = col("radius").copy()
        else:
            raise DumpFormatError(f"{atoms.source}: snapshot at timestep {atoms.timestep} has "
                                  "neither 'diameter' nor 'radius'")
        if "mass" not in cols:
            raise DumpFormatError(f"{atoms.source}: snapshot at timestep {atoms.timestep} has "
                                  "no 'mass' column")
        mass = col("mass")
        ltype = col("type").astype(np.int64)
        if ltype.min() < 0 or ltype.max() >= len(self.ptype_of_type) or \
                np.any(self.ptype_of_type[ltype] < 0):
            raise DumpFormatError(f"{atoms.source}: snapshot at timestep {atoms.timestep} has "
                                  f"atom types {sorted(set(ltype.tolist()))}, not all known "
                                  "(flow and base types)")
        ptype = self.ptype_of_type[ltype]
        fixed = ptype == self.base_ptype
        # flow particles first, base last (granflow's order), stable within each group
        order2 = np.argsort(fixed, kind="stable")
        self._sorted_ids = ids
        self._index_of_sorted = np.empty(len(ids), np.int64)
        self._index_of_sorted[order2] = np.arange(len(ids))
        self.ids = ids[order2]
        self.pos = pos[order2] / L
        self.pos[:, 2] -= self.z_shift
        self.vel = vel[order2] / V
        self.omega = omega[order2] * self.time_unit
        self.radius = radius[order2] / L
        self.mass = mass[order2] / self.mass_unit
        self.inertia = 0.4 * self.mass * self.radius**2
        self.ptype = ptype[order2]
        self.fixed = fixed[order2]
        self.timestep = int(atoms.timestep)
        self.step_count = self.timestep
        if self.time_from_step or not math.isfinite(atoms.time):
            self.time = self.timestep * self.dt
        else:
            self.time = atoms.time / self.time_unit
        self.n_snapshots += 1
        self._pairs = pairs
        self._contacts = None
        self._energies = None
        self._atoms_source = atoms.source

    # ---------------------------------------------------------------- contacts
    def _index_of_ids(self, id_values, source):
        ids = self._sorted_ids
        k = np.minimum(np.searchsorted(ids, id_values), len(ids) - 1)
        bad = ids[k] != id_values
        if bad.any():
            raise DumpFormatError(f"{source}: pair snapshot at timestep {self.timestep} names "
                                  f"atom ID {int(id_values[bad][0])}, absent from the atom "
                                  "snapshot")
        return self._index_of_sorted[k]

    def _compute_contacts(self):
        pairs = self._pairs
        empty = np.zeros((0, 3))
        if pairs is None or pairs.data.shape[0] == 0:
            self._contacts = {"contact_i": np.zeros(0, np.int64),
                              "contact_j": np.zeros(0, np.int64), "contact_force": empty,
                              "contact_rij": empty, "contact_point": empty,
                              "contact_ft": empty, "contact_delta": np.zeros(0),
                              "contact_vt": empty, "contact_meff": np.zeros(0)}
            return
        cols = pairs.columns
        if len(cols) != len(self.pair_columns):
            if len(cols) == len(self.pair_columns) + 1:  # a leading "index" column
                cols = cols[1:]
                data = pairs.data[:, 1:]
            else:
                raise DumpFormatError(
                    f"{pairs.source}: pair snapshot at timestep {pairs.timestep} has "
                    f"{len(pairs.columns)} columns ({' '.join(pairs.columns)}); expected "
                    f"{len(self.pair_columns)}: {' '.join(self.pair_columns)} (see "
                    "granflow.lammps.ingest for the dump commands)")
        else:
            data = pairs.data
        c = {name: data[:, k] for k, name in enumerate(self.pair_columns)}
        L = self.length
        F = self.mass_unit * self.g
        i = self._index_of_ids(c["id1"].astype(np.int64), pairs.source)
        j = self._index_of_ids(c["id2"].astype(np.int64), pairs.source)
        dist = c["dist"] / L
        rij = np.column_stack([c["dx"], c["dy"], c["dz"]]) / L
        fn = np.column_stack([c["fx"], c["fy"], c["fz"]]) / F
        ft = np.column_stack([c["ftx"], c["fty"], c["ftz"]]) / F
        delta = self.radius[i] + self.radius[j] - dist
        keep = (delta > 0.0) & ~(self.fixed[i] & self.fixed[j])
        i, j, dist, rij, fn, ft, delta = (a[keep] for a in (i, j, dist, rij, fn, ft, delta))
        swap = self.fixed[i]
        if swap.any():
            i, j = np.where(swap, j, i), np.where(swap, i, j)
            sign = np.where(swap, -1.0, 1.0)[:, None]
            rij = rij * sign
            fn = fn * sign
            ft = ft * sign
        force = fn + ft
        b = (self.radius[i] - 0.5 * delta) / dist
        point = self.pos[i] - b[:, None] * rij
        # relative tangential velocity of the contact (as LAMMPS: v_r - v_n n - (r_i w_i +
        # r_j w_j) x n) and effective mass (a base partner: the flow particle's mass)
        n = rij / dist[:, None]
        vr = self.vel[i] - self.vel[j]
        vt = vr - np.einsum("ij,ij->i", vr, n)[:, None] * n
        wr = self.radius[i][:, None] * self.omega[i] + self.radius[j][:, None] * self.omega[j]
        vtr = vt - np.cross(wr, n)
        mi, mj = self.mass[i], self.mass[j]
        m_eff = np.where(self.fixed[j], mi, mi * mj / (mi + mj))
        self._contacts = {"contact_i": i.astype(np.int64), "contact_j": j.astype(np.int64),
                          "contact_force": force, "contact_rij": rij, "contact_point": point,
                          "contact_ft": ft, "contact_delta": delta, "contact_vt": vtr,
                          "contact_meff": m_eff}
        if len(delta):
            dmin = np.minimum(self.radius[i], self.radius[j]) * 2.0
            self.max_overlap = float(np.max(delta / dmin))
        else:
            self.max_overlap = 0.0

    def contacts(self) -> dict:
        """Current contacts: i (flow), j, force on i, r_i - r_j, contact point (see module)."""
        if self._contacts is None:
            self._compute_contacts()
        c = self._contacts
        return {k: c[k] for k in ("contact_i", "contact_j", "contact_force", "contact_rij",
                                  "contact_point")}

    def energies(self) -> dict:
        """Kinetic (translational + rotational), elastic and slope-normal gravitational energy
        of the flow particles, as :meth:`ParticleSystem.energies`."""
        if self._energies is None:
            if self._contacts is None:
                self._compute_contacts()
            mob = ~self.fixed
            m = self.mass[mob]
            et = 0.5 * float(np.sum(m[:, None] * self.vel[mob] ** 2))
            er = 0.5 * float(np.sum(self.inertia[mob][:, None] * self.omega[mob] ** 2))
            c = self._contacts
            ti, tj = self.ptype[c["contact_i"]], self.ptype[c["contact_j"]]
            e_el = elastic_energy(ti, tj, c["contact_delta"], c["contact_ft"], self.tables,
                                  c["contact_meff"], c["contact_vt"])
            e_grav = float(np.sum(m * (-self.gvec[2]) * self.pos[mob, 2]))
            self._energies = {"kinetic": et + er, "kinetic_translational": et,
                              "kinetic_rotational": er, "elastic": e_el,
                              "gravitational": e_grav, "released": 0.0}
        return dict(self._energies)

    @property
    def n(self) -> int:
        return len(self.radius)
