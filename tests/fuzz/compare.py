"""Run grazejax and the independent reference on random systems; compare; classify.

One `jit(vmap(simulate))` per (family, solver, tolerance, saveat) is compiled and kept
(`runner`). A system *agrees* when statuses, impact counts and surfaces are equal and impact
times, pre/post states and final states are within

    tol_t = 1e3 · rtol · (1 + |t1 − t0|),   tol_x = tol_t · (1 + max |x|)

(rtol = atol, grazejax's tolerance). Every disagreement — and every system whose own impact
log contradicts the semantics (`self_check`: a logged pre-impact state off its surface,
outside its piece, moving away, or a post state that is not J(pre)) — is classified:

- **grazejax defect**: the log contradicts the semantics; or, on an unambiguous system
  (below), grazejax's counts/surfaces/status differ from the reference's, or its numbers do
  and still do at rtol = atol = 1e-12; or a state that grazejax saves (`saveat`, 1e-12)
  lies below a surface inside its piece with no impact logged in between;
- **reference doubt**: the reference failed, or disagrees with itself when re-run at
  rtol = atol = 3e-14 with 4× finer scans;
- **ill-conditioned**: before the first disagreement the reference met a close call within
  δ = 1e3 · rtol · (1 + |t1 − t0|) (a dip within δ of 0, a crossing within δ of a `where`
  boundary, contacts of two surfaces within δ of each other, an event within δ of t1, a
  jump landing within δ of an impenetrable wall, an almost geometric impact sequence when
  Zeno is at stake), or the system amplifies a 1e-8 perturbation of x0 by more than
  10 (1 + |t1 − t0|) (or changes its impact sequence);
- **tolerance**: only numbers differ, and grazejax at 1e-12 agrees (an unambiguous
  system whose global error exceeded 1e3·rtol at the base tolerance).
"""

import collections
import dataclasses
import functools
import math

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

import grazejax as gj
from tests.mappings import release_compiled_programs

from . import reference as ref
from .generator import Family, families

SOLVERS = {
    "Tsit5": lambda: None,
    "Dopri5": diffrax.Dopri5,
    "Dopri8": diffrax.Dopri8,
    "Vern9": gj.Vern9,
}
BASE_TOL = 1e-10
TIGHT_TOL = 1e-12
MAX_STEPS = 20_000
SAVES = 400
CLASSES = ("grazejax defect", "reference doubt", "ill-conditioned", "tolerance")

for _code, _name in ref.STATUS_NAMES.items():
    assert gj.Status[_name] == _code, _name


def _simulate(fam: Family, solver: str, tol: float, x0, args, t0, t1, **kw):
    """`simulate` of one system of `fam` with the campaign's settings."""
    return gj.simulate(
        fam.scene,
        x0,
        t0,
        t1,
        args,
        solver=SOLVERS[solver](),
        rtol=tol,
        atol=tol,
        max_impacts=fam.max_impacts,
        max_steps=MAX_STEPS,
        direction=fam.direction,
        **kw,
    )


@functools.cache
def runner(family_name: str, solver: str, tol: float, saves: int = 0):
    """jit(vmap) of simulate for one family: (x0, args, t0, t1) batched -> dict of arrays."""
    fam = families()[family_name]

    def one(x0, args, t0, t1):
        saveat = None if not saves else jnp.linspace(t0, t1, saves)
        sol = _simulate(fam, solver, tol, x0, args, t0, t1, saveat=saveat)
        out = dict(
            status=sol.status,
            num_impacts=sol.num_impacts,
            t_final=sol.t_final,
            x_final=sol.x_final,
            times=sol.impact_times,
            pre=sol.impact_pre,
            post=sol.impact_post,
            surfaces=sol.impact_surface,
            kinds=sol.impact_kind,
        )
        if saves:
            out.update(ts=sol.ts, xs=sol.xs)
        return out

    return jax.jit(jax.vmap(one))


# Lanes run in chunks of one size, the last padded with copies of its last lane: one
# compiled program per family, solver and settings whatever the number of lanes, which the
# default and slow jobs' campaigns (and the reruns of a few suspects) share through JAX's
# persistent compilation cache.
CHUNK = 64


