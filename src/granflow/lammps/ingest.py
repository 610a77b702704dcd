"""``granflow ingest lammps``: a user's own LAMMPS chute run -> granflow's run outputs.

Reads the run's per-atom dump and its pair (contact) dump snapshot by snapshot -- never more
than one snapshot of each in memory -- and feeds each pair of snapshots to the *same*
observers as a granflow simulation (:func:`granflow.simulate.build_observers`): the energy
series, the coarse-graining into depth profiles (Weinhart et al. 2012 Eq. 13-32, 43, with the
flow-base stress term; :class:`granflow.coarse.DepthProfileAccumulator`) and the steady-state
monitor and classifier (§6).  It writes exactly the files of ``granflow simulate``:
``series.nc``, ``profiles.nc`` (averaged over the steady window) and ``summary.json`` (flow
state and depth averages h, u_bar, F, alpha, K, rho_c), so every later step (derive, collect,
fit, library, report) takes the run as it takes granflow's own.

What the dumps must hold (LAMMPS commands; N = sample interval in steps)::

    compute gfpair all pair/local dist dx dy dz fx fy fz p1 p2 p3 cutoff radius
    compute gfid   all property/local patom1 patom2 cutoff radius
    dump    gfatoms all custom N atoms.dump id type mass diameter x y z vx vy vz omegax omegay omegaz
    dump_modify gfatoms time yes
    dump    gfpairs all local  N pairs.dump c_gfid[1] c_gfid[2] c_gfpair[*]
    dump_modify gfpairs time yes

(``p1 p2 p3`` are the tangential force on the first atom for ``pair_style granular`` and
``gran/hooke/history``-type styles; ``cutoff radius`` makes both computes list the touching
pairs in the same order.)  ``radius`` may replace ``diameter``; ``xu yu zu`` or ``xs ys zs``
may replace ``x y z``; without ``time yes`` give ``--dt``.  Several files of one dump
(``atoms.*.dump``) and gzipped files are read in timestep order.

Conventions the chute must follow (granflow's): periodic in x and y, x downslope, z normal to
the base, gravity g (sin theta, 0, -cos theta) (LAMMPS ``fix gravity g chute theta`` or
``vector``), a rough base of frozen particles (types given by ``--base-types``; by default the
types whose particles do not move between the first two snapshots).  Units are converted to
granflow's d = m = g = 1 with the median flow diameter and mass and ``--gravity`` (|g| of the
run); z is shifted so that the highest base-particle centre is at z = 0.
"""

from __future__ import annotations

import itertools
import logging
import math
import os
from pathlib import Path

import numpy as np

from ..engine.species import ContactSpecies, InteractionTable
from .dump import DumpFormatError, DumpReader, order_dump_files
from .inputs import PAIR_COLUMNS
from .snapshot import SnapshotSystem
from .species import PairTables, pair_tables

log = logging.getLogger(__name__)

#: Defaults of the analysis parameters (as granflow.simulate's).
INGEST_DEFAULTS = dict(averaging_time=100.0, check_every=10.0, min_accelerating_time=None,
                       cg_width=0.25, cg_dz=0.05, cg_window=10.0, cg_every=1,
                       cg_base_line="contact_then_down")


class _IngestRun:
    """What :func:`granflow.simulate.write_outputs` reads of a run."""

    def __init__(self, system, series, stop_reason):
        self.system = system
        self.series = series
        self.stop_reason = stop_reason


def _paired(atoms_iter, pairs_iter):
    """Atom and pair snapshots of the same timestep, in order (streaming merge join)."""
    pairs = next(pairs_iter, None)
    for atoms in atoms_iter:
        while pairs is not None and pairs.timestep < atoms.timestep:
            pairs = next(pairs_iter, None)
        if pairs is None or pairs.timestep != atoms.timestep:
            raise DumpFormatError(f"{atoms.source}: no pair snapshot at timestep "
                                  f"{atoms.timestep} (the pair dump must be written at the "
                                  "timesteps of the atom dump)")
        yield atoms, pairs
        pairs = next(pairs_iter, None)


def _detect_base_types(first, second) -> list[int]:
    types = first.column("type").astype(np.int64)
    ids = first.column("id").astype(np.int64)
    moved = np.zeros(types.max() + 1, bool)
    if second is None:
        raise ValueError("--base-types is needed: the dump has one snapshot only (base types "
                         "are detected as the types whose particles do not move)")
    pos_cols = [c for c in ("x", "y", "z", "xu", "yu", "zu", "xs", "ys", "zs") if first.has(c)]
    v = np.column_stack([first.column(c) for c in ("vx", "vy", "vz")])
    a = np.column_stack([first.column(c) for c in pos_cols])[np.argsort(ids)]
    b = np.column_stack([second.column(c) for c in pos_cols])[
        np.argsort(second.column("id").astype(np.int64))]
    if a.shape != b.shape:
        raise ValueError("--base-types is needed: the first two snapshots have different atoms")
    still = np.all(a == b, axis=1) & np.all(v[np.argsort(ids)] == 0.0, axis=1)
    types_sorted = types[np.argsort(ids)]
    for t in np.unique(types_sorted):
        moved[t] = not still[types_sorted == t].all()
    base = [int(t) for t in np.unique(types) if not moved[t]]
    if not base:
        raise ValueError("no frozen base found (every type moves between the first two "
                         "snapshots): give --base-types")
    return base


