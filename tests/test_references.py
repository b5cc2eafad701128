"""Reference rows: the mesh classifier on real generated meshes, and the predictors by hand."""

import numpy as np
import pytest
import trimesh

from basic_shapes.generate import GenerateConfig, generate
from basic_shapes.shards import is_ood_variant, iter_objects
from benchmark.scoring.data import BenchmarkData
from benchmark.scoring.references import MeshClassifier, References, normal_descriptor, strongest
from benchmark_fixture import make_dataset

CLASSES = ("cube", "cylinder", "sphere", "cone", "torus")


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    """Real Blender meshes of every primitive: 8 objects per class, simple + 4 variants."""
    out = tmp_path_factory.mktemp("gen")
    generate(
        out,
        GenerateConfig(classes=CLASSES, objects_per_class=8, variants=4, seed=11),
        workers=0,
        progress=False,
    )
    return out


@pytest.mark.slow  # minutes of real training / real Blender meshes: CI's slow set
def test_class_from_normals_on_real_meshes_of_every_variant(generated):
    objs = list(iter_objects(generated))
    train = [(o, m) for k, (_, o, m) in enumerate(objs) if k % 2 == 0]
    held = [(o, m) for k, (_, o, m) in enumerate(objs) if k % 2 == 1]
    clf = MeshClassifier(
        np.stack([normal_descriptor(m[0][1], m[0][2]) for _, m in train]),
        np.array([CLASSES.index(o["class"]) for o, _ in train]),
    )
    right = {False: [], True: []}  # OOD mesh? -> hits
    for o, meshes in held:  # held-out objects, every variant (remeshed, cut, decimated)
        for variant, v, f in meshes:
            right[bool(is_ood_variant(variant))].append(
                clf.predict(v, f) == CLASSES.index(o["class"])
            )
    assert len(right[False]) == 100 and np.mean(right[False]) >= 0.97, np.mean(right[False])
    # meshes from remeshers the reference never saw: it degrades (12 of these 18 right when
    # measured; the reason the reference rows are scored on OOD meshes too), but stays far
    # above chance (1/5)
    print(
        "class from the mesh, accuracy regular / OOD:", np.mean(right[False]), np.mean(right[True])
    )
    assert len(right[True]) == 18 and np.mean(right[True]) >= 0.5, np.mean(right[True])


def test_descriptor_by_hand():
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    d = normal_descriptor(box.vertices, box.faces)
    assert list(d[:4]) == [1.0, 0.0, 0.0, 0.0]  # all area along an axis; convex
    # |n_x| histogram: faces facing x hold 2*6/22 of the area (last bin), the rest 0 (first)
    assert d[4] == pytest.approx(0.1 * 10 / 22) and d[9] == pytest.approx(0.1 * 12 / 22)
    cyl = trimesh.creation.cylinder(radius=0.5, height=2.0, sections=64)
    cyl.apply_scale((1.0, 2.0, 1.0))  # elliptic: the side still faces exactly across z
    d = normal_descriptor(cyl.vertices, cyl.faces)
    assert d[0] + d[1] == pytest.approx(1.0) and d[2] == pytest.approx(0.0, abs=1e-9)
    caps = 2 * np.pi * 0.5 * 1.0 / cyl.area  # two elliptic caps, plus the 4 side facets that
    assert caps < d[0] < caps + 4 * (2 * np.pi * 1.0 / 64) * 2.0 / cyl.area  # face x or y
    cone = trimesh.creation.cone(radius=0.5, height=1.0, sections=64)
    cone.apply_scale((1.0, 1.5, 1.0))
    d = normal_descriptor(cone.vertices, cone.faces)
    assert d[1] == 0.0 and d[2] < 0.1  # n_z nearly a function of the azimuth: a ruled side
    sphere = trimesh.creation.icosphere(subdivisions=3)
    assert normal_descriptor(sphere.vertices, sphere.faces)[2] == 0.5  # saturated spread
    torus = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3)
    assert normal_descriptor(torus.vertices, torus.faces)[3] > 3 * 0.2  # inner side faces in


def test_reference_predictions_by_hand(tmp_path):
    with BenchmarkData(make_dataset(tmp_path / "d", objects_per_class=5)) as data:
        refs = References(data)
        train = data.object_rows("train")
        targets = np.stack([data.target(o).astype(np.float64) for o in train])
        np.testing.assert_allclose(refs.mean, targets.mean(axis=0), rtol=1e-12)
        for obj in data.object_rows("test"):
            c = data.objects["class_index"][obj]
            p = refs.predictions(int(obj))
            same = train[data.objects["class_index"][train] == c]
            np.testing.assert_allclose(
                p["class-mean"][0], np.mean([data.target(o) for o in same], 0), rtol=1e-6
            )
            log_scale = np.log(data.objects["scale"])
            d = np.linalg.norm(log_scale[train] - log_scale[obj], axis=1)
            near = train[np.argsort(d, kind="stable")[:3]]
            np.testing.assert_allclose(
                p["nearest-scale"][0], np.mean([data.target(o) for o in near], 0), rtol=1e-6
            )
            # the fixture's meshes are boxes, cylinders and icospheres: the class is read right
            dc = np.where(data.objects["class_index"][train] == c, d, np.inf)
            near = train[np.argsort(dc, kind="stable")[:3]]
            expected = np.mean([data.target(o) for o in near], 0)
            np.testing.assert_allclose(
                p["class-scale-nn"], np.broadcast_to(expected, p["class-scale-nn"].shape), rtol=1e-6
            )


def test_strongest_reference_is_the_lowest_complex_mse():
    rows = {
        "train-mean": {"simple_mse": 5.0, "complex_mse": 9.0},
        "class-mean": {"simple_mse": 1.0, "complex_mse": 7.0},
        "nearest-scale": {"simple_mse": 3.0, "complex_mse": 3.0},
    }
    assert strongest(rows) == "nearest-scale"
    rows["nearest-scale"]["complex_mse"] = None
    assert strongest(rows) == "class-mean"
