"""Campaign grids: configuration -> run points -> readable run directories and run parameters.

A run point is fully described by its directory (Paramspace style), relative to the campaign's
results folder ``results/<name>/``::

    chute/<law>/lambda~<lam>/theta~<theta>/H~<H>                  (closure runs, sigma = 1)
    bracket/<law>/lambda~<lam>/theta~<theta>/H~<H>                (hstop bisection runs: stop
                                                                   once decisively flowing)
    segregation/<law>/lambda~<lam>/theta~<theta>/H~<H>/sigma~<s>   (bidisperse runs)

so that a rule can rebuild the run's parameters from its output path alone (the grid runs and
the points proposed by the adaptive hstop search share one ``simulate`` rule).  Replicates
(``replicates: n``, globally under ``numerics`` or per grid block) add ``/seed~k`` for
k = 1 .. n - 1: the same point with the insertion seed ``seed + k`` (replicate 0 keeps the plain
directory and the configured seed, so a campaign without replicates is unchanged).  A
segregation run started fully segregated (``campaigns.segregation.initial_mixing`` lists
``segregated`` beside the default ``mixed``) adds ``/start~segregated`` before any ``/seed~k``:
it approaches the steady segregated state from above where the mixed start approaches it from
below (:class:`granflow.engine.chute.ChuteConfig`); ``profile<Ps>`` (e.g. ``profile3.5``,
``/start~profile3.5``) starts stratified as T-eq. 28's steady profile at that Peclet number,
nearer the steady state than either limit, and approaches it from the side Ps lies on.  Replicates
share the rough base of their (lambda, box): they measure the scatter of the flow over one
boundary, the quantity a closure fitted to that base must be given; the base realisation is a
separate (systematic) question, studied by changing ``base.seed``, or, for the hstop
bisection chains, by ``hstop_bisection.replicate_bases`` (replicate chain k on a base of seed
``base.seed + k``).  Numbers are
written as the shortest string that reads back to the same float, without a trailing ``.0``
(``24``, ``0.5``, ``0.6666666666666666``).

The configuration layout is documented key by key in ``config/config.yaml`` and checked by
``workflow/schemas/config.schema.yaml``; this module only reads it.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

KINDS = ("chute", "segregation", "bracket")
#: how a segregation run's species start (granflow.engine.chute.INITIAL_MIXINGS; "mixed" is the
#: default and keeps the plain directory)
STARTS = ("mixed", "segregated", "profile")
#: a "profile" start names its T-eq. 28 Peclet number: ``profile<Ps>`` (e.g. ``profile3.5``)
_PROFILE_RE = re.compile(r"profile([0-9][0-9.e+-]*)")


def start_initial_Ps(start: str) -> float | None:
    """The Peclet number of a ``profile<Ps>`` start, None for "mixed" and "segregated";
    ValueError for anything else (the allowed names and Ps range)."""
    if start in ("mixed", "segregated"):
        return None
    m = _PROFILE_RE.fullmatch(str(start))
    ps = None
    if m is not None:
        try:
            ps = float(m.group(1))
        except ValueError:
            ps = None
    if ps is None or not (0.0 < ps <= 1e3):
        raise ValueError(f"start {start!r} is unknown: allowed 'mixed', 'segregated' or "
                         "'profile<Ps>' with Ps in (0, 1000] (e.g. 'profile3.5': stratified as "
                         "T-eq. 28's steady profile at that Peclet number)")
    return ps


def check_start(start: str, kind: str = "segregation") -> str:
    """``start`` if allowed for a run of ``kind`` (anything but "mixed" only for segregation
    runs), else ValueError naming the allowed starts."""
    if start != "mixed" and kind != "segregation":
        raise ValueError(f"start {start!r} of a {kind} run: allowed 'mixed' only (the other "
                         "starts are for segregation runs)")
    start_initial_Ps(start)
    return start

#: configuration ``species`` keys -> run parameter names (granflow.simulate.PARAMETERS)
SPECIES_KEYS = ("t_c", "e", "mu_c", "kt_over_kn", "gt_over_gn", "v_ref", "base_t_c", "base_e",
                "base_mu_c")
#: configuration ``numerics`` keys passed to every run as they are
NUMERICS_KEYS = ("t_end", "averaging_time", "check_every", "min_accelerating_time",
                 "max_overlap", "steps_per_collision", "skin", "sample_interval", "cg_width", "cg_dz",
                 "cg_window", "cg_every", "checkpoint_every_s", "seed", "early_stop",
                 "insertion_growth")

_NUM = r"[0-9][0-9.e+-]*"
_RUN_RE = re.compile(
    rf"(?P<kind>chute|segregation|bracket)/(?P<law>[A-Za-z_]+)/lambda~(?P<lam>{_NUM})/"
    rf"theta~(?P<theta>{_NUM})/H~(?P<H>{_NUM})(?:/sigma~(?P<sigma>{_NUM}))?"
    rf"(?:/start~(?P<start>[a-z]+(?:{_NUM})?))?(?:/seed~(?P<rep>[0-9]+))?")
#: regular expression of the ``point`` part of a run directory (for Snakemake wildcard constraints)
POINT_REGEX = (rf"lambda~{_NUM}/theta~{_NUM}/H~{_NUM}(/sigma~{_NUM})?(/start~[a-z]+({_NUM})?)?"
               rf"(/seed~[0-9]+)?")


def format_value(x) -> str:
    """Shortest string that reads back to the same float, without a trailing ``.0``."""
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"cannot put the non-finite value {x} into a run directory name")
    s = repr(x)
    if s.endswith(".0"):
        s = s[:-2]
    return s


@dataclass(frozen=True, order=True)
class RunPoint:
    """One run of a campaign: kind ("chute" or "segregation"), contact law and grid values."""

    kind: str
    law: str
    lam: float
    theta: float
    H: float
    sigma: float = 1.0
    replicate: int = 0
    start: str = "mixed"

    @property
    def path(self) -> str:
        """Run directory relative to the campaign's results folder."""
        return run_path(self)

    @property
    def point(self) -> str:
        """The ``lambda~/theta~/H~[/sigma~]`` part of the run directory."""
        return self.path.split("/", 2)[2]


