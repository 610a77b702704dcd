"""Tests of granflow.coarse depth profiles against closed forms (Weinhart et al. 2012 §3).

Closed forms used (plane average over the periodic box, area A = Lx Ly; g, G = density and CDF
of the 1D Gaussian of width w, truncated at cutoff*w and renormalised):
* density rho(z) = sum_i m_i g(z - z_i) / A                                     (Eq. 13)
* flow-flow pair (segment r_i -> r_j): sigma_ab(z) = f_a r_b / r_z (G(z - z_j) - G(z - z_i)) / A
* flow-base pair (half-line from r_i along unit u):
  sigma_ab(z) = -f_a u_b / |u_z| (1 - G(z - z_i)) / A
  for u_z < 0 and -f_a u_b / u_z G(z - z_i) / A for u_z > 0                        (Eq. 32)
(compressive positive, i.e. -1 times Eq. 32).
"""

import math

import numpy as np
import pytest
from scipy.special import erf

from granflow.coarse import DepthProfileAccumulator, coarse_grain_profiles

KEYS = ("pos", "vel", "mass", "diameter", "species", "fixed", "contact_i", "contact_j",
        "contact_force", "contact_rij", "contact_point")


def g_t(a, w, cut):
    """Truncated renormalised Gaussian density."""
    norm = math.erf(cut / math.sqrt(2))
    out = np.exp(-0.5 * (a / w) ** 2) / (math.sqrt(2 * math.pi) * w * norm)
    return np.where(np.abs(a) < cut * w, out, 0.0)


def G_t(a, w, cut):
    """CDF of g_t."""
    norm = math.erf(cut / math.sqrt(2))
    inner = 0.5 * (1 + erf(a / (math.sqrt(2) * w)) / norm)
    return np.where(a <= -cut * w, 0.0, np.where(a >= cut * w, 1.0, inner))


def snapshot(pos, fixed=None, vel=None, mass=None, diameter=None, species=None, contacts=()):
    """Snapshot dict; contacts: list of (i, j, force(3), contact point(3) or None)."""
    pos = np.asarray(pos, dtype=float)
    n = len(pos)
    ci = np.array([c[0] for c in contacts], dtype=np.int64)
    cj = np.array([c[1] for c in contacts], dtype=np.int64)
    f = np.array([c[2] for c in contacts], dtype=float).reshape(-1, 3)
    rij = (pos[ci] - pos[cj]).reshape(-1, 3)
    cp = np.array([c[3] if c[3] is not None else pos[c[0]] - 0.5 * (pos[c[0]] - pos[c[1]])
                   for c in contacts], dtype=float).reshape(-1, 3)
    return {
        "time": 0.0, "pos": pos,
        "vel": np.zeros((n, 3)) if vel is None else np.asarray(vel, float),
        "mass": np.ones(n) if mass is None else np.asarray(mass, float),
        "diameter": np.ones(n) if diameter is None else np.asarray(diameter, float),
        "species": np.zeros(n, np.int32) if species is None else np.asarray(species, np.int32),
        "fixed": np.zeros(n, bool) if fixed is None else np.asarray(fixed, bool),
        "contact_i": ci, "contact_j": cj, "contact_force": f, "contact_rij": rij,
        "contact_point": cp,
    }


def profiles(snaps, z_min=-4.0, z_max=4.0, dz=0.01, **kw):
    kw.setdefault("Lx", 2.0)
    kw.setdefault("Ly", 3.0)
    return coarse_grain_profiles(snaps, z_min, z_max, dz, **kw)


# ---------------------------------------------------------------- Fig. 1 two-particle systems
C = 0.1234  # off-grid centre
W = 0.2


