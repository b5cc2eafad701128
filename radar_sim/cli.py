"""``radar-sim label|rcs|plot``: label shards, print a mesh file's RCS, plot an object's signature.

Errors in the input (missing or foreign files, bad meshes, config mismatches) end the
program with one line naming the file and the problem, and a non-zero exit status.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import warnings
from pathlib import Path

import numpy as np

from basic_shapes.infra import (
    ArgumentParser,
    add_cluster_flags,
    add_debug_flag,
    add_quiet_flag,
    cli_boundary,
    number,
    separate_outputs,
)
from basic_shapes.shards import Shard, ShardError, find_object
from radar_sim.config import NEWEST
from radar_sim.field import CHANNELS
from radar_sim.label import MODES, LabelError, LabelRequest, label_directory, parse_mesh_labels
from radar_sim.meshio import UNITS, load_mesh

CONVENTION = "dB = 20 log10|A| = 10 log10 sigma (sigma in m^2, dBsm)"


MAX_VALUES = 100_000  # numbers in one --freq/--aspect list: the field is values x faces


def _numbers(text: str, positive: bool = False) -> np.ndarray:
    """'8,10,12' or 'start:stop:step' (stop included) -> finite floats (> 0 if ``positive``)."""
    try:
        if ":" in text:
            start, stop, step = (float(x) for x in text.split(":"))
            count = (stop - start) / step if step > 0 else -1
            if not 0 <= count < MAX_VALUES:  # also NaN and inf
                raise argparse.ArgumentTypeError(
                    f"{text!r}: start:stop:step needs step > 0, stop >= start and at most "
                    f"{MAX_VALUES} values"
                )
            values = np.arange(start, stop + step / 2, step)
        else:
            values = np.array([float(x) for x in text.split(",")])
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected numbers like 8,10,12 or start:stop:step"
        ) from None
    if len(values) == 0 or len(values) > MAX_VALUES or not np.isfinite(values).all():
        raise argparse.ArgumentTypeError(f"{text!r}: expected 1 to {MAX_VALUES} finite numbers")
    if positive and not (values > 0).all():
        raise argparse.ArgumentTypeError(f"{text!r}: frequencies must be > 0 GHz")
    return values


MAX_GHZ = 3000.0  # above this a --freq value is Hz given where GHz is expected


def _frequencies(text: str) -> np.ndarray:
    values = _numbers(text, positive=True)
    if values.max() > MAX_GHZ:
        raise argparse.ArgumentTypeError(
            f"{text!r}: --freq is in GHz; {values.max():g} looks like Hz "
            f"(give {values.max() / 1e9:g} for {values.max():g} Hz)"
        )
    return values


def _png_path(text: str) -> str:
    """An output file whose directory exists (checked before any simulation runs)."""
    parent = Path(text).parent
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r}: directory {str(parent)!r} does not exist")
    return text


def _mesh_labels(text: str) -> str:
    try:
        parse_mesh_labels(text)
    except LabelError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def load_config(spec: str):
    """A named config ("xband-v1") or a JSON file written by ``RadarConfig.to_json``."""
    from radar_sim import RadarConfig

    try:
        if Path(spec).is_file():
            return RadarConfig.from_file(spec)
        return RadarConfig.named(spec)
    except ValueError as exc:
        raise SystemExit(f"--config: {exc}") from None


@contextlib.contextmanager
def units_hint(path: str):
    """Print the simulator's units warning as one line that names the file and the fix."""
    from radar_sim import UnitsWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UnitsWarning)
        yield
    for w in caught:
        if issubclass(w.category, UnitsWarning):
            print(
                f"radar-sim: warning: {path}: {w.message}; if the file is in millimetres, "
                f"pass --units mm",
                file=sys.stderr,
            )
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


def cmd_label(args) -> None:
    request = LabelRequest(
        load_config(args.config), args.mesh_labels, args.mode, args.frequency_response
    )
    summary = label_directory(
        args.data,
        request,
        workers=args.workers,
        scheduler=args.scheduler,
        overwrite=args.overwrite,
        progress=not args.quiet,
    )
    reused = f" ({summary.reused} finished before an interruption)" if summary.reused else ""
    print(
        f"labelled {len(summary.labelled)} shard(s), {summary.objects} object(s){reused}; "
        f"skipped {len(summary.skipped)} shard(s) already labelled with this config"
    )


MAX_WAVELENGTHS = 300.0


