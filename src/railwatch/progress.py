"""Progress of long work that shows both on a terminal and in a log.

On a terminal (stderr is a TTY) a tqdm bar; anywhere else (``make run > log 2>&1``, ``nohup``, CI,
a service) tqdm would stay silent for the whole run, so :class:`Progress` writes plain log lines
instead, through :mod:`logging` (the library never prints; the CLI sends ``railwatch`` log records
to stderr):

    bench: 5/72 cells (7%), 0:42 elapsed, ~9:21 left; stage1-cnn-ae-seed0 AUC 0.912

one per update, or at most one every ``every_s`` seconds, and always one at the end. The estimate
of the time left counts only timed work: cells reused from an earlier run advance the count
(``update(n, timed=False)``) without making the rest look faster.
"""

from __future__ import annotations

import logging
import sys
import time
from types import TracebackType
from typing import Any

log = logging.getLogger("railwatch.progress")


def clock(seconds: float) -> str:
    """``h:mm:ss`` or ``m:ss``.

    >>> clock(42.4), clock(561), clock(3725)
    ('0:42', '9:21', '1:02:05')
    """
    s = int(round(seconds))
    h, rest = divmod(s, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class Progress:
    """Count ``total`` units of work named ``desc``; a bar on a terminal, log lines elsewhere.

    ``enabled=False`` (``--quiet``, or progress off in a config) shows nothing. ``every_s`` is the
    least time between two log lines (0: a line per update). ``terminal`` overrides the TTY check
    (tests). Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, total: float, desc: str, unit: str, *, enabled: bool = True,
                 every_s: float = 10.0, terminal: bool | None = None, **bar_options: Any) -> None:
        self.total, self.desc, self.unit = total, desc, unit
        self.enabled, self.every_s = enabled, every_s
        self.n = 0.0
        self.timed_n = 0.0
        self.postfix = ""
        self.started = time.monotonic()
        self._last_line = -float("inf")
        self._logged_n = 0.0
        self._closed = False
        tty = sys.stderr.isatty() if terminal is None else terminal
        self._bar = None
        if enabled and tty:
            from tqdm.auto import tqdm

            self._bar = tqdm(total=total, desc=desc, unit=unit, **bar_options)

    def update(self, n: float = 1, *, timed: bool = True) -> None:
        """``n`` more units done; ``timed=False`` for work that took no time (reused results)."""
        self.n += n
        if timed:
            self.timed_n += n
        if self._bar is not None:
            self._bar.update(n)
        elif self.enabled and (timed or self.n >= self.total):  # reused work is no news
            now = time.monotonic()
            if now - self._last_line >= self.every_s or self.n >= self.total:
                self._log_line(now)

    def set_postfix_str(self, text: str) -> None:
        """A note after the count (the last cell's result, say); shown with the next update."""
        self.postfix = text
        if self._bar is not None:
            self._bar.set_postfix_str(text, refresh=False)

    def set_description(self, desc: str) -> None:
        self.desc = desc
        if self._bar is not None:
            self._bar.set_description(desc)

    def line(self) -> str:
        """The log line for the current count."""
        elapsed = time.monotonic() - self.started
        share = f" ({100 * self.n / self.total:.0f}%)" if self.total else ""
        text = f"{self.desc}: {self.n:,.0f}/{self.total:,.0f} {self.unit}{share}, " \
               f"{clock(elapsed)} elapsed"
        remaining = self.total - self.n
        if 0 < remaining and self.timed_n > 0:
            text += f", ~{clock(elapsed / self.timed_n * remaining)} left"
        return text + (f"; {self.postfix}" if self.postfix else "")

    def _log_line(self, now: float) -> None:
        self._last_line, self._logged_n = now, self.n
        log.info("%s", self.line())

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._bar is not None:
            self._bar.close()
        elif self.enabled and self._logged_n < self.n < self.total:
            self._log_line(time.monotonic())  # stopped early: say where

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def seconds_of_recording(total_s: float, desc: str, enabled: bool = True) -> Progress:
    """Progress counting seconds of recording: a bar on a terminal, a log line every 10 s
    elsewhere."""
    return Progress(round(total_s, 1), desc, "s of recording", every_s=10.0, enabled=enabled,
                    unit_scale=True,
                    bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s of recording "
                               "[{elapsed}<{remaining}]")
