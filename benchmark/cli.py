"""`benchmark`: evaluate a model or a predictions file, train baselines, reproduce the paper.

`evaluate` never imports torch (unless the model does); the other commands import their
modules only when chosen.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

from basic_shapes.infra import ArgumentParser, add_debug_flag, add_quiet_flag, cli_boundary, number

EPILOG = """examples:
  benchmark evaluate --data data/bs --predictions preds.h5 --out results.json
  benchmark evaluate --data data/bs --model benchmark.scoring.protocol:MeanResponseModel \\
      --model-arg data_dir=data/bs --out results.json --write-predictions preds.h5
  benchmark evaluate --data data/bs --model my_model.py:MyModel --out results.json
  benchmark train --help
  benchmark reproduce --preset tiny --out out/tiny
  benchmark report --preset tiny --data out/tiny/data --out out/tiny
  benchmark dataset --list
  benchmark dataset cpu-v3 --data data/cpu-v3
  benchmark dataset cpu-v3 --data heldout/cpu-v3 --secret-seed-file ~/secret
  benchmark export-onnx out/tiny/checkpoints/graph-basic/seed-0 --out graph-basic.onnx
  benchmark weights --out out/tiny --pack tiny-weights.tar
  benchmark weights --out rescore --from URL --manifest docs/results/cpu-v2/weights.json"""

DELEGATED = {
    "train": (
        "benchmark.training.train_cli",
        "train a baseline (Basic, Ideal, pretrain + fine-tune)",
    ),
    "reproduce": (
        "benchmark.reproduction.reproduce",
        "run a preset (tiny|small|cpu|paper) and write the paper's table",
    ),
    "report": (
        "benchmark.reproduction.report_cli",
        "rebuild a reproduce folder's table from its per-seed results and the dataset",
    ),
    "dataset": (
        "benchmark.scoring.versions",
        "build a named dataset version (generate + label) and check its fingerprints",
    ),
    "weights": (
        "benchmark.reproduction.weights",
        "pack a reproduce folder's trained weights as a release archive, or fetch and verify one",
    ),
    "export-onnx": (
        "benchmark.training.onnx_export",
        "export checkpoints to the board's ONNX model contract, checked against PyTorch",
    ),
}


def _key_value(text: str) -> tuple[str, str]:
    key, sep, value = text.partition("=")
    if not sep or not key.isidentifier():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    return key, value


def _delegate(command: str):
    module = DELEGATED[command][0]
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise SystemExit(f"benchmark {command}: {module} is unavailable ({exc})") from None


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser; the arguments of a delegated subcommand are added only if it is ``command``."""
    p = ArgumentParser(
        prog="benchmark",
        description=__doc__,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_debug_flag(p)
    sub = p.add_subparsers(dest="command", required=True)
    e = sub.add_parser(
        "evaluate",
        help="score a model or a predictions file on the test split -> results JSON",
        description="Score a model (run over every test mesh, timed) or a predictions file "
        "(scored without running anyone's code) on the test split; both give identical "
        "metrics. See docs/BENCHMARK.md for the protocol and the file layouts.",
    )
    e.add_argument("--data", required=True, help="labelled dataset directory (shards)")
    src = e.add_mutually_exclusive_group(required=True)
    src.add_argument(
        "--model",
        metavar="SPEC",
        help="module:Class or path/to/file.py:Class "
        "(runs its code; prefer --predictions for untrusted submissions)",
    )
    src.add_argument("--predictions", metavar="FILE", help="predictions HDF5 file to score")
    e.add_argument("--out", required=True, help="results JSON to write")
    e.add_argument(
        "--write-predictions", metavar="FILE", help="with --model: keep its predictions file"
    )
    e.add_argument(
        "--model-arg",
        metavar="KEY=VALUE",
        type=_key_value,
        action="append",
        default=[],
        help="constructor argument for --model, as a string (repeatable)",
    )
    e.add_argument(
        "--batch-size",
        type=number(int, minimum=1, maximum=1 << 16),
        default=16,
        help="meshes per predict call (default: %(default)s)",
    )
    e.add_argument(
        "--name",
        help="model name for the results (default: the model's `name` "
        "attribute, its class name, or the predictions file's stem)",
    )
    e.add_argument(
        "--params",
        type=number(int, minimum=0, maximum=10**12),
        help="parameter count (default: the model's `params`)",
    )
    e.add_argument(
        "--embedding", help="face embedding, e.g. direct|graph|token (default: the model's)"
    )
    e.add_argument("--regime", help="training regime, e.g. basic|ideal|classification|autoencoder")
    e.add_argument(
        "--train-seed",
        type=number(int, minimum=0, maximum=2**64 - 1),
        help="seed the model was trained with",
    )
    e.add_argument(
        "--speed-ms",
        type=number(float, minimum=0, maximum=1e9),
        metavar="X",
        help="with --predictions: your own ms per mesh, recorded as self-reported "
        "(the harness times only --model)",
    )
    add_quiet_flag(e)
    for name, (_, help_text) in DELEGATED.items():
        d = sub.add_parser(name, help=help_text, description=help_text)
        if name == command:
            _delegate(name).add_arguments(d)
    return p


def evaluate_command(args: argparse.Namespace) -> int:
    from basic_shapes.infra import one_line, separate_outputs
    from basic_shapes.shards import ShardError
    from benchmark.scoring.evaluate import evaluate, format_metrics
    from benchmark.scoring.protocol import (
        ModelError,
        PredictionsError,
        ResultsError,
        load_model,
        write_results,
    )

    if args.write_predictions and not args.model:
        raise SystemExit("benchmark evaluate: error: --write-predictions needs --model")
    if args.speed_ms is not None and not args.predictions:
        raise SystemExit(
            "benchmark evaluate: error: --speed-ms goes with --predictions "
            "(a --model is timed by the harness)"
        )
    model_file = args.model.rpartition(":")[0] if args.model and ":" in args.model else None
    separate_outputs(
        {"--out": args.out, "--write-predictions": args.write_predictions},
        {
            "--data": args.data,
            "--predictions": args.predictions,
            "--model": model_file if model_file and Path(model_file).exists() else None,
        },
    )
    out = Path(args.out)
    overrides = {
        "name": args.name,
        "params": args.params,
        "embedding": args.embedding,
        "regime": args.regime,
    }
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        model = load_model(args.model, dict(args.model_arg)) if args.model else None
        results = evaluate(
            args.data,
            model=model,
            predictions=args.predictions,
            write_predictions=args.write_predictions,
            overrides=overrides,
            train_seed=args.train_seed,
            batch_size=args.batch_size,
            progress=not args.quiet,
            scratch_dir=out.parent,
            speed_ms=args.speed_ms,
        )
        write_results(out, results)
    except (ShardError, ModelError, PredictionsError, ResultsError, OSError) as exc:
        raise SystemExit(f"benchmark evaluate: error: {one_line(exc)}") from None
    print(format_metrics(results))
    print(f"results written to {out}")
    return 0


def parser_for(argv: list[str]) -> argparse.ArgumentParser:
    """The parser ``argv`` is read with (the docs' commands are checked against it)."""
    return build_parser(next((a for a in argv if not a.startswith("-")), None))


def _main(argv: list[str]) -> int:
    args = parser_for(argv).parse_args(argv)
    if args.command == "evaluate":
        return evaluate_command(args)
    return _delegate(args.command).run(args) or 0


def main(argv: list[str] | None = None) -> int:
    """Console entry point, behind the shared error boundary (docs/CLI.md)."""
    return cli_boundary("benchmark", _main, argv)


if __name__ == "__main__":
    sys.exit(main())
