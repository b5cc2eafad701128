"""`basic-shapes`: generate, inspect, look at and export Basic Shapes datasets."""

from __future__ import annotations

import argparse
import sys

from basic_shapes.generate import GenerateConfig
from basic_shapes.infra import (
    ArgumentParser,
    add_cluster_flags,
    add_debug_flag,
    add_quiet_flag,
    cli_boundary,
    number,
    separate_outputs,
)
from basic_shapes.scales import MIN_DISTANCE, SCALE_RANGE

EPILOG = """examples:
  basic-shapes generate --data data/bs --objects-per-class 20 --variants 9
  basic-shapes info --data data/bs
  basic-shapes show --data data/bs --object 0 --out object0.png
  basic-shapes export --data data/bs --format obj --out meshes/

The dataset is always --data DIR; --out names what a command derives from it (docs/CLI.md)."""


def _classes(text: str) -> tuple[str, ...]:
    """Comma-separated primitives: at least one, known, each once (exit 2, like other flags)."""
    from basic_shapes.primitives import PRIMITIVES

    names = tuple(c.strip() for c in text.split(",") if c.strip())
    unknown = [c for c in names if c not in PRIMITIVES]
    if unknown or not names:
        what = f"unknown class {', '.join(unknown)}" if unknown else f"{text!r} names no class"
        raise argparse.ArgumentTypeError(f"{what}; known: {', '.join(PRIMITIVES)}")
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"{text!r} names a class twice")
    return names


class _Range(argparse.Action):
    """LOW HIGH with LOW < HIGH, refused by the parser (exit 2) like every other flag value."""

    def __call__(self, parser, namespace, values, option_string=None):
        if values[0] >= values[1]:
            parser.error(
                f"argument {option_string}: LOW {values[0]:g} must be < HIGH {values[1]:g}"
            )
        setattr(namespace, self.dest, values)


