"""The model protocol, predictions files, results JSON and `benchmark evaluate`."""

import json
import subprocess
import sys
import textwrap

import h5py
import numpy as np
import pytest

from basic_shapes.shards import dataset_fingerprint, label_fingerprint
from benchmark.cli import main
from benchmark.scoring.data import BenchmarkData
from benchmark.scoring.evaluate import evaluate
from benchmark.scoring.protocol import (
    ModelError,
    NearestScaleModel,
    PredictionsError,
    ResultsError,
    load_model,
    load_results,
    score_predictions,
    write_predictions,
    write_results,
)
from benchmark_fixture import CLASSES, make_dataset

GEOMETRY_MODEL = '''
import numpy as np

class GeometryModel:
    """Depends on every input, so a mesh mixed up with another changes the metrics."""
    name = "geometry"

    def __init__(self, offset="0"):
        self.offset = float(offset)

    def predict(self, batch):
        out = []
        for v, f, bins, s in zip(batch["vertices"], batch["faces"], batch["scale_bins"],
                                 batch["scale_m"]):
            base = -30.0 + 0.37 * bins.sum() + 0.011 * len(f) + 3.3 * np.abs(v).mean() + s.prod()
            wave = np.sin(np.arange(7 * 5 * 16)).reshape(7, 5, 16)
            out.append(base + wave * s[0] * 10 + self.offset)
        return np.stack(out)
'''


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("data"))


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "geometry_model.py"
    path.write_text(GEOMETRY_MODEL)
    return path


@pytest.fixture(scope="module")
def model_run(data_dir, model_file, tmp_path_factory):
    """Results of the model path, with its predictions kept."""
    preds = tmp_path_factory.mktemp("run") / "preds.h5"
    model = load_model(f"{model_file}:GeometryModel", {"offset": "0.5"})
    return evaluate(data_dir, model=model, write_predictions=preds, progress=False), preds


def independent_metrics(data_dir, preds_path):
    """Simple/Complex/Variation MSE straight from the raw shard and predictions HDF5 files."""
    with h5py.File(preds_path) as f:
        by_uid = dict(zip(f["mesh_uid"][()].tolist(), f["target_db"][()].astype(np.float64)))
    simple, complex_, variation = [], [], []
    for path in sorted(data_dir.glob("shard-*.h5")):
        with h5py.File(path) as f:
            ids, split, resp = f["objects/id"][()], f["objects/split"][()], f["radar/response"][()]
            owner, variant = f["meshes/object_index"][()], f["meshes/variant"][()]
        for k in np.flatnonzero(split == b"test"):
            t = 20 * np.log10(np.maximum(np.abs(resp[k].astype(np.complex128)), 1e-4)).astype(
                np.float32
            )
            s = by_uid[ids[k] * 1000]
            cs = [by_uid[ids[k] * 1000 + v] for v in variant[owner == k] if v > 0]
            simple.append(np.mean((t - s) ** 2))
            complex_.append(np.mean([np.mean((t - c) ** 2) for c in cs]))
            variation.append(np.mean([np.mean((s - c) ** 2) for c in cs]))
    return np.mean(simple), np.mean(complex_), np.mean(variation)


def test_model_path_and_predictions_path_give_identical_metrics(data_dir, model_run):
    results, preds = model_run
    assert score_predictions(data_dir, preds) == results["metrics"]
    from_file = evaluate(data_dir, predictions=preds, progress=False)
    assert from_file["metrics"] == results["metrics"]
    assert from_file["model"]["name"] == "preds" and results["model"]["name"] == "geometry"
    assert results["speed"]["ms_per_mesh"] > 0 and results["speed"]["hardware"].startswith("cpu: ")
    assert from_file["speed"] == {"ms_per_mesh": None, "hardware": None, "self_reported": False}
    sp = results["speed"]
    assert sp["self_reported"] is False and sp["cpu"] in sp["hardware"] and sp["load_avg_1m"] >= 0
    assert len(results["per_object"]["object_id"]) == results["metrics"]["n_objects"]
    assert results["dataset_fingerprint"] == dataset_fingerprint(data_dir)
    assert results["label_fingerprint"] == label_fingerprint(data_dir)


