"""Periodic orbits, their stability and their continuation: the orbit package.

Each module calls only those below it, and only the period map calls `simulate`:

- `continuation` (`continue_orbit`), `bifurcation_curve` (`continue_bifurcation`),
  `grazing_curve` (`continue_grazing`, `locate_grazing`): the front ends;
- `bifurcation`: the defining systems of fold, period-doubling and Neimark–Sacker points,
  solved by Newton (`locate_bifurcation`);
- `arclength`: the one pseudo-arclength engine and its corrector;
- `contacts`, `floquet`: what an orbit meets and its multipliers from per-impact factors;
- `periodic`: the periodic-orbit solve (`find_periodic_orbit`, `Orbit`);
- `period_map`: one period of `simulate`, its linearization and the tolerance conventions.

The names these modules share carry no underscore; the public API is `grazejax`'s.
"""
