MJX_SETS="--set env.solver_iterations=4 --set env.solver_ls_iterations=8" OFFPOLICY_ALGOS=sac OFFPOLICY_MINUTES=4.2 bash benchmarks/gpu/session.sh offpolicy:295
