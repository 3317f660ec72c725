"""HTML building blocks of the report: escaping, number formatting, tables, verdict cells,
the page's inline CSS and its one inline script (no external resources)."""

from __future__ import annotations

import html

import numpy as np

__all__ = ["esc", "slug", "num", "verdict", "verdict_cell", "html_table", "not_available", "DASH",
           "CSS", "SCRIPT"]


DASH = "—"


def esc(x) -> str:
    return html.escape(str(x), quote=True)


def slug(text: str) -> str:
    return "".join(c if c.isalnum() else "-" for c in text.lower()).strip("-")


def num(value, fmt: str = ".4g") -> str:
    if value is None:
        return DASH
    value = float(value)
    if np.isnan(value):
        return DASH
    if np.isinf(value):
        return "∞"
    return format(value, fmt)


def verdict(ok: bool | None) -> str:
    return {True: "PASS", False: "FAIL", None: "n/a"}[ok]


def verdict_cell(value_text: str, ok: bool | None, **data) -> str:
    attrs = " ".join(f'data-{k}="{esc(v)}"' for k, v in data.items())
    cls = {True: "pass", False: "fail", None: "na"}[ok]
    return (f'<td class="verdict {cls}" {attrs}><span class="value">{esc(value_text)}</span> '
            f'<b>{verdict(ok)}</b></td>')


def html_table(header: list[str], rows: list[list[str]], cls: str = "", raw: bool = False,
               table_id: str = "") -> str:
    """An HTML table; cells are escaped text unless ``raw`` (then each is a full ``<td>``)."""
    head = "".join(f"<th>{esc(h)}</th>" for h in header)
    body = []
    for row in rows:
        cells = "".join(c if raw and c.startswith("<td") else f"<td>{esc(c)}</td>" for c in row)
        body.append(f"<tr>{cells}</tr>")
    tid = f' id="{table_id}"' if table_id else ""
    return (f'<table class="{cls}"{tid}><thead><tr>{head}</tr></thead>'
            f'<tbody>{"".join(body)}</tbody></table>')


def not_available(what: str) -> str:
    return f'<p class="na">Not available: {esc(what)}</p>'


CSS = """
body{font-family:-apple-system,"Segoe UI",Helvetica,Arial,sans-serif;margin:0 auto;
max-width:1100px;padding:0 18px 40px;color:#1c1c1c;line-height:1.4}
h1{font-size:1.6em;margin:18px 0 4px}h2{border-bottom:2px solid #4a6fa5;padding-bottom:3px;
margin-top:34px}h3{margin:18px 0 6px}
table{border-collapse:collapse;margin:8px 0 14px;font-size:.86em}
th,td{border:1px solid #c9cfd8;padding:3px 7px;text-align:left;vertical-align:top}
thead th{background:#e8edf4}table.numeric td{font-variant-numeric:tabular-nums}
td.pass{background:#dff3e0}td.fail{background:#f8d9d6}td.na{color:#777}
td.verdict b{font-size:.85em;margin-left:4px}
figure{margin:10px 0 18px}figure img{max-width:100%;height:auto;border:1px solid #e1e4e8}
figcaption{font-size:.85em;color:#444}.file{color:#888}p.na{color:#8a5a00;font-style:italic}
pre{background:#f4f6f8;padding:8px;overflow-x:auto;font-size:.82em}
nav table td{font-size:.95em}.meta{color:#555;font-size:.9em}
"""


#: Inline check used by the headless-browser test: after load, how many images decoded.
SCRIPT = """
window.addEventListener('load', function () {
  var imgs = document.images, ok = 0;
  for (var i = 0; i < imgs.length; i++) {
    if (imgs[i].complete && imgs[i].naturalWidth > 0) { ok++; }
  }
  var el = document.getElementById('image-check');
  el.setAttribute('data-loaded', String(ok));
  el.setAttribute('data-total', String(imgs.length));
  el.textContent = 'images loaded ' + ok + ' / ' + imgs.length;
});
"""
