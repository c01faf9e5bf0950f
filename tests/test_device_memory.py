"""Whether a compiled training program fits the device: the estimate from XLA's memory analysis, the one-line error
that names env.num_envs, and recognising XLA's out-of-memory errors."""

import jax
import jax.numpy as jnp
import pytest

from canter.errors import CanterError
from canter.training import device_memory


def test_a_real_compiled_program_reports_what_it_needs():
    compiled = jax.jit(lambda x: (x @ x.T).sum()).lower(jnp.ones((256, 128), jnp.float32)).compile()
    need = device_memory.required_bytes(compiled)
    assert need is not None and need >= 256 * 128 * 4  # at least its argument


class _Analysis:
    argument_size_in_bytes = 3 * 2**30
    output_size_in_bytes = 1 * 2**30
    temp_size_in_bytes = 2 * 2**30
    alias_size_in_bytes = 1 * 2**30


class _Compiled:
    def memory_analysis(self):
        return _Analysis()


def test_a_program_larger_than_the_free_memory_is_refused_before_training(monkeypatch):
    assert device_memory.required_bytes(_Compiled()) == 5 * 2**30  # aliased buffers count once
    monkeypatch.setattr(device_memory, "free_bytes", lambda: 4 * 2**30)
    with pytest.raises(CanterError) as error:
        device_memory.check_fits(_Compiled(), 4096)
    assert str(error.value) == (
        "env.num_envs=4096 does not fit in the device's memory (needs about 5.0 GiB, 4.0 GiB free); lower it, "
        "e.g. --set env.num_envs=2048"
    )
    monkeypatch.setattr(device_memory, "free_bytes", lambda: 6 * 2**30)
    device_memory.check_fits(_Compiled(), 4096)  # fits
    monkeypatch.setattr(device_memory, "free_bytes", lambda: None)
    device_memory.check_fits(_Compiled(), 4096)  # the CPU reports no memory: nothing to check


def test_xla_out_of_memory_errors_are_recognised():
    assert device_memory.is_out_of_memory(RuntimeError("RESOURCE_EXHAUSTED: Out of memory allocating 1.2GiB"))
    assert not device_memory.is_out_of_memory(RuntimeError("INVALID_ARGUMENT: shapes differ"))
    assert "lower it, e.g. --set env.num_envs=1" in str(device_memory.too_many_envs(1))


def test_the_compile_cache_folder_follows_the_environment(monkeypatch, tmp_path):
    from canter.core import runtime

    monkeypatch.delenv(runtime.COMPILE_CACHE_ENV, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert runtime.compile_cache_dir() == str(tmp_path / "canter" / "xla")
    monkeypatch.setenv(runtime.COMPILE_CACHE_ENV, str(tmp_path / "mine"))
    assert runtime.compile_cache_dir() == str(tmp_path / "mine")
    for off in ("0", "off", "no", "false"):
        monkeypatch.setenv(runtime.COMPILE_CACHE_ENV, off)
        assert runtime.compile_cache_dir() is None


CACHED_PROGRAM = """
import sys
import warnings

if sys.argv[1] == "without-filelock":
    sys.modules["filelock"] = None  # as if not installed: `import filelock` fails, find_spec gives None
warnings.simplefilter("error")  # JAX's failed cache reads are warnings
import jax
import jax.numpy as jnp
from jax import monitoring

from canter.core import runtime

hits = []
monitoring.register_event_listener(lambda event, **_: hits.append(event) if event.endswith("cache_hits") else None)
runtime.use_compile_cache(jax)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
jax.jit(lambda x: jnp.sin(x) * 3.0 + x.sum())(jnp.ones(7)).block_until_ready()
print(len(hits))
"""


@pytest.mark.parametrize("filelock", ["with-filelock", "without-filelock"])
def test_a_second_process_reads_the_compile_cache_with_or_without_filelock(filelock, tmp_path):
    """The GPU machine installs canter with --no-deps and may lack filelock, without which JAX cannot bound the
    cache: bounding it anyway made every read of a kept program fail, so each process compiled again."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, CANTER_COMPILE_CACHE=str(tmp_path / "xla"))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)

    def run() -> int:
        done = subprocess.run(
            [sys.executable, "-c", CACHED_PROGRAM, filelock], env=env, capture_output=True, text=True, timeout=120
        )
        assert done.returncode == 0, done.stderr[-2000:]
        return int(done.stdout.split()[-1])

    run()  # compiles and keeps the program
    assert run() > 0  # found it
