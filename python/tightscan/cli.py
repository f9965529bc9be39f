"""Command line: `tightscan scan | simulate | demo | import rexroth | diagnose | config | report`.

Exit codes: 0 done; 1 changes found, with `scan --fail-on-change`; 2 usage (bad arguments or
parameter values); 3 data (a file or column that breaks the data contract, files that failed to
import). Errors are one line on stderr naming the file or column, never a traceback.

Output: `--json` (scan, simulate, import, diagnose) prints one JSON object on stdout and nothing
else there; what is printed for people then goes to stderr. `--quiet` prints errors only (the
JSON still, when asked). Progress bars draw on stderr on a terminal (`--no-progress`, `--quiet`
or TIGHTSCAN_PROGRESS=0 turn them off, TIGHTSCAN_PROGRESS=1 forces them on).
"""

from __future__ import annotations

import argparse
import ctypes
import dataclasses
import json
import math
import re
import sys
import time
import warnings
from pathlib import Path
from typing import Any, Sequence, TextIO

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from ._api import simulate
from ._progress import Progress
from ._core import __version__
from ._scan import ScanSummary, read_results, scan_parquet
from .config import (
    CusumConfig,
    DecisionConfig,
    DetectConfig,
    config_from_toml,
    config_to_toml,
)
from .exceptions import DataFileError, InvalidParameterError, SchemaError, TightscanError
from .rexroth import DuplicateRunWarning, import_summary, rexroth_files, write_rexroth

EXIT_OK = 0
EXIT_CHANGES = 1
EXIT_USAGE = 2
EXIT_DATA = 3

# Tightenings per Parquet row group, and in memory at once: ~25 MB of float32 channels, so that
# `simulate -o` stays far below 500 MB and a scan's reader holds little of a row group.
SIMULATE_CHUNK = 1_000
SIMULATE_STEP = 1_000  # tightenings per simulator call: what the progress bar counts
# Switchable effects of the simulator (`--effect NAME=VALUE`), with their units; 0 is off.
EFFECTS = {
    "speed_friction": "a in mu (1 + a ln(v / 30 rpm)), |a| <= 0.25",
    "torque_lowpass_ms": "low-pass time constant of the torque channel [ms]",
    "inertia": "rotational inertia J [kg m^2], adds J * angular acceleration to the torque",
    "pressure_friction": "c in mu (1 + c (F / F_target - 1)), |c| < 1",
    "prevailing_torque_nm": "prevailing torque of a locking element [Nm]",
    "runout": "once-per-revolution run-out amplitude r, torque * (1 + r sin(angle + phase))",
}


def _config(args: argparse.Namespace) -> DetectConfig:
    """The defaults, then `--config FILE.toml`, then the detector flags given on the command line
    (their argparse default is None: "not given")."""
    config = config_from_toml(args.config) if args.config else DetectConfig()
    cusum: dict[str, Any] = {}
    if args.kappa is not None:
        cusum["kappa"] = args.kappa
    if args.arl0 is not None:
        cusum["arl0"] = args.arl0
        cusum["threshold"] = None  # an explicit --arl0 wins over a file's threshold
    if args.threshold is not None:
        cusum["threshold"] = args.threshold
    decision: dict[str, Any] = {}
    if args.alpha is not None:
        decision["alpha"] = args.alpha
    if args.rule is not None:
        decision["rule"] = args.rule
    if args.detectors:
        decision["detectors"] = tuple(args.detectors)
    return dataclasses.replace(
        config,
        cusum=dataclasses.replace(config.cusum, **cusum),
        decision=dataclasses.replace(config.decision, **decision),
        residual_tests=dataclasses.replace(config.residual_tests, kde=True) if args.kde else config.residual_tests,
        pf=dataclasses.replace(config.pf, enabled=True) if args.pf else config.pf,
    )


