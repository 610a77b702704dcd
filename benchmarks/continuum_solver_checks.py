"""Solver checks of granflow.continuum.shallow_layer (Weinhart et al. 2012 Eq. 34), printed.

Not a timing benchmark: prints the numbers the issue-17 report quotes for the 1D finite-volume
shallow-layer solver (the fast tests in tests/test_continuum.py assert the same properties with
tolerances):

* mass conservation on a periodic chute with a Gaussian bump (Eq. 50 friction, K, alpha):
  max |M(t) - M(0)| / M(0);
* a uniform steady flow (u = the steady Froude number of Eq. 50) stays steady;
* the uniform limit (8 periodic cells) against the uniform-layer ODE (uniform_layer);
* the Coulomb-friction dam break on a slope against Mangeney et al. (2000): relative L1 error of
  h, the 5 %-of-h0 contour and the numerical tip against the exact front x_B, for three dx;
* tilupy's independent implementation of the same exact solution against granflow's;
* with the depth-averaged viscous stress of Gray & Edwards (2014) (nu of the Table 1 closure
  at 25 deg, h = 8): the decay rate of a small Fourier mode against the linearised equations,
  and momentum and mass conservation on a periodic chute whose friction balances gravity.

Run: ``NUMBA_NUM_THREADS=1 .venv/bin/python benchmarks/continuum_solver_checks.py``
(needs the ``test`` extra for tilupy; ~15 s).
"""

import math

import numpy as np

from granflow.continuum import (FlowClosures, dam_break_front, mangeney_dam_break, shallow_layer,
                                uniform_layer)
from granflow.fitting.flow_rule import mu_eq50

# Eq. 50 parameters of the paper's lambda = 1 fit (Weinhart et al. 2012, Table 1), copied in.
P_EQ50 = dict(delta1=17.708, delta2=32.780, A=3.355, beta=0.196, gamma=0.040)


def eq50_closures(theta, K=1.0, alpha=1.0):
    return FlowClosures(theta=theta, mu=lambda h, F: mu_eq50(h, F, **P_EQ50), K=K,
                        alpha=lambda h: np.full(np.shape(h), alpha))


def mass_conservation():
    c = eq50_closures(26.0, K=1.05, alpha=1.25)
    x = np.arange(200) * 0.5 + 0.25
    r = shallow_layer(c, x, 6.0 + 3.0 * np.exp(-((x - 30.0) / 5.0) ** 2), 0.6, t_end=40.0, n_out=9)
    m = r.mass.values
    print(f"mass: max |M(t)-M(0)|/M(0) = {np.max(np.abs(m - m[0])) / m[0]:.2e} "
          f"({r.attrs['n_steps']} steps)")


def steady_and_uniform_limit():
    c = eq50_closures(25.0, K=1.02, alpha=1.3)
    us = c.steady_froude(8.0) * math.sqrt(c.g_cos * 8.0)
    r = shallow_layer(c, np.arange(32) + 0.5, 8.0, us, t_end=100.0, n_out=11)
    print(f"steady: max|h-h0| = {np.max(np.abs(r.h.values - 8.0)):.2e}, "
          f"max|u-u_s| = {np.nanmax(np.abs(r.u_bar.values - us)):.2e}")
    o = uniform_layer(c, 10.0, 0.3, 100.0, n_out=101)
    f = shallow_layer(c, np.arange(8) + 0.5, 10.0, 0.3, t_end=100.0, n_out=101)
    print(f"uniform limit: max|u_FV - u_ODE| = "
          f"{np.max(np.abs(f.u_bar.values - o.u_bar.values[:, None])):.2e}")


def dam_break(t=5.0, h0=4.0):
    for theta, delta in ((30.0, 20.0), (35.0, 25.0)):
        for dx in (0.25, 0.125, 0.0625):
            c = FlowClosures.coulomb(theta=theta, mu=math.tan(math.radians(delta)))
            x = np.arange(-60.0, 40.0, dx) + 0.5 * dx
            r = shallow_layer(c, x, np.where(x < 0, h0, 0.0), 0.0, t_end=t, bc="open", n_out=2)
            h_exact, _ = mangeney_dam_break(x, t, h0, theta, delta)
            h = r.h.values[-1]
            inside = x > -40.0     # away from the upstream end of the finite reservoir

            def contour(hh, level=0.05 * h0):
                return x[np.nonzero(hh > level)[0][-1]]

            l1 = np.sum(np.abs(h - h_exact)[inside]) / np.sum(h_exact[inside])
            tip = x[np.nonzero(h > 1e-4 * h0)[0][-1]]
            print(f"dam break theta={theta} delta={delta} dx={dx}: L1(h) rel {l1:.2e}, "
                  f"5%-contour {contour(h):.3f} vs exact {contour(h_exact):.3f}, "
                  f"tip {tip:.2f} vs x_B {dam_break_front(t, h0, theta, delta):.2f}")


