"""Reference rows every table shows: what a model must beat before its numbers mean anything.

Four zero-parameter predictors, fitted on the training split only and scored through the
same ``Scorer`` as any model (so the same floor, intervals and no-skill rule apply):

* ``train-mean``: the mean training target, for every mesh (the no-skill baseline);
* ``class-mean``: the mean training target of the object's class (the class is *given*:
  how much skill the class alone explains);
* ``nearest-scale``: the mean target of the ``K_NEAREST`` training objects nearest in log
  scale (sees the scale, never the mesh: Variation MSE 0);
* ``class-scale-nn``: the class inferred from each mesh (``MeshClassifier``), then the mean
  target of the ``K_NEAREST`` training objects of that class nearest in log scale.

They are scored on the out-of-distribution meshes too; only ``class-scale-nn`` reads the mesh,
so only it can be fooled there (a remeshed cube whose class is read wrong).

K_NEAREST = 3 because a reference should be the strongest cheap bar, not a strawman: on the
small preset's dataset (180 objects, 18 test) one neighbour gives Complex MSE 120.7
(scale) / 69.1 (class + scale), three give 63.9 / 47.5, five 61.7 / 50.4.

A model's ``skill`` is reported against the strongest reference (lowest Complex MSE, else
Simple MSE) and against ``class-mean``, as paired differences over the same test objects.
"""

from __future__ import annotations

import numpy as np

from basic_shapes.shards import ood_remesher
from benchmark.scoring.data import BenchmarkData
from benchmark.scoring.mesh_features import normal_descriptor
from benchmark.scoring.metrics import METRIC_NAMES, Scorer, metric_block, per_remesher, skill_test
from benchmark.scoring.schema import REFERENCE_NAMES
from benchmark.scoring.uncertainty import paired, verdict

REFERENCES = REFERENCE_NAMES  # the names' owner is the schema (the rows results may carry)
K_NEAREST = 3


class MeshClassifier:
    """1-nearest-neighbour (L1) on ``normal_descriptor`` (``benchmark.scoring.mesh_features``)
    of the training objects' simple meshes."""

    def __init__(self, descriptors: np.ndarray, classes: np.ndarray):
        self.descriptors, self.classes = np.asarray(descriptors), np.asarray(classes)

    @classmethod
    def fit(cls, data: BenchmarkData, objects: np.ndarray) -> MeshClassifier:
        desc = [normal_descriptor(*data.mesh(int(data.meshes_of(o)[0]))) for o in objects]
        return cls(np.stack(desc), data.objects["class_index"][objects])

    def predict(self, vertices: np.ndarray, faces: np.ndarray) -> int:
        d = np.abs(self.descriptors - normal_descriptor(vertices, faces)).sum(axis=1)
        return int(self.classes[int(np.argmin(d))])