def size_warning(extent_m, f_min_hz: float, f_max_hz: float, units: str) -> str | None:
    """Why the object's size is implausible for the band, or None.

    Above 300 wavelengths at the top frequency (7.5 m at 12 GHz; the generator's largest
    objects are 2 m, 80 wavelengths) a file is more likely in millimetres than a target that
    large; below half a wavelength at the bottom frequency physical optics does not hold, the
    sign of a file in metres read with ``--units mm``.
    """
    from radar_sim.field import C0

    size = float(np.max(extent_m))
    if size > MAX_WAVELENGTHS * C0 / f_max_hz:
        hint = "if the file is in millimetres, pass --units mm" if units == "m" else "check --units"
        return (
            f"the object is {size:.4g} m across, {size * f_max_hz / C0:.0f} wavelengths at "
            f"{f_max_hz / 1e9:.4g} GHz, larger than {MAX_WAVELENGTHS:.0f}: {hint}"
        )
    if size < 0.5 * C0 / f_min_hz:
        return (
            f"the object is {size:.4g} m across, under half a wavelength at "
            f"{f_min_hz / 1e9:.4g} GHz, where physical optics does not hold: check --units"
        )
    return None


def cmd_rcs(args) -> None:
    from radar_sim import detect_mode, rcs

    vertices, faces = load_mesh(args.meshfile, args.units)
    mode = detect_mode(vertices, faces) if args.mode == "auto" else args.mode
    with units_hint(args.meshfile):
        field = rcs(vertices, faces, args.freq * 1e9, args.aspect, args.roll, mode=mode)
    extent = np.ptp(vertices, axis=0)
    text = " x ".join(f"{e:.4g}" for e in extent)
    print(
        f"# {args.meshfile}: {len(faces)} faces, units {args.units} (extent {text} m), "
        f"mode {mode}, roll {args.roll:g} deg; VV, physical optics without edge diffraction"
    )
    warning = size_warning(extent, args.freq.min() * 1e9, args.freq.max() * 1e9, args.units)
    if warning:
        print(f"# warning: {warning}")
        print(f"radar-sim: warning: {args.meshfile}: {warning}", file=sys.stderr)
    print(f"# RCS in dBsm: {CONVENTION}")
    print("aspect_deg " + " ".join(f"{f:>10.4g}GHz" for f in args.freq))
    with np.errstate(divide="ignore"):
        db = 20 * np.log10(np.abs(field))
    for aspect, row in zip(args.aspect, db):
        print(f"{aspect:>10.4g} " + " ".join(f"{v:>13.4f}" for v in row))


def dataset_signature(
    directory,
    object_id: int,
    config: str | None,
    mode: str = "auto",
    variant: int | None = None,
    channel: str = "VV",
):
    """(coordinates, profiles, frequency response, title) of one mesh of a dataset object, in
    one polarization ``channel``.

    Without ``variant``: the object's label, stored when it includes the frequency response,
    otherwise computed as ``radar-sim label`` does (the primitive on its simulation mesh).
    With ``variant``: the physics on that representation mesh (0 = simple), simulated. Both
    simulate with ``config``, by default the config the dataset was labelled with (so the
    plot is its label), NEWEST for an unlabelled dataset.
    """
    from basic_shapes.analytic import simulation_mesh, solid_for
    from radar_sim import MeshError, RadarConfig
    from radar_sim.label import object_mode

    path, obj, meshes = find_object(directory, object_id)
    k = obj["shard_object_index"]
    title = f"object {obj['id']} ({obj['class']})"
    with Shard(path) as s:
        # a /radar group without its responses is a damaged label, not an unlabelled dataset
        radar = s.radar if s.has_radar else None
        stored_vv = channel == "VV" and radar is not None and radar.has_frequency_response
        if variant is None and stored_vv:
            return (
                radar.coordinates,
                radar.response(k),
                radar.frequency_response(k),
                f"{title}: its stored label, VV",
            )
        params = s.object_params()[k]
        try:
            stored = None if config or radar is None else radar.config
            cfg = RadarConfig(**stored) if stored else load_config(config or NEWEST)
        except (TypeError, ValueError) as exc:
            raise ShardError(f"{path}: stored radar config: {exc}") from None
    if variant is not None:
        by_variant = {v: (vertices, faces) for v, vertices, faces in meshes}
        if variant not in by_variant:
            raise ShardError(
                f"{path}: object {obj['id']} has no variant {variant} "
                f"(--variant 0..{max(by_variant)})"
            )
        name = "simple mesh" if variant == 0 else f"variant {variant}"
        try:
            return simulated_signature(
                *by_variant[variant], cfg, mode, f"{title}: simulated on its {name}", channel
            )
        except MeshError as exc:  # name the shard and the mesh, not only --data
            raise ShardError(f"{path}: object {obj['id']} variant {variant}: {exc}") from None
    solid = solid_for(obj["class"], obj["scale"], params)
    vertices, faces = simulation_mesh(solid, cfg.f_stop_hz, rule=cfg.simulation_rule)
    return simulated_signature(
        vertices,
        faces,
        cfg,
        object_mode(obj["class"], mode),
        f"{title}: its label, the primitive on a {len(faces)}-face simulation mesh"
        if radar is not None and not config
        else f"{title}: {'not labelled; ' if radar is None else ''}the label {cfg.name} would "
        f"give, the primitive on a {len(faces)}-face simulation mesh",
        channel,
    )


