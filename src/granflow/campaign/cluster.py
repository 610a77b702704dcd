"""Cluster resources of the campaign workflow: per-rule requests, Slurm limits, status command.

The workflow's rules take their Slurm resources (partition, account, CPUs per task, run time in
minutes, memory) from the campaign configuration's ``cluster`` section (defaults in
:data:`DEFAULT_RESOURCES`).  When the workflow runs with the Slurm executor, every request is
checked against what the chosen partition can give (``scontrol show partition``, ``sinfo``):

* CPUs per task above the largest node of the partition are **capped** (a simulation gives the
  same numbers for any number of threads, so capping only costs time);
* a run time above the partition's ``MaxTime`` is capped as well (a simulation killed at the
  limit resumes from its checkpoint when it is resubmitted: the profile sets ``retries``);
* memory above the largest node is **refused**: it cannot be capped safely.

``cluster.over_limit: refuse`` refuses every impossible request instead of capping it.  Either
way the message names the rule, the request and the limit, before any job is submitted -- a job
that asks for more than the cluster has otherwise pends forever without an error.

:func:`slurm_status_command` picks how the Slurm executor polls job states: ``sacct`` when the
cluster keeps accounting (it also reports why a job failed), ``squeue`` when it does not (the
plugin's default ``sacct`` fails there and the workflow waits forever).  The project's
single-node test cluster (``workflow/cluster/local-slurm.sh``) runs without accounting.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from dataclasses import dataclass, field

#: Per-rule requests: cpus_per_task (simulate: numerics.threads), runtime (minutes), mem_mb.
DEFAULT_RESOURCES = {
    "base": {"cpus_per_task": 1, "runtime": 60, "mem_mb": 2000},
    "simulate": {"runtime": 2880, "mem_mb": 4000},
    "row": {"cpus_per_task": 1, "runtime": 15, "mem_mb": 2000},
    "collect": {"cpus_per_task": 1, "runtime": 30, "mem_mb": 4000},
    "fit": {"cpus_per_task": 1, "runtime": 60, "mem_mb": 4000},
    "library": {"cpus_per_task": 1, "runtime": 15, "mem_mb": 2000},
    "report": {"cpus_per_task": 1, "runtime": 60, "mem_mb": 8000},
}
RESOURCE_KEYS = ("cpus_per_task", "runtime", "mem_mb")
OVER_LIMIT = ("cap", "refuse")


class ClusterRequestError(ValueError):
    """A rule asks for more than the cluster can give (raised before any job is submitted)."""


@dataclass(frozen=True)
class PartitionLimits:
    """What one job can get on a partition: CPUs and memory of its largest node, MaxTime."""

    partition: str
    max_cpus: int | None          # CPUs of the largest node (None: unknown)
    max_mem_mb: int | None        # memory of the largest node in MB (None: unknown)
    max_runtime: int | None       # MaxTime in minutes (None: unlimited/unknown)


def _run(cmd: list[str]) -> str | None:
    if shutil.which(cmd[0]) is None:
        return None
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return None
    return proc.stdout if proc.returncode == 0 else None


def parse_slurm_time(text: str) -> int | None:
    """Minutes of a Slurm time limit ('UNLIMITED', 'MM', 'HH:MM:SS', 'D-HH:MM[:SS]'); None if
    unlimited."""
    text = text.strip()
    if not text or text.upper() in ("UNLIMITED", "INFINITE", "NONE", "N/A"):
        return None
    days = 0
    if "-" in text:
        d, text = text.split("-", 1)
        days = int(d)
    parts = [int(p) for p in text.split(":")]
    if days and len(parts) == 1:
        h, m, s = parts[0], 0, 0
    elif days and len(parts) == 2:
        h, m, s = parts[0], parts[1], 0
    elif len(parts) == 1:
        h, m, s = 0, parts[0], 0
    elif len(parts) == 2:
        h, m, s = 0, parts[0], parts[1]
    else:
        h, m, s = parts[-3], parts[-2], parts[-1]
    return days * 1440 + h * 60 + m + (1 if s else 0)


def default_partition() -> str | None:
    """The cluster's default partition (marked '*' by sinfo), or None."""
    out = _run(["sinfo", "-h", "-o", "%P"])
    if out is None:
        return None
    for name in out.split():
        if name.endswith("*"):
            return name[:-1]
    return None


