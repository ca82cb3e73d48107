"""The twin's physics: heat sources, the lumped thermal network, room, sensors and displacement.

A lumped thermal network (10 nodes, :data:`rafi.twin.machines.NODES`) is integrated exactly at
the sample step with a zero-order-hold exponential integrator (``expm`` of the augmented
system, cached per speed), so a 4 h run at 5 s takes a few milliseconds. An on/off oil cooler
with a hysteresis thermostat tracks the room temperature; it makes the coolant temperatures
cycle like on a real machine. Sixteen sensors read mixes of node temperatures through their own
first-order lag and calibration offset. The axial displacement is the thermal expansion of
shaft, cartridge, head and column plus the centrifugal draw-in of the BT30 holder (~n^2, a jump
when the speed changes).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
from scipy.linalg import expm

from rafi.twin.machines import AMBIENT, N_REF, NODE_INDEX, NODES, Ambient, TwinParams
from rafi.twin.signals import first_order

_N = len(NODES)
_I = NODE_INDEX


def heat_sources(params: TwinParams, speed_rpm: float, wear: float = 0.0) -> np.ndarray:
    """Heat input per node (W) at a constant speed; ``wear`` raises bearing friction."""
    n = abs(float(speed_rpm))
    q = np.zeros(_N)
    if n <= 0:
        return q
    r = n / N_REF
    fb = params.bearing_front_w * r ** (5.0 / 3.0) * (1.0 + wear)
    rb = params.bearing_rear_w * r ** (5.0 / 3.0) * (1.0 + wear)
    s = params.bearing_to_shaft
    q[_I["front_bearing"]] += fb * (1 - s)
    q[_I["rear_bearing"]] += rb * (1 - s)
    q[_I["shaft"]] += (fb + rb) * s
    field_weak = min(1.0, params.motor_base_speed_rpm / n) ** 2
    # above base speed the flux is weakened (~1/n): magnetising copper loss ~ 1/n^2,
    # iron loss ~ f^1.4 B^2
    q[_I["stator"]] += (params.motor_magnetising_w + params.motor_iron_w * r**1.4) * field_weak
    q[_I["shaft"]] += params.rotor_w * r**2
    return q


def system_matrices(params: TwinParams, speed_rpm: float, wear: float) -> tuple[np.ndarray, np.ndarray]:
    """Continuous system x' = A x + B u, u = [T_ambient, 1, cooler_on]."""
    n = abs(float(speed_rpm))
    r = n / N_REF
    G = np.zeros((_N, _N))

    def add(a, b, g):
        i, j = _I[a], _I[b]
        G[i, j] += g
        G[j, i] += g

    for (a, b), g in params.links.items():
        add(a, b, g)
    for (a, b), (g0, g1, e) in params.speed_links.items():
        add(a, b, g0 + g1 * r**e)
    add("coolant", "tank", params.coolant_flow_w_per_k)  # well-mixed jacket, loop to the tank
    ga = np.zeros(_N)
    for node, (g0, g1, e) in params.to_ambient.items():
        ga[_I[node]] += g0 + g1 * r**e
    cap = np.array([params.capacity[nm] for nm in NODES])
    A = (G - np.diag(G.sum(axis=1) + ga)) / cap[:, None]
    B = np.zeros((_N, 3))
    B[:, 0] = ga / cap
    B[:, 1] = heat_sources(params, n, wear) / cap
    B[_I["tank"], 2] = -params.cooler_power_w / cap[_I["tank"]]
    return A, B


