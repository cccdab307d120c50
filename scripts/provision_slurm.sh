#!/usr/bin/env bash
# A single-node SLURM (Debian's slurmctld, slurmd, slurm-client, munge) for the tests in
# tests/cluster/test_slurm.py, inside a private network namespace that has only loopback, so
# its daemons and Dask processes are unreachable from outside and collide with no one.
#
#   scripts/provision_slurm.sh          install if needed, start; quick when already running
#   scripts/provision_slurm.sh stop     stop the daemons and remove the namespace
#   nsenter --net=/run/netns/boxslurm sinfo    then run SLURM (and Dask) commands inside it
#
# Needs root (apt-get, daemons, network namespaces). Exit codes: 0 running, 3 cannot provide
# SLURM on this machine (the reason is the last line of stderr).
set -euo pipefail

NS=${BOX_SLURM_NETNS:-boxslurm}
CONF=/etc/slurm/slurm.conf
LOGS=/var/log/slurm
STATE=/var/lib/slurm

cannot() { echo "cannot provide SLURM: $*" >&2; exit 3; }
in_ns() { nsenter --net="/run/netns/$NS" "$@"; }  # not ip netns exec: it remounts /sys

stop() {
  for pidfile in /run/slurmd.pid /run/slurmctld.pid; do
    if [ -s "$pidfile" ]; then kill "$(cat "$pidfile")" 2>/dev/null || true; rm -f "$pidfile"; fi
  done
  ip netns del "$NS" 2>/dev/null || true
}

[ "$(id -u)" = 0 ] || cannot "needs root (apt-get, daemons, network namespaces)"
if [ "${1:-start}" = stop ]; then stop; exit 0; fi

if ip netns list 2>/dev/null | grep -qw "$NS" && [ -s /run/slurmctld.pid ] \
   && in_ns sinfo -h -o %t 2>/dev/null | grep -qE 'idle|mix|alloc'; then
  exit 0  # already running
fi

if ! command -v slurmctld >/dev/null || ! command -v slurmd >/dev/null \
   || ! command -v sbatch >/dev/null || ! command -v munged >/dev/null \
   || ! command -v ip >/dev/null || ! command -v nsenter >/dev/null; then
  command -v apt-get >/dev/null || cannot "no apt-get to install Debian's SLURM packages"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq >/dev/null || cannot "apt-get update failed"
  apt-get install -y -qq --no-install-recommends slurmctld slurmd slurm-client munge \
    iproute2 util-linux >/dev/null \
    || cannot "apt-get install slurmctld slurmd slurm-client munge iproute2 failed"
fi

stop  # a half-started earlier attempt
ip netns add "$NS" || cannot "ip netns add failed (no network namespaces here)"
in_ns ip link set lo up
in_ns ip addr add 127.0.0.2/8 dev lo 2>/dev/null || true  # getaddrinfo wants a 2nd address

# munge authenticates SLURM's messages; its socket is a file, shared with the namespace.
if [ ! -s /etc/munge/munge.key ]; then
  mungekey --create --keyfile /etc/munge/munge.key 2>/dev/null \
    || dd if=/dev/urandom of=/etc/munge/munge.key bs=1024 count=1 status=none
  chown munge:munge /etc/munge/munge.key; chmod 400 /etc/munge/munge.key
fi
if ! munge -n </dev/null >/dev/null 2>&1; then
  mkdir -p /run/munge && chown munge:munge /run/munge
  runuser -u munge -- /usr/sbin/munged || cannot "munged did not start"
fi

cpus=$(nproc)
memory_mb=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 256 ))
mkdir -p "$LOGS" "$STATE/slurmctld" "$STATE/slurmd" /etc/slurm
cat > "$CONF" <<CONFIG
# Written by scripts/provision_slurm.sh: one node, loopback only, for tests.
ClusterName=box
SlurmctldHost=localhost(127.0.0.1)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=$STATE/slurmctld
SlurmdSpoolDir=$STATE/slurmd
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
SlurmctldLogFile=$LOGS/slurmctld.log
SlurmdLogFile=$LOGS/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MpiDefault=none
ReturnToService=2
SlurmdTimeout=30
NodeName=localhost NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$memory_mb State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONFIG

in_ns slurmctld || cannot "slurmctld did not start (see $LOGS/slurmctld.log)"
in_ns slurmd -N localhost || cannot "slurmd did not start (see $LOGS/slurmd.log)"
for _ in $(seq 120); do
  if in_ns sinfo -h -o %t 2>/dev/null | grep -qE 'idle|mix|alloc'; then exit 0; fi
  sleep 0.5
done
cannot "the node did not become idle in 60 s (see $LOGS/slurmctld.log, $LOGS/slurmd.log)"
