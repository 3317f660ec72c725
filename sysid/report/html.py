"""Self-contained HTML report of a campaign: the paper's figures and tables from a DataTree.

:func:`write_report` reads the campaign groups of ``docs/data_model.md`` and writes
``out_dir/report.html`` -- one file, every plot embedded as a base64 PNG, inline CSS and one
inline script, no external resources, so it opens offline -- plus every plot as a PNG file in
``out_dir/figures/`` with a stable descriptive name. Everything is built in a temporary
directory and moved into place at the end: a failure leaves no half-written report.

Sections (each only when its groups exist; a section whose groups are missing is left out,
so the report of imported data alone has trim, inputs and provenance), with the items of
the paper
(*Comparison of frequency and time domain identification of a helicopter in hover*) they reproduce:

========================  ==========================================================
section                   paper item, source groups
========================  ==========================================================
Trim                      Table 1; ``/trim`` or the ``trim_*`` attrs of a manoeuvre
Inputs                    Figure 1; ``/maneuvers/sweep_*``
Conditioning              Figures 2-3; ``/frequency_response`` vs
                          ``/frequency_response_siso``, ``cross_coherence``
Input/output pairs        Figures 4-15; ``/frequency_response``, ``/models/*``,
                          ``/linearization``; MUAD mismatch (Eq. 20)
Time-domain verification  Figures 16-19; ``/verification/<maneuver>``
Derivatives               Tables 2 (stability) and 3 (control, delays); ``/models/*``
Guidelines                cost and accuracy guidelines of ``docs/methods.md``
Model reduction           ``/models/<method>/reduction`` or the model's ``reduction_steps``
Provenance                versions, seeds, FMU, campaign settings
========================  ==========================================================

Guideline thresholds (:data:`sysid.core.guidelines.GUIDELINES`, Tischler & Remple 2012;
docs/methods.md, "Guidelines"):
``J_ave <= 100``, every pair ``J <= 200``, Cramer-Rao bound ``<= 20 %``, insensitivity
``<= 10 %``, ``J_rms <= 2``, ``TIC <= 0.25``, composite coherence ``>= 0.6`` over the fitted
range, cross-control coherence ``<= 0.5``.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import xarray as xr

from sysid import __version__
from sysid.assess.envelopes import MUAD, Envelope
from sysid.core.errors import InputDataError
from sysid.core.util import Progress
from sysid.report.figures import Context, Renderer, report_processes
from sysid.report.page import CSS, SCRIPT, esc
from sysid.report.sections import (SECTIONS, PairResult, index, section_conditioning,
                                   section_derivatives, section_fidelity,
                                   section_guidelines, section_inputs,
                                   section_pairs, section_provenance, section_reduction,
                                   section_time, section_trim)
from sysid.report.handling_qualities import section_handling_qualities

__all__ = ["write_report", "build_html"]


def build_html(tree: xr.DataTree, figure_dir: str | os.PathLike, *, title: str | None = None,
               progress: Progress | None = None, envelope: Envelope = MUAD) -> str:
    """The report's HTML text; figures are written into ``figure_dir`` on the way."""
    progress = progress or Progress(quiet=True)
    renderer = Renderer(report_processes())
    try:
        ctx = Context(tree, Path(figure_dir), progress, envelope, renderer)
        text = _page(ctx, title)
        with progress.stage(f"report: rendering {len(ctx.figures)} figures"):
            return ctx.embed_figures(text)
    finally:
        renderer.close()


