"""Bags with known content for the analysis tests (helpers, not tests).

Synthetic bags are written with real CDR (rosbags' serializer, ``cdr``: no ROS installation is
needed) through BagRecorder and carry known half-order content on a speed ramp, so resampling on
the crank angle matters. The "node recording" is produced offline, without DDS: the node's own
simulation core (dmf_sim.live.simulation.LiveSimulation, what driveline_node steps) is advanced in
chunks and its samples are serialized and recorded as dmf_sim/node.py does (same topics, messages,
custom_data).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from dmf_sim.bags.metadata import RunMetadata
from dmf_sim.bags.writer import BagRecorder
from dmf_sim.physics.model import read_driveline
from support.cdr import (
    DiagnosticArray,
    DiagnosticStatus,
    Float64,
    Header,
    KeyValue,
    String,
    joint_state as _joint_state,
    serialize_message,
    stamp,
)

NAMES = read_driveline('truck_dmf').names
T0 = 1_700_000_000_000_000_000
RATE = 1000.0
TOL = 0.005                       # synthetic content must come back within 0.5 %
# x(psi) = mean + sum_n a_n cos(n psi / 2 + phase_n): n = 6 is the 3rd order, n = 3 the 1.5th
WINDUP = {'mean': 0.21, 3: (0.0015, 0.7), 6: (0.012, -1.2), 9: (0.0008, 0.1), 12: (0.002, 2.0)}
CYL1 = {'mean': 2e-3, 6: (5e-4, 0.3), 12: (1.5e-4, -0.4)}
TORQUE = {'mean': 1800.0, 3: (50.0, 1.0), 6: (350.0, -0.5)}
TOPICS = {'/driveline/joint_states': 'sensor_msgs/msg/JointState',
          '/driveline/dmf_windup': 'std_msgs/msg/Float64',
          '/engine/speed': 'std_msgs/msg/Float64',
          '/engine/crank_angle': 'std_msgs/msg/Float64'}


def synth(spec: dict, psi: np.ndarray) -> np.ndarray:
    x = np.full_like(psi, spec['mean'])
    for n, (a, ph) in ((k, v) for k, v in spec.items() if k != 'mean'):
        x += a * np.cos(n * psi / 2 + ph)
    return x


def ramp(duration: float = 16.0, v0: float = 700.0, v1: float = 1500.0):
    """Time [s], speed [rpm] (linear ramp) and crank angle [rad] at RATE."""
    t = np.arange(int(duration * RATE)) / RATE
    rpm = v0 + (v1 - v0) * t / duration
    omega = rpm * math.pi / 30
    psi = 0.3 + np.concatenate(([0.0], np.cumsum(0.5 * (omega[1:] + omega[:-1]) / RATE)))
    return t, rpm, psi


def joint_state(stamp_ns: int, position, effort, names=NAMES, frame='driveline'):
    return _joint_state(stamp_ns, names, position, effort=effort, frame=frame)


def write_synthetic(path: Path, topics=('joints', 'windup', 'speed', 'crank'), *,
                    namespaces=('',), jump_back_s: float = 0.0, custom_data=None,
                    max_duration_s: float | None = None, **kw) -> Path:
    """A bag like the node's (BagRecorder, CDR) with known content on a speed ramp.

    ``namespaces``: the node's topics under each of these ('' = none); ``jump_back_s``: stamps
    jump back by this much half-way (a clock re-anchored while recording)."""
    t, rpm, psi = ramp(**kw)
    w, cyl, tq = synth(WINDUP, psi), synth(CYL1, psi), synth(TORQUE, psi)
    i_cyl, i_in = NAMES.index('CYL1'), NAMES.index('INPUT SHAFT')
    keys = dict(zip(('joints', 'windup', 'speed', 'crank'), TOPICS))
    declared = {ns + keys[k]: TOPICS[keys[k]] for k in topics for ns in namespaces}
    declared['/rosout_like'] = 'std_msgs/msg/String'       # an extra topic nobody asked for
    declared['/late'] = 'std_msgs/msg/Float64'             # wind-up again, only after 5 s
    shift = np.where(np.arange(len(t)) >= len(t) // 2, -int(jump_back_s * 1e9), 0)
    split = {} if max_duration_s is None else {'max_duration_s': max_duration_s}
    with BagRecorder(path, declared, custom_data=custom_data, **split) as rec:
        for i in range(len(t)):
            ns_t = T0 + int(round(t[i] * 1e9)) + int(shift[i])
            for ns in namespaces:
                if 'joints' in topics:
                    pos = np.zeros(len(NAMES))
                    pos[i_cyl] = cyl[i]
                    eff = np.zeros(len(NAMES))
                    eff[i_in] = tq[i]
                    rec.write(ns + keys['joints'], ns_t,
                              serialize_message(joint_state(ns_t, pos, eff)))
                for key, val in (('windup', w[i]), ('speed', rpm[i]), ('crank', psi[i])):
                    if key in topics:
                        rec.write(ns + keys[key], ns_t,
                                  serialize_message(Float64(data=float(val))))
            if i % 500 == 0:
                rec.write('/rosout_like', ns_t, serialize_message(String(data=f'tick {i}')))
            if t[i] >= 5.0:
                rec.write('/late', ns_t, serialize_message(Float64(data=float(w[i]))))
    return path


def check_table(table, spec: dict, tol: float = TOL, orders=(3, 6)) -> None:
    """Every speed bin recovers the amplitudes of ``spec`` within ``tol``."""
    assert len(table) > 0
    for n in orders:
        if n not in spec:
            continue
        a = spec[n][0]
        got = table.amplitudes[:, n]
        assert np.all(np.isfinite(got))
        assert np.max(np.abs(got - a)) / a < tol, (n, got.min(), got.max(), a)
    assert np.allclose(table.mean, spec['mean'], rtol=tol, atol=1e-12)


def record_node_run_up(path: Path, v0: float, v1: float, ramp_rpm_s: float, hold_s: float,
                       load: float = 1.0, chunk_steps: int = 100, hold_end_s: float = 0.3,
                       store_load: bool = False, engine: str = 'engine_d13') -> Path:
    """Offline 'node recording' without DDS: the node's simulation core (LiveSimulation) steps in
    chunks; every published sample is serialized and recorded as dmf_sim/node.py does, with its
    RunMetadata as custom_data (the load only with ``store_load``)."""
    from dmf_sim.live.simulation import LiveSimulation

    sim = LiveSimulation.from_config('truck_dmf', engine, load_set='A', speed_rpm=v0,
                                     load=load, speed_ramp_rpm_per_s=ramp_rpm_s, stride=10)
    spring = sim.model.spring
    custom = RunMetadata(driveline='truck_dmf', engine=engine, load_set='A',
                         alpha=spring.alpha, theta_rad=spring.theta, spring=spring.as_dict(),
                         load=load if store_load else None, speed_rpm=v0, dt_s=sim.dt,
                         publish_rate_hz=1000.0).to_custom_data()
    n_total = int(round((hold_s + abs(v1 - v0) / ramp_rpm_s + hold_end_s) / sim.dt))
    with BagRecorder(path, {**TOPICS, '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray'},
                     custom_data=custom) as rec:
        done = 0
        while done < n_total:
            if done * sim.dt >= hold_s and sim.speed_setpoint != v1:
                assert sim.set_speed_setpoint(v1) is None
            s = sim.advance(chunk_steps)
            done += chunk_steps
            write_samples(rec, s, sim.names)
    return path


def write_samples(rec, s, names: list[str] | None) -> None:
    """Record the samples ``s`` of LiveSimulation.advance as the node publishes them: joint
    states of the elements ``names`` (none if None), wind-up, speed, crank angle; log time
    T0 + t."""
    for i in range(len(s)):
        ns = T0 + int(round(float(s.t[i]) * 1e9))
        if names is not None:
            js = _joint_state(ns, names, s.position[i], s.velocity[i], s.effort[i])
            rec.write('/driveline/joint_states', ns, serialize_message(js))
        for topic, val in (('/driveline/dmf_windup', s.windup[i]),
                           ('/engine/speed', s.speed_rpm[i]),
                           ('/engine/crank_angle', s.psi[i])):
            rec.write(topic, ns, serialize_message(Float64(data=float(val))))


# ------------------------------------------------------------------ damaged files

def chunk_spans(file: Path) -> list[tuple[int, int, int, int]]:
    """(record offset, record length, message start, message end [ns]) of every chunk of a
    complete MCAP file, from its summary's chunk index."""
    from mcap.reader import make_reader

    with open(file, 'rb') as fh:
        summary = make_reader(fh).get_summary()
    return [(c.chunk_start_offset, c.chunk_length, c.message_start_time, c.message_end_time)
            for c in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)]