class References:
    """The four reference predictors of one dataset, fitted on its training split."""

    def __init__(self, data: BenchmarkData):
        self.data = data
        self.train = data.object_rows("train")
        if not len(self.train):
            raise ValueError(f"{data.directory}: no training objects to fit references on")
        cls = data.objects["class_index"][self.train]
        self.train_class = cls
        self.log_scale = np.log(data.objects["scale"][self.train].astype(np.float64))
        total = None
        by_class: dict[int, np.ndarray] = {}
        for o, c in zip(self.train, cls):
            t = data.target(int(o)).astype(np.float64)
            total = t if total is None else total + t
            by_class[int(c)] = by_class.get(int(c), 0.0) + t
        self.mean = total / len(self.train)
        counts = np.bincount(cls, minlength=len(data.class_names))
        self.class_mean = {c: s / counts[c] for c, s in by_class.items()}
        self.classifier = MeshClassifier.fit(data, self.train)
        self._targets: dict[int, np.ndarray] = {}

    def _target(self, obj: int) -> np.ndarray:
        if obj not in self._targets:
            self._targets[obj] = self.data.target(obj)
        return self._targets[obj]

    def nearest(self, obj: int, class_index: int | None = None) -> np.ndarray:
        """The ``K_NEAREST`` training objects nearest to test object ``obj`` in log scale (of a
        class, if given; ties broken by row order)."""
        pool = (
            np.arange(len(self.train))
            if class_index is None
            else np.flatnonzero(self.train_class == class_index)
        )
        if not len(pool):
            pool = np.arange(len(self.train))
        x = np.log(self.data.objects["scale"][obj].astype(np.float64))
        d = np.linalg.norm(self.log_scale[pool] - x, axis=1)
        return self.train[pool[np.argsort(d, kind="stable")[:K_NEAREST]]]

    def _mean_target(self, objects: np.ndarray) -> np.ndarray:
        return np.mean([self._target(int(o)).astype(np.float64) for o in objects], axis=0)

    def predictions(self, obj: int) -> dict[str, np.ndarray]:
        """Each reference's predictions (n_meshes, *target_shape) for test object ``obj``: its
        regular meshes (``meshes_of``), then its OOD meshes (``ood_meshes_of``)."""
        rows = np.concatenate([self.data.meshes_of(obj), self.data.ood_meshes_of(obj)])
        c = int(self.data.objects["class_index"][obj])
        n = len(rows)
        scale_nn = self._mean_target(self.nearest(obj))
        inferred = [self.classifier.predict(*self.data.mesh(int(r))) for r in rows]
        class_nn = {k: self._mean_target(self.nearest(obj, k)) for k in set(inferred)}
        shape = (n, *self.mean.shape)
        return {
            "train-mean": np.broadcast_to(self.mean, shape),
            "class-mean": np.broadcast_to(self.class_mean.get(c, self.mean), shape),
            "nearest-scale": np.broadcast_to(scale_nn, (n, *scale_nn.shape)),
            "class-scale-nn": np.stack([class_nn[k] for k in inferred]),
        }

    def score(self) -> dict[str, Scorer]:
        """A filled ``Scorer`` per reference, over the test split."""
        scorers = {name: Scorer(self.data.class_names, self.mean) for name in REFERENCES}
        for obj in self.data.test_objects():
            target = self.data.target(int(obj))
            c, oid = int(self.data.objects["class_index"][obj]), int(self.data.objects["id"][obj])
            n = len(self.data.meshes_of(int(obj)))
            ood = self.data.ood_meshes_of(int(obj))
            remeshers = [ood_remesher(v) for v in self.data.meshes["variant"][ood]]
            for name, pred in self.predictions(int(obj)).items():
                scorers[name].add(
                    c, target, pred[0], pred[1:n], oid, ood=pred[n:], ood_remeshers=remeshers
                )
        return scorers


_CACHE: dict[tuple, tuple[np.ndarray, dict]] = {}


def reference_scores(data: BenchmarkData) -> tuple[np.ndarray, dict[str, Scorer]]:
    """(training mean, reference scorers) of a dataset, computed once per process."""
    key = (str(data.directory.resolve()), data.fingerprint)
    if key not in _CACHE:
        refs = References(data)
        _CACHE[key] = (refs.mean, refs.score())
    return _CACHE[key]


def summary(scorer: Scorer) -> dict:
    """A reference's row: the metrics with intervals (OOD ones included, also per remesher)
    and its no-skill flag, overall only."""
    po = scorer.per_object()
    return {
        **metric_block(po, po["class_index"]),
        "no_skill": skill_test(po, po["class_index"])["no_skill"],
        "per_remesher": per_remesher(po, po["class_index"]),
    }


def strongest(rows: dict[str, dict]) -> str:
    """The reference with the lowest Complex MSE (Simple MSE when there is none)."""
    complete = all(r["complex_mse"] is not None for r in rows.values())
    key = "complex_mse" if complete else "simple_mse"
    return min(rows, key=lambda name: (rows[name][key], REFERENCES.index(name)))


def compare(model_po: dict, ref_po: dict) -> dict:
    """Paired model - reference difference per metric, with interval, verdict and
    skill = 1 - MSE_model / MSE_reference (the objects must be the same, in the same order)."""
    if not np.array_equal(model_po["object_id"], ref_po["object_id"]):
        raise ValueError("model and reference were scored on different test objects")
    out = {}
    for m in METRIC_NAMES[:2]:
        p = paired(model_po[m], ref_po[m], model_po["class_index"])
        if p is None:
            continue
        ref = float(np.nanmean(ref_po[m]))
        out[m] = {
            **p,
            "skill": 1.0 - float(np.nanmean(model_po[m])) / ref if ref > 0 else None,
            "verdict": verdict(p["ci"]),
        }
    return out


