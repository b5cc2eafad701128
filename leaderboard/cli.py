"""`leaderboard`: verify submissions, render the board as a static site, preview it."""

from __future__ import annotations

import sys
from argparse import RawDescriptionHelpFormatter
from pathlib import Path

from basic_shapes.infra import (
    ArgumentParser,
    add_debug_flag,
    add_quiet_flag,
    cli_boundary,
    number,
    separate_outputs,
)
from leaderboard.store import DEFAULT_ENTRIES

EPILOG = """examples:
  leaderboard submit out/results.json --predictions out/predictions.h5 --data data/bs \\
      --entries leaderboard/entries --name "my-model" --link https://example.org/paper
  leaderboard seed --from out/reproduce/results --data out/reproduce/data \\
      --entries leaderboard/entries
  leaderboard evaluate-model model.onnx --data heldout/tiny-v3 --entries leaderboard/entries \\
      --name "my-model" --link https://example.org/paper
  leaderboard simulator --data data/bs --entries leaderboard/entries
  leaderboard render --out site/
  leaderboard serve site/ --port 8000

Entries are JSON files in the entries folder (default: the repository's leaderboard/entries/);
publish a new one by pull request (docs/SUBMITTING.md)."""


def build_parser() -> ArgumentParser:
    p = ArgumentParser(
        prog="leaderboard",
        description=__doc__,
        epilog=EPILOG,
        formatter_class=RawDescriptionHelpFormatter,
    )
    add_debug_flag(p)
    sub = p.add_subparsers(dest="command", required=True)
    entries = {
        "default": DEFAULT_ENTRIES,
        "type": Path,
        "help": "entries folder (default: %(default)s)",
    }
    # Writing commands never default to the repository's own board: the folder is named.
    new_entries = {
        "required": True,
        "type": Path,
        "help": f"entries folder to write into (the published board: {DEFAULT_ENTRIES})",
    }
    unregistered = {
        "action": "store_true",
        "help": "accept a dataset that is not a registered version (benchmark "
        "dataset --list): a private board; the entry says so",
    }

    s = sub.add_parser(
        "submit",
        help="re-score a results JSON + predictions file and add an entry",
        description="Score the predictions file again against the dataset (nothing "
        "submitted is executed), refuse the results if any number differs from the "
        "re-score, if a fingerprint belongs to another dataset or if a file is "
        "malformed; otherwise write one entry file atomically. No model is run, so "
        "the entry's speed and parameter count are recorded as self-reported.",
    )
    s.add_argument("results", type=Path, help="results JSON written by `benchmark evaluate`")
    s.add_argument("--predictions", type=Path, required=True, help="predictions HDF5 file")
    s.add_argument("--data", type=Path, required=True, help="the labelled dataset directory")
    s.add_argument("--entries", **new_entries)
    s.add_argument("--unregistered", **unregistered)
    s.add_argument("--name", help="name on the board (default: the results' model.name)")
    s.add_argument("--link", help="http(s) URL of a paper or code for this entry")

    d = sub.add_parser(
        "seed",
        help="submit every <row>/results.json + predictions.h5 of a directory",
        description="Submit each row that `benchmark reproduce` wrote "
        "(OUT/results/<row>/results.json beside OUT/results/<row>/predictions.h5, "
        "where OUT is reproduce's --out). Rows already on "
        "the board are skipped; every refusal is listed, then the exit is non-zero. For your "
        "own reproduce runs only: the speeds and parameter counts the harness measured there "
        "are kept as measured.",
    )
    d.add_argument(
        "--from",
        dest="from_dir",
        type=Path,
        required=True,
        metavar="OUT/results",
        help="the results/ folder inside `benchmark reproduce --out OUT`",
    )
    d.add_argument("--data", type=Path, required=True, help="the labelled dataset directory")
    d.add_argument("--entries", **new_entries)
    d.add_argument("--unregistered", **unregistered)
    d.add_argument("--link", help="http(s) URL shared by the seeded entries")
    add_quiet_flag(d)

    x = sub.add_parser(
        "evaluate-model",
        help="the ranked track: run ONNX models on a held-out build and add their entries",
        description="Validate each ONNX model file (the contract of docs/SUBMITTING.md: "
        "standard operators only, no external data), count its parameters from the graph, "
        "run it with onnxruntime (one thread, memory and time limits, in a child process) "
        "over every test mesh of a held-out build (benchmark dataset NAME --secret-seed-file "
        "F), score it and write a held-out-track entry with the board-measured ms per mesh. "
        "Predictions files are refused here: the ranked track runs models only.",
    )
    x.add_argument("models", type=Path, nargs="+", metavar="MODEL.onnx", help="ONNX model files")
    x.add_argument("--data", type=Path, required=True, help="the held-out build's directory")
    x.add_argument("--entries", **new_entries)
    x.add_argument(
        "--unregistered",
        action="store_true",
        help="accept a dataset that is no held-out build of a registered version (a private "
        "board); a public build is refused whatever",
    )
    x.add_argument("--name", help="name on the board (one model; default: the file's stem)")
    x.add_argument("--link", help="http(s) URL of a paper or code for this entry")
    x.add_argument(
        "--time-limit",
        type=number(float, above=0),
        default=600.0,
        metavar="S",
        help="wall-time limit of one model over all test meshes, s (default: %(default)s)",
    )
    x.add_argument(
        "--memory-limit",
        type=number(int, minimum=256),
        default=4096,
        metavar="MIB",
        help="address-space limit of the process running it, MiB (default: %(default)s)",
    )
    add_quiet_flag(x)

    m = sub.add_parser(
        "simulator",
        help="record the physics simulator's point for a dataset",
        description="Write the dataset's simulator entry: the physics "
        "simulator run on each stored representation mesh (radar-sim label "
        "--mesh-labels), scored "
        "against the object's label like a model (test objects with mesh "
        "physics only); speed = radar_sim timed on every scored test mesh, one "
        "thread in a child process, or --ms-per-mesh.",
    )
    m.add_argument("--data", type=Path, required=True, help="the labelled dataset directory")
    m.add_argument("--entries", **new_entries)
    m.add_argument(
        "--ms-per-mesh",
        type=number(minimum=0),
        help="record this speed instead of timing radar_sim",
    )
    m.add_argument("--hardware", help="hardware description (default: this machine's CPU)")
    add_quiet_flag(m)

    r = sub.add_parser(
        "render",
        help="build the static site and LEADERBOARD.md",
        description="Render every entry into OUT/index.html (sortable tables, "
        "per-class breakdowns, speed-vs-error chart, example predictions) and "
        "OUT/LEADERBOARD.md. The site loads nothing from the network.",
    )
    r.add_argument(
        "--out", type=Path, default=Path("site"), help="output folder (default: %(default)s)"
    )
    r.add_argument("--entries", **entries)
    add_quiet_flag(r)

    v = sub.add_parser("serve", help="preview the rendered site locally (http.server)")
    v.add_argument(
        "site",
        type=Path,
        nargs="?",
        default=Path("site"),
        help="rendered site folder (default: %(default)s)",
    )
    v.add_argument(
        "--port",
        type=number(int, minimum=0, maximum=65535),
        default=8000,
        help="port (default: %(default)s; 0 = any free)",
    )
    v.add_argument("--host", default="127.0.0.1", help="address to bind (default: %(default)s)")
    return p