def slurm_partition_limits(partition: str | None = None) -> PartitionLimits | None:
    """Limits of ``partition`` (default: the cluster's default partition); None without Slurm."""
    partition = partition or default_partition()
    if not partition:
        return None
    show = _run(["scontrol", "show", "partition", partition])
    if show is None:
        raise ClusterRequestError(
            f"Slurm partition {partition!r} does not exist (scontrol show partition "
            f"{partition} failed); set cluster.partition to one of: "
            f"{(_run(['sinfo', '-h', '-o', '%R']) or '?').split()}")
    fields = dict(item.split("=", 1) for item in show.split() if "=" in item)
    max_runtime = parse_slurm_time(fields.get("MaxTime", "UNLIMITED"))
    per_node_cap = fields.get("MaxCPUsPerNode", "UNLIMITED")
    nodes = _run(["sinfo", "-h", "-N", "-p", partition, "-o", "%c %m"]) or ""
    cpus, mems = [], []
    for line in nodes.splitlines():
        parts = line.split()
        if len(parts) >= 2:
            cpus.append(int(re.sub(r"\D", "", parts[0]) or 0))
            mems.append(int(re.sub(r"\D", "", parts[1]) or 0))
    max_cpus = max(cpus) if cpus else None
    if per_node_cap.isdigit() and max_cpus is not None:
        max_cpus = min(max_cpus, int(per_node_cap))
    return PartitionLimits(partition, max_cpus, max(mems) if mems else None, max_runtime)


def slurm_accounting_enabled() -> bool:
    """True if the cluster keeps job accounting (``sacct`` can answer)."""
    conf = _run(["scontrol", "show", "config"])
    if conf is not None:
        m = re.search(r"^AccountingStorageType\s*=\s*(\S+)", conf, re.M)
        if m and m.group(1).endswith("/none"):
            return False
    return _run(["sacct", "-n", "-X", "-o", "JobID", "-S", "now"]) is not None


def slurm_status_command() -> str:
    """'sacct' where accounting answers, else 'squeue' (used by profiles/slurm)."""
    return "sacct" if slurm_accounting_enabled() else "squeue"


@dataclass
class ClusterPlan:
    """Per-rule resources from the configuration, fitted to the Slurm partition on first use."""

    config: dict
    threads: int = 1
    _limits: PartitionLimits | None = None
    _checked: bool = False
    messages: list = field(default_factory=list)
    _fitted: dict = field(default_factory=dict)

    @property
    def section(self) -> dict:
        return self.config.get("cluster") or {}

    @property
    def partition(self) -> str | None:
        return self.section.get("partition")

    @property
    def account(self) -> str | None:
        return self.section.get("account")

    def requested(self, rule: str) -> dict:
        """The configured request of ``rule`` (defaults, overridden by cluster.resources)."""
        req = dict(DEFAULT_RESOURCES.get(rule, {"cpus_per_task": 1, "runtime": 30,
                                                "mem_mb": 2000}))
        if rule == "simulate":
            req["cpus_per_task"] = self.threads
        req.update((self.section.get("resources") or {}).get(rule) or {})
        return req

    def limits(self) -> PartitionLimits | None:
        if not self._checked:
            self._limits = slurm_partition_limits(self.partition)
            self._checked = True
        return self._limits

    def fitted(self, rule: str, on_slurm: bool) -> dict:
        """The request of ``rule``, capped/refused against the partition when ``on_slurm``."""
        if not on_slurm:
            return self.requested(rule)
        if rule not in self._fitted:
            fitted, msgs = fit_request(rule, self.requested(rule), self.limits(),
                                       self.section.get("over_limit", "cap"))
            self._fitted[rule] = fitted
            self.messages += msgs
        return self._fitted[rule]


def fit_request(rule: str, request: dict, limits: PartitionLimits | None,
                over_limit: str = "cap") -> tuple[dict, list[str]]:
    """Cap (or refuse) ``request`` against ``limits``; returns (fitted request, messages).

    Raises :class:`ClusterRequestError` naming the rule, the request and the limit for memory
    above the largest node, and for anything above a limit when ``over_limit == 'refuse'``.
    """
    if over_limit not in OVER_LIMIT:
        raise ClusterRequestError(f"cluster.over_limit = {over_limit!r}: must be one of "
                                  f"{list(OVER_LIMIT)}")
    out, msgs = dict(request), []
    if limits is None:
        return out, msgs
    where = f"partition {limits.partition!r}"
    checks = (("cpus_per_task", limits.max_cpus, "CPUs on its largest node", True),
              ("runtime", limits.max_runtime, "minutes MaxTime", True),
              ("mem_mb", limits.max_mem_mb, "MB memory on its largest node", False))
    for key, limit, what, cappable in checks:
        value = out.get(key)
        if value is None or limit is None or value <= limit:
            continue
        text = (f"rule {rule}: {key} = {value} exceeds what {where} can give ({limit} {what})")
        if over_limit == "refuse" or not cappable:
            raise ClusterRequestError(
                text + f"; a job asking for it would pend forever. Lower "
                f"cluster.resources.{rule}.{key} (or numerics.threads for simulate) or choose "
                f"another partition with cluster.partition")
        out[key] = limit
        msgs.append(text + f": capped to {limit}")
    return out, msgs


def in_slurm_job() -> bool:
    """True inside a Slurm job (the job step of a workflow job)."""
    return "SLURM_JOB_ID" in os.environ
