"""The fitted rig driven by what was measured: eq. (3) with the specimen's measured force as an input.

``replay(rig, u, force, supply, x0)`` integrates the fifth-order model of sim.rig (its friction with the
stick band, its valve law and orifice, eq. 2 for the command) for the valve commands ``u`` that the rig was
sent, with the specimen's force taken from the record instead of a Bouc-Wen model (a lab's specimen is not
known; its force is measured). It returns what the rig's sensors would have read: the position ``L`` late
(linear in between periods, as sim.sensors reads it) and the load pressure. This is how a fitted model is
judged: by the response it predicts to the same commands, not by the equations it was fitted to.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..isolator import NO_SPECIMEN
from ..rig import (
    P_AREA,
    P_BETA,
    P_MASS,
    P_SUPPLY,
    P_VISCOUS,
    P_VOLUME,
    P_WV,
    P_XIV,
    RigParameters,
    load_flow,
    pack_plant,
    table_acceleration,
    valve_command,
)

SUBSTEPS = 5
N_X = 6  # y, y', P_L, v_e, v_e', z (the Dahl law's state, when the fit chose it)
#: the Dahl friction law's parameters in ``dahl``: its level F_c (N), pre-sliding distance delta (m; 0: the rig's
#: Coulomb law with the stick band), pre-sliding damping sigma_1 (N s/m)
D_LEVEL, D_DELTA, D_DAMPING = range(3)


@njit(cache=True)
def _derivatives(x, v_c, force, p, dahl, dx):
    """Eq. (3) with the specimen's force given: y, y', P_L, v_e, v_e', z. The friction is the rig's Coulomb law
    with its stick band, or the Dahl law the fit chose (sim.commission.force): F_c z + sigma_1 delta z'."""
    v = x[1]
    net = p[P_AREA] * x[2] - force - p[P_VISCOUS] * v
    dx[0] = v
    if dahl[D_DELTA] > 0.0:
        sign = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
        z_rate = v * (1.0 - x[5] * sign) / dahl[D_DELTA]
        dx[1] = (net - dahl[D_LEVEL] * x[5] - dahl[D_DAMPING] * dahl[D_DELTA] * z_rate) / p[P_MASS]
        dx[5] = z_rate
    else:
        dx[1] = table_acceleration(v, net, p)
        dx[5] = 0.0
    dx[2] = 2.0 * p[P_BETA] / p[P_VOLUME] * (-p[P_AREA] * v + load_flow(x[3], x[2], p))
    wv = p[P_WV]
    dx[3] = x[4]
    dx[4] = -wv * wv * x[3] - 2.0 * p[P_XIV] * wv * x[4] + wv * wv * v_c


@njit(cache=True)
def _replay(p, dahl, u, force, supply, x, substeps, dt, out_y, out_v, out_p):
    k1 = np.empty(N_X)
    k2 = np.empty(N_X)
    k3 = np.empty(N_X)
    k4 = np.empty(N_X)
    tmp = np.empty(N_X)
    h = dt / substeps
    for k in range(u.size):
        out_y[k] = x[0]
        out_v[k] = x[1]
        out_p[k] = x[2]
        p[P_SUPPLY] = supply[k]
        v_c = valve_command(u[k], p)
        f = force[k]
        for _ in range(substeps):
            _derivatives(x, v_c, f, p, dahl, k1)
            for i in range(N_X):
                tmp[i] = x[i] + 0.5 * h * k1[i]
            _derivatives(tmp, v_c, f, p, dahl, k2)
            for i in range(N_X):
                tmp[i] = x[i] + 0.5 * h * k2[i]
            _derivatives(tmp, v_c, f, p, dahl, k3)
            for i in range(N_X):
                tmp[i] = x[i] + h * k3[i]
            _derivatives(tmp, v_c, f, p, dahl, k4)
            for i in range(N_X):
                x[i] += h * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) / 6.0
            x[5] = min(1.0, max(-1.0, x[5]))
        if not np.isfinite(x[0]):
            return k + 1
    return u.size


def replay(rig: RigParameters, u: np.ndarray, force: np.ndarray, supply: np.ndarray, position_m: float,
           velocity_m_per_s: float, load_pressure_pa: float, dt_s: float, valve_v: float | None = None,
           valve_rate_v_per_s: float = 0.0, dahl: tuple[float, float, float] | None = None,
           dahl_state: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(position reading, the table's velocity when that reading was taken, load pressure) at each period for
    the commands ``u`` held over them, from the table at ``position_m`` moving at ``velocity_m_per_s`` with
    ``load_pressure_pa`` and the valve at ``valve_v`` (None: at rest on its first command). ``dahl``: (F_c,
    delta, sigma_1) of the Dahl friction law in place of the rig's Coulomb law, its state starting at
    ``dahl_state``. NaN after the model's state went non-finite."""
    p = pack_plant(rig, NO_SPECIMEN, float(supply[0]))
    u = np.ascontiguousarray(u, dtype=float)
    x = np.array([position_m, velocity_m_per_s, load_pressure_pa, 0.0, valve_rate_v_per_s, dahl_state])
    x[3] = valve_command(float(u[0]), p) if valve_v is None else valve_v
    law = np.zeros(3) if dahl is None else np.array(dahl, dtype=float)
    y = np.full(u.size, np.nan)
    v = np.full(u.size, np.nan)
    pl = np.full(u.size, np.nan)
    _replay(p, law, u, np.ascontiguousarray(force, dtype=float), np.ascontiguousarray(supply, dtype=float), x, SUBSTEPS,
            dt_s, y, v, pl)
    lag = rig.position_latency_s / dt_s
    t = np.arange(u.size, dtype=float)
    return (np.interp(t - lag, t, y, left=position_m), np.interp(t - lag, t, v, left=velocity_m_per_s), pl)
