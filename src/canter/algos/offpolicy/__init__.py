"""Off-policy algorithms: td3, ddpg and sac, sharing one replay buffer (canter.core.replay) and one jitted loop.

Modules: sections.py (their config sections and specs, read without JAX when a config is built), one module per
algorithm (ddpg.py, td3.py, sac.py: learner state, init, gradient step, acting), learner.py (the
`OffPolicyLearner` protocol), iteration.py (the env loop with storage and updates, which drives any
`OffPolicyLearner`), record.py (the `Algorithm` record built around a learner), algorithms.py (the records), and
the shared networks.py (actors, stacked critics, Adam), losses.py (pure targets and losses) and noise.py
(exploration). The package itself imports nothing.
"""
