#!/usr/bin/env bash
# A one-node Slurm on this machine (munged, slurmctld, slurmd from a configuration in a temporary folder), for running the batch recipes of docs/many-scenes.md for real.
#
#   bash scripts/batch/slurm-local.sh             install slurm-wlm and munge if missing, start a
#                                                 cluster, run scripts/batch/shards-check.sh on it,
#                                                 stop it; exit status: the check's
#   bash scripts/batch/slurm-local.sh start DIR   start a cluster whose files all live in DIR (an
#                                                 empty or new folder); prints the SLURM_CONF to export
#   bash scripts/batch/slurm-local.sh stop DIR    stop the cluster started in DIR: exactly the
#                                                 processes its pid files name
#
# Environment: SPAR (the spar program, default build/bin/spar), MODEL, SCENES (see
# shards-check.sh). Needs root for the packages (apt-get) and runs the daemons as this user.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)

install_packages() {
  command -v slurmctld > /dev/null && command -v munged > /dev/null && return 0
  echo "slurm-local: installing slurm-wlm and munge"
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge > /dev/null
}

# A port nobody listens on, from a range the kernel does not hand out to clients.
free_port() {
  local p
  for _ in $(seq 50); do
    p=$((20000 + RANDOM % 10000))
    if ! (exec 3<> "/dev/tcp/127.0.0.1/$p") 2> /dev/null; then echo "$p"; return; fi
  done
  echo "slurm-local: no free port found" >&2; exit 1
}

start() {
  local dir=$1 node user memory
  mkdir -p "$dir" && dir=$(cd "$dir" && pwd)
  chmod 700 "$dir"
  node=$(hostname -s)
  user=$(id -un)
  memory=$(awk '/MemTotal/ {print int($2 / 1024 * 0.9)}' /proc/meminfo)
  mkdir -p "$dir/state" "$dir/spool"
  # munge: a key of its own and a socket in DIR, so a system munged (if any) is not touched.
  head -c 1024 /dev/urandom > "$dir/munge.key"
  chmod 400 "$dir/munge.key"
  munged --force --key-file="$dir/munge.key" --socket="$dir/munge.socket" --pid-file="$dir/munged.pid" \
    --log-file="$dir/munged.log" --seed-file="$dir/munged.seed"
  cat > "$dir/slurm.conf" << CONF
# slurm-local.sh: one node, $node, everything in $dir
ClusterName=sparlocal
SlurmctldHost=$node(127.0.0.1)
SlurmUser=$user
SlurmdUser=$user
SlurmctldPort=$(free_port)
SlurmdPort=$(free_port)
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$dir/munge.socket
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/slurmctld.log
SlurmdLogFile=$dir/slurmd.log
# no cgroups here: processes tracked through /proc, no task binding
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MpiDefault=none
SchedulerType=sched/backfill
# the main loop every 2 s, not 60: a requeued task whose begin time was moved to now starts at
# once, even when no other job event wakes the scheduler
SchedulerParameters=sched_interval=2,bf_interval=2
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
SlurmdParameters=config_overrides
NodeName=$node NodeAddr=127.0.0.1 CPUs=$(nproc) RealMemory=$memory State=UNKNOWN
PartitionName=local Nodes=$node Default=YES MaxTime=INFINITE State=UP
CONF
  export SLURM_CONF=$dir/slurm.conf
  slurmctld -f "$SLURM_CONF"
  slurmd -f "$SLURM_CONF" -N "$node"
  for _ in $(seq 120); do
    if sinfo -h -o %t 2> /dev/null | grep -qx idle; then
      echo "slurm-local: one node ($node, $(nproc) CPUs) up in $dir; export SLURM_CONF=$SLURM_CONF"
      return 0
    fi
    sleep 0.5
  done
  echo "slurm-local: the node did not come up in 60 s; see $dir/slurmctld.log and $dir/slurmd.log" >&2
  stop "$dir"
  return 1
}

stop() {
  local dir=$1 name pid
  for name in slurmd slurmctld munged; do
    [ -f "$dir/$name.pid" ] || continue
    pid=$(cat "$dir/$name.pid")
    # only the process this cluster started: the pid file's, still running that program
    if [ -n "$pid" ] && grep -qs "$name" "/proc/$pid/comm"; then
      kill "$pid" 2> /dev/null || true
      for _ in $(seq 100); do kill -0 "$pid" 2> /dev/null || break; sleep 0.1; done
      kill -9 "$pid" 2> /dev/null || true
    fi
    rm -f "$dir/$name.pid"
  done
}

case "${1:-check}" in
  start) install_packages; start "${2:?usage: slurm-local.sh start DIR}" ;;
  stop) stop "${2:?usage: slurm-local.sh stop DIR}" ;;
  check)
    install_packages
    cluster=$(mktemp -d /tmp/slurm-local.XXXXXX)
    trap 'stop "$cluster"; rm -rf "$cluster"' EXIT
    start "$cluster"
    export SLURM_CONF=$cluster/slurm.conf
    bash "$here/shards-check.sh"
    ;;
  *) echo "usage: slurm-local.sh [check | start DIR | stop DIR]" >&2; exit 2 ;;
esac
