"""The hidden-parameter track: the frustum, whose top/base radius ratio class + scale cannot tell.

Checked against closed forms that share no code with basic_shapes.analytic: the volume and
lateral area of a frustum, and the distance to a circular frustum as the distance to its
profile polyline in the meridian half-plane.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import radar_sim
from basic_shapes import analytic
from basic_shapes.analytic import hidden_params
from basic_shapes.generate import GenerateConfig, generate, plan_objects
from basic_shapes.shards import Shard, content_fingerprint, list_shards
from benchmark.scoring.data import db_target


def stored_simple_meshes(directory):
    """(object id, stored hidden parameters, extents, simple-mesh vertices (float64)) of every
    object of a generated dataset, read from the raw shard arrays."""
    for path in list_shards(directory):
        with Shard(path) as s:
            f = s.file
            for k, oid in enumerate(f["objects/id"][()]):
                row = np.flatnonzero(
                    (f["meshes/object_index"][()] == k) & (f["meshes/variant"][()] == 0)
                )[0]
                yield (
                    int(oid),
                    json.loads(f["objects/params"][k]),
                    f["objects/scale"][k].astype(np.float64),
                    s.mesh(int(row))[0].astype(np.float64),
                )


def frustum(scale, ratio):
    return analytic.solid_for("frustum", scale, {"top_ratio": ratio})


def profile_distance(points, radius, half_height, ratio):
    """Distance to a circular frustum: to the polyline (0, -c) (R, -c) (rR, c) (0, c) in the
    (rho, z) half-plane, point-segment distance by hand."""
    q = np.column_stack([np.hypot(points[:, 0], points[:, 1]), points[:, 2]])
    c = half_height
    corners = np.array([[0.0, -c], [radius, -c], [ratio * radius, c], [0.0, c]])
    best = np.full(len(q), np.inf)
    for a, b in zip(corners[:-1], corners[1:]):
        e = b - a
        if not e.any():  # a cone's top edge
            continue
        w = np.clip(((q - a) @ e) / (e @ e), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(q - (a + w[:, None] * e), axis=1))
    return best


def mesh_volume_area(v, f):
    t = v[f]
    cross = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    volume = np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0
    return volume, cross, t


@pytest.mark.parametrize("ratio", [0.0, 0.3, 0.9])
def test_simulation_mesh_volume_and_area_against_closed_form(ratio):
    a, b, c = 0.35, 0.2, 0.3
    v, f = analytic.simulation_mesh(frustum((2 * a, 2 * b, 2 * c), ratio), 12e9)
    volume, _, _ = mesh_volume_area(v, f)
    exact = 2 * c * math.pi * a * b * (1 + ratio + ratio**2) / 3
    assert exact * 0.995 <= volume <= exact  # inscribed: below, by the polygon's sagitta
    # circular: the lateral area (side faces, not horizontal) is pi (R + r) slant
    r0 = 0.3
    v, f = analytic.simulation_mesh(frustum((2 * r0, 2 * r0, 2 * c), ratio), 12e9)
    _, cross, _ = mesh_volume_area(v, f)
    side = np.abs(cross[:, 2]) < 0.999 * np.linalg.norm(cross, axis=1)
    lateral = np.linalg.norm(cross[side], axis=1).sum() / 2
    exact = math.pi * r0 * (1 + ratio) * math.hypot(r0 * (1 - ratio), 2 * c)
    assert exact * 0.995 <= lateral <= exact


@pytest.mark.parametrize("ratio", [0.0, 0.45, 0.9])
def test_surface_distance_is_the_profile_distance(ratio):
    radius, c = 0.4, 0.25
    rng = np.random.default_rng(1)
    p = rng.uniform(-0.7, 0.7, (3000, 3)) * [1, 1, 0.8]
    exact = profile_distance(p, radius, c, ratio)
    got = analytic.surface_distance(frustum((2 * radius, 2 * radius, 2 * c), ratio), p)
    assert np.max(np.abs(got - exact)) < 1e-9


def test_surface_samples_lie_on_the_surface_and_cover_it():
    radius, c, ratio = 0.4, 0.25, 0.6
    solid = frustum((2 * radius, 2 * radius, 2 * c), ratio)
    s = analytic.surface_samples(solid, 0.01)
    assert np.max(profile_distance(s, radius, c, ratio)) < 1e-12
    # every part of the surface is near a sample: the top cap's rim and centre too
    from scipy.spatial import cKDTree

    probes = np.array(
        [
            [ratio * radius, 0, c],
            [0, 0, c],
            [0, 0, -c],
            [radius, 0, -c],
            [0, (1 + ratio) / 2 * radius, 0.0],
        ]
    )
    assert np.max(cKDTree(s).query(probes)[0]) < 0.01


def test_elliptic_distance_is_below_the_nearest_dense_sample():
    """Unsigned distance never exceeds the distance to a surface point, and a dense sample
    is within its spacing of the closest point."""
    solid = frustum((0.4, 0.9, 0.6), 0.35)
    s = analytic.surface_samples(solid, 0.003)
    p = np.random.default_rng(2).uniform(-0.6, 0.6, (1500, 3))
    from scipy.spatial import cKDTree

    nn = cKDTree(s).query(p)[0]
    d = analytic.surface_distance(solid, p)
    assert np.all(d <= nn + 1e-12)
    assert np.all(nn - d < 0.003)


def test_params_are_validated():
    with pytest.raises(ValueError, match="top_ratio"):
        analytic.solid_for("frustum", (1, 1, 1))
    with pytest.raises(ValueError, match="top_ratio must be a number in"):
        analytic.solid_for("frustum", (1, 1, 1), {"top_ratio": 0.95})
    with pytest.raises(ValueError, match="shape parameters must be none"):
        analytic.solid_for("cone", (1, 1, 1), {"top_ratio": 0.5})


def test_params_are_drawn_deterministically_from_the_object_seed():
    cfg = GenerateConfig(classes=("cube", "frustum"), objects_per_class=40, variants=1)
    plans, again = plan_objects(cfg), plan_objects(cfg)
    assert [p.params for p in plans] == [p.params for p in again]
    ratios = np.array([p.params["top_ratio"] for p in plans if p.class_name == "frustum"])
    assert all(p.params == {} for p in plans if p.class_name == "cube")
    assert np.all((ratios >= 0) & (ratios <= 0.9)) and len(set(ratios)) == len(ratios)
    assert ratios.max() - ratios.min() > 0.6  # spread over the interval
    p = plans[-1]
    assert hidden_params("frustum", p.seed) == p.params  # the seed alone fixes it


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    out = tmp_path_factory.mktemp("hidden")
    generate(
        out,
        GenerateConfig(
            classes=("frustum",),
            objects_per_class=3,
            variants=3,
            test_fraction=0.34,
            val_fraction=0.0,
        ),
        workers=0,
        progress=False,
    )
    return out


def test_generated_objects_store_their_drawn_ratio(generated):
    """/objects/params holds the planned ratio, and the simple mesh's top rim (normalised per
    axis) has that radius: the mesh shows what class + scale cannot."""
    plans = {
        p.id: p
        for p in plan_objects(
            GenerateConfig(
                classes=("frustum",),
                objects_per_class=3,
                variants=3,
                test_fraction=0.34,
                val_fraction=0.0,
            )
        )
    }
    seen = 0
    for oid, params, scale, v in stored_simple_meshes(generated):
        assert params == plans[oid].params
        top = v[np.isclose(v[:, 2], scale[2] / 2, atol=1e-6)]
        rim = 2 * np.max(np.hypot(top[:, 0] / scale[0], top[:, 1] / scale[1]))
        assert abs(rim - params["top_ratio"]) < 1e-5
        seen += 1
    assert seen == 3


def test_blender_meshes_lie_on_their_frustum_not_another():
    """Simple and complex meshes of a circular frustum are within their primitive tolerance
    of the profile of their own ratio, and measurably off the profile of a nearby ratio."""
    from basic_shapes.blender import object_meshes
    from basic_shapes.verify import primitive_tolerance

    scale = np.array([0.6, 0.6, 0.5])
    meshes = object_meshes("frustum", scale, 7, 6, {"top_ratio": 0.5})
    diagonal = float(np.linalg.norm(scale))
    for m in meshes:
        v = m.vertices.astype(np.float64)
        bound = primitive_tolerance("frustum", m.params) * diagonal
        assert profile_distance(v, 0.3, 0.25, 0.5).max() <= bound
        assert profile_distance(v, 0.3, 0.25, 0.4).max() > 2 * bound


@pytest.mark.parametrize(
    "kind, key, values",
    [("frustum", "top_ratio", (0.1, 0.8)), ("roundbox", "round_ratio", (0.1, 0.4))],
)
def test_labels_depend_on_the_hidden_parameter_by_a_margin(kind, key, values):
    """Two objects of one hidden family with the same extents and two values of its hidden
    parameter: their labels differ by far more than either label's own discretisation error
    (the rule against twice its resolution)."""
    config = radar_sim.RadarConfig(name="test-hidden", n_aspect=7, n_roll=3)
    scale = (0.5, 0.4, 0.6)

    def label(value, refinement=1.0):
        solid = analytic.solid_for(kind, scale, {key: value})
        v, f = analytic.simulation_mesh(solid, config.f_stop_hz, refinement=refinement)
        return db_target(radar_sim.simulate(v, f, config).range_profiles).astype(np.float64)

    low, high = label(values[0]), label(values[1])
    between = float(np.mean((low - high) ** 2))
    own = max(float(np.mean((x - label(r, 2.0)) ** 2)) for x, r in zip((low, high), values))
    assert between > 20.0 and between > 50 * own


def test_oracle_picks_neighbours_by_scale_and_hidden_parameter(tmp_path):
    """OracleReference by hand on the benchmark fixture with a made-up hidden parameter written
    into /objects/params: nearest same-class training objects in (log scale, parameter), each
    feature divided by its spread over the training objects of the class."""
    import h5py

    from benchmark.scoring.data import BenchmarkData
    from benchmark.scoring.references import OracleReference, References
    from benchmark_fixture import make_dataset

    directory = make_dataset(tmp_path / "d", objects_per_class=6)
    rng = np.random.default_rng(5)
    for path in list_shards(directory):
        with h5py.File(path, "r+") as f:
            n = len(f["objects/id"])
            f["objects/params"][...] = [
                json.dumps({"top_ratio": float(x)}) for x in rng.uniform(0, 0.9, n)
            ]
    with BenchmarkData(directory) as data:
        oracle = OracleReference(References(data))
        assert oracle.keys == ["top_ratio"]
        ratio = np.array(
            [
                json.loads(data._shard(int(s)).file["objects/params"][int(r)])["top_ratio"]
                for s, r in zip(data.objects["shard"], data.objects["row"])
            ]
        )
        x = np.column_stack([np.log(data.objects["scale"]), ratio])
        train = data.object_rows("train")
        cls = data.objects["class_index"]
        for c in np.unique(cls):
            x[cls == c] /= x[train[cls[train] == c]].std(axis=0)
        scorer = oracle.score()
        for k, obj in enumerate(data.test_objects()):
            same = train[cls[train] == cls[obj]]
            near = same[np.argsort(np.linalg.norm(x[same] - x[obj], axis=1))[:3]]
            assert sorted(oracle.nearest(int(obj))) == sorted(near)
            pred = np.mean([data.target(int(o)) for o in near], axis=0)
            target = data.target(int(obj)).astype(np.float64)
            expected = np.mean((np.maximum(pred, -80.0) - target) ** 2)
            assert scorer.per_object()["simple_mse"][k] == pytest.approx(expected, rel=1e-5)


def test_report_table_shows_the_oracle_only_with_hidden_parameters(tmp_path):
    """The table's oracle block: absent on a dataset without hidden parameters; with them,
    the OracleReference's own Simple MSE, its paired difference to class-scale-nn computed
    here from the two per-object error arrays, a row in table.md, and never the reference
    that skill is measured against."""
    import h5py

    from benchmark.reproduction import report
    from benchmark.scoring.data import BenchmarkData
    from benchmark.scoring.references import OracleReference, References
    from benchmark_fixture import make_dataset

    directory = make_dataset(tmp_path / "d", objects_per_class=6)
    with BenchmarkData(directory) as data:
        assert report.reference_rows(data)[2] is None
    rng = np.random.default_rng(7)
    for path in list_shards(directory):
        with h5py.File(path, "r+") as f:
            f["objects/params"][...] = [
                json.dumps({"top_ratio": float(x)})
                for x in rng.uniform(0, 0.9, len(f["objects/id"]))
            ]
            f.attrs["fingerprint"] = content_fingerprint(f)  # a new dataset, not an edit
    with BenchmarkData(directory) as data:
        scorers, rows, oracle = report.reference_rows(data)
        own = OracleReference(References(data)).score().per_object()
    assert oracle["hidden"] == ["top_ratio"] and "oracle" not in rows
    assert oracle["simple_mse"] == pytest.approx(float(np.mean(own["simple_mse"])))
    diff = own["simple_mse"] - scorers["class-scale-nn"].per_object()["simple_mse"]
    assert oracle["vs_class_scale_nn"]["simple_mse"]["diff"] == pytest.approx(diff.mean())
    table = report.build_table(
        "tiny",
        [0],
        {},
        {"fingerprint": "f", "description": "d"},
        scorers,
        rows,
        {"command": "c", "hardware": None, "python": "3", "timing": None},
        oracle,
    )
    text = report.render_markdown(table)
    assert "| oracle | " in text and "`top_ratio`" in text
    assert table["strongest_reference"] != "oracle"
