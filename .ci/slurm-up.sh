#!/usr/bin/env bash
# A single-node Slurm cluster on this machine, for tests/test_slurm.py (docs/cluster.md):
#   1. Debian's slurm-wlm and munge, installed if missing (apt, non-interactive; root or sudo);
#   2. /etc/slurm/slurm.conf: one node on 127.0.0.1 with this machine's CPUs and memory
#      (`slurmd -C`), proctrack/linuxproc, task/none, no cgroups, no accounting, MinJobAge 1 h
#      (snakemake-executor-plugin-slurm's squeue status needs finished jobs to stay visible);
#   3. the munge key (if missing), then munged, slurmctld and slurmd started by hand (no systemd);
#   4. waits (at most SLURM_UP_WAIT_S, 60 s) until `sinfo` shows the node idle.
# Idempotent: with the cluster up (slurmctld answers, the node is usable) it does nothing.
# The config must be /etc/slurm/slurm.conf: the job-step side ignores SLURM_CONF.
# Stop it with .ci/slurm-down.sh. Logs: /var/log/slurm/.
set -euo pipefail

WAIT_S="${SLURM_UP_WAIT_S:-60}"
CONF=/etc/slurm/slurm.conf
LOGDIR=/var/log/slurm

if [ "$(id -u)" = 0 ]; then
    as_root=()
else
    as_root=(sudo)
fi

say() { echo "slurm-up: $*"; }

node_state() {
    # state of the one node (idle, mix, alloc, down*, drain, unk ...) or empty
    timeout 10 sinfo -h -N -o '%t' 2>/dev/null | head -n 1 || true
}

usable() {
    case "$(node_state)" in
    idle | mix | alloc | comp) return 0 ;;
    *) return 1 ;;
    esac
}

if command -v sinfo >/dev/null && [ -f "$CONF" ] && timeout 10 scontrol ping 2>/dev/null | grep -q UP && usable; then
    say "cluster already up (node $(node_state)); nothing to do"
    exit 0
fi

need=()
command -v slurmctld >/dev/null || need+=(slurm-wlm)
command -v munged >/dev/null || need+=(munge)
if [ ${#need[@]} -gt 0 ]; then
    say "installing ${need[*]}"
    "${as_root[@]}" apt-get update -qq
    "${as_root[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
fi

node="$(hostname -s 2>/dev/null || echo localhost)"
[ -n "$node" ] || node=localhost
# this machine as slurmd sees it: CPUs=.. Boards=.. SocketsPerBoard=.. CoresPerSocket=..
# ThreadsPerCore=.. RealMemory=.. (first line of `slurmd -C`, without its NodeName)
hw="$(slurmd -C | head -n 1 | sed -e 's/^NodeName=[^ ]* //')"
cpus="$(sed -n 's/.*CPUs=\([0-9]*\).*/\1/p' <<<"$hw")"
[ -n "$cpus" ] || {
    say "cannot read the CPU count from 'slurmd -C': $hw"
    exit 1
}

"${as_root[@]}" mkdir -p /etc/slurm /var/spool/slurmctld /var/spool/slurmd "$LOGDIR"
tmp="$(mktemp)"
cat >"$tmp" <<EOF
# Written by .ci/slurm-up.sh: a single-node test cluster on 127.0.0.1 (docs/cluster.md).
ClusterName=rafi
SlurmctldHost=${node}(127.0.0.1)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
MpiDefault=none
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ReturnToService=2
MinJobAge=3600
KillWait=5
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
SlurmdSpoolDir=/var/spool/slurmd
StateSaveLocation=/var/spool/slurmctld
SlurmctldLogFile=${LOGDIR}/slurmctld.log
SlurmdLogFile=${LOGDIR}/slurmd.log
NodeName=${node} NodeAddr=127.0.0.1 ${hw} State=UNKNOWN
PartitionName=main Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF
"${as_root[@]}" install -m 0644 "$tmp" "$CONF"
rm -f "$tmp"

# munge: a key readable by the munge user only, then the daemon as that user
if [ ! -s /etc/munge/munge.key ]; then
    say "creating the munge key"
    "${as_root[@]}" mkdir -p /etc/munge
    "${as_root[@]}" dd if=/dev/urandom of=/etc/munge/munge.key bs=1 count=1024 status=none
fi
"${as_root[@]}" chown munge:munge /etc/munge /etc/munge/munge.key
"${as_root[@]}" chmod 0700 /etc/munge
"${as_root[@]}" chmod 0400 /etc/munge/munge.key
"${as_root[@]}" mkdir -p /run/munge /var/log/munge /var/lib/munge
"${as_root[@]}" chown munge:munge /run/munge /var/log/munge /var/lib/munge
alive() { [ -f "$1" ] && "${as_root[@]}" kill -0 "$(cat "$1")" 2>/dev/null; }
if ! alive /run/munge/munged.pid; then
    say "starting munged"
    "${as_root[@]}" runuser -u munge -- /usr/sbin/munged
fi
if ! munge -n </dev/null | unmunge >/dev/null 2>&1; then
    say "munge does not work (munge -n | unmunge failed); see /var/log/munge/munged.log"
    exit 1
fi

# slurmctld first (-c: a fresh state, no jobs or node states of an earlier cluster), then slurmd
if ! alive /run/slurmctld.pid; then
    say "starting slurmctld"
    "${as_root[@]}" /usr/sbin/slurmctld -c
fi
if ! alive /run/slurmd.pid; then
    say "starting slurmd (node ${node}, ${hw})"
    "${as_root[@]}" /usr/sbin/slurmd -N "$node"
fi

for _ in $(seq "$WAIT_S"); do
    state="$(node_state)"
    case "$state" in
    idle | mix | alloc) break ;;
    drain* | down*) "${as_root[@]}" scontrol update NodeName="$node" State=RESUME >/dev/null 2>&1 || true ;;
    esac
    sleep 1
done
if ! usable; then
    say "node ${node} not idle after ${WAIT_S} s (state: '$(node_state)'); see ${LOGDIR}/slurmctld.log and ${LOGDIR}/slurmd.log"
    tail -n 5 "$LOGDIR/slurmctld.log" "$LOGDIR/slurmd.log" 2>/dev/null || true
    exit 1
fi
say "cluster up: node ${node} $(node_state), ${cpus} CPUs"