def test_fig1_both_flowing_closed_form():
    """Two flowing unit masses at z = C -/+ 1 repelling with |f| = 1 (Fig. 1 top)."""
    lo, hi = C - 1.0, C + 1.0
    snap = snapshot([[0.3, 0.4, lo], [0.3, 0.4, hi]], diameter=[2.1, 2.1],
                    contacts=[(0, 1, [0, 0, -1.0], None)])  # force on the lower one points down
    ds = profiles([snap], width=W, cutoff=10.0)
    z = ds.z.values
    A = 6.0
    gauss = lambda a: np.exp(-a * a / (2 * W * W)) / (math.sqrt(2 * math.pi) * W)  # noqa: E731
    Phi = lambda a: 0.5 * (1 + erf(a / (math.sqrt(2) * W)))  # noqa: E731
    np.testing.assert_allclose(ds.density.values, (gauss(z - lo) + gauss(z - hi)) / A,
                               rtol=0, atol=1e-10)
    # segment integral: sigma_zz = f_z r_z int_0^1 g(z - z_i + s r_z) ds = Phi(z-lo) - Phi(z-hi)
    expected = (Phi(z - lo) - Phi(z - hi)) / A
    np.testing.assert_allclose(ds.stress_zz.values, expected, rtol=0, atol=1e-10)
    np.testing.assert_allclose(ds.stress_contact_zz.values, expected, rtol=0, atol=1e-10)
    assert np.all(ds.stress_base_zz.values == 0)
    assert ds.stress_zz.values.max() == pytest.approx(1 / A, rel=1e-5)  # compressive positive
    for name in ("stress_xx", "stress_xz", "stress_yz", "stress_kinetic_zz"):
        np.testing.assert_allclose(ds[name].values, 0.0, atol=1e-15)


def test_fig1_one_fixed_closed_form():
    """Fixed base particle at C - 1, flowing particle at C + 1, repelling (Fig. 1 bottom)."""
    lo, hi = C - 1.0, C + 1.0
    snap = snapshot([[0.3, 0.4, hi], [0.3, 0.4, lo]], fixed=[False, True], diameter=[2.1, 2.1],
                    contacts=[(0, 1, [0, 0, 1.0], [0.3, 0.4, C])])
    ds = profiles([snap], width=W, cutoff=10.0)
    z = ds.z.values
    A = 6.0
    gauss = lambda a: np.exp(-a * a / (2 * W * W)) / (math.sqrt(2 * math.pi) * W)  # noqa: E731
    Phi = lambda a: 0.5 * (1 + erf(a / (math.sqrt(2) * W)))  # noqa: E731
    np.testing.assert_allclose(ds.density.values, gauss(z - hi) / A, rtol=0, atol=1e-10)
    # half-line from hi down to -infinity: int_0^inf g(z - hi + t) dt = 1 - Phi(z - hi)
    expected = (1 - Phi(z - hi)) / A
    np.testing.assert_allclose(ds.stress_zz.values, expected, rtol=0, atol=1e-10)
    np.testing.assert_allclose(ds.stress_base_zz.values, expected, rtol=0, atol=1e-10)
    assert np.all(ds.stress_contact_zz.values == 0)
    assert ds.stress_zz.values[0] == pytest.approx(1 / A, rel=1e-12)  # stress reaches -infinity