def test_scores_agree_with_an_independent_computation(data_dir, model_run):
    results, preds = model_run
    simple, complex_, variation = independent_metrics(data_dir, preds)
    m = results["metrics"]
    assert m["simple_mse"] == pytest.approx(simple, rel=1e-9)
    assert m["complex_mse"] == pytest.approx(complex_, rel=1e-9)
    assert m["variation_mse"] == pytest.approx(variation, rel=1e-9)
    assert m["variation_mse"] > 0 and m["n_objects"] == 6 and m["n_meshes"] == 18
    assert set(m["per_class"]) == set(CLASSES)


def test_third_party_file_in_any_row_order_scores_the_same(data_dir, model_run, tmp_path):
    results, preds = model_run
    with h5py.File(preds) as f:
        uid, tgt = f["mesh_uid"][()], f["target_db"][()]
    perm = np.random.default_rng(0).permutation(len(uid))
    shuffled = tmp_path / "shuffled.h5"
    labels = label_fingerprint(data_dir)
    write_predictions(
        shuffled, dataset_fingerprint(data_dir), uid[perm], tgt[perm], label_fingerprint=labels
    )
    assert score_predictions(data_dir, shuffled) == results["metrics"]
    # a different prediction for one mesh changes the numbers: the check can fail
    tgt[perm[0]] += 1.0
    write_predictions(shuffled, dataset_fingerprint(data_dir), uid, tgt, label_fingerprint=labels)
    assert score_predictions(data_dir, shuffled) != results["metrics"]


def test_models_load_from_module_and_file(data_dir, model_file):
    m = load_model(
        "benchmark.scoring.protocol:NearestScaleModel", {"data_dir": str(data_dir), "k": "2"}
    )
    assert isinstance(m, NearestScaleModel) and m.k == 2
    assert load_model(f"{model_file}:GeometryModel").name == "geometry"
    for spec, problem in [
        ("nocolon", "module:Class"),
        ("benchmark.scoring.protocol:Nope", "has no Nope"),
        ("no_such_module_xyz:Model", "cannot import"),
        ("/no/file.py:Model", "no such file"),
        ("benchmark.scoring.protocol:MeanResponseModel", "constructing MeanResponseModel failed"),
        ("benchmark.scoring.protocol:PredictionsError", "has no predict"),
    ]:
        with pytest.raises(ModelError, match=problem):
            load_model(spec)


def test_reference_rows_match_the_reference_models_and_the_mean_has_no_skill(data_dir):
    kw = {"data_dir": str(data_dir)}
    mean = evaluate(
        data_dir,
        model=load_model("benchmark.scoring.protocol:MeanResponseModel", kw),
        progress=False,
    )
    near = evaluate(
        data_dir,
        model=load_model("benchmark.scoring.protocol:NearestScaleModel", kw),
        progress=False,
    )  # k = 3, as the reference
    refs = mean["metrics"]["references"]
    assert set(refs) == {"train-mean", "class-mean", "nearest-scale", "class-scale-nn"}
    for model, name in (
        (mean, "train-mean"),
        (near, "nearest-scale"),
    ):  # two code paths, one number
        for k in ("simple_mse", "complex_mse", "variation_mse"):
            assert refs[name][k] == pytest.approx(model["metrics"][k], rel=1e-5, abs=1e-6)
    assert mean["metrics"]["no_skill"] is True and refs["train-mean"]["no_skill"] is True
    assert mean["metrics"]["variation_mse"] == near["metrics"]["variation_mse"] == 0.0
    sk = mean["metrics"]["skill"]
    assert sk["reference"] in refs and isinstance(sk["explained_by_class"], bool)
    assert sk["vs_reference"]["complex_mse"]["diff"] == pytest.approx(
        mean["metrics"]["complex_mse"] - refs[sk["reference"]]["complex_mse"], rel=1e-9
    )


class BadShape:
    def predict(self, batch):
        return np.zeros((len(batch["scale_m"]), 7, 5, 15))


class Crashes:
    def predict(self, batch):
        raise RuntimeError("out of memory\nsecond line")


class NaNs:
    def predict(self, batch):
        return np.full((len(batch["scale_m"]), 7, 5, 16), np.nan)


