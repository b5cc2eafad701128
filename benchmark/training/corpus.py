"""Pretraining corpus: procedural CAD-like shapes (manifold3d) and a ShapeNetCore v2 loader.

The paper pretrains its face encoders on a large, varied mesh corpus (classification or
MeshGPT-style autoencoding) before fine-tuning on Basic Shapes. Every mesh comes out centred
and scaled to the unit bounding box (longest side 1), float32 vertices, int32 faces, at most
``max_faces`` faces. Same seed, same bytes (on one machine and library version). Nothing here
downloads.
"""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import fast_simplification
import h5py
import manifold3d as m3d
import numpy as np
from tqdm import tqdm

from basic_shapes.geometry import read_obj
from basic_shapes.infra import atomic_path, load_json, open_hdf5
from basic_shapes.meshcheck import (
    MeshError,
    as_arrays,
    drop_unreferenced,
    face_repeats,
    is_closed,
    repeated_vertex,
    weld,
)
from benchmark.scoring.data import normalize_mesh  # one normalization for corpus and benchmark

Mesh = tuple[np.ndarray, np.ndarray, int]

CORPUS_FORMAT = "basic-shapes-corpus"
CORPUS_VERSION = 1
MIN_FACES = 4  # the smallest closed triangle mesh (a tetrahedron)
MIN_BUDGET = 48  # procedural families need this many faces to stay closed after decimation


class CorpusError(ValueError):
    """A corpus file or a ShapeNet directory is unreadable, foreign or inconsistent."""


# --------------------------------------------------------------------------- mesh helpers


def _compact(
    vertices: np.ndarray, faces: np.ndarray, drop_fins: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Drop degenerate faces, repeated faces and unreferenced vertices.

    Faces on the same three vertices are either double-sided geometry (ShapeNet has plenty:
    keep one) or the back-to-back fin an edge collapse leaves on a closed surface
    (``drop_fins``: remove both, which closes the surface again).
    """
    f = faces[~repeated_vertex(faces)]
    first, count = face_repeats(f)
    v, f = drop_unreferenced(vertices, f[count == 1] if drop_fins else f[first])
    return v, f.astype(np.int32)


class SimplifyError(MeshError):
    """Quadric decimation could not meet the face budget (or keep the surface closed)."""


def simplify_to(
    vertices: np.ndarray, faces: np.ndarray, max_faces: int, keep_watertight: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Quadric decimation (fast-simplification) to at most ``max_faces`` faces.

    The decimator may stop above its target (it refuses collapses that flip or squash
    triangles), so the target is tightened a few times. It has no link-condition check and can
    pinch a closed surface; with ``keep_watertight`` such a result is an error, not an output.
    """
    v, f = _compact(
        np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int32), keep_watertight
    )
    target = max_faces
    for _ in range(3):
        if len(f) <= max_faces or target < MIN_FACES:
            break
        sv, sf = fast_simplification.simplify(v, f, target_count=target)
        sv, sf = _compact(sv, np.asarray(sf, dtype=np.int32), keep_watertight)
        target = int(target * max_faces / max(len(sf), 1) * 0.9)
        if len(sf) <= max_faces:
            v, f = sv, sf
    if not MIN_FACES <= len(f) <= max_faces:
        raise SimplifyError(
            f"cannot simplify a {len(faces)}-face mesh to {MIN_FACES}..{max_faces} faces"
        )
    if keep_watertight and not is_closed(f):
        raise SimplifyError(
            f"simplifying a {len(faces)}-face mesh to {len(f)} faces left it not watertight"
        )
    return v, f


def _mesh_of(solid: m3d.Manifold) -> tuple[np.ndarray, np.ndarray]:
    mesh = solid.to_mesh()
    # copies: the buffers manifold3d hands out are read-only, which fast-simplification rejects
    return np.array(mesh.vert_properties[:, :3], dtype=np.float64), np.array(
        mesh.tri_verts, dtype=np.int32
    )


# --------------------------------------------------------------------------- shape families
# Each builder draws its parameters from ``rng`` and returns a closed manifold3d solid whose
# tessellation roughly fits ``budget`` faces (decimation does the rest: it struggles to remove
# the long slivers of flat CAD faces, so starting far above budget gets many draws rejected).


def _segments(
    rng: np.random.Generator, lo: int, hi: int, budget: int, faces_per_segment: float
) -> int:
    """A random tessellation count in [lo, hi], capped so that about ``budget`` faces suffice."""
    hi = max(lo, min(hi, int(budget / faces_per_segment)))
    return int(rng.integers(lo, hi + 1))


