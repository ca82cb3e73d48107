#!/usr/bin/env bash
# Stop the test cluster of .ci/slurm-up.sh: cancel every job left, then slurmd, slurmctld and
# munged (by their pid files, each waited for at most 10 s). Safe to call when nothing runs.
set -uo pipefail

if [ "$(id -u)" = 0 ]; then
    as_root=()
else
    as_root=(sudo)
fi

if command -v scancel >/dev/null; then
    timeout 10 "${as_root[@]}" scancel --full --quiet --user="$(id -un)" 2>/dev/null || true
fi

stop() {
    local name="$1" pidfile="$2" pid
    [ -f "$pidfile" ] || return 0
    pid="$(cat "$pidfile")"
    if "${as_root[@]}" kill -0 "$pid" 2>/dev/null; then
        echo "slurm-down: stopping $name ($pid)"
        "${as_root[@]}" kill -TERM "$pid" 2>/dev/null || true
        for _ in $(seq 20); do
            "${as_root[@]}" kill -0 "$pid" 2>/dev/null || break
            sleep 0.5
        done
        "${as_root[@]}" kill -0 "$pid" 2>/dev/null && "${as_root[@]}" kill -KILL "$pid" 2>/dev/null
    fi
    "${as_root[@]}" rm -f "$pidfile"
}

stop slurmd /run/slurmd.pid
stop slurmctld /run/slurmctld.pid
stop munged /run/munge/munged.pid
exit 0