@pytest.mark.parametrize(
    "model, problem",
    [
        (BadShape(), r"float64\(16, 7, 5, 15\), expected"),
        (Crashes(), "predict failed: RuntimeError"),
        (NaNs(), "non-finite"),
    ],
)
def test_bad_models_fail_cleanly_and_leave_no_file(data_dir, tmp_path, model, problem):
    out = tmp_path / "p.h5"
    with pytest.raises(ModelError, match=problem) as err:
        evaluate(data_dir, model=model, write_predictions=out, progress=False)
    assert "\n" not in str(err.value) and list(tmp_path.iterdir()) == []


def _rewrite(src, dst, edit):
    with h5py.File(src) as f:
        uid, tgt = f["mesh_uid"][()], f["target_db"][()]
        attrs = dict(f.attrs)
    uid, tgt, attrs = edit(uid, tgt, attrs)
    with h5py.File(dst, "w") as f:
        f.attrs.update(attrs)
        f["mesh_uid"], f["target_db"] = uid, tgt


def _with_nan(t):
    t = t.copy()
    t[3, 0, 0, 0] = np.nan
    return t


MALFORMED = {
    "wrong grid": (
        lambda u, t, a: (u, t[..., :-1], a),
        r"/target_db is float32\(18, 7, 5, 15\), expected float32\(18, 7, 5, 16\)",
    ),
    "float64": (lambda u, t, a: (u, t.astype(np.float64), a), "/target_db is float64"),
    "int32 uid": (lambda u, t, a: (u.astype(np.int32), t, a), "/mesh_uid is int32"),
    "missing mesh": (lambda u, t, a: (u[1:], t[1:], a), "missing 1 of 18 test meshes"),
    "extra mesh": (
        lambda u, t, a: (np.append(u, 999999), np.concatenate([t, t[:1]]), a),
        "1 rows are not test-split meshes",
    ),
    "duplicate": (
        lambda u, t, a: (np.append(u, u[0]), np.concatenate([t, t[:1]]), a),
        "1 duplicated mesh_uid",
    ),
    "fingerprint": (
        lambda u, t, a: (u, t, {**a, "dataset_fingerprint": "0" * 64}),
        "made for dataset 0000",
    ),
    "labels": (
        lambda u, t, a: (u, t, {**a, "label_fingerprint": "0" * 64}),
        "made for labels 0000",
    ),
    "version": (lambda u, t, a: (u, t, {**a, "version": 7}), "version 7 is not 1"),
    "foreign": (lambda u, t, a: (u, t, {}), "not a predictions file"),
    "nan": (lambda u, t, a: (u, _with_nan(t), a), "non-finite prediction for mesh_uid"),
}


@pytest.mark.parametrize("case", list(MALFORMED))
def test_malformed_predictions_give_one_line_errors(data_dir, model_run, tmp_path, case):
    edit, problem = MALFORMED[case]
    bad = tmp_path / f"{case.replace(' ', '_')}.h5"
    _rewrite(model_run[1], bad, edit)
    with pytest.raises(PredictionsError, match=problem) as err:
        score_predictions(data_dir, bad)
    assert str(err.value).startswith(str(bad)) and "\n" not in str(err.value)


def test_writing_a_non_finite_prediction_is_refused_and_leaves_no_file(tmp_path):
    target = np.zeros((3, 2, 2, 5), np.float32)
    target[1, 0, 1, 2] = np.inf
    path = tmp_path / "p.h5"
    with pytest.raises(PredictionsError, match=r"p.h5: non-finite prediction for mesh_uid 11$"):
        write_predictions(path, "f" * 64, np.array([10, 11, 12]), target, label_fingerprint="l")
    assert list(tmp_path.iterdir()) == []


def test_non_hdf5_and_linked_datasets_are_refused(data_dir, model_run, tmp_path):
    text = tmp_path / "preds.h5"
    text.write_text("mesh_uid,target\n")
    with pytest.raises(PredictionsError, match="not a readable HDF5 file"):
        score_predictions(data_dir, text)
    linked = tmp_path / "linked.h5"
    _rewrite(model_run[1], linked, lambda u, t, a: (u, t, a))
    with h5py.File(linked, "a") as f:
        del f["target_db"]
        f["target_db"] = h5py.ExternalLink(str(model_run[1]), "/target_db")
    with pytest.raises(PredictionsError, match=r"/target_db is a link \(ExternalLink\)"):
        score_predictions(data_dir, linked)