def run_gj(family_name, solver, batch, lanes=None, tol=BASE_TOL, saves=0):
    lanes = np.arange(len(batch)) if lanes is None else np.asarray(lanes)
    padded = np.concatenate([lanes, np.repeat(lanes[-1:], -len(lanes) % CHUNK)])
    run = runner(family_name, solver, tol, saves)
    rows = []
    for start in range(0, len(padded), CHUNK):
        part = padded[start : start + CHUNK]
        out = run(
            jnp.asarray(batch.x0[part]),
            {k: jnp.asarray(v[part]) for k, v in batch.args.items()},
            jnp.asarray(batch.t0[part]),
            jnp.asarray(batch.t1[part]),
        )
        out = {k: np.asarray(v) for k, v in out.items()}
        rows += [{k: v[j] for k, v in out.items()} for j in range(len(part))]
    return rows[: len(lanes)]


def run_ref(fam: Family, batch, i, **kw):
    return ref.run(
        fam,
        batch.x0[i],
        batch.t0[i],
        batch.t1[i],
        batch.lane(i),
        max_impacts=fam.max_impacts,
        freq=batch.freq[i],
        **kw,
    )


# --------------------------------------------------------------------------------------
# Comparison


def _scale(batch, i):
    return 1.0 + abs(batch.t1[i] - batch.t0[i])


BLOW_UP = (gj.Status.MAX_STEPS, gj.Status.NONFINITE, gj.Status.STEP_SIZE_UNDERFLOW)


def differences(g, r: ref.RefResult, t_scale, tol):
    """(structural reasons, numeric reasons, worst numeric error / its tolerance)."""
    structural, numeric = [], []
    tol_t = 1e3 * tol * t_scale
    worst = 0.0
    k_g, k_r = int(g["num_impacts"]), r.num_impacts
    logged = min(k_g, k_r, len(g["times"]))
    status = int(g["status"])
    blow_up = r.status == ref.STEP_SIZE_UNDERFLOW and status in BLOW_UP
    if status != r.status and not blow_up:
        structural.append(f"status {gj.Status(status).name} vs {ref.STATUS_NAMES[r.status]}")
    if k_g != k_r:
        structural.append(f"{k_g} impacts vs {k_r}")
    for k in range(logged):
        tg, tr = float(g["times"][k]), r.times[k]
        if int(g["surfaces"][k]) != r.surfaces[k]:
            structural.append(f"impact {k}: surface {int(g['surfaces'][k])} vs {r.surfaces[k]}")
            break
        x_scale = 1 + max(np.max(np.abs(r.pre[k])), np.max(np.abs(r.post[k])))
        dx = max(np.max(np.abs(g["pre"][k] - r.pre[k])), np.max(np.abs(g["post"][k] - r.post[k])))
        ratio = max(abs(tg - tr) / tol_t, dx / (tol_t * x_scale))
        if not ratio <= 1:
            worst = max(worst, ratio) if math.isfinite(ratio) else math.inf
            numeric.append(f"impact {k}: t {tg:.15g} vs {tr:.15g}, states differ by {dx:.3g}")
    if not structural and r.status in (ref.SUCCESS, ref.MAX_IMPACTS):
        x_scale = 1 + np.max(np.abs(r.x_final))
        err = np.max(np.abs(g["x_final"] - r.x_final))
        if not err <= tol_t * x_scale:
            worst = max(worst, err / (tol_t * x_scale)) if math.isfinite(err) else math.inf
            numeric.append(f"x_final differs by {err:.3g}")
    if len(numeric) > 3:
        numeric = numeric[:3] + [f"... {len(numeric) - 3} more numeric differences"]
    return structural, numeric, worst


def first_difference_time(g, r: ref.RefResult, t1):
    """Times of the first impact that is not in both logs (or where the runs stopped, if
    they stopped differently; t1 if the logs agree)."""
    k_g = int(g["num_impacts"])
    for k in range(max(k_g, r.num_impacts)):
        in_g = k < min(k_g, len(g["times"]))
        in_r = k < r.num_impacts
        if not (in_g and in_r) or int(g["surfaces"][k]) != r.surfaces[k]:
            times = ([float(g["times"][k])] if in_g else []) + ([r.times[k]] if in_r else [])
            return times or [float(g["t_final"]), r.t_final]
        if abs(float(g["times"][k]) - r.times[k]) > 1e-6 * (1 + abs(r.times[k])):
            return [float(g["times"][k]), r.times[k]]
    if int(g["status"]) != r.status:
        return [float(g["t_final"]), r.t_final]
    return [t1]


