"""Periodic sensors: samples at phase + k·period with detection and false-alarm probabilities.

A sample reports the target present with probability 1 − (1 − pd·P_detect(d))·(1 − pfa)
(DESIGN §8.3, paper 004 §III), with P_detect 1 inside the range and 0 outside for the ideal
model, or paper 001 eq. 25/26 for the imperfect one; with several targets each may be
detected independently. Disk and sector sensors yield only the samples whose value differs
from the previous one (lossless given the period); motion sensors yield every sample.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from bintrack.formats import Event, idle_value
from bintrack.deployment_model import DiskSensor, MotionSensor, SectorSensor
from bintrack.sensing import DiskModel, MotionModel, SectorModel, model_for
from bintrack.sim.trajectories import Trajectory

PIR_WALKING_SPEED = 0.5
"""units/s: a PIR sensor sees a person at least this fast with its full pd"""


def sample_times(phase: float, period: float, t_start: float, t_end: float) -> np.ndarray:
    """The times phase + k·period (s, integer k) that lie in [t_start, t_end]."""
    first = math.ceil((t_start - phase) / period)
    last = math.floor((t_end - phase) / period)
    return phase + period * np.arange(first, last + 1)


def presence_samples(sensor: DiskSensor | SectorSensor, trajectories: Sequence[Trajectory],
                     times: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Sampled reports of a disk (1/0) or sector (0..s−1/−1) sensor at ``times`` (s).

    Target j is detected with probability pd·P_detect(d_j) (pd defaults to 1); independently a
    false alarm occurs with probability pfa (default 0). A sector sensor reports the sector of
    the lowest-numbered detected target, or a uniformly random sector for a false alarm alone."""
    model = model_for(sensor)
    if not isinstance(model, DiskModel):
        raise TypeError(f"sensor {sensor.id!r} is not a disk or sector sensor")
    if isinstance(sensor, DiskSensor) and not isinstance(sensor, SectorSensor) and (sensor.hold is not None or sensor.still is not None):
        return pir_samples(sensor, trajectories, times, rng)
    pd = 1.0 if sensor.pd is None else sensor.pd
    pfa = 0.0 if sensor.pfa is None else sensor.pfa
    sector = isinstance(model, SectorModel)
    value = np.full(times.shape, -1 if sector else 0)
    for trajectory in trajectories:
        alive = trajectory.alive(times)
        position = trajectory.position(times)
        p = np.zeros(times.shape)
        p[alive] = pd * model.detect_probability(position[alive])
        detected = rng.random(times.shape) < p
        if sector:
            free = detected & (value == -1)
            value[free] = model.sector_of(position[free])
        else:
            value[detected] = 1
    alarm = rng.random(times.shape) < pfa
    if sector:
        random_sector = rng.integers(0, model.sectors, times.shape)
        value = np.where((value == -1) & alarm, random_sector, value)
    else:
        value[alarm] = 1
    return value


def pir_samples(sensor: DiskSensor | SectorSensor, trajectories: Sequence[Trajectory], times: np.ndarray,
                rng: np.random.Generator) -> np.ndarray:
    """Sampled reports (1/0) of a real PIR sensor (a sensor with ``hold`` or ``still``) at ``times`` (s).

    A PIR sensor sees motion, not presence: target j within the footprint triggers it in a
    sample with probability pd·P_detect(d_j)·m(v_j), where m(v) = still + (1 − still)·min(1, v/V)
    falls from 1 for a walking person (speed ≥ V = ``PIR_WALKING_SPEED`` units/s) to ``still``
    for one standing still; a false trigger occurs with probability pfa. After a trigger the
    output stays on for ``hold`` s (it reports 1 at every sample within hold of a trigger)."""
    model = model_for(sensor)
    pd = 1.0 if sensor.pd is None else sensor.pd
    pfa = 0.0 if sensor.pfa is None else sensor.pfa
    still = 1.0 if sensor.still is None else sensor.still
    trigger = np.zeros(times.shape, dtype=bool)
    for trajectory in trajectories:
        alive = trajectory.alive(times)
        p = np.zeros(times.shape)
        if alive.any():
            speed = np.hypot(*trajectory.velocity(times[alive]).T)
            motion = still + (1.0 - still) * np.minimum(1.0, speed / PIR_WALKING_SPEED)
            p[alive] = pd * model.detect_probability(trajectory.position(times[alive])) * motion
        trigger |= rng.random(times.shape) < p
    trigger |= rng.random(times.shape) < pfa
    if not sensor.hold:
        return trigger.astype(int)
    fired = times[trigger]
    k = np.searchsorted(fired, times, side="right") - 1  # the last trigger at or before each sample
    last = np.where(k >= 0, fired[np.maximum(k, 0)], -np.inf)
    return (times - last < sensor.hold + 1e-9).astype(int)


def motion_samples(sensor: MotionSensor, trajectories: Sequence[Trajectory],
                   times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closer/farther reports (+1/−1, paper 002) at ``times`` (s) about the lowest-numbered
    target present; returns (times with a target present, values)."""
    model = model_for(sensor)
    if not isinstance(model, MotionModel):
        raise TypeError(f"sensor {sensor.id!r} is not a motion sensor")
    value = np.zeros(times.shape, dtype=int)
    for trajectory in trajectories:
        free = trajectory.alive(times) & (value == 0)
        value[free] = model.status(trajectory.position(times[free]), trajectory.velocity(times[free]))
    present = value != 0
    return times[present], value[present]


def periodic_events(sensor: DiskSensor | SectorSensor | MotionSensor, trajectories: Sequence[Trajectory],
                    window: tuple[float, float], phase: float, rng: np.random.Generator) -> list[Event]:
    """Events of a periodic sensor sampling at phase + k·period (s) within ``window`` (s):
    changes of value only for disk and sector sensors, every sample for motion sensors."""
    times = sample_times(phase, sensor.period, *window)
    if isinstance(sensor, MotionSensor):
        times, values = motion_samples(sensor, trajectories, times)
        return [Event(float(t), sensor.id, int(v)) for t, v in zip(times, values)]
    values = presence_samples(sensor, trajectories, times, rng)
    previous = np.concatenate([[idle_value(sensor)], values[:-1]])
    changed = np.flatnonzero(values != previous)
    return [Event(float(times[k]), sensor.id, int(values[k])) for k in changed]