def skill(model_po: dict, scorers: dict[str, Scorer], rows: dict[str, dict]) -> dict:
    """The ``skill`` block: against the strongest reference and against the class mean."""
    best = strongest(rows)
    vs_best = compare(model_po, scorers[best].per_object())
    vs_class = compare(model_po, scorers["class-mean"].per_object())
    key = "complex_mse" if "complex_mse" in vs_class else "simple_mse"
    return {
        "reference": best,
        "vs_reference": vs_best,
        "vs_class_mean": vs_class,
        "explained_by_class": vs_class[key]["verdict"] != "holds",
    }


def hidden_parameters(data: BenchmarkData) -> tuple[list[str], np.ndarray]:
    """(names, values (n_objects, n_names)) of the objects' hidden shape parameters, from each
    shard's ``/objects/params`` (0 where an object lacks one; no names on Basic Shapes)."""
    params = data.object_params()
    keys = sorted({k for p in params for k in p})
    values = np.array([[p.get(k, 0.0) for k in keys] for p in params], np.float64)
    return keys, values.reshape(len(params), len(keys))


class OracleReference:
    """The hidden-parameter track's upper bar: the mean target of the ``K_NEAREST`` training
    objects of the same class nearest in (log scale, hidden shape parameters), each feature
    divided by its spread over the training objects of that class (a family's parameter is
    not diluted by the zeros of another family's objects). It knows what the mesh must reveal, so
    the gap between it and ``class-scale-nn`` is what reading the mesh can win; on Basic Shapes
    (no hidden parameters) it is ``class-scale-nn`` with the true class."""

    def __init__(self, refs: References):
        self.refs, objects = refs, refs.data.objects
        keys, hidden = hidden_parameters(refs.data)
        features = np.concatenate([np.log(objects["scale"].astype(np.float64)), hidden], axis=1)
        for c in np.unique(objects["class_index"]):
            spread = features[refs.train[refs.train_class == c]].std(axis=0)
            rows = objects["class_index"] == c
            features[rows] /= np.where(spread > 0, spread, 1.0)
        self.features, self.keys = features, keys

    def nearest(self, obj: int) -> np.ndarray:
        train = self.refs.train
        pool = train[self.refs.train_class == self.refs.data.objects["class_index"][obj]]
        d = np.linalg.norm(self.features[pool] - self.features[obj], axis=1)
        return pool[np.argsort(d, kind="stable")[:K_NEAREST]]

    def score(self) -> Scorer:
        """A filled ``Scorer`` over the test split (one prediction for every mesh, the OOD
        meshes included)."""
        data, refs = self.refs.data, self.refs
        scorer = Scorer(data.class_names, refs.mean)
        for obj in data.test_objects():
            pred = refs._mean_target(self.nearest(int(obj)))
            n = len(data.meshes_of(int(obj)))
            ood = data.ood_meshes_of(int(obj))
            c, oid = int(data.objects["class_index"][obj]), int(data.objects["id"][obj])
            scorer.add(
                c,
                data.target(int(obj)),
                pred,
                np.broadcast_to(pred, (n - 1, *pred.shape)),
                oid,
                ood=np.broadcast_to(pred, (len(ood), *pred.shape)),
                ood_remeshers=[ood_remesher(v) for v in data.meshes["variant"][ood]],
            )
        return scorer


def oracle_row(data: BenchmarkData, scorers: dict[str, Scorer]) -> dict | None:
    """The table's ``oracle`` block on a dataset with hidden shape parameters (None on one
    without): its row, the parameters it knows, and the paired oracle - ``class-scale-nn``
    difference, what a neighbour search gains from knowing them. Kept apart from the
    references: it is not a model (it is told what the mesh must reveal), so skill is never
    measured against it."""
    if not hidden_parameters(data)[0]:
        return None
    oracle = OracleReference(References(data))
    scorer = oracle.score()
    return {
        **summary(scorer),
        "hidden": oracle.keys,
        "vs_class_scale_nn": compare(scorer.per_object(), scorers["class-scale-nn"].per_object()),
    }
