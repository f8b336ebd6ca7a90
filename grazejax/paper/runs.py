"""The paper's runs: batched, chunked simulation through `grazejax.sweep`, and JSON-ready
summaries of the runs.

Every figure and claim simulates through `run_batch`, which calls `sweep` (plain `vmap`,
`balance="none"`: most batches are two or three starts, which gain nothing from refilling
and compile faster without the pool) with one batch width per example and `RunConfig`, so
that the runs of one example reuse one compiled program.

The ε = 1e-4 damping of `ex1dof` acts on a time scale 1/(ε(1+μ)²) ≈ 10⁴, so its runs are
long (up to 10⁵ time units); they run in chunks that restart from the last state (the
per-step cost of `simulate` grows with `max_impacts` and the `saveat` length, so small
buffers per chunk are much faster than one big run).
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import jax
import numpy as np

from .. import examples, plot
from .._solution import FailedLanesWarning, Solution
from .._status import ImpactKind, Status
from .._sweep import sweep

TWO_PI = 2 * math.pi


@dataclass(frozen=True)
class RunConfig:
    """Static settings of one compiled simulator (changing them recompiles)."""

    rtol: float
    atol: float
    max_impacts: int
    max_steps: int
    n_save: int  # saved states per call (0: no dense output)
    lanes: int = 0  # pad batches of starts to this size (one compiled shape); 0: no padding


# Short accurate runs (orbex2, exnonaxial, smalldisc): one call each.
SHORT = RunConfig(rtol=1e-10, atol=1e-12, max_impacts=128, max_steps=200_000, n_save=2000,
                lanes=2)
# ex1dof: long runs in chunks of at most CHUNK time units, few saves per chunk.
LONG = RunConfig(rtol=1e-8, atol=1e-10, max_impacts=128, max_steps=400_000, n_save=400,
               lanes=3)
# ex1dof bifurcation sweep: no dense output, batched over μ.
SWEEP = RunConfig(rtol=1e-8, atol=1e-10, max_impacts=128, max_steps=400_000, n_save=0)
CHUNK = 500.0


@functools.cache
def paper_scene(name: str):
    # One Scene object per example, so that jit caches keyed on it are reused.
    return examples.PAPER_SCENES[name][0]()


def paper_args(name: str, *a, **kw):
    return examples.PAPER_SCENES[name][1](*a, **kw)


def _pad(rows: list[np.ndarray], width: int, fill=np.nan, dtype=float) -> np.ndarray:
    """Stack ragged per-lane arrays along a new first axis, padding to `width`."""
    shape = (len(rows), width) + (rows[0].shape[1:] if rows and rows[0].ndim > 1 else ())
    out = np.full(shape, fill, dtype=dtype)
    for i, row in enumerate(rows):
        out[i, : len(row)] = row
    return out


def run_batch(
    scene_name: str,
    cfg: RunConfig,
    starts,
    args,
    t1: float,
    *,
    batch_args: bool = False,
    boundaries: Sequence[float] | None = None,
    saveat: np.ndarray | None = None,
) -> Solution:
    """Simulate every start from t = 0 to `t1`; return one batched `Solution` (NumPy).

    The run is cut at `boundaries` (chunk ends, default: one chunk); each chunk restarts
    from the state reached (after `MAX_IMPACTS` a lane resumes from its last impact). Saved
    states: `saveat` (a global sorted grid, at most `cfg.n_save` points per chunk), or
    `cfg.n_save` uniform points per chunk. Logs and saves are stitched per lane and padded
    with NaN; `num_steps` are summed.
    """
    x_now = np.atleast_2d(np.array(starts, dtype=float))
    n_real = x_now.shape[0]
    if cfg.lanes and not batch_args and n_real < cfg.lanes:
        # Same batch shape for every call: pad with copies of the last start (dropped below).
        x_now = np.concatenate([x_now, np.repeat(x_now[-1:], cfg.lanes - n_real, axis=0)])
    batch = x_now.shape[0]
    ends = sorted(set([float(b) for b in (boundaries or []) if 0 < b < t1] + [float(t1)]))
    t_now = np.zeros(batch)
    status = np.full(batch, int(Status.SUCCESS))
    stopped = np.zeros(batch, dtype=bool)
    lanes = _Stitched(batch)
    calls = 0
    for end in ends:
        while True:
            active = (~stopped) & (t_now < end)
            if not active.any():
                break
            calls += 1
            if calls > 10_000:
                raise RuntimeError("run_batch made no progress (internal error)")
            t0s = np.where(active, t_now, end - 1.0)
            grids = _save_grids(cfg, saveat, t0s, end)
            for i, sol, row in _sweep(scene_name, cfg, x_now, args, t0s, end, grids, active,
                                      batch_args):
                lanes.append(i, sol, row, t0s[i], saved=grids is not None)
                code = int(sol.status[row])
                t_reached = float(sol.t_final[row])
                if code == Status.SUCCESS:
                    t_now[i] = end
                elif code == Status.MAX_IMPACTS and t_reached > t_now[i]:
                    t_now[i] = t_reached
                else:
                    stopped[i], status[i], t_now[i] = True, code, t_reached
                x_now[i] = sol.x_final[row]
    sol = lanes.solution(t_now, x_now, status, saved=bool(cfg.n_save))
    return jax.tree.map(lambda leaf: leaf[:n_real], sol)


def _sweep(scene_name: str, cfg: RunConfig, x_now, args, t0s, end: float, grids, active,
           batch_args: bool):
    """One chunk of the active lanes through `grazejax.sweep`: `(lane, sol, row)` for each.

    `sweep` takes one start time per call, so the lanes run in groups of equal start time
    (one group unless some lane resumed after `MAX_IMPACTS`). Each call has the width of the
    whole batch (padded with copies of a lane of the group): one compiled program.
    """
    scene = paper_scene(scene_name)
    batch = len(t0s)
    flags = jax.tree.map(lambda _: batch_args, args)
    for t0 in np.unique(t0s[active]):
        members = np.flatnonzero(active & (t0s == t0))
        index = np.concatenate([members, np.full(batch - len(members), members[0])])
        lane_args = (jax.tree.map(lambda leaf, index=index: np.asarray(leaf)[index], args)
                     if batch_args else args)
        # `run_batch` keeps each lane's status in the Solution it returns; a warning per
        # chunk (padding lanes included) would count the same lanes again and again.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FailedLanesWarning)
            sol = sweep(
                scene, x_now[index], float(t0), end, lane_args, args_batched=flags,
                balance="none", progress=False, rtol=cfg.rtol, atol=cfg.atol,
                max_impacts=cfg.max_impacts, max_steps=cfg.max_steps,
                saveat=None if grids is None else grids[members[0]],
            )
        for row, i in enumerate(members):
            yield i, sol, row


def _save_grids(cfg: RunConfig, saveat, t0s, end: float) -> np.ndarray | None:
    """The save times of one chunk, `cfg.n_save` per lane (padded with `end`), or None."""
    if not cfg.n_save:
        return None
    grids = np.empty((len(t0s), cfg.n_save))
    for i in range(len(t0s)):
        if saveat is not None:
            g = saveat[(saveat >= t0s[i]) & (saveat <= end)]
            if len(g) > cfg.n_save:
                raise ValueError(
                    f"{len(g)} save times in one chunk, more than n_save={cfg.n_save}"
                )
        else:
            g = np.linspace(t0s[i], end, cfg.n_save)
        g = np.concatenate([g, np.full(cfg.n_save - len(g), end)])
        grids[i] = g
    return grids


_LOG_FIELDS = (("t", "impact_times"), ("pre", "impact_pre"), ("post", "impact_post"),
               ("surface", "impact_surface"), ("kind", "impact_kind"))


class _Stitched:
    """The chunks of each lane of `run_batch`: impact logs, saved states, step counts."""

    def __init__(self, batch: int):
        self.batch = batch
        self.ts = [[] for _ in range(batch)]
        self.xs = [[] for _ in range(batch)]
        self.logs = {key: [[] for _ in range(batch)] for key, _ in _LOG_FIELDS}
        self.steps = np.zeros(batch, dtype=np.int64)
        self.accepted = np.zeros(batch, dtype=np.int64)

    def append(self, i: int, sol: Solution, row: int, t0: float, *, saved: bool) -> None:
        """Lane `i`'s chunk: row `row` of the batched `sol`, started at `t0`."""
        k = int(sol.num_impacts[row])
        for key, field in _LOG_FIELDS:
            self.logs[key][i].append(getattr(sol, field)[row][:k])
        if saved:
            ts_i, xs_i = sol.ts[row], sol.xs[row]
            ok = np.isfinite(ts_i) & np.all(np.isfinite(xs_i), axis=-1)
            if t0 > 0:  # the chunk's start state was saved by the chunk before
                ok &= ts_i > t0
            self.ts[i].append(ts_i[ok])
            self.xs[i].append(xs_i[ok])
        self.steps[i] += int(sol.num_steps[row])
        self.accepted[i] += int(sol.num_accepted_steps[row])

    def solution(self, t_final, x_final, status, *, saved: bool) -> Solution:
        """One batched `Solution`: the chunks concatenated, lanes padded with NaN."""

        def cat(parts, empty_shape):
            return [np.concatenate(p) if p else np.zeros(empty_shape) for p in parts]

        n = x_final.shape[1]
        log_t = cat(self.logs["t"], (0,))
        width = max(1, max(len(v) for v in log_t))
        ts = xs = None
        if saved:
            ts_l, xs_l = cat(self.ts, (0,)), cat(self.xs, (0, n))
            save_width = max(1, max(len(v) for v in ts_l))
            ts, xs = _pad(ts_l, save_width), _pad(xs_l, save_width)
        kinds = cat(self.logs["kind"], (0,))
        return Solution(
            t_final=t_final.copy(),
            x_final=x_final.copy(),
            num_impacts=np.array([len(v) for v in log_t]),
            impact_times=_pad(log_t, width),
            impact_pre=_pad(cat(self.logs["pre"], (0, n)), width),
            impact_post=_pad(cat(self.logs["post"], (0, n)), width),
            impact_surface=_pad(cat(self.logs["surface"], (0,)), width, fill=-1, dtype=int),
            impact_kind=_pad(kinds, width, fill=int(ImpactKind.NONE), dtype=int),
            status=status,
            zeno_time=np.full(self.batch, np.nan),
            num_steps=self.steps,
            num_accepted_steps=self.accepted,
            ts=ts,
            xs=xs,
        )