def flip_chunks(file: Path, which, nbytes: int = 64) -> list[tuple[int, int, int, int]]:
    """Invert ``nbytes`` bytes in the middle of the records of each chunk ``which`` (indexes into
    :func:`chunk_spans`), as a bad sector or a bit-rotted copy would; returns those chunks."""
    spans = chunk_spans(file)
    picked = [spans[i] for i in which]
    with open(file, 'r+b') as fh:
        for off, length, _, _ in picked:
            at = off + length // 2
            fh.seek(at)
            data = fh.read(nbytes)
            fh.seek(at)
            fh.write(bytes(b ^ 0xFF for b in data))
    return picked


# ------------------------------------------------------------- a load change

NODE = '/driveline_node'


def health_status(sim, node: str = NODE):
    """The node's health status as /diagnostics carries it (the keys and formats of
    dmf_sim.live.health that the analysis reads: load, load_setpoint, alpha, theta_rad)."""
    from dmf_sim.core.numbers import fmt_num
    from dmf_sim.live.health import status_name

    spring = sim.model.spring
    values = {'sim_time_s': f'{sim.t:.4f}', 'speed_rpm': f'{sim.speed:.3f}',
              'load': f'{sim.load:.4f}', 'load_setpoint': fmt_num(sim.load_setpoint),
              'alpha': fmt_num(spring.alpha), 'theta_rad': fmt_num(spring.theta)}
    return DiagnosticStatus(level=0, name=status_name(node), hardware_id=node,
                            message='offline recording',
                            values=[KeyValue(key=k, value=v) for k, v in values.items()])


