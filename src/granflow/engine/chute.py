"""Chute set-up: rough-base preparation, flow insertion and the periodic inclined chute.

Implements the protocol of Weinhart et al. (2012) §5 (physics.md §3):

* **rough base** — fill a horizontal periodic box with particles of diameter lambda, let them
  settle to a static layer ``base_layers`` (paper: 12) diameters thick, keep the particles with
  z in [base_layers - 2.7, base_layers - 1] lambda (paper: [9.3, 11] lambda), delete the rest,
  shift down by (base_layers - 1) lambda and freeze them.  lambda = 0 is a flat frictional wall
  at z = 0.  Settling uses a soft, strongly damped preparation species (the frozen positions
  are all that is kept; the flow never feels that species): by default with friction 0.5
  (bulk solid fraction ~0.61); ``prep_mu_c = 0`` as MercuryDPM's ChuteBottom (~0.65, with
  ``fill_packing`` ~0.65 so that the pile still settles ~12 layers thick).  ``band="top"``
  keeps MercuryDPM's slice instead (the 1.2 lambda below the highest centre minus lambda/2).
* **flow insertion** — random positions in [0, Lx] x [0, Ly] x [0, I], I = H initially;
  overlapping trials are rejected and I grows by ``insertion_growth`` after each rejection.
  The paper's text says 0.01 and "initial packing about 0.3", which disagree: 0.01 gives a
  column at solid fraction ~0.12 in the 20 x 10 box (~0.18 in 10 x 5), while MercuryDPM's
  SilbertPeriodic driver grows I by 1e-4 particle radii (5e-5 d), which gives ~0.31 (0.35 in
  10 x 5).  Default 0.01 (every run made so far); the looser column falls from about twice the
  height.  The number of flow particles is N = H Lx Ly (monodisperse d = 1: "filling height" H
  is the flow volume / (Lx Ly pi/6)), for mixtures N_s, N_l follow from phi0.  A mixture
  starts ``initial_mixing = "mixed"`` (default: both species inserted in one random order) or
  ``"segregated"`` (all small particles inserted first in [0, phi0 I], the large ones above the
  highest small one: the fully segregated limit, from which the steady segregated state is
  approached from above while a mixed start approaches it from below -- the two bracket the
  steady Ps of T-eq. 28 when a run ends before its segregation is steady) or ``"profile"``
  (stratified like T-eq. 28's steady profile at Peclet number ``initial_Ps``: each particle
  gets a target scaled height, the quantiles of its species' share phi(zeta) (small) or
  1 - phi(zeta) (large) of that profile, and the particles are inserted in about one-diameter
  slabs of target height, bottom up, each slab above the highest particle of the one below it;
  ``"segregated"`` is the limit initial_Ps -> infinity in two slabs.  A start nearer the
  steady profile than the fully segregated one relaxes to it sooner, from the side its
  initial_Ps lies on: measured with T-eq. 27 itself at Ps 5, D 0.039, depth 22 (2026-12-07),
  the fitted Ps of a start at 7 is 5.79 at t = 600 where the fully segregated start's is
  7.51, and a start at 3.5 is 4.22 where the mixed start's is 1.97).
* **gravity** tilted by theta: g = (sin theta, 0, -cos theta).

Everything random is drawn from ``numpy.random.default_rng(seed)``: the same configuration and
seed give the same particles, bit for bit.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field

import numpy as np

from ..units import RHO_PARTICLE
from .lib.kernels import insert_random
from .species import ContactSpecies, InteractionTable, check_range
from .system import ParticleSystem

log = logging.getLogger(__name__)

#: Packing fraction assumed when sizing the base-preparation fill.
BASE_FILL_PACKING = 0.6
#: Height added to the flow's insertion domain per rejected trial (the paper's text; see the
#: module docstring for MercuryDPM's 5e-5, which gives the paper's stated initial packing).
DEFAULT_INSERTION_GROWTH = 0.01
#: Overlap guard of the base-preparation settling, as a fraction of lambda.  The engine's 5 %
#: (:data:`granflow.engine.system.MAX_OVERLAP_FRACTION`) guards the runs' physics; the preparation
#: is a soft, strongly damped settling whose only output is where its particles come to rest, and
#: the paper's own box at lambda = 1/2 (20 x 10, seed 1, 11 001 particles) reached 5.02 % of
#: lambda during its fall (2026-11-26) and was refused.  The bases prepared under 5 % are the same
#: (the guard only stops a run, it does not change one).
PREP_MAX_OVERLAP = 0.15


#: Which slice of the settled pile becomes the rough base: "paper" (004 §5: z in
#: [base_layers - 2.7, base_layers - 1] lambda of the nominal pile) or "top" (MercuryDPM's
#: ``ChuteBottom::makeRoughBottom``: the 1.2 lambda below z_max - lambda/2, z_max the highest
#: particle centre -- measured from the pile's actual surface, thinner).
BASE_BANDS = ("paper", "top")


@dataclass
class BaseConfig:
    """Rough-base preparation parameters (physics.md §3)."""

    lam: float = 1.0                 # base particle diameter / flow particle diameter (0 = flat wall)
    Lx: float = 20.0
    Ly: float = 10.0
    base_layers: float = 12.0        # settled layer thickness in base diameters (paper: 12)
    seed: int = 1
    settle_time: float = 30.0        # maximum settling time (units sqrt(lambda/g) x sqrt(lambda))
    prep_t_c: float = 0.02           # soft preparation species: collision time (x sqrt(lambda))
    prep_e: float = 0.2              # and restitution (strongly damped: settles quickly)
    prep_mu_c: float = 0.5           # and sliding friction (MercuryDPM's ChuteBottom: 0)
    fill_packing: float = BASE_FILL_PACKING  # solid fraction the pile is sized for
    band: str = "paper"              # which slice of the pile is kept (BASE_BANDS)

    def validate(self):
        check_range("lam", self.lam, 0.0, 10.0)
        check_range("Lx", self.Lx, 0.0, 1e4, lo_open=True)
        check_range("Ly", self.Ly, 0.0, 1e4, lo_open=True)
        check_range("base_layers", self.base_layers, 3.0, 100.0)
        check_range("settle_time", self.settle_time, 0.0, 1e5, lo_open=True)
        check_range("prep_t_c", self.prep_t_c, 0.0, 1.0, lo_open=True)
        check_range("prep_e", self.prep_e, 0.0, 1.0, lo_open=True)
        check_range("prep_mu_c", self.prep_mu_c, 0.0, 10.0)
        check_range("fill_packing", self.fill_packing, 0.3, 0.74)
        if self.band not in BASE_BANDS:
            raise ValueError(f"band = {self.band!r} is unknown: allowed {sorted(BASE_BANDS)}")
        if self.lam > 0 and (self.Lx < 3 * self.lam or self.Ly < 3 * self.lam):
            raise ValueError(f"Lx, Ly = {self.Lx}, {self.Ly} must be at least 3 lambda = {3 * self.lam}")
        return self


def prepare_rough_base(cfg: BaseConfig) -> np.ndarray:
    """Positions (M, 3) of the frozen rough-base particles, top of the kept band at z = 0.

    Returns an empty array for lambda = 0 (flat wall).
    """
    cfg.validate()
    lam = cfg.lam
    if lam == 0:
        return np.zeros((0, 3))
    rng = np.random.default_rng(cfg.seed)
    area = cfg.Lx * cfg.Ly
    n = int(math.ceil(cfg.base_layers * lam * area * cfg.fill_packing / (math.pi / 6 * lam**3)))
    radius = np.full(n, 0.5 * lam)
    pos = _insert(rng, np.zeros((0, 3)), np.zeros(0), radius, cfg.Lx, cfg.Ly,
                  z_lo=0.5 * lam, height0=2.0 * cfg.base_layers * lam)
    tc = cfg.prep_t_c * math.sqrt(lam)
    tab = InteractionTable(["base", "wall"], [lam, 0.0])
    prep = ContactSpecies(t_c=tc, e=cfg.prep_e, mu_c=cfg.prep_mu_c)
    for a in ("base", "wall"):
        for b in ("base", "wall"):
            tab.set(a, b, prep)
    sys_ = ParticleSystem(cfg.Lx, cfg.Ly, tab, gvec=(0.0, 0.0, -1.0), use_wall=True, wall_type=1,
                          skin=0.2 * lam)
    sys_.max_overlap_fraction = PREP_MAX_OVERLAP
    sys_.set_particles(pos, np.full(n, lam), density=RHO_PARTICLE, ptype=0, fixed=False)
    sys_.initialize()
    chunk = max(1, int(round(0.5 * math.sqrt(lam) / sys_.dt)))
    t_end = cfg.settle_time * math.sqrt(lam)
    e_ref = n * lam**3  # energy scale m g d of the layer
    while sys_.time < t_end:
        sys_.step(chunk)
        if sys_.time > 3.0 * math.sqrt(lam) and sys_.energies()["kinetic"] < 1e-5 * e_ref:
            break
    log.info("base preparation: lambda=%g, %d particles settled for t=%.2f (E_kin=%.3g)",
             lam, n, sys_.time, sys_.energies()["kinetic"])
    z = sys_.pos[:, 2]
    if cfg.band == "top":  # MercuryDPM: (z_max - 3.4 r, z_max - r), r = lambda / 2
        top = float(z.max()) - 0.5 * lam
        keep = (z > top - 1.2 * lam) & (z < top)
    else:
        top = (cfg.base_layers - 1.0) * lam
        keep = (z >= (cfg.base_layers - 2.7) * lam) & (z <= top)
    base = sys_.pos[keep].copy()
    base[:, 2] -= top
    order = np.lexsort((base[:, 0], base[:, 1], base[:, 2]))
    return base[order]


def _insert(rng, existing_pos, existing_radius, radius, Lx, Ly, z_lo, height0,
            grow=DEFAULT_INSERTION_GROWTH):
    """Seeded random sequential insertion (draws more random numbers until it fits)."""
    nbatch = max(3 * 64 * len(radius), 3000)
    uniforms = rng.random(nbatch)
    while True:
        pos, used, _ = insert_random(existing_pos, existing_radius, radius, Lx, Ly, z_lo,
                                     height0, grow, uniforms)
        if used >= 0:
            return pos
        uniforms = np.concatenate([uniforms, rng.random(len(uniforms))])


def profile_target_heights(species, Ps: float, phi0: float) -> np.ndarray:
    """Target scaled heights zeta in (0, 1) of a "profile" start: species 0 (small) at the
    mid-quantiles of the distribution whose density is T-eq. 28's phi(zeta) at ``Ps``, the
    others at those of 1 - phi(zeta) (each species' share of the volume at that height; the
    particles of one species have one volume, so counts follow volumes)."""
    from ..fitting.segregation import phi_teq28

    species = np.asarray(species)
    grid = np.linspace(0.0, 1.0, 4001)
    phi = phi_teq28(grid, Ps, phi0)
    out = np.empty(species.size)
    for small, dens in ((True, phi), (False, 1.0 - phi)):
        idx = np.nonzero((species == 0) == small)[0]
        if not idx.size:
            continue
        cdf = np.concatenate(([0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(grid))))
        cdf /= cdf[-1]
        out[idx] = np.interp((np.arange(idx.size) + 0.5) / idx.size, cdf, grid)
    return out


def _insert_profile(rng, base_positions, base_r, d_flow, species, cfg, z_lo):
    """Positions of a "profile" start (:class:`ChuteConfig`): the particles grouped by target
    height (:func:`profile_target_heights`) into ~``PROFILE_SLABS_PER_H`` H slabs, each
    inserted in random order above the highest top of the slabs below, its insertion domain
    its share of the flow volume times H (growing by ``insertion_growth`` per rejection)."""
    zeta = profile_target_heights(species, cfg.initial_Ps, cfg.phi0)
    nslab = max(2, int(round(PROFILE_SLABS_PER_H * cfg.H)))
    slab = np.minimum((zeta * nslab).astype(np.int64), nslab - 1)
    vol = d_flow ** 3
    pos = np.empty((d_flow.size, 3))
    placed_pos, placed_r = base_positions, base_r
    top = z_lo
    for k in range(nslab):
        idx = np.nonzero(slab == k)[0]
        if not idx.size:
            continue
        idx = idx[rng.permutation(idx.size)]
        r = 0.5 * d_flow[idx]
        lo = top if k == 0 else top + float(r.max())
        p = _insert(rng, placed_pos, placed_r, r, cfg.Lx, cfg.Ly, z_lo=lo,
                    height0=cfg.H * float(vol[idx].sum() / vol.sum()), grow=cfg.insertion_growth)
        pos[idx] = p
        placed_pos = np.concatenate([placed_pos, p])
        placed_r = np.concatenate([placed_r, r])
        top = float((p[:, 2] + r).max())
    return pos


#: How a mixture's species start (:class:`ChuteConfig.initial_mixing`).
INITIAL_MIXINGS = ("mixed", "segregated", "profile")
#: target-height slabs of a "profile" start per unit of filling height (about one per diameter)
PROFILE_SLABS_PER_H = 1.0


@dataclass
class ChuteConfig:
    """One periodic chute run (physics.md §1, §3); defaults are the paper's reference values."""

    theta: float = 24.0              # inclination, degrees
    H: float = 10.0                  # filling height (flow volume / (Lx Ly pi/6))
    lam: float = 1.0                 # base roughness: base / flow particle diameter
    Lx: float = 20.0                 # box length downslope
    Ly: float = 10.0                 # box width
    seed: int = 1
    flow: ContactSpecies = field(default_factory=ContactSpecies)       # flow-flow interaction
    base: ContactSpecies | None = None                                 # flow-base (default = flow)
    steps_per_collision: float = 50.0
    skin: float = 0.2
    # bidisperse mixtures (segregation runs): sigma = d_small / d_large; phi0 = small volume fraction
    sigma: float = 1.0
    phi0: float = 1.0
    d_small: float = 1.0
    # flow insertion: height added to the insertion domain per rejected trial (module docstring)
    insertion_growth: float = DEFAULT_INSERTION_GROWTH
    # mixtures: "mixed" (one random insertion order), "segregated" (small below, large above)
    # or "profile" (stratified as T-eq. 28's steady profile at Peclet number initial_Ps)
    initial_mixing: str = "mixed"
    initial_Ps: float = 0.0

    def validate(self):
        check_range("theta", self.theta, 0.0, 90.0, lo_open=True, hi_open=True)
        check_range("H", self.H, 0.0, 1e4, lo_open=True)
        check_range("lam", self.lam, 0.0, 10.0)
        check_range("Lx", self.Lx, 0.0, 1e4, lo_open=True)
        check_range("Ly", self.Ly, 0.0, 1e4, lo_open=True)
        check_range("sigma", self.sigma, 0.0, 1.0, lo_open=True)
        check_range("phi0", self.phi0, 0.0, 1.0)
        check_range("steps_per_collision", self.steps_per_collision, 10.0, 1e6)
        check_range("skin", self.skin, 0.0, 10.0, lo_open=True)
        check_range("d_small", self.d_small, 0.0, 100.0, lo_open=True)
        check_range("insertion_growth", self.insertion_growth, 0.0, 10.0, lo_open=True)
        if self.initial_mixing not in INITIAL_MIXINGS:
            raise ValueError(f"initial_mixing = {self.initial_mixing!r} is unknown: allowed "
                             f"{list(INITIAL_MIXINGS)}")
        if self.initial_mixing in ("segregated", "profile") and not self.bidisperse:
            raise ValueError(f"initial_mixing = {self.initial_mixing!r} needs a mixture: phi0 = "
                             f"{self.phi0:g}, allowed phi0 < 1")
        if self.initial_mixing == "profile":
            check_range("initial_Ps", self.initial_Ps, 0.0, 1e3, lo_open=True)
            check_range("phi0", self.phi0, 0.0, 1.0, lo_open=True, hi_open=True)
        elif self.initial_Ps != 0.0:
            raise ValueError(f"initial_Ps = {self.initial_Ps!r} is set but initial_mixing = "
                             f"{self.initial_mixing!r}: allowed only with initial_mixing = "
                             "'profile'")
        return self

    @property
    def gravity(self):
        t = math.radians(self.theta)
        return (math.sin(t), 0.0, -math.cos(t))

    @property
    def bidisperse(self) -> bool:
        """Two flow species "small" and "large" (phi0 < 1).  sigma = 1 with phi0 < 1 gives two
        *identical* species, tagged only: the no-segregation control of a size-ratio sweep."""
        return self.phi0 < 1.0

    def flow_particles(self):
        """Diameters and species index (0 = small, 1 = large) of the flow particles."""
        area = self.Lx * self.Ly
        d_s = self.d_small
        if not self.bidisperse:
            n = int(round(self.H * area / d_s**3))
            return np.full(n, d_s), np.zeros(n, np.int64)
        d_l = d_s / self.sigma
        v_total = self.H * area * math.pi / 6.0
        n_s = int(round(self.phi0 * v_total / (math.pi / 6 * d_s**3)))
        n_l = int(round((1 - self.phi0) * v_total / (math.pi / 6 * d_l**3)))
        d = np.concatenate([np.full(n_s, d_s), np.full(n_l, d_l)])
        return d, np.concatenate([np.zeros(n_s, np.int64), np.ones(n_l, np.int64)])

    def interactions(self) -> InteractionTable:
        base_sp = self.base if self.base is not None else self.flow
        bidisperse = self.bidisperse
        names = ["small", "large"] if bidisperse else ["flow"]
        diams = [self.d_small, self.d_small / self.sigma] if bidisperse else [self.d_small]
        wall_d = self.lam if self.lam > 0 else 0.0
        tab = InteractionTable(names + ["base"], diams + [wall_d])
        for a in names:
            for b in names:
                tab.set(a, b, self.flow)
            tab.set(a, "base", base_sp)
        tab.set("base", "base", base_sp)
        return tab

    def as_dict(self) -> dict:
        d = asdict(self)
        return d


