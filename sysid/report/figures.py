"""Figures of one report: queued while the sections are built, rendered in worker processes
(:func:`report_processes`), written as PNG files and embedded as base64 ``<figure>`` elements.

:class:`Context` is the state the sections share: the tree, the figure queue, the anchors of
the index and each model's frequency response on the data grid (rad/s).
"""

from __future__ import annotations

import base64
import concurrent.futures
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import xarray as xr

import sysid.report.plots as plots
from sysid.assess.envelopes import Envelope
from sysid.core.util import POOL_FAILURES, Progress, forkserver_context, worker_processes
from sysid.models import frequency_response
from sysid.report.page import esc

__all__ = ["MAX_REPORT_PROCESSES", "report_processes", "Renderer", "Context"]


#: Worker processes that render the report's figures (``SYSID_REPORT_PROCESSES`` overrides;
#: 1 renders in the calling process). Drawing is most of a report's time (about 0.9 s a
#: figure, 25 figures for the hover study) and pure Python, so only processes help.
MAX_REPORT_PROCESSES = 4


def report_processes() -> int:
    """How many processes render figures: ``SYSID_REPORT_PROCESSES``, else the usable cores
    up to :data:`MAX_REPORT_PROCESSES`; 1 inside a daemonic process (a Dask worker), which
    may not start children."""
    return worker_processes("SYSID_REPORT_PROCESSES", MAX_REPORT_PROCESSES)


class Renderer:
    """Renders figures in a process pool, or inline with one process; figures are queued
    while the sections are built and collected when the page is assembled. A pool that
    cannot start or whose worker dies (e.g. killed for memory) costs time, not the report:
    its figures are drawn here instead."""

    def __init__(self, processes: int):
        self._pool = None
        if processes > 1:
            self._pool = concurrent.futures.ProcessPoolExecutor(
                processes, mp_context=forkserver_context())

    def submit(self, builder, args: tuple) -> Callable[[], bytes]:
        """A callable that returns the figure's PNG bytes."""
        if self._pool is not None:
            try:
                future = self._pool.submit(plots.render_png, builder, args)
            except POOL_FAILURES:
                self.close()
            else:
                def result() -> bytes:
                    try:
                        return future.result()
                    except POOL_FAILURES:
                        return plots.render_png(builder, args)
                return result
        data = plots.render_png(builder, args)
        return lambda: data

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


@dataclass
class Context:
    """Shared state of one report: the tree, where figures go, the index of anchors."""

    tree: xr.DataTree
    figure_dir: Path
    progress: Progress
    envelope: Envelope
    renderer: Renderer
    figures: list[str] = field(default_factory=list)
    anchors: dict[str, str] = field(default_factory=dict)  # anchor -> caption
    _model_fr: dict = field(default_factory=dict)
    _pending: dict = field(default_factory=dict)  # slot token -> (name, path, caption, png)

    def figure(self, name: str, caption: str, builder, *args) -> str:
        """Queue ``builder(*args)`` (a :mod:`sysid.report.plots` figure function) for
        ``figures/<name>.png``; return a slot token that :meth:`embed_figures` replaces
        with the embedded ``<figure>``."""
        path = self.figure_dir / f"{name}.png"
        self.figures.append(path.name)
        self.anchors[f"fig-{name}"] = caption
        token = f"\x00figure:{name}\x00"
        self._pending[token] = (name, path, caption, self.renderer.submit(builder, args))
        return token

    def embed_figures(self, text: str) -> str:
        """Write every queued figure and put its ``<figure>`` in place of its slot token."""
        for token, (name, path, caption, png) in self._pending.items():
            data = png()
            path.write_bytes(data)
            b64 = base64.b64encode(data).decode("ascii")
            text = text.replace(
                token,
                f'<figure id="fig-{name}"><img alt="{esc(caption)}" '
                f'src="data:image/png;base64,{b64}"><figcaption>{esc(caption)} '
                f'<span class="file">(figures/{esc(path.name)})</span></figcaption></figure>')
        self._pending.clear()
        return text

    def model_response(self, name: str, model: xr.Dataset, omega: np.ndarray) -> xr.DataArray:
        """Frequency response of a model on the data grid, computed once per model."""
        if name not in self._model_fr:
            self._model_fr[name] = frequency_response(model, omega)
        return self._model_fr[name]
