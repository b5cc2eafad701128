"""The rows beyond the paper (issue 21): meshgraph, pointcloud, regressor.

Each learns (a tiny batch the scale cannot tell apart), trains through the real path and
exports to the ONNX contract; the surface sampler is uniform by area and deterministic; each
model has the symmetry it claims, and no more is asserted than holds.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from torch_geometric.nn import EdgeConv as PygEdgeConv

from benchmark.scoring.data import BenchmarkData
from benchmark.scoring.mesh_features import K_NEIGHBOURS, N_POINTS, point_neighbours, surface_points
from benchmark.training.models import REGISTRY, build_model, collate, featurize
from benchmark.training.models.checkpoint import save_checkpoint
from benchmark.training.onnx_export import INPUT_NAMES, export
from benchmark.training.train import TrainConfig, train
from benchmark_fixture import make_dataset
from test_models import model, normalized, ragged_meshes, resplit

NEW = ("meshgraph", "pointcloud", "regressor")
SCALE = np.array([[0.9, 0.6, 0.4]])  # one object scale for every mesh of a test
BINS = np.array([[3, 2, 1]])


def batch_of(name, meshes, scale=SCALE, bins=BINS):
    feats = [featurize(v, f, REGISTRY[name].needs) for v, f in meshes]
    n = len(meshes)
    return collate(
        feats,
        scale_bin=np.repeat(bins, n, 0),
        scale_m=np.repeat(np.asarray(scale, np.float64).reshape(1, 3), n, 0),
    )


# --- the surface sampler --------------------------------------------------------------------
def test_surface_points_are_uniform_by_area_and_deterministic():
    # face 0 in z = 0 of area 1, face 1 in x = 5 of area 3, face 2 degenerate at x = -9
    v = np.array(
        [[0, 0, 0], [2, 0, 0], [0, 1, 0], [5, 0, 0], [5, 3, 0], [5, 0, 2], [-9, 0, 0], [-9, 1, 0]],
        np.float64,
    )
    f = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 6]])
    for n in (N_POINTS, 1001):
        p = surface_points(v, f, n_points=n)
        assert p.shape == (n, 6) and p.dtype == np.float32
        on_first, on_second = p[:, 2] == 0, p[:, 0] == 5
        assert (on_first ^ on_second).all()  # none on the degenerate face
        # stratified: within 2 of n a / A (a binomial draw would be off by ~sqrt(n) / 2)
        assert abs(on_first.sum() - n / 4) < 2
        np.testing.assert_array_equal(p[on_first, 3:], np.tile([0, 0, 1], (on_first.sum(), 1)))
        np.testing.assert_array_equal(p[on_second, 3:], np.tile([1, 0, 0], (on_second.sum(), 1)))
        x, y = p[on_first, 0], p[on_first, 1]
        assert (x >= 0).all() and (y >= 0).all() and (x / 2 + y <= 1 + 1e-6).all()
    np.testing.assert_array_equal(surface_points(v, f), surface_points(v, f))  # cacheable
    assert not np.array_equal(surface_points(v, f), surface_points(v, f, seed=1))
    with pytest.raises(ValueError, match="no face of non-zero area"):
        surface_points(v, f[2:])


def test_point_neighbours_are_the_nearest():
    p = surface_points(*normalized(trimesh.creation.icosphere(subdivisions=2)))
    nb = point_neighbours(p)
    assert nb.shape == (N_POINTS, K_NEIGHBOURS) and nb.dtype == np.int64
    assert (nb[:, 0] == np.arange(N_POINTS)).all()  # itself first
    d = np.linalg.norm(p[:, None, :3].astype(np.float64) - p[None, :, :3], axis=-1)
    inside = np.take_along_axis(d, nb, 1)
    others = np.ones_like(d, bool)
    np.put_along_axis(others, nb, False, 1)
    assert (np.diff(inside, axis=1) >= 0).all()  # nearest first
    assert (inside[:, -1] <= np.where(others, d, np.inf).min(1)).all()


def test_points_are_uniform_within_a_face():
    """The four midpoint sub-triangles of one face (equal areas) get a quarter each, within
    4 binomial standard deviations: the corner a point is drawn near is not favoured."""
    a, b, c = np.array([[0.0, 0, 0], [1, 0, 0], [0.2, 0.7, 0]])
    p = surface_points(np.stack([a, b, c]), np.array([[0, 1, 2]]), n_points=4000)[:, :3]
    # barycentric coordinates (w_b, w_c) of each point; sub-triangles by the midpoints
    w = np.linalg.solve(np.stack([b - a, c - a])[:, :2].T, (p - a)[:, :2].T).T
    wa = 1 - w.sum(1)
    part = np.where(wa > 0.5, 0, np.where(w[:, 0] > 0.5, 1, np.where(w[:, 1] > 0.5, 2, 3)))
    counts = np.bincount(part, minlength=4)
    assert (np.abs(counts - 1000) < 4 * np.sqrt(4000 * 0.25 * 0.75)).all(), counts


def test_two_meshings_give_two_samples_of_one_distribution():
    """Not the same points, but the same share of points on each side of a box (within 4
    binomial standard deviations; stratification only narrows it)."""
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    meshings = [(box.vertices, box.faces), resplit(box.vertices, box.faces, 300, seed=1)]
    samples = [surface_points(v, f) for v, f in meshings]
    assert not np.allclose(samples[0], samples[1])
    side_area = np.array([0.6 * 0.4, 1.0 * 0.4, 1.0 * 0.6])
    share = np.repeat(side_area / (2 * side_area.sum()), 2)  # -x, +x, -y, +y, -z, +z
    bound = 4 * np.sqrt(N_POINTS * share * (1 - share))
    for p in samples:
        n = p[:, 3:]
        axis = np.argmax(np.abs(n), 1)
        side = 2 * axis + (n[np.arange(len(n)), axis] > 0)
        assert (np.abs(np.bincount(side, minlength=6) - N_POINTS * share) < bound).all()


# --- the models -----------------------------------------------------------------------------
@pytest.mark.parametrize("name", NEW)
def test_new_rows_learn_what_the_scale_cannot_tell(name):
    """Three shapes of one scale with different targets: the decoder's scale input cannot
    tell them apart, so the loss falls below the targets' spread only through the embedding."""
    torch.manual_seed(0)
    batch = batch_of(name, ragged_meshes())
    batch.target = 10 * torch.randn(3, 24)
    m = build_model(name, 24, 8, dim=32, embed_layers=2, agg_layers=1, decoder_hidden=64)
    m.decoder.set_output_statistics(batch.target)
    spread = float(((batch.target - batch.target.mean(0)) ** 2).mean())
    opt = torch.optim.AdamW(m.parameters(), lr=3e-3)
    for _ in range(60):
        loss = torch.nn.functional.mse_loss(m(batch)[0], batch.target)
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert loss.item() < 0.1 * spread, (loss.item(), spread)


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    return make_dataset(
        tmp_path_factory.mktemp("new"), objects_per_class=3, n_test_per_class=1, grid=(3, 2, 8)
    )


