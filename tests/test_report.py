"""tightscan report (issue 14): one self-contained HTML file, checked in a real headless browser.

The browser is Debian's chromium (``make browser``, which ``make test`` runs first, installs
it); the test is skipped, saying why, only where it is not installed. It renders the report
twice: a screenshot of the page as written (any console message fails: the report has no
script, so a message means the browser complained), and the DOM of a copy with a probe script
appended that lists every image's natural size once the page has loaded."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import tightscan
from tightscan.cli import main

pytest.importorskip("jinja2", reason="the report needs Jinja2")
pytest.importorskip("matplotlib", reason="the report needs matplotlib")

DIAGNOSIS = {
    "model": "T = a_j + b_j angle + runout",
    "rmse_before": 0.031,
    "rmse_after": 0.012,
    "unexplained_structure": False,
    "tightenings": 40,
    "effects": [
        {"name": "runout", "description": "once-per-revolution modulation", "level": "within_tightening", "significant": True,
         "parameters": {}, "rmse_after": 0.012, "rmse_unit": "Nm", "evidence": {"rmse_gain": 0.6}},
    ],
    "spectrum": {"peaks": [{"domain": "angle", "period_deg": 360.0, "frequency": 1 / 360, "power_ratio": 30.0, "p_value": 1e-8, "explained_by": "runout"}],
                 "axes": {"angle": {}}},
}
DETECTION_QUALITY = {"recall_vs_magnitude": {"edges": [0.03, 0.06, 0.09], "same_curves": {"ours (rule)": [0.4, 0.9]}}}


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A scan of 60 simulated tightenings on two stations (one named to test escaping), its
    report with the curves, a diagnosis and the benchmark's recall, written by the CLI."""
    d = tmp_path_factory.mktemp("report")
    curves, _ = tightscan.simulate(60, seed=21, with_clamp_force=True)
    station = np.where(np.arange(60) % 2 == 0, "A-1", "<b>B&2</b>")
    curves = curves.append_column("station", pa.array(station.tolist()))
    pq.write_table(curves, d / "curves.parquet")
    tightscan.scan_parquet(d / "curves.parquet", d / "results", passthrough=["station"], progress=False)
    (d / "diag.json").write_text(json.dumps(DIAGNOSIS))
    (d / "dq.json").write_text(json.dumps(DETECTION_QUALITY))
    out = d / "report.html"
    code = main(["report", str(d / "results"), "--curves", str(d / "curves.parquet"), "--diagnose", str(d / "diag.json"),
                 "--detection-quality", str(d / "dq.json"), "--by", "station", "--worst", "2", "-o", str(out)])
    assert code == 0
    return out


def test_report_is_self_contained_and_escaped(report: Path) -> None:
    html = report.read_text()
    # every figure is embedded; nothing points off the page
    sources = re.findall(r'<img[^>]*\bsrc="([^"]*)"', html)
    assert len(sources) == 2 * 2 + 1 + 1 + 1  # two tightenings x (curve, detectors), control chart, spectrum, recall
    assert all(s.startswith("data:image/png;base64,") for s in sources)
    assert not re.search(r'(src|href)="(https?:)?//', html) and "url(" not in html and "<script" not in html
    # the summary's parts
    for text in ("60</b>tightenings", "Changes by station", "Changes by detector", "CUSUM threshold h", "Decision rule", "runout", "Control charts", "Detection quality"):
        assert text in html, text
    # a group name is text, not markup (autoescape)
    assert "station=&lt;b&gt;B&amp;2&lt;/b&gt;" in html and "<b>B&2</b>" not in html
    # the scan's manifest is summarised
    assert "curves.parquet" in html


def test_report_without_curves_says_how_to_get_them(tmp_path: Path) -> None:
    curves, _ = tightscan.simulate(12, seed=2)
    results = tightscan.detect_batch(curves)
    from tightscan.report import write_report

    html = write_report(results, tmp_path / "r.html", worst=3).read_text()
    assert "Give the curves (<code>--curves</code>)" in html
    assert len(re.findall(r"<img ", html)) == 1  # the control chart only


def test_report_cli_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["report", str(tmp_path / "missing.parquet"), "-o", str(tmp_path / "r.html")]) == 3
    assert "missing.parquet" in capsys.readouterr().err
    bad = tmp_path / "diag.json"
    bad.write_text("[1, 2")
    curves, _ = tightscan.simulate(5, seed=1)
    pq.write_table(tightscan.detect_batch(curves), tmp_path / "res.parquet")
    assert main(["report", str(tmp_path / "res.parquet"), "--diagnose", str(bad), "-o", str(tmp_path / "r.html")]) == 3
    assert "diag.json" in capsys.readouterr().err
    assert main(["report", str(tmp_path / "res.parquet"), "--by", "station", "-o", str(tmp_path / "r.html")]) == 3
    assert "'station'" in capsys.readouterr().err
    assert not (tmp_path / "r.html").exists()


