"""Small HTML tables for notebooks (``_repr_html_`` of the result objects).

Plain tables, escaped, no styling beyond what a notebook gives tables, so that they read the
same in Jupyter, VS Code and a static HTML export.
"""

from __future__ import annotations

import html
import math
from typing import Any, Iterable, Sequence


def cell(value: Any) -> str:
    """A value as escaped table text: floats to 4 significant digits, counts with separators.

    >>> cell(0.123456), cell(12345), cell(None), cell("<a>")
    ('0.1235', '12,345', '', '&lt;a&gt;')
    """
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return f"{value:,}"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.4g}"
    return html.escape(str(value))


def key_value_table(title: str, rows: Iterable[tuple[str, Any]]) -> str:
    """A two-column table (parameter, value) under a caption."""
    body = "".join(f"<tr><th style='text-align:left'>{html.escape(k)}</th><td>{cell(v)}</td></tr>" for k, v in rows)
    return f"<table><caption>{html.escape(title)}</caption><tbody>{body}</tbody></table>"


def grid_table(title: str, header: Sequence[str], rows: Iterable[Sequence[Any]], more: int = 0) -> str:
    """A table with a header row; ``more`` rows left out are named in a last row."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in row) + "</tr>" for row in rows)
    if more:
        body += f"<tr><td colspan='{len(header)}'>... and {more:,} more rows</td></tr>"
    return f"<table><caption>{html.escape(title)}</caption><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