def _box_with_holes(rng, budget):
    size = rng.uniform(0.4, 1.0, 3)
    solid = m3d.Manifold.cube(tuple(size), center=True)
    n_holes = int(rng.integers(1, 1 + min(4, max(1, budget // 60))))
    for _ in range(n_holes):
        axis = int(rng.integers(3))
        others = [a for a in range(3) if a != axis]
        r = rng.uniform(0.05, 0.22) * size[others].min()
        centre = np.zeros(3)
        centre[others] = [rng.uniform(-0.5, 0.5) * (size[a] - 2.4 * r) for a in others]
        hole = m3d.Manifold.cylinder(
            2.0, r, -1.0, _segments(rng, 6, 48, budget, 6 * n_holes), center=True
        )
        if axis == 0:
            hole = hole.rotate((0.0, 90.0, 0.0))
        elif axis == 1:
            hole = hole.rotate((90.0, 0.0, 0.0))
        solid = solid - hole.translate(tuple(centre))
    return solid


def _l_bracket(rng, budget):
    a, b = rng.uniform(0.5, 1.0, 2)
    t1, t2 = rng.uniform(0.08, 0.3, 2) * min(a, b)
    section = m3d.CrossSection([np.array([[0, 0], [a, 0], [a, t1], [t2, t1], [t2, b], [0, b]])])
    depth = rng.uniform(0.3, 1.0)
    solid = m3d.Manifold.extrude(section, depth)
    n_holes = int(rng.integers(0, 1 + min(2, budget // 60)))
    for _ in range(n_holes):  # bolt holes through the horizontal leg
        r = rng.uniform(0.2, 0.4) * min(depth, a - t2) / 2
        x = rng.uniform(t2 + r * 1.5, a - r * 1.5)
        hole = m3d.Manifold.cylinder(
            1.0, r, -1.0, _segments(rng, 6, 48, budget, 6 * n_holes), center=True
        )
        solid = solid - hole.rotate((90.0, 0.0, 0.0)).translate((x, 0.0, depth / 2))
    return solid


def _tube(rng, budget):
    n = _segments(rng, 3, 64, budget, 8)
    outer = rng.uniform(0.2, 0.5)
    inner = outer * rng.uniform(0.4, 0.9)
    ring = m3d.CrossSection.circle(outer, n) - m3d.CrossSection.circle(inner, n)
    return m3d.Manifold.extrude(ring, rng.uniform(0.3, 2.0))


def _revolved_vase(rng, budget):
    h = rng.uniform(0.6, 1.5)
    k = int(rng.integers(4, 9))
    y = np.linspace(0.0, h, k)
    r = rng.uniform(0.15, 0.5, k)
    r[0] = rng.uniform(0.15, 0.35)
    hollow = rng.random() < 0.7
    n = _segments(rng, 6, 64, budget, 2 * (k + 1) * (1 + hollow))
    profile = np.vstack([[0.0, 0.0], np.column_stack([r, y]), [0.0, h]])
    outer = m3d.Manifold.revolve(m3d.CrossSection([profile]), n)
    if hollow:  # cut a cavity from the top, keeping a floor and a wall
        wall = rng.uniform(0.03, 0.08)
        floor = rng.uniform(0.05, 0.15) * h
        inner_r = np.maximum(r - wall, 0.02)
        cavity = np.vstack(
            [
                [0.0, floor],
                np.column_stack([inner_r[1:], y[1:]]),
                [inner_r[-1], h + 1.0],
                [0.0, h + 1.0],
            ]
        )
        cavity[1, 1] = max(cavity[1, 1], floor + 1e-3)
        outer = outer - m3d.Manifold.revolve(m3d.CrossSection([cavity]), n)
    return outer


def _star_prism(rng, budget):
    n = int(rng.integers(3, 13))
    radius = rng.uniform(0.3, 0.6)
    if rng.random() < 0.6:  # star: alternate outer and inner radius
        rad = np.where(np.arange(2 * n) % 2 == 0, radius, radius * rng.uniform(0.3, 0.8))
        angle = np.arange(2 * n) * np.pi / n
    else:  # regular polygon
        rad = np.full(n, radius)
        angle = np.arange(n) * 2 * np.pi / n
    poly = np.column_stack([rad * np.cos(angle), rad * np.sin(angle)])
    twist = rng.uniform(0.0, 90.0) if rng.random() < 0.4 else 0.0
    top = rng.uniform(0.3, 1.0) if rng.random() < 0.4 else 1.0
    # a division per 15 degrees of twist keeps the side walls from self-intersecting
    divisions = int(np.ceil(twist / 15.0))
    return m3d.Manifold.extrude(
        m3d.CrossSection([poly]), rng.uniform(0.2, 1.5), divisions, twist, (top, top)
    )


def _torus_ring(rng, budget):
    major = rng.uniform(0.3, 0.6)
    minor = major * rng.uniform(0.1, 0.6)
    if rng.random() < 0.6:  # elliptic section
        n_section = _segments(rng, 4, 32, budget, 12)
        section = m3d.CrossSection.circle(minor, n_section).scale((1.0, rng.uniform(0.5, 2.0)))
    else:  # washer with a rectangular section
        n_section = 4
        section = m3d.CrossSection.square((2 * minor, rng.uniform(0.5, 3.0) * minor), center=True)
    n = _segments(rng, 6, 64, budget, 2 * n_section)
    return m3d.Manifold.revolve(section.translate((major, 0.0)), n)


def _random_primitive(rng, budget, centre):
    kind = int(rng.integers(3))
    if kind == 0:
        solid = m3d.Manifold.cube(tuple(rng.uniform(0.2, 0.7, 3)), center=True)
    elif kind == 1:  # a geodesic sphere of n segments has about n**2 / 2 faces
        n = _segments(rng, 4, 32, int(np.sqrt(2 * budget)), 1)
        solid = m3d.Manifold.sphere(rng.uniform(0.12, 0.35), n)
    else:
        solid = m3d.Manifold.cylinder(
            rng.uniform(0.2, 0.8),
            rng.uniform(0.08, 0.3),
            -1.0,
            _segments(rng, 4, 40, budget, 4),
            center=True,
        )
    return solid.rotate(tuple(rng.uniform(0.0, 360.0, 3))).translate(tuple(centre))


def _surface_point(solid, rng):
    vertices = solid.to_mesh().vert_properties
    return vertices[rng.integers(len(vertices)), :3]


def _csg_primitives(rng, budget):
    """Union of 2-5 primitives, each centred on the surface of the union so far (so it stays
    one piece), sometimes minus one more."""
    count = int(rng.integers(2, 6))
    solid = _random_primitive(rng, budget // count, (0.0, 0.0, 0.0))
    for _ in range(count - 1):
        solid = solid + _random_primitive(rng, budget // count, _surface_point(solid, rng))
    if rng.random() < 0.4:
        cut = solid - _random_primitive(rng, budget // count, _surface_point(solid, rng))
        if len(cut.decompose()) == 1:
            solid = cut
    return solid


def _capsule_rounded_box(rng, budget):
    n = _segments(rng, 4, 32, int(np.sqrt(2 * budget)), 1)
    r = rng.uniform(0.08, 0.25)
    if rng.random() < 0.5:  # capsule: hull of two spheres
        length = rng.uniform(0.2, 1.2)
        balls = [m3d.Manifold.sphere(r, n).translate((0.0, 0.0, z)) for z in (0.0, length)]
    else:  # rounded box: hull of eight corner spheres
        half = rng.uniform(0.1, 0.5, 3)
        balls = [
            m3d.Manifold.sphere(r, n).translate(tuple(half * s))
            for s in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
        ]
    return m3d.Manifold.batch_hull(balls)


def _wedge_pyramid(rng, budget):
    kind = int(rng.integers(3))
    if kind == 0:  # wedge: a right-triangle prism
        w, h = rng.uniform(0.3, 1.0, 2)
        section = m3d.CrossSection([np.array([[0.0, 0.0], [w, 0.0], [0.0, h]])])
        return m3d.Manifold.extrude(section, rng.uniform(0.2, 1.0))
    n = int(rng.integers(3, 9))
    angle = np.arange(n) * 2 * np.pi / n + rng.uniform(0, np.pi)
    base = m3d.CrossSection(
        [rng.uniform(0.3, 0.6) * np.column_stack([np.cos(angle), np.sin(angle)])]
    )
    top = 0.0 if kind == 1 else rng.uniform(0.2, 0.8)  # pyramid or frustum
    return m3d.Manifold.extrude(base, rng.uniform(0.3, 1.2), 0, 0.0, (top, top))


def _gear(rng, budget):
    teeth = _segments(rng, 6, 32, budget, 20)
    outer = rng.uniform(0.35, 0.5)
    root = outer * rng.uniform(0.75, 0.9)
    pitch = 2 * np.pi / teeth
    # a trapezoidal tooth per pitch: root, rise, tip, fall
    fractions = np.array([0.0, 0.25, 0.4, 0.6, 0.75])
    angle = (np.arange(teeth)[:, None] + fractions[None, :]).ravel() * pitch
    rad = np.tile([root, root, outer, outer, root], teeth)
    profile = m3d.CrossSection([np.column_stack([rad * np.cos(angle), rad * np.sin(angle)])])
    bore = m3d.CrossSection.circle(root * rng.uniform(0.15, 0.5), _segments(rng, 6, 32, budget, 8))
    return m3d.Manifold.extrude(profile - bore, rng.uniform(0.05, 0.4))


_BUILDERS = {
    "box_with_holes": _box_with_holes,
    "l_bracket": _l_bracket,
    "tube": _tube,
    "revolved_vase": _revolved_vase,
    "star_prism": _star_prism,
    "torus_ring": _torus_ring,
    "csg_primitives": _csg_primitives,
    "capsule_rounded_box": _capsule_rounded_box,
    "wedge_pyramid": _wedge_pyramid,
    "gear": _gear,
}
FAMILIES: tuple[str, ...] = tuple(_BUILDERS)
WATERTIGHT: tuple[bool, ...] = tuple(True for _ in FAMILIES)  # every builder returns a closed solid


MAX_ATTEMPTS = 16


def _check_max_faces(max_faces: int, least: int) -> None:
    if max_faces < least:
        raise ValueError(f"max_faces must be at least {least}, got {max_faces}")


def build_family_mesh(
    family: int, rng: np.random.Generator, max_faces: int = 800
) -> tuple[np.ndarray, np.ndarray]:
    """One random member of ``FAMILIES[family]``: unit-bbox float32 vertices, int32 faces.

    A random face budget in [max(MIN_BUDGET, max_faces/4), max_faces] varies triangle density
    within a family. Draws that the decimator cannot bring under budget as a closed surface are
    rejected and redrawn from the same generator (so the result stays a function of the seed).
    """
    _check_max_faces(max_faces, MIN_BUDGET)
    name = FAMILIES[family]
    for _ in range(MAX_ATTEMPTS):
        budget = int(rng.integers(max(MIN_BUDGET, max_faces // 4), max_faces + 1))
        solid = _BUILDERS[name](rng, budget)
        if (
            solid.status() != m3d.Error.NoError
            or solid.num_tri() < MIN_FACES
            or len(solid.decompose()) != 1
        ):
            continue
        # half the draws are remeshed: edges split k ways, then decimated back under budget
        k = int(np.sqrt(2.0 * budget / solid.num_tri()))
        if k >= 2 and rng.random() < 0.5:
            solid = solid.refine(int(rng.integers(2, k + 1)))
        try:
            v, f = simplify_to(*_mesh_of(solid), budget, keep_watertight=WATERTIGHT[family])
        except SimplifyError:
            continue
        return normalize_mesh(v), f
    raise RuntimeError(
        f"family {name}: no valid mesh of at most {max_faces} faces in {MAX_ATTEMPTS} draws; "
        "raise max_faces"
    )


def procedural_corpus(
    n_meshes: int, seed: int, max_faces: int = 800, progress: bool = False
) -> list[Mesh]:
    """``n_meshes`` labelled meshes ``(vertices, faces, family_index)``, balanced over families.

    Mesh ``i`` belongs to family ``i % len(FAMILIES)`` and draws its parameters from its own
    generator seeded by ``(seed, i)``, so a corpus is a prefix of any larger one with the same
    seed and the same bytes come back on every run.
    """
    _check_max_faces(max_faces, MIN_BUDGET)
    if n_meshes < 0:
        raise ValueError(f"n_meshes must be non-negative, got {n_meshes}")
    out: list[Mesh] = []
    for i in tqdm(range(n_meshes), desc="procedural corpus", unit="mesh", disable=not progress):
        family = i % len(FAMILIES)
        v, f = build_family_mesh(family, np.random.default_rng([seed, i]), max_faces)
        out.append((v, f, family))
    return out


# --------------------------------------------------------------------------- corpus files


def write_corpus_file(
    path: str | Path,
    meshes: list[Mesh],
    class_names: list[str] | tuple[str, ...],
    meta: dict | None = None,
) -> None:
    """Write meshes flat with offsets (the shards' ragged layout), atomically, byte-deterministic.

    The format marker is written last, so a file cut short never reads as a corpus.
    """
    path = Path(path)
    for i, (v, f, c) in enumerate(meshes):
        try:
            as_arrays(v, f)
        except MeshError as exc:
            raise ValueError(f"{path}: mesh {i}: {exc}") from None
        if not 0 <= c < len(class_names):
            raise ValueError(f"{path}: mesh {i} has class {c}, not in 0..{len(class_names) - 1}")
    n_v = np.cumsum([0] + [len(v) for v, _, _ in meshes], dtype=np.int64)
    n_f = np.cumsum([0] + [len(f) for _, f, _ in meshes], dtype=np.int64)
    vertices = np.concatenate(
        [np.zeros((0, 3), np.float32)] + [np.asarray(v, np.float32) for v, _, _ in meshes]
    )
    faces = np.concatenate(
        [np.zeros((0, 3), np.int32)] + [np.asarray(f, np.int32) for _, f, _ in meshes]
    )
    labels = np.array([c for _, _, c in meshes], dtype=np.int32)
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w") as h5:
            for name, data in [
                ("vertices", vertices),
                ("faces", faces),
                ("vertex_offset", n_v),
                ("face_offset", n_f),
                ("label", labels),
            ]:
                h5.create_dataset(name, data=data, track_times=False)
            h5.attrs["class_names"] = json.dumps(list(class_names))
            h5.attrs["meta"] = json.dumps(meta or {}, sort_keys=True)
            h5.attrs["version"] = CORPUS_VERSION
            h5.attrs["format"] = CORPUS_FORMAT


def _corpus_header(h5: h5py.File, path: Path) -> tuple[list[str], dict]:
    if h5.attrs.get("format") != CORPUS_FORMAT:
        raise CorpusError(f"{path}: not a {CORPUS_FORMAT} file")
    if h5.attrs.get("version") != CORPUS_VERSION:
        raise CorpusError(
            f"{path}: corpus version {h5.attrs.get('version')} unsupported (need {CORPUS_VERSION})"
        )
    try:
        return tuple(
            load_json(h5.attrs[name], what=f"{path}: {name} attribute", error=CorpusError)
            for name in ("class_names", "meta")
        )
    except KeyError as exc:
        raise CorpusError(f"{path}: damaged corpus header (no {exc} attribute)") from None


def _open(path: Path) -> h5py.File:
    """Through the hardened opener: a corpus file may come from anywhere (docs/CLI.md)."""
    return open_hdf5(path, CorpusError, "corpus file")


def read_corpus_file(path: str | Path) -> tuple[list[Mesh], list[str], dict]:
    """Meshes, class names and build metadata of a corpus file; ``CorpusError`` if it is not one."""
    path = Path(path)
    with _open(path) as h5:
        names, meta = _corpus_header(h5, path)
        try:
            vertices, faces = h5["vertices"][...], h5["faces"][...]
            vo, fo, labels = h5["vertex_offset"][...], h5["face_offset"][...], h5["label"][...]
        except (OSError, KeyError) as exc:
            raise CorpusError(f"{path}: truncated corpus file ({exc})") from None
    n = len(labels)
    if (
        len(vo) != n + 1
        or len(fo) != n + 1
        or vo[0] != 0
        or fo[0] != 0
        or vo[-1] != len(vertices)
        or fo[-1] != len(faces)
        or (np.diff(vo) < 0).any()
        or (np.diff(fo) <= 0).any()
    ):
        raise CorpusError(f"{path}: inconsistent offsets")
    meshes = []
    for i in range(n):
        v, f = vertices[vo[i] : vo[i + 1]], faces[fo[i] : fo[i + 1]]
        if f.min() < 0 or f.max() >= len(v) or not 0 <= labels[i] < len(names):
            raise CorpusError(f"{path}: mesh {i} has out-of-range face indices or class")
        meshes.append((v, f, int(labels[i])))
    return meshes, names, meta


GENERATOR_VERSION = 1  # bump when a family changes, so cached corpus files get rebuilt


def build_corpus_file(
    path: str | Path, n_meshes: int, seed: int, max_faces: int = 800, progress: bool = False
) -> Path:
    """Cache ``procedural_corpus`` in an HDF5 file, so training reruns start instantly.

    A corpus file already built with the same arguments is kept as is; one built with other
    arguments is rebuilt; any other existing file is an error (never overwritten).
    """
    path = Path(path)
    meta = {
        "source": "procedural",
        "generator_version": GENERATOR_VERSION,
        "n_meshes": n_meshes,
        "seed": seed,
        "max_faces": max_faces,
    }
    if path.exists():
        with _open(path) as h5:
            names, old = _corpus_header(h5, path)
        if old == meta and tuple(names) == FAMILIES:
            return path
    write_corpus_file(path, procedural_corpus(n_meshes, seed, max_faces, progress), FAMILIES, meta)
    return path


def load_corpus_file(path: str | Path) -> list[Mesh]:
    """The meshes ``(vertices, faces, class_index)`` of a corpus file."""
    return read_corpus_file(path)[0]


# --------------------------------------------------------------------------- ShapeNetCore v2

SHAPENET_MODEL = Path("models") / "model_normalized.obj"
WELD_DECIMALS = 6
"""ShapeNet duplicates vertices per UV seam: coordinates equal to 6 decimals are welded."""
_SYNSET = re.compile(r"^\d{8}$")


def _shapenet_synsets(root: Path) -> list[Path]:
    layout = f"expected <root>/<synset_id>/<model_id>/{SHAPENET_MODEL.as_posix()}"
    if not root.is_dir():
        raise CorpusError(f"{root}: not a directory; {layout}")
    synsets = sorted(p for p in root.iterdir() if p.is_dir() and _SYNSET.match(p.name))
    if not synsets or not any(any(s.glob(f"*/{SHAPENET_MODEL.as_posix()}")) for s in synsets):
        raise CorpusError(f"{root}: not a ShapeNetCore v2 directory; {layout}")
    return synsets


def shapenet_class_names(path: str | Path) -> list[str]:
    """Class names in class-index order: taxonomy.json's first name per synset, else the id."""
    root = Path(path)
    synsets = _shapenet_synsets(root)
    names = {}
    taxonomy = root / "taxonomy.json"
    if taxonomy.is_file():
        entries = load_json(taxonomy, error=CorpusError)
        try:
            names = {e["synsetId"]: e["name"].split(",")[0].strip() for e in entries}
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise CorpusError(f"{taxonomy}: unreadable taxonomy ({exc})") from None
    return [names.get(s.name, s.name) for s in synsets]


def load_shapenet(
    path: str | Path,
    max_faces: int = 800,
    limit: int | None = None,
    seed: int = 0,
    progress: bool = False,
) -> list[Mesh]:
    """Meshes ``(vertices, faces, class_index)`` of a local ShapeNetCore v2 directory.

    Class indices follow ``shapenet_class_names(path)`` (synset ids in sorted order). With
    ``limit``, a ``seed``-chosen random subset of at most ``limit`` readable models is loaded,
    returned in directory order (without ``limit`` every model is loaded and ``seed`` is
    unused). Unreadable models are skipped and counted in one warning.
    """
    _check_max_faces(max_faces, MIN_FACES)
    if limit is not None and limit < 1:
        raise ValueError(f"limit must be positive or None, got {limit}")
    root = Path(path)
    synsets = _shapenet_synsets(root)
    models = [
        (c, obj)
        for c, s in enumerate(synsets)
        for obj in sorted(s.glob(f"*/{SHAPENET_MODEL.as_posix()}"))
    ]
    order = (
        np.random.default_rng(seed).permutation(len(models))
        if limit is not None
        else np.arange(len(models))
    )
    loaded: dict[int, Mesh] = {}
    unreadable = degenerate = 0
    for k in tqdm(order, desc="ShapeNet", unit="model", disable=not progress):
        if limit is not None and len(loaded) >= limit:
            break
        cls, obj = models[k]
        try:
            v, f = weld(*read_obj(obj), decimals=WELD_DECIMALS)
        except (OSError, ValueError):
            unreadable += 1
            continue
        try:
            v, f = simplify_to(v, f, max_faces)
            loaded[int(k)] = (normalize_mesh(v), f, cls)
        except ValueError:  # decimation stalled above budget, or the mesh is flat to a point
            degenerate += 1
    if unreadable or degenerate:
        warnings.warn(
            f"{root}: skipped {unreadable + degenerate} ShapeNet model(s): {unreadable} "
            f"unreadable, "
            f"{degenerate} degenerate or not reducible to {max_faces} faces",
            stacklevel=2,
        )
    if not loaded:
        raise CorpusError(f"{root}: no usable ShapeNet model")
    return [loaded[k] for k in sorted(loaded)]
