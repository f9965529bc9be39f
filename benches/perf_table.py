#!/usr/bin/env python3
"""Issue 15's figures in one table, each beside its goal, from what the benches wrote:

- ``target/criterion/**/new/{benchmark,estimates}.json``: the Rust kernels (criterion's mean,
  as elements/s of the bench's own throughput unit; ``stages/*`` and ``cusum/*`` run on one
  thread, so those are per core);
- ``benches/results/bench_cusum.json`` (``benches/bench_cusum.py``): ``detect_batch`` on all
  cores and on one, against the numpy reference of the default rule (with the agreement of
  their decisions) and against ruptures Binseg ``linear``;
- ``benches/results/plant-<n>.json`` (``benches/plant.py``): ``tightscan simulate`` and
  ``tightscan scan`` end to end, their peak RSS, and the scan against pyarrow reading the
  same file.

Prints the table and, with ``--readme README.md``, replaces the README's table between the
``<!-- perf-table:begin -->`` and ``<!-- perf-table:end -->`` markers: the README's figures are
this script's output, never typed by hand. A missing source is a row saying how to make it.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
BEGIN, END = "<!-- perf-table:begin -->", "<!-- perf-table:end -->"

GOAL_DETECT = 100e6  # samples/s, default rule, 2 cores
GOAL_NUMPY = 10.0
GOAL_BINSEG = 100.0
GOAL_SCAN_OVER_READ = 1.25
GOAL_RSS_MB = 500.0


def criterion_rows(root: Path) -> list[tuple[str, str, str, str]]:
    """One row per criterion bench: its mean time and throughput."""
    rows = []
    for bench in sorted(root.glob("**/new/benchmark.json")):
        try:
            meta = json.loads(bench.read_text())
            est = json.loads((bench.parent / "estimates.json").read_text())
        except (OSError, ValueError):
            continue
        seconds = est["mean"]["point_estimate"] * 1e-9
        throughput = meta.get("throughput") or {}
        name = meta.get("full_id") or str(bench.parent.parent.relative_to(root))
        # criterion's Throughput, serde's external tagging: {"Elements": n}, {"Bytes": n},
        # {"BytesDecimal": n}, {"ElementsAndBytes": {"elements": n, "bytes": m}}
        both = throughput.get("ElementsAndBytes")
        elements = throughput.get("Elements") or (both or {}).get("elements")
        nbytes = throughput.get("Bytes") or throughput.get("BytesDecimal") or (both or {}).get("bytes")
        unit = "samples" if "detect" in name or "stages" in name else "elements"
        if elements:
            rate = f"{elements / seconds / 1e6:,.2f} M {unit}/s"
            if nbytes:
                rate += f" ({nbytes / seconds / 1e6:,.0f} MB/s)"
        elif nbytes:
            rate = f"{nbytes / seconds / 1e6:,.1f} MB/s"
        else:
            rate = f"{seconds * 1e3:,.2f} ms"
        per_core = "1 thread" if name.startswith(("stages/", "cusum/")) or "1_thread" in name else "all cores"
        rows.append((f"kernel `{name}` ({per_core})", "-", rate, ""))
    return rows


def _met(ok: bool | None) -> str:
    return "" if ok is None else ("met" if ok else "**missed**")


def table(criterion: Path, results: Path) -> tuple[list[tuple[str, str, str, str]], list[str]]:
    rows: list[tuple[str, str, str, str]] = []
    notes: list[str] = []
    crit = criterion_rows(criterion) if criterion.exists() else []
    if not crit:
        rows.append(("Rust kernels (criterion)", "per core, each stage", "not measured: `cargo bench -p tightscan-benches`", ""))
    rows.extend(crit)

    bench_path = results / "bench_cusum.json"
    if bench_path.exists():
        b = json.loads(bench_path.read_text())
        n, samples = b["n_tightenings"], b["samples"]
        rows.append((f"`detect_batch`, default rule, {b['cpus']} cores", ">= 100 M samples/s", f"{b['rust_samples_per_s'] / 1e6:.2f} M samples/s", _met(b["rust_samples_per_s"] >= GOAL_DETECT)))
        if b.get("rust_1_thread_samples_per_s"):
            rows.append(("`detect_batch`, default rule, 1 thread", "-", f"{b['rust_1_thread_samples_per_s'] / 1e6:.2f} M samples/s", ""))
        agreement = b.get("agreement", {})
        same = agreement.get("change_detected_agreement")
        rows.append((
            "x numpy reference of the default rule",
            ">= 10x",
            f"{b['speedup_rust_over_numpy']:.2f}x (decisions identical on {same:.1%})" if same is not None else f"{b['speedup_rust_over_numpy']:.2f}x",
            _met(b["speedup_rust_over_numpy"] >= GOAL_NUMPY),
        ))
        ratio = b.get("speedup_rust_over_binseg")
        rows.append(("x ruptures Binseg `linear`", ">= 100x", f"{ratio:.0f}x" if ratio else "not measured", _met(ratio >= GOAL_BINSEG) if ratio else ""))
        busy = b.get("cpu_busy_before")
        notes.append(
            f"`bench_cusum.py`: {n:,} tightenings ({samples:,} samples), {b['timestamp']}"
            + (f", CPUs {busy:.0%} busy with other work before the run" if busy is not None else "")
        )
    else:
        rows.append(("`detect_batch`, x numpy, x Binseg", "", "not measured: `python benches/bench_cusum.py`", ""))

    plants = sorted(results.glob("plant-*.json"), key=lambda p: json.loads(p.read_text())["n"])
    if not plants:
        rows.append(("scan / simulate end to end", "", "not measured: `python benches/plant.py --n 20000`", ""))
    for path in plants:
        f = json.loads(path.read_text())
        n = f["n"]
        label = f"{n:,} tightenings ({f['samples'] / 1e6:,.0f} M samples, {f['parquet_bytes'] / 1e9:.1f} GB)"
        scan, sim, read = f["scan"], f["simulate"], f["read"]
        rows.append((f"`tightscan scan`, {label}", "-", f"{scan['seconds']:,.0f} s, {scan['samples_per_s'] / 1e6:.2f} M samples/s", ""))
        rows.append((f"scan / pyarrow read, {n:,}", "<= 1.25x", f"{f['scan_over_read']:.1f}x (read {read['seconds']:,.0f} s; scan CPU {scan['cpu_seconds']:,.0f} s)", _met(f["scan_over_read"] <= GOAL_SCAN_OVER_READ)))
        rows.append((f"peak RSS of `tightscan scan`, {n:,}", "< 500 MB", f"{scan['peak_rss_mb']:,.0f} MB", _met(scan["peak_rss_mb"] < GOAL_RSS_MB)))
        rows.append((f"`tightscan simulate -o`, {label}", "-", f"{sim['seconds']:,.0f} s, {sim['samples_per_s'] / 1e6:.2f} M samples/s", ""))
        rows.append((f"peak RSS of `tightscan simulate -o`, {n:,}", "< 500 MB", f"{sim['peak_rss_mb']:,.0f} MB", _met(sim["peak_rss_mb"] < GOAL_RSS_MB)))
        load = f.get("machine", {}).get("load_at_end")
        commit = f", code {f['commit']}" if f.get("commit") else ""
        notes.append(f"`plant.py --n {n}`" + (f": load average {load[0]:.1f} at its end" if load else "") + commit)
    return rows, notes


def render(rows: list[tuple[str, str, str, str]], notes: list[str]) -> str:
    lines = ["| figure | goal | measured | |", "|---|---|---|---|"]
    lines += [f"| {a} | {b} | {c} | {d} |" for a, b, c, d in rows]
    lines.append("")
    lines.append(f"Generated by `benches/perf_table.py` ({time.strftime('%Y-%m-%d')}, {os.cpu_count()} CPUs) from: " + "; ".join(notes) + ".")
    return "\n".join(lines)


def update_readme(readme: Path, text: str) -> None:
    content = readme.read_text()
    if BEGIN not in content or END not in content:
        raise SystemExit(f"{readme} has no {BEGIN} ... {END} markers")
    head, rest = content.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    readme.write_text(f"{head}{BEGIN}\n{text}\n{END}{tail}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    target = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    ap.add_argument("--criterion", type=Path, default=target / "criterion", help="criterion's output directory")
    ap.add_argument("--results", type=Path, default=HERE / "results", help="where the Python benches wrote their JSON")
    ap.add_argument("--readme", type=Path, default=None, help="regenerate this README's table between the markers")
    args = ap.parse_args()
    rows, notes = table(args.criterion, args.results)
    text = render(rows, notes)
    print(text)
    if args.readme is not None:
        update_readme(args.readme, text)
        print(f"\n{args.readme}: performance table regenerated")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