def _chromium() -> str:
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("no chromium on this machine (make browser installs Debian's; apt-get was not available here)")


CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--hide-scrollbars",
                  "--enable-logging=stderr", "--v=0", "--virtual-time-budget=10000"]
PROBE = """<script>
window.addEventListener("load", () => {
  const images = [...document.images].map(i => ({complete: i.complete, width: i.naturalWidth, height: i.naturalHeight}));
  const probe = document.createElement("pre"); probe.id = "probe"; probe.textContent = JSON.stringify(images);
  document.body.appendChild(probe);
});
</script>"""


def _run(args: list[str], tmp: Path) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, HOME=str(tmp))  # a fresh profile: nothing of the user's leaks in
    return subprocess.run(args, capture_output=True, text=True, timeout=180, env=env, cwd=tmp)


def test_report_renders_in_a_headless_browser(report: Path, tmp_path: Path) -> None:
    chromium = _chromium()
    shot = tmp_path / "report.png"
    width, height = 1280, 3000
    run = _run([chromium, *CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}",
                f"--window-size={width},{height}", report.as_uri()], tmp_path)
    assert shot.exists(), run.stderr[-2000:]
    console = [line for line in run.stderr.splitlines() if ":CONSOLE" in line or "Uncaught" in line]
    assert not console, console

    from PIL import Image

    with Image.open(shot) as image:
        assert image.size == (width, height)
        pixels = np.asarray(image.convert("RGB"), dtype=np.int16)
    not_white = np.any(pixels < 235, axis=2)
    assert not_white.mean() > 0.03, "the screenshot is (nearly) blank"
    assert np.any(np.abs(pixels[..., 0] - pixels[..., 2]) > 60), "no coloured pixels: figures did not draw"
    rows_with_ink = np.flatnonzero(not_white.any(axis=1))
    assert rows_with_ink.max() > height * 0.9, "the page stops early: figures missing?"

    probed = tmp_path / "probed.html"
    probed.write_text(report.read_text().replace("</body>", PROBE + "</body>"))
    dom = _run([chromium, *CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'profile2'}", "--dump-dom", probed.as_uri()], tmp_path)
    found = re.search(r'<pre id="probe">(.*?)</pre>', dom.stdout, re.S)
    assert found, dom.stderr[-2000:]
    images = json.loads(found.group(1).replace("&quot;", '"'))
    assert len(images) == 7
    assert all(i["complete"] and i["width"] > 100 and i["height"] > 100 for i in images), images


def test_diagnosis_object_gives_its_figures(tmp_path: Path) -> None:
    """A Diagnosis (not its JSON) carries the samples: residual before and after, the evidence
    (residual against each effect's signal) and the spectrum are drawn, here and in the report."""
    from tightscan import plot
    from tightscan.report import write_report

    curves, _ = tightscan.simulate(80, seed=5, fault_fraction=0.0, strategies=["CSDT", "HDT"], torque_lowpass_ms=5.0)
    diagnosis = tightscan.diagnose(curves.drop_columns(["strategy", "thread"]))
    assert [e.name for e in diagnosis.effects] == ["channel_delay"]
    before = plot.plot_diagnosis_residual(diagnosis, "before")
    assert any(line.get_gid() == "mean_residual" for ax in before.axes for line in ax.get_lines())
    evidence = plot.plot_diagnosis_evidence(diagnosis)
    assert "channel_delay" in [ax.get_title().split(" ")[0] for ax in evidence.axes]
    assert any(line.get_gid() == "partial_residual" for ax in evidence.axes for line in ax.get_lines())
    with pytest.raises(tightscan.InvalidParameterError, match="which"):
        plot.plot_diagnosis_residual(diagnosis, "during")
    html = write_report(tightscan.detect_batch(curves), tmp_path / "r.html", diagnosis=diagnosis, worst=0).read_text()
    captions = re.findall(r'alt="diagnosis: ([^"]*)"', html)
    assert captions == ["residual before the effects found", "residual after the effects found",
                        "evidence: residual against each effect&#39;s signal", "residual spectrum with its peaks"]
    assert "channel_delay" in html