def discrete_system(
    params: TwinParams, speed_rpm: float, dt: float, wear: float
) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation ``(Phi, Gamma)`` of :func:`system_matrices` at step ``dt``."""
    A, B = system_matrices(params, speed_rpm, wear)
    M = np.zeros((_N + 3, _N + 3))
    M[:_N, :_N] = A
    M[:_N, _N:] = B
    E = expm(M * dt)
    return E[:_N, :_N], E[:_N, _N:]


def ambient_series(ambient: Ambient, times: pd.DatetimeIndex, rng: np.random.Generator) -> np.ndarray:
    """Room temperature at the given clock times (seeded wander)."""
    t0 = times[0]
    hours = np.asarray((times - t0) / pd.Timedelta(hours=1), dtype=float)
    clock = (t0.hour + t0.minute / 60 + t0.second / 3600) + hours
    temp = ambient.base_c + ambient.daily_amplitude_c * np.cos(2 * np.pi * (clock - ambient.peak_hour) / 24)
    temp = temp + ambient.drift_c_per_h * hours
    periods = rng.uniform(0.7, 6.0, size=6)
    phases = rng.uniform(0, 2 * np.pi, size=6)
    amps = rng.normal(0, 1, size=6)
    wander = sum(a * np.sin(2 * np.pi * hours / p + ph) for a, p, ph in zip(amps, periods, phases))
    rms = np.sqrt(np.sum(amps**2) / 2) or 1.0
    return temp + ambient.wander_c * wander / rms


def integrate(
    params: TwinParams,
    speeds: np.ndarray,
    t_amb: np.ndarray,
    dt: float,
    *,
    wear: float = 0.0,
    x0: np.ndarray | None = None,
    cooler_on0: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Integrate the network: node temperatures (n x nodes) at each sample and cooler state.

    Sample ``k`` is the state at the sample instant; the speed and room temperature of
    sample ``k`` are held over the interval to sample ``k + 1`` (zero-order hold, exact).
    The cooler thermostat is evaluated at each sample (on above set + h/2, off below
    set - h/2, set = room + offset).
    """
    n = len(speeds)
    x = np.full(_N, t_amb[0]) if x0 is None else np.array(x0, dtype=float)
    cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    out = np.empty((n, _N))
    cooler = np.zeros(n, dtype=bool)
    on = bool(cooler_on0)
    half = params.cooler_hysteresis_c / 2
    it = _I["tank"]
    for k in range(n):
        out[k] = x
        sp = float(speeds[k])
        if sp not in cache:
            cache[sp] = discrete_system(params, sp, dt, wear)
        Phi, Gam = cache[sp]
        sp_set = t_amb[k] + params.cooler_offset_c
        if x[it] > sp_set + half:
            on = True
        elif x[it] < sp_set - half:
            on = False
        cooler[k] = on
        x = Phi @ x + Gam @ np.array([t_amb[k], 1.0, 1.0 if on else 0.0])
    return out, cooler


#: Natural convection (``integrate_realistic``): the still-air loss of a node equals the linear
#: law's at this rise above the room (K), and its rise is taken as at least the floor (K), so the
#: loss of a node at room temperature stays finite.
CONVECTION_REF_K = 2.0
CONVECTION_FLOOR_K = 0.3
#: Steps of the convection factor the discretisation is cached at (relative).
CONVECTION_QUANTUM = 0.01


