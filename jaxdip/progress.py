"""A small host-side progress bar for chunked scans and iterative searches (stderr, no dependency)."""

from __future__ import annotations

import os
import sys
import time


class Progress:
    def __init__(self, total: int, desc: str = "", enabled: bool = True, stream=None):
        self.total = max(int(total), 1)
        self.desc = desc
        self.n = 0
        self.t0 = time.perf_counter()
        self.stream = stream or sys.stderr
        self.enabled = enabled and os.environ.get("JAXDIP_NO_PROGRESS", "") == ""
        self.postfix = ""
        self._draw()

    def update(self, n: int = 1, postfix: str | None = None):
        self.n = min(self.n + n, self.total)
        if postfix is not None:
            self.postfix = postfix
        self._draw()

    def _draw(self):
        if not self.enabled:
            return
        frac = self.n / self.total
        width = 24
        bar = "#" * int(frac * width) + "-" * (width - int(frac * width))
        el = time.perf_counter() - self.t0
        eta = f"{el / frac - el:5.1f}s" if frac > 0 else "    ?"  # unknown until the first chunk is done
        tail = f" {self.postfix}" if self.postfix else ""
        end = "\n" if self.n >= self.total else ""
        self.stream.write(f"\r{self.desc} [{bar}] {self.n}/{self.total} {el:5.1f}s eta {eta}{tail}{end}")
        self.stream.flush()

    def close(self):
        if self.enabled and self.n < self.total:
            self.stream.write("\n")
            self.stream.flush()