def self_check(fam: Family, g, a, tol):
    """What grazejax's own log says against the semantics (no reference needed)."""
    problems = []
    sigma = fam.direction
    k_g = min(int(g["num_impacts"]), len(g["times"]))
    with np.errstate(all="ignore"):
        for k in range(k_g):
            i, t = int(g["surfaces"][k]), float(g["times"][k])
            pre, post = g["pre"][k].astype(float), g["post"][k].astype(float)
            if i < 0 or i >= len(fam.surfaces):
                problems.append(f"impact {k}: surface index {i}")
                continue
            spec = fam.surfaces[i]
            scale = 1 + np.max(np.abs(pre)) + np.max(np.abs(post))
            band = 1e3 * tol * scale
            law = spec.jump if sigma > 0 else spec.inverse
            if law is not None:
                err = np.max(np.abs(law(t, pre, a, np) - post))
                if err > 1e-9 * scale:
                    problems.append(f"impact {k}: post differs from the jump of pre by {err:.3g}")
            z = pre if sigma > 0 else post
            g_on = float(spec.phi(t, spec.inverse(t, pre, a, np) if sigma < 0 else pre, a, np))
            if abs(g_on) > band:
                problems.append(f"impact {k} (surface {i}, t = {t:.15g}): gap at pre {g_on:.3g}")
            if spec.margin is not None:
                margin = float(spec.margin(t, z, a, np))
                if margin < -band:
                    problems.append(
                        f"impact {k} (surface {i}, t = {t:.15g}): outside its piece "
                        f"by {-margin:.3g}"
                    )
            h = 1e-30
            v = fam.field(t, z, a, np)
            rate = float(np.imag(spec.phi(t + 1j * h, z + 1j * h * v, a, np)) / h)
            if rate > 1e-3 * (1 + np.max(np.abs(v))):
                problems.append(
                    f"impact {k} (surface {i}, t = {t:.15g}): gap increasing (dΦ/dt = {rate:.3g})"
                )
        if k_g >= 2:
            steps = sigma * np.diff(g["times"][:k_g])
            if np.any(steps < 0):
                problems.append("impact times not monotone")
    return problems


def saveat_check(fam: Family, g, a):
    """Saved states below a surface inside its piece, entered with no impact logged."""
    if fam.direction < 0:
        return []
    ts, xs = g["ts"], g["xs"]
    k_g = min(int(g["num_impacts"]), len(g["times"]))
    logged = np.asarray(g["times"][:k_g], float)
    out = []
    with np.errstate(all="ignore"):
        for i, spec in enumerate(fam.surfaces):
            ok = np.isfinite(ts)
            phi = np.where(ok, spec.phi(ts, xs.T, a, np), np.nan)
            margin = (
                np.full(len(ts), np.inf) if spec.margin is None else spec.margin(ts, xs.T, a, np)
            )
            band = 1e-6 * (1 + np.nanmax(np.abs(xs)))
            for k in range(len(ts) - 1):
                if not (phi[k] > band and phi[k + 1] < -band):
                    continue
                if not (margin[k] > band and margin[k + 1] > band):
                    continue
                if np.any((logged > ts[k]) & (logged <= ts[k + 1])):
                    continue
                out.append(
                    f"surface {i}: saved state at t = {ts[k + 1]:.15g} has Φ = "
                    f"{phi[k + 1]:.3g} inside the piece, none logged since {ts[k]:.15g}"
                )
                break
    return out


def close_calls(r: ref.RefResult, cut, delta, zeno_at_stake, sigma):
    """The reference's close calls met up to the disagreement (the latest of the times in
    `cut`, in the run's direction)."""
    reasons = []
    tests = {
        "dip": delta,
        "where": delta,
        "approach": delta,
        "simultaneous": delta,
        "t1": delta,
        "t1_gap": delta,
        "jump": delta,
    }
    if zeno_at_stake:
        tests["zeno_ratio"] = 0.3
    latest = max(sigma * t for t in cut)
    for key, limit in tests.items():
        for t, value in r.diag.get(key, []):
            if sigma * t <= latest + delta and value <= limit:
                reasons.append(f"{key} {value:.2g} at t = {t:.6g}")
                break
    return reasons


@dataclasses.dataclass
class Record:
    family: str
    solver: str
    lane: int
    outcome: str  # "agree" or one of CLASSES
    reasons: list
    system: dict | None = None  # x0, t0, t1, args of a defect (a reproducer)


