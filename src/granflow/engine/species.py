"""Contact species: from (collision time, restitution) to stiffness and damping per reduced mass.

Weinhart et al. (2012) Eq. (5)-(6) relate the linear spring-dashpot parameters to the collision
time t_c and the normal restitution e of a pair with reduced mass m_ij = m_i m_j / (m_i + m_j):

    t_c = pi / sqrt(k_n/m_ij - (gamma_n / (2 m_ij))^2),     e = exp(-t_c gamma_n / (2 m_ij)).

Inverting them,

    k_n = m_ij (pi^2 + ln^2 e) / t_c^2,     gamma_n = -2 m_ij ln(e) / t_c.

As physics.md §1 explains, the paper's quoted k_n = 2e5, gamma_n = 50 reproduce t_c = 0.005,
e = 0.88 only if damping is per unit reduced mass; granflow therefore specifies every interaction by
(t_c, e, k_t/k_n, gamma_t/gamma_n, mu_c) and stores ``k_hat = k / m_ij`` and ``g_hat = gamma / m_ij``,
so every pair (equal or unequal masses, flow-flow or flow-base with m_ij = m_flow) has exactly
the stated t_c and e.

Walton-Braun plastic law (Thornton et al., T-eq. 5): loading stiffness k1, unloading/reloading
k2, e = sqrt(k1/k2).  A central collision lasts a quarter period on the k1 branch plus a quarter
period on the k2 branch, t_c = (pi/2)(1/w1 + 1/w2) with w = sqrt(k/m_ij), so

    k1 / m_ij = (pi (1 + e) / (2 t_c))^2,      k2 = k1 / e^2.

The plastic law has no normal dashpot; its tangential dashpot uses gamma_t/gamma_n times the
linear-law gamma_n of the same (t_c, e).

Hertzian law (T-eq. 4): both spring-dashpot forces are multiplied by sqrt(delta_n / d_ij) with
d_ij = r_i + r_j.  Its collision time depends on the impact velocity (t_c ~ v^-1/5), so the
species states (t_c, e) at a reference impact velocity ``v_ref``; the per-mass stiffness and
damping are found by integrating the central collision and solving for both (see
:func:`hertz_coefficients`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from .lib.kernels import LAW_HERTZ, LAW_LINEAR, LAW_PLASTIC

LAWS = {"linear": LAW_LINEAR, "hertz": LAW_HERTZ, "plastic": LAW_PLASTIC}

#: The paper's reference interaction (physics.md §1).
REFERENCE = dict(t_c=0.005, e=0.88, kt_over_kn=2.0 / 7.0, gt_over_gn=1.0, mu_c=0.5)


@dataclass(frozen=True)
class ContactSpecies:
    """Interaction parameters of one pair of particle types.

    Attributes
    ----------
    t_c : collision time of a central collision (at ``v_ref`` for the Hertzian law)
    e : normal coefficient of restitution, in (0, 1]
    kt_over_kn : tangential / normal stiffness ratio (paper: 2/7)
    gt_over_gn : tangential / normal damping ratio (paper: 1)
    mu_c : microscopic (Coulomb) contact friction; ``math.inf`` for no sliding
    law : "linear", "hertz" or "plastic"
    v_ref : reference impact velocity for the Hertzian calibration
    """

    t_c: float = REFERENCE["t_c"]
    e: float = REFERENCE["e"]
    kt_over_kn: float = REFERENCE["kt_over_kn"]
    gt_over_gn: float = REFERENCE["gt_over_gn"]
    mu_c: float = REFERENCE["mu_c"]
    law: str = "linear"
    v_ref: float = 1.0

    def __post_init__(self):
        check_range("t_c", self.t_c, 0.0, math.inf, lo_open=True)
        check_range("e", self.e, 0.0, 1.0, lo_open=True)
        check_range("kt_over_kn", self.kt_over_kn, 0.0, math.inf)
        check_range("gt_over_gn", self.gt_over_gn, 0.0, math.inf)
        if not (self.mu_c >= 0.0):
            raise ValueError(f"mu_c = {self.mu_c!r} is out of range: allowed [0, inf]")
        if self.law not in LAWS:
            raise ValueError(f"law = {self.law!r} is unknown: allowed {sorted(LAWS)}")
        check_range("v_ref", self.v_ref, 0.0, math.inf, lo_open=True)
        if self.law == "plastic" and self.e >= 1.0:
            raise ValueError("e = 1 is not allowed for the plastic law: allowed (0, 1)")

    def coefficients(self, d_ij: float = 1.0) -> dict:
        """Per-unit-reduced-mass coefficients k_hat, g_hat, kt_hat, gt_hat, k2_hat, mu."""
        ln_e = math.log(self.e)
        gn_lin = -2.0 * ln_e / self.t_c
        if self.law == "linear":
            kn = (math.pi**2 + ln_e**2) / self.t_c**2
            gn = gn_lin
            k2 = 0.0
        elif self.law == "plastic":
            kn = (math.pi * (1.0 + self.e) / (2.0 * self.t_c)) ** 2
            k2 = kn / self.e**2
            gn = 0.0
        else:
            kn, gn = hertz_coefficients(self.t_c, self.e, self.v_ref, d_ij)
            k2 = 0.0
        gt_base = gn if self.law != "plastic" else gn_lin
        return dict(
            kn_hat=kn, gn_hat=gn, kt_hat=self.kt_over_kn * kn, gt_hat=self.gt_over_gn * gt_base,
            k2_hat=k2, mu=self.mu_c,
        )

    def as_dict(self) -> dict:
        return asdict(self)


def check_range(name, value, lo, hi, lo_open=False, hi_open=False):
    """Raise ValueError naming ``name`` unless ``value`` lies in the stated interval."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {value!r} is not a number") from None
    bad = (
        not math.isfinite(v) and not (hi == math.inf and v == math.inf and not hi_open)
    ) or v < lo or v > hi or (lo_open and v == lo) or (hi_open and v == hi)
    if math.isnan(v) or bad:
        left = "(" if lo_open else "["
        right = ")" if hi_open or hi == math.inf else "]"
        raise ValueError(f"{name} = {value!r} is out of range: allowed {left}{lo}, {hi}{right}")
    return v


