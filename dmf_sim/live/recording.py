"""The live node's recording lifecycle without ROS: bag path, open, write, split, close, fail.

:class:`RecordingControl` owns at most one :class:`dmf_sim.bags.writer.BagRecorder` at a time:

* :meth:`check` refuses a ``bag_path`` that exists (never overwritten); :meth:`target` chooses
  ``dmf_bag_<YYYYmmdd_HHMMSS>[_i]`` in the working directory for an empty one.
* :meth:`prepare` creates the bag (the only complete check that it can be written; ~10 ms, so
  the node calls it outside its tick lock), missing parent directories included (as rosbag2
  does) — logged with the directories it created. :meth:`start` makes it the live recording
  (logged once: "recording to X"); :meth:`discard` removes one that was prepared for nothing.
* :meth:`write` / :meth:`flush` from the tick thread; a write or flush error stops the recording
  (:meth:`fail`: logged, reported as ``error`` in the diagnostics) while the simulation goes on.
* :meth:`stop` closes the bag and returns what it did ("bag X closed: N messages").
* Splits: ``max_duration_s`` is handed to the recorder when it supports it (the bag layer's
  ``max_duration_s``); :attr:`splits_supported` tells whether it does.
* QoS: each topic's offered QoS (``qos``, rosbag2 profile mappings) goes into the bag. The last
  messages of each transient-local (latched) topic, as many as its depth, are kept while not
  recording too, and every recording starts with them (the bag layer repeats them at the start
  of every split), as a late subscriber receives them: a recording started after the prediction
  still holds it, one started after a fault's start holds the fault's ground truth.

:func:`run_metadata` is what the node stores in the bag's ``custom_data``.
"""
from __future__ import annotations

import inspect
import shutil
import time
from collections import deque
from pathlib import Path
from typing import Mapping

from dmf_sim.bags.metadata import RunMetadata
from dmf_sim.bags.writer import latched_depth
from dmf_sim.core.errors import BagError, one_line

__all__ = ['run_metadata', 'RecordingControl']


def run_metadata(sim, *, driveline: str, engine: str, node: str,
                 publish_rate_hz: float) -> RunMetadata:
    """The :class:`RunMetadata` of a recording starting now (load and speed at its start)."""
    spring = sim.model.spring
    return RunMetadata(
        driveline=driveline, engine=engine, load_set=str(getattr(sim.engine, 'load_set', '')),
        alpha=spring.alpha if spring else None, theta_rad=spring.theta if spring else None,
        spring=spring.as_dict() if spring else None, load=sim.load, speed_rpm=sim.speed,
        dt_s=sim.dt, publish_rate_hz=publish_rate_hz, node=node,
        sensors=(sim.line.sensors.as_dict() if getattr(sim, 'live_sensors', None) is not None
                 else None))


def _missing_parents(path: Path) -> list[Path]:
    """The parent directories of ``path`` that do not exist, outermost first."""
    return [p for p in reversed(path.absolute().parents) if not p.exists()]