def sensitivity(fam, batch, i, r, rng, cut):
    """Whether a 1e-8 perturbation of x0 changes the impact sequence, or is amplified by
    more than 10 (1 + T), before the disagreement (the latest time in `cut`)."""
    x0 = batch.x0[i]
    eps = 1e-8 * (1 + np.max(np.abs(x0)))
    d = rng.normal(size=x0.shape)
    pert = ref.run(
        fam,
        x0 + eps * d / np.linalg.norm(d),
        batch.t0[i],
        batch.t1[i],
        batch.lane(i),
        max_impacts=fam.max_impacts,
        freq=batch.freq[i],
    )
    sigma = fam.direction
    latest = max(sigma * t for t in cut) + 1e-6 * _scale(batch, i)
    k = sum(sigma * t <= latest for t in r.times)
    k_p = sum(sigma * t <= latest for t in pert.times)
    if k != k_p or pert.surfaces[:k] != r.surfaces[:k]:
        return "a 1e-8 change of x0 changes the impact sequence before the disagreement"
    amp = max(
        [abs(a - b) / eps for a, b in zip(pert.times[:k], r.times[:k], strict=True)], default=0.0
    )
    at_end = latest >= sigma * batch.t1[i]
    if at_end and pert.status != r.status:
        return "a 1e-8 change of x0 changes the status"
    if at_end and r.status in (ref.SUCCESS, ref.MAX_IMPACTS):
        amp = max(amp, np.max(np.abs(pert.x_final - r.x_final)) / eps)
    if amp > 10 * _scale(batch, i):
        return f"amplifies a change of x0 by {amp:.3g}"
    return None


def compare_family(fam: Family, solver: str, batch, tol=BASE_TOL, rng=None, refs=None):
    """Records for every lane of `batch` (refs: reference results, computed if None)."""
    rng = rng or np.random.default_rng(0)
    gjs = run_gj(fam.name, solver, batch, tol=tol)
    refs = refs or [run_ref(fam, batch, i) for i in range(len(batch))]
    records, suspects = [], []
    for i, (g, r) in enumerate(zip(gjs, refs, strict=True)):
        structural, numeric, worst = differences(g, r, _scale(batch, i), tol)
        own = self_check(fam, g, batch.lane(i), tol)
        if own:
            records.append(Record(fam.name, solver, i, "grazejax defect", own + structural))
        elif structural or numeric or r.failed:
            suspects.append((i, g, r, structural, numeric, worst))
        else:
            records.append(Record(fam.name, solver, i, "agree", []))
    if suspects:
        records += _classify(fam, solver, batch, suspects, tol, rng)
    for rec in records:
        if rec.outcome == "grazejax defect":
            i = rec.lane
            rec.system = {
                "x0": batch.x0[i].tolist(),
                "t0": float(batch.t0[i]),
                "t1": float(batch.t1[i]),
                "args": {k: np.asarray(v).tolist() for k, v in batch.lane(i).items()},
            }
    return sorted(records, key=lambda rec: rec.lane), gjs, refs


def _as_gj(r: ref.RefResult):
    """A reference result in the shape of `run_gj`'s rows (to compare two references)."""
    return {
        "status": r.status,
        "num_impacts": r.num_impacts,
        "t_final": r.t_final,
        "times": np.array(r.times + [np.nan]),
        "surfaces": np.array(r.surfaces + [-1]),
        "pre": np.array(r.pre + [r.x_final]),
        "post": np.array(r.post + [r.x_final]),
        "x_final": r.x_final,
    }


