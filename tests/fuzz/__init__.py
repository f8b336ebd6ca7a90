"""Random-scene differential fuzzing of grazejax against an independent SciPy event loop.

- `generator`: seeded families of random impact systems (structure fixed per family, all
  random numbers in `args`, so one compiled program serves a whole family);
- `reference`: an event loop written from docs/semantics.md with SciPy only (DOP853 at
  1e-13, or the exact flow), no grazejax code;
- `compare`: runs both, compares, classifies every disagreement;
- `campaign`: `python -m tests.fuzz.campaign --systems N --seed S` prints the counts table.
"""
