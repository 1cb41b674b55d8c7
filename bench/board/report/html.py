"""HTML building blocks of `bench report`: the page's CSS, escaping, estimates with their intervals, tables, images.

Every section of the page (bench.board.report.page, bench.board.report.remote) writes its HTML through these.
"""

from __future__ import annotations

import html
from collections.abc import Collection

from bench.scoring.summary import EstimateDoc, fmt_estimate

CSS = """
body{font-family:-apple-system,'Segoe UI',Helvetica,Arial,sans-serif;margin:24px auto;max-width:1100px;color:#222;
line-height:1.4;padding:0 16px}
h1{font-size:22px;margin-bottom:2px} h2{font-size:17px;margin-top:28px;border-bottom:1px solid #ddd;padding-bottom:4px}
.meta{color:#666;font-size:12px} img{max-width:100%;border:1px solid #eee;margin:6px 0}
table{border-collapse:collapse;font-size:12px;margin:8px 0} th,td{border-bottom:1px solid #eee;padding:3px 8px;
text-align:left} th{background:#f6f6f6} td.num{text-align:right;font-variant-numeric:tabular-nums}
.seen{color:#3b6fb6;font-weight:600} .unseen{color:#e07b28;font-weight:600} .bad{color:#b00020;font-weight:600}
.good{color:#1b7f3b;font-weight:600} .note{color:#555;font-size:12px}
figure{display:inline-block;margin:2px 4px} figcaption{font-size:11px}
"""


def esc(x: object) -> str:
    return html.escape(str(x))


def _estimate(est: EstimateDoc | None, pct: bool, signed: bool = True) -> str:
    """`summary.fmt_estimate`, or n/a with the reason (escaped) when there is no value."""
    if not est or est.get("value") is None:
        return f"n/a{' (' + esc(est.get('reason')) + ')' if est and est.get('reason') else ''}"
    return fmt_estimate(est, pct, signed)


def return_cell(est: EstimateDoc | None) -> str:
    """A mean return with its interval, in the env's units (`-274.6 [-325.5, -233.9]`), never as a percentage."""
    return _estimate(est, pct=False, signed=False)


def rate_cell(est: EstimateDoc | None) -> str:
    return _estimate(est, pct=True)


def signed_cell(est: EstimateDoc | None) -> str:
    return _estimate(est, pct=False)


def table_html(header: list[str], rows: list[list[str]], num: Collection[int] = frozenset()) -> str:
    th = "".join(f"<th>{esc(h)}</th>" for h in header)
    body = "".join(
        "<tr>"
        + "".join(f"<td class='num'>{c}</td>" if i in num else f"<td>{c}</td>" for i, c in enumerate(r))
        + "</tr>"
        for r in rows
    )
    return f"<table><tr>{th}</tr>{body}</table>"


def img_tag(name: str, alt: str) -> str:
    return f"<img src='{esc(name)}' alt='{esc(alt)}'>"
