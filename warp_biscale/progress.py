"""Progress display for long runs: a one-line bar on a terminal, plain lines otherwise."""

from __future__ import annotations

import contextlib
import sys
import threading
import time

# Library-wide word to the user: set_quiet(True) (the command line's -q) silences compile_notice.
_QUIET = False
_COMPILE_NOTICE_SAID = False
COMPILE_NOTICE_DELAY = 0.5  # s: a build that takes longer is a compile, not a cache hit


def set_quiet(quiet: bool) -> None:
    """Silence (or restore) the library's own words on stderr outside a Progress (compile_notice)."""
    global _QUIET
    _QUIET = bool(quiet)


@contextlib.contextmanager
def compile_notice(stream=None):
    """Around a kernel build (a Warp module load, an OpenCL program build): if it runs longer than
    COMPILE_NOTICE_DELAY, which a cached build never does, say "compiling kernels (first run only)…"
    on stderr, once per process, so a first run's half minute of compiling is not silent."""
    def say():
        global _COMPILE_NOTICE_SAID
        if not _QUIET and not _COMPILE_NOTICE_SAID:
            _COMPILE_NOTICE_SAID = True
            out = stream or sys.stderr
            out.write("compiling kernels (first run only)…\n")
            out.flush()

    timer = threading.Timer(COMPILE_NOTICE_DELAY, say)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()


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