def long_schedule(t1: float, head: float, tail: float, chunk: float = CHUNK) -> list[float]:
    """Chunk ends: a dense head [0, head], chunks of ≤ `chunk`, a dense tail [t1-tail, t1]."""
    middle = np.arange(head, t1 - tail, chunk).tolist()
    return sorted(set([head, *middle, t1 - tail, t1]))


# JSON-ready summaries of runs (for report.json)


def as_float(x) -> float:
    return float(np.asarray(x))


def as_list(x) -> list[float]:
    return [float(v) for v in np.asarray(x).ravel()]


def impact_record(log, j, scene) -> dict:
    return {
        "t": as_float(log["times"][j]),
        "surface": scene.surface_name(int(log["surface"][j])),
        "kind": ImpactKind(int(log["kind"][j])).name,
        "pre": as_list(log["pre"][j]),
        "post": as_list(log["post"][j]),
    }


def run_record(sol, i: int, start, label: str, scene_name: str) -> dict:
    """JSON-ready summary of lane `i` (started at `start` at t = 0): status, impacts, end."""
    scene = paper_scene(scene_name)
    one = plot.lane(sol, i)
    log = plot.impacts_of(one)
    rec = {
        "label": label,
        "start": as_list(start),
        "t_final": as_float(one.t_final),
        "status": Status(int(one.status)).name,
        "num_impacts": int(one.num_impacts),
        "impacts_by_surface": {
            scene.surface_name(int(s)): int(c)
            for s, c in zip(*np.unique(log["surface"], return_counts=True), strict=True)
        },
        "impact_kinds": {
            ImpactKind(int(k)).name: int(c)
            for k, c in zip(*np.unique(log["kind"], return_counts=True), strict=True)
        },
        "final_state": as_list(one.x_final),
        "num_steps": int(one.num_steps),
    }
    if len(log["times"]):
        rec["first_impact"] = impact_record(log, 0, scene)
        rec["last_impact"] = impact_record(log, len(log["times"]) - 1, scene)
    return rec
