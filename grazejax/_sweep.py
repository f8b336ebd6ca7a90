"""`sweep`: many runs of one scene, batched with vmap, chunked, sharded across devices.

A sweep is `jax.vmap(simulate)` plus the three things a batch of thousands to millions of
lanes needs:

- **bounded memory**: lanes run in chunks of `chunk_size`; every chunk has the same shape
  (the last one is padded), so the program compiles once;
- **devices**: each chunk is split across `devices` with a `NamedSharding` over a 1-D mesh,
  using JAX's own runtime (on several hosts, call `jax.distributed.initialize()` first and
  pass `devices=jax.devices()`: every process then runs the same call on its share);
- **the slowest-lane problem**: a vmapped while loop runs until its slowest lane finishes
  (DESIGN.md §4), so a chunk that mixes 2-impact and 200-impact lanes costs as if all had 200.
  `balance="presort"` runs a cheap loose-tolerance pass first, sorts the lanes by the number
  of steps it took, and chunks them in that order so that each chunk holds lanes of similar
  cost; results come back in the caller's order. `benchmarks/bench_sweep.py` measures the gain.
"""

from collections.abc import Sequence
from typing import Any, Literal

import jax
import numpy as np

from ._scene import Scene
from ._simulate import simulate
from ._solution import Solution