def top_up_flow(system: ParticleSystem, cfg: ChuteConfig) -> int:
    """Pour the flow particles that ``system`` lacks for the filling height ``cfg.H`` on top of
    it, at rest, keeping its particles and contacts (:meth:`ParticleSystem.add_particles`):
    the paper's §6 staircase raises H by 2 particle heights on an arrested pile.  They are
    inserted without overlaps above the highest flow particle (seeded by ``cfg.seed`` and the
    present count).  Monodisperse chutes only.  Returns the number added; raises ValueError
    when the system has more flow particles than ``cfg.H`` gives."""
    if cfg.bidisperse:
        raise ValueError("top-up (adding layers to a saved state) is for monodisperse chutes "
                         f"only: phi0 = {cfg.phi0:g} < 1")
    mobile = ~system.fixed
    n_flow = int(mobile.sum())
    d_flow, _ = cfg.flow_particles()
    k = len(d_flow) - n_flow
    if k < 0:
        raise ValueError(f"H = {cfg.H:g}: the state has {n_flow} flow particles, more than the "
                         f"{len(d_flow)} of this filling height (a top-up only adds)")
    if k == 0:
        return 0
    top = float(system.pos[mobile, 2].max()) if n_flow else 0.0
    rng = np.random.default_rng([cfg.seed, 11, n_flow])
    new_r = 0.5 * d_flow[n_flow:]
    pos = _insert(rng, system.pos, system.radius, new_r, cfg.Lx, cfg.Ly, z_lo=top,
                  height0=max(1.0, k / (cfg.Lx * cfg.Ly)), grow=cfg.insertion_growth)
    flow_type = int(system.ptype[mobile][0]) if n_flow else 0
    system.add_particles(pos, 2.0 * new_r, density=RHO_PARTICLE, ptype=flow_type)
    log.info("top-up: %d flow particles poured on the state (z >= %.3g) for H = %g", k, top,
             cfg.H)
    return k


