"""Per-stage clocks of the stereo tracker: wall time (``time.perf_counter``) and the CPU time of
the process (``time.process_time``, all its threads), so that a frame's cost can be compared on a
shared machine where wall time mostly measures the other processes."""

from __future__ import annotations

import time
from contextlib import contextmanager


class StageClock:
    """Seconds by stage, wall (:attr:`wall`) and CPU (:attr:`cpu`), accumulated over the
    ``with clock.stage(name):`` blocks of one frame."""

    def __init__(self, stages):
        self.wall = dict.fromkeys(stages, 0.0)
        self.cpu = dict.fromkeys(stages, 0.0)

    @contextmanager
    def stage(self, name: str):
        w, c = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.wall[name] = self.wall.get(name, 0.0) + time.perf_counter() - w
            self.cpu[name] = self.cpu.get(name, 0.0) + time.process_time() - c