#: conventions for the flow-base pair of a code that holds one set of *absolute* coefficients
#: (see :func:`flow_base_species`)
FLOW_BASE_CONVENTIONS = ("per_pair", "absolute", "absolute_k_reduced_damping")


def flow_base_species(flow: "ContactSpecies", convention: str = "per_pair",
                      m_flow: float = 1.0) -> "ContactSpecies":
    """The flow-base species that a code with another parameter convention gives a fixed base.

    The base has infinite mass, so a flow-base contact has the reduced mass of one flow particle,
    m_fb = m_flow, twice the flow-flow pair's m_ff = m_flow / 2.  Which (t_c, e) it then has
    depends on how a code stores the flow-flow species:

    * ``per_pair`` (granflow, physics.md §1): every pair has the stated t_c and e;
    * ``absolute`` (absolute k_n and gamma_n of the flow-flow pair for every pair, e.g.
      MercuryDPM's species set by collision time and restitution for the flow particle's mass):
      k_n = m_ff k_hat, gamma_n = m_ff g_hat, so the flow-base contact is softer (t_c sqrt 2
      longer) and less damped;
    * ``absolute_k_reduced_damping`` (absolute k_n, damping per unit effective mass: Silbert et
      al. 2001, LAMMPS ``gran/hooke/history``): k_n as above, g_hat unchanged.

    Tangential stiffness and damping keep their ratios to the normal ones.  Linear law only.
    """
    if convention not in FLOW_BASE_CONVENTIONS:
        raise ValueError(f"convention = {convention!r}: allowed values are {FLOW_BASE_CONVENTIONS}")
    if flow.law != "linear":
        raise ValueError(f"law = {flow.law!r}: flow_base_species is defined for the linear law only")
    check_range("m_flow", m_flow, 0.0, math.inf, lo_open=True, hi_open=True)
    if convention == "per_pair":
        return flow
    c = flow.coefficients()
    m_ff, m_fb = 0.5 * m_flow, m_flow
    k_hat = m_ff * c["kn_hat"] / m_fb
    g_hat = (m_ff * c["gn_hat"] / m_fb) if convention == "absolute" else c["gn_hat"]
    t_c = math.pi / math.sqrt(k_hat - 0.25 * g_hat * g_hat)
    return ContactSpecies(t_c=t_c, e=math.exp(-0.5 * g_hat * t_c), kt_over_kn=flow.kt_over_kn,
                          gt_over_gn=flow.gt_over_gn, mu_c=flow.mu_c, law=flow.law)