def run_path(p: RunPoint) -> str:
    if p.kind not in KINDS:
        raise ValueError(f"run kind {p.kind!r} is unknown: allowed {KINDS}")
    s = (f"{p.kind}/{p.law}/lambda~{format_value(p.lam)}/theta~{format_value(p.theta)}/"
         f"H~{format_value(p.H)}")
    if p.kind == "segregation":
        s += f"/sigma~{format_value(p.sigma)}"
    if p.start != "mixed":
        check_start(p.start, p.kind)
        s += f"/start~{p.start}"
    if p.replicate:
        s += f"/seed~{int(p.replicate)}"
    return s


def parse_run_path(path: str) -> RunPoint:
    """Inverse of :func:`run_path` (accepts a longer path that contains a run directory)."""
    m = _RUN_RE.search(str(path).replace("\\", "/"))
    if m is None:
        raise ValueError(f"{path!r} is not a campaign run directory "
                         "(<kind>/<law>/lambda~L/theta~T/H~H[/sigma~S])")
    g = m.groupdict()
    if g["kind"] == "segregation" and g["sigma"] is None:
        raise ValueError(f"segregation run directory {path!r} lacks sigma~")
    start = g["start"] or "mixed"
    try:
        check_start(start, g["kind"])
    except ValueError as exc:
        raise ValueError(f"run directory {path!r}: start~{start} is not allowed: {exc}") from None
    return RunPoint(g["kind"], g["law"], float(g["lam"]), float(g["theta"]), float(g["H"]),
                    float(g["sigma"]) if g["sigma"] is not None else 1.0,
                    int(g["rep"]) if g["rep"] is not None else 0, start)


def _as_list(x):
    if x is None:
        return []
    return list(x) if isinstance(x, (list, tuple)) else [x]


def campaign_cfg(config: dict, kind: str) -> dict:
    return (config.get("campaigns") or {}).get(kind) or {}


def enabled(config: dict, kind: str) -> bool:
    c = campaign_cfg(config, kind)
    return bool(c) and bool(c.get("enabled", True))


def chute_points(config: dict) -> list[RunPoint]:
    """Grid runs of the "chute" campaign: the union of the products in ``grids`` and the
    explicit ``points``; each block may override ``lambda`` and ``contact_law``."""
    c = campaign_cfg(config, "chute")
    if not enabled(config, "chute"):
        return []
    laws0, lams0 = _as_list(c.get("contact_law", ["linear"])), _as_list(c.get("lambda", [1.0]))
    reps0 = replicates(config, "chute")
    out = set()
    for block in c.get("grids") or []:
        for law in _as_list(block.get("contact_law", laws0)):
            for lam in _as_list(block.get("lambda", lams0)):
                for theta in _as_list(block.get("theta")):
                    for H in _as_list(block.get("H")):
                        for k in range(int(block.get("replicates", reps0))):
                            out.add(RunPoint("chute", str(law), float(lam), float(theta),
                                             float(H), replicate=k))
    for pt in c.get("points") or []:
        for law in _as_list(pt.get("contact_law", laws0)):
            for lam in _as_list(pt.get("lambda", lams0)):
                for k in range(int(pt.get("replicates", reps0))):
                    out.add(RunPoint("chute", str(law), float(lam), float(pt["theta"]),
                                     float(pt["H"]), replicate=k))
    return sorted(out)


