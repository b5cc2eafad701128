"""How the paper's findings tighten as training seeds are added: each finding's largest paired
95% half-width and the seeds per row it projects for ±3 dB², at 3, 4, ... seeds per row.

    python perf/seed_progress.py RESULTS_DIR --data DATA_DIR [--preset cpu] [--from 3]
        [--out perf/results/seed_progress.json] [--figure PNG]

RESULTS_DIR: a `benchmark reproduce --out` folder (or a committed copy: per-seed results.json
and checkpoint config.json only, e.g. docs/results/hidden-cpu-v3-seeds); DATA_DIR: the dataset
they were scored on. For n seeds it uses seeds 0..n-1 of every row, through the same code as
`benchmark report --seeds 0,..,n-1` (so each line equals that table's findings); past a row's
last consecutive seed the row keeps all it has, so a row given more seeds (the one whose seeds
spread most) shows what its extra seeds bought. Writes JSON (with each row's per-seed Simple and
Complex MSE), prints a table and, with --figure, plots the half-widths against the seeds with
the ±3 dB² line beside each row's per-seed Simple and Complex MSE: a row whose Complex MSE
scatters over the seeds while its Simple MSE does not is the row that keeps a half-width wide.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from basic_shapes.infra import save_png, write_json
from benchmark.reproduction import report
from benchmark.reproduction.presets import PRESETS
from benchmark.scoring.data import BenchmarkData

RESULTS = Path(__file__).parent / "results"
TARGET = 3.0  # dB², the paired half-width issue 21 asks of every Complex MSE comparison


def consecutive(seeds) -> int:
    """The largest n such that ``seeds`` holds 0..n-1."""
    n = 0
    while n in seeds:
        n += 1
    return n


def progress(records: dict, first: int) -> list[dict]:
    """One entry per seed count n (rows with fewer keep all theirs): each row's seeds, each
    finding's verdict counts, largest half-width (every metric) and the largest Complex MSE
    half-width with its projection."""
    have = {row: consecutive(r) for row, r in records.items()}
    out = []
    for n in range(first, max(have.values()) + 1):
        subset = {row: {s: r[s] for s in range(min(n, have[row]))} for row, r in records.items()}
        per_row = {row: len(r) for row, r in subset.items()}
        entry = {"seeds": n, "seeds_per_row": per_row, "findings": []}
        for f in report.findings(report.table_rows(subset)):
            if f["verdict"] is None:  # its rows are not in this folder
                continue
            complex_hw = [c["half_width"] for c in f["comparisons"] if c["metric"] == "complex_mse"]
            entry["findings"].append(
                {
                    "claim": f["claim"],
                    "verdict": f["verdict"],
                    **{k: f[k] for k in ("holds", "reversed", "inconclusive", "of")},
                    "max_half_width": f["max_half_width"],
                    "max_complex_half_width": max(complex_hw),
                    "complex_seeds_for_3": f["complex_seeds_for_3"],
                }
            )
        out.append(entry)
    return out


def per_seed(records: dict) -> dict:
    """Each row's Simple and Complex MSE of its consecutive seeds 0, 1, ..., in seed order
    (rows as in the table)."""
    return {
        row: {
            m: [r[s]["results"]["metrics"][m] for s in range(consecutive(r))]
            for m in ("simple_mse", "complex_mse")
        }
        for row, r in records.items()
    }


def plot(steps: list[dict], spread: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 4.5), width_ratios=(1, 1.1))
    for i, claim in enumerate(f["claim"] for f in steps[0]["findings"]):
        ns = [s["seeds"] for s in steps]
        hw = [s["findings"][i]["max_complex_half_width"] for s in steps]
        ax.plot(ns, hw, marker="o", label=claim.split(" (")[0].replace(" on all three metrics", ""))
    ax.xaxis.set_major_locator(MaxNLocator(integer=True, nbins=16))
    common = min(steps[-1]["seeds_per_row"].values())
    if common < steps[-1]["seeds"]:
        ax.axvline(common, color="0.6", lw=1, ls=":", label=f"every row's seeds end ({common})")
    ax.axhline(TARGET, color="k", ls="--", lw=1, label="±3 dB² asked")
    ax.set_xlabel("training seeds per row (a row with fewer keeps all its own)")
    ax.set_ylabel("largest paired 95% half-width,\nComplex MSE (dB²)")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    ax.set_title("The paper's findings: interval width against seeds")
    for y, values in enumerate(spread.values()):
        for m, colour in (("simple_mse", "0.5"), ("complex_mse", "C3")):
            bx.plot(values[m], [y] * len(values[m]), "|", ms=12, color=colour)
    bx.set_yticks(range(len(spread)), [f"{k} ({len(v['simple_mse'])})" for k, v in spread.items()])
    bx.invert_yaxis()
    bx.set_xlabel("MSE of one training seed (dB²)")
    bx.set_title("Each row's seeds (count): Simple MSE (grey), Complex MSE (red)")
    fig.tight_layout()
    save_png(fig, path)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("results", type=Path, help="a benchmark reproduce --out folder")
    p.add_argument("--data", required=True, help="the dataset the results were scored on")
    p.add_argument("--preset", default="cpu", choices=tuple(PRESETS))
    p.add_argument("--from", dest="first", type=int, default=3, help="fewest seeds (default 3)")
    p.add_argument("--out", type=Path, default=RESULTS / "seed_progress.json")
    p.add_argument("--figure", type=Path, help="PNG of the half-widths against the seeds")
    args = p.parse_args()
    with BenchmarkData(args.data) as data:
        records = report.load_records(args.results, args.preset, list(range(100)), data)
        fingerprints = {"mesh": data.fingerprint, "label": data.label_fingerprint}
    steps = progress(records, args.first)
    if not steps:
        raise SystemExit(f"{args.results}: fewer than {args.first} seeds in every row")
    spread = per_seed(records)
    write_json(
        args.out,
        {
            "results": str(args.results),
            "dataset": fingerprints,
            "rows": sorted(records),
            "steps": steps,
            "per_seed": spread,
        },
    )
    if args.figure:
        plot(steps, spread, args.figure)
    print(f"{'seeds':>5}  finding (largest Complex MSE half-width dB², seeds for ±3, verdict)")
    for s in steps:
        cells = [
            f"{f['max_complex_half_width']:5.2f} {f['complex_seeds_for_3']!s:>3} {f['verdict']}"
            for f in s["findings"]
        ]
        print(f"{s['seeds']:>5}  " + " | ".join(cells))
    print(f"wrote {args.out}" + (f" and {args.figure}" if args.figure else ""))


if __name__ == "__main__":
    main()