@pytest.mark.parametrize("name", NEW)
def test_new_rows_train_and_export_through_the_real_paths(name, data_dir, tmp_path):
    """`train` (features, scale and batches as reproduce makes them), then the checkpoint's
    ONNX export, checked by the exporter against ``CheckpointModel`` on its check meshes."""
    cfg = TrainConfig(
        embedding=name,
        dim=16,
        embed_layers=1,
        agg_layers=1,
        n_heads=2,
        decoder_hidden=32,
        epochs=2,
        batch_size=4,
    )
    with BenchmarkData(data_dir) as data:
        net, config = train(cfg, data, progress=False)
    assert len(config["history"]["train"]) == 2
    save_checkpoint(tmp_path / "ck", net, config)
    report = export(tmp_path / "ck", tmp_path / "m.onnx", tolerance=1e-3)
    assert report["meshes_checked"] == 3 and report["max_abs_db"] <= 1e-3
    assert set(report["inputs"]) == {*INPUT_NAMES[name], "scale_m"}


def test_meshgraph_ignores_face_order_and_is_fooled_by_the_meshing():
    v, f = ragged_meshes()[1]
    perm = np.random.default_rng(0).permutation(len(f))
    rolled = np.roll(f[perm], 1, axis=1)  # same faces, other order, other first corner
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    split = resplit(box.vertices, box.faces, 300, seed=1)
    m = model("meshgraph")
    with torch.no_grad():
        a, b = (m(batch_of("meshgraph", [mesh]))[0] for mesh in [(v, f), (v, rolled)])
        c, d = (m(batch_of("meshgraph", [mesh]))[0] for mesh in [(box.vertices, box.faces), split])
    torch.testing.assert_close(a, b, atol=1e-4, rtol=1e-4)
    assert (c - d).abs().max() > 1e-3  # its tokens are the faces


def test_pointcloud_ignores_point_order_and_its_edgeconv_is_pygs():
    m = model("pointcloud")
    batch = batch_of("pointcloud", ragged_meshes()[:2])
    shuffled = batch_of("pointcloud", ragged_meshes()[:2])
    perm = torch.randperm(N_POINTS)  # relabel the points: new point i is old point perm[i]
    shuffled.points = shuffled.points[:, perm]
    shuffled.neighbours = torch.argsort(perm)[shuffled.neighbours[:, perm]]
    with torch.no_grad():
        torch.testing.assert_close(m(batch)[0], m(shuffled)[0], atol=1e-4, rtol=1e-4)
        # the first EdgeConv layer against torch_geometric's, on the same neighbour graph
        x, neighbours = batch.points[0], batch.neighbours[0]  # (N, k): target i, sources j
        edge_index = torch.stack(
            [neighbours.flatten(), torch.arange(N_POINTS).repeat_interleave(K_NEIGHBOURS)]
        )
        conv = m.embedding.convs[0]
        pyg = PygEdgeConv(torch.nn.Sequential(conv.lin, torch.nn.LeakyReLU(0.2)), aggr="max")
        ours = conv(x[None], neighbours[None])[0]  # (pyg re-initialised the shared layer)
        theirs = pyg(x, edge_index)
    torch.testing.assert_close(ours, theirs, atol=1e-5, rtol=1e-5)


def test_regressor_reads_class_and_continuous_scale_not_the_meshing():
    """Splitting a box's faces leaves its normal descriptor and so the prediction unchanged;
    another primitive of the same scale, or another scale within the same bins, changes it."""
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    cylinder = trimesh.creation.cylinder(radius=0.5, height=1.0, sections=24)
    meshes = {
        "box": normalized(box),
        "split": resplit(*normalized(box), 300, seed=1),
        "cylinder": normalized(cylinder),
    }
    m = model("regressor")
    with torch.no_grad():
        pred = {k: m(batch_of("regressor", [mesh]))[0] for k, mesh in meshes.items()}
        wider = m(batch_of("regressor", [meshes["box"]], scale=SCALE * 1.02))[0]
    torch.testing.assert_close(pred["box"], pred["split"], atol=1e-5, rtol=0)
    assert (pred["box"] - pred["cylinder"]).abs().max() > 1e-3
    assert (pred["box"] - wider).abs().max() > 1e-4  # the same bins, another scale
