"""Peak memory of reading damaged closure libraries: character-array strings (schema 2.1)
against HDF5 variable-length strings (schema 2.0).

Two kinds of damage, each opened with ``granflow.closures.open_library`` in a forked child
that records how much its peak resident memory (VmHWM) grew:

* random: one random byte flipped per trial (``--trials``, ``--seed``);
* lengths: every stored length of HDF5 variable-length data (a 4-byte length followed by the
  file address of a global heap collection, "GCOL") set to about 1e9, one per file.

A variable-length string's length is a number in the file that HDF5 allocates before it can
tell the file is corrupt; a character array is the size its shape declares.  (Variable-length
data remain in every netCDF-4 file: the dimension lists of its variables.)  Linux only (/proc).

    .venv/bin/python benchmarks/library_damage_memory.py [LIBRARY.nc] --trials 1500 --seed 1

Without LIBRARY a synthetic library of every closure kind is written (the fast tests' fits).
The 2.0 layout is the same dataset rewritten with xarray's default string encoding.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _hwm_mb() -> int:
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmHWM")) // 1024


def _open_in_child(path: Path) -> tuple[int, str]:
    """(MB the peak resident memory grew while opening ``path``, outcome) from a forked child."""
    from granflow.closures import open_library

    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # child
        os.close(r)
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")  # the peak restarts from the present resident size
        base = _hwm_mb()
        try:
            open_library(path)
            outcome = "opened"
        except Exception as exc:  # noqa: BLE001 -- any failure is an outcome here
            outcome = type(exc).__name__
        os.write(w, json.dumps([_hwm_mb() - base, outcome]).encode())
        os._exit(0)
    os.close(w)
    data = os.read(r, 4096)
    os.close(r)
    _, status = os.waitpid(pid, 0)
    if not data:
        return -1, f"child died (status {status})"
    grown, outcome = json.loads(data)
    return grown, outcome


def _synthetic_library(folder: Path) -> Path:
    sys.path.insert(0, str(REPO / "tests"))
    from test_closures import make_fits, make_table  # the fast tests' synthetic closures

    from granflow.closures import write_library

    return write_library(folder, "damage", make_fits(), make_table(),
                         config={"campaign": "synthetic"})


def _as_schema_2_0(path: Path, out: Path) -> Path:
    import xarray as xr

    from granflow.closures import open_library

    ds = open_library(path).assign_attrs(schema_version="2.0")
    for var in ds.variables.values():
        var.encoding = {}  # xarray's default: variable-length strings
    ds.to_netcdf(out, engine="netcdf4")
    with xr.open_dataset(out) as check:  # same data
        assert check.attrs["content_hash"] == ds.attrs["content_hash"]
    return out


def measure(path: Path, trials: int, seed: int, threshold_mb: int, scratch: Path) -> dict:
    original = path.read_bytes()
    rng = random.Random(seed)
    big, worst, outcomes = [], 0, {}
    bad = scratch / f"damaged-{path.name}"
    for trial in range(trials):
        blob = bytearray(original)
        offset = rng.randrange(len(blob))
        blob[offset] ^= rng.randrange(1, 256)
        bad.write_bytes(bytes(blob))
        grown, outcome = _open_in_child(bad)
        outcomes[outcome] = outcomes.get(outcome, 0) + 1
        worst = max(worst, grown)
        if grown > threshold_mb:
            big.append((trial, offset, grown, outcome))
    return {"bytes": len(original), "trials": trials, "over_threshold": big,
            "max_mb": worst, "outcomes": outcomes}


def length_fields(blob: bytes) -> list[int]:
    """Offsets of the stored lengths of variable-length data: 4 bytes (a length below 1e5)
    before the 8-byte address of a global heap collection."""
    import re
    import struct

    out = []
    for heap in (m.start() for m in re.finditer(b"GCOL", blob)):
        for m in re.finditer(re.escape(struct.pack("<Q", heap)), blob):
            offset = m.start() - 4
            if offset >= 0 and 0 < struct.unpack("<I", blob[offset:offset + 4])[0] < 100_000:
                out.append(offset)
    return sorted(set(out))


def measure_lengths(path: Path, threshold_mb: int, scratch: Path) -> dict:
    original = path.read_bytes()
    offsets = length_fields(original)
    big, worst, outcomes = 0, 0, {}
    bad = scratch / f"length-{path.name}"
    for offset in offsets:
        blob = bytearray(original)
        blob[offset + 3] = 0x40  # the length grows by 0x40 << 24, about 1.07e9
        bad.write_bytes(bytes(blob))
        grown, outcome = _open_in_child(bad)
        outcomes[outcome] = outcomes.get(outcome, 0) + 1
        worst = max(worst, grown)
        big += grown > threshold_mb
    return {"fields": len(offsets), "over_threshold": big, "max_mb": worst,
            "outcomes": outcomes}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("library", nargs="?", type=Path, help="a closure library (default: synthetic)")
    ap.add_argument("--trials", type=int, default=1500)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--threshold-mb", type=int, default=100)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        scratch = Path(tmp)
        lib = args.library or _synthetic_library(scratch / "lib")
        layouts = {"2.1 character arrays": lib,
                   "2.0 variable-length strings": _as_schema_2_0(lib, scratch / "as-2.0.nc")}
        print(f"one random byte flipped per trial, {args.trials} trials, seed {args.seed}; "
              f"peak resident growth while opening, threshold {args.threshold_mb} MB")
        print("| layout | file bytes | trials over threshold | largest growth (MB) | outcomes |")
        print("|---|---|---|---|---|")
        for name, path in layouts.items():
            r = measure(path, args.trials, args.seed, args.threshold_mb, scratch)
            print(f"| {name} | {r['bytes']} | {len(r['over_threshold'])} | {r['max_mb']} | "
                  f"{r['outcomes']} |")
            for trial, offset, grown, outcome in r["over_threshold"]:
                print(f"    trial {trial}: byte {offset} -> {grown} MB, {outcome}")
        print("\nevery stored length of variable-length data set to about 1e9, one per file")
        print("| layout | length fields | files over threshold | largest growth (MB) | outcomes |")
        print("|---|---|---|---|---|")
        for name, path in layouts.items():
            r = measure_lengths(path, args.threshold_mb, scratch)
            print(f"| {name} | {r['fields']} | {r['over_threshold']} | {r['max_mb']} | "
                  f"{r['outcomes']} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
