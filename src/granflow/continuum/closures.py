"""Closures of the depth-averaged equations (Weinhart et al. 2012 Eq. 34) as plain functions.

:class:`FlowClosures` holds, for one inclination theta, the basal friction mu(h, F) (Eq. 50),
the shape factor alpha(h) (Eq. 54/55) and the stress ratio K (Eq. 53) as vectorised numpy
functions with fixed parameters, so that a solver can evaluate them millions of times without
the per-call checks of :mod:`granflow.closures.evaluate`.  The checks are not lost: a
``FlowClosures`` built from a library refuses closures that are not ``ok``/``reduced`` (unless
``allow_unidentified=True``) exactly like the evaluators, and :meth:`FlowClosures.check` runs
the library's own evaluators (fitted range, fitted runs' (h, F) hull, impossible values) on the
states a model is about to use, before any compute.

Uncertainty: :meth:`FlowClosures.ensemble` returns one ``FlowClosures`` per stored parameter
sample (bootstrap refits or covariance draws; for mu the joint hstop/flow-rule ensemble), so a
model run over the ensemble gives the spread of its prediction.

Synthetic closures (for solver tests and what-if studies) are built directly:
``FlowClosures(theta=30, mu=lambda h, F: np.full(np.shape(F), 0.4))`` or
:meth:`FlowClosures.coulomb`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ..fitting.bulk import stress_ratio_eq53
from ..fitting.flow_rule import mu_eq50
from ..fitting.hstop import hstop_eq45
from ..fitting.shape_factor import alpha_eq54

#: gravitational acceleration in the nondimensional units (d = m = g = 1)
G = 1.0


def _const(value):
    def f(*args):
        return np.full(np.broadcast(*args).shape if args else (), float(value))
    return f


class _Members(list):
    """Ensemble members, with the number of samples dropped as no friction law."""

    ensemble_dropped = 0


def _physical_friction(p) -> bool:
    """Whether Eq. (50)'s parameters describe a friction law: 0 < delta1 < delta2 < 90 deg,
    A > 0, beta > 0 (all finite)."""
    try:
        d1, d2, A, beta = (float(p[k]) for k in ("delta1", "delta2", "A", "beta"))
    except (KeyError, TypeError, ValueError):
        return False
    return bool(0.0 < d1 < d2 < 90.0 and A > 0.0 and beta > 0.0
                and math.isfinite(float(p.get("gamma", 0.0))))


@dataclass(frozen=True)
class FlowClosures:
    """mu(h, F), alpha(h) and K at one inclination ``theta`` (degrees).

    ``mu(h, F)`` and ``alpha(h)`` take numpy arrays; ``K`` is a number (Eq. 53 depends on theta
    only).  ``status`` maps closure kind -> library status (``ok``, ``reduced``,
    ``unidentified``, ...; ``synthetic`` for closures given by hand), ``form`` kind -> stored
    form, ``source`` says where they came from, ``member`` which ensemble sample (None: the
    stored central values).
    """

    theta: float
    mu: Callable
    alpha: Callable = field(default=_const(1.0))
    K: float = 1.0
    status: dict = field(default_factory=lambda: {"friction": "synthetic", "alpha": "synthetic",
                                                  "stress_ratio": "synthetic"})
    form: dict = field(default_factory=dict)
    source: str = "synthetic"
    member: int | None = None
    _lib: object = field(default=None, repr=False, compare=False)
    _sel: dict = field(default_factory=dict, repr=False, compare=False)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def coulomb(cls, theta: float, mu: float, K: float = 1.0, alpha: float = 1.0):
        """Constant (Coulomb) friction tan(delta) = ``mu``, constant K and alpha (Mangeney et
        al. 2000; Savage & Hutter)."""
        return cls(theta=float(theta), mu=_const(mu), alpha=_const(alpha), K=float(K),
                   status={k: "synthetic" for k in ("friction", "alpha", "stress_ratio")},
                   form={"friction": f"Coulomb mu = {mu:g}", "alpha": f"constant {alpha:g}",
                         "stress_ratio": f"constant {K:g}"},
                   source="Coulomb friction (synthetic)")

    @classmethod
    def paper(cls, theta: float, lam: float = 1.0):
        """The paper's own closures at basal roughness ``lam`` (Weinhart et al. 2012 Table 1:
        Eq. 50's delta1, delta2, A, beta, gamma; Table 2: alpha, Eq. 54 with d_lambda and
        hstop(theta; 1) or Eq. 55's constant; Eq. 53's K with d0 = 132, d1 = 21.50), from
        :data:`granflow.reference.PAPER`: an independent comparator for a library's closures,
        status ``paper``.  Raises ValueError for a lam the paper's tables do not list."""
        from ..reference import paper_value

        theta = float(theta)
        p = {k: paper_value(kind, k, lam) for kind, k in (
            ("hstop", "delta1"), ("hstop", "delta2"), ("hstop", "A"), ("flow_rule", "beta"),
            ("flow_rule", "gamma"))}
        if not all(math.isfinite(v) for v in p.values()):
            raise ValueError(f"lam = {lam!r} is out of range: the paper's Table 1 lists "
                             "lambda = 1/2, 2/3, 5/6, 1, 2 with every friction parameter")

        def mu(h, F, p=p):
            return mu_eq50(np.asarray(h, float), np.asarray(F, float), p["delta1"],
                           p["delta2"], p["A"], p["beta"], p["gamma"])

        a_const = paper_value("alpha", "alpha_constant", lam)
        if math.isfinite(a_const):
            alpha, a_form = _const(a_const), f"Table 2 constant {a_const:g}"
        else:
            d_lam = paper_value("alpha", "d_lambda", lam)
            hst = float(hstop_eq45(theta, *(paper_value("hstop", k, 1.0)
                                            for k in ("delta1", "delta2", "A"))))

            def alpha(h, d_lam=d_lam, hst=hst):
                return alpha_eq54(np.asarray(h, float), hst, d_lam)
            a_form = f"Eq. 54, d_lambda = {d_lam:g}"
        K = float(stress_ratio_eq53(theta, paper_value("stress_ratio", "d0"),
                                    paper_value("stress_ratio", "d1")))
        return cls(theta=theta, mu=mu, alpha=alpha, K=K,
                   status={k: "paper" for k in ("friction", "alpha", "stress_ratio")},
                   form={"friction": "Eq. 50, Table 1 lambda = " + f"{lam:g}: " + ", ".join(
                       f"{k} {v:g}" for k, v in p.items()), "alpha": a_form,
                       "stress_ratio": "Eq. 53, d0 = 132, d1 = 21.50"},
                   source=f"Weinhart et al. 2012, Tables 1-2 and Eq. 53 (lambda = {lam:g})")

    @classmethod
    def from_library(cls, lib, theta: float, lam=None, *, contact_law=None,
                     allow_unidentified: bool = False, member: int | None = None):
        """The library's friction (Eq. 50), shape factor (Eq. 54/55) and K (Eq. 53) at theta.

        A closure that is not ``ok``/``reduced`` raises ValueError naming it and why
        (``allow_unidentified=True`` uses it anyway; its status is kept in ``status`` and in
        every dataset a model returns).  ``member``: index into the stored parameter ensemble
        (None: central values).
        """
        from ..closures.evaluate import closure_parameters

        theta = float(theta)
        kw = dict(contact_law=contact_law, allow_unidentified=allow_unidentified)
        fr = closure_parameters(lib, "friction", lam, **kw)
        al = closure_parameters(lib, "alpha", lam, **kw)
        kr = closure_parameters(lib, "stress_ratio", None, **kw)
        # Eq. (54) uses hstop(theta; lambda = 1), as granflow.closures.alpha does
        hs = closure_parameters(lib, "hstop", 1.0, contact_law=contact_law,
                                allow_unidentified=True)

        def pick(c, names):
            if member is None:
                return dict(c.params)
            rows = c.samples(names)
            if not rows:
                raise ValueError(f"the {c.kind} closure stores no ensemble")
            return dict(c.params, **rows[member % len(rows)])

        pf = pick(fr, ("delta1", "delta2", "A", "beta", "gamma"))

        def mu(h, F, p=pf):
            return mu_eq50(np.asarray(h, float), np.asarray(F, float), p["delta1"],
                           p["delta2"], p["A"], p["beta"], p["gamma"])

        if math.isfinite(al.params["alpha_constant"]) and not math.isfinite(al.params["d_lambda"]):
            a_const = pick(al, ("alpha_constant",))["alpha_constant"]
            alpha = _const(a_const)
        else:
            d_lam = pick(al, ("d_lambda",))["d_lambda"]
            hst = float(hstop_eq45(theta, hs.params["delta1"], hs.params["delta2"],
                                   hs.params["A"]))

            def alpha(h, d_lam=d_lam, hst=hst):
                return alpha_eq54(np.asarray(h, float), hst, d_lam)
        if kr.form == "constant":
            K = pick(kr, ("K_ref",))["K_ref"]
        else:
            pk = pick(kr, ("d0", "d1"))
            K = float(stress_ratio_eq53(theta, pk["d0"], pk["d1"]))
        return cls(theta=theta, mu=mu, alpha=alpha, K=float(K),
                   status={"friction": fr.status, "alpha": al.status,
                           "stress_ratio": kr.status},
                   form={"friction": fr.form, "alpha": al.form, "stress_ratio": kr.form},
                   source=f"library {lib.attrs.get('library_name', '?')}-v"
                          f"{lib.attrs.get('library_version', '?')} "
                          f"({lib.attrs.get('content_hash', '')[:19]})",
                   member=member, _lib=lib,
                   _sel=dict(lam=lam, contact_law=contact_law,
                             allow_unidentified=allow_unidentified))

    def at(self, theta: float) -> "FlowClosures":
        """The same closures at another inclination (library closures are rebuilt)."""
        if self._lib is None:
            return replace(self, theta=float(theta))
        return FlowClosures.from_library(self._lib, theta, self._sel["lam"],
                                         contact_law=self._sel["contact_law"],
                                         allow_unidentified=self._sel["allow_unidentified"],
                                         member=self.member)

    def ensemble(self, n: int | None = None) -> list["FlowClosures"]:
        """One FlowClosures per stored parameter sample (the first ``n``; all if None).  A
        synthetic closure set has no ensemble: a list holding itself."""
        if self._lib is None:
            return [self]
        from ..closures.evaluate import closure_parameters

        fr = closure_parameters(self._lib, "friction", self._sel["lam"],
                                contact_law=self._sel["contact_law"], allow_unidentified=True)
        m = len(fr.samples(("delta1", "delta2", "A", "beta", "gamma")))
        if m < 10:
            raise ValueError(f"the friction closure stores no usable ensemble ({m} samples)")
        n = m if n is None else min(int(n), m)
        # a bootstrap refit can land on parameters that are no friction law (delta1 <= 0,
        # delta2 <= delta1, A <= 0 or beta <= 0: mu jumps or has a pole inside the flow); such
        # samples are dropped and counted (``ensemble_dropped`` on the returned list)
        rows = fr.samples(("delta1", "delta2", "A", "beta", "gamma"))
        keep = [i for i in range(n) if _physical_friction(rows[i % len(rows)])]
        out = _Members(FlowClosures.from_library(self._lib, self.theta, self._sel["lam"],
                                                 contact_law=self._sel["contact_law"],
                                                 allow_unidentified=self._sel["allow_unidentified"],
                                                 member=i) for i in keep)
        out.ensemble_dropped = n - len(keep)
        return out

    # ------------------------------------------------------------------ checks and helpers
    def check(self, h, F, *, extrapolate: bool = False):
        """Run the library's evaluators on the states (h, F) a model will use: raises
        ValueError when an input lies outside the fitted range or the fitted runs' (h, F)
        hull (unless ``extrapolate``) or a value is physically impossible.  No-op for
        synthetic closures."""
        if self._lib is None:
            return
        kw = dict(lam=self._sel["lam"], contact_law=self._sel["contact_law"],
                  allow_unidentified=self._sel["allow_unidentified"], extrapolate=extrapolate)
        h = np.atleast_1d(np.asarray(h, float))
        F = np.atleast_1d(np.asarray(F, float))
        h, F = np.broadcast_arrays(h, F)
        self._lib.closures.mu(h, F, **kw)
        self._lib.closures.alpha(np.full(h.shape, self.theta), h, **kw)
        kw.pop("lam")
        self._lib.closures.K(self.theta, **kw)

    def fitted_ranges(self) -> dict | None:
        """``{"h": (min, max), "F": (min, max)}`` of the data the friction closure was fitted
        to (None for synthetic closures)."""
        if self._lib is None:
            return None
        from ..closures.evaluate import _cell, closure_parameters

        c = closure_parameters(self._lib, "friction", self._sel["lam"],
                               contact_law=self._sel["contact_law"], allow_unidentified=True)
        out = {}
        for v in ("h", "F"):
            lo, hi = (float(_cell(self._lib, f"friction_{v}_{e}", c.sel).item())
                      for e in ("min", "max"))
            out[v] = (lo, hi)
        return out

    @property
    def g_cos(self) -> float:
        return G * math.cos(math.radians(self.theta))

    @property
    def tan_theta(self) -> float:
        return math.tan(math.radians(self.theta))

    def acceleration(self, h, u):
        """Source of the depth-averaged momentum equation per unit mass, Eq. (34b-c) on a flat
        base: g cos(theta) (tan(theta) - mu(h, |F|) sign(u)), F = u / sqrt(g h cos theta).

        At rest (u = 0) friction holds the layer when tan(theta) <= mu(h, 0) (zero
        acceleration) and otherwise opposes the driving force."""
        h = np.asarray(h, float)
        u = np.asarray(u, float)
        gc = self.g_cos
        with np.errstate(divide="ignore", invalid="ignore"):
            F = np.abs(u) / np.sqrt(gc * np.maximum(h, 1e-300))
        mu = np.asarray(self.mu(h, F), float)
        s = np.sign(u)
        at_rest = s == 0
        if np.any(at_rest):
            s = np.where(at_rest, np.sign(self.tan_theta), s)
            mu = np.where(at_rest & (abs(self.tan_theta) <= mu), abs(self.tan_theta), mu)
        return gc * (self.tan_theta - mu * s)

    def steady_froude(self, h, F_max: float = 50.0):
        """F with mu(h, F) = tan(theta) (steady uniform flow), NaN where none in [0, F_max]
        (arrested: tan(theta) < mu(h, 0); accelerating: tan(theta) > mu(h, F_max))."""
        from scipy.optimize import brentq

        h = np.atleast_1d(np.asarray(h, float))
        out = np.full(h.shape, np.nan)
        t = self.tan_theta
        for i, hh in enumerate(h.ravel()):
            def f(F):
                return float(self.mu(hh, F)) - t
            a, b = f(0.0), f(F_max)
            if a <= 0 <= b:
                out.flat[i] = 0.0 if a == 0 else brentq(f, 0.0, F_max, xtol=1e-15, rtol=1e-15,
                                                        maxiter=500)
        return out if out.size > 1 else float(out[0])

    def gray_edwards_viscosity(self, h_ref: float) -> float:
        """Coefficient nu of the depth-averaged viscous stress d(nu h^(3/2) du/dx)/dx of Gray &
        Edwards (2014, J. Fluid Mech. 755, 503) for a layer of depth ``h_ref`` at theta:

            nu = (2/9) tan(theta) sqrt(g cos(theta)) h_ref / F_s(h_ref),

        F_s the steady Froude number of these closures (:meth:`steady_froude`).  Their
        nu = (2/9) (L sqrt(g) / beta) sin / sqrt(cos) (tan zeta2 - tan) / (tan - tan zeta1) is
        this with the flow rule F = beta h / hstop(theta) (h / F_s = hstop / beta, the same at
        every depth); with Eq. (47)'s offset gamma, h / F_s depends on the depth, hence
        ``h_ref`` (the layer's mean depth).  It comes from the mu(I)-rheology's longitudinal
        stress, mu p / |du/dz| integrated over a Bagnold profile (F = (2/5) I h / d), evaluated
        at the steady state: an extension of Eq. (34), not part of the paper.  Raises
        ValueError where the closures have no steady flow at ``h_ref``."""
        h_ref = float(h_ref)
        if not (math.isfinite(h_ref) and h_ref > 0):
            raise ValueError(f"h_ref = {h_ref!r} is out of range: allowed (0, inf)")
        F = self.steady_froude(h_ref)
        if not (math.isfinite(F) and F > 0):
            raise ValueError(f"no steady flow at h_ref = {h_ref:g}, theta = {self.theta:g} deg "
                             f"(F_s = {F!r}): the Gray-Edwards viscosity needs one")
        return 2.0 / 9.0 * self.tan_theta * math.sqrt(self.g_cos) * h_ref / F

    def attrs(self) -> dict:
        """Dataset attributes describing these closures (source, status, forms, K)."""
        out = {"closure_source": self.source, "theta_deg": self.theta,
               "closure_K": self.K}
        for k, v in self.status.items():
            out[f"closure_status_{k}"] = v
        for k, v in self.form.items():
            out[f"closure_form_{k}"] = v
        if self.member is not None:
            out["closure_ensemble_member"] = int(self.member)
        return out
