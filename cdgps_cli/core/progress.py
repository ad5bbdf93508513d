"""Progress of long stages on stderr: bars on a terminal, occasional plain lines otherwise.

One small API for every module (reading and writing MCAP, CSV logs, the filter, spectra …):

>>> from cdgps_cli.core import progress
>>> with progress.bar(n_epochs, "filter", unit="epoch") as p:   # doctest: +SKIP
...     for k in range(n_epochs):
...         p.update()
>>> for row in progress.iterate(rows, "writing states"):       # doctest: +SKIP
...     ...
>>> with progress.stage("smoothing"):                          # doctest: +SKIP
...     rts_smooth(...)                                         # no count: elapsed time only

Behaviour, decided when a bar opens:

* disabled (the default for library use, and ``cdgps --quiet`` / ``-q``): nothing is printed and
  the calls cost almost nothing;
* stderr is a terminal: a ``tqdm`` bar (rate, ETA), shown only for stages lasting over 0.5 s and
  erased when done (the commands' own summaries follow);
* stderr is not a terminal (logs, CI, pipes): a plain line ``desc: 40% (14400/36001 epoch), 8.0 s``
  at most every :data:`PLAIN_INTERVAL_S` seconds, and ``desc: done, … in 21.3 s`` at the end, only
  for stages longer than :data:`PLAIN_MIN_S`.

Progress goes to stderr only and never touches the data: outputs are byte-identical with and
without it.  The command line turns it on with :func:`configure` (``enabled=not quiet``).
"""

from __future__ import annotations

import io
import sys
import threading
import time
from contextlib import contextmanager

PLAIN_INTERVAL_S = 10.0
"""Non-terminal output: at most one progress line per stage every this many seconds."""
PLAIN_MIN_S = 2.0
"""Non-terminal output: stages shorter than this print nothing."""
BAR_DELAY_S = 0.5
"""Terminal: a bar appears only once its stage has run this long."""

_state = {"enabled": False, "stream": None}
_active: list = []
_lock = threading.Lock()


_KEEP = object()


def configure(enabled: bool | None = None, *, stream=_KEEP) -> None:
    """Turn progress output on or off (None: leave as is), and choose its stream (None:
    ``sys.stderr`` at the time a bar opens, so test runners that replace stderr capture it)."""
    if enabled is not None:
        _state["enabled"] = bool(enabled)
    if stream is not _KEEP:
        _state["stream"] = stream


def enabled() -> bool:
    return _state["enabled"]


def _stream():
    return _state["stream"] if _state["stream"] is not None else sys.stderr


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def _sized(stream) -> bool:
    """Whether the terminal reports its size (the bar then follows it).  A pseudo-terminal without
    one (0 × 0, e.g. under ``script``) gets 80 × 24: with 0 rows tqdm would hide the bar."""
    import os

    try:
        size = os.get_terminal_size(stream.fileno())
    except (AttributeError, ValueError, OSError, io.UnsupportedOperation):
        return False
    return size.columns > 0 and size.lines > 0