def _page(ctx: Context, title: str | None) -> str:
    """The page, with a slot token where each queued figure goes."""
    tree, progress = ctx.tree, ctx.progress
    body: dict[str, str] = {}
    pair_results: dict[str, PairResult] = {}
    with progress.stage("report: trim (Table 1)"):
        body["trim"] = section_trim(ctx)
    with progress.stage("report: inputs (Figure 1)"):
        body["inputs"] = section_inputs(ctx)
    with progress.stage("report: conditioning (Figures 2-3)"):
        body["conditioning"] = section_conditioning(ctx)
    with progress.stage("report: input/output pairs (Figures 4-15)"):
        body["pairs"] = section_pairs(ctx, pair_results)
    with progress.stage("report: time-domain verification (Figures 16-19)"):
        time = section_time(ctx)
        body["time"] = time["html"]
    with progress.stage("report: derivatives (Tables 2-3)"):
        body["derivatives"] = section_derivatives(ctx)
        body["fidelity"] = section_fidelity(ctx)
    with progress.stage("report: guidelines, reduction, provenance"):
        body["guidelines"] = section_guidelines(ctx, pair_results, time)
        body["reduction"] = section_reduction(ctx)
        body["provenance"] = section_provenance(ctx)
    with progress.stage("report: handling qualities (ADS-33E-PRF), hold margins"):
        body["handling_qualities"] = section_handling_qualities(ctx)
    root = tree.to_dataset(inherit=False).attrs
    if title is None:
        name = root.get("campaign", root.get("name", "campaign"))
        cond = root.get("flight_condition")
        title = f"sysid report — {name}" + (f" ({cond})" if cond else "")
    # A section whose groups the campaign does not hold is left out (and out of the index).
    present = [(a, h, items) for a, h, items in SECTIONS if body[a].strip()]
    sections = "".join(
        f'<section id="{a}"><h2>{esc(h)}'
        + (f' <span class="meta">(paper {esc(items)})</span>' if items else "")
        + f"</h2>{body[a]}</section>" for a, h, items in present)
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{esc(title)}</title><style>{CSS}</style></head><body>"
            f"<h1>{esc(title)}</h1><p class=\"meta\">Rotorcraft system identification report "
            f"generated by sysid {esc(__version__)}; {len(ctx.figures)} figures "
            f"(also as PNG files in figures/).</p>"
            f'<div id="image-check" hidden data-loaded="" data-total=""></div>'
            f"{index(ctx, present)}{sections}<script>{SCRIPT}</script></body></html>\n")


def write_report(tree: xr.DataTree, out_dir: str | os.PathLike, *, title: str | None = None,
                 quiet: bool = False, envelope: Envelope = MUAD) -> Path:
    """Write ``out_dir/report.html`` and ``out_dir/figures/*.png`` for a campaign DataTree.

    Parameters
    ----------
    tree : xr.DataTree
        A campaign (``docs/data_model.md``); any subset of its groups may be present.
    out_dir : path
        Created if needed. An existing ``report.html`` and ``figures/`` are replaced.
    title : str, optional
        Default: from the root attributes ``campaign`` and ``flight_condition``.
    quiet : bool
        Silence the per-section progress lines.
    envelope : sysid.assess.envelopes.Envelope
        Mismatch envelope of the pair figures (default MUAD).

    Returns
    -------
    Path of ``report.html``.

    Everything is built in a temporary directory inside ``out_dir`` and moved into place
    only when complete: if anything fails, no new ``report.html`` is left behind.
    """
    if not isinstance(tree, xr.DataTree):
        raise InputDataError(f"write_report: expected an xarray.DataTree campaign, got "
                             f"{type(tree).__name__}")
    out_dir = Path(out_dir)
    created = not out_dir.exists()
    out_dir.mkdir(parents=True, exist_ok=True)
    progress = Progress(quiet=quiet)
    tmp = Path(tempfile.mkdtemp(prefix=".report-", dir=out_dir))
    try:
        (tmp / "figures").mkdir()
        text = build_html(tree, tmp / "figures", title=title, progress=progress,
                          envelope=envelope)
        (tmp / "report.html").write_text(text, encoding="utf-8")
        old = out_dir / "figures"
        if old.exists():
            trash = tmp / "old-figures"
            os.replace(old, trash)
        os.replace(tmp / "figures", out_dir / "figures")
        os.replace(tmp / "report.html", out_dir / "report.html")
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if created:
            shutil.rmtree(out_dir, ignore_errors=True)
        raise
    shutil.rmtree(tmp, ignore_errors=True)
    progress.message(f"[sysid] report written to {out_dir / 'report.html'}")
    return out_dir / "report.html"
