# Device call 1 of 3, 2026-11-26 20:16 UTC, one NVIDIA H100 80GB HBM3, fresh machine, carry: [".whl"]
MJX_SETS="--set env.solver_iterations=4 --set env.solver_ls_iterations=8" SEEDS_ENVS=1024 SEEDS_STEPS=500000 OFFPOLICY_MINUTES=1.5 OFFPOLICY_EVAL_EVERY=500000 bash benchmarks/gpu/session.sh seeds:200 offpolicy:300