def build_chute(cfg: ChuteConfig, base_positions: np.ndarray | None = None) -> ParticleSystem:
    """Create the chute system: base (prepared or given), inserted flow particles, tilted gravity."""
    cfg.validate()
    if base_positions is None:
        base_positions = prepare_rough_base(BaseConfig(lam=cfg.lam, Lx=cfg.Lx, Ly=cfg.Ly, seed=cfg.seed))
    base_positions = np.asarray(base_positions, dtype=np.float64).reshape(-1, 3)
    if cfg.lam == 0 and len(base_positions):
        raise ValueError("base_positions must be empty for lam = 0 (flat wall)")
    if cfg.lam > 0 and not len(base_positions):
        raise ValueError(f"base_positions is empty but lam = {cfg.lam} > 0 needs a rough base")
    rng = np.random.default_rng([cfg.seed, 7])
    d_flow, species = cfg.flow_particles()
    # the flow's particle order stays small-then-large for species-resolved output.  Mixtures are
    # inserted in random order so that the species start mixed (inserting large particles first
    # would put them low and start the run inversely segregated: at depth 24, 1/sigma = 1.5, the
    # small particles' centre of mass started 3.3 d above the flow's and was still sinking at
    # t = 400); one species: in index order.
    base_r = np.full(len(base_positions), 0.5 * cfg.lam)
    z_lo = 0.0 if cfg.lam > 0 else 0.5 * float(d_flow.max())
    if cfg.bidisperse and cfg.initial_mixing == "segregated":
        # the small particles (species 0, listed first) in the bottom phi0 of the insertion
        # height, then the large ones above the highest small centre: the fully segregated start
        small = species == 0
        r_s, r_l = 0.5 * d_flow[small], 0.5 * d_flow[~small]
        pos_s = _insert(rng, base_positions, base_r, r_s, cfg.Lx, cfg.Ly, z_lo=z_lo,
                        height0=cfg.phi0 * cfg.H, grow=cfg.insertion_growth)
        top = float(pos_s[:, 2].max()) + float(r_s.max()) if len(pos_s) else z_lo
        pos_l = _insert(rng, np.concatenate([base_positions, pos_s]),
                        np.concatenate([base_r, r_s]), r_l, cfg.Lx, cfg.Ly,
                        z_lo=top + float(r_l.max()) if len(r_l) else top,
                        height0=(1.0 - cfg.phi0) * cfg.H, grow=cfg.insertion_growth)
        pos_flow = np.concatenate([pos_s, pos_l])
    elif cfg.bidisperse and cfg.initial_mixing == "profile":
        pos_flow = _insert_profile(rng, base_positions, base_r, d_flow, species, cfg, z_lo)
    else:
        if cfg.bidisperse:
            order = rng.permutation(len(d_flow))
        else:
            order = np.arange(len(d_flow))
        pos_sorted = _insert(rng, base_positions, base_r, 0.5 * d_flow[order], cfg.Lx, cfg.Ly,
                             z_lo=z_lo, height0=cfg.H, grow=cfg.insertion_growth)
        pos_flow = np.empty_like(pos_sorted)
        pos_flow[order] = pos_sorted
    tab = cfg.interactions()
    base_type = len(tab.type_names) - 1
    sys_ = ParticleSystem(cfg.Lx, cfg.Ly, tab, gvec=cfg.gravity, skin=cfg.skin,
                          use_wall=cfg.lam == 0, wall_type=base_type,
                          steps_per_collision=cfg.steps_per_collision)
    nb = len(base_positions)
    pos = np.concatenate([pos_flow, base_positions])
    diam = np.concatenate([d_flow, np.full(nb, cfg.lam)])
    ptype = np.concatenate([species, np.full(nb, base_type, np.int64)])
    fixed = np.concatenate([np.zeros(len(d_flow), bool), np.ones(nb, bool)])
    sys_.set_particles(pos, diam, density=RHO_PARTICLE, ptype=ptype, fixed=fixed)
    sys_.initialize()
    log.info("chute: theta=%g H=%g lambda=%g: %d flow + %d base particles, dt=%.3g",
             cfg.theta, cfg.H, cfg.lam, len(d_flow), nb, sys_.dt)
    return sys_
