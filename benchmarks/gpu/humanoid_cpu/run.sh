#!/usr/bin/env bash
# The GPU `humanoid` part's PPO settings (benchmarks/gpu/run.sh humanoid: the brax preset with its humanoid table,
# 2048 envs, seed 0) trained on C MuJoCo (EnvPool, the XML's own solver) on the CPU, evaluated every 2M steps:
# how many env steps these settings need on Humanoid-v5, whatever the hardware. Hours on 2 cores; --max-minutes
# stops it with a checkpoint, and `canter train --resume RUN` carries it on. REWARD_SCALE is the table's reward
# scaling, Brax's 0.1 by default; LOG_STD_INIT the policy's initial log std, by default Brax's noise relative to the
# action range (std 0.4 on Humanoid-v5's [-0.4, 0.4]); HIDDEN the policy's hidden layers (Brax's are 32,32,32,32);
# N_STEPS and MINIBATCH the steps per env of each iteration and the minibatch size (Brax's are 160 and 10240).
# The runs in recipes.md trained with REWARD_SCALE=1 LOG_STD_INIT=0 HIDDEN=32,32,32,32 N_STEPS=160 MINIBATCH=10240
# (run/, before env.reward_scale existed); the same with REWARD_SCALE=0.1; HIDDEN=32,32,32,32 N_STEPS=160
# MINIBATCH=10240; N_STEPS=160 MINIBATCH=10240; and the defaults.
#
#   [REWARD_SCALE=0.1] [LOG_STD_INIT=-0.916] [HIDDEN=256,256,256] [N_STEPS=80] [MINIBATCH=5120] \
#       bash benchmarks/gpu/humanoid_cpu/run.sh [OUT_DIR] [MINUTES] [--set K=V ...]
set -euo pipefail
cd "$(dirname "$0")/../../.."
exec "${PYTHON:-.venv/bin/python}" -m canter.cli train Humanoid-v5 --preset brax --seed 0 --set env.num_envs=2048 \
    --set ppo.n_steps="${N_STEPS:-80}" --set ppo.minibatch_size="${MINIBATCH:-5120}" --set ppo.epochs=8 --set ppo.ent_coef=1e-3 \
    --set env.reward_scale="${REWARD_SCALE:-0.1}" --set net.log_std_init="${LOG_STD_INIT:--0.916}" \
    --set net.hidden="${HIDDEN:-256,256,256}" \
    --total-steps 2e7 --eval-every 2e6 --eval-episodes 10 --max-minutes "${2:-95}" --out-dir "${1:-runs/humanoid-cpu}" "${@:3}"