def _discrete_with_heat(
    params: TwinParams, speed_rpm: float, dt: float, wear: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`discrete_system` plus ``Psi``: the state's response to a heat input (W) per node
    held over the step (zero-order hold, exact)."""
    A, B = system_matrices(params, speed_rpm, wear)
    cap = np.array([params.capacity[nm] for nm in NODES])
    M = np.zeros((2 * _N + 3, 2 * _N + 3))
    M[:_N, :_N] = A
    M[:_N, _N : _N + 3] = B
    M[:_N, _N + 3 :] = np.diag(1.0 / cap)
    E = expm(M * dt)
    return E[:_N, :_N], E[:_N, _N : _N + 3], E[:_N, _N + 3 :]


def integrate_realistic(
    params: TwinParams,
    speeds: np.ndarray,
    t_amb: np.ndarray,
    dt: float,
    *,
    extra_w: np.ndarray | None = None,
    convection_exponent: float | None = None,
    cooler_set_c: float | None = None,
    x0: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`integrate` (no wear) with what the linear network leaves out.

    Parameters
    ----------
    params, speeds, t_amb, dt
        As :func:`integrate`.
    extra_w : numpy.ndarray, optional
        Heat (W) into each node at each sample (n x nodes), held over the step: a source no
        sensor is meant for (a hydraulic unit, a neighbouring machine).
    convection_exponent : float, optional
        Natural convection loses heat as ``dT ** exponent`` (about 1.25 for free convection from
        a vertical plate): the still-air part ``G0`` of every node's conductance to the room is
        scaled by ``(max(|dT|, CONVECTION_FLOOR_K) / CONVECTION_REF_K) ** (exponent - 1)``, ``dT``
        the node's rise above the room at the sample (quantised to :data:`CONVECTION_QUANTUM`);
        the part that grows with speed (forced by the rotation) stays linear.
    cooler_set_c : float, optional
        The oil cooler's thermostat holds this fixed set point (degC) instead of the room's
        temperature plus ``params.cooler_offset_c``.
    x0 : numpy.ndarray, optional
        The nodes' temperatures at the first sample (default: every node at the room's).

    Returns
    -------
    tuple of numpy.ndarray
        Node temperatures (n x nodes) and the cooler state, as :func:`integrate`.
    """
    n = len(speeds)
    x = np.full(_N, t_amb[0]) if x0 is None else np.array(x0, dtype=float)
    extra = np.zeros((n, _N)) if extra_w is None else np.asarray(extra_w, dtype=float)
    natural = {node: law for node, law in params.to_ambient.items() if law[0] > 0}
    cache: dict[tuple, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    out = np.empty((n, _N))
    cooler = np.zeros(n, dtype=bool)
    on = False
    half = params.cooler_hysteresis_c / 2
    it = _I["tank"]
    for k in range(n):
        out[k] = x
        sp = float(speeds[k])
        factors: tuple = ()
        if convection_exponent is not None:
            rise = np.maximum(np.abs(x - t_amb[k]), CONVECTION_FLOOR_K) / CONVECTION_REF_K
            factors = tuple(
                round(float(rise[_I[node]] ** (convection_exponent - 1.0)) / CONVECTION_QUANTUM)
                for node in natural
            )
        key = (sp, factors)
        if key not in cache:
            scaled = params
            if factors:
                laws = dict(params.to_ambient)
                for (node, (g0, g1, e)), f in zip(natural.items(), factors):
                    laws[node] = (g0 * f * CONVECTION_QUANTUM, g1, e)
                scaled = replace(params, to_ambient=laws)
            cache[key] = _discrete_with_heat(scaled, sp, dt, 0.0)
        Phi, Gam, Psi = cache[key]
        sp_set = t_amb[k] + params.cooler_offset_c if cooler_set_c is None else cooler_set_c
        if x[it] > sp_set + half:
            on = True
        elif x[it] < sp_set - half:
            on = False
        cooler[k] = on
        x = Phi @ x + Gam @ np.array([t_amb[k], 1.0, 1.0 if on else 0.0]) + Psi @ extra[k]
    return out, cooler


def thermal_displacement(params: TwinParams, nodes: np.ndarray, x_ref: np.ndarray) -> np.ndarray:
    """Axial displacement (um) from the thermal expansion of the nodes against ``x_ref``."""
    z = np.zeros(len(nodes))
    for node, gain in params.disp_gain.items():
        z += gain * (nodes[:, _I[node]] - x_ref[_I[node]])
    return z


def displacement_truth(
    params: TwinParams, nodes: np.ndarray, speeds: np.ndarray, dt: float, x_ref: np.ndarray
) -> np.ndarray:
    """Noise-free axial displacement (um): thermal expansion + centrifugal draw-in."""
    z = thermal_displacement(params, nodes, x_ref)
    cf = params.centrifugal_um * (np.abs(speeds) / N_REF) ** 2
    # the draw-in follows the speed within seconds: a visible jump at each speed change
    a = np.exp(-dt / params.centrifugal_lag_s)
    prev = np.concatenate([[cf[0]], cf[:-1]])
    z += prev + (cf - prev) * (1 - a)
    return z


def sensor_truth(
    params: TwinParams, nodes: np.ndarray, t_amb: np.ndarray, dt: float, drift: dict | None = None
) -> np.ndarray:
    """Noise-free sensor readings (n x 16): node mix, own lag, calibration offset (+ drift)."""
    drift = drift or {}
    out = np.empty((len(nodes), len(params.sensors)))
    for j, s in enumerate(params.sensors):
        mixed = np.zeros(len(nodes))
        for name, w in s.mix:
            mixed += w * (t_amb if name == AMBIENT else nodes[:, _I[name]])
        out[:, j] = first_order(mixed, dt, s.lag_s, y0=mixed[0]) + s.offset_c + drift.get(s.name, 0.0)
    return out