class RecordingControl:
    """One recording at a time for the live node.

    Args:
        topics: absolute topic name -> ROS type name of every stream recorded.
        log: info/warning/error logger.
        max_duration_s: split the recording into files of this many seconds (if the recorder
            supports it; None = the recorder's default).
        recorder_class: the bag writer (``BagRecorder``).
        qos: topic -> offered QoS profile (:func:`dmf_sim.bags.writer.qos_profile`); topics
            not given are recorded as the writer's default.
    """

    def __init__(self, topics: Mapping[str, str], log, *, max_duration_s: float | None = None,
                 recorder_class=None, qos: Mapping[str, dict] | None = None) -> None:
        if recorder_class is None:
            from dmf_sim.bags.writer import BagRecorder as recorder_class
        self.topics = dict(topics)
        self.qos = dict(qos or {})
        #: latched topic -> its last messages (log time, bytes), as many as its depth, recorded
        #: or not
        self.latched: dict[str, deque] = {
            t: deque(maxlen=n) for t, profile in self.qos.items()
            if (n := latched_depth([profile]))}
        self.log = log
        self.max_duration_s = max_duration_s
        self.recorder_class = recorder_class
        self.recorder = None
        self.path: Path | None = None       # the current or last bag
        self.error = ''

    @property
    def active(self) -> bool:
        return self.recorder is not None

    @property
    def message_count(self) -> int:
        return self.recorder.message_count if self.recorder is not None else 0

    @property
    def splits_supported(self) -> bool:
        return 'max_duration_s' in inspect.signature(self.recorder_class).parameters

    # ---- paths ------------------------------------------------------------------------------
    @staticmethod
    def check(bag_path: str) -> str | None:
        """Why ``bag_path`` cannot be recorded to, or None ('' = a new default name)."""
        if bag_path and (Path(bag_path).exists() or Path(bag_path).is_symlink()):
            return (f'bag path {bag_path} exists already; not overwriting it '
                    '(set another bag_path)')
        return None

    @staticmethod
    def target(bag_path: str) -> Path:
        """The bag directory for ``bag_path`` ('' = ``dmf_bag_<time>`` not yet taken)."""
        if bag_path:
            return Path(bag_path)
        base = f'dmf_bag_{time.strftime("%Y%m%d_%H%M%S")}'
        path, i = Path(base), 1
        while path.exists():
            path, i = Path(f'{base}_{i}'), i + 1
        return path

    def note_bag_path(self, bag_path: str) -> str | None:
        """What a new ``bag_path`` means while recording (None when not recording)."""
        if self.recorder is None:
            return None
        msg = (f'bag_path {bag_path!r} applies to the next recording; still recording to '
               f'{self.path}')
        self.log.info(msg)
        return msg

    # ---- lifecycle --------------------------------------------------------------------------
    def prepare(self, bag_path: str, metadata: RunMetadata):
        """Create the bag for ``bag_path``. Returns (recorder, None) or (None, reason)."""
        if reason := self.check(bag_path):
            return None, reason
        path = self.target(bag_path)
        created = _missing_parents(path)
        kwargs = {'custom_data': metadata.to_custom_data()}
        if self.qos:
            kwargs['qos'] = self.qos
        if self.max_duration_s is not None and self.splits_supported:
            kwargs['max_duration_s'] = float(self.max_duration_s)
        try:
            recorder = self.recorder_class(path, self.topics, **kwargs)
        except (OSError, ValueError) as exc:
            return None, f'cannot record to {path}: {one_line(exc)}'
        if created:
            self.log.info(f'created directory {created[0]} for bag {path}')
        return recorder, None

    def start(self, recorder) -> None:
        """Record to a prepared bag from now on; it starts with the latched messages."""
        for topic, held in self.latched.items():
            for last in held:
                if hasattr(recorder, 'hold_latched'):
                    recorder.hold_latched(topic, *last)
        self.recorder, self.path, self.error = recorder, recorder.path, ''
        self.log.info(f'recording to {recorder.path}')

    @staticmethod
    def discard(recorder) -> None:
        """Remove a bag that was prepared for a change refused after all."""
        recorder.close()
        shutil.rmtree(recorder.path, ignore_errors=True)

    def remove_unused(self) -> None:
        """Remove the live recording's bag: the node's start failed before it recorded
        anything (its ``bag_path`` is free again for the corrected start)."""
        rec, self.recorder = self.recorder, None
        if rec is not None:
            self.discard(rec)
            self.log.info(f'removed bag {rec.path}: the node did not start')

    def stop(self) -> str:
        """Close the bag; returns what happened (for the log, the ``~/record`` answer)."""
        rec, self.recorder = self.recorder, None
        if rec is None:
            return 'not recording'
        try:
            rec.close()
        except (OSError, BagError) as exc:
            msg = f'closing bag {rec.path} failed: {one_line(exc)}'
            self.log.error(msg)
            return msg
        msg = f'stopped recording: bag {rec.path.absolute()} closed, {rec.message_count} messages'
        self.log.info(msg)
        return msg

    def fail(self, exc: BaseException) -> None:
        """A write or flush failed (disk full, ...): stop recording, keep what is written."""
        self.error = one_line(exc)
        self.log.error(f'recording to {self.path} stopped: {self.error}')
        rec, self.recorder = self.recorder, None
        try:
            rec.close()
        except Exception:  # noqa: BLE001 - the bag stays readable up to its last chunk
            pass

    def write(self, topic: str, log_ns: int, data: bytes) -> None:
        if (held := self.latched.get(topic)) is not None:
            held.append((log_ns, bytes(data)))
        if self.recorder is None:
            return
        try:
            self.recorder.write(topic, log_ns, data)
        except (OSError, ValueError) as exc:
            self.fail(exc)

    def flush(self) -> None:
        if self.recorder is None:
            return
        try:
            self.recorder.flush()
        except (OSError, ValueError) as exc:
            self.fail(exc)