def ingest_lammps(dumps, out_dir, theta: float, *, base_types=None, dt=None, gravity=1.0,
                  kn=None, t_c=None, e=None, kt_over_kn=2.0 / 7.0, gt_over_gn=1.0, mu_c=0.5,
                  pair_columns=PAIR_COLUMNS, t_start=None, z_origin=None, **analysis) -> dict:
    """Ingest a user's LAMMPS chute run (see the module docstring); returns the summary.

    ``kn`` (normal stiffness in the dump's units, every pair) or ``t_c`` and ``e`` (the flow
    species in granflow units, as ``granflow simulate``) give the elastic energy of the
    flow-state classifier (E_kin / E_ela).  ``analysis`` overrides :data:`INGEST_DEFAULTS`.
    ``t_start`` skips snapshots before that (granflow) time.  ``z_origin`` (dump units) is
    the height that becomes z = 0 (default: the highest base-particle centre).
    """
    from ..simulate import build_observers, startup_time, write_outputs
    from ..engine.run import EnergySeries
    from ..engine.species import check_range

    check_range("theta", theta, 0.0, 90.0, lo_open=True, hi_open=True)
    check_range("gravity", gravity, 0.0, math.inf, lo_open=True)
    unknown = sorted(set(analysis) - set(INGEST_DEFAULTS))
    if unknown:
        raise ValueError(f"unknown analysis setting(s) {unknown}: allowed {sorted(INGEST_DEFAULTS)}")
    if kn is None and t_c is None:
        raise ValueError("the elastic energy of the flow-state classifier needs the contact "
                         "stiffness: give kn (--kn, normal stiffness in the dump's units) or "
                         "t_c and e (--t-c, --e, the flow species in granflow units)")
    if kn is not None:
        check_range("kn", kn, 0.0, math.inf, lo_open=True)
    if t_c is not None:
        check_range("t_c", t_c, 0.0, math.inf, lo_open=True)
        check_range("e", 0.88 if e is None else e, 0.0, 1.0, lo_open=True)
    files = order_dump_files(dumps)
    if not files["atoms"]:
        raise ValueError("no per-atom dump among the files (ITEM: ATOMS ...: dump custom)")
    if not files["local"]:
        raise ValueError("no pair dump among the files (ITEM: ENTRIES ...: dump local of "
                         "compute pair/local and property/local)")
    # the first two atom snapshots: types, scales, box (a reader reads only what it yields)
    head = list(itertools.islice(iter(DumpReader(files["atoms"], kind="atoms")), 2))
    if not head:
        raise DumpFormatError(f"{files['atoms'][0]}: no snapshot")
    first = head[0]
    second = head[1] if len(head) > 1 else None
    types = first.column("type").astype(np.int64)
    if base_types is None:
        base_types = _detect_base_types(first, second)
        log.info("base types (frozen particles): %s", base_types)
    base_types = sorted({int(t) for t in base_types})
    present = sorted(set(types.tolist()))
    missing = [t for t in base_types if t not in present]
    if missing:
        raise ValueError(f"base type(s) {missing} do not occur in {first.source} (types "
                         f"present: {present})")
    flow_types = [t for t in present if t not in base_types]
    if not flow_types:
        raise ValueError(f"every type {present} is a base type: no flow particles")
    diam = (first.column("diameter") if first.has("diameter")
            else 2.0 * first.column("radius"))
    mass = first.column("mass")
    flow = ~np.isin(types, base_types)
    length = float(np.median(diam[flow]))
    mass_unit = float(np.median(mass[flow]))
    # flow species: flow types by mean diameter (species 0 the smallest, as granflow's "small")
    by_size = sorted(flow_types, key=lambda t: (float(diam[types == t].mean()), t))
    sizes = sorted({round(float(diam[types == t].mean()) / length, 9) for t in by_size})
    species_of_type = {}
    for t in by_size:
        species_of_type[t] = sizes.index(round(float(diam[types == t].mean()) / length, 9))
    n_species = len(sizes)
    base_ptype = n_species
    ptype_of_type = np.full(max(present) + 1, -1, np.int64)
    for t, sp in species_of_type.items():
        ptype_of_type[t] = sp
    for t in base_types:
        ptype_of_type[t] = base_ptype
    box = first.box
    if not np.isfinite(box).all():
        raise DumpFormatError(f"{first.source}: no BOX BOUNDS in the first snapshot")
    Lx = (box[0, 1] - box[0, 0]) / length
    Ly = (box[1, 1] - box[1, 0]) / length
    if first.boundary and not first.boundary.startswith("pp pp"):
        raise ValueError(f"{first.source}: box boundary {first.boundary!r}: a chute must be "
                         "periodic in x and y ('pp pp ..')")
    pos_col = "z" if first.has("z") else ("zu" if first.has("zu") else None)
    if pos_col is not None:
        z = first.column(pos_col)
    else:
        z = box[2, 0] + first.column("zs") * (box[2, 1] - box[2, 0])
    z_shift = (float(z[~flow].max()) if z_origin is None else float(z_origin)) / length
    lam = float(np.median(diam[~flow])) / length
    d_flow = diam[flow] / length
    H = float(np.sum(d_flow**3)) / (Lx * Ly)
    time_unit = math.sqrt(length / gravity)
    has_time = math.isfinite(first.time)
    if not has_time and dt is None:
        raise ValueError(f"{first.source}: the dump has no ITEM: TIME (dump_modify time yes): "
                         "give --dt (the run's time step, dump units)")
    dt_g = (dt / time_unit) if dt is not None else math.nan
    th = math.radians(theta)
    gvec = (math.sin(th), 0.0, -math.cos(th))
    # contact tables for the elastic energy (granflow units, type = granflow type index)
    names = [f"flow{k}" for k in range(n_species)] + ["base"]
    tab = InteractionTable(names, [s for s in sizes] + [lam])
    if t_c is not None:
        sp = ContactSpecies(t_c=t_c, e=0.88 if e is None else e, kt_over_kn=kt_over_kn,
                            gt_over_gn=gt_over_gn, mu_c=mu_c)
        for a in names:
            for b in names:
                tab.set(a, b, sp)
        tables = pair_tables(tab)
    else:
        sp = ContactSpecies()
        for a in names:
            for b in names:
                tab.set(a, b, sp)
        kn_g = kn * length / (mass_unit * gravity)  # force/length in granflow units
        t = len(names)
        full = lambda v: np.full((t, t), float(v))  # noqa: E731
        r = np.asarray(tab.type_diameters) / 2.0
        tables = PairTables(law=[["linear"] * t for _ in range(t)], kn=full(kn_g),
                            eta=full(0.0), kt=full(kt_over_kn * kn_g), x_gt=full(0.0),
                            mu=full(mu_c), d_ij=r[:, None] + r[None, :],
                            R=r[:, None] * r[None, :] / (r[:, None] + r[None, :]),
                            hertz=np.zeros((t, t), bool))
    p = dict(INGEST_DEFAULTS)
    p.update(analysis)
    p.update(theta=float(theta), H=H, lam=lam, Lx=Lx, Ly=Ly, engine="lammps-ingest",
             t_end=math.inf, stop_when_flowing=False)  # an ingest never stops a run
    system = SnapshotSystem(Lx, Ly, gvec, ptype_of_type, base_ptype, tables,
                            dt=dt_g if not has_time else math.nan, time_from_step=not has_time,
                            length=length, mass_unit=mass_unit, g=gravity, z_shift=z_shift,
                            interactions=tab, pair_columns=pair_columns)
    series = EnergySeries()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    atoms_it = iter(DumpReader(files["atoms"], kind="atoms"))
    pairs_it = iter(DumpReader(files["local"], kind="local"))
    observers = None
    n = 0
    for atoms, pairs in _paired(atoms_it, pairs_it):
        system.load(atoms, pairs)
        if t_start is not None and system.time < t_start - 1e-12:
            continue
        if observers is None:
            # the start-up transient (insertion fall) is excluded from the steady onset, as in
            # granflow's runs, when the dump starts at timestep 0
            t0 = system.time
            min_onset = t0 + (startup_time(system, theta) if atoms.timestep == 0 else 0.0)
            profile_obs, monitor_obs = build_observers(
                p, n_species, float(d_flow.max()), series, min_onset, t_cap=math.inf)
            monitor_obs.name = "monitor_passive"
            observers = [series, profile_obs, monitor_obs]
        for obs in observers:
            obs.sample(system)
        n += 1
    if observers is None:
        raise ValueError("no snapshot to ingest" + (f" at t >= {t_start}" if t_start else ""))
    p["t_end"] = system.time
    sources = {"atoms_dumps": [os.fspath(f) for f in files["atoms"]],
               "pair_dumps": [os.fspath(f) for f in files["local"]]}
    extra = {"engine": "lammps-ingest", "ingest_snapshots": n,
             "ingest_length_unit": length, "ingest_mass_unit": mass_unit,
             "ingest_gravity": float(gravity), "ingest_z_shift": z_shift * length,
             "ingest_base_types": " ".join(map(str, base_types)),
             "ingest_flow_types": " ".join(f"{t}:{species_of_type[t]}" for t in by_size),
             "ingest_sources": " ".join(sources["atoms_dumps"] + sources["pair_dumps"]),
             "ingest_elastic_energy": ("k_n = %g (dump units) for every pair" % kn
                                       if kn is not None else
                                       f"flow species t_c = {t_c:g}, e = {0.88 if e is None else e:g}")}
    run = _IngestRun(_NoSave(system), series, stop_reason=f"end of the dumps ({n} snapshots)")
    return write_outputs(p, out_dir, run, monitor_obs, profile_obs, None, extra)


class _NoSave:
    """A system without ``save``: an ingest writes no final_state.npz."""

    save = None

    def __init__(self, system):
        self._s = system

    def __getattr__(self, name):
        return getattr(self._s, name)
