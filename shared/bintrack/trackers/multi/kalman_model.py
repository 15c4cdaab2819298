"""The constant-velocity Kalman filter of the MCMCDA tracks, per axis (paper 004 §II; Oh,
Russell and Sastry 2009, §II-A).

The filter runs per axis (x and y independent: constant velocity with white-acceleration
spectral density q, measurement variance the report covariance's diagonal), which keeps the
chain's inner loop in scalar arithmetic; the report covariance's off-diagonal term is dropped.
A state is the tuple (p, v, P_pp, P_pv, P_vv): position (units), velocity (units/s) and their
covariance.
"""

from __future__ import annotations

import math

LOG_2PI = math.log(2.0 * math.pi)


def kf_predict(state, dt: float, q: float):
    """The state predicted ``dt`` s ahead, with white-acceleration spectral density ``q`` (units²/s³)."""
    p, v, ppp, ppv, pvv = state
    return (p + v * dt, v,
            ppp + 2 * dt * ppv + dt * dt * pvv + q * dt ** 3 / 3.0,
            ppv + dt * pvv + q * dt * dt / 2.0,
            pvv + q * dt)


def kf_update(state, z: float, r: float):
    """Kalman update of one axis with measurement z (variance r); returns (state, log N(ν; 0, S))."""
    p, v, ppp, ppv, pvv = state
    s = ppp + r
    nu = z - p
    kp, kv = ppp / s, ppv / s
    new = (p + kp * nu, v + kv * nu, ppp - kp * ppp, ppv - kp * ppv, pvv - kv * ppv)
    return new, -0.5 * (LOG_2PI + math.log(s) + nu * nu / s)
