"""The HTML report of a campaign (:func:`write_report`).

``html`` assembles the page and writes it, ``sections`` builds one section per paper item,
``read`` reads the campaign tree, ``figures`` renders the figures in worker processes,
``page`` holds the HTML building blocks and ``plots`` the matplotlib figures.
"""

from sysid.report.html import build_html, write_report
from sysid.report.sections import PAPER_PAIRS

__all__ = ["write_report", "build_html", "PAPER_PAIRS"]