def build_parser() -> ArgumentParser:
    p = ArgumentParser(
        prog="basic-shapes",
        description=__doc__,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_debug_flag(p)
    sub = p.add_subparsers(dest="command", required=True)

    g = sub.add_parser(
        "generate",
        help="generate a dataset of verified mesh variants (HDF5 shards)",
        description="Generate objects (random per-axis scales), their simple mesh "
        "and complex variants of exactly the same shape, verify each one "
        "(two-sided Hausdorff) and write HDF5 shards. Rerunning the same command "
        "resumes a killed run; the result is byte-identical. The sizes are "
        "required: --objects-per-class 4 --variants 9 takes about a minute, the "
        "paper's 1000 x 99 (300,000 meshes) takes hours.",
    )
    g.add_argument(
        "--data",
        required=True,
        metavar="DIR",
        help="dataset directory (created; resumed if it exists)",
    )
    g.add_argument(
        "--classes",
        type=_classes,
        default=GenerateConfig.classes,
        help="comma-separated primitives (default: cube,cylinder,sphere; also cone,torus)",
    )
    g.add_argument(
        "--objects-per-class",
        type=number(int, minimum=1),
        required=True,
        help="objects per class (required; the paper: 1000, i.e. hours of work)",
    )
    g.add_argument(
        "--variants",
        type=number(int, minimum=0, maximum=999),
        required=True,
        help="complex variants per object, besides the simple mesh (required; the paper: 99)",
    )
    g.add_argument(
        "--ood-variants",
        type=number(int, minimum=0, maximum=25),
        default=GenerateConfig.ood_variants_per_remesher,
        help="out-of-distribution meshes per remesher per test object, variants 900-999 "
        "(default: %(default)s; 0 = none)",
    )
    g.add_argument(
        "--hidden-ood",
        action="store_true",
        help="give test objects of hidden-parameter classes (frustum, roundbox) OOD meshes too "
        "(off in hidden-cpu-v1 and -v2, which predate them)",
    )
    g.add_argument(
        "--seed",
        type=number(int, minimum=0, maximum=2**63 - 1),
        default=0,
        help="dataset seed (default: %(default)s)",
    )
    add_cluster_flags(g)
    add_quiet_flag(g)
    g.add_argument(
        "--objects-per-shard",
        type=number(int, minimum=1),
        default=GenerateConfig.objects_per_shard,
        help="objects per HDF5 shard (default: %(default)s)",
    )
    g.add_argument(
        "--scale-range",
        type=number(above=0),
        nargs=2,
        default=SCALE_RANGE,
        metavar=("LOW", "HIGH"),
        action=_Range,
        help="per-axis bbox extent range in metres (default: %(default)s)",
    )
    g.add_argument(
        "--min-scale-distance",
        type=number(above=0),
        default=MIN_DISTANCE,
        help="minimum log-scale distance between objects of one class (default: %(default)s)",
    )

    i = sub.add_parser("info", help="counts, face-count histograms and Hausdorff statistics")
    i.add_argument("--data", required=True, metavar="DIR", help="dataset directory")
    i.add_argument(
        "--figure",
        metavar="PNG",
        help="also draw the histograms: per class, faces and Hausdorff distances of the simple, "
        "complex and OOD meshes, and the objects' extents",
    )

    s = sub.add_parser("show", help="render an object's simple mesh beside complex variants (PNG)")
    s.add_argument("--data", required=True, metavar="DIR", help="dataset directory")
    s.add_argument("--object", type=number(int, minimum=0), required=True, help="object id")
    s.add_argument("--out", required=True, help="output PNG")
    s.add_argument(
        "--count",
        type=number(int, minimum=0, maximum=99),
        default=5,
        help="complex variants to show (default: %(default)s)",
    )

    e = sub.add_parser(
        "export",
        help="write every mesh as a plain OBJ/PLY/STL file, or labelled shards as NetCDF (g2s)",
    )
    e.add_argument("--data", required=True, metavar="DIR", help="dataset directory")
    e.add_argument(
        "--format",
        choices=("obj", "ply", "stl", "g2s"),
        default="obj",
        help="mesh files, or g2s: one NetCDF per shard, meshes + radar labels in the "
        "layout of the paper's group (docs/ARCHITECTURE.md, Formats)",
    )
    e.add_argument("--out", required=True, help="output directory")
    e.add_argument(
        "--object", type=number(int, minimum=0), default=None, help="only this object id"
    )
    add_quiet_flag(e)
    return p


def _main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "generate":
        from basic_shapes.generate import generate

        cfg = GenerateConfig(
            classes=args.classes,
            objects_per_class=args.objects_per_class,
            variants=args.variants,
            seed=args.seed,
            ood_variants_per_remesher=args.ood_variants,
            hidden_ood=args.hidden_ood,
            objects_per_shard=args.objects_per_shard,
            scale_range=tuple(args.scale_range),
            min_scale_distance=args.min_scale_distance,
        )
        stats = generate(
            args.data, cfg, workers=args.workers, scheduler=args.scheduler, progress=not args.quiet
        )
        print(
            f"{args.data}: {stats['shards']} shards ({stats['skipped']} already done), "
            f"{stats['meshes']} meshes built in {stats['seconds']:.1f} s "
            f"({stats['meshes_per_second']:.1f} verified meshes/s)"
        )
    elif args.command == "info":
        from basic_shapes.info import figure, summary

        print(summary(args.data))
        if args.figure:
            separate_outputs({"--figure": args.figure}, {"--data": args.data})
            figure(args.data, args.figure)
            print(f"wrote {args.figure}")
    elif args.command == "show":
        from basic_shapes.render import show_object

        separate_outputs({"--out": args.out}, {"--data": args.data})
        show_object(args.data, args.object, args.out, args.count)
        print(f"wrote {args.out}")
    elif args.command == "export":
        from basic_shapes.export import export

        separate_outputs({"--out": args.out}, {"--data": args.data})
        n = export(args.data, args.out, args.format, args.object, progress=not args.quiet)
        kind = "NetCDF (g2s)" if args.format == "g2s" else args.format.upper()
        print(f"wrote {n} {kind} files to {args.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Console entry point, behind the shared error boundary (docs/CLI.md)."""
    return cli_boundary("basic-shapes", _main, argv)


if __name__ == "__main__":
    sys.exit(main())