def replicates(config: dict, kind: str) -> int:
    """Replicates per run point: the campaign's ``numerics.replicates``, else the global
    ``numerics.replicates``, else 1 (a grid block or point may set its own ``replicates``)."""
    c = campaign_cfg(config, _config_kind(kind))
    n = (c.get("numerics") or {}).get("replicates",
                                      (config.get("numerics") or {}).get("replicates", 1))
    return max(int(n), 1)


def segregation_points(config: dict) -> list[RunPoint]:
    """Runs of the "segregation" campaign: one per (contact law, size ratio sigma, start,
    replicate); ``initial_mixing`` (default ``[mixed]``) lists the starts."""
    c = campaign_cfg(config, "segregation")
    if not enabled(config, "segregation"):
        return []
    out = set()
    for law in _as_list(c.get("contact_law", ["linear"])):
        for sigma in _as_list(c.get("sigma")):
            for start in _as_list(c.get("initial_mixing", ["mixed"])):
                for k in range(replicates(config, "segregation")):
                    out.add(RunPoint("segregation", str(law), float(c.get("lambda", 1.0)),
                                     float(c["theta"]), float(c["H"]), float(sigma),
                                     replicate=k, start=str(start)))
    return sorted(out)


def restart_parent(config: dict, p: RunPoint) -> RunPoint | None:
    """The grid run whose final state run ``p`` restarts from, or None (a fresh fall).

    With ``campaigns.chute.restart_from_neighbour: true`` the chute grid runs of one contact
    law, lambda, H and replicate form a chain over their inclinations, rooted at the middle one
    (the lower middle of an even count): the root falls fresh, each run above it restarts from
    the next lower inclination, each run below from the next higher one -- at most about half
    the angles in sequence, and no run starts from far away.  The job restarts only if its
    parent ended steady (``granflow simulate --from-if-steady``); otherwise it falls fresh and
    its outputs say why.  Brackets and segregation runs always fall fresh."""
    if p.kind != "chute" or not bool(campaign_cfg(config, "chute").get("restart_from_neighbour")):
        return None
    thetas = sorted({q.theta for q in chute_points(config)
                     if (q.law, q.lam, q.H, q.replicate) == (p.law, p.lam, p.H, p.replicate)})
    if p.theta not in thetas:
        return None
    i, root = thetas.index(p.theta), (len(thetas) - 1) // 2
    if i == root:
        return None
    j = i - 1 if i > root else i + 1
    return RunPoint("chute", p.law, p.lam, thetas[j], p.H, replicate=p.replicate)


def expand_runs(config: dict) -> list[RunPoint]:
    """Every grid run of a configuration (chute grid, then segregation sweep), sorted."""
    return chute_points(config) + segregation_points(config)


def _config_kind(kind: str) -> str:
    """The campaign block a run kind takes its settings from (brackets belong to "chute")."""
    return "chute" if kind == "bracket" else kind


def box(config: dict, kind: str) -> tuple[float, float]:
    """Box (Lx, Ly) of a run kind: the campaign's ``Lx``, ``Ly`` (default the paper's 20 x 10);
    hstop bisection brackets take ``hstop_bisection.Lx``/``Ly`` where set (an arrest/flow
    bracket is cheaper in a smaller box, while the steady grid's closures feel the box: measured
    at lambda = 1/2, :data:`granflow.reference.BOX_EFFECT`)."""
    c = campaign_cfg(config, _config_kind(kind))
    Lx, Ly = float(c.get("Lx", 20.0)), float(c.get("Ly", 10.0))
    if kind == "bracket":
        bis = c.get("hstop_bisection") or {}
        Lx, Ly = float(bis.get("Lx", Lx)), float(bis.get("Ly", Ly))
    return Lx, Ly


def base_settings(config: dict) -> dict:
    """How the campaign's rough bases are made (``base:`` of the config, with
    :class:`~granflow.engine.chute.BaseConfig`'s defaults for the keys it leaves out)."""
    from ..engine.chute import BaseConfig

    b = config.get("base") or {}
    d = BaseConfig()
    return {"layers": float(b.get("layers", d.base_layers)),
            "settle_time": float(b.get("settle_time", d.settle_time)),
            "seed": int(b.get("seed", d.seed)),
            "settle_mu_c": float(b.get("settle_mu_c", d.prep_mu_c)),
            "fill_packing": float(b.get("fill_packing", d.fill_packing)),
            "band": str(b.get("band", d.band))}


def base_making(config: dict) -> dict:
    """The ``base:`` keys of how a base settles, as keyword arguments of
    :class:`~granflow.engine.chute.BaseConfig` / :func:`granflow.simulate.prepare_base_file`
    (``prep_mu_c``, ``fill_packing``, ``band``)."""
    b = base_settings(config)
    return {"prep_mu_c": b["settle_mu_c"], "fill_packing": b["fill_packing"], "band": b["band"]}