def record_load_change(path: Path, speed_rpm: float, load0: float, load1: float,
                       change_s: float, duration_s: float, *, diagnostics_hz: float = 1.0,
                       record_setpoint: bool = False, joints: bool = False,
                       chunk_steps: int = 100) -> Path:
    """Offline 'node recording' (the node's simulation core, as record_node_run_up) at a fixed
    speed whose load setpoint goes ``load0`` -> ``load1`` at ``change_s``; the node's health
    status in /diagnostics every 1/``diagnostics_hz`` s and, with ``record_setpoint``, the
    setpoint topic as ``ros2 bag record -a`` would hold it; the joint states only with
    ``joints`` (the wind-up analysis does not read them). custom_data stores the start load."""
    from dmf_sim.live.simulation import LiveSimulation

    sim = LiveSimulation.from_config('truck_dmf', 'engine_d13', load_set='A', speed_rpm=speed_rpm,
                                     load=load0, stride=10)
    spring = sim.model.spring
    custom = RunMetadata(driveline='truck_dmf', engine='engine_d13', load_set='A',
                         alpha=spring.alpha, theta_rad=spring.theta, spring=spring.as_dict(),
                         load=load0, speed_rpm=speed_rpm, dt_s=sim.dt, publish_rate_hz=1000.0,
                         node=NODE).to_custom_data()
    topics = {**TOPICS, '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray'}
    if not joints:
        del topics['/driveline/joint_states']
    if record_setpoint:
        topics['/engine/load_setpoint'] = 'std_msgs/msg/Float64'
    next_diag = 0.0
    with BagRecorder(path, topics, custom_data=custom) as rec:
        while sim.t < duration_s:
            if sim.t >= change_s and sim.load_setpoint != load1:
                assert sim.set_load_setpoint(load1) is None
                if record_setpoint:
                    rec.write('/engine/load_setpoint', T0 + int(round(sim.t * 1e9)),
                              serialize_message(Float64(data=float(load1))))
            write_samples(rec, sim.advance(chunk_steps), sim.names if joints else None)
            if sim.t >= next_diag:
                ns = T0 + int(round(sim.t * 1e9))
                msg = DiagnosticArray(header=Header(stamp=stamp(ns), frame_id=''),
                                      status=[health_status(sim)])
                rec.write('/diagnostics', ns, serialize_message(msg))
                next_diag += 1.0 / diagnostics_hz
    return path
