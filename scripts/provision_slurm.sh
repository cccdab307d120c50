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

ns_pids() { ip netns pids "$NS" 2>/dev/null || true; }

# Cancel every job and let the steps finish (a step whose slurmd is gone hangs for ever and
# is recovered as running by the next slurmctld), then end every process in the namespace:
# daemons, job steps, workers; nothing outside it.
stop() {
  if ip netns list 2>/dev/null | grep -qw "$NS"; then
    in_ns scancel --full --user=root 2>/dev/null || true
    for _ in $(seq 40); do
      [ -z "$(in_ns squeue -h -o %i 2>/dev/null)" ] && break
      sleep 0.25
    done
    pids=$(ns_pids)
    if [ -n "$pids" ]; then
      # shellcheck disable=SC2086
      kill $pids 2>/dev/null || true
      sleep 1
      pids=$(ns_pids)
      # shellcheck disable=SC2086
      [ -z "$pids" ] || kill -9 $pids 2>/dev/null || true
    fi
    ip netns del "$NS" 2>/dev/null || true
  fi
  rm -f /run/slurmd.pid /run/slurmctld.pid
}

[ "$(id -u)" = 0 ] || cannot "needs root (apt-get, daemons, network namespaces)"
if [ "${1:-start}" = stop ]; then stop; exit 0; fi

if ip netns list 2>/dev/null | grep -qw "$NS" && [ -s /run/slurmctld.pid ] \
   && in_ns sinfo -h -o %t 2>/dev/null | grep -qE 'idle|mix|alloc'; then
  exit 0  # already running
fi

# Debian's SLURM, munge, ip and nsenter (nothing is installed when they are all there)
installed=$("$(dirname "$0")/install_debian.sh" slurm 2>&1) \
  || cannot "$(printf '%s\n' "$installed" | tail -n 1)"

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

# this machine as slurmd sees it (CPUs, sockets, cores, memory), named localhost
node=$(slurmd -C | head -1 | sed -E 's/^NodeName=[^ ]+ //; s/ UpTime=.*//')
rm -rf "$STATE/slurmctld" "$STATE/slurmd"  # no jobs recovered from an earlier start
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
NodeName=localhost NodeAddr=127.0.0.1 $node State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONFIG

in_ns slurmctld || cannot "slurmctld did not start (see $LOGS/slurmctld.log)"
in_ns slurmd -N localhost || cannot "slurmd did not start (see $LOGS/slurmd.log)"
for _ in $(seq 120); do
  if in_ns sinfo -h -o %t 2>/dev/null | grep -qE 'idle|mix|alloc'; then exit 0; fi
  sleep 0.5
done
cannot "the node did not become idle in 60 s (see $LOGS/slurmctld.log, $LOGS/slurmd.log)"