def simulated_signature(vertices, faces, config, mode: str, title: str, channel: str = "VV"):
    """``config``: a RadarConfig; ``channel`` one of its channels."""
    from radar_sim import simulate

    channels = config.channel_list
    if channel not in channels:
        raise SystemExit(
            f"config {config.name} has no {channel} channel (it computes {','.join(channels)}; "
            f"HH and HV need a polarimetric config: add --config {NEWEST}, the newest)"
        )
    result = simulate(vertices, faces, config, mode=mode)
    coords = {n: getattr(result, n) for n in ("aspect_deg", "roll_deg", "range_m", "frequency_hz")}
    profiles, response = result.range_profiles, result.frequency_response
    if channel != "VV":
        c = channels.index(channel)
        profiles, response = result.channel_profiles[c], result.channel_response[c]
    return (
        coords,
        profiles,
        response,
        f"{title} ({result.mode}, config {config.name}, {channel})",
    )


def cmd_plot(args) -> None:
    from radar_sim.plot import plot_signature

    if (args.meshfile is None) == (args.data is None):
        raise SystemExit("plot needs a MESHFILE or --data DIR --object ID (one of the two)")
    source = args.meshfile or args.data
    separate_outputs({"--out": args.out}, {"MESHFILE": args.meshfile, "--data": args.data})
    if not Path(source).exists():
        raise SystemExit(f"{source}: no such file or directory")
    if args.data is not None:
        if not Path(args.data).is_dir():
            raise SystemExit(f"--data {args.data}: not a dataset directory")
        if args.object is None:
            raise SystemExit(f"--data {args.data}: pass --object ID")
        signature = dataset_signature(
            args.data, args.object, args.config, args.mode, args.variant, args.channel
        )
    else:
        if args.variant is not None or args.object is not None:
            raise SystemExit(
                f"{args.meshfile} is a mesh file: --object and --variant need --data DIR"
            )
        vertices, faces = load_mesh(args.meshfile, args.units)
        with units_hint(args.meshfile):
            signature = simulated_signature(
                vertices,
                faces,
                load_config(args.config or NEWEST),
                args.mode,
                Path(args.meshfile).name,
                args.channel,
            )
    coords, profiles, response, title = signature
    plot_signature(
        args.out,
        range_profiles=profiles,
        frequency_response=response,
        roll=args.roll,
        title=title,
        **coords,
    )
    print(f"wrote {args.out}")


EPILOG = """examples:
  radar-sim label --data data/bs --workers 2             # xband-v3: HH, VV, HV, edge diffraction
  radar-sim plot --data data/bs --object 0 --out radar.png
  radar-sim plot --data data/bs --object 0 --variant 1 --out v1.png   # a complex mesh, simulated
  radar-sim rcs box.obj --freq 10 --aspect 0:90:15

docs/RADAR.md is the physics; docs/CLI.md the conventions shared by the four tools."""


