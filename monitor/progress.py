"""Progress of long CLI steps (demo rendering, model build, replay, quantization): a tqdm bar
on stderr when it is a terminal, and nothing at all otherwise, so logs of CI jobs and services
hold only the result lines (a bar's redraws are noise in a log file)."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import TextIO, TypeVar

T = TypeVar("T")


def is_terminal(stream: TextIO | None = None) -> bool:
    """True when ``stream`` (default stderr) is a terminal an operator watches."""
    stream = stream or sys.stderr
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # closed, or a stream without isatty
        return False


def progress(items: Iterable[T], total: int | None = None, desc: str = "",
             stream: TextIO | None = None, unit: str = "it") -> Iterator[T]:
    """Yield ``items``; on a terminal with a tqdm bar on ``stream`` (default stderr)."""
    stream = stream or sys.stderr
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    if not is_terminal(stream):
        yield from items
        return
    from tqdm import tqdm

    yield from tqdm(items, total=total, desc=desc, file=stream, leave=False, unit=unit,
                    dynamic_ncols=True)


class _NoBar:
    def update(self, n: int = 1) -> None:
        pass

    def set_postfix_str(self, text: str) -> None:
        pass

    def close(self) -> None:
        pass


def bar(total: int | None, desc: str, unit: str = "it", stream: TextIO | None = None,
        enabled: bool = True):
    """A bar to ``update(n)`` and ``close()``: tqdm on a terminal, a silent stand-in else."""
    stream = stream or sys.stderr
    if not (enabled and is_terminal(stream)):
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total or None, desc=desc, unit=unit, file=stream, leave=False,
                dynamic_ncols=True)


class Steps:
    """Named steps of one job (``steps.start("writing")`` ... ``steps.done()``): a bar over the
    steps, naming the current one, on a terminal; silent otherwise."""

    def __init__(self, names: list[str], desc: str, stream: TextIO | None = None) -> None:
        self.names = names
        self.desc = desc
        self._bar = bar(len(names), desc, "step", stream)
        self._done = 0

    def start(self, name: str) -> None:
        self._bar.set_postfix_str(name)
        self._bar.update(0)  # redraw now: the step may run for a while

    def done(self) -> None:
        self._done += 1
        self._bar.update(1)
        if self._done >= len(self.names):
            self._bar.close()

    def close(self) -> None:
        self._bar.close()