class Bar:
    """A progress counter for one stage (use :func:`bar`); a no-op when progress is disabled.

    ``update`` is cheap (an addition and a comparison): the display is refreshed only every
    ~0.1 % of ``total``, so it can be called once per message or epoch.
    """

    def __init__(self, total: int | None, desc: str, unit: str = "it"):
        self.total = None if total is None else int(total)
        self.desc = desc
        self.unit = unit
        self.n = 0
        self._shown = 0
        self._tqdm = None
        self._plain = None
        self._closed = not enabled()
        if self._closed:
            self._next = float("inf")
            return
        self._t0 = time.monotonic()
        self._step = max((self.total or 0) // 1000, 1)
        self._next = self._step
        stream = _stream()
        if _isatty(stream):
            from tqdm import tqdm

            tqdm.monitor_interval = 0       # no monitor thread: stages fork (core/beside.py) while a bar is up
            sized = _sized(stream)
            self._tqdm = tqdm(total=self.total, desc=desc, unit=unit, file=stream, leave=False, delay=BAR_DELAY_S,
                              mininterval=0.2, dynamic_ncols=sized, ncols=None if sized else 80,
                              nrows=None if sized else 24, unit_scale=(self.total or 0) >= 100_000)
        else:
            self._plain = stream
            self._last_line = self._t0
            self._printed = False
        with _lock:
            _active.append(self)

    # -- counting
    def update(self, n: int = 1) -> None:
        self.n += n
        if self.n >= self._next:
            self._flush()

    def update_to(self, n: int) -> None:
        """Set the count (for loops that know their position)."""
        self.update(n - self.n)

    def set_description(self, desc: str) -> None:
        self.desc = desc
        if self._tqdm is not None:
            self._tqdm.set_description_str(desc, refresh=False)

    def _flush(self) -> None:
        if self._closed:
            return
        self._next = self.n + self._step
        if self._tqdm is not None:
            self._tqdm.update(self.n - self._shown)
            self._shown = self.n
            return
        now = time.monotonic()
        if now - self._t0 >= PLAIN_MIN_S and now - self._last_line >= PLAIN_INTERVAL_S:
            self._last_line = now
            self._printed = True
            self._line(f"{self._count()}, {now - self._t0:.1f} s")

    def _count(self) -> str:
        if self.total:
            return f"{100.0 * self.n / self.total:3.0f}% ({self.n}/{self.total} {self.unit})"
        return f"{self.n} {self.unit}" if self.n else "…"

    def _line(self, text: str) -> None:
        try:
            print(f"{self.desc}: {text}", file=self._plain, flush=True)
        except (OSError, ValueError):        # a closed or broken stderr never stops the work
            self._closed = True

    def refresh(self) -> None:
        if self._tqdm is not None and not self._closed:
            self._tqdm.refresh()

    # -- end
    def close(self, done: bool = True) -> None:
        """End the bar; ``done=False``: the work stopped (an error): no "done" line."""
        if self._closed:
            return
        if self._tqdm is not None:
            self._tqdm.update(self.n - self._shown)
            self._tqdm.close()
        else:
            took = time.monotonic() - self._t0
            if done and (self._printed or took >= PLAIN_MIN_S):
                self._line(f"done, {self.n} {self.unit} in {took:.1f} s" if self.n else f"done in {took:.1f} s")
        self._closed = True
        with _lock:
            if self in _active:
                _active.remove(self)

    def __enter__(self) -> "Bar":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def bar(total: int | None, desc: str, unit: str = "it") -> Bar:
    """A :class:`Bar` over ``total`` units (None: unknown), e.g. ``bar(n, "reading run.mcap", "msg")``."""
    return Bar(total, desc, unit)


def iterate(iterable, desc: str, total: int | None = None, unit: str = "it"):
    """Yield the items of ``iterable`` while counting them on a bar (``total`` defaults to ``len``)."""
    if total is None:
        try:
            total = len(iterable)
        except TypeError:
            total = None
    with Bar(total, desc, unit) as b:
        for item in iterable:
            yield item
            b.update()


@contextmanager
def stage(desc: str):
    """A stage whose amount of work is not known (a compiled pass, a library call): elapsed time.

    On a terminal the bar's clock is refreshed twice a second by a helper thread; elsewhere one
    ``desc: done in X s`` line when the stage took over :data:`PLAIN_MIN_S`.
    """
    b = Bar(None, desc, "")
    stop = threading.Event()
    ticker = None
    if b._tqdm is not None:
        def tick():
            while not stop.wait(0.5):
                b.refresh()

        ticker = threading.Thread(target=tick, daemon=True)
        ticker.start()
    try:
        yield b
    finally:
        stop.set()
        if ticker is not None:
            ticker.join()
        b.close()


class CountingReader:
    """A binary file whose reads advance a bar by the bytes read (for parsers that take a file)."""

    def __init__(self, fh, b: Bar):
        self._fh, self._bar = fh, b

    def read(self, n: int = -1) -> bytes:
        data = self._fh.read(n)
        self._bar.update(len(data))
        return data

    def read1(self, n: int = -1) -> bytes:
        data = self._fh.read1(n)
        self._bar.update(len(data))
        return data

    def readinto(self, buf) -> int:
        k = self._fh.readinto(buf)
        self._bar.update(k or 0)
        return k

    def readline(self, limit: int = -1) -> bytes:
        data = self._fh.readline(limit)
        self._bar.update(len(data))
        return data

    def __iter__(self):
        return iter(self.readline, b"")

    def __getattr__(self, name):
        return getattr(self._fh, name)


@contextmanager
def reading(path, desc: str | None = None):
    """Open ``path`` for binary reading with a bar over its size in bytes (compressed size for a
    compressed file: wrap the handle with ``gzip.open``/``lzma.open`` to decompress)."""
    import os

    fh = open(path, "rb")
    try:
        size = os.fstat(fh.fileno()).st_size
        with Bar(size, desc or f"reading {os.path.basename(str(path))}", "B") as b:
            yield CountingReader(fh, b)
    finally:
        fh.close()


def to_csv(df, path, desc: str, rows_per_piece: int = 50_000, **to_csv_kwargs) -> None:
    """``df.to_csv(path, index=False, …)`` written in pieces of rows with a bar over the rows.

    The bytes are those of one ``df.to_csv`` call (each piece is the same formatting of its rows;
    only the first carries the header): writing in pieces changes nothing but the progress.
    """
    n = len(df)
    header = to_csv_kwargs.pop("header", True)
    with open(path, "w", encoding="utf-8", newline="") as fh, Bar(n, desc, "row") as b:
        if n == 0:
            df.to_csv(fh, header=header, **to_csv_kwargs)
            return
        for a in range(0, n, rows_per_piece):
            df.iloc[a:a + rows_per_piece].to_csv(fh, header=header if a == 0 else False, **to_csv_kwargs)
            b.update(min(rows_per_piece, n - a))


def write(msg: str) -> None:
    """Print a message line on stderr without breaking a bar that is on the screen."""
    stream = _stream()
    if any(b._tqdm is not None for b in _active):
        from tqdm import tqdm

        tqdm.write(msg, file=stream)
    else:
        print(msg, file=stream, flush=True)


def close_all() -> None:
    """Close every open bar (before an error message, so it is not printed onto a bar)."""
    with _lock:
        bars = list(_active)
    for b in bars:
        b.close(done=False)
