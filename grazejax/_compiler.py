"""XLA compiler options on CPU: wide vectors for batched runs, a quick compile for single ones.

**Batched runs.** XLA's CPU backend asks LLVM for 256-bit vectors by default, also on a
processor with AVX-512. A sweep runs every operation of the impact loop across its lanes,
so its kernels are long elementwise loops that 512-bit vectors serve better (faster
sweeps, impact times bit for bit equal: `benchmarks/README.md`). heyoka's batch mode, the peer in the throughput
benchmark, uses the full AVX-512 width too.

`compiler_options()` is what `sweep` passes to `jax.jit`; pass it to your own
`jax.jit(jax.vmap(simulate), compiler_options=grazejax.compiler_options())` for the same
effect.

**Single runs.** XLA:CPU emits each fusion through MLIR ("fusion emitters") by default,
which is most of a first call's time: XLA's older LLVM emitters compile a single run in
about half the time, and the program runs as fast. For a batch the older emitters give
slower kernels, so they are for programs of one
trajectory: `compiler_options(batched=False)`, which grazejax's own analysis programs
(periodic orbits, continuation, flow Jacobians) use. The two emitters may round
transcendental functions differently: results can differ in the last bits, not in
accuracy.

An option the user set in `XLA_FLAGS` is the user's choice and wins; an option this XLA
does not know is not passed.
"""

import functools
import os

import equinox as eqx
import jax

VECTOR_WIDTH_OPTION = "xla_cpu_prefer_vector_width"
FUSION_EMITTERS_OPTION = "xla_cpu_use_fusion_emitters"


@functools.cache
def _host_has_avx512() -> bool:
    """Whether this (Linux) host's processor has AVX-512F; False where it cannot tell."""
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            for line in cpuinfo:
                if line.startswith("flags"):
                    return "avx512f" in line.split()
    except OSError:
        pass
    return False


@functools.cache
def _known(option: str, value) -> bool:
    """Whether this XLA accepts `option` per program (compiles a trivial one to see)."""
    try:
        jax.jit(lambda x: x + 1, compiler_options={option: value}).lower(1.0).compile()
    except Exception:  # an unknown option: XLA's error type is not part of JAX's API
        return False
    return True


def _option(option: str, value) -> dict:
    if option in os.environ.get("XLA_FLAGS", "") or not _known(option, value):
        return {}
    return {option: value}


def compiler_options(platform: str | None = None, *, batched: bool = True) -> dict:
    """XLA options for a program compiled for `platform` (default: JAX's default backend).

    `batched=True` (a vmapped run, `sweep`): 512-bit vectors on a CPU with AVX-512,
    nothing otherwise; results are the same bits. `batched=False` (one trajectory, where
    the compile is most of the time): XLA:CPU's older, quicker emitters; results may
    differ in the last bits. Nothing on other backends.

    Use as `jax.jit(fn, compiler_options=grazejax.compiler_options())`.
    """
    platform = jax.default_backend() if platform is None else platform
    if platform != "cpu":
        return {}
    if not batched:
        return _option(FUSION_EMITTERS_OPTION, False)
    return _option(VECTOR_WIDTH_OPTION, 512) if _host_has_avx512() else {}


def single_run_jit(fn):
    """`eqx.filter_jit(fn)` compiled with `compiler_options(batched=False)`, for the
    analysis programs that run one trajectory (or a few tangents of it) at a time.

    JAX takes compiler options only for a top-level program: called inside another
    `jit` (or under `vmap`, `grad`: its inputs are tracers there), `fn` is jitted plainly
    and the enclosing program's options apply. The jits are built on the first call
    (asking for the backend at import would start it). `.jitted` is the top-level
    `eqx.filter_jit` wrapper, once built.
    """
    plain = eqx.filter_jit(fn)

    @functools.wraps(fn)
    def call(*args, **kwargs):
        if _traced(args, kwargs):
            return plain(*args, **kwargs)
        if call.jitted is None:
            call.jitted = eqx.filter_jit(fn, compiler_options=compiler_options(batched=False))
        try:
            return call.jitted(*args, **kwargs)
        except ValueError as error:
            # Inside a trace that none of the inputs shows (constants only).
            if "top-level" not in str(error):
                raise
            return plain(*args, **kwargs)

    call.jitted = None
    return call


def _traced(args, kwargs) -> bool:
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves((args, kwargs)))


# XLA:CPU's `ThunkExecutor::Options::execute_sequential_buffer_threshold`: a sequence of
# kernels (a loop body, a branch) runs one after another only if none of them touches a
# buffer over this many bytes (see `_loop/state.py: stage_log`, `_loop/stored.py`).
SEQUENTIAL_BUFFER_BYTES = 512