def _batch_size(x0s, args, args_batched):
    sizes = {}
    x0s = np.asarray(x0s) if not isinstance(x0s, jax.Array) else x0s
    if x0s.ndim == 2:
        sizes["x0s"] = x0s.shape[0]
    elif x0s.ndim != 1:
        raise ValueError(f"x0s must have shape (batch, n) or (n,), got {x0s.shape}")
    leaves = jax.tree.leaves(args) if args is not None else []
    flags = jax.tree.leaves(args_batched) if args_batched is not None else []
    if args_batched is not None and len(flags) != len(leaves):
        raise ValueError("args_batched must have the structure of args (one bool per leaf)")
    for i, (leaf, batched) in enumerate(zip(leaves, flags)):
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
    balance: Literal["none", "presort"] = "none",
    progress: bool = True,
    **simulate_kwargs: Any,
) -> Solution:
    r"""Run `simulate` over a batch of initial states and/or parameters.

    **Arguments:**

    - `scene`, `t0`, `t1`: as [`grazejax.simulate`][] (shared by all lanes).
    - `x0s`: initial states, shape `(batch, n)`, or `(n,)` to use one state for all lanes.
    - `args`: parameters; leaves marked in `args_batched` carry the batch along axis 0.
    - `args_batched`: a pytree of bools with the structure of `args`. Default: a leaf is
      batched iff its leading axis equals the batch size (pass it explicitly when a
      parameter vector happens to have that length).
    - `chunk_size`: lanes per compiled call (memory stays bounded by one chunk). Default:
      the whole batch, up to 65536 lanes.
    - `devices`: devices to shard each chunk over (default: all of `jax.devices()`). Results
      do not depend on the number of devices.
    - `balance`: `"presort"` to group lanes of similar cost (see the module docstring).
    - `progress`: show a tqdm progress bar across chunks.
    - `**simulate_kwargs`: every keyword option of `simulate` (rtol, atol, solver,
      max_impacts, saveat, ...).

    **Returns:** a [`grazejax.Solution`][] whose fields are NumPy arrays with a leading batch
    axis, in the order of the inputs. A lane that fails (NaN, Zeno, max steps) reports it in
    its own `status` and never affects the others.

    **Example:**

    ```python
    x0s = np.stack([np.zeros(1000), np.linspace(0.05, 1.5, 1000)], axis=1)
    sols = gj.sweep(examples.ex1dof(), x0s, 0.0, 200.0, examples.ex1dof_args(-0.2))
    ```
    """
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
    if float(t0) == float(t1):
        raise ValueError(f"t0 == t1 == {float(t0)}: nothing to simulate")
    if chunk_size is None:
        chunk_size = min(batch, 65536)
    if not isinstance(chunk_size, (int, np.integer)) or chunk_size <= 0:
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    if balance not in ("none", "presort"):
        raise ValueError(f"balance must be 'none' or 'presort', got {balance!r}")
    devices = list(jax.devices()) if devices is None else list(devices)
    if not devices:
        raise ValueError("devices is empty")
    num_devices = len(devices)
    # Every device gets the same number of lanes per chunk.
    chunk_size = -(-min(chunk_size, batch) // num_devices) * num_devices

    x0s = np.asarray(x0s, dtype=np.float64)
    x0_batched = x0s.ndim == 2
    flags = args_batched if args_batched is not None else jax.tree.map(lambda _: False, args)

    def lane_inputs(index):
        x = x0s[index] if x0_batched else x0s
        a = jax.tree.map(
            lambda leaf, b: np.asarray(leaf)[index] if b else leaf, args, flags
        )
        return x, a

    run_chunk = _compiled_chunk(scene, t0, t1, args, flags, x0_batched, devices, simulate_kwargs)

    order = np.arange(batch)
    if balance == "presort":
        order = _presort_order(scene, t0, t1, lane_inputs, batch, chunk_size, flags, x0_batched,
                               args, devices, simulate_kwargs)

    starts = range(0, batch, chunk_size)
    if progress:
        from tqdm.auto import tqdm

        starts = tqdm(starts, total=len(starts), desc="grazejax.sweep", unit="chunk")
    pieces = []
    for start in starts:
        index = order[start : start + chunk_size]
        padded = np.concatenate([index, np.full(chunk_size - len(index), index[0])])
        x, a = lane_inputs(padded)
        out = run_chunk(x, a)
        pieces.append(jax.tree.map(lambda leaf: np.asarray(leaf)[: len(index)], out))
    stacked = jax.tree.map(lambda *leaves: np.concatenate(leaves, axis=0), *pieces)
    inverse = np.empty_like(order)
    inverse[order] = np.arange(batch)
    return jax.tree.map(lambda leaf: leaf[inverse], stacked)


def _compiled_chunk(scene, t0, t1, args, flags, x0_batched, devices, simulate_kwargs):
    """The jitted, vmapped (and sharded) chunk runner, compiled once per configuration.

    Numbers (x0s, args, t0, t1, saveat) are arguments; structure (scene, which leaves are
    batched, solver and options, devices) is the cache key, so repeated sweeps over new
    values reuse the compiled program instead of recompiling a fresh closure each call.
    """
    options = dict(simulate_kwargs)
    saveat = options.pop("saveat", None)
    direction = 1 if float(t1) > float(t0) else -1
    in_axes_args = jax.tree.map(lambda b: 0 if b else None, flags)
    treedef = jax.tree.structure(in_axes_args, is_leaf=lambda v: v is None)
    key = (scene, x0_batched, treedef, tuple(jax.tree.leaves(in_axes_args, is_leaf=lambda v: v is None)),
           tuple(sorted(options.items())), tuple(devices), direction)
    try:
        hash(key)
    except TypeError:  # unhashable option values: compile without caching
        return _build_chunk(scene, in_axes_args, x0_batched, devices, options, direction, flags)(
            t0, t1, saveat)
    return _cached_chunk(key, scene, in_axes_args, x0_batched, devices, options, direction, flags)(
        t0, t1, saveat)


_CHUNK_CACHE: dict = {}


def _cached_chunk(key, *build_args):
    if key not in _CHUNK_CACHE:
        _CHUNK_CACHE[key] = _build_chunk(*build_args)
    return _CHUNK_CACHE[key]


def _build_chunk(scene, in_axes_args, x0_batched, devices, options, direction, flags):
    def one(x0, a, t0, t1, saveat):
        return simulate(scene, x0, t0, t1, a, saveat=saveat, direction=direction, **options)

    batched = jax.vmap(one, in_axes=(0 if x0_batched else None, in_axes_args, None, None, None))
    if len(devices) == 1:
        compiled = jax.jit(batched)
        device = devices[0]

        def bind(t0, t1, saveat):
            return lambda x, a: compiled(
                jax.device_put(x, device), jax.device_put(a, device), t0, t1, saveat
            )

        return bind
    mesh = jax.sharding.Mesh(np.array(devices), ("lanes",))
    lanes = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("lanes"))
    replicated = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())
    x_sharding = lanes if x0_batched else replicated
    a_sharding = jax.tree.map(lambda b: lanes if b else replicated, flags)
    compiled = jax.jit(batched, out_shardings=lanes)

    def bind(t0, t1, saveat):
        return lambda x, a: compiled(
            jax.device_put(x, x_sharding), jax.tree.map(jax.device_put, a, a_sharding), t0, t1, saveat
        )

    return bind


def _presort_order(scene, t0, t1, lane_inputs, batch, chunk_size, flags, x0_batched, args,
                   devices, simulate_kwargs):
    """Order lanes by the steps a loose-tolerance pass needs (a cheap cost proxy)."""
    loose = dict(simulate_kwargs)
    loose.pop("saveat", None)
    loose.pop("stepsize_controller", None)
    loose["rtol"], loose["atol"] = 1e-4, 1e-6
    probe = _compiled_chunk(scene, t0, t1, args, flags, x0_batched, devices, loose)
    cost = np.empty(batch)
    for start in range(0, batch, chunk_size):
        index = np.arange(start, min(start + chunk_size, batch))
        padded = np.concatenate([index, np.full(chunk_size - len(index), index[0])])
        x, a = lane_inputs(padded)
        cost[index] = np.asarray(probe(x, a).num_steps)[: len(index)]
    return np.argsort(cost, kind="stable")
