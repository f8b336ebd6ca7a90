"""`sweep`: many runs of one scene, batched, chunked, sharded across devices.

A sweep is `jax.vmap(simulate)` plus the three things a batch of thousands to millions of
lanes needs:

- **bounded memory**: lanes run in chunks of `chunk_size`; every chunk has the same shape
  (the last one is padded), so the program compiles once;
- **devices**: each chunk is split across `devices` over a 1-D mesh, using JAX's own runtime
  (on several hosts, call `jax.distributed.initialize()` in every process and make the
  same `sweep` call with the same inputs: each process runs the lanes of its own devices,
  and every process gets the whole result back; tested with two processes joined over gloo
  on one machine, bit-identical to one process);
- **the slowest-lane problem**: a vmapped while loop runs until its slowest lane finishes
  (docs/design.md, *Batches*), so a chunk that mixes 2-impact and 200-impact lanes costs as if all had
  200. With `balance="refill"` (the default) each device runs its share of a chunk on a pool
  of `pool_size` lane slots (`_loop/pool.py`): whenever an eighth of the slots have finished, their
  results are written out and the next lanes of the queue are loaded into them; at the end
  the last few running lanes move to a pool an eighth as wide. The pool runs the very loop
  of `simulate` (`_loop.program.build_program`: same `init`, same `step`, same `finish`), so a
  lane computes what `simulate` computes for it alone, whichever lanes share the pool.
  `balance="none"` is plain `jax.vmap(simulate)` per chunk, sharded with a `NamedSharding`.
  `benchmarks/bench_sweep.py` measures the gain (see benchmarks/README.md).

**Reproducibility.** With `balance="refill"`, results are bit-for-bit independent of
`chunk_size`, `pool_size` (≥ 2) and the number of devices. Against `balance="none"` and
against single `simulate` calls they agree to rounding: XLA fuses the same loop differently
in different programs (and specialises batch size 1), which can move a result by an ulp,
and a few impacts later by the rounding those ulps grow to. Statuses, impact counts and
step counts agree exactly in the tests.
"""

import contextlib
import warnings
from collections.abc import Sequence
from typing import Any, Literal, NamedTuple

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ._adjoint import loop_kinds
from ._compiler import compiler_options
from ._loop.pool import run_pool
from ._scene import Scene
from ._simulate import SIMULATE_OPTIONS, _throw_if_failed, numeric_options, prepare, simulate
from ._solution import FailedLanesWarning, Solution, failed_lanes_message
from ._validate import saveat_times

_BALANCES = ("refill", "none")
_DEFAULT_POOL = 1024


def _batch_size(x0s, args, args_batched):
    sizes = {}
    x0s = np.asarray(x0s) if not isinstance(x0s, jax.Array) else x0s
    if x0s.ndim == 2:
        sizes["x0s"] = x0s.shape[0]
    elif x0s.ndim != 1:
        raise ValueError(f"x0s must have shape (batch, n) or (n,), got {x0s.shape}")
    leaves = jax.tree.leaves(args) if args is not None else []
    # (no flags: no args leaf is batched)
    flags = jax.tree.leaves(args_batched) if args_batched is not None else [False] * len(leaves)
    if args_batched is not None and len(flags) != len(leaves):
        raise ValueError("args_batched must have the structure of args (one bool per leaf)")
    for i, (leaf, batched) in enumerate(zip(leaves, flags, strict=True)):
        if batched:
            shape = np.shape(leaf)
            if len(shape) == 0:
                raise ValueError(f"args leaf {i} is marked batched but is a scalar")
            sizes[f"args leaf {i}"] = shape[0]
    if not sizes:
        raise ValueError(
            "nothing to sweep: pass x0s of shape (batch, n), or batched args with args_batched"
        )
    distinct = set(sizes.values())
    if len(distinct) != 1:
        raise ValueError(f"mismatched batch sizes: {sizes}")
    size = distinct.pop()
    if size == 0:
        raise ValueError("empty batch: there are no lanes to simulate")
    return size


def _auto_batched(args, batch):
    """Default `args_batched`: a leaf is batched iff its leading axis has the batch size."""
    return jax.tree.map(lambda leaf: np.ndim(leaf) >= 1 and np.shape(leaf)[0] == batch, args)


