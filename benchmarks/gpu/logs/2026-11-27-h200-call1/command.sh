MJX_SETS="--set env.solver_iterations=4 --set env.solver_ls_iterations=8" OFFPOLICY_ALGOS=td3 OFFPOLICY_MINUTES=4.5 bash benchmarks/gpu/session.sh offpolicy:330 ppo-brax=humanoid:240
