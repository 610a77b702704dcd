"""Streaming reader of LAMMPS text dump files (per-atom ``dump custom`` and ``dump local``).

A LAMMPS text dump is a sequence of snapshots, each a header of ``ITEM:`` blocks followed by
one row per atom (``ITEM: ATOMS <columns>``) or per local entry, e.g. per contact of
``compute pair/local`` (``ITEM: ENTRIES <columns>``)::

    ITEM: TIME                      (optional: dump_modify time yes)
    12.5
    ITEM: TIMESTEP
    31250
    ITEM: NUMBER OF ATOMS           (NUMBER OF ENTRIES for dump local)
    4096
    ITEM: BOX BOUNDS pp pp mm       (orthogonal box; a triclinic box is refused)
    0 20
    0 10
    -2.1 31.7
    ITEM: ATOMS id type mass diameter x y z vx vy vz omegax omegay omegaz
    ...

:class:`DumpReader` yields one :class:`DumpSnapshot` at a time and keeps nothing of earlier
snapshots, so memory stays flat however long the run (granflow's ingest never holds a
trajectory).  It reads plain or gzip-compressed (``.gz``) files, several files of one dump in
sequence (``dump ... atoms.*.dump`` writes one file per snapshot), and live streams (a named
pipe LAMMPS writes while it runs, see :mod:`granflow.lammps.runner`).  Every malformed input --
a truncated snapshot, a row with the wrong number of values, an unknown ``ITEM`` -- raises
:class:`DumpFormatError` naming the file, the line and the timestep.
"""

from __future__ import annotations

import gzip
import io
import itertools
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["DumpFormatError", "DumpReader", "DumpSnapshot", "dump_kind", "first_timestep",
           "order_dump_files", "write_dump_snapshot"]

#: Header items with one value line (name -> parser).
_ONE_LINE = {"TIMESTEP": int, "TIME": float, "UNITS": str}


class DumpFormatError(ValueError):
    """A LAMMPS dump that cannot be read; the message names the file, line and timestep."""


@dataclass
class DumpSnapshot:
    """One snapshot of a dump: its kind ("atoms" or "local"), timestep, time (NaN if the dump
    does not state it), box bounds (3 x 2: lo, hi per axis), boundary flags (e.g. "pp pp mm"),
    column names, and the rows as a float array (n, n_columns)."""

    kind: str
    timestep: int
    time: float
    box: np.ndarray
    boundary: str
    columns: tuple
    data: np.ndarray
    source: str
    line: int

    def column(self, name: str) -> np.ndarray:
        try:
            return self.data[:, self.columns.index(name)]
        except ValueError:
            raise DumpFormatError(f"{self.source}: snapshot at timestep {self.timestep} has no "
                                  f"column {name!r} (columns: {' '.join(self.columns)})") from None

    def has(self, name: str) -> bool:
        return name in self.columns


def _open_text(path: Path):
    if path.suffix == ".gz":
        return io.TextIOWrapper(gzip.open(path, "rb"), encoding="ascii", errors="replace")
    return open(path, "r", encoding="ascii", errors="replace", buffering=1 << 20)


def _parse_rows(lines, ncol, source, line0, timestep):
    """(n, ncol) float array from n text rows; a short or long row is named in the error."""
    n = len(lines)
    if n == 0:
        return np.zeros((0, ncol))
    text = "".join(lines)
    try:
        values = np.array(text.split(), dtype=np.float64)
    except ValueError as exc:
        for k, row in enumerate(lines):
            if row.startswith("ITEM:"):
                raise DumpFormatError(f"{source}: line {line0 + k}: the snapshot at timestep "
                                      f"{timestep} has {k} rows, its header says {n}") from None
        raise DumpFormatError(f"{source}: line {line0}+: a row of the snapshot at timestep "
                              f"{timestep} holds a non-number ({exc})") from None
    if values.size != n * ncol:
        for k, row in enumerate(lines):
            if row.startswith("ITEM:"):
                raise DumpFormatError(f"{source}: line {line0 + k}: the snapshot at timestep "
                                      f"{timestep} has {k} rows, its header says {n}")
            if len(row.split()) != ncol:
                raise DumpFormatError(
                    f"{source}: line {line0 + k}: row has {len(row.split())} values, the header "
                    f"of the snapshot at timestep {timestep} names {ncol} columns")
        raise DumpFormatError(f"{source}: snapshot at timestep {timestep}: {values.size} values "
                              f"for {n} rows of {ncol} columns")
    return values.reshape(n, ncol)


