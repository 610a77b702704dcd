#!/usr/bin/env bash
# A single-node Slurm on this machine, to try and test the campaign's Slurm profile
# (profiles/slurm) without a real cluster.  Needs root and Debian/Ubuntu packages.
#
#   bash workflow/cluster/local-slurm.sh install   # apt-get install slurm-wlm munge (once)
#   bash workflow/cluster/local-slurm.sh start     # write slurm.conf, start munged, slurmctld, slurmd
#   bash workflow/cluster/local-slurm.sh status    # sinfo; exit 0 when the node is up
#   bash workflow/cluster/local-slurm.sh stop      # stop the three daemons again
#
# Every command is idempotent: `start` on a running cluster only checks it, `stop` on a
# stopped one does nothing.  No systemd is needed: the daemons are started directly.
# The cluster: one node (this host) with all its CPUs (GRANFLOW_SLURM_CPUS overrides) and the
# memory slurmd detects, one partition `debug` (default, no time limit unless
# GRANFLOW_SLURM_MAXTIME is set, e.g. 60 minutes), ProctrackType=proctrack/linuxproc,
# TaskPlugin=task/none and **no accounting** (AccountingStorageType=accounting_storage/none):
# the profile then polls job states with squeue (see granflow.campaign.cluster).
set -euo pipefail

CONF_DIR=/etc/slurm
CONF=$CONF_DIR/slurm.conf
MARK="# granflow local single-node Slurm (workflow/cluster/local-slurm.sh)"
STATE=/var/spool/slurmctld
SPOOL=/var/spool/slurmd
LOGDIR=/var/log/slurm
RUNDIR=/run/slurm

die() { echo "local-slurm: $*" >&2; exit 1; }
need_root() { [ "$(id -u)" = 0 ] || die "must run as root (it writes $CONF and starts daemons)"; }
alive() { [ -f "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }

install() {
  need_root
  if command -v slurmctld >/dev/null && command -v slurmd >/dev/null && command -v munged >/dev/null; then
    echo "local-slurm: slurm-wlm and munge already installed ($(slurmctld -V))"
    return
  fi
  command -v apt-get >/dev/null || die "apt-get not found: install slurm-wlm and munge with your package manager"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge
}

write_conf() {
  local host cpus mem maxtime
  host=$(hostname -s)
  cpus=${GRANFLOW_SLURM_CPUS:-$(nproc)}
  # the memory slurmd sees (a node configured with more is drained)
  mem=$(slurmd -C 2>/dev/null | sed -n 's/.*RealMemory=\([0-9]*\).*/\1/p' | head -1)
  mem=${mem:-1000}
  maxtime=${GRANFLOW_SLURM_MAXTIME:-INFINITE}
  mkdir -p "$CONF_DIR"
  if [ -f "$CONF" ] && ! head -1 "$CONF" | grep -qF "$MARK"; then
    die "$CONF exists and was not written by this script; not touching it"
  fi
  local tmp
  tmp=$(mktemp)
  cat > "$tmp" <<EOF
$MARK
ClusterName=granflow-local
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=$STATE
SlurmdSpoolDir=$SPOOL
SlurmctldPidFile=$RUNDIR/slurmctld.pid
SlurmdPidFile=$RUNDIR/slurmd.pid
SlurmctldLogFile=$LOGDIR/slurmctld.log
SlurmdLogFile=$LOGDIR/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MpiDefault=none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
# completed jobs stay visible to squeue for 5 minutes (the profile polls squeue)
MinJobAge=300
SlurmctldTimeout=30
SlurmdTimeout=30
NodeName=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=$maxtime State=UP
EOF
  if [ -f "$CONF" ] && cmp -s "$tmp" "$CONF"; then
    rm -f "$tmp"
    return 1   # unchanged
  fi
  mv "$tmp" "$CONF"
  chmod 644 "$CONF"
  echo "local-slurm: wrote $CONF ($host, CPUs=$cpus, RealMemory=$mem MB, MaxTime=$maxtime)"
  return 0
}

start() {
  need_root
  command -v slurmctld >/dev/null || die "Slurm is not installed: run '$0 install' first"
  mkdir -p "$STATE" "$SPOOL" "$LOGDIR" "$RUNDIR" /run/munge /var/log/munge /var/lib/munge
  chown munge:munge /run/munge /var/log/munge /var/lib/munge 2>/dev/null || true
  if [ ! -s /etc/munge/munge.key ]; then
    if command -v mungekey >/dev/null; then mungekey --create --force; else create-munge-key -f; fi
    chown munge:munge /etc/munge/munge.key
    chmod 400 /etc/munge/munge.key
  fi
  local changed=0
  if write_conf; then changed=1; fi
  if alive /run/munge/munged.pid; then
    echo "local-slurm: munged running"
  else
    # munged refuses to start as root unless forced; run it as the munge user
    su -s /bin/sh munge -c "munged --pid-file=/run/munge/munged.pid" \
      || munged --force --pid-file=/run/munge/munged.pid
    echo "local-slurm: started munged"
  fi
  if alive $RUNDIR/slurmctld.pid; then
    if [ $changed = 1 ]; then scontrol reconfigure; echo "local-slurm: slurmctld reconfigured"; fi
    echo "local-slurm: slurmctld running"
  else
    slurmctld
    echo "local-slurm: started slurmctld"
  fi
  if alive $RUNDIR/slurmd.pid; then
    echo "local-slurm: slurmd running"
  else
    slurmd
    echo "local-slurm: started slurmd"
  fi
  # wait for the node to accept jobs
  local i state
  for i in $(seq 1 60); do
    state=$(sinfo -h -N -o "%T" 2>/dev/null | head -1 || true)
    case "$state" in
      idle*|mixed*|allocated*) echo "local-slurm: node $(hostname -s) is $state"; return 0 ;;
      down*|drain*)
        scontrol update NodeName="$(hostname -s)" State=RESUME >/dev/null 2>&1 || true ;;
    esac
    sleep 1
  done
  die "the node did not come up within 60 s (state '$state'); see $LOGDIR/slurmctld.log and slurmd.log"
}

stop_one() {
  local name=$1 pidfile=$2 i
  if alive "$pidfile"; then
    kill "$(cat "$pidfile")"
    for i in $(seq 1 20); do alive "$pidfile" || break; sleep 0.5; done
    echo "local-slurm: stopped $name"
  else
    echo "local-slurm: $name not running"
  fi
}

stop() {
  need_root
  stop_one slurmd $RUNDIR/slurmd.pid
  stop_one slurmctld $RUNDIR/slurmctld.pid
  stop_one munged /run/munge/munged.pid
}

status() {
  if alive $RUNDIR/slurmctld.pid && alive $RUNDIR/slurmd.pid && sinfo -h >/dev/null 2>&1; then
    sinfo
    return 0
  fi
  echo "local-slurm: not running"
  return 1
}

case "${1:-}" in
  install) install ;;
  start) start ;;
  stop) stop ;;
  status) status ;;
  restart) stop; start ;;
  *) echo "usage: $0 install|start|status|stop|restart" >&2; exit 2 ;;
esac