def _classify(fam, solver, batch, suspects, tol, rng):
    out = []
    pending = []
    for i, g, r, structural, numeric, worst in suspects:
        reasons = structural + numeric
        if r.failed:
            out.append(Record(fam.name, solver, i, "reference doubt", [r.failed] + reasons))
            continue
        cut = first_difference_time(g, r, batch.t1[i])
        delta = 1e3 * tol * _scale(batch, i)
        zeno = int(g["status"]) == ref.ZENO or r.status == ref.ZENO
        calls = close_calls(r, cut, delta, zeno, fam.direction)
        if calls:
            out.append(Record(fam.name, solver, i, "ill-conditioned", calls + reasons))
            continue
        sens = sensitivity(fam, batch, i, r, rng, cut)
        if sens:
            out.append(Record(fam.name, solver, i, "ill-conditioned", [sens] + reasons))
            continue
        tight = run_ref(fam, batch, i, rtol=3e-14, atol=3e-14, scan=128)
        s2, n2, _ = differences(_as_gj(tight), r, _scale(batch, i), 1e-12)
        if s2 or n2 or tight.failed:
            out.append(
                Record(
                    fam.name,
                    solver,
                    i,
                    "reference doubt",
                    ["reference at 3e-14: " + "; ".join(s2 + n2)] + reasons,
                )
            )
            continue
        pending.append((i, r, structural, numeric, worst))
    if pending:
        lanes = [p[0] for p in pending]
        tight_gj = run_gj(fam.name, solver, batch, lanes, tol=TIGHT_TOL, saves=SAVES)
        for (i, r, structural, numeric, worst), g2 in zip(pending, tight_gj, strict=True):
            reasons = structural + numeric
            tunnel = saveat_check(fam, g2, batch.lane(i))
            s2, n2, _ = differences(g2, r, _scale(batch, i), TIGHT_TOL)
            if tunnel:
                out.append(
                    Record(
                        fam.name,
                        solver,
                        i,
                        "grazejax defect",
                        reasons + ["at 1e-12: " + t for t in tunnel],
                    )
                )
            elif structural or s2 or n2 or worst > 100:
                out.append(
                    Record(
                        fam.name,
                        solver,
                        i,
                        "grazejax defect",
                        reasons + ["at 1e-12: " + ("; ".join(s2 + n2) or "agrees")],
                    )
                )
            else:
                out.append(Record(fam.name, solver, i, "tolerance", reasons))
    return out


# --------------------------------------------------------------------------------------
# Campaigns


def plan(solvers_per_family: int | None = None):
    """(family, solver) pairs: every family with every solver, or (default suite) each
    family with `solvers_per_family` solvers taken in rotation."""
    names = list(families())
    solvers = list(SOLVERS)
    if solvers_per_family is None:
        return [(f, s) for f in names for s in solvers]
    return [
        (f, solvers[(j + k) % len(solvers)])
        for j, f in enumerate(names)
        for k in range(solvers_per_family)
    ]


def campaign(pairs, lanes: int, seed: int, tol=BASE_TOL, progress=None, first: int = 0):
    """Run `lanes` random systems per (family, solver) pair; returns the records. Pair j's
    systems are drawn from the seed (`seed`, `first` + j): a campaign split into parts
    (`first` = the part's offset in the whole list) draws the whole one's systems."""
    records = []
    for j, (name, solver) in enumerate(pairs, start=first):
        fam = families()[name]
        rng = np.random.default_rng([seed, j])
        batch = fam.sample(rng, lanes)
        recs, _, _ = compare_family(fam, solver, batch, tol=tol, rng=rng)
        records += recs
        if progress:
            progress(name, solver, recs)
        release_compiled_programs()
    return records


def table(records) -> str:
    """Markdown counts: systems, agreeing, and disagreements by class, per family × solver."""
    rows = collections.defaultdict(collections.Counter)
    for rec in records:
        rows[(rec.family, rec.solver)][rec.outcome] += 1
    head = "| family | solver | systems | agree | " + " | ".join(CLASSES) + " |"
    lines = [head, "|" + "---|" * (4 + len(CLASSES))]
    total = collections.Counter()
    for (fam, solver), counts in sorted(rows.items()):
        n = sum(counts.values())
        total.update(counts)
        lines.append(
            f"| {fam} | {solver} | {n} | {counts['agree']} | "
            + " | ".join(str(counts[c]) for c in CLASSES)
            + " |"
        )
    per_solver = collections.defaultdict(collections.Counter)
    for rec in records:
        per_solver[rec.solver][rec.outcome] += 1
    for solver, counts in sorted(per_solver.items()):
        lines.append(
            f"| all | {solver} | {sum(counts.values())} | {counts['agree']} | "
            + " | ".join(str(counts[c]) for c in CLASSES)
            + " |"
        )
    lines.append(
        f"| **all** | **all** | {sum(total.values())} | {total['agree']} | "
        + " | ".join(str(total[c]) for c in CLASSES)
        + " |"
    )
    return "\n".join(lines)


def defects(records):
    return [rec for rec in records if rec.outcome == "grazejax defect"]


# --------------------------------------------------------------------------------------
# Derivatives