def test_results_json_round_trip_and_validation(model_run, tmp_path):
    results = model_run[0]
    path = tmp_path / "r.json"
    write_results(path, results)
    assert load_results(path) == results
    cases = {
        "missing": (
            {k: v for k, v in results.items() if k != "speed"},
            "speed must be a JSON object",
        ),
        "fingerprint": ({**results, "dataset_fingerprint": "abc"}, "not a sha256"),
        "labels": ({**results, "label_fingerprint": "abc"}, "label_fingerprint is not a sha256"),
        "bool mse": (
            {**results, "metrics": {**results["metrics"], "simple_mse": True}},
            "simple_mse must be",
        ),
        "negative": (
            {**results, "metrics": {**results["metrics"], "variation_mse": -1.0}},
            "variation_mse must be",
        ),
        "params": ({**results, "model": {**results["model"], "params": "many"}}, "model.params"),
        "per class": (
            {**results, "metrics": {**results["metrics"], "per_class": {"cube": {}}}},
            "per_class.cube.simple_mse",
        ),
        "created": ({**results, "created": "yesterday"}, "created is not a UTC timestamp"),
        "interval": (
            {**results, "metrics": {**results["metrics"], "simple_mse_ci": [3.0, 1.0]}},
            "simple_mse_ci must have lo <= hi",
        ),
        "skill": (
            {
                **results,
                "metrics": {
                    **results["metrics"],
                    "skill": {**results["metrics"]["skill"], "reference": "oracle"},
                },
            },
            "skill.reference must be",
        ),
        "per object": (
            {**results, "per_object": {**results["per_object"], "simple_mse": [1.0]}},
            "per_object.simple_mse must be a list of 6",
        ),
        "self-reported": (
            {**results, "speed": {**results["speed"], "self_reported": "yes"}},
            "speed.self_reported must be true or false",
        ),
    }
    for name, (bad, problem) in cases.items():
        p = tmp_path / f"{name}.json"
        p.write_text(json.dumps(bad))
        with pytest.raises(ResultsError, match=problem) as err:
            load_results(p)
        assert str(err.value).startswith(str(p)) and "\n" not in str(err.value)
    nan = tmp_path / "nan.json"
    nan.write_text(json.dumps(results).replace('"simple_mse": ', '"simple_mse": NaN, "x": ', 1))
    with pytest.raises(ResultsError, match="not valid JSON"):
        load_results(nan)
    with pytest.raises(ResultsError, match="model.name"):
        write_results(tmp_path / "never.json", {**results, "model": {}})
    assert not (tmp_path / "never.json").exists()


def test_cli_evaluate_both_paths(data_dir, model_file, tmp_path, capsys):
    preds, r1, r2 = tmp_path / "p.h5", tmp_path / "out" / "r1.json", tmp_path / "r2.json"
    assert (
        main(
            [
                "evaluate",
                "--quiet",
                "--data",
                str(data_dir),
                "--model",
                f"{model_file}:GeometryModel",
                "--model-arg",
                "offset=1",
                "--out",
                str(r1),
                "--write-predictions",
                str(preds),
                "--params",
                "12",
                "--regime",
                "basic",
                "--train-seed",
                "3",
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "evaluate",
                "--data",
                str(data_dir),
                "--predictions",
                str(preds),
                "--out",
                str(r2),
                "--name",
                "geometry-file",
                "--speed-ms",
                "2.5",
            ]
        )
        == 0
    )
    a, b = load_results(r1), load_results(r2)
    out = capsys.readouterr().out
    assert a["metrics"] == b["metrics"] and "no skill" in out and "ref class-scale-nn" in out
    assert b["speed"] == {"ms_per_mesh": 2.5, "hardware": None, "self_reported": True}
    assert "2.500 ms/mesh self-reported" in out and a["speed"]["self_reported"] is False
    assert a["model"] == {"name": "geometry", "params": 12, "embedding": None, "regime": "basic"}
    assert a["seeds"] == {"dataset": 0, "train": 3} and b["model"]["name"] == "geometry-file"


