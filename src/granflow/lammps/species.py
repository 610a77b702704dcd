"""granflow contact species -> LAMMPS ``pair_style granular`` coefficients, per type pair.

granflow specifies every interaction by (t_c, e, k_t/k_n, gamma_t/gamma_n, mu_c) and stores
stiffness and damping per unit reduced mass, k_hat = k / m_ij, g_hat = gamma / m_ij
(Weinhart et al. 2012 Eq. 5-6; physics.md §1), so that every pair has exactly the stated t_c
and e.  LAMMPS ``pair_style granular`` takes ``pair_coeff`` per type pair, so the same contact
law is written exactly, pair by pair (m_ij is constant per type pair: one diameter and density
per type; a frozen base particle has infinite mass, and with ``fix freeze`` LAMMPS takes the
mobile partner's mass as the effective mass, as granflow does):

linear law (``hooke``, ``damping mass_velocity``, ``tangential linear_history``)::

    F_n = k_n delta - eta_n m_eff v_n          k_n   = m_ij k_hat            eta_n = g_hat
    F_t = -k_t xi - x_gt eta_n m_eff v_t       k_t   = m_ij kt_hat           x_gt  = gt_hat / g_hat
    |F_t| <= mu |F_n| (spring truncated)       mu    = mu_c

Hertzian law (granflow multiplies both spring-dashpot forces by sqrt(delta / d_ij), d_ij =
r_i + r_j; LAMMPS ``hertz`` / ``mindlin`` / ``damping viscoelastic`` multiply by the contact
radius a = sqrt(R delta), R = r_i r_j / (r_i + r_j), so every coefficient is divided by
sqrt(d_ij R))::

    k_n = m_ij k_hat / sqrt(d_ij R),   eta_n = g_hat / sqrt(d_ij R),   k_t = m_ij kt_hat / sqrt(d_ij R)

The plastic (Walton-Braun) law has no LAMMPS ``pair_style granular`` counterpart: refused.
A flat wall (lambda = 0) is not written either (granflow's wall is a contact partner of zero
radius; refused with a clear message).

The same tables give the elastic energy of a contact from its overlap and tangential force
(:func:`elastic_energy`): a LAMMPS dump does not carry the tangential spring, so its energy is
taken as |F_t|^2 / (2 k_t), exact for a contact at rest and an estimate otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..engine.species import InteractionTable
from ..units import RHO_PARTICLE

#: Contact laws the LAMMPS engine writes.
SUPPORTED_LAWS = ("linear", "hertz")


@dataclass
class PairTables:
    """Absolute per-type-pair coefficients (T x T arrays, type index = granflow ptype)."""

    law: list            # contact law name per type (row-major nested list)
    kn: np.ndarray       # normal stiffness (force / length; Hertz: force / length^(3/2) / a)
    eta: np.ndarray      # normal damping per unit effective mass (1 / time; Hertz: / a)
    kt: np.ndarray       # tangential stiffness
    x_gt: np.ndarray     # tangential / normal damping
    mu: np.ndarray       # Coulomb friction
    d_ij: np.ndarray     # r_i + r_j of the type pair
    R: np.ndarray        # r_i r_j / (r_i + r_j)
    hertz: np.ndarray    # bool: Hertzian pair


def check_supported(law: str, lam: float):
    """Refuse, before any compute, what the LAMMPS engine cannot write."""
    if law not in SUPPORTED_LAWS:
        raise ValueError(f"contact_law = {law!r} is not available with engine = 'lammps': allowed "
                         f"{list(SUPPORTED_LAWS)} (LAMMPS pair_style granular has no Walton-Braun "
                         "plastic law)")
    if not lam > 0:
        raise ValueError(f"lam = {lam!r} (flat wall) is not available with engine = 'lammps': "
                         "allowed (0, 10] (a rough base of frozen particles)")


def pair_tables(interactions: InteractionTable, density: float = RHO_PARTICLE) -> PairTables:
    """Absolute LAMMPS coefficients of every type pair of a granflow interaction table."""
    names = interactions.type_names
    diam = [float(d) for d in interactions.type_diameters]
    if any(d <= 0 for d in diam):
        raise ValueError("a type of zero diameter (flat wall) cannot be written for LAMMPS: "
                         "allowed lam > 0")
    t = len(names)
    mass = [density * math.pi / 6.0 * d**3 for d in diam]
    base = t - 1  # the base type is last (granflow.engine.chute.ChuteConfig.interactions)
    z = lambda: np.zeros((t, t))  # noqa: E731
    tabs = dict(kn=z(), eta=z(), kt=z(), x_gt=z(), mu=z(), d_ij=z(), R=z())
    hertz = np.zeros((t, t), bool)
    laws = [[None] * t for _ in range(t)]
    for a in range(t):
        for b in range(t):
            sp = interactions.get(names[a], names[b])
            check_supported(sp.law, 1.0)
            ra, rb = 0.5 * diam[a], 0.5 * diam[b]
            d_ij = ra + rb
            c = sp.coefficients(0.5 * (diam[a] + diam[b]))
            # reduced mass: a frozen base particle has infinite mass (the flow partner's mass)
            if a == base and b == base:
                m_ij = 0.5 * mass[a]  # never in contact (base-base excluded); any finite value
            elif a == base:
                m_ij = mass[b]
            elif b == base:
                m_ij = mass[a]
            else:
                m_ij = mass[a] * mass[b] / (mass[a] + mass[b])
            R = ra * rb / d_ij
            scale = 1.0 / math.sqrt(d_ij * R) if sp.law == "hertz" else 1.0
            tabs["kn"][a, b] = m_ij * c["kn_hat"] * scale
            tabs["eta"][a, b] = c["gn_hat"] * scale
            tabs["kt"][a, b] = m_ij * c["kt_hat"] * scale
            tabs["x_gt"][a, b] = c["gt_hat"] / c["gn_hat"] if c["gn_hat"] > 0 else 0.0
            tabs["mu"][a, b] = c["mu"]
            tabs["d_ij"][a, b] = d_ij
            tabs["R"][a, b] = R
            hertz[a, b] = sp.law == "hertz"
            laws[a][b] = sp.law
    return PairTables(law=laws, hertz=hertz, **tabs)


def _g(x) -> str:
    return f"{float(x):.17g}"


def pair_coeff_lines(tables: PairTables) -> list[str]:
    """``pair_coeff`` commands (LAMMPS types are granflow ptype + 1)."""
    t = tables.kn.shape[0]
    lines = []
    for a in range(t):
        for b in range(a, t):
            if tables.hertz[a, b]:
                normal = f"hertz {_g(tables.kn[a, b])} {_g(tables.eta[a, b])} damping viscoelastic"
                tang = (f"tangential mindlin {_g(tables.kt[a, b])} {_g(tables.x_gt[a, b])} "
                        f"{_g(tables.mu[a, b])}")
            else:
                normal = f"hooke {_g(tables.kn[a, b])} {_g(tables.eta[a, b])} damping mass_velocity"
                tang = (f"tangential linear_history {_g(tables.kt[a, b])} "
                        f"{_g(tables.x_gt[a, b])} {_g(tables.mu[a, b])}")
            lines.append(f"pair_coeff {a + 1} {b + 1} {normal} {tang}")
    return lines


def elastic_energy(ti, tj, delta, f_t, tables: PairTables, m_eff=None, v_t=None) -> float:
    """Elastic energy of the contacts (type indices ti, tj, overlaps delta, tangential forces
    f_t (m, 3)): normal 0.5 k_n delta^2 (Hertz: 0.4 k_n sqrt(delta / d_ij) delta^2, as the numba
    engine) plus the tangential spring's |k_t xi|^2 / (2 k_t).  LAMMPS's tangential force is
    f_t = -k_t xi - x_gt eta m_eff v_t (also after Coulomb truncation, which rescales xi), so
    with the effective masses ``m_eff`` and relative tangential contact velocities ``v_t``
    (m, 3) the spring force is f_t + x_gt eta m_eff v_t; without them |f_t| stands for it."""
    if len(delta) == 0:
        return 0.0
    if m_eff is not None and v_t is not None:
        damp = tables.x_gt[ti, tj] * tables.eta[ti, tj] * m_eff
        damp = np.where(tables.hertz[ti, tj], damp * np.sqrt(tables.R[ti, tj] * delta), damp)
        f_t = f_t + damp[:, None] * v_t
    kn = tables.kn[ti, tj]
    kt = tables.kt[ti, tj]
    hz = tables.hertz[ti, tj]
    # Hertz: LAMMPS k_n * a with a = sqrt(R delta) equals granflow's k sqrt(delta / d_ij)
    kn_eff = np.where(hz, kn * np.sqrt(tables.R[ti, tj] * delta), kn)
    kt_eff = np.where(hz, kt * np.sqrt(tables.R[ti, tj] * delta), kt)
    e_n = np.where(hz, 0.4, 0.5) * kn_eff * delta * delta
    ft2 = np.einsum("ij,ij->i", f_t, f_t)
    e_t = np.divide(0.5 * ft2, kt_eff, out=np.zeros_like(ft2), where=kt_eff > 0)
    return float(e_n.sum() + e_t.sum())