@pytest.mark.parametrize("swap", [False, True])
def test_oblique_pairs_all_components(swap):
    """Oblique flow-flow and flow-base contacts: every stored component vs the closed forms."""
    w, cut = 0.25, 4.0
    p = np.array([[1.0, 1.0, 0.83], [1.55, 0.8, 0.05], [0.4, 1.3, -0.61]])
    f01 = np.array([-0.7, 0.3, 1.9])  # force on 0 from 1
    u = np.array([0.35, -0.2, -0.6])  # from particle 0 towards its base contact (downwards)
    u2 = np.array([-0.3, 0.5, 0.45])  # upward half-line of particle 2
    f0b = np.array([0.2, -0.1, 2.5])
    f2b = np.array([0.4, 0.1, -0.9])
    base = np.array([[1.2, 1.0, -1.2], [0.2, 1.5, -0.2]])
    pos = np.vstack([p, base])
    fixed = [False, False, False, True, True]
    contacts = [(0, 1, f01, None), (0, 3, f0b, p[0] + 0.5 * u / np.linalg.norm(u)),
                (2, 4, f2b, p[2] + 0.4 * u2 / np.linalg.norm(u2))]
    snap = snapshot(pos, fixed=fixed, contacts=contacts)
    if swap:  # list the base contacts with the base particle first (defensive path)
        ci, cj = snap["contact_i"].copy(), snap["contact_j"].copy()
        snap["contact_i"][1:], snap["contact_j"][1:] = cj[1:], ci[1:]
        snap["contact_force"][1:] *= -1
        snap["contact_rij"][1:] *= -1
    ds = profiles([snap], width=w, cutoff=cut, dz=0.0137, base_line="contact")
    z = ds.z.values
    A = 6.0
    r = p[0] - p[1]
    comps = {"xx": (0, 0), "yy": (1, 1), "zz": (2, 2), "xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}
    un = u / np.linalg.norm(u)
    un2 = u2 / np.linalg.norm(u2)
    for name, (a, b) in comps.items():
        con = f01[a] * r[b] / r[2] * (G_t(z - p[1, 2], w, cut) - G_t(z - p[0, 2], w, cut)) / A
        bas = (-f0b[a] * un[b] / abs(un[2]) * (1 - G_t(z - p[0, 2], w, cut))
               - f2b[a] * un2[b] / un2[2] * G_t(z - p[2, 2], w, cut)) / A
        np.testing.assert_allclose(ds[f"stress_contact_{name}"].values, con, atol=1e-10, rtol=0)
        np.testing.assert_allclose(ds[f"stress_base_{name}"].values, bas, atol=1e-10, rtol=0)
    assert ds.attrs["cg_n_upward_base_contacts"] == 1


@pytest.mark.parametrize("base_line", ["contact_then_down", "through_contact"])
@pytest.mark.parametrize("swap", [False, True])
def test_base_paths_closed_form_and_zero_above(swap, base_line):
    """Base paths for a downward and an *upward* branch vector (flow particle sitting below the
    centre of the base particle it touches), every component against its closed form:
    segment r_i -> contact point c, then straight down from c (``contact_then_down``, default):
        f_a r_b / r_z (G(z - z_c) - G(z - z_i)) + [b = z] f_a (1 - G(z - z_c)),  r = r_i - c;
    the paper's half-line along u = c - r_i (``through_contact``):
        f_a u_b / u_z (1 - G(z - z_i)) for u_z < 0 and -f_a u_b / u_z G(z - z_i) for u_z > 0.
    With the default every base-stress component is exactly 0 above max(z_i, z_c) + cutoff w;
    the literal half-line leaves the upward contact's plateau all the way up."""
    w, cut = 0.25, 4.0
    p = np.array([[1.0, 1.0, 0.33], [0.4, 1.3, -0.21]])
    base = np.array([[1.2, 0.9, -0.4], [0.1, 1.6, 0.25]])
    c0 = p[0] + 0.5 * np.array([0.35, -0.2, -0.6]) / np.linalg.norm([0.35, -0.2, -0.6])
    c1 = p[1] + 0.45 * np.array([-0.3, 0.5, 0.45]) / np.linalg.norm([-0.3, 0.5, 0.45])  # up
    f0 = np.array([0.2, -0.1, 2.5])
    f1 = np.array([0.4, 0.1, -0.9])
    snap = snapshot(np.vstack([p, base]), fixed=[False, False, True, True],
                    contacts=[(0, 2, f0, c0), (1, 3, f1, c1)])
    if swap:
        ci, cj = snap["contact_i"].copy(), snap["contact_j"].copy()
        snap["contact_i"], snap["contact_j"] = cj, ci
        snap["contact_force"] *= -1
        snap["contact_rij"] *= -1
        # contact point relative to the (stored) base particle: unchanged here (no periodic image)
    ds = profiles([snap], width=w, cutoff=cut, dz=0.0137, base_line=base_line)
    assert ds.attrs["cg_base_line"] == base_line
    assert "contact point" in ds.attrs["cg_base_line_description"]
    assert profiles([snap], width=w, cutoff=cut).attrs["cg_base_line"] == "contact_then_down"
    assert ds.attrs["cg_n_upward_base_contacts"] == 1
    z = ds.z.values
    A = 6.0
    comps = {"xx": (0, 0), "yy": (1, 1), "zz": (2, 2), "xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}
    for name, (a, b) in comps.items():
        expected = np.zeros_like(z)
        for pi, ci_, fi in ((p[0], c0, f0), (p[1], c1, f1)):
            r = pi - ci_
            if base_line == "through_contact":  # the paper's half-line along u = c - r_i
                u = ci_ - pi
                expected += fi[a] * u[b] / u[2] * ((1 - G_t(z - pi[2], w, cut)) if u[2] < 0
                                                   else -G_t(z - pi[2], w, cut))
                continue
            expected += fi[a] * r[b] / r[2] * (G_t(z - ci_[2], w, cut) - G_t(z - pi[2], w, cut))
            if b == 2:
                expected += fi[a] * (1 - G_t(z - ci_[2], w, cut))
        np.testing.assert_allclose(ds[f"stress_base_{name}"].values, expected / A, atol=1e-10,
                                   rtol=0)
        top = max(p[0, 2], p[1, 2], c0[2], c1[2]) + cut * w
        above = ds[f"stress_base_{name}"].values[z > top + 1e-12]
        if base_line == "contact_then_down":
            assert np.all(above == 0.0), name
        elif name in ("xx", "yy", "xy"):  # the upward contact's plateau, all the way up
            assert np.all(np.abs(above) > 1e-3), name


@pytest.mark.parametrize("base_line", ["contact_then_down", "down", "through_contact"])
def test_momentum_balance_with_upward_branch_vectors(base_line):
    """sigma_az(z) = sum_i F_i,a (1 - G(z - z_i)) / A + const for every base path, with half of
    the flow-base branch vectors pointing up: the momentum balance is exact for each; the
    constant is 0 for the two paths into the base (stress vanishes above the flow) and minus
    the upward contacts' summed f_a (the plateau) for the literal half-line."""
    rng = np.random.default_rng(11)
    w, cut = 0.25, 4.0
    snap = random_snapshot(rng, upward_fraction=0.5)
    n = int((~snap["fixed"]).sum())
    F = np.zeros((len(snap["pos"]), 3))
    np.add.at(F, snap["contact_i"], snap["contact_force"])
    np.add.at(F, snap["contact_j"], -snap["contact_force"])
    ds = coarse_grain_profiles([snap], -3, 9, 0.023, width=w, Lx=4.0, Ly=3.0, cutoff=cut,
                               base_line=base_line)
    z = ds.z.values
    zi = snap["pos"][:n, 2]
    Gm = G_t(z[None, :] - zi[:, None], w, cut)
    base = snap["fixed"][snap["contact_j"]]
    up = base & (snap["contact_point"][:, 2] > snap["pos"][snap["contact_i"], 2])
    assert up.sum() >= 5
    for a, c in enumerate("xyz"):
        expected = (F[:n, a, None] * (1 - Gm)).sum(axis=0) / 12.0
        if base_line == "through_contact":  # exact too, but offset by the upward plateau
            expected = expected - snap["contact_force"][up, a].sum() / 12.0
        got = ds[f"stress_contact_{c}z"].values + ds[f"stress_base_{c}z"].values
        np.testing.assert_allclose(got, expected, atol=1e-10, rtol=0)
    if base_line != "through_contact":
        top = max(snap["pos"][snap["contact_i"][base], 2].max(),
                  snap["contact_point"][base, 2].max()) + cut * w
        for name in ("xx", "yy", "zz", "xy", "xz", "yz"):
            assert np.all(ds[f"stress_base_{name}"].values[z > top + 1e-12] == 0.0)


def test_horizontal_pair_midpoint():
    """A horizontal flow-flow pair spreads f_a r_b g(z - z_i) (segment at constant z)."""
    w, cut = 0.25, 4.0
    pos = [[0.2, 0.2, 0.317], [1.1, 0.2, 0.317]]
    f = [-2.0, 0.0, 0.3]
    ds = profiles([snapshot(pos, contacts=[(0, 1, f, None)])], width=w, cutoff=cut)
    z = ds.z.values
    expected = f[0] * (-0.9) * g_t(z - 0.317, w, cut) / 6.0
    np.testing.assert_allclose(ds.stress_xx.values, expected, atol=1e-12, rtol=0)
    np.testing.assert_allclose(ds.stress_zz.values, 0.0, atol=1e-14)


# ---------------------------------------------------------------- conservation identities
def random_snapshot(rng, n=60, n_base=20, Lx=4.0, Ly=3.0, tilt=True, upward_fraction=0.0):
    pos = np.column_stack([rng.uniform(0, Lx, n), rng.uniform(0, Ly, n), rng.uniform(0.3, 5, n)])
    base = np.column_stack([rng.uniform(0, Lx, n_base), rng.uniform(0, Ly, n_base),
                            rng.uniform(-0.8, 0.0, n_base)])
    allpos = np.vstack([pos, base])
    contacts = []
    for _ in range(3 * n // 2):
        i, j = rng.choice(n, 2, replace=False)
        contacts.append((i, j, rng.normal(size=3), None))
    for i in rng.choice(n, 15, replace=False):
        k = n + rng.integers(n_base)
        u = allpos[k] - allpos[i]
        u[2] = -abs(u[2]) - 0.1  # downward half-lines ...
        if rng.uniform() < upward_fraction:
            u[2] = -u[2]  # ... or a flow particle below the contact point
        contacts.append((i, k, rng.normal(size=3), allpos[i] + 0.5 * u / np.linalg.norm(u)))
    contacts.append((0, 1, rng.normal(size=3), None))
    allpos[1, 2] = allpos[0, 2]  # one exactly horizontal pair
    snap = snapshot(allpos, fixed=[False] * n + [True] * n_base, contacts=contacts,
                    vel=rng.normal(size=(n + n_base, 3)), mass=rng.uniform(0.5, 2, n + n_base),
                    diameter=rng.uniform(0.8, 1.2, n + n_base))
    return snap


def test_momentum_balance_random_network():
    """sigma_az(z) = sum_i F_i,a (1 - G(z - z_i)) / A for the net contact force F_i on every flow
    particle (plane-averaged Eq. 19/28, exact for any contact network with downward base lines)."""
    rng = np.random.default_rng(4)
    w, cut = 0.25, 4.0
    snap = random_snapshot(rng)
    n = int((~snap["fixed"]).sum())
    F = np.zeros((len(snap["pos"]), 3))
    np.add.at(F, snap["contact_i"], snap["contact_force"])
    np.add.at(F, snap["contact_j"], -snap["contact_force"])
    ds = coarse_grain_profiles([snap], -3, 9, 0.023, width=w, Lx=4.0, Ly=3.0, cutoff=cut)
    z = ds.z.values
    zi = snap["pos"][:n, 2]
    Gm = G_t(z[None, :] - zi[:, None], w, cut)
    for a, c in enumerate("xyz"):
        expected = (F[:n, a, None] * (1 - Gm)).sum(axis=0) / 12.0
        got = ds[f"stress_contact_{c}z"].values + ds[f"stress_base_{c}z"].values
        np.testing.assert_allclose(got, expected, atol=1e-10, rtol=0)
    # base_line="down" changes only where the base half-lines are inside the kernel support
    ds_down = coarse_grain_profiles([snap], -3, 9, 0.023, width=w, Lx=4.0, Ly=3.0, cutoff=cut,
                                    base_line="down")
    np.testing.assert_allclose(ds_down.stress_zz.values, ds.stress_zz.values, atol=1e-10)


@pytest.mark.parametrize("cut", [8.0])
def test_density_integral_equals_mass(cut):
    """int rho dz = flowing mass / (Lx Ly) (base particles carry no mass)."""
    rng = np.random.default_rng(1)
    snap = random_snapshot(rng)
    ds = coarse_grain_profiles([snap], -6, 12, 0.05, width=0.25, Lx=4.0, Ly=3.0, cutoff=cut)
    flow_mass = snap["mass"][~snap["fixed"]].sum()
    integral = ds.density.sum().item() * 0.05  # spectrally accurate for the Gaussian
    assert integral == pytest.approx(flow_mass / 12.0, rel=1e-10)
    # momentum likewise
    p = (snap["mass"] * snap["vel"][:, 0])[~snap["fixed"]].sum() / 12.0
    assert ds.momentum_x.sum().item() * 0.05 == pytest.approx(p, rel=1e-10)
    # species volume fraction integrates to the particle volume
    vol = (np.pi / 6 * snap["diameter"] ** 3)[~snap["fixed"]].sum() / 12.0
    assert ds.volume_fraction.sum().item() * 0.05 == pytest.approx(vol, rel=1e-10)


def test_static_column_lithostatic():
    """Vertical chain on a fixed base particle in exact static equilibrium under tilted gravity:
    sigma_zz = cos(theta) int_z^inf rho dz' and sigma_xz = -sin(theta) int_z^inf rho dz'
    everywhere, including at and below the base (this checks the base half-line term)."""
    w, cut = 0.25, 4.0
    theta = math.radians(24.0)
    n = 12
    masses = np.linspace(0.7, 1.4, n)
    zs = 0.9 + 0.97 * np.arange(n)
    pos = np.vstack([np.column_stack([np.full(n, 0.7), np.full(n, 0.4), zs]), [[0.7, 0.4, 0.0]]])
    gdir = np.array([math.sin(theta), 0.0, -math.cos(theta)])
    contacts = []
    for k in range(1, n):  # force on particle k from k-1 below = weight of k and above
        contacts.append((k, k - 1, -gdir * masses[k:].sum(), None))
    contacts.append((0, n, -gdir * masses.sum(), pos[0] + [0, 0, -0.45]))
    snap = snapshot(pos, fixed=[False] * n + [True], mass=np.append(masses, 1e30),
                    contacts=contacts)
    ds = profiles([snap], z_min=-3.0, z_max=16.0, dz=0.0173, width=w, cutoff=cut)
    z = ds.z.values
    A = 6.0
    rho = (masses[:, None] * g_t(z[None, :] - zs[:, None], w, cut)).sum(axis=0) / A
    above = (masses[:, None] * (1 - G_t(z[None, :] - zs[:, None], w, cut))).sum(axis=0) / A
    np.testing.assert_allclose(ds.density.values, rho, atol=1e-10, rtol=0)
    np.testing.assert_allclose(ds.stress_zz.values, math.cos(theta) * above, atol=1e-10, rtol=0)
    np.testing.assert_allclose(ds.stress_xz.values, -math.sin(theta) * above, atol=1e-10, rtol=0)
    # numerically as well: sigma_zz(z) - sigma_zz(z + dz) = cos(theta) int rho (trapezoid)
    trap = 0.5 * (rho[1:] + rho[:-1]) * 0.0173 * math.cos(theta)
    np.testing.assert_allclose(-np.diff(ds.stress_zz.values), trap, atol=2e-4)
    assert ds.stress_zz.values[0] == pytest.approx(math.cos(theta) * masses.sum() / A, rel=1e-12)


# ---------------------------------------------------------------- kinetic stress, species
def test_kinetic_stress_and_velocity():
    w, cut = 0.25, 4.0
    pos = [[0.1, 0.1, 0.4], [1.0, 2.0, 0.4], [0.5, 0.5, 2.9]]
    vel = [[1.5, 0.0, 0.2], [-0.5, 0.0, 0.2], [3.0, -1.0, 0.5]]
    ds = profiles([snapshot(pos, vel=vel, mass=[1.0, 3.0, 2.0])], width=w, cutoff=cut)
    z = ds.z.values
    i0 = np.argmin(abs(z - 0.4))
    # at z = 0.4 only the two particles at that height contribute (equal kernel weight)
    assert ds.velocity_x.values[i0] == pytest.approx((1.5 - 1.5) / 4.0, abs=1e-12)
    gk = g_t(np.array(z[i0] - 0.4), w, cut) / 6.0
    V = 0.0
    expect_xx = gk * (1.0 * 1.5 ** 2 + 3.0 * 0.5 ** 2) - 4.0 * gk * V ** 2
    assert ds.stress_kinetic_xx.values[i0] == pytest.approx(expect_xx, rel=1e-10)
    assert ds.stress_kinetic_zz.values[i0] == pytest.approx(0.0, abs=1e-13)  # equal v_z
    # a lone particle has no velocity fluctuation about V = v
    i2 = np.argmin(abs(z - 2.9))
    assert ds.velocity_y.values[i2] == pytest.approx(-1.0, rel=1e-12)
    for c in ("xx", "yy", "zz", "xy", "xz", "yz"):
        assert abs(ds[f"stress_kinetic_{c}"].values[i2]) < 1e-12
    assert np.isnan(ds.velocity_x.values[-1])  # no material: velocity undefined


def test_species_and_small_fraction():
    w, cut = 0.25, 4.0
    pos = [[0.1, 0.1, 1.0], [1.0, 1.0, 1.0], [0.5, 2.0, 1.0]]
    d = [0.5, 0.5, 1.0]
    ds = profiles([snapshot(pos, diameter=d, mass=[0.125, 0.125, 1.0], species=[1, 1, 0])],
                  width=w, cutoff=cut, n_species=2)
    i0 = np.argmin(abs(ds.z.values - 1.0))
    vs = np.pi / 6 * np.array(d) ** 3
    assert ds.attrs["cg_small_species"] == 1
    assert ds.small_particle_fraction.values[i0] == pytest.approx(2 * vs[0] / vs.sum(), rel=1e-12)
    np.testing.assert_allclose(ds.species_density.sum("species").values, ds.density.values,
                               rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(ds.species_volume_fraction.sum("species").values,
                               ds.volume_fraction.values, rtol=1e-12, atol=1e-15)
    for name, var in ds.data_vars.items():
        assert "units" in var.attrs and "long_name" in var.attrs, name


# ---------------------------------------------------------------- width convergence
def layered_packing(n_layers=20, L=10, seed=2):
    rng = np.random.default_rng(seed)
    gx, gy = np.meshgrid(np.arange(L) + 0.5, np.arange(L) + 0.5, indexing="ij")
    pos = []
    for k in range(n_layers):
        xy = np.column_stack([gx.ravel(), gy.ravel()]) + rng.uniform(-0.2, 0.2, (L * L, 2))
        pos.append(np.column_stack([xy % L, np.full(L * L, k + 0.5)]))
    return snapshot(np.vstack(pos))


def test_width_convergence_layering():
    """Layers at z = 0.5, 1.5, ...: layered at w = 0.25, smooth at w = 1, same bulk density."""
    from granflow.coarse import interval_mean

    snap = layered_packing()
    bulk = {}
    for w in (0.25, 0.5, 1.0):
        ds = coarse_grain_profiles([snap], -5, 25, 0.01, width=w, Lx=10, Ly=10)
        z, rho = ds.z.values, ds.density.values
        inside = (z >= 7) & (z <= 13)
        swing = (rho[inside].max() - rho[inside].min()) / rho[inside].mean()
        if w == 0.25:
            assert swing > 0.5  # strong layering (Fig. 6)
        if w == 1.0:
            assert swing < 1e-3  # smooth bulk
        bulk[w] = interval_mean(z, rho, 7.0, 13.0)  # six whole layers
    for w in bulk:
        assert bulk[w] == pytest.approx(1.0, rel=1e-2)
        assert bulk[w] == pytest.approx(bulk[0.25], rel=1e-2)


# ---------------------------------------------------------------- accumulator mechanics
def dynamic_snapshots(k=6, seed=3):
    rng = np.random.default_rng(seed)
    snaps = []
    for t in range(k):
        s = random_snapshot(rng)
        s["time"] = 0.5 * t
        snaps.append(s)
    return snaps


def test_state_dict_round_trip(tmp_path):
    snaps = dynamic_snapshots()
    kw = dict(z_min=-3, z_max=8, dz=0.05, Lx=4.0, Ly=3.0, window_length=1.0)
    a = DepthProfileAccumulator(**kw)
    for s in snaps[:3]:
        a.add_snapshot(s["time"], *(s[k] for k in KEYS))
    state = a.state_dict()
    np.savez(tmp_path / "ck.npz", **state)
    with np.load(tmp_path / "ck.npz", allow_pickle=False) as fh:
        b = DepthProfileAccumulator.from_state_dict(dict(fh))
    for s in snaps[3:]:
        a.add_snapshot(s["time"], *(s[k] for k in KEYS))
        b.add_snapshot(s["time"], *(s[k] for k in KEYS))
    sa, sb = a.state_dict(), b.state_dict()
    for key in sa:
        np.testing.assert_array_equal(np.asarray(sa[key]), np.asarray(sb[key]), err_msg=key)
    da, db = a.to_dataset({"x": 1}), b.to_dataset({"x": 1})
    assert da.attrs["x"] == 1
    for name in da.data_vars:
        np.testing.assert_array_equal(da[name].values, db[name].values)
    # the dataset (with provenance attrs) is netCDF-writable and reads back unchanged
    from granflow.provenance import atomic_to_netcdf, provenance_attrs

    dc = a.to_dataset(provenance_attrs({"run": 1}, theta=24.0))
    atomic_to_netcdf(dc, tmp_path / "p.nc")
    import xarray as xr

    with xr.open_dataset(tmp_path / "p.nc") as back:
        np.testing.assert_array_equal(back.stress_zz.values, dc.stress_zz.values)
        assert back.stress_zz.attrs["units"] == "1"  # nondimensional (UDUNITS)
        assert back.stress_zz.attrs["nondimensional_unit"] == \
            "particle_mass*gravity*particle_diameter**-2"  # m g / d^2
        assert back.attrs["param_theta"] == 24.0


def test_snapshot_order_and_windows():
    snaps = dynamic_snapshots()
    for s in snaps:
        s["time"] = 10.0 + 0.1 * s["time"]  # all in one window
    kw = dict(z_min=-3, z_max=8, dz=0.05, Lx=4.0, Ly=3.0)
    d1 = coarse_grain_profiles(snaps, **kw)
    d2 = coarse_grain_profiles(snaps[::-1], **kw)
    for name in d1.data_vars:
        np.testing.assert_allclose(d1[name].values, d2[name].values, atol=1e-12, rtol=0,
                                   equal_nan=True)
    # windows: two windows of three snapshots; per-window means average to the overall mean
    for k, s in enumerate(snaps):
        s["time"] = 100.0 + k
    dw = coarse_grain_profiles(snaps, window_length=3.0, **kw)
    assert list(dw.window_n_snapshots.values) == [3, 3]
    assert dw.density_window.dims == ("time_window", "z")
    assert dw.species_density_window.dims == ("time_window", "species", "z")
    np.testing.assert_allclose(dw.stress_zz_window.mean("time_window").values,
                               dw.stress_zz.values, atol=1e-13)
    single = coarse_grain_profiles(snaps[:3], **kw)
    np.testing.assert_allclose(dw.stress_zz_window.values[0], single.stress_zz.values, atol=1e-13)
