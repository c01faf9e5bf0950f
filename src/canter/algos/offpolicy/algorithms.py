"""The runtime records of td3, ddpg and sac (`AlgorithmSpec.runtime`)."""

from canter.algos.offpolicy import ddpg, sac, td3

ALGORITHMS = {"td3": td3.ALGORITHM, "ddpg": ddpg.ALGORITHM, "sac": sac.ALGORITHM}