def against_tilupy(t=5.0, h0=4.0):
    import tilupy.analytic_sol as analytic   # the test extra

    # tilupy works in dimensional time with g = 9.81: the same nondimensional t is t / sqrt(g)
    sol = analytic.Mangeney_dry(x_0=0.0, h_0=h0, theta=30.0, delta=20.0)
    xx = np.linspace(-30.0, 40.0, 141)
    sol.compute_h(xx, [t / math.sqrt(9.81)])
    ours, _ = mangeney_dam_break(xx, t, h0, 30.0, 20.0)
    print(f"tilupy vs granflow.continuum.exact: max|dh| = {np.max(np.abs(sol._h[0] - ours)):.2e}")


def _least_damped(c, h, u, alpha, k, nu):
    """Linearised Eq. (34) with the viscous stress: the least-damped complex frequency."""
    def source(hh, qq):
        return hh * float(c.acceleration(hh, qq / hh))
    q, e = h * u, 1e-6
    s_h = (source(h + e, q) - source(h - e, q)) / (2 * e) + k * k * nu * math.sqrt(h) * u
    s_q = (source(h, q + e) - source(h, q - e)) / (2 * e) - k * k * nu * math.sqrt(h)
    f_h, f_q = c.K * c.g_cos * h - alpha * u * u, 2 * alpha * u
    om = np.roots([1.0, -f_q * k - 1j * s_q, -f_h * k * k - 1j * s_h * k])
    return om[np.argmax(om.imag)]


def viscous_stress():
    alpha, h = 1.3, 8.0
    c = eq50_closures(25.0, K=1.02, alpha=alpha)
    nu = c.gray_edwards_viscosity(h)
    u = c.steady_froude(h) * math.sqrt(c.g_cos * h)
    for wl in (25.0, 50.0, 100.0):
        k = 2 * math.pi / wl
        w, w0 = _least_damped(c, h, u, alpha, k, nu), _least_damped(c, h, u, alpha, k, 0.0)
        x = (np.arange(100) + 0.5) * wl / 100
        h0 = h + 1e-3 * h * np.cos(k * x)
        q0 = h * u + 1e-3 * h * np.real(w / k * np.exp(1j * k * x))
        t_end = -1.0 / w.imag
        r = shallow_layer(c, x, h0, q0 / h0, t_end, n_out=2, viscosity=nu)
        ratio = np.sum((r.h.values[1] - h) * np.exp(-1j * k * x)) / \
            np.sum((r.h.values[0] - h) * np.exp(-1j * k * x))
        print(f"viscous (nu = {nu:.3f}) wavelength {wl:g}: decay rate solver "
              f"{-math.log(abs(ratio)) / t_end:.5f} vs linearised {-w.imag:.5f} "
              f"(Eq. 34 alone {-w0.imag:.5f})")
    cc = FlowClosures.coulomb(theta=25.0, mu=math.tan(math.radians(25.0)), alpha=1.2)
    x = np.arange(200) * 0.5 + 0.25
    r = shallow_layer(cc, x, 6.0 + 3.0 * np.exp(-((x - 30.0) / 5.0) ** 2),
                      2.0 + 0.5 * np.sin(2 * math.pi * x / 100.0), t_end=20.0, n_out=5,
                      viscosity=2.0)
    mom = (r.h * r.u_bar).sum("x").values
    m = r.mass.values
    print(f"viscous: max |P(t)-P(0)|/P(0) = {np.max(np.abs(mom - mom[0])) / mom[0]:.2e}, "
          f"max |M(t)-M(0)|/M(0) = {np.max(np.abs(m - m[0])) / m[0]:.2e}")


if __name__ == "__main__":
    mass_conservation()
    steady_and_uniform_limit()
    dam_break()
    against_tilupy()
    viscous_stress()
