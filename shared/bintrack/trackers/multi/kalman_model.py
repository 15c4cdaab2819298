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


def kf_smoothed(observations: list[tuple[float, float, float]], t: float, q: float, v0: float) -> tuple[float, float]:
    """(position, velocity) at time ``t`` (s) of one axis, given ``observations`` (time s, position
    units, variance units², in time order, the first at or before ``t``): the Rauch–Tung–Striebel
    smoother of this constant-velocity model (q units²/s³), started at the first observation
    with velocity 0 of variance ``v0`` (units²/s²). The backward pass needs only the means."""
    times = sorted({o[0] for o in observations} | {t})
    z = {o[0]: (o[1], o[2]) for o in observations}
    first, r0 = z[times[0]]
    state = (first, 0.0, r0, 0.0, v0)
    filtered, predicted = [state], [state]
    for prev, now in zip(times, times[1:]):
        ahead = kf_predict(state, now - prev, q)
        predicted.append(ahead)
        state = kf_update(ahead, *z[now])[0] if now in z else ahead
        filtered.append(state)
    p, v = filtered[-1][:2]
    for k in range(len(times) - 2, times.index(t) - 1, -1):
        # gain C = P_f Fᵀ P_p⁻¹ of the step k → k + 1, F = [[1, dt], [0, 1]]
        _, _, a, b, c = filtered[k]
        dt = times[k + 1] - times[k]
        pp, pv_, d, e, f = predicted[k + 1]
        det = d * f - e * e
        ga, gb = a + b * dt, b
        gc, gd = b + c * dt, c
        c11, c12 = (ga * f - gb * e) / det, (gb * d - ga * e) / det
        c21, c22 = (gc * f - gd * e) / det, (gd * d - gc * e) / det
        dp, dv = p - pp, v - pv_
        p, v = filtered[k][0] + c11 * dp + c12 * dv, filtered[k][1] + c21 * dp + c22 * dv
    return p, v
