#!/bin/bash
# The implementation check of report 001's page: canter's `cleanrl` preset (Baselines ppo2 / CleanRL ppo_continuous
# settings) on Humanoid-v4 for 1M steps, seeds 100-102 (chosen before the runs), one whole process each, one after
# another, against CleanRL's published 716 ± 49 (training return at 1M, v4, 3 seeds). Then bench's final evaluation
# (10 deterministic episodes, env seed 0) of each run's last checkpoint, written to its eval.json.
#   bash benchmarks/reports/001-humanoid-ppo/train_v4_check.sh OUT_DIR
set -u
out=${1:?usage: train_v4_check.sh OUT_DIR}
mkdir -p "$out"
for s in 100 101 102; do
  start=$(date +%s.%N)
  .venv/bin/canter train Humanoid-v4 --preset cleanrl --seed $s --total-steps 1e6 --out-dir "$out/runs" --quiet \
    > "$out/train_s$s.log" 2>&1
  rc=$?
  end=$(date +%s.%N)
  echo "seed $s rc $rc wall $(echo "$end - $start" | bc) load $(cut -d' ' -f1-3 /proc/loadavg)" >> "$out/timing.txt"
done
.venv/bin/python -c "
import sys
from pathlib import Path
from canter.orchestrate.jobs import write_final_eval
for run in sorted(Path(sys.argv[1]).iterdir()):
    write_final_eval(run, 10)
" "$out/runs"
