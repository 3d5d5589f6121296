"""Progress display for long runs: a one-line bar on a terminal, plain lines otherwise."""

from __future__ import annotations

import sys
import time


class Progress:
    """Report stage progress. `enabled=None` shows it only when stderr is a terminal.

    Call `stage(name, total)` to start a stage and `advance(n)` as work completes; `done()`
    closes the current stage with its wall time.
    """

    def __init__(self, enabled: bool | None = None, stream=None):
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else bool(enabled)
        self.tty = self.enabled and self.stream.isatty()
        self._name, self._total, self._count, self._t0 = None, 0, 0, 0.0

    def stage(self, name: str, total: int = 1):
        self.done()
        self._name, self._total, self._count, self._t0 = name, max(int(total), 1), 0, time.perf_counter()
        self._draw()

    def advance(self, n: int = 1):
        self._count = min(self._count + n, self._total)
        if self.tty:
            self._draw()

    def done(self):
        if self._name is None:
            return
        self._count = self._total
        if self.enabled:
            dt = time.perf_counter() - self._t0
            end = "\r" if self.tty else ""
            self.stream.write(f"{end}{self._name:<28} done in {dt:8.3f} s{' ' * 20}\n")
            self.stream.flush()
        self._name = None

    def _draw(self):
        if not self.tty:
            return
        frac = self._count / self._total
        bar = "#" * int(30 * frac)
        self.stream.write(f"\r{self._name:<28} [{bar:<30}] {100 * frac:5.1f}%")
        self.stream.flush()


class NoProgress(Progress):
    def __init__(self):
        super().__init__(enabled=False)


def as_progress(progress) -> Progress:
    if isinstance(progress, Progress):
        return progress
    return Progress(enabled=progress)