def sweep(
    scene: Scene,
    x0s,
    t0,
    t1,
    args=None,
    *,
    args_batched=None,
    chunk_size: int | None = None,
    devices: Sequence[jax.Device] | None = None,
    balance: Literal["refill", "none"] = "refill",
    pool_size: int | None = None,
    progress: bool = True,
    **simulate_kwargs: Any,
) -> Solution:
    r"""Run `simulate` over a batch of initial states and/or parameters.

    **Arguments:**

    - `scene`, `t0`, `t1`: as `grazejax.simulate` (shared by all lanes).
    - `x0s`: initial states, shape `(batch, n)`, or `(n,)` to use one state for all lanes.
    - `args`: parameters; leaves marked in `args_batched` carry the batch along axis 0.
    - `args_batched`: a pytree of bools with the structure of `args`. Default: a leaf is
      batched iff its leading axis equals the batch size (pass it explicitly when a
      parameter vector happens to have that length).
    - `chunk_size`: lanes per compiled call (memory stays bounded by one chunk's results).
      Default: the whole batch, up to 65536 lanes.
    - `devices`: devices to shard each chunk over (default: all of `jax.devices()`). Results
      do not depend on the number of devices.
    - `balance`: how lanes of different cost share the vectorised loop:
        - `"refill"` (default): each device runs its lanes on a pool of `pool_size` slots,
          loading the next lane into a slot when its lane finishes, so that a chunk costs
          about the sum of its lanes' steps rather than its slowest lane's steps times the
          chunk size (see the module docstring);
        - `"none"`: `jax.vmap(simulate)` over the whole chunk: every lane of a chunk
          waits for the slowest one.
    - `pool_size`: slots per device for `balance="refill"` (default: 1024, or the chunk's
      share per device if smaller). Wider pools vectorise better; narrower ones waste
      less on the last lanes of a chunk.
    - `progress`: show a tqdm progress bar of the lanes done (with `balance="refill"` it
      moves as lanes finish inside a chunk; with `"none"`, chunk by chunk). Until the first
      lanes are done it reads "compiling", without rate or ETA; then its clock restarts,
      so that rate and ETA are those of the run.
    - `**simulate_kwargs`: every keyword option of `simulate` (rtol, atol, solver,
      max_impacts, saveat, ...). `adjoint` is checked and otherwise has no effect: the
      results are NumPy arrays, not differentiable (differentiate a batch with
      `jax.vmap` of `jax.grad` through `grazejax.simulate` instead).

    **Returns:** a `grazejax.Solution` whose fields are NumPy arrays with a leading batch
    axis, in the order of the inputs (with `saveat`, `ts` too has one row per lane). A lane
    that fails (NaN, max steps, ...) reports it in its own `status` and never affects the
    others; if any lane fails, `sweep` warns once with a `grazejax.FailedLanesWarning`
    that counts the failing lanes by status (with `throw=True` it raises a
    `grazejax.SimulationError` instead). `SUCCESS`, `MAX_IMPACTS` and `ZENO` are not
    failures. Results do not depend on `chunk_size`, `pool_size` or the devices (see the
    module docstring for what "the same" means across `balance` values).

    **Example:**

    ```python
    x0s = np.stack([np.zeros(1000), np.linspace(0.05, 1.5, 1000)], axis=1)
    sols = gj.sweep(examples.ex1dof(), x0s, 0.0, 200.0, examples.ex1dof_args(-0.2))
    ```
    """
    unknown = set(simulate_kwargs) - set(SIMULATE_OPTIONS)
    if unknown:
        raise TypeError(f"sweep got unknown simulate options: {sorted(unknown)}")
    if "direction" in simulate_kwargs:
        raise TypeError("sweep sets direction itself (from t0 and t1)")
    if "adjoint" in simulate_kwargs:
        # The results come back as NumPy arrays, so nothing downstream can differentiate
        # them: check the adjoint (an unsupported one is the same error as in simulate)
        # and run the primal loop, the fastest kind (a bounded loop is several times slower).
        simulate_kwargs = dict(simulate_kwargs)
        loop_kinds(simulate_kwargs.pop("adjoint"))
    if balance not in _BALANCES:
        raise ValueError(f"balance must be one of {_BALANCES}, got {balance!r}")
    if pool_size is not None and (
        not isinstance(pool_size, (int, np.integer)) or isinstance(pool_size, bool) or pool_size <= 0
    ):
        raise ValueError(f"pool_size must be a positive integer, got {pool_size!r}")
    if pool_size is not None and balance != "refill":
        raise ValueError("pool_size applies to balance='refill' only")
    if args_batched is None and args is not None:
        x0_size = np.shape(x0s)[0] if np.ndim(x0s) == 2 else None
        if x0_size is not None:
            args_batched = _auto_batched(args, x0_size)
        else:
            sizes = {np.shape(leaf)[0] for leaf in jax.tree.leaves(args) if np.ndim(leaf) >= 1}
            if len(sizes) > 1:
                raise ValueError(
                    f"cannot infer which args leaves are batched (leading sizes {sorted(sizes)}): "
                    "pass args_batched"
                )
            args_batched = _auto_batched(args, sizes.pop()) if sizes else None
    batch = _batch_size(x0s, args, args_batched)
    simulate_kwargs = dict(simulate_kwargs)
    # Checked on the host once every lane is back, so that the error can name the lanes.
    throw = simulate_kwargs.pop("throw", False)
    if simulate_kwargs.get("saveat") is not None:  # a diffrax.SaveAt is not a jit argument
        simulate_kwargs["saveat"] = saveat_times(simulate_kwargs["saveat"], t0, t1)
    if float(t0) == float(t1):
        raise ValueError(f"t0 == t1 == {float(t0)}: nothing to simulate")
    if chunk_size is None:
        chunk_size = min(batch, 65536)
    if not isinstance(chunk_size, (int, np.integer)) or isinstance(chunk_size, bool) or chunk_size <= 0:
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    devices = list(jax.devices()) if devices is None else list(devices)
    if not devices:
        raise ValueError("devices is empty")
    num_devices = len(devices)
    # Every device gets the same number of lanes per chunk.
    chunk_size = -(-min(chunk_size, batch) // num_devices) * num_devices
    width = None
    if balance == "refill":
        width = int(min(pool_size or _DEFAULT_POOL, chunk_size // num_devices))

    x0s = np.asarray(x0s, dtype=np.float64)
    x0_batched = x0s.ndim == 2
    flags = args_batched if args_batched is not None else jax.tree.map(lambda _: False, args)

    def lane_inputs(index):
        x = x0s[index] if x0_batched else x0s
        a = jax.tree.map(lambda leaf, b: np.asarray(leaf)[index] if b else leaf, args, flags)
        return x, a

    run_chunk = _compiled_chunk(scene, t0, t1, flags, x0_batched, devices, width, simulate_kwargs,
                                progress=progress)

    bar = _Progress(batch) if progress else None
    pieces = []
    try:
        for start in range(0, batch, chunk_size):
            index = np.arange(start, min(start + chunk_size, batch))
            size = len(index)
            # Padding repeats the first lane (the pool never runs it; vmap runs it in step).
            padded = np.concatenate([index, np.full(chunk_size - size, index[0])])
            x, a = lane_inputs(padded)
            with _lanes_done_to(bar):
                out = run_chunk(x, a, np.arange(chunk_size) < size)
                pieces.append(jax.tree.map(lambda leaf, size=size: _to_host(leaf)[:size], out))
            if bar is not None:  # exact count (the pool's reports are per refill)
                bar.set(start + size)
    finally:
        if bar is not None:
            bar.close()
    result = jax.tree.map(lambda *leaves: np.concatenate(leaves, axis=0), *pieces)
    if throw:
        return _throw_if_failed(result)
    # Failing lanes are easy to miss among thousands: warn once, with or without a
    # progress bar (`throw=True` raises instead).
    message = failed_lanes_message(result.status)
    if message is not None:
        warnings.warn(message, FailedLanesWarning, stacklevel=2)
    return result


# The progress bar that the pool's in-program reports (`run_pool(on_finished=...)`) go to.
# The compiled chunk is cached across sweeps, so its callback cannot hold one sweep's bar.
_BAR: list = [None]


@contextlib.contextmanager
def _lanes_done_to(bar):
    _BAR[0] = bar
    try:
        yield
    finally:
        _BAR[0] = None


def _report_lanes_done(count) -> None:
    bar = _BAR[0]
    if bar is not None and int(count) > 0:
        bar.add(int(count))


class _Progress:
    """tqdm's bar of the lanes done.

    The first chunk compiles the program before it runs a lane, often for longer than the
    lanes take, so a rate and an ETA counted from the start would be the compile's. Until
    the first lanes are done (reported from inside the first chunk with
    `balance="refill"`, at its end with `"none"`), the bar says it is compiling and shows
    neither. Then its clock restarts, so that rate, ETA and elapsed time are the run's;
    a sweep done by then keeps its whole time and mean rate.
    """

    DESCRIPTION = "grazejax.sweep"
    COMPILING_FORMAT = "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}]"

    def __init__(self, total: int):
        from tqdm.auto import tqdm

        self.bar = tqdm(total=total, desc=f"{self.DESCRIPTION} (compiling)", unit="lane",
                        bar_format=self.COMPILING_FORMAT)
        self.compiling = True

    def add(self, count: int) -> None:
        """Lanes done inside a chunk (the pool's reports, one per refill)."""
        self.bar.update(count)
        self._running()

    def set(self, done: int) -> None:
        """The exact count at the end of a chunk."""
        self.bar.n = done
        self._running()
        self.bar.refresh()

    def close(self) -> None:
        self.bar.close()

    def _running(self) -> None:
        if not self.compiling:
            return
        self.compiling = False
        bar, done = self.bar, self.bar.n
        bar.bar_format = None  # tqdm's default: with rate and ETA
        bar.set_description(self.DESCRIPTION, refresh=False)
        if done < bar.total:
            bar.reset()  # (a fresh clock and rate estimate; it sets n to 0)
            bar.n = bar.initial = bar.last_print_n = done
        bar.refresh()


def _put(value, sharding):
    """`device_put` onto a mesh that may span several processes. Each process builds its own
    shards from its (identical) copy of the inputs: multi-process `device_put` instead
    checks that the copies are equal, which fails on a NaN lane (NaN != NaN)."""
    if jax.process_count() == 1:
        return jax.device_put(value, sharding)
    value = np.asarray(value)
    return jax.make_array_from_callback(value.shape, sharding, lambda index: value[index])


def _to_host(leaf) -> np.ndarray:
    """A chunk's output as NumPy. On several hosts the output spans other processes'
    devices: every process gathers the whole chunk (so each returns the full result)."""
    if isinstance(leaf, jax.Array) and not leaf.is_fully_addressable:
        from jax.experimental import multihost_utils

        leaf = multihost_utils.process_allgather(leaf, tiled=True)
    return np.asarray(leaf)


def _compiled_chunk(scene, t0, t1, flags, x0_batched, devices, width, simulate_kwargs,
                    progress=False):
    """The jitted (and sharded) chunk runner, compiled once per configuration.

    Numbers (x0s, args, t0, t1, saveat) are arguments; structure (scene, which leaves are
    batched, solver and options, devices, pool width) is the cache key, so repeated sweeps
    over new values reuse the compiled program instead of recompiling a fresh closure.
    `progress` compiles in the pool's progress reports (one host callback per refill), so
    that sweeps without a bar (and the benchmarks) run without them.
    """
    options = dict(simulate_kwargs)
    saveat = options.pop("saveat", None)
    # Tolerances are inputs, like t0 and t1: a sweep at a new rtol reuses the program.
    numbers = numeric_options(options)
    options = {name: value for name, value in options.items() if name not in numbers}
    direction = 1 if float(t1) > float(t0) else -1
    in_axes_args = jax.tree.map(lambda b: 0 if b else None, flags)
    is_none = lambda v: v is None  # noqa: E731
    key = (scene, x0_batched, jax.tree.structure(in_axes_args, is_leaf=is_none),
           tuple(jax.tree.leaves(in_axes_args, is_leaf=is_none)),
           tuple(sorted(options.items())), tuple(sorted(numbers)), tuple(devices), direction,
           width, progress)
    try:
        hash(key)
    except TypeError:  # unhashable option values: compile without caching
        build = _build_chunk(scene, in_axes_args, x0_batched, devices, options, direction, width,
                             progress)
    else:
        if key not in _CHUNK_CACHE:
            _CHUNK_CACHE[key] = _build_chunk(
                scene, in_axes_args, x0_batched, devices, options, direction, width, progress
            )
        build = _CHUNK_CACHE[key]
    return build(t0, t1, saveat, numbers)


_CHUNK_CACHE: dict = {}


def _build_chunk(scene, in_axes_args, x0_batched, devices, options, direction, width, progress):
    x_axis = 0 if x0_batched else None
    is_none = lambda v: v is None  # noqa: E731

    if width is None:

        def run(x0s, a, valid, t0, t1, saveat, numbers):
            del valid  # padding lanes run like the others
            return jax.vmap(
                lambda x0, aa: simulate(
                    scene, x0, t0, t1, aa, saveat=saveat, direction=direction, **options,
                    **numbers,
                ),
                in_axes=(x_axis, in_axes_args),
            )(x0s, a)

    else:
        # Every option of simulate but those the chunk sets itself.
        # (the pool builds the loop with `prepare`, as simulate does, with its defaults)
        kw = {**SIMULATE_OPTIONS, **options}
        for own in ("saveat", "direction", "throw"):
            kw.pop(own)

        def run(x0s, a, valid, t0, t1, saveat, numbers):
            # One lane's inputs as the template: `prepare` only reads shapes and dtypes
            # from them (the values are traced).
            lane_x0 = x0s if x_axis is None else x0s[0]
            lane_args = jax.tree.map(
                lambda leaf, axis: leaf if axis is None else leaf[0], a, in_axes_args,
                is_leaf=is_none,
            )
            # (`batched`: the pool runs the program's step on a batch of lanes)
            checked, program = prepare(
                scene, lane_x0, t0, t1, lane_args, saveat=saveat, direction=direction,
                batched=True, **{**kw, **numbers}
            )
            x0s = x0s.astype(checked.x0.dtype)  # as simulate's validate_inputs does
            return run_pool(program, x0s, a, (x_axis, in_axes_args), valid, width,
                            on_finished=_report_lanes_done if progress else None)

    if len(devices) == 1:
        device = devices[0]
        compiled = jax.jit(run, compiler_options=compiler_options(device.platform))

        def place(x, a, valid):
            return jax.device_put((x, a, valid), device)

        return lambda *shared: _Runner(compiled, place, shared)

    mesh = Mesh(np.array(devices), ("lanes",))
    xla_options = compiler_options(devices[0].platform)
    lanes, replicated = PartitionSpec("lanes"), PartitionSpec()
    x_spec = lanes if x0_batched else replicated
    a_specs = jax.tree.map(lambda axis: replicated if axis is None else lanes, in_axes_args,
                           is_leaf=is_none)
    if width is None:
        # Plain vmap: XLA partitions the batch over the mesh.
        compiled = jax.jit(run, out_shardings=NamedSharding(mesh, lanes), compiler_options=xla_options)
    else:
        # Each device runs its own pool on its share of the chunk.
        compiled = jax.jit(jax.shard_map(
            run, mesh=mesh,
            in_specs=(x_spec, a_specs, lanes, replicated, replicated, replicated, replicated),
            out_specs=lanes, check_vma=False,
        ), compiler_options=xla_options)
    x_sharding = NamedSharding(mesh, x_spec)
    a_sharding = jax.tree.map(lambda spec: NamedSharding(mesh, spec), a_specs)
    valid_sharding = NamedSharding(mesh, lanes)

    def place(x, a, valid):
        return (_put(x, x_sharding), jax.tree.map(_put, a, a_sharding), _put(valid, valid_sharding))

    return lambda *shared: _Runner(compiled, place, shared)


class _Runner(NamedTuple):
    """One chunk's compiled program with its shared inputs; `lower` is for benchmarks
    (e.g. `runner.lower(x, a, valid).compile().memory_analysis()`)."""

    compiled: Any
    place: Any
    shared: tuple  # t0, t1, saveat, the numeric options

    def __call__(self, x, a, valid):
        return self.compiled(*self.place(x, a, valid), *self.shared)

    def lower(self, x, a, valid):
        return self.compiled.lower(*self.place(x, a, valid), *self.shared)
