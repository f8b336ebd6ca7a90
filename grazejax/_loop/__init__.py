"""The impact loop as named phases over one typed state.

- `state.py`: `LoopState`, everything one lane carries from one solver step to the next.
- `context.py`: `LoopContext`, what every lane of one configuration shares (pieces, clock,
  tolerances, solver, controller), and the per-surface tests built on it.
- `step.py`: one solver step and the step-size controller's verdict on it.
- `stepping.py`: the loop's step-size controller and error norm.
- `unrolled.py`: explicit Runge–Kutta steps with their stages written out (the solver
  step the loop takes).
- `gaps.py`: every surface's gap along a step, sampled where the contact tests read it
  (and whether those samples resolve it: else the step is retaken shorter).
- `events.py`: the contact tests on a step's samples of a gap (crossings, dips, humps,
  whether the samples resolve it) and the located contact.
- `detect.py`: the search for a contact inside an accepted step.
- `land.py`: the landing step: Newton correction of the event time, jumps, impact log.
- `policies.py`: what happens at a Zeno accumulation or a sticking contact: the Zeno
  policies, with the hooks the phases call.
- `program.py`: `init`, `step`, `running`, `finish` of one lane, as a `Program`.
- `compact.py`: phases that only some lanes need, paid for by those lanes under `vmap`.
- `pool.py`: a refilling pool of lane slots that runs `Program.step` (`sweep`'s
  `balance="refill"`).
- `forward.py`: the forward-mode loop, in phases where they gain (the impact log written
  outside the loop that steps; sliding steps only while something slides).
- `reverse.py`: the loops that reverse mode differentiates, one per `adjoint` (two levels
  of checkpoints by default, every step stored, Equinox's checkpointed loop), built on
  `stored.py` (each step's linearisation stored) and `bounded.py` (`DirectAdjoint`'s
  nested scans).
- `replay.py`: the step decisions that reverse mode's re-runs of steps replay.
- `runners.py`: one loop class per kind of `adjoint` (`ForwardLoop`, `CheckpointedLoop`,
  `BoundedLoop`), each running its own loop over the program's phases.
"""