def hertz_collision(k_hat: float, g_hat: float, v: float, d_ij: float):
    """Collision time and restitution of a central Hertzian collision (per unit reduced mass).

    Integrates delta'' = -sqrt(delta/d)(k_hat delta + g_hat delta') from delta = 0, delta' = v
    until the overlap returns to zero (as in the force kernel, the normal force is not clipped,
    so the contact lasts while the particles overlap).
    """
    from scipy.integrate import solve_ivp

    def rhs(t, y):
        d = max(y[0], 0.0)
        return [y[1], -math.sqrt(d / d_ij) * (k_hat * d + g_hat * y[1])]

    def force_zero(t, y):
        return y[0] if t > 0 else 1.0

    force_zero.terminal = True
    force_zero.direction = -1
    # undamped Hertz time scale sets the integration horizon
    dm = (5.0 * v * v / (4.0 * k_hat / math.sqrt(d_ij))) ** 0.4
    horizon = 20.0 * dm / v
    sol = solve_ivp(rhs, (0.0, horizon), [0.0, v], events=force_zero, rtol=1e-10, atol=1e-14,
                    max_step=horizon / 2000)
    if not sol.t_events[0].size:
        raise RuntimeError("Hertz calibration: collision did not end")
    t_end = float(sol.t_events[0][0])
    v_end = float(sol.y_events[0][0][1])
    return t_end, -v_end / v


def hertz_coefficients(t_c: float, e: float, v_ref: float, d_ij: float):
    """(k_hat, g_hat) of the Hertzian law giving collision time t_c and restitution e at v_ref.

    The collision time of the undamped law is t = 2.9432 delta_max / v with
    delta_max = (5 v^2 sqrt(d) / (4 k))^(2/5); that fixes the stiffness scale, and a 2-D root
    search (scipy.optimize.fsolve on log-parameters) matches both t_c and e.
    """
    from scipy.optimize import fsolve

    # undamped estimate: t_c = 2.9432 * dm / v  ->  dm = t_c v / 2.9432
    dm = t_c * v_ref / 2.94320
    k0 = 5.0 * v_ref**2 * math.sqrt(d_ij) / (4.0 * dm**2.5)
    g0 = -2.0 * math.log(e) / t_c * math.sqrt(d_ij / dm)

    def residual(x):
        tc, ee = hertz_collision(math.exp(x[0]), math.exp(x[1]), v_ref, d_ij)
        return [math.log(tc / t_c), math.log(ee / e)]

    if e >= 1.0:
        return k0, 0.0
    x, info, ier, msg = fsolve(residual, [math.log(k0), math.log(max(g0, 1e-12))],
                               full_output=True, xtol=1e-12)
    if ier != 1:
        raise RuntimeError(f"Hertz calibration failed for t_c={t_c}, e={e}: {msg}")
    return math.exp(x[0]), math.exp(x[1])


@dataclass
class InteractionTable:
    """Pair-parameter tables indexed by particle type (flow species first, then the base type)."""

    type_names: list
    type_diameters: list
    pairs: dict = field(default_factory=dict)  # (name_a, name_b) -> ContactSpecies

    def set(self, a: str, b: str, species: ContactSpecies):
        self.pairs[(a, b)] = species
        self.pairs[(b, a)] = species

    def get(self, a: str, b: str) -> ContactSpecies:
        try:
            return self.pairs[(a, b)]
        except KeyError:
            raise ValueError(f"no contact species given for the type pair ({a!r}, {b!r})") from None

    def arrays(self):
        """numpy tables (law, kn, gn, kt, gt, mu, k2), each of shape (T, T)."""
        t = len(self.type_names)
        law = np.zeros((t, t), dtype=np.int64)
        tabs = {k: np.zeros((t, t)) for k in ("kn_hat", "gn_hat", "kt_hat", "gt_hat", "mu", "k2_hat")}
        for a, na in enumerate(self.type_names):
            for b, nb in enumerate(self.type_names):
                sp = self.get(na, nb)
                d_ij = 0.5 * (self.type_diameters[a] + self.type_diameters[b])
                if self.type_diameters[a] == 0 or self.type_diameters[b] == 0:  # flat wall
                    d_ij = 0.5 * max(self.type_diameters[a], self.type_diameters[b])
                c = sp.coefficients(d_ij)
                law[a, b] = LAWS[sp.law]
                for k in tabs:
                    tabs[k][a, b] = c[k]
        return (law, tabs["kn_hat"], tabs["gn_hat"], tabs["kt_hat"], tabs["gt_hat"], tabs["mu"],
                tabs["k2_hat"])

    def min_collision_time(self) -> float:
        return min(sp.t_c for sp in self.pairs.values())

    def to_json_dict(self) -> dict:
        return {
            "type_names": list(self.type_names),
            "type_diameters": [float(d) for d in self.type_diameters],
            "pairs": [[a, b, sp.as_dict()] for (a, b), sp in sorted(self.pairs.items()) if a <= b],
        }

    @classmethod
    def from_json_dict(cls, data: dict) -> "InteractionTable":
        tab = cls(list(data["type_names"]), list(data["type_diameters"]))
        for a, b, sp in data["pairs"]:
            tab.set(a, b, ContactSpecies(**sp))
        return tab
