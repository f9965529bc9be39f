"""The result objects show as small HTML tables in a notebook (`_repr_html_`) and as one short
line in a console (`__repr__`): the tables parse, hold the numbers, and escape what they show."""

from __future__ import annotations

from html.parser import HTMLParser

import numpy as np
import pyarrow as pa

import tightscan
from tightscan.diagnose import Diagnosis, Effect


class _Cells(HTMLParser):
    """The text of every table cell (th and td), and the captions, in document order."""

    def __init__(self) -> None:
        super().__init__()
        self.cells: list[str] = []
        self.captions: list[str] = []
        self.tables = 0
        self._in: str | None = None

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag == "table":
            self.tables += 1
        if tag in ("td", "th", "caption"):
            self._in = tag
            (self.captions if tag == "caption" else self.cells).append("")

    def handle_endtag(self, tag: str) -> None:
        if tag in ("td", "th", "caption"):
            self._in = None

    def handle_data(self, data: str) -> None:
        if self._in == "caption":
            self.captions[-1] += data
        elif self._in is not None:
            self.cells[-1] += data


def _parse(html: str) -> _Cells:
    p = _Cells()
    p.feed(html)
    p.close()
    return p


def test_scan_summary_table_holds_the_counts_and_escapes_names() -> None:
    s = tightscan.ScanSummary(
        "<out>.parquet", files=2, tightenings=1234, samples=5_000_000, changes=17, seconds=2.0,
        status_counts={"ok": 1200, "too_short": 34}, skipped_files=[("bad.parquet", "no torque")],
    )
    html = s._repr_html_()
    assert "<out>" not in html and "&lt;out&gt;" in html
    p = _parse(html)
    assert p.tables == 3
    pairs = dict(zip(p.cells[0::2], p.cells[1::2]))
    assert pairs["tightenings"] == "1,234" and pairs["changes found"] == "17" and pairs["M samples/s"] == "2.5"
    assert p.cells[p.cells.index("too_short") + 1] == "34"
    assert "bad.parquet" in p.cells and "no torque" in p.cells
    assert any("<out>.parquet" in c for c in p.captions)


def test_diagnosis_repr_is_one_line_and_its_table_lists_the_effects() -> None:
    effect = Effect("channel_delay", "the torque channel lags", "within_tightening", True, {}, 0.05, {"rmse_gain": 0.25})
    d = Diagnosis("m", 0.1, 0.05, [effect], False, details={"tightenings": 321, "long": list(range(1000))})
    text = repr(d)
    assert "\n" not in text and "channel_delay" in text and "0.05" in text and len(text) < 300
    p = _parse(d._repr_html_())
    pairs = dict(zip(p.cells[0:10:2], p.cells[1:10:2]))
    assert pairs["tightenings"] == "321" and pairs["RMSE before [Nm]"] == "0.1" and pairs["unexplained structure left"] == "no"
    row = p.cells[p.cells.index("channel_delay") - 1 : p.cells.index("channel_delay") + 4]
    assert row == ["1", "channel_delay", "yes", "0.05 Nm", "25.0 %"]


def test_sequence_monitor_shows_groups_with_an_alarm_first() -> None:
    t = pa.table({
        "station": ["a"] * 40 + ["b"] * 40,
        "n": list(range(40)) * 2,
        "torque_rate": [1.0 + 0.01 * (i % 3) for i in range(40)] + [1.0 + 0.01 * (i % 3) + (0.3 if i >= 25 else 0.0) for i in range(40)],
    })
    m = tightscan.monitor_sequence(t, by=["station"], order_by="n", features=["torque_rate"])
    assert repr(m) == "SequenceMonitor(tightenings=80 rows, groups=2 rows, groups with an alarm=1)"
    p = _parse(m._repr_html_())
    header = m.groups.column_names
    assert p.cells[: len(header)] == header
    first_row = p.cells[len(header) : 2 * len(header)]
    assert first_row[header.index("station")] == "b"  # the group with the alarm leads
    assert first_row[header.index("first_alarm_order")] == "25"
    assert "1 with an alarm" in p.captions[0]


def test_regression_monitor_repr_and_table() -> None:
    rate = 0.5 + np.random.default_rng(1).normal(0.0, 0.02, 300)
    rate[150:] *= 1.1
    m = tightscan.monitor_regression(rate, training=60)
    assert repr(m).startswith("RegressionMonitor(method=") and "alarm=True" in repr(m) and "\n" not in repr(m)
    p = _parse(m._repr_html_())
    pairs = dict(zip(p.cells[0::2], p.cells[1::2]))
    assert pairs["alarm"] == "yes" and pairs["training observations m"] == "60"
    assert int(pairs["alarm index"].replace(",", "")) == m.alarm_index


def test_result_columns_show_as_a_table() -> None:
    cols = tightscan.result_columns()
    p = _parse(cols._repr_html_())  # type: ignore[attr-defined]
    assert p.cells[:4] == ["column", "type", "unit", "meaning"]
    assert p.cells[4::4] == [c.name for c in cols]
    assert p.cells[p.cells.index("torque_rate") + 2] == "Nm/deg"