def build_parser() -> ArgumentParser:
    p = ArgumentParser(
        prog="radar-sim",
        description=(
            "Exact physical-optics radar simulator: label Basic Shapes shards, print the RCS\n"
            "of a mesh file, plot an object's signature. Units are metres;\n"
            f"{CONVENTION}."
        ),
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_debug_flag(p)
    sub = p.add_subparsers(dest="command", required=True)

    q = sub.add_parser(
        "label",
        help="add /radar labels to every shard of a dataset, in place",
        description="Label every shard in place, atomically and resumably: an "
        "object's label is the physics of its analytic primitive (on a simulation "
        "mesh refined for the top frequency); finished objects survive a kill; a "
        "shard already labelled with the same config is skipped. Runs on Dask.",
    )
    q.add_argument(
        "--data", required=True, metavar="DIR", help="dataset directory holding shard-*.h5"
    )
    q.add_argument(
        "--config",
        default=NEWEST,
        help="config name or JSON file (default %(default)s, the newest: HH, VV and HV with edge "
        "diffraction, the v3 dataset versions' labels; xband-v1: PO, VV only)",
    )
    add_cluster_flags(q, "worker processes, one thread each")
    add_quiet_flag(q)
    q.add_argument(
        "--mesh-labels",
        type=_mesh_labels,
        default="none",
        help="also store the "
        "physics on stored meshes (representations, the simple one included): none, "
        "sample:K (K per object, drawn from the object seed) or all (default none)",
    )
    q.add_argument(
        "--mode",
        choices=MODES,
        default="auto",
        help="physics per mesh: auto-detected, or forced (default auto)",
    )
    q.add_argument(
        "--frequency-response",
        action="store_true",
        help="also store the complex frequency response per object",
    )
    q.add_argument(
        "--overwrite",
        action="store_true",
        help="relabel shards labelled with a different config or options",
    )
    q.set_defaults(run=cmd_label)

    q = sub.add_parser(
        "rcs",
        help="print the monostatic RCS (dBsm) of a mesh file",
        description=f"Monostatic RCS of one OBJ/STL/PLY mesh, VV channel, physical optics "
        f"without edge diffraction (the mesh as given, not a primitive). {CONVENTION}. Line "
        "of sight (sin a cos r, sin a sin r, cos a) for aspect a, roll r.",
    )
    q.add_argument("meshfile", help="OBJ, STL or PLY file")
    q.add_argument(
        "--freq", type=_frequencies, required=True, help="GHz: 10 or 8,10,12 or 8:12:0.5"
    )
    q.add_argument("--aspect", type=_numbers, required=True, help="degrees: 0,45,90 or 0:180:5")
    q.add_argument("--roll", type=number(), default=0.0, help="degrees (default 0)")
    q.add_argument("--units", choices=UNITS, default="m", help="units of the file (default m)")
    q.add_argument("--mode", choices=MODES, default="auto", help="physics (default auto)")
    q.set_defaults(run=cmd_rcs)

    q = sub.add_parser(
        "plot",
        help="range-aspect image and RCS polar plot of one object (PNG)",
        description="Plot |range profile| (dB) against range and aspect, and the "
        "RCS (dBsm) against aspect at the frequency sample nearest the band centre "
        "(named in the title), at one roll angle.",
    )
    q.add_argument(
        "meshfile",
        nargs="?",
        default=None,
        help="OBJ, STL or PLY file (or give --data DIR --object ID)",
    )
    q.add_argument("--data", metavar="DIR", default=None, help="dataset directory (with --object)")
    q.add_argument(
        "--object", type=number(int, minimum=0), default=None, help="object id in --data"
    )
    q.add_argument(
        "--variant",
        type=number(int, minimum=0),
        default=None,
        help="plot the physics on this representation mesh of the object (0 = "
        "simple, 1.. = complex), simulated; default: the object's label",
    )
    q.add_argument("--out", type=_png_path, required=True, help="PNG file to write")
    q.add_argument(
        "--roll", type=number(), default=0.0, help="degrees; nearest grid roll (default 0)"
    )
    q.add_argument(
        "--config",
        default=None,
        help="config name or JSON file for simulation (default: the one the dataset was "
        f"labelled with; {NEWEST} for a mesh file or an unlabelled dataset)",
    )
    q.add_argument("--units", choices=UNITS, default="m", help="units of a mesh file (default m)")
    q.add_argument("--mode", choices=MODES, default="auto", help="physics (default auto)")
    q.add_argument(
        "--channel",
        choices=CHANNELS,
        default="VV",
        help="polarization (default VV, the benchmark's target); HH and HV need a polarimetric "
        "config (xband-v2 and later; a dataset labelled with one has them)",
    )
    q.set_defaults(run=cmd_plot)
    return p


def _main(argv: list[str]) -> None:
    from radar_sim import MeshError

    args = build_parser().parse_args(argv)
    try:
        args.run(args)
    except MeshError as exc:
        source = getattr(args, "meshfile", None) or args.data
        raise SystemExit(f"{source}: {exc}") from None


def main(argv: list[str] | None = None) -> None:
    """Console entry point, behind the shared error boundary (docs/CLI.md)."""
    cli_boundary("radar-sim", _main, argv)


if __name__ == "__main__":
    main()
