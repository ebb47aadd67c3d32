"""An independent peer of the compiled simulator: the same closed loop built from python-control
objects, for the benchmark's speed ratio and for the agreement test.

Nothing here calls the project's control law or its discretization: the plant is python-control's
``ss`` of M, C, K discretized by ``sample_system`` (ZOH), and the cascade is written again from
its specification as python-control nonlinear I/O systems, interconnected at the velocity-loop
period. The two-rate loop is lifted to that single period: the position controller carries a
counter state and updates its held speed reference every Tp / Tv steps.
"""
from __future__ import annotations

import math

import numpy as np


def peer_simulate(m, k, c, c_motor, pitch, Tp, Tv, Kv, FFV, Kp, Ti, tau_max, x_cmd, table=1):
    """Closed loop on the position clock command ``x_cmd`` (held after its end); friction off.

    Returns the positions of all masses at each position tick (before the tick's update)."""
    import warnings

    import control
    warnings.filterwarnings("ignore", message="Unused output", category=UserWarning)

    n = len(m)
    M = np.diag(m)
    K = np.zeros((n, n))
    C = np.zeros((n, n))
    for i in range(n - 1):
        for A_, v in ((K, k[i]), (C, c[i])):
            A_[i, i] += v
            A_[i + 1, i + 1] += v
            A_[i, i + 1] -= v
            A_[i + 1, i] -= v
    ratio = 2 * math.pi / pitch
    C[0, 0] += c_motor * ratio ** 2
    Minv = np.linalg.inv(M)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ C]])
    B = np.zeros((2 * n, 1))
    B[n, 0] = 1.0 / m[0]
    plant_c = control.ss(A, B * ratio, np.eye(2 * n), np.zeros((2 * n, 1)))   # input: motor torque
    plant = control.sample_system(plant_c, Tv, method="zoh")
    plant = control.ss(plant.A, plant.B, plant.C, plant.D, Tv, inputs=["tau"],
                       outputs=[f"x{i}" for i in range(2 * n)], states=2 * n, name="plant")
    N = int(round(Tp / Tv))
    steps = (len(x_cmd)) * N
    cmd = np.append(np.asarray(x_cmd, float), x_cmd[-1])

    # position controller: states [w_ref held, step counter]; inputs: x_table, x_cmd[k], x_cmd[k+1]
    def pos_update(t, x, u, params):
        w_ref, count = x
        if int(round(count)) % N == 0:
            w_ref = (Kv * (u[1] - u[0]) + FFV * (u[2] - u[1]) / Tp) * ratio
        return np.array([w_ref, count + 1])

    def pos_output(t, x, u, params):
        # the reference is computed at the tick and used by the same tick's velocity step
        w_ref, count = x
        if int(round(count)) % N == 0:
            return np.array([(Kv * (u[1] - u[0]) + FFV * (u[2] - u[1]) / Tp) * ratio])
        return np.array([w_ref])

    pos = control.nlsys(pos_update, pos_output, inputs=["x_table", "xc", "xc_next"], outputs=["w_ref"],
                        states=["w_held", "count"], dt=Tv, name="position")

    # velocity PI with conditional integration: states [I, saturated]
    def pi_raw(x, u):
        I, sat = x
        e = u[0] - u[1]
        if sat == 0.0:
            I = I + e * Tv
        tau = Kp * (e + I / Ti)
        return I, tau

    def vel_update(t, x, u, params):
        I, tau = pi_raw(x, u)
        sat = 1.0 if abs(tau) > tau_max else 0.0
        return np.array([I, sat])

    def vel_output(t, x, u, params):
        _, tau = pi_raw(x, u)
        return np.array([min(max(tau, -tau_max), tau_max)])

    vel = control.nlsys(vel_update, vel_output, inputs=["w_ref", "w"], outputs=["tau"], states=["I", "sat"],
                        dt=Tv, name="velocity")
    # the motor speed in rad/s from the plant's state
    gain = control.ss([], [], [], [[ratio]], dt=Tv, inputs=["v1"], outputs=["w"], name="tacho")
    sys = control.interconnect(
        [plant, pos, vel, gain],
        connections=[["position.x_table", f"plant.x{table}"], ["velocity.w_ref", "position.w_ref"],
                     ["tacho.v1", f"plant.x{n}"], ["velocity.w", "tacho.w"], ["plant.tau", "velocity.tau"]],
        inplist=["position.xc", "position.xc_next"], outlist=[f"plant.x{i}" for i in range(n)],
        dt=Tv)
    T = np.arange(steps) * Tv
    kk = np.arange(steps) // N
    U = np.vstack([cmd[kk], cmd[kk + 1]])
    X0 = np.zeros(sys.nstates)
    # the plant starts at rest at the first command
    names = sys.state_labels
    for i in range(n):
        X0[names.index(f"plant_x[{i}]") if f"plant_x[{i}]" in names else i] = cmd[0]
    resp = control.input_output_response(sys, T, U, X0)
    y = np.atleast_2d(resp.outputs)
    return y[:, ::N].T
