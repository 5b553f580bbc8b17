"""Where a step test comes to rest, and the bound that sets on any one rig against Tables III and IV.

In eq. (3) the valve passes no flow only at P_L = P_s, so a step test that has settled rests where the cylinder
force, less the friction, equals the isolator force: A_p P_s - (mu N + F_c) = F_BW(y) (first line of eq. 3
with y' = 0; the table comes from below and stops at the first such point). Eq. (7) at steady state gives
y = a_s tanh(u / k), so the identified a_s is that rest position over tanh(u / k).

Whatever the rig is - its piston area, friction, valve, leakage - the force on the isolator at rest depends
only on the supply pressure and the command, not on the isolator. ``common_rest_force_bound`` finds, for each
(P_s, u) cell of two tables, the smallest relative a_s error that lets ONE force put both isolators at their
tabulated a_s: no rig under the paper's model can do better on that cell.
"""

from __future__ import annotations

import numpy as np

from .isolator import Isolator, simulate_loop
from .models import K_VOLT

BRANCH_MAX_DISPLACEMENT_M = 0.2  # far beyond the tables' largest a_s (0.043 m)
BRANCH_POINTS = 20001

Branch = tuple[np.ndarray, np.ndarray]  # displacement (m), force (N)


def loading_branch(isolator: Isolator, max_displacement_m: float = BRANCH_MAX_DISPLACEMENT_M,
                   points: int = BRANCH_POINTS, prior_excursion_m: float = 0.0) -> Branch:
    """Displacement (m) and Bouc-Wen force (N, eq. 4) on the loading branch: d rising from 0.

    From the virgin state (w = 0) by default; with ``prior_excursion_m`` the isolator first goes there and back
    to 0 (a previous test's history, e.g. +0.03 m leaves w near -1). The force rises monotonically along the
    branch, so a force can be turned back into a displacement by interpolation.
    """
    d = np.linspace(0.0, max_displacement_m, points)
    step = d[1] - d[0]
    n_prior = int(round(abs(prior_excursion_m) / step))
    prior = np.linspace(0.0, prior_excursion_m, n_prior + 1)
    path = np.concatenate([prior, prior[-2::-1], d[1:]]) if n_prior else d
    return d, simulate_loop(isolator, path, step)[-points:]


def rest_a_s_m(branch: Branch, force_n: float, step_v: float) -> float:
    """The a_s (m) eq. (7) identifies from a step test that rests where the isolator carries ``force_n``."""
    d, f = branch
    if not f[0] <= force_n <= f[-1]:
        raise ValueError(f"force {force_n:.4g} N outside the branch's {f[0]:.4g} .. {f[-1]:.4g} N")
    return float(np.interp(force_n, f, d)) / np.tanh(step_v / K_VOLT)


def common_rest_force_bound(tables: dict[str, dict[tuple[float, float], float]],
                            branches: dict[str, Branch]) -> dict[tuple[float, float], float]:
    """Per (supply_bar, step_v) cell: the smallest e such that one rest force gives every isolator an a_s within
    a relative error e of its table (``tables[name][(bar, volt)] = a_s_m``; cells every table has), each isolator
    on its loading branch ``branches[name]`` (``loading_branch``).

    For an isolator with tabulated a_s the forces allowed at error e form the interval
    [F((1 - e) a_s tanh(u/k)), F((1 + e) a_s tanh(u/k))] on its loading branch; e is found by bisection as
    the smallest value where all the intervals meet.
    """
    if len(tables) < 2:
        raise ValueError("the bound compares at least two isolators' tables")
    cells = set.intersection(*(set(t) for t in tables.values()))

    def intervals_meet(cell, e: float) -> bool:
        lows, highs = [], []
        for name, table in tables.items():
            d, f = branches[name]
            rest_m = table[cell] * np.tanh(cell[1] / K_VOLT)
            lows.append(np.interp(max(0.0, 1.0 - e) * rest_m, d, f))
            highs.append(np.interp((1.0 + e) * rest_m, d, f))
        return max(lows) <= min(highs)

    bound = {}
    for cell in sorted(cells):
        lo, hi = 0.0, 1.0
        while not intervals_meet(cell, hi):  # at e >= 1 every interval starts at its branch's first force
            hi *= 2.0
            if hi > 1.0e6:
                raise ValueError(f"cell {cell}: the branches' force ranges never meet (extend max_displacement_m)")
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if intervals_meet(cell, mid) else (mid, hi)
        bound[cell] = hi
    return bound
