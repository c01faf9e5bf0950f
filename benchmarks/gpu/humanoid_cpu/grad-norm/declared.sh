#!/usr/bin/env bash
# Declared 2026-11-28 18:50 UTC, before any run: one lever, ppo.max_grad_norm=0.5 (canter's default, and SB3's and
# CleanRL's) on top of --preset humanoid (which has Brax's max_grad_norm=1e9, no bound). Why this lever and not
# ppo.target_kl: the collapse (seed 2, approx_kl 76 in one iteration) happened inside one iteration, and canter's
# target_kl only stops the epochs after the first whose last minibatch's KL is over the target, so it bounds an
# iteration no sooner than after 32 minibatch steps; a global gradient-norm clip bounds every step.
# Seeds 2, 3, 0, 1, 4 in this order, the five-seed table's budget (8.1M steps, eval every 2M, 10 episodes).
# Rule, written now: the preset takes max_grad_norm=0.5 if, over the five seeds at 8.1M env steps,
#  (a) at least 3 of 5 seeds evaluate at 6000 or more (the unbounded preset's count), and
#  (b) the median of the best checkpoints' held-out evaluations (10 env seeds) is at least 8,060.1 (the unbounded one).
# Every finished seed is reported; with fewer than five finished, no decision is taken.
cd /work/main
for s in 2 3 0 1 4; do
  echo "# $(date -u +%H:%M) UTC: seed $s start"
  bash benchmarks/gpu/humanoid_cpu/run.sh /work/longruns/gnorm 70 --seed $s --total-steps 8.1e6 --set ppo.max_grad_norm=0.5 --quiet > /work/longruns/gnorm$s.log 2>&1
  echo "# $(date -u +%H:%M) UTC: seed $s rc $?"
  run=$(ls -d /work/longruns/gnorm/*__s${s}__* | tail -1)
  .venv/bin/canter eval "$run" --checkpoint best --episodes 10 --json "$run/eval-best.json" > /work/longruns/gnorm-eval$s.log 2>&1
  echo "# $(date -u +%H:%M) UTC: seed $s eval rc $?"
done
