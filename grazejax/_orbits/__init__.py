"""Periodic orbits, their stability and their continuation: the orbit package.

Each module calls only those below it, and only the period map calls `simulate`:

- `bifurcation_curve` (`continue_bifurcation`, every kind), `locate`
  (`locate_bifurcation`, every kind), `grazing_curve` (`continue_grazing`,
  `locate_grazing`), `continuation` (`continue_orbit`): the front ends, each of the first
  two passing a grazing point to the grazing one;
- `switching` (grazing located and switched through, special points between accepted
  points), `family` (one family's unknown, corrector and corrected points) and `branch`
  (`Branch`, `GrazingPoint`, `SpecialPoint`): `continue_orbit`'s parts;
- `bifurcation`: the defining systems of fold, period-doubling and Neimark–Sacker points,
  solved by Newton (`locate_special`);
- `arclength`: the one pseudo-arclength engine and its corrector;
- `contacts`, `floquet`: what an orbit meets and its multipliers from per-impact factors;
- `periodic`: the periodic-orbit solve (`find_periodic_orbit`, `Orbit`);
- `period_map`: one period of `simulate`, its linearization and the tolerance conventions.

The names these modules share carry no underscore; the public API is `grazejax`'s.
"""
