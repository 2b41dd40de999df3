"""Progress of long CLI steps (model build, quantization): a tqdm bar on a terminal, steady
lines otherwise, so logs of CI jobs and services show how far a step got without bar noise."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator
from typing import TextIO, TypeVar

T = TypeVar("T")


def progress(items: Iterable[T], total: int | None = None, desc: str = "",
             stream: TextIO | None = None, every_s: float = 2.0) -> Iterator[T]:
    """Yield ``items`` while showing progress on ``stream`` (default stderr).

    On a terminal: a tqdm bar. Otherwise one line ``desc: i/total`` at the first item, at most
    every ``every_s`` seconds after that, and at the end.
    """
    stream = stream or sys.stderr
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    if _is_terminal(stream):
        from tqdm import tqdm

        yield from tqdm(items, total=total, desc=desc, file=stream, leave=False,
                        dynamic_ncols=True)
        return
    of = f"/{total}" if total else ""
    last = -float("inf")
    count = 0
    for count, item in enumerate(items, 1):
        now = time.monotonic()
        if now - last >= every_s:
            print(f"{desc}: {count - 1}{of}", file=stream, flush=True)
            last = now
        yield item
    print(f"{desc}: {count}{of} done", file=stream, flush=True)


class Steps:
    """Named steps of one job (``with steps.step("writing")``), shown like :func:`progress`."""

    def __init__(self, names: list[str], desc: str, stream: TextIO | None = None) -> None:
        self.names = names
        self.desc = desc
        self.stream = stream or sys.stderr
        self._bar = None
        self._done = 0
        if _is_terminal(self.stream):
            from tqdm import tqdm

            self._bar = tqdm(total=len(names), desc=desc, file=self.stream, leave=False,
                             dynamic_ncols=True)

    def start(self, name: str) -> None:
        if self._bar is not None:
            self._bar.set_postfix_str(name)
        else:
            print(f"{self.desc}: step {self._done + 1}/{len(self.names)}: {name}",
                  file=self.stream, flush=True)

    def done(self) -> None:
        self._done += 1
        if self._bar is not None:
            self._bar.update(1)
            if self._done >= len(self.names):
                self._bar.close()


def _is_terminal(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False