def _add_output_options(p: argparse.ArgumentParser, json_flag: bool = True) -> None:
    if json_flag:
        p.add_argument("--json", action="store_true", help="print a JSON summary on stdout (nothing else there)")
    p.add_argument("-q", "--quiet", action="store_true", help="print errors only (and the --json summary when asked)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _json_on_stdout(args: argparse.Namespace) -> bool:
    return args.json is True or args.json == "-"


def _info(args: argparse.Namespace) -> TextIO | None:
    """Where text for people goes: stdout; stderr when stdout carries the JSON; nowhere with --quiet."""
    if args.quiet:
        return None
    return sys.stderr if _json_on_stdout(args) else sys.stdout


def _say(args: argparse.Namespace, text: str) -> None:
    stream = _info(args)
    if stream is not None:
        print(text, file=stream)


def _progress(args: argparse.Namespace) -> bool | None:
    """False when switched off, else None: the bar shows on a terminal (or TIGHTSCAN_PROGRESS=1)."""
    return False if args.no_progress or args.quiet else None


def _jsonable(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


def _print_json(document: dict[str, Any]) -> None:
    print(json.dumps(_jsonable(document), indent=2, allow_nan=False))


def _add_detect_options(p: argparse.ArgumentParser) -> None:
    d = CusumConfig()
    decision = DecisionConfig()
    p.add_argument(
        "--config",
        default=None,
        metavar="FILE.toml",
        help="detector parameters from a TOML file (`tightscan config --show` prints them all); flags given here override it",
    )
    p.add_argument(
        "--alpha",
        type=float,
        default=None,
        help=f"false-alarm probability per tightening of change_detected (default {decision.alpha})",
    )
    p.add_argument("--rule", default=None, help=f"'any' or 'K-of-n' (default {decision.rule})")
    p.add_argument(
        "--detectors",
        nargs="+",
        default=None,
        metavar="NAME",
        help=f"detectors of the rule: break, l1, cusum, kde, pf (default {' '.join(decision.detectors)})",
    )
    p.add_argument("--kde", action="store_true", help="run the kernel-density test (about 1 ms per tightening)")
    p.add_argument("--pf", action="store_true", help="run the particle-filter fault test (opt-in; pf_* columns)")
    p.add_argument("--kappa", type=float, default=None, help=f"CUSUM drift in sigma units (default {d.kappa})")
    p.add_argument(
        "--arl0",
        type=float,
        default=None,
        help="in-control ARL in blocks that sets h (default: from the CUSUM's share of --alpha)",
    )
    p.add_argument("--threshold", type=float, default=None, help="explicit CUSUM threshold h (overrides --arl0)")
    p.add_argument("--passthrough", nargs="*", default=None, metavar="COLUMN", help="input columns to copy into the results")
    p.add_argument("--batch-size", type=int, default=None, help="rows per streamed batch (default: about 16 MB of decoded data each)")


def print_summary(summary: ScanSummary, by_strategy: pa.Table | None = None, file: TextIO | None = None) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console(file=file)
    t = Table(title=f"tightscan: {summary.destination}", show_header=False)
    t.add_row("files", f"{summary.files}")
    t.add_row("tightenings", f"{summary.tightenings:,}")
    t.add_row("samples", f"{summary.samples:,}")
    t.add_row("changes found", f"{summary.changes:,}")
    for code, count in sorted(summary.status_counts.items()):
        t.add_row(f"status {code}", f"{count:,}")
    rate = summary.samples / summary.seconds / 1e6 if summary.seconds > 0 else float("nan")
    t.add_row("time", f"{summary.seconds:.2f} s ({rate:.1f} M samples/s incl. Parquet I/O)")
    console.print(t)
    if by_strategy is not None:
        s = Table(title="by strategy")
        for name in by_strategy.column_names:
            s.add_column(name, justify="right")
        for row in by_strategy.to_pylist():
            s.add_row(*(f"{v:.3f}" if isinstance(v, float) else str(v) for v in row.values()))
        console.print(s)


def _strategy_table(results: pa.Table, truth: pa.Table | None) -> pa.Table | None:
    if "strategy" not in results.column_names:
        return None
    t = results.select(["tightening_id", "strategy", "change_detected"])
    t = t.set_column(2, "change_detected", pc.fill_null(t.column("change_detected"), False))
    if truth is None:
        g = t.group_by("strategy").aggregate([("tightening_id", "count"), ("change_detected", "sum")])
        return g.rename_columns(["strategy", "tightenings", "changes_found"])
    joined = t.join(truth.select(["tightening_id", "has_change"]), "tightening_id")
    rows = []
    for strategy in sorted(set(joined.column("strategy").to_pylist())):
        sub = joined.filter(pc.equal(joined.column("strategy"), strategy))
        found = sub.column("change_detected").to_numpy(zero_copy_only=False)
        real = sub.column("has_change").to_numpy(zero_copy_only=False)
        rows.append(
            {
                "strategy": strategy,
                "tightenings": len(found),
                "changes_found": int(found.sum()),
                "true_changes": int(real.sum()),
                "recall": float(found[real].mean()) if real.any() else float("nan"),
                "false_alarm_rate": float(found[~real].mean()) if (~real).any() else float("nan"),
            }
        )
    return pa.Table.from_pylist(rows)


_FILTER_TERM = re.compile(r"^\s*([A-Za-z_][\w.]*)\s*(==|!=|>=|<=|=|>|<|\s+in\s+)\s*(.*?)\s*$")


def _filter_value(text: str) -> object:
    """``'B'`` or ``"B"`` a string; ``12`` an integer, ``1.5`` a float; anything else as written."""
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"":
        return text[1:-1]
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def parse_filter(terms: Sequence[str]) -> pc.Expression:
    """``--filter`` terms, all of which must hold, as a pyarrow expression pushed to the reader.

    A term is ``COLUMN OP VALUE`` with OP one of ``= == != < <= > >=``, or ``COLUMN in A,B,C``;
    a value is a number, or text (quote it to keep digits text: ``plant='7'``).

    >>> parse_filter(["station=2", "plant in A,B"]).equals((pc.field("station") == 2) & pc.field("plant").isin(["A", "B"]))
    True
    """
    expression: pc.Expression | None = None
    for term in terms:
        m = _FILTER_TERM.match(term)
        if m is None or not m.group(3):
            raise ValueError(f"--filter {term!r}: expected COLUMN OP VALUE (OP: = != < <= > >= in), e.g. station=7")
        column, op, value = m.group(1), m.group(2).strip(), m.group(3)
        f = pc.field(column)
        if op == "in":
            e = f.isin([_filter_value(v.strip()) for v in value.split(",")])
        else:
            v = _filter_value(value)
            e = {"=": f == v, "==": f == v, "!=": f != v, "<": f < v, "<=": f <= v, ">": f > v, ">=": f >= v}[op]
        expression = e if expression is None else expression & e
    assert expression is not None
    return expression


def _fixed_mmap_threshold() -> None:
    """Keeps big buffers (a chunk of curves, tens of MB) mmapped, so that freeing one gives it
    back to the OS. glibc raises its mmap threshold to the size of each big buffer freed (up
    to 32 MB), after which such buffers come from the heap, which keeps them: the RSS of a
    long `simulate` or `scan` then creeps up with the data (261 -> 432 MB from 20 k to 1 M
    tightenings). Set for this command's process only; a no-op without glibc."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, 1 << 20)  # M_MMAP_THRESHOLD (malloc.h): fixed at 1 MB
    except (OSError, AttributeError):
        pass


def cmd_scan(args: argparse.Namespace) -> int:
    _fixed_mmap_threshold()
    passthrough: Sequence[str] | bool | None = args.passthrough
    try:
        row_filter = parse_filter(args.filter) if args.filter else None
    except ValueError as e:
        raise InvalidParameterError(str(e), "filter") from None
    summary = scan_parquet(
        args.inputs,
        args.output,
        _config(args),
        columns=args.columns,
        filter=row_filter,
        passthrough=passthrough,
        batch_size=args.batch_size,
        progress=_progress(args),
        engine=args.engine,
        partition_by=args.partition_by,
        on_bad_file=args.on_bad_file,
        resume=args.resume,
    )
    try:
        results = read_results(args.output, columns=["tightening_id", "strategy", "change_detected"])
    except TightscanError:
        results = None  # no strategy column passed through: no table by strategy
    by_strategy = _strategy_table(results, None) if results is not None else None
    code = EXIT_CHANGES if args.fail_on_change and summary.changes else EXIT_OK
    info = _info(args)
    if info is not None:
        print_summary(summary, by_strategy, file=info)
        if summary.resumed_files:
            print(f"{summary.resumed_files:,} input files were complete already (--resume) and not read again", file=info)
        for path, reason in summary.skipped_files:
            print(f"skipped {path}: {reason}", file=info)
    if args.json:
        _print_json(
            {
                "command": "scan",
                "version": __version__,
                **summary.to_dict(),
                "by_strategy": by_strategy.to_pylist() if by_strategy is not None else None,
                "exit_code": code,
                "config": dataclasses.asdict(_config(args)),
            }
        )
    return code


def write_simulation(
    n: int,
    seed: int,
    output: str,
    truth_output: str | None,
    progress: bool | None = False,
    chunk: int = SIMULATE_CHUNK,
    step: int = SIMULATE_STEP,
    **kwargs: object,
) -> dict[str, int]:
    """Simulates in chunks so that memory stays bounded for millions of tightenings; returns
    the counts of what it wrote (``tightenings``, ``samples``, ``with_change``).

    Each chunk of ``chunk`` tightenings is one Parquet row group, generated ``step`` at a time
    so that the progress bar moves. The data do not depend on either: the simulator seeds
    tightening i from (seed, first_id + i) alone, so any split gives the rows of one call.
    """
    writer = truth_writer = None
    counts = {"tightenings": 0, "samples": 0, "with_change": 0}
    bar = Progress("simulating", n, progress, unit="tightenings")
    try:
        for first in range(0, n, chunk):
            count = min(chunk, n - first)
            parts = []
            for part_first in range(first, first + count, step):
                part = simulate(min(step, first + count - part_first), seed=seed, first_id=part_first, **kwargs)  # type: ignore[arg-type]
                parts.append(part)
                bar.advance(part[0].num_rows)
            curves = parts[0][0] if len(parts) == 1 else pa.concat_tables([c for c, _ in parts])
            truth = parts[0][1] if len(parts) == 1 else pa.concat_tables([t for _, t in parts])
            del parts  # the chunk's only copy is `curves`: freed once written
            if writer is None:
                writer = pq.ParquetWriter(output, curves.schema)
                if truth_output:
                    truth_writer = pq.ParquetWriter(truth_output, truth.schema)
            writer.write_table(curves)
            if truth_writer is not None:
                truth_writer.write_table(truth)
            counts["tightenings"] += curves.num_rows
            counts["samples"] += int(pc.sum(pc.list_value_length(curves.column("torque"))).as_py() or 0)
            counts["with_change"] += int(pc.sum(truth.column("has_change")).as_py() or 0)
    finally:
        bar.close()
        if writer is not None:
            writer.close()
        if truth_writer is not None:
            truth_writer.close()
    return counts


def _effect(text: str) -> tuple[str, float]:
    """`NAME=VALUE` of `--effect`."""
    name, sep, value = text.partition("=")
    name = name.strip()
    if not sep or name not in EFFECTS:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE with NAME one of {', '.join(EFFECTS)}, got {text!r}")
    try:
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{name}: {value!r} is not a number") from None


def cmd_simulate(args: argparse.Namespace) -> int:
    _fixed_mmap_threshold()
    truth = args.truth or str(Path(args.output).with_name(Path(args.output).stem + "-truth.parquet"))
    ranges: dict[str, Any] = {
        key: tuple(getattr(args, key))
        for key in ("magnitude_range", "onset_fraction_range", "mu_th_range", "mu_b_range", "joint_stiffness_range")
        if getattr(args, key) is not None
    }
    for path in (args.output, truth):
        Path(path).parent.mkdir(parents=True, exist_ok=True)  # `-o data/day1.parquet` on a fresh tree
    started = time.perf_counter()
    counts = write_simulation(
        args.n,
        args.seed,
        args.output,
        truth,
        progress=_progress(args),
        with_clamp_force=args.clamp_force,
        fault_fraction=args.fault_fraction,
        with_yield=args.with_yield,
        **ranges,
        **dict(args.effect or []),
    )
    seconds = time.perf_counter() - started
    _say(args, f"wrote {args.n:,} tightenings to {args.output} and their ground truth to {truth}")
    if args.json:
        _print_json(
            {
                "command": "simulate",
                "version": __version__,
                "output": args.output,
                "truth": truth,
                "seed": args.seed,
                **counts,
                "seconds": seconds,
            }
        )
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    out = Path(args.dir)
    out.mkdir(parents=True, exist_ok=True)
    curves = out / "tightenings.parquet"
    truth = out / "truth.parquet"
    stamp = out / f".dataset-n{args.n}-seed{args.seed}"
    if not stamp.exists() or not curves.exists() or not truth.exists():
        print(f"simulating the built-in dataset: {args.n:,} tightenings (seed {args.seed}) -> {curves}")
        write_simulation(args.n, args.seed, str(curves), str(truth), progress=False if args.no_progress else None)
        for old in out.glob(".dataset-*"):
            old.unlink()
        stamp.touch()
    results_path = out / "results.parquet"
    summary = scan_parquet(curves, results_path, passthrough=["strategy"], progress=False if args.no_progress else None)
    results = pq.read_table(results_path, columns=["tightening_id", "strategy", "change_detected"])
    print_summary(summary, _strategy_table(results, pq.read_table(truth)))
    print(f"results: {results_path}")
    return 0


def _join_keys(text: str) -> tuple[str, str]:
    """``cycle=run_id`` -> ("cycle", "run_id"); ``cycle`` alone means the same name on both sides."""
    left, sep, right = text.partition("=")
    left, right = left.strip(), right.strip() if sep else left.strip()
    if not left or not right:
        raise argparse.ArgumentTypeError(f"expected TABLE_COLUMN=LABEL_COLUMN, not {text!r}")
    return left, right


def cmd_import_rexroth(args: argparse.Namespace) -> int:
    """Writes every file's row (failed ones with their import_status), then prints what became
    of the files; exits 3 when any file failed, so that a script cannot miss it."""
    files = rexroth_files(args.inputs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DuplicateRunWarning)  # reported in the summary below
        rows = write_rexroth(
            files,
            args.output,
            labels=args.labels,
            on=args.on,
            keep_redundant=args.keep_redundant,
            progress=_progress(args),
            compression=args.compression,
        )
    written = pq.read_table(args.output, columns=["tightening_id", "file_name", "import_status", "duplicate_id"])
    s = import_summary(written, files.skipped)
    detail = f" ({', '.join(f'{c}: {n:,}' for c, n in sorted(s.failure_codes.items()))})" if s.failure_codes else ""
    _say(
        args,
        f"{rows:,} Rexroth runs written to {args.output}: {s.imported:,} imported, {s.failed:,} failed{detail}, "
        f"{s.skipped:,} files skipped (not *.json)",
    )
    for name, status in s.first_failures:
        _say(args, f"  failed: {name}: {status}")
    if args.json:
        _print_json(
            {
                "command": "import rexroth",
                "version": __version__,
                "output": args.output,
                "runs": rows,
                "imported": s.imported,
                "failed": s.failed,
                "skipped": s.skipped,
                "failure_codes": dict(sorted(s.failure_codes.items())),
                "first_failures": [{"file": name, "import_status": status} for name, status in s.first_failures],
                "duplicates": [{"tightening_id": tid, "files": list(names)} for tid, names in s.duplicates.items()],
                "exit_code": EXIT_DATA if s.failed else EXIT_OK,
            }
        )
    if s.duplicates and not args.quiet:
        shown = "; ".join(f"{tid}: {', '.join(names)}" for tid, names in list(s.duplicates.items())[:5])
        more = f"; and {len(s.duplicates) - 5:,} more" if len(s.duplicates) > 5 else ""
        print(f"warning: {len(s.duplicates):,} runs come from more than one file (column duplicate_id): {shown}{more}", file=sys.stderr)
    if s.failed:
        first_name, first_status = s.first_failures[0]
        print(
            f"tightscan: error: {s.failed:,} of {rows:,} files failed to import (first: {first_name}: {first_status}); "
            "their rows are written with null channels and their import_status",
            file=sys.stderr,
        )
        return EXIT_DATA
    return EXIT_OK


def cmd_diagnose(args: argparse.Namespace) -> int:
    from .diagnose import diagnose, load_table, write_report

    table = load_table(args.input, progress=_progress(args))
    if args.limit is not None:
        table = table.slice(0, args.limit)
    group_by: Sequence[str] | str | None = "auto"
    if args.group_by is not None:
        group_by = args.group_by if args.group_by else None
    grouping: Sequence[str] | str | None = "auto"
    if args.grouping_factors is not None:
        grouping = args.grouping_factors if args.grouping_factors else None
    result = diagnose(
        table,
        grouping_factors=grouping,
        folds=args.folds,
        alpha=args.alpha,
        min_gain=args.min_gain,
        max_effects=args.max_effects,
        group_by=group_by,
        seed=args.seed,
        progress=_progress(args),
    )
    if args.json is not None and not _json_on_stdout(args):
        result.to_json(args.json)
    figures = write_report(result, Path(args.report) / "figures") if args.report else []
    info = _info(args)
    if info is not None:
        print_diagnosis(result, file=info)
    written = [args.json] if args.json is not None and not _json_on_stdout(args) else []
    if figures:
        written.append(f"{len(figures)} figures to {Path(args.report) / 'figures'}")
    if written:
        _say(args, "wrote " + " and ".join(written))
    if _json_on_stdout(args):
        print(result.to_json())
    return 0


def print_diagnosis(result: object, file: TextIO | None = None) -> None:
    from rich.console import Console
    from rich.table import Table

    from .diagnose import Diagnosis

    assert isinstance(result, Diagnosis)
    console = Console(file=file)
    t = Table(title=f"tightscan diagnose: {result.details.get('tightenings', 0):,} tightenings", show_header=True)
    for name in ("level", "effect", "significant", "RMSE after", "gain"):
        t.add_column(name)
    t.add_row("1", "declared model", "", f"{result.rmse_before:.4g} Nm", "")
    for e in result.effects:
        gain = e.evidence.get("rmse_gain")
        t.add_row(
            "1" if e.level == "within_tightening" else "2",
            e.name,
            "yes" if e.significant else "no",
            f"{e.rmse_after:.4g} {e.rmse_unit}",
            f"{100 * gain:.1f} %" if isinstance(gain, float) else "",
        )
    console.print(t)
    console.print(f"unexplained structure left: {'yes' if result.unexplained_structure else 'no'}")


def cmd_config(args: argparse.Namespace) -> int:
    print(config_to_toml(config_from_toml(args.config) if args.config else DetectConfig()), end="")
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tightscan",
        description="Find friction changes in bolted-joint tightening curves.",
    )
    parser.add_argument("--version", action="version", version=f"tightscan {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    scan = sub.add_parser("scan", help="detect changes in Parquet files, write results Parquet")
    scan.add_argument("inputs", nargs="+", help="Parquet files, directories, globs or URIs (file://, s3://, gs://, abfs://)")
    scan.add_argument(
        "-o",
        "--output",
        required=True,
        help="results: a *.parquet file, or a directory (any other name) with one results file per input file",
    )
    _add_detect_options(scan)
    scan.add_argument("--columns", nargs="+", default=None, metavar="COLUMN", help="read only these input columns")
    scan.add_argument(
        "--filter",
        action="append",
        default=None,
        metavar="TERM",
        help="read only rows where COLUMN OP VALUE holds (OP: = != < <= > >= in; repeat: all must hold), "
        "e.g. --filter station=7 --filter \"day>=20250101\"; hive partitions not matching are not read",
    )
    scan.add_argument("--partition-by", nargs="+", default=None, metavar="COLUMN", help="hive directories of the results by these columns")
    scan.add_argument(
        "--on-bad-file",
        choices=["raise", "skip"],
        default="raise",
        help="a file that breaks the data contract stops the scan (raise), or is skipped and listed (default %(default)s)",
    )
    scan.add_argument("--resume", action="store_true", help="skip input files whose results are complete in the output directory")
    scan.add_argument(
        "--engine",
        choices=["local", "dask", "ray"],
        default="local",
        help="where files are scanned: this process, the Dask cluster or Ray (default %(default)s)",
    )
    scan.add_argument("--fail-on-change", action="store_true", help="exit with 1 when a change is found (for CI and scripts)")
    _add_output_options(scan)
    scan.set_defaults(func=cmd_scan)

    sim = sub.add_parser("simulate", help="write labelled synthetic tightenings as Parquet")
    sim.add_argument("-n", type=int, required=True, help="number of tightenings")
    sim.add_argument("-o", "--output", required=True, help="tightenings Parquet file")
    sim.add_argument("--truth", default=None, help="ground-truth Parquet file (default: OUTPUT-truth.parquet)")
    sim.add_argument("--seed", type=int, default=0)
    sim.add_argument("--fault-fraction", type=float, default=0.5)
    sim.add_argument("--clamp-force", action="store_true", help="add a clamp_force channel")
    for flag, what in [
        ("--magnitude-range", "|relative change| of mu of a fault (default 0.05 0.30)"),
        ("--onset-fraction-range", "fault onset as a fraction of the elastic zone (default 0.30 0.85)"),
        ("--mu-th-range", "thread friction coefficient (default 0.10 0.20)"),
        ("--mu-b-range", "head (bearing) friction coefficient (default 0.10 0.20)"),
        ("--joint-stiffness-range", "joint stiffness [kN/deg] (default: from the thread size, 20-120 deg elastic angle)"),
    ]:
        sim.add_argument(flag, nargs=2, type=float, metavar=("LO", "HI"), default=None, help=f"{what}; LO = HI fixes it")
    sim.add_argument("--with-yield", action="store_true", help="bolts yield before the target (yield zone)")
    sim.add_argument(
        "--effect",
        action="append",
        type=_effect,
        metavar="NAME=VALUE",
        help="switch an effect on (repeatable): " + "; ".join(f"{k}: {v}" for k, v in EFFECTS.items()),
    )
    _add_output_options(sim)
    sim.set_defaults(func=cmd_simulate)

    demo = sub.add_parser("demo", help="scan the built-in dataset and compare with its ground truth")
    demo.add_argument("-n", type=int, default=20_000, help="tightenings in the built-in dataset (default %(default)s)")
    demo.add_argument("--seed", type=int, default=2026)
    demo.add_argument("--dir", default="out/demo", help="where data and results go (default %(default)s)")
    demo.add_argument("--no-progress", action="store_true")
    demo.set_defaults(func=cmd_demo)

    # `import` takes the tool format as a sub-subcommand, so that other controllers' exports
    # can be added beside `rexroth` without changing what existing commands mean.
    imp = sub.add_parser("import", help="convert tightening-tool exports into the tightening table (Parquet)")
    formats = imp.add_subparsers(dest="format", required=True, metavar="FORMAT")
    rex = formats.add_parser("rexroth", help="Bosch Rexroth JSON exports, one file per run (docs/rexroth-import.md)")
    rex.add_argument(
        "inputs", nargs="+", metavar="DIR_OR_FILES", help="JSON files, directories (every *.json below them, any case) or globs"
    )
    rex.add_argument("-o", "--output", required=True, help="tightening table Parquet file")
    rex.add_argument("--labels", default=None, help="CSV of labels to left-join (one row per run)")
    rex.add_argument(
        "--on",
        type=_join_keys,
        default=("cycle", "run_id"),
        metavar="COLUMN=LABEL_COLUMN",
        help="join key: table column = labels column (default cycle=run_id)",
    )
    rex.add_argument("--keep-redundant", action="store_true", help="also write the torque_red and angle_red channels")
    rex.add_argument("--compression", choices=["zstd", "snappy"], default="zstd", help="Parquet compression (default %(default)s)")
    _add_output_options(rex)
    rex.set_defaults(func=cmd_import_rexroth)

    diag = sub.add_parser(
        "diagnose",
        help="find what the declared tightening model misses, add it, report the error before and after",
        description="Fit the declared model per phase across many tightenings, trace residual structure to "
        "the effects the model lacks, add them, and report the out-of-sample error before and after "
        "(docs/diagnose-s01.md).",
    )
    diag.add_argument("input", metavar="INPUT", help="Rexroth export directory (runs/*.json or *.json), Parquet file or directory")
    diag.add_argument(
        "--json",
        nargs="?",
        const="-",
        default=None,
        metavar="OUT.json",
        help="write the diagnosis (JSON) to OUT.json; without a file name, or '-', print it on stdout "
        "(nothing else there); give INPUT before a bare --json",
    )
    diag.add_argument("--report", default=None, metavar="DIR", help="also write figures to DIR/figures/diagnose-*.png")
    diag.add_argument("--folds", type=int, default=5, help="K of the K-fold split across tightenings (default %(default)s)")
    diag.add_argument("--alpha", type=float, default=0.01, help="family-wise level of each round (default %(default)s)")
    diag.add_argument("--min-gain", type=float, default=0.01, help="smallest relative RMSE reduction of an effect (default %(default)s)")
    diag.add_argument("--max-effects", type=int, default=6, help="level-1 effects at most (default %(default)s)")
    diag.add_argument("--group-by", nargs="*", default=None, metavar="COLUMN", help="columns that group the folds (default: auto; none given: no grouping)")
    diag.add_argument(
        "--grouping-factors",
        nargs="*",
        default=None,
        metavar="COLUMN",
        help="categorical columns tested as level-2 grouping factors (default: auto; none given: none)",
    )
    diag.add_argument("--limit", type=int, default=None, metavar="N", help="only the first N tightenings")
    diag.add_argument("--seed", type=int, default=0, help="seed of the fold assignment")
    _add_output_options(diag, json_flag=False)
    diag.set_defaults(func=cmd_diagnose)

    conf = sub.add_parser(
        "config",
        help="print the detector parameters as TOML (for --config)",
        description="Print every detector parameter as TOML: the defaults, or a --config file's values on top of them "
        "(which checks the file). Save it, edit it, and pass it to `scan --config`.",
    )
    conf.add_argument("--show", action="store_true", required=True, help="print the parameters as TOML")
    conf.add_argument("--config", default=None, metavar="FILE.toml", help="show this file's parameters on top of the defaults")
    conf.set_defaults(func=cmd_config)

    # issue 14: the HTML report (handler cmd_report below)
    rep = sub.add_parser(
        "report",
        help="write one self-contained HTML report of scan results (opens offline)",
        description="Summary, the tightenings with the strongest evidence of a change drawn with their "
        "detectors (needs --curves), control charts per group, diagnose findings: one HTML file with "
        "embedded figures. Needs matplotlib and Jinja2 (pip install 'tightscan[report]').",
    )
    rep.add_argument("results", metavar="RESULTS", help="results Parquet file or directory written by `tightscan scan`")
    rep.add_argument("-o", "--output", required=True, metavar="REPORT.html", help="where the report goes")
    rep.add_argument("--curves", default=None, metavar="CURVES", help="the scanned tightenings (Parquet file or directory): draws the worst ones")
    rep.add_argument("--diagnose", default=None, metavar="DIAG.json", help="a `tightscan diagnose --json` file: its findings and spectrum")
    rep.add_argument("--detection-quality", default=None, metavar="JSON", help="benches/results/detection_quality.json: recall against magnitude")
    rep.add_argument("--by", nargs="+", default=None, metavar="COLUMN", help="group columns of the control charts (default: a station-like pass-through column)")
    rep.add_argument("--order-by", default=None, metavar="COLUMN", help="order of the control charts (default: timestamp, date, cycle or tightening_id)")
    rep.add_argument("--feature", default=None, metavar="COLUMN", help="what the control charts show (default: mu_tot, else torque_rate)")
    rep.add_argument("--worst", type=int, default=6, metavar="N", help="tightenings drawn (default %(default)s)")
    rep.set_defaults(func=cmd_report)
    return parser


def cmd_report(args: argparse.Namespace) -> int:
    """`tightscan report`: tightscan.report.write_report from the command line."""
    from .report import write_report

    if args.worst < 0:
        raise InvalidParameterError(f"--worst must be 0 or more, got {args.worst}", "worst")
    for path in (args.results, args.curves, args.diagnose, args.detection_quality):
        if path is not None and "://" not in path and not Path(path).exists():
            raise DataFileError(f"{path} does not exist", path)
    out = write_report(
        args.results,
        args.output,
        curves=args.curves,
        diagnosis=args.diagnose,
        detection_quality=args.detection_quality,
        by=args.by,
        order_by=args.order_by,
        feature=args.feature,
        worst=args.worst,
    )
    print(f"report written to {out} ({out.stat().st_size / 1e6:.1f} MB)")
    return EXIT_OK


def _one_line(e: BaseException) -> str:
    """The error as one line, naming the file or column when its message does not."""
    text = " ".join(str(e).split())
    where = None
    if isinstance(e, DataFileError):
        where = e.path
    elif isinstance(e, SchemaError):
        where = e.column
    elif isinstance(e, OSError):
        where = e.filename if isinstance(e.filename, str) else None
    if where and where not in text:
        label = "column" if isinstance(e, SchemaError) else "file"
        text = f"{text} ({label} {where!r})"
    return text


def main(argv: Sequence[str] | None = None) -> int:
    """Runs one command; returns the exit code (module docstring). argparse exits with 2 itself."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except InvalidParameterError as e:  # a value given on the command line is out of range
        print(f"tightscan: error: {_one_line(e)}", file=sys.stderr)
        return EXIT_USAGE
    except (TightscanError, OSError, pa.ArrowException) as e:  # DataFileError, SchemaError, unreadable files
        print(f"tightscan: error: {_one_line(e)}", file=sys.stderr)
        return EXIT_DATA
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
