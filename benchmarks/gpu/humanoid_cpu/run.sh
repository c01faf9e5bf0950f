#!/usr/bin/env bash
# The GPU `humanoid` part's PPO settings (benchmarks/gpu/run.sh humanoid: `--preset humanoid`, 2048 envs, seed 0)
# trained on C MuJoCo (EnvPool, the XML's own solver) on the CPU, evaluated every 2M steps: how many env steps
# these settings need on Humanoid-v5, whatever the hardware. Hours on 2 cores; --max-minutes stops it with a
# checkpoint, and `canter train --resume RUN --max-minutes M` carries it on.
# Each variable undoes one of the preset's changes to Brax's humanoid settings: REWARD_SCALE the reward scaling
# (Brax's 0.1 in both); LOG_STD_INIT the policy's initial log std (Brax's 0; the preset's -0.916 is Brax's noise
# relative to Humanoid-v5's [-0.4, 0.4] action range); HIDDEN the policy's hidden layers (Brax's 32,32,32,32);
# N_STEPS and MINIBATCH the steps per env of each iteration and the minibatch size (Brax's 160 and 10240).
# The runs in recipes.md trained with the brax preset and these as `--set` flags, which give the same config
# (tests/test_presets.py): REWARD_SCALE=1 LOG_STD_INIT=0 HIDDEN=32,32,32,32 N_STEPS=160 MINIBATCH=10240 (run/,
# before env.reward_scale existed); the same with REWARD_SCALE=0.1; HIDDEN=32,32,32,32 N_STEPS=160
# MINIBATCH=10240; N_STEPS=160 MINIBATCH=10240; and the preset as it is.
#
#   [REWARD_SCALE=R] [LOG_STD_INIT=L] [HIDDEN=H,H,...] [N_STEPS=N] [MINIBATCH=M] \
#       bash benchmarks/gpu/humanoid_cpu/run.sh [OUT_DIR] [MINUTES] [--set K=V ...]
set -euo pipefail
cd "$(dirname "$0")/../../.."
undo=()
[ -n "${REWARD_SCALE:-}" ] && undo+=(--set env.reward_scale="$REWARD_SCALE")
[ -n "${LOG_STD_INIT:-}" ] && undo+=(--set net.log_std_init="$LOG_STD_INIT")
[ -n "${HIDDEN:-}" ] && undo+=(--set net.hidden="$HIDDEN")
[ -n "${N_STEPS:-}" ] && undo+=(--set ppo.n_steps="$N_STEPS")
[ -n "${MINIBATCH:-}" ] && undo+=(--set ppo.minibatch_size="$MINIBATCH")
exec "${PYTHON:-.venv/bin/python}" -m canter.cli train Humanoid-v5 --preset humanoid --seed 0 --set env.num_envs=2048 \
    "${undo[@]}" --total-steps 2e7 --eval-every 2e6 --eval-episodes 10 --max-minutes "${2:-95}" \
    --out-dir "${1:-runs/humanoid-cpu}" "${@:3}"
