"""Where a step test comes to rest, and the bound that sets on any one rig against Tables III and IV.

In eq. (3) the valve passes no flow only at P_L = P_s, so a step test that has settled rests where the cylinder
force, less the friction, equals the isolator force: A_p P_s - (mu N + F_c) = F_BW(y) (first line of eq. 3
with y' = 0; the table comes from below and stops at the first such point). Eq. (7) at steady state gives
y = a_s tanh(u / k), so the identified a_s is that rest position over tanh(u / k).

Whatever the rig is - its piston area, friction, valve, leakage - the force on the isolator at rest depends
only on the supply pressure and the command, not on the isolator. ``common_rest_force_bound`` finds, for each
(P_s, u) cell of two tables, the smallest relative a_s error that lets ONE force put both isolators at their
tabulated a_s: no rig under the paper's model can do better on that cell.

That holds while both isolators are tested under the same friction. The guide friction mu N + F_c follows the
vertical load N on the specimen (eq. 1), which the paper does not state for its step tests: with one load per
table the rest force is A_p P_s - (mu N_iso + F_c) and differs between the isolators. ``rest_a_s_errors`` gives
the a_s errors of such a static balance, ``best_rest_balance`` the best (A_p, friction per isolator or shared).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from .isolator import Isolator, simulate_loop
from .models import K_VOLT
from .rig import BAR_PA

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


def rest_a_s_errors(tables: dict[str, dict[tuple[float, float], float]], branches: dict[str, Branch],
                    piston_area_m2: float, friction_n: dict[str, float]) -> dict[tuple[str, float, float], float]:
    """Relative a_s error per (isolator, supply_bar, step_v) of a rig resting where A_p P_s - friction_n[name]
    = F_BW(y) (eq. 3, first line, y' = 0), each isolator under its own friction mu N + F_c (eq. 1), i.e. its own
    vertical load. ValueError if the rest force leaves an isolator's loading branch (e.g. friction > A_p P_s)."""
    errors = {}
    for name, table in tables.items():
        for (bar, volt), a_s_m in table.items():
            push_n = piston_area_m2 * bar * BAR_PA - friction_n[name]
            errors[(name, bar, volt)] = rest_a_s_m(branches[name], push_n, volt) / a_s_m - 1.0
    return errors


def best_rest_balance(tables: dict[str, dict[tuple[float, float], float]], branches: dict[str, Branch],
                      per_isolator_friction: bool, friction_range_n: tuple[float, float] = (0.0, np.inf),
                      start_area_m2: float = 0.012,
                      start_friction_n: float = 5000.0) -> tuple[float, float, dict[str, float]]:
    """The piston area A_p (m2) and friction (N; one per isolator, or one shared) whose static balance
    (``rest_a_s_errors``) has the smallest worst |a_s error|: (worst error, A_p, friction per isolator).
    ``friction_range_n`` bounds each friction, e.g. (F_c, F_c + mu N_max) for loads within the jack's range.
    Nelder-Mead in log space from a few starts around the given one (the worst error is not smooth)."""
    names = list(tables)
    lo_n, hi_n = friction_range_n

    def unpack(theta):
        friction = np.exp(theta[1:]) if per_isolator_friction else np.full(len(names), np.exp(theta[1]))
        friction = np.clip(friction, lo_n, hi_n)
        return float(np.exp(theta[0])), dict(zip(names, map(float, friction), strict=True))

    def worst(theta) -> float:
        try:
            return max(abs(e) for e in rest_a_s_errors(tables, branches, *unpack(theta)).values())
        except ValueError:  # the rest force leaves a branch: far from any useful balance
            return 10.0

    x0 = np.log([start_area_m2] + [start_friction_n] * (len(names) if per_isolator_friction else 1))
    best = None
    for shift in (0.0, 0.3, -0.3):
        for spread in (0.0, 1.0, -1.0) if per_isolator_friction else (0.0,):
            start = x0 + shift
            start[1:] += np.linspace(-spread, spread, start.size - 1)  # frictions apart as well as together
            sol = minimize(worst, start, method="Nelder-Mead",
                           options={"xatol": 1e-5, "fatol": 1e-7, "maxfev": 3000})
            if best is None or sol.fun < best.fun:
                best = sol
    area, friction = unpack(best.x)
    return float(best.fun), area, friction