@functools.cache
def derivative_runner(family_name: str, solver: str, tol: float):
    """(jit(vmap(jacfwd)) of x_final w.r.t. x0, jit(vmap(grad)) of w · x_final with a
    checkpointed reverse adjoint)."""
    fam = families()[family_name]

    def final(x0, args, t0, t1, adjoint):
        sol = _simulate(fam, solver, tol, x0, args, t0, t1, adjoint=adjoint)
        return sol.x_final, sol.num_impacts

    def forward(x0, args, t0, t1):
        jac = jax.jacfwd(lambda x: final(x, args, t0, t1, None)[0])(x0)
        return jac, final(x0, args, t0, t1, None)[1]

    def reverse(x0, args, t0, t1, w):
        adjoint = diffrax.RecursiveCheckpointAdjoint()
        return jax.grad(lambda x: w @ final(x, args, t0, t1, adjoint)[0])(x0)

    return jax.jit(jax.vmap(forward)), jax.jit(jax.vmap(reverse))


def transversal(fam, batch, i, r: ref.RefResult, margin=1e-2, min_rate=0.05):
    """Whether every impact of the reference run is transversal and far from every close
    call (so that x_final is smooth in x0 near x0)."""
    if r.failed or r.status not in (ref.SUCCESS, ref.MAX_IMPACTS):
        return False
    if any(rate < min_rate for rate in r.rates):
        return False
    if r.status == ref.MAX_IMPACTS:
        return False  # t_final is an impact time: x_final jumps with x0 there
    return not close_calls(r, [batch.t1[i]], margin, True, fam.direction)


def reference_jacobian(fam, batch, i, r, h):
    """Central differences of the reference's x_final (None if a perturbed run changes the
    impact sequence), and an estimate of their error (|D_h − D_2h|)."""
    x0 = batch.x0[i]
    cols = {}
    for step in (h, 2 * h):
        columns = []
        for k in range(len(x0)):
            e = np.zeros_like(x0)
            e[k] = step
            runs = [
                ref.run(
                    fam,
                    x0 + s * e,
                    batch.t0[i],
                    batch.t1[i],
                    batch.lane(i),
                    max_impacts=fam.max_impacts,
                    freq=batch.freq[i],
                )
                for s in (1, -1)
            ]
            if any(q.surfaces != r.surfaces or q.status != r.status for q in runs):
                return None, None
            columns.append((runs[0].x_final - runs[1].x_final) / (2 * step))
        cols[step] = np.stack(columns, axis=1)
    return cols[h], np.max(np.abs(cols[h] - cols[2 * h]))


def derivative_campaign(pairs, lanes: int, seed: int, tol=BASE_TOL, first: int = 0):
    """Compare jacfwd and reverse-mode grad of x_final with the reference's central
    differences on transversal systems. Returns rows (family, solver, lane, error of
    jacfwd, error of grad, tolerance). `first`: as in `campaign`."""
    rows = []
    for j, (name, solver) in enumerate(pairs, start=first):
        fam = families()[name]
        rng = np.random.default_rng([seed, 1000 + j])
        batch = fam.sample(rng, lanes, grazing_fraction=0.0)
        refs = [run_ref(fam, batch, i) for i in range(lanes)]
        keep = [i for i in range(lanes) if transversal(fam, batch, i, refs[i])]
        fds = {}
        for i in keep:
            h = 1e-5 * (1 + np.max(np.abs(batch.x0[i])))
            fd, err = reference_jacobian(fam, batch, i, refs[i], h)
            if fd is not None:
                fds[i] = (fd, err)
        if not fds:
            continue
        idx = np.array(sorted(fds))
        w = rng.normal(size=(len(idx), fam.n))
        forward, reverse = derivative_runner(name, solver, tol)
        args = {k: jnp.asarray(v[idx]) for k, v in batch.args.items()}
        inputs = (
            jnp.asarray(batch.x0[idx]),
            args,
            jnp.asarray(batch.t0[idx]),
            jnp.asarray(batch.t1[idx]),
        )
        jac, count = (np.asarray(a) for a in forward(*inputs))
        grad = np.asarray(reverse(*inputs, jnp.asarray(w)))
        for k, i in enumerate(idx):
            fd, fd_err = fds[i]
            size = 1 + np.max(np.abs(fd))
            tolerance = 1e3 * tol * _scale(batch, i) * size + 10 * fd_err
            err_fwd = np.max(np.abs(jac[k] - fd))
            err_rev = np.max(np.abs(grad[k] - fd.T @ w[k]))
            if int(count[k]) != refs[i].num_impacts:
                err_fwd = err_rev = math.inf
            rows.append((name, solver, int(i), float(err_fwd), float(err_rev), float(tolerance)))
        release_compiled_programs()
    return rows
