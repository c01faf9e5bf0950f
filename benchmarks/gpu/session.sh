#!/usr/bin/env bash
# Several parts of run.sh in one device call, each under its own time limit, packed for the trip back: the device
# returns at most 8 files, 2 folders down, so everything goes into $OUT/session.tgz (logs, figures, run folders without
# checkpoints) and the figures also into $OUT/session.md.
#
#   bash benchmarks/gpu/session.sh ppo-brax=ant:240 seeds:150      # PART[=ARG]:SECONDS ...
#
# A part that reaches its limit gets SIGTERM, which canter train answers by checkpointing and stopping cleanly; its
# figures are then summarized from what it wrote. A part still running KILL_AFTER seconds (60) past its limit is
# killed.
#
# SESSION_SECONDS (optional): the device call's timeout_s. A part whose limit and KILL_AFTER do not fit in what is
# left of it (less a margin for the packing) gets a shorter limit, or is skipped when less than a minute is left:
# a device call that is killed brings back only session.log, and none of the part's run folders.
set -uo pipefail
cd "$(dirname "$0")/../.."
began=$(date +%s)
PY=${PYTHON:-python3} # the interpreter run.sh runs the parts with
# shellcheck source=benchmarks/gpu/carried.sh
source benchmarks/gpu/carried.sh # the cd above put us in the repository root
KILL_AFTER=${KILL_AFTER:-60}
PACKING=20 # seconds for the last summary and tar
final=${OUT:-benchmarks/gpu/out}
mkdir -p "$final"
# Everything this call prints also goes straight to $OUT, so a call the device stops before its packing still
# brings back its log.
exec > >(
    trap '' TERM
    exec tee -a "$final/session.log"
) 2>&1
# At exit, end tee's input and wait for it: bash does not wait for a process substitution, and the log's last lines
# would be lost to a device call that returns as soon as this exits.
tee_pid=$!
trap 'exec >&- 2>&-; wait "$tee_pid"' EXIT
work=$(mktemp -d /tmp/canter-gpu.XXXX)
if compgen -G ".whl/*.whl" >/dev/null; then
    # A wheel that does not install would fail every part at its first import: stop before the parts.
    if ! install_carried_wheels; then
        echo "session.sh: the wheels in .whl/ did not install (above); run benchmarks/gpu/wheels.sh again here"
        exit 1
    fi
    export PYTHONPATH=/tmp/site:$PWD/src
fi
export CANTER_GPU_INSTALL=0 PYTHONUNBUFFERED=1
for item in "$@"; do
    spec=${item%:*}
    limit=${item##*:}
    part=${spec%%=*}
    arg=()
    [ "$spec" != "$part" ] && arg=("${spec#*=}")
    if [ -n "${SESSION_SECONDS:-}" ]; then
        left=$((SESSION_SECONDS - ($(date +%s) - began) - KILL_AFTER - PACKING))
        if [ "$left" -lt 60 ]; then
            echo "== $part skipped: ${left} s left of SESSION_SECONDS=$SESSION_SECONDS after the time it needs to stop"
            continue
        fi
        if [ "$limit" -gt "$left" ]; then
            echo "== $part: limit ${limit} s cut to ${left} s to end within SESSION_SECONDS=$SESSION_SECONDS"
            limit=$left
        fi
    fi
    echo "== $part ${arg[*]} (limit ${limit} s, $(date -u +%T))"
    OUT=$work timeout --kill-after="$KILL_AFTER" "$limit" bash benchmarks/gpu/run.sh "$part" "${arg[@]}"
    status=$?
    echo "== $part exit $status ($(date -u +%T))"
    if [ $status -ne 0 ]; then
        find "$work/runs" -type d -name checkpoints -prune -exec rm -rf {} + 2>/dev/null
        "$PY" benchmarks/gpu/summarize.py "$part" "$work" || true
    fi
    # Packed after every part, so a call cut short still brings back the parts that finished.
    cat "$work"/*.md >"$final/session.md" 2>/dev/null
    tar czf "$final/session.tgz" -C "$work" .
done
ls -la "$final"
