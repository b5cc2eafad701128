"""The baseline models: features, adjacency, ragged batching, the VQ codebook, invariance."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
import trimesh

from basic_shapes.geometry import fibonacci_directions
from benchmark.scoring.mesh_features import N_POINTS
from benchmark.training.models import (
    EMBEDDINGS,
    FACE_EMBEDDINGS,
    REGISTRY,
    build_model,
    collate,
    featurize,
)
from benchmark.training.models.features import N_BINS, OPTIONAL, face_adjacency, face_geometry
from benchmark.training.models.probes import N_RAYS, ray_probes

N_OUT = 2 * 3 * 4


def normalized(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    v = mesh.vertices - (mesh.vertices.min(0) + mesh.vertices.max(0)) / 2
    return (v / np.ptp(mesh.vertices, axis=0).max()).astype(np.float32), mesh.faces.astype(np.int64)


def ragged_meshes() -> list[tuple[np.ndarray, np.ndarray]]:
    return [
        normalized(m)
        for m in (
            trimesh.creation.box(extents=(1.0, 0.5, 0.3)),
            trimesh.creation.icosphere(subdivisions=2),
            trimesh.creation.cylinder(radius=0.4, height=1.0, sections=12),
        )
    ]


def resplit(vertices, faces, n, seed):
    """Re-mesh the same surface: split ``n`` random faces at a random interior point."""
    rng = np.random.default_rng(seed)
    v, f = [np.asarray(x, np.float64) for x in vertices], [tuple(x) for x in faces]
    for _ in range(n):
        a, b, c = f.pop(int(rng.integers(len(f))))
        w = rng.dirichlet([1, 1, 1])
        v.append(w[0] * v[a] + w[1] * v[b] + w[2] * v[c])
        i = len(v) - 1
        f += [(a, b, i), (b, c, i), (c, a, i)]
    return np.array(v), np.array(f)


def model(name: str, seed: int = 0):
    torch.manual_seed(seed)
    return build_model(
        name,
        N_OUT,
        n_scale_bins=8,
        dim=32,
        embed_layers=2,
        agg_layers=2,
        decoder_hidden=32,
        codebook_size=16,
    ).eval()


# --- features -----------------------------------------------------------------------------
def brute_force_adjacency(faces) -> set[tuple[int, int]]:
    edges = [{frozenset(p) for p in itertools.combinations(f, 2)} for f in faces]
    return {
        (i, j)
        for i in range(len(faces))
        for j in range(len(faces))
        if i != j and edges[i] & edges[j]
    }


def test_face_adjacency_matches_brute_force_on_closed_mesh():
    mesh = trimesh.creation.icosphere(subdivisions=1)
    e = face_adjacency(mesh.faces)
    got = set(map(tuple, e.T.tolist()))
    assert got == brute_force_adjacency(mesh.faces.tolist())
    assert np.all(np.bincount(e[0], minlength=len(mesh.faces)) == 3)  # closed 2-manifold


def test_face_adjacency_non_manifold_fan_and_isolated_face():
    faces = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [5, 6, 7], [2, 1, 8]])
    got = set(map(tuple, face_adjacency(faces).T.tolist()))
    assert got == brute_force_adjacency(faces.tolist())
    assert {(0, 1), (0, 2), (1, 2), (0, 4)} <= got and not any(3 in p for p in got)


def test_direct_features_reconstruct_the_triangles():
    v, f = ragged_meshes()[2]
    feats = featurize(v, f)
    tri = feats.direct[:, :3, None] + feats.direct[:, 3:12].reshape(-1, 3, 3).transpose(0, 2, 1)
    np.testing.assert_allclose(
        np.sort(tri.transpose(0, 2, 1), axis=1), np.sort(v[f], axis=1), atol=1e-6
    )
    normal = feats.direct[:, 12:]
    np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(np.einsum("ij,ij->i", normal, v[f[:, 1]] - v[f[:, 0]]), 0, atol=1e-6)
    np.testing.assert_allclose(feats.area, trimesh.Trimesh(v, f).area_faces, rtol=1e-5)
    np.testing.assert_allclose(face_geometry(v, f)["angles"].sum(1), np.pi, atol=1e-9)


def test_discretized_tokens_of_a_known_triangle():
    # corners sorted by (z, y, x); coordinates in [-0.5, 0.5] map to floor((x + 0.5) * 128)
    v = np.array([[0.5, 0.5, 0.0], [-0.5, 0.0, 0.0], [0.0, -0.25, 0.0]], np.float32)
    tokens = featurize(v, np.array([[0, 1, 2]])).tokens[0]
    assert tokens[:9].tolist() == [64, 32, 64, 0, 64, 64, N_BINS - 1, N_BINS - 1, 64]
    angles = np.degrees(face_geometry(v, np.array([[0, 1, 2]]))["angles"][0])
    order = [2, 1, 0]  # corner order after sorting: v2 (y=-0.25), v1 (y=0), v0 (y=0.5)
    np.testing.assert_array_equal(tokens[9:12], np.floor(angles[order] / 180 * N_BINS).astype(int))
    assert tokens[13:].tolist() == [64, 64, N_BINS - 1]  # normal (0, 0, 1)
    assert tokens.min() >= 0 and tokens.max() < N_BINS


# --- encoders on ragged batches -----------------------------------------------------------
@pytest.mark.parametrize("name", EMBEDDINGS)
def test_ragged_batch_shapes_masks_and_padding_independence(name):
    meshes = ragged_meshes()
    feats = [featurize(v, f, REGISTRY[name].needs) for v, f in meshes]
    bins = np.array([[1, 2, 3], [4, 5, 6], [7, 0, 1]])
    scale = np.array([[1.0, 0.5, 0.3], [0.8, 0.8, 0.8], [0.8, 0.8, 1.0]])
    batch = collate(feats, scale_bin=bins, scale_m=scale)
    n_faces = [len(f) for _, f in meshes]
    assert batch.mask.sum(1).tolist() == n_faces and batch.direct.shape[1] == max(n_faces)
    m = model(name)
    with torch.no_grad():
        pred, _ = m(batch)
        emb, mask, _ = m.embed_faces(batch)
        alone = [
            m(collate([x], scale_bin=bins[i : i + 1], scale_m=scale[i : i + 1]))[0][0]
            for i, x in enumerate(feats)
        ]
    assert pred.shape == (3, N_OUT) and torch.isfinite(pred).all()
    if name in FACE_EMBEDDINGS:
        assert emb.shape == (3, max(n_faces), 32) and torch.equal(mask, batch.mask)
        assert emb[~mask].abs().max() == 0  # padding carries nothing
    for i in range(3):  # padding and batch neighbours change nothing
        torch.testing.assert_close(pred[i], alone[i], atol=1e-4, rtol=1e-4)


@pytest.mark.parametrize("name", FACE_EMBEDDINGS)
def test_face_order_does_not_matter(name):
    v, f = ragged_meshes()[1]
    perm = np.random.default_rng(0).permutation(len(f))
    rolled = np.roll(f[perm], 1, axis=1)  # same faces, other order, other first corner
    m = model(name)
    with torch.no_grad():
        a = m(collate([featurize(v, f)]))[0]
        b = m(collate([featurize(v, rolled)]))[0]
    torch.testing.assert_close(a, b, atol=1e-4, rtol=1e-4)


@pytest.mark.parametrize("n_layers", [1, 2])
def test_aggregator_reads_the_full_encoders_cls_row(n_layers):
    """The last layer computed for the CLS token alone is the full encoder's row 0, with
    padding, in training and in eval mode (where torch takes its fused inference path)."""
    from benchmark.training.models.aggregator import Aggregator

    torch.manual_seed(0)
    agg = Aggregator(32, n_layers, n_heads=2)
    emb = torch.randn(4, 30, 32)
    mask = torch.arange(30)[None] < torch.tensor([[30], [7], [1], [19]])
    x = torch.cat([agg.cls.expand(4, -1, -1), emb], 1)
    pad = torch.cat([mask.new_zeros(4, 1), ~mask], 1)
    for training in (True, False):
        agg.train(training)
        full = agg.norm(agg.encoder(x, src_key_padding_mask=pad)[:, 0])
        torch.testing.assert_close(agg(emb, mask), full, atol=1e-5, rtol=1e-5)


FUSED = "aten::_transformer_encoder_layer_fwd"  # torch's fused inference path


def _ops(run) -> set[str]:
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
        run()
    return {e.key for e in prof.key_averages()}


def test_aggregator_predicts_with_the_arithmetic_it_trained_with():
    """Prediction does not take torch's fused inference path, which torch takes for a bare
    layer (its full attention matrices took 62 GiB of GPU at the paper's size): eval without
    grad gives the training-mode output bit for bit, and torch's global fast-path switch is
    left as it was."""
    from benchmark.training.models.aggregator import Aggregator

    torch.manual_seed(0)
    agg = Aggregator(64, 3, n_heads=4)
    emb = torch.randn(4, 50, 64)
    mask = torch.arange(50)[None] < torch.tensor([[50], [40], [30], [20]])
    with torch.no_grad():
        trained = agg.train()(emb, mask)
        agg.eval()
        assert FUSED in _ops(lambda: agg.encoder.layers[0](emb, src_key_padding_mask=~mask))
        assert FUSED not in _ops(lambda: agg(emb, mask))
        predicted = agg(emb, mask)
    assert torch.equal(predicted, trained)
    assert torch.backends.mha.get_fastpath_enabled()


def test_graph_node_features_are_the_projected_concatenation():
    """The folded one-hot sum is the projection of the concatenated token embeddings."""
    from benchmark.training.models.features import TOKEN_GROUPS

    g = model("graph").embedding
    batch = collate([featurize(v, f) for v, f in ragged_meshes()])
    tokens = batch.tokens[batch.mask]
    starts = np.cumsum([0] + [n for _, n in TOKEN_GROUPS])
    concatenated = torch.cat(
        [
            table(tokens[:, a:b]).flatten(1)
            for table, a, b in zip(g.tables, starts[:-1], starts[1:])
        ],
        1,
    )
    torch.testing.assert_close(g.node_features(batch), g.proj(concatenated), atol=1e-5, rtol=1e-5)


def test_vq_of_the_packed_faces_is_the_masked_vq_of_the_padded_batch():
    """The token embedding quantizes the real faces as one sequence: the same codes,
    commitment loss and codebook updates as the padded batch under its mask."""
    import copy

    m = model("token").train()
    batch = collate([featurize(v, f) for v, f in ragged_meshes()])
    vq = copy.deepcopy(m.embedding.vq)
    for step in range(3):
        emb = m.embedding.graph(batch)[0].detach().requires_grad_()  # as in training: the
        torch.manual_seed(step)  # rotation trick; dead codes are re-seeded from random faces
        quantized, _, commit = m.embedding(batch)
        torch.manual_seed(step)
        q_ref, codes_ref, commit_ref = vq(emb, mask=batch.mask)
        assert torch.equal(m.embedding.last_codes[batch.mask], codes_ref[batch.mask])
        torch.testing.assert_close(commit, commit_ref.sum())
        torch.testing.assert_close(quantized[batch.mask], q_ref[batch.mask])
    for a, b in zip(m.embedding.vq.state_dict().values(), vq.state_dict().values()):
        torch.testing.assert_close(a, b)


def test_vq_codebook_is_used_and_quantizes_to_codebook_vectors():
    m = model("token")
    m.train()
    batch = collate([featurize(v, f) for v, f in ragged_meshes()])
    for _ in range(3):  # EMA codebook updates from the data
        _, commit = m(batch)
        assert commit.item() > 0  # the commitment loss reaches the training loss
    m.eval()
    with torch.no_grad():
        quantized, _, _ = m.embedding(batch)
    codes = m.embedding.last_codes
    assert codes.shape == (*batch.mask.shape, 2)
    assert (codes[~batch.mask] == -1).all() and (codes[batch.mask] >= 0).all()
    books = m.embedding.vq.codebooks  # (n_quantizers, codebook_size, dim)
    real = codes[batch.mask]
    rebuilt = books[0][real[:, 0]] + books[1][real[:, 1]]
    torch.testing.assert_close(quantized[batch.mask], rebuilt, atol=1e-5, rtol=1e-5)
    assert len(torch.unique(real[:, 0])) >= 4  # the first codebook does not collapse to one code


def test_unknown_model_name():
    with pytest.raises(ValueError, match="unknown model 'mlp'"):
        build_model("mlp", 4, 4)


# --- the invariant model ------------------------------------------------------------------
def test_ray_probes_of_a_box_and_a_sphere_against_geometry():
    d = fibonacci_directions(N_RAYS)
    half = np.array([0.5, 0.25, 0.15])
    probes = ray_probes(*normalized(trimesh.creation.box(extents=2 * half)))
    expected = np.min(half / np.maximum(np.abs(d), 1e-12), axis=1)  # exit distance of a box
    np.testing.assert_allclose(probes[:, 4], expected, rtol=1e-6)
    np.testing.assert_allclose(probes[:, 8], expected, rtol=1e-6)  # convex: near = far
    assert (probes[:, 3] == 1).all()
    axis = np.argmax(np.abs(d) / half, axis=1)  # the face a ray leaves through
    np.testing.assert_allclose(np.abs(probes[np.arange(len(d)), 5 + axis]), 1.0, atol=1e-6)
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    p = ray_probes(sphere.vertices, sphere.faces)
    inscribed = 0.5 * np.cos(np.radians(4.0))  # facets of a level-4 icosphere are < 4 deg wide
    assert (p[:, 4] <= 0.5 + 1e-9).all() and (p[:, 4] >= inscribed).all()


def test_invariant_model_same_prediction_for_two_meshings_of_a_box():
    """Exact, not statistical: the probes are properties of the surface, so a re-meshed box
    gives the same input up to float round-off (no sampling tolerance is needed). The graph
    baseline, fed the same two meshes, does see the difference."""
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    v1, f1 = box.vertices, box.faces
    v2, f2 = resplit(v1, f1, 300, seed=1)
    other = trimesh.creation.box(extents=(1.0, 0.8, 0.3))
    np.testing.assert_allclose(ray_probes(v1, f1), ray_probes(v2, f2), atol=1e-9)
    inv, graph = model("invariant"), model("graph")
    with torch.no_grad():
        a, b, c = (
            inv(collate([featurize(v, f, ("probes",))]))[0][0]
            for v, f in [(v1, f1), (v2, f2), (other.vertices, other.faces)]
        )
        ga, gb = (graph(collate([featurize(v, f)]))[0][0] for v, f in [(v1, f1), (v2, f2)])
    torch.testing.assert_close(a, b, atol=1e-5, rtol=0)
    assert (a - c).abs().max() > 100 * (a - b).abs().max() + 1e-4  # it does see shape
    assert (ga - gb).abs().max() > 1e-3  # a face-based encoder is fooled by the meshing


def test_every_registered_embedding_keeps_the_one_forward_contract():
    """(emb (B, L, dim), mask (B, L), scalar aux) from every registry entry; padding masked."""
    meshes = ragged_meshes()
    batch = collate(
        [featurize(v, f, tuple(OPTIONAL)) for v, f in meshes],
        scale_m=np.ones((3, 3)),
    )
    n_faces = [len(f) for _, f in meshes]
    for name in EMBEDDINGS:
        torch.manual_seed(0)
        model = build_model(name, N_OUT, 8, dim=16, embed_layers=1, agg_layers=1, n_heads=2)
        emb, mask, aux = model.embedding(batch)
        assert emb.shape[:2] == mask.shape and emb.shape[2] == 16 and aux.ndim == 0, name
        expected = {
            "invariant": [N_RAYS] * 3,
            "blind": [1] * 3,
            "pointcloud": [N_POINTS] * 3,
            "regressor": [1] * 3,
        }.get(name, n_faces)
        assert mask.sum(1).tolist() == expected, name


def test_blind_model_sees_the_scale_and_not_the_mesh():
    """The learned scale reference: a box and a sphere of the same scale bins get the same
    prediction; another scale changes it."""
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    sphere = trimesh.creation.icosphere(subdivisions=2)
    m = model("blind")
    bins = np.array([[1, 2, 3]])
    with torch.no_grad():
        a, b, c = (
            m(collate([featurize(mesh.vertices, mesh.faces)], scale_bin=sb))[0][0]
            for mesh, sb in [(box, bins), (sphere, bins), (box, bins + 2)]
        )
    torch.testing.assert_close(a, b, atol=0, rtol=0)
    assert (a - c).abs().max() > 1e-3
