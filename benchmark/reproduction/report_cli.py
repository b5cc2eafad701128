"""``benchmark report``: rebuild table.md, table.json and the plot of a ``benchmark reproduce``
output folder from its per-seed results and the dataset alone.

A long run's results JSONs are small enough to commit (docs/results/); its checkpoints and
predictions are not. This command makes such a table reproducible from what was committed:
the rows from ``results/<row>/seed-<s>/results.json`` (per-object errors included), the
reference rows recomputed from ``--data``, through the same code as ``benchmark reproduce``.
"""

from __future__ import annotations

import argparse
import platform
import sys
from pathlib import Path

from basic_shapes.infra import add_quiet_flag
from benchmark.reproduction import report
from benchmark.reproduction.presets import PRESETS, seeds_of


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--preset",
        choices=tuple(PRESETS),
        required=True,
        help="the preset the results were made with: its seeds, and whether "
        "the table decides the paper's findings (not: "
        + ", ".join(k for k, v in PRESETS.items() if not v.findings)
        + ")",
    )
    parser.add_argument(
        "--data",
        required=True,
        help="the labelled dataset the results were scored on (reference rows)",
    )
    parser.add_argument(
        "--out",
        required=True,
        help="a `benchmark reproduce --out` folder: reads results/<row>/seed-<s>/"
        "results.json (and checkpoints/<row>/seed-<s>/config.json for the "
        "training time, where kept); writes table.md, table.json, "
        "speed_vs_error.png",
    )
    parser.add_argument("--seeds", help="comma-separated training seeds (default: the preset's)")
    add_quiet_flag(parser)


def run(args: argparse.Namespace) -> None:
    """Read and check every result, then write the table; nothing is written on an error."""
    from tqdm import tqdm

    from benchmark.scoring.data import BenchmarkData

    seeds = seeds_of(args.seeds, PRESETS[args.preset])
    out = Path(args.out)
    # Four steps, each one call without a loop to hook into: a bar of steps, named as they run.
    with tqdm(total=4, desc="report", unit="step", disable=args.quiet) as bar:
        bar.set_postfix_str("results")
        with BenchmarkData(args.data) as data:
            records = report.load_records(out, args.preset, seeds, data)
            dataset = report.dataset_info(data, args.data)
            bar.update()
            bar.set_postfix_str("reference models")
            ref_scorers, ref_rows, oracle = report.reference_rows(data)
            bar.update()
        if not args.quiet:
            tqdm.write(
                f"{sum(map(len, records.values()))} (row, seed) results of {len(records)} rows "
                f"in {out / 'results'}",
                file=sys.stdout,
            )
        command = f"benchmark report --preset {args.preset} --data {args.data} --out {args.out}"
        if args.seeds:
            command += f" --seeds {args.seeds}"
        bar.set_postfix_str("table and intervals")
        table = report.build_table(
            args.preset,
            seeds,
            records,
            dataset,
            ref_scorers,
            ref_rows,
            {
                "command": command,
                "hardware": None,
                "python": platform.python_version(),
                "timing": None,
            },
            oracle,
        )
        bar.update()
        bar.set_postfix_str("plots")
        report.write_outputs(out, table)
        bar.update()
    print(report.render_markdown(table))
    print(f"table, JSON and plot in {out}")