class DumpReader:
    """Iterate over the snapshots of one LAMMPS dump, one at a time.

    Parameters
    ----------
    sources : a path, a list of paths read in sequence (files of one dump, ordered by time:
        see :func:`order_dump_files`), or an open text stream (``name`` names it in errors).
    kind : "atoms" or "local" to check what the dump holds (None: accept either).
    """

    def __init__(self, sources, kind: str | None = None, name: str | None = None):
        if isinstance(sources, (str, os.PathLike)):
            sources = [sources]
        if hasattr(sources, "readline"):
            self._streams = [(sources, name or getattr(sources, "name", "<stream>"))]
            self._paths = None
        else:
            self._paths = [Path(p) for p in sources]
            self._streams = None
            for p in self._paths:
                if not p.exists():
                    raise FileNotFoundError(f"dump file {os.fspath(p)!r} does not exist")
        if kind not in (None, "atoms", "local"):
            raise ValueError(f"kind = {kind!r}: allowed 'atoms', 'local' or None")
        self.kind = kind

    def __iter__(self):
        if self._streams is not None:
            for fh, name in self._streams:
                yield from self._read(fh, name)
            return
        for path in self._paths:
            with _open_text(path) as fh:
                yield from self._read(fh, os.fspath(path))

    # ------------------------------------------------------------------ one stream
    def _read(self, fh, source):
        lineno = 0

        def next_line():
            nonlocal lineno
            line = fh.readline()
            if line:
                lineno += 1
            return line

        while True:
            header = {}
            line = next_line()
            while line and not line.strip():
                line = next_line()
            if not line:
                return  # clean end of the stream (between snapshots)
            start = lineno
            while True:
                if not line:
                    raise DumpFormatError(f"{source}: ends inside the header of the snapshot "
                                          f"starting at line {start} (truncated dump)")
                if not line.startswith("ITEM:"):
                    raise DumpFormatError(f"{source}: line {lineno}: expected an 'ITEM:' header "
                                          f"line, found {line.strip()[:60]!r}")
                item = line[5:].strip()
                key = item.split()[0] if item else ""
                if item.startswith("NUMBER OF ATOMS") or item.startswith("NUMBER OF ENTRIES"):
                    header["n"] = self._value(next_line(), int, source, lineno, item)
                    header["kind"] = "atoms" if "ATOMS" in item else "local"
                elif item.startswith("BOX BOUNDS"):
                    flags = item.split()[2:]
                    if flags and flags[0] in ("xy", "xz", "yz"):
                        raise DumpFormatError(f"{source}: line {lineno}: triclinic box "
                                              "(BOX BOUNDS xy xz yz): granflow reads orthogonal "
                                              "chute boxes only")
                    box = np.zeros((3, 2))
                    for a in range(3):
                        parts = next_line().split()
                        try:
                            box[a] = [float(parts[0]), float(parts[1])]
                        except (IndexError, ValueError):
                            raise DumpFormatError(f"{source}: line {lineno}: bad BOX BOUNDS "
                                                  "line (need 'lo hi')") from None
                    header["box"] = box
                    header["boundary"] = " ".join(flags)
                elif key in _ONE_LINE and item == key:
                    header[key] = self._value(next_line(), _ONE_LINE[key], source, lineno, item)
                elif item.startswith("ATOMS") or item.startswith("ENTRIES"):
                    header["columns"] = tuple(item.split()[1:])
                    header["body_kind"] = "atoms" if item.startswith("ATOMS") else "local"
                    break
                else:
                    raise DumpFormatError(f"{source}: line {lineno}: unknown header item "
                                          f"{line.strip()!r}")
                line = next_line()
            for need in ("TIMESTEP", "n"):
                if need not in header:
                    raise DumpFormatError(f"{source}: snapshot starting at line {start} lacks "
                                          f"its {'ITEM: TIMESTEP' if need == 'TIMESTEP' else 'ITEM: NUMBER OF ...'} block")
            kind = header["body_kind"]
            if header["kind"] != kind:
                raise DumpFormatError(f"{source}: line {lineno}: NUMBER OF "
                                      f"{'ATOMS' if header['kind'] == 'atoms' else 'ENTRIES'} "
                                      f"with ITEM: {'ATOMS' if kind == 'atoms' else 'ENTRIES'}")
            if self.kind is not None and kind != self.kind:
                raise DumpFormatError(f"{source}: holds {kind} rows ('ITEM: "
                                      f"{'ATOMS' if kind == 'atoms' else 'ENTRIES'}'), expected "
                                      f"a {'per-atom (dump custom)' if self.kind == 'atoms' else 'local (dump local)'} dump")
            n = header["n"]
            ts = header["TIMESTEP"]
            body0 = lineno + 1
            rows = list(itertools.islice(fh, n)) if n else []
            lineno += len(rows)
            if len(rows) < n or (n and not rows[-1].endswith("\n")):
                raise DumpFormatError(f"{source}: ends inside the snapshot at timestep {ts} "
                                      f"({len(rows)} of {n} rows; truncated dump)")
            data = _parse_rows(rows, len(header["columns"]), source, body0, ts)
            yield DumpSnapshot(kind=kind, timestep=ts, time=float(header.get("TIME", np.nan)),
                               box=header.get("box", np.full((3, 2), np.nan)),
                               boundary=header.get("boundary", ""),
                               columns=header["columns"], data=data, source=source, line=start)

    @staticmethod
    def _value(line, conv, source, lineno, item):
        try:
            return conv(line.split()[0])
        except (IndexError, ValueError):
            raise DumpFormatError(f"{source}: line {lineno}: bad value {line.strip()[:40]!r} "
                                  f"after 'ITEM: {item}'") from None


