"""A training group's jitted program: one seed's iteration alone, or every seed's vmapped on a leading axis, and the
train state and env carry that it steps from one call to the next."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from canter.config.algorithms import algorithm_spec, key_value
from canter.config.schema import Config
from canter.envs.base import JaxVecEnv
from canter.training import device_memory
from canter.training.seed_run import SeedRun


def initial_state_program(algorithm: Any, config: Config, spec: Any) -> Callable[[int], Any]:
    """`initial_state(seed)`: the train state that a new run of `config` starts from with run seed `seed`, built by
    one compiled program rather than the initializers' few dozen small operations compiled one by one (a td3
    process takes about 5% less CPU, a ppo one the same); the seed is the program's argument, so that the seeds of a
    group share its compile. The state is the eager one, bit for bit."""
    import jax

    program = jax.jit(lambda seed: algorithm.init_state(config, spec, seed))
    return lambda seed: program(np.uint32(seed))


@contextmanager
def fewer_envs_when_out_of_device_memory(envs: int) -> Iterator[None]:
    """The device running out of memory, reported as what the user can change: env.num_envs."""
    try:
        yield
    except Exception as exc:
        if device_memory.is_out_of_memory(exc):
            raise device_memory.too_many_envs(envs) from None
        raise


class TwoPrograms:
    """An iteration as two jitted programs, `rollout(state, carry) -> (state, carry, collected)` and then
    `learn(state, collected, lr_fraction) -> (state, metrics)`, lowered and compiled and called as one."""

    def __init__(self, rollout: Any, learn: Any) -> None:
        self.rollout, self.learn = rollout, learn

    def lower(self, state: Any, carry: Any, lr_fraction: Any) -> TwoPrograms:
        import jax

        state_after, _, collected = jax.eval_shape(self.rollout, state, carry)
        return TwoPrograms(self.rollout.lower(state, carry), self.learn.lower(state_after, collected, lr_fraction))

    def compile(self) -> TwoPrograms:
        return TwoPrograms(self.rollout.compile(), self.learn.compile())

    @property
    def programs(self) -> tuple[Any, Any]:
        return self.rollout, self.learn

    def __call__(self, state: Any, carry: Any, lr_fraction: Any) -> tuple[Any, Any, Any]:
        state, carry, collected = self.rollout(state, carry)
        state, metrics = self.learn(state, collected, lr_fraction)
        return state, carry, metrics


@dataclass(frozen=True)
class Chunk:
    """One call of the group's program: the state and env carry it returned, its metrics on the host, and its wall
    seconds."""

    state: Any
    carry: Any
    metrics: Any
    iterations: np.ndarray  # each seed's iteration count after the call
    elapsed: float


class GroupProgram:
    """The group's jitted iteration (one seed's alone, or every seed's vmapped on a leading axis), and the train state
    and env carry it steps from one call to the next."""

    def __init__(self, config: Config, algorithm: Any, spec: Any, env: Any, states: list[Any], carry: Any) -> None:
        import jax

        self.algorithm = algorithm
        self.group = len(states)
        self.total = config.run.total_steps
        self.envs = config.env.num_envs
        # The keys that size one call's memory, as a refusal of a program too large for it names them.
        self.call_sizes = ", ".join(
            f"{key}={key_value(config, key):,}" for key in algorithm_spec(config.run.algo).memory_keys()
        )
        donate = (0,) if algorithm.donate_state else ()
        self.pick: Callable[[Any, int], Any]  # seed i's part of a tree the group computed
        jax_env = isinstance(env, JaxVecEnv)
        if self.group == 1:
            state = states[0]
            env_step = env.jax_step
            over_seeds: Callable[[Callable], Callable] = lambda f: f  # noqa: E731
            self.pick = lambda tree, i: tree
        else:
            from canter.training import seedgroup

            state = seedgroup.stack(states)
            # A JAX env vmaps like the learner, each seed stepping its own envs; EnvPool's step goes through group_step.
            env_step = env.jax_step if jax_env else seedgroup.group_step(env.jax_step, self.group)
            over_seeds = jax.vmap
            self.pick = seedgroup.unstack
        # An env step that is not JAX makes its program uncacheable (see `Algorithm.make_parts`): the update that
        # does not step the env is compiled on its own where the algorithm can part them.
        self.iteration: Any
        if algorithm.make_parts is not None and not jax_env:
            rollout, learn = algorithm.make_parts(config, spec, env_step)
            self.iteration = TwoPrograms(
                jax.jit(over_seeds(rollout)), jax.jit(over_seeds(learn), donate_argnums=donate)
            )
        else:
            self.iteration = jax.jit(
                over_seeds(algorithm.make_iteration(config, spec, env_step)), donate_argnums=donate
            )
        self.keeps_carry = jax_env
        if algorithm.donate_state:
            state = jax.device_put(state)  # donation needs device buffers (a resumed state holds numpy arrays)
        self.state = state
        self.carry = carry
        self.compiled: Any = None

    def env_carry(self, tree: Any, i: int) -> Any:
        """Seed i's episodes in flight, for a backend that can resume them exactly (else None)."""
        return self.pick(tree, i) if self.keeps_carry else None

    def lr_fractions(self, runs: list[SeedRun]) -> Any:
        """Each seed's fraction of its budget still to train, which its learning-rate schedule follows."""
        import jax.numpy as jnp

        values = [max(1.0 - run.global_step / self.total, 0.0) for run in runs]
        return jnp.float32(values[0]) if self.group == 1 else jnp.asarray(values, jnp.float32)

    def compile(self, runs: list[SeedRun]) -> float:
        """Compile the iteration, refusing a program the device cannot hold; returns the seconds this took."""
        start = time.perf_counter()
        with fewer_envs_when_out_of_device_memory(self.envs):
            self.compiled = self.iteration.lower(self.state, self.carry, self.lr_fractions(runs)).compile()
        for program in getattr(self.compiled, "programs", (self.compiled,)):
            device_memory.check_fits(program, self.envs, self.call_sizes)
        return time.perf_counter() - start

    def call(self, runs: list[SeedRun]) -> Chunk:
        """One call of the compiled iteration, from the state and carry that the last one left."""
        import jax

        t0 = time.perf_counter()
        with fewer_envs_when_out_of_device_memory(self.envs):
            state, carry, metrics = self.compiled(self.state, self.carry, self.lr_fractions(runs))
        metrics = jax.device_get(metrics)
        iterations = np.asarray(jax.device_get(state.iteration))
        return Chunk(state, carry, metrics, iterations, time.perf_counter() - t0)

    def advance(self, chunk: Chunk) -> None:
        """The next call goes on from this chunk. Until then `state` and `carry` are those from before it, which a
        seed whose chunk was non-finite keeps."""
        self.state, self.carry = chunk.state, chunk.carry