def base_seed(config: dict, p: RunPoint) -> int:
    """Seed of the base a run falls onto: ``base.seed``, plus k for replicate k of an hstop
    bisection chain when ``hstop_bisection.replicate_bases`` is set (every other run, and
    replicate 0, shares the campaign's base)."""
    seed = base_settings(config)["seed"]
    bis = campaign_cfg(config, "chute").get("hstop_bisection") or {}
    if p.kind == "bracket" and p.replicate and bis.get("replicate_bases", False):
        seed += int(p.replicate)
    return seed


def base_path(config: dict, p: RunPoint) -> str:
    """Rough-base file of a run, relative to the campaign folder: one per (lambda, box), and
    one per further seed of ``hstop_bisection.replicate_bases`` (``/seed~<s>``)."""
    Lx, Ly = box(config, p.kind)
    folder = f"bases/lambda~{format_value(p.lam)}/box~{format_value(Lx)}x{format_value(Ly)}"
    seed = base_seed(config, p)
    if seed != base_settings(config)["seed"]:
        folder += f"/seed~{seed}"
    return f"{folder}/base.npy"


def parse_base_path(path: str) -> tuple[float, float, float]:
    m = re.search(rf"lambda~(?P<lam>{_NUM})/box~(?P<Lx>{_NUM})x(?P<Ly>{_NUM})", str(path))
    if m is None:
        raise ValueError(f"{path!r} is not a base path (bases/lambda~L/box~LXxLY/base.npy)")
    return float(m["lam"]), float(m["Lx"]), float(m["Ly"])


def run_params(config: dict, p: RunPoint) -> dict:
    """Complete ``granflow simulate`` parameters of run ``p`` (validated by the job itself).

    Layering: species, then ``numerics``, then the campaign's own ``numerics`` overrides, then
    the box, base thickness and the grid values of the point; a ``bracket`` run (hstop
    bisection) is a chute run that stops as soon as it is decisively flowing (under the
    ``continuation`` protocol: one that runs to the arrest horizon unless arrested or steady,
    :data:`granflow.campaign.hstop.BISECTION_PROTOCOLS`) and at the arrest horizon at the
    latest (not arrested by then: flowing, the paper's §6 rule), coarse-grained every
    ``hstop_bisection.cg_every``-th sample where that is set; a campaign with
    ``engine: lammps`` adds ``engine`` (the run is then carried out by LAMMPS,
    :mod:`granflow.lammps`).
    """
    species = config.get("species") or {}
    numerics = dict(config.get("numerics") or {})
    c = campaign_cfg(config, _config_kind(p.kind))
    numerics.update(c.get("numerics") or {})
    params = {k: species[k] for k in SPECIES_KEYS if species.get(k) is not None}
    params.update({k: numerics[k] for k in NUMERICS_KEYS if numerics.get(k) is not None})
    Lx, Ly = box(config, p.kind)
    params.update(theta=p.theta, H=p.H, lam=p.lam, Lx=Lx, Ly=Ly, contact_law=p.law,
                  base_layers=base_settings(config)["layers"])
    if p.kind == "segregation":
        params.update(sigma=p.sigma, phi0=float(c.get("phi0", 0.5)))
        if p.start != "mixed":  # absent for the default: older run parameters unchanged
            ps = start_initial_Ps(p.start)
            params["initial_mixing"] = p.start if ps is None else "profile"
            if ps is not None:
                params["initial_Ps"] = ps
    if p.kind == "bracket":
        from .hstop import bisection_protocol

        bis = c.get("hstop_bisection") or {}
        protocol, horizon = bisection_protocol(bis)
        if protocol == "continuation":  # arrested within the horizon, or flowing
            params.update(stop_when_flowing=False, early_stop=True,
                          t_end=min(float(params.get("t_end", horizon)), horizon))
        else:  # arrested (within the horizon) or decisively flowing is all a bracket needs
            params.update(stop_when_flowing=True, early_stop=True,
                          t_end=min(float(params.get("t_end", horizon)), horizon))
        if bis.get("cg_every") is not None:  # its profiles enter no closure (hstop: state only)
            params["cg_every"] = int(bis["cg_every"])
    if p.replicate:  # replicate k: the insertion seed + k (the base is shared)
        params["seed"] = int(params.get("seed", 1)) + int(p.replicate)
    if c.get("engine", "numba") != "numba":  # absent for numba: older run parameters unchanged
        params["engine"] = str(c["engine"])
    return {k: (float(v) if isinstance(v, int) and not isinstance(v, bool) and k != "seed"
                and k != "cg_every" else v) for k, v in params.items()}


def threads(config: dict) -> int:
    return int((config.get("numerics") or {}).get("threads", 1))