# ---------------------------------------------------------------------- file sets
def _head(path: Path, nlines: int = 40):
    out = []
    with _open_text(path) as fh:
        for _ in range(nlines):
            line = fh.readline()
            if not line:
                break
            out.append(line)
    return out


def dump_kind(path) -> str:
    """"atoms" (``dump custom``/``atom``) or "local" (``dump local``) from a file's header."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"dump file {os.fspath(path)!r} does not exist")
    try:
        head = _head(path)
    except (OSError, EOFError, gzip.BadGzipFile) as exc:
        raise DumpFormatError(f"{os.fspath(path)}: unreadable ({exc})") from None
    if not head or not head[0].startswith("ITEM:"):
        raise DumpFormatError(f"{os.fspath(path)}: not a LAMMPS text dump (first line "
                              f"{(head[0].strip()[:60] if head else '<empty file>')!r}; binary "
                              "dumps: convert with LAMMPS's binary2txt tool)")
    for line in head:
        if line.startswith("ITEM: NUMBER OF ATOMS"):
            return "atoms"
        if line.startswith("ITEM: NUMBER OF ENTRIES"):
            return "local"
    raise DumpFormatError(f"{os.fspath(path)}: no 'ITEM: NUMBER OF ATOMS/ENTRIES' in its header")


def first_timestep(path) -> int:
    """Timestep of a dump file's first snapshot (reads its header only)."""
    head = _head(Path(path))
    for k, line in enumerate(head[:-1]):
        if line.startswith("ITEM: TIMESTEP"):
            try:
                return int(head[k + 1].split()[0])
            except (IndexError, ValueError):
                break
    raise DumpFormatError(f"{os.fspath(path)}: no readable 'ITEM: TIMESTEP' in its header")


_NUM_IN_NAME = re.compile(r"(\d+)")


def order_dump_files(paths) -> dict:
    """Sort dump files into {"atoms": [...], "local": [...]}, each ordered by first timestep."""
    groups = {"atoms": [], "local": []}
    for p in paths:
        p = Path(p)
        groups[dump_kind(p)].append((first_timestep(p), p.name, p))
    return {k: [p for _, _, p in sorted(v)] for k, v in groups.items()}


# ---------------------------------------------------------------------- writing
def write_dump_snapshot(fh, kind: str, timestep: int, columns, data, box, time=None,
                        boundary="pp pp mm", fmt="%.10g"):
    """Append one snapshot in LAMMPS text-dump layout to the open text file ``fh``.

    For tests, benchmarks and converting other codes' snapshots to what ``granflow ingest
    lammps`` reads; ``kind`` is "atoms" (``ITEM: ATOMS``) or "local" (``ITEM: ENTRIES``).
    """
    if kind not in ("atoms", "local"):
        raise ValueError(f"kind = {kind!r}: allowed 'atoms', 'local'")
    data = np.asarray(data, dtype=np.float64).reshape(-1, len(columns))
    box = np.asarray(box, dtype=np.float64).reshape(3, 2)
    what = "ATOMS" if kind == "atoms" else "ENTRIES"
    head = ""
    if time is not None:
        head += f"ITEM: TIME\n{float(time):.16g}\n"
    head += (f"ITEM: TIMESTEP\n{int(timestep)}\nITEM: NUMBER OF {what}\n{len(data)}\n"
             f"ITEM: BOX BOUNDS {boundary}\n"
             + "".join(f"{lo:.16e} {hi:.16e}\n" for lo, hi in box)
             + f"ITEM: {what} {' '.join(columns)}\n")
    fh.write(head)
    if len(data):
        np.savetxt(fh, data, fmt=fmt)