def run(args) -> None:
    if args.command == "submit":
        from leaderboard.submit import submit

        separate_outputs(
            {"--entries": args.entries},
            {"RESULTS": args.results, "--predictions": args.predictions, "--data": args.data},
        )
        path = submit(
            args.results,
            args.predictions,
            args.data,
            args.entries,
            args.name,
            args.link,
            unregistered=args.unregistered,
        )
        print(f"accepted: {path}")
    elif args.command == "seed":
        from leaderboard.submit import seed

        separate_outputs(
            {"--entries": args.entries}, {"--from": args.from_dir, "--data": args.data}
        )
        accepted, skipped, refused = seed(
            args.from_dir,
            args.data,
            args.entries,
            args.link,
            unregistered=args.unregistered,
            progress=not args.quiet,
        )
        _outcome(accepted, skipped, refused)
    elif args.command == "evaluate-model":
        from leaderboard.evaluate_model import evaluate_models

        separate_outputs({"--entries": args.entries}, {"--data": args.data})
        accepted, skipped, refused = evaluate_models(
            args.models,
            args.data,
            args.entries,
            args.name,
            args.link,
            unregistered=args.unregistered,
            time_limit=args.time_limit,
            memory_mib=args.memory_limit,
            progress=not args.quiet,
        )
        _outcome(accepted, skipped, refused, single=len(args.models) == 1)
    elif args.command == "simulator":
        from leaderboard.simulator import record

        separate_outputs({"--entries": args.entries}, {"--data": args.data})
        try:
            path = record(
                args.data, args.entries, args.ms_per_mesh, args.hardware, progress=not args.quiet
            )
        except ImportError as exc:
            raise ValueError(f"cannot time radar_sim ({exc}); pass --ms-per-mesh") from None
        print(f"recorded: {path}")
    elif args.command == "render":
        from leaderboard.render import render

        separate_outputs({"--out": args.out}, {"--entries": args.entries})
        files = render(
            args.out,
            args.entries,
            warn=lambda msg: print(f"leaderboard render: warning: {msg}", file=sys.stderr),
            progress=not args.quiet,
        )
        print(
            f"rendered {len(files)} files into {args.out}/ from the entries in {args.entries}/ "
            f"(open {args.out / 'index.html'})"
        )
    elif args.command == "serve":
        from leaderboard.serve import serve

        serve(args.site, args.port, args.host)


def _outcome(accepted: list, skipped: list, refused: list, single: bool = False) -> None:
    """What ``seed`` and ``evaluate-model`` did, entry by entry (results: printed even with
    --quiet); a refusal exits non-zero, with the one refusal's own line for a single input."""
    for path in accepted:
        print(f"accepted: {path}")
    for msg in skipped:
        print(f"skipped: {msg}")
    if single and refused:
        raise SystemExit(refused[0])
    for msg in refused:
        print(f"refused: {msg}", file=sys.stderr)
    if refused:
        raise SystemExit(
            f"{len(accepted)} accepted, {len(skipped)} skipped, "
            f"{len(refused)} refused (first: {refused[0]})"
        )


def _main(argv: list[str]) -> None:
    args = build_parser().parse_args(argv)
    run(args)


def main(argv: list[str] | None = None) -> None:
    """Console entry point, behind the shared error boundary (docs/CLI.md)."""
    cli_boundary("leaderboard", _main, argv)


if __name__ == "__main__":
    main()
