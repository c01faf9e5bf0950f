#!/usr/bin/env bash
# One command for the PPO speed benchmark: makes the Stable-Baselines3 venv (benchmarks/.sb3-venv) from
# requirements-sb3.txt if it is missing or out of date, then runs run.py with canter's interpreter.
# All arguments go to run.py:  bash benchmarks/ppo_speed/run.sh [--total-steps 1e6] [--seeds 0] [--skip-sb3]
#                                                              [--only canter-cleanrl,canter-fast,sb3]
# Environment: PYTHON (python3, to make the SB3 venv), SB3_VENV, CANTER_PYTHON (.venv/bin/python).
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"
python="${PYTHON:-python3}"
sb3_venv="${SB3_VENV:-$root/benchmarks/.sb3-venv}"
canter_python="${CANTER_PYTHON:-$root/.venv/bin/python}"
requirements="$here/requirements-sb3.txt"

if [[ ! -x "$canter_python" ]]; then
    echo "run.sh: no canter venv at $canter_python; run 'make install' in $root first" >&2
    exit 2
fi

# Is SB3 going to run? Not with --skip-sb3, nor with an --only list that leaves it out.
need_sb3=1
args=("$@")
for ((i = 0; i < ${#args[@]}; i++)); do
    case "${args[i]}" in
        --skip-sb3) need_sb3=0 ;;
        --only) [[ "${args[i + 1]:-}" == *sb3* ]] || need_sb3=0 ;;
        --only=*) [[ "${args[i]}" == *sb3* ]] || need_sb3=0 ;;
        -h|--help) need_sb3=0 ;;
    esac
done

if [[ $need_sb3 == 1 ]] && ! cmp -s "$requirements" "$sb3_venv/.requirements-sb3.txt"; then
    echo "run.sh: making the SB3 venv in $sb3_venv" >&2
    [[ -x "$sb3_venv/bin/python" ]] || "$python" -m venv "$sb3_venv"
    # torch first and on its own, so that pip settles on the CPU build where one is available to it.
    "$sb3_venv/bin/python" -m pip install -q "$(grep -E '^torch==' "$requirements")"
    "$sb3_venv/bin/python" -m pip install -q -r "$requirements"
    cp "$requirements" "$sb3_venv/.requirements-sb3.txt"
fi

exec "$canter_python" "$here/run.py" --sb3-python "$sb3_venv/bin/python" "$@"