def test_cli_errors_are_one_line_and_keep_existing_results(data_dir, tmp_path):
    out = tmp_path / "r.json"
    out.write_text("keep me")
    bad = tmp_path / "bad.h5"
    with h5py.File(bad, "w") as f:
        f["x"] = np.zeros(3)
    for argv, problem in [
        (["--predictions", str(bad)], "not a predictions file"),
        (["--predictions", str(bad), "--write-predictions", "x.h5"], "needs --model"),
        (["--model", "m:M", "--speed-ms", "3"], "goes with --predictions"),
        (["--model", "nope"], "module:Class"),
    ]:
        with pytest.raises(SystemExit) as err:
            main(["evaluate", "--data", str(data_dir), "--out", str(out), *argv])
        assert problem in str(err.value.code) and "\n" not in str(err.value.code)
    with pytest.raises(SystemExit) as err:
        main(
            [
                "evaluate",
                "--data",
                str(tmp_path / "none"),
                "--predictions",
                str(bad),
                "--out",
                str(out),
            ]
        )
    assert "no such dataset directory" in str(err.value.code)
    assert out.read_text() == "keep me"


def test_scoring_and_evaluate_do_not_import_torch(data_dir, model_run):
    code = textwrap.dedent(f"""
        import sys
        from benchmark.cli import main
        main(["evaluate", "--quiet", "--data", {str(data_dir)!r},
              "--predictions", {str(model_run[1])!r},
              "--out", {str(model_run[1].with_suffix(".json"))!r}])
        assert "torch" not in sys.modules, "torch was imported"
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


def test_dataset_without_test_split_is_refused(tmp_path):
    d = make_dataset(tmp_path / "d", objects_per_class=1, n_test_per_class=0, n_shards=1)
    with pytest.raises(SystemExit) as err:
        main(
            [
                "evaluate",
                "--data",
                str(d),
                "--model",
                "benchmark.scoring.protocol:MeanResponseModel",
                "--model-arg",
                f"data_dir={d}",
                "--out",
                str(tmp_path / "r.json"),
            ]
        )
    assert "has no test-split objects" in str(err.value.code)


def test_writer_refuses_mismatched_blocks(tmp_path):
    with pytest.raises(PredictionsError, match=r"2 mesh uids but predictions of shape \(3, 4\)"):
        write_predictions(
            tmp_path / "p.h5",
            "0" * 64,
            np.arange(2),
            np.zeros((3, 4), np.float32),
            label_fingerprint="0" * 64,
        )
    assert list(tmp_path.iterdir()) == []


OOD = (900, 901, 925, 950)  # isotropic twice, qem, delaunay


@pytest.fixture(scope="module")
def ood_dir(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("ood"), ood=OOD)


def _random_predictions(data_dir, path, drop_ood=False):
    """A predictions file of independent random rows for every test mesh (OOD ones unless
    ``drop_ood``), built from the raw shard files; returns {uid: row} and the raw layout."""
    rng = np.random.default_rng(7)
    objs = []
    for shard in sorted(data_dir.glob("shard-*.h5")):
        with h5py.File(shard) as f:
            ids, split, cls = f["objects/id"][()], f["objects/split"][()], f["objects/class"][()]
            resp, owner, variant = (
                f["radar/response"][()],
                f["meshes/object_index"][()],
                f["meshes/variant"][()],
            )
        for k in np.flatnonzero(split == b"test"):
            t = 20 * np.log10(np.maximum(np.abs(resp[k].astype(np.complex128)), 1e-4))
            objs.append(
                (
                    int(ids[k]),
                    int(cls[k]),
                    t.astype(np.float32),
                    sorted(variant[owner == k].tolist()),
                )
            )
    uids = [i * 1000 + v for i, _, _, vs in objs for v in vs if not (drop_ood and v >= 900)]
    rows = rng.normal(-40, 15, (len(uids), 7, 5, 16)).astype(np.float32)
    with BenchmarkData(data_dir) as data:
        write_predictions(
            path,
            data.fingerprint,
            np.array(uids, np.int64),
            rows,
            label_fingerprint=data.label_fingerprint,
        )
    return dict(zip(uids, rows.astype(np.float64))), objs


def test_ood_metrics_against_a_direct_numpy_computation(ood_dir, tmp_path):
    by_uid, objs = _random_predictions(ood_dir, tmp_path / "p.h5")
    metrics = score_predictions(ood_dir, tmp_path / "p.h5")

    def err(a, b):
        return np.mean((a - np.maximum(b, -80.0)) ** 2)

    want = {key: [] for key in ("ood_complex_mse", "ood_variation_mse", "isotropic", "qem")}
    per_class = {}
    for oid, c, t, variants in objs:
        s = np.maximum(by_uid[oid * 1000], -80.0)
        ood = {v: by_uid[oid * 1000 + v] for v in variants if v >= 900}
        assert sorted(ood) == list(OOD)
        oc = np.mean([err(t, p) for p in ood.values()])
        want["ood_complex_mse"].append(oc)
        want["ood_variation_mse"].append(np.mean([err(s, p) for p in ood.values()]))
        want["isotropic"].append(np.mean([err(t, ood[900]), err(t, ood[901])]))
        want["qem"].append(err(t, ood[925]))
        per_class.setdefault(CLASSES[c], []).append(oc)
    for key in ("ood_complex_mse", "ood_variation_mse"):
        assert metrics[key] == pytest.approx(np.mean(want[key]), rel=1e-9)
        lo, hi = metrics[key + "_ci"]
        assert lo < metrics[key] < hi
    for cname, values in per_class.items():
        assert metrics["per_class"][cname]["ood_complex_mse"] == pytest.approx(np.mean(values))
    pr = metrics["per_remesher"]
    assert set(pr) == {"isotropic", "qem", "delaunay"}
    assert pr["isotropic"]["ood_complex_mse"] == pytest.approx(np.mean(want["isotropic"]))
    assert pr["qem"]["ood_complex_mse"] == pytest.approx(np.mean(want["qem"]))
    assert pr["qem"]["n_objects"] == len(objs)
    assert metrics["n_meshes"] == sum(len(v) for *_, v in objs)
    # the regular metrics are untouched by the OOD meshes
    simple = np.mean([err(t, by_uid[oid * 1000]) for oid, _, t, _ in objs])
    assert metrics["simple_mse"] == pytest.approx(simple)
    # the mesh-blind references predict the same on every mesh: OOD = Simple, no variation
    for name in ("train-mean", "class-mean", "nearest-scale"):
        ref = metrics["references"][name]
        assert ref["ood_complex_mse"] == pytest.approx(ref["simple_mse"], rel=1e-12)
        assert ref["ood_variation_mse"] == 0.0
    assert metrics["references"]["class-scale-nn"]["ood_complex_mse"] is not None


def test_predictions_without_ood_rows_are_refused(ood_dir, tmp_path):
    _random_predictions(ood_dir, tmp_path / "p.h5", drop_ood=True)
    with pytest.raises(PredictionsError) as info:
        score_predictions(ood_dir, tmp_path / "p.h5")
    n_ood = len(OOD) * 2 * len(CLASSES)
    assert f"missing {n_ood} of {n_ood} out-of-distribution test meshes" in str(info.value)
    assert "\n" not in str(info.value)


def test_evaluate_predicts_ood_meshes_and_results_round_trip(ood_dir, model_file, tmp_path):
    model = load_model(f"{model_file}:GeometryModel")
    results = evaluate(ood_dir, model=model, write_predictions=tmp_path / "p.h5", progress=False)
    with h5py.File(tmp_path / "p.h5") as f:
        assert {int(u) % 1000 for u in f["mesh_uid"][()]} >= set(OOD)
    po = results["per_object"]
    assert len(po["ood_complex_mse:isotropic"]) == results["metrics"]["n_objects"]
    assert results["metrics"]["ood_complex_mse"] == pytest.approx(np.mean(po["ood_complex_mse"]))
    write_results(tmp_path / "r.json", results)
    assert load_results(tmp_path / "r.json") == results
    broken = {**results, "per_object": {k: v for k, v in po.items() if k != "ood_complex_mse"}}
    with pytest.raises(ResultsError, match="per_object must hold exactly"):
        write_results(tmp_path / "bad.json", broken)
