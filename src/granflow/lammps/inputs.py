"""LAMMPS input of a granflow chute run: data file (particles) and input script.

The particles are granflow's own: :func:`granflow.engine.chute.build_chute` builds the chute
from the run parameters (the same rough-base file, the same seeded flow insertion of Weinhart
et al. 2012 §5), and :func:`write_data` writes exactly those positions, diameters, densities
and types (LAMMPS type = granflow type + 1; atom ID = granflow index + 1).  :func:`write_input`
writes the script: ``pair_style granular`` with one ``pair_coeff`` per type pair
(:mod:`granflow.lammps.species`), the base frozen (``fix freeze``: no motion, and its
contacts' effective mass is the flow particle's), tilted gravity g = (sin theta, 0,
-cos theta), velocity Verlet (``fix nve/sphere``), time step t_c / steps_per_collision, and two
dumps every sample interval that granflow coarse-grains exactly as the numba engine's
snapshots:

* ``atoms``: ``id type mass diameter x y z vx vy vz omegax omegay omegaz`` (sorted by id);
* ``pairs``: one row per touching pair from ``compute property/local patom1 patom2`` and
  ``compute pair/local dist dx dy dz fx fy fz p1 p2 p3`` (both with ``cutoff radius``, so the
  two computes list the same pairs in the same order): IDs i, j, distance, r_i - r_j, the
  normal force on i and (p1-p3 of pair granular) the tangential force on i.

Both carry ``dump_modify time yes`` and 10 significant digits.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ..provenance import atomic_write_bytes
from .species import PairTables, pair_coeff_lines

#: Column names of the per-atom dump written (and expected by default).
ATOM_COLUMNS = ("id", "type", "mass", "diameter", "x", "y", "z", "vx", "vy", "vz",
                "omegax", "omegay", "omegaz")
#: Column names of the pair dump (dump local), in order.
PAIR_COLUMNS = ("id1", "id2", "dist", "dx", "dy", "dz", "fx", "fy", "fz", "ftx", "fty", "ftz")
#: Digits of the dumped floats.
DUMP_DIGITS = 10


def _g(x) -> str:
    return f"{float(x):.17g}"


def write_data(path, pos, diameter, mass, ptype, Lx, Ly, title="granflow chute", vel=None,
               omega=None):
    """LAMMPS data file (``atom_style sphere``) of the given particles, written atomically.

    The z extent is the particles' range plus two diameters (the box is shrink-wrapped in z,
    ``boundary p p m``, so it only has to contain them).  ``vel`` / ``omega`` ((N, 3), a
    restart from a saved state): a ``Velocities`` section (``atom-ID vx vy vz wx wy wz``);
    without them, or when both are zero, none (LAMMPS starts every particle at rest).
    """
    pos = np.asarray(pos, dtype=np.float64)
    diameter = np.asarray(diameter, dtype=np.float64)
    mass = np.asarray(mass, dtype=np.float64)
    ptype = np.asarray(ptype, dtype=np.int64)
    n = len(diameter)
    if pos.shape != (n, 3) or mass.shape != (n,) or ptype.shape != (n,):
        raise ValueError("write_data: pos (N, 3), diameter, mass, ptype (N,) must agree")
    if n == 0:
        raise ValueError("write_data: no particles")
    density = mass / (math.pi / 6.0 * diameter**3)
    dmax = float(diameter.max())
    zlo = float(pos[:, 2].min()) - 2.0 * dmax
    zhi = float(pos[:, 2].max()) + 2.0 * dmax
    x = np.mod(pos[:, 0], Lx)
    y = np.mod(pos[:, 1], Ly)
    ntypes = int(ptype.max()) + 1
    head = (f"LAMMPS data file: {title} (written by granflow.lammps.inputs)\n\n"
            f"{n} atoms\n{ntypes} atom types\n\n"
            f"0 {_g(Lx)} xlo xhi\n0 {_g(Ly)} ylo yhi\n{_g(zlo)} {_g(zhi)} zlo zhi\n\n"
            "Atoms # sphere\n\n")
    rows = np.column_stack([np.arange(1, n + 1), ptype + 1, diameter, density, x, y, pos[:, 2],
                            np.zeros(n, np.int64), np.zeros(n, np.int64), np.zeros(n, np.int64)])
    import io

    buf = io.StringIO()
    buf.write(head)
    # atom-ID atom-type diameter density x y z ix iy iz
    np.savetxt(buf, rows, fmt=["%d", "%d", "%.17g", "%.17g", "%.17g", "%.17g", "%.17g",
                               "%d", "%d", "%d"])
    v = np.zeros((n, 3)) if vel is None else np.asarray(vel, dtype=np.float64)
    w = np.zeros((n, 3)) if omega is None else np.asarray(omega, dtype=np.float64)
    if v.shape != (n, 3) or w.shape != (n, 3):
        raise ValueError("write_data: vel and omega must be (N, 3) like pos")
    if v.any() or w.any():
        buf.write("\nVelocities\n\n")
        # atom-ID vx vy vz wx wy wz (atom_style sphere: angular velocity, not momentum)
        np.savetxt(buf, np.column_stack([np.arange(1, n + 1), v, w]),
                   fmt=["%d"] + ["%.17g"] * 6)
    atomic_write_bytes(path, buf.getvalue().encode())


def write_input(path, *, tables: PairTables, gravity, dt: float, n_steps: int,
                sample_every: int, skin: float, n_types: int, atoms_dump: str, pairs_dump: str,
                data_file: str = "chute.data", thermo_every: int | None = None,
                title: str = "granflow chute run"):
    """The LAMMPS input script (see the module docstring), written atomically.

    ``atoms_dump`` / ``pairs_dump`` are the dump file names (relative to the run folder; a
    named pipe for a live run, or names with ``*`` for one file per snapshot).
    """
    if n_steps < 1 or sample_every < 1:
        raise ValueError("n_steps and sample_every must be >= 1")
    base_type = n_types  # LAMMPS type of the base (granflow's last type)
    flow_types = " ".join(str(t) for t in range(1, n_types))
    g = np.asarray(gravity, dtype=np.float64)
    gnorm = float(np.linalg.norm(g))
    if not gnorm > 0:
        raise ValueError("gravity must be a nonzero vector")
    thermo_every = thermo_every or max(sample_every, (n_steps // 100) or 1)
    acols = " ".join(ATOM_COLUMNS)
    fmt = f"%.{DUMP_DIGITS}g"
    pair_names = " ".join(f"colname {k + 1} {name}" for k, name in enumerate(PAIR_COLUMNS))
    lines = [
        f"# {title}",
        "# written by granflow.lammps.inputs: the particles of granflow's build_chute, the contact",
        "# species of granflow.lammps.species, dumps read back by granflow.lammps.ingest",
        "units           lj",
        "atom_style      sphere",
        "dimension       3",
        "boundary        p p m",
        "comm_modify     vel yes",
        f"read_data       {data_file}",
        f"group           flow type {flow_types}",
        f"group           base type {base_type}",
        f"neighbor        {_g(skin)} bin",
        f"neigh_modify    delay 0 every 1 check yes exclude type {base_type} {base_type}",
        "pair_style      granular",
        *pair_coeff_lines(tables),
        f"timestep        {_g(dt)}",
        "fix             frz base freeze",
        # fix gravity normalises the vector; its magnitude is the first argument
        f"fix             grav flow gravity {_g(gnorm)} vector {_g(g[0])} {_g(g[1])} "
        f"{_g(g[2])}",
        "fix             integ flow nve/sphere",
        "compute         gfpair all pair/local dist dx dy dz fx fy fz p1 p2 p3 cutoff radius",
        "compute         gfid all property/local patom1 patom2 cutoff radius",
        f"dump            gfatoms all custom {sample_every} {atoms_dump} {acols}",
        f"dump_modify     gfatoms sort id time yes flush yes format float {fmt}",
        f"dump            gfpairs all local {sample_every} {pairs_dump} c_gfid[1] c_gfid[2] "
        "c_gfpair[*]",
        f"dump_modify     gfpairs time yes flush yes format float {fmt} {pair_names}",
        "thermo_style    custom step time atoms ke",
        "thermo_modify   norm no",
        f"thermo          {thermo_every}",
        f"run             {n_steps}",
    ]
    atomic_write_bytes(path, ("\n".join(lines) + "\n").encode())
    return Path(path)


def lammps_types(ptype) -> np.ndarray:
    """LAMMPS atom types of granflow types (1-based)."""
    return np.asarray(ptype, dtype=np.int64) + 1


def relpath(path, start) -> str:
    return os.path.relpath(os.fspath(path), os.fspath(start))
