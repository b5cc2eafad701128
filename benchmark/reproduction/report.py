"""The paper's table from finished (row, seed) results: rows, findings, Markdown and plot.

One way to build a table, used by ``benchmark reproduce`` (from the runs it just finished or
reused) and by ``benchmark report`` (from the per-seed results JSONs alone, so results
committed without checkpoints or predictions still rebuild their table). The table carries
the reference rows (``benchmark.scoring.references``, recomputed from the dataset), each row's
mean ± std across seeds with the 95% interval of the seed-mean (bootstrap over test objects
of the per-object errors averaged over seeds), its skill against the strongest reference,
and the paper's findings decided by paired intervals (``findings``).
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from basic_shapes.infra import atomic_path, load_json
from benchmark.reproduction.presets import PRESETS, PRETRAINING, ROWS
from benchmark.reproduction.runner import checkpoint_dir, row_files
from benchmark.scoring.schema import (
    METRIC_NAMES,
    OOD_METRIC_NAMES,
    PEAK_METRIC_NAMES,
    REFERENCE_NAMES,
)
from benchmark.training.models import FACE_EMBEDDINGS, REGISTRY
from benchmark.training.models.checkpoint import CONFIG_MAX_BYTES, number, plateau_record


class ReportError(ValueError):
    """The results of a reproduce folder are missing, foreign or inconsistent (one line)."""


# --- records ----------------------------------------------------------------------------------
def reference_rows(data) -> tuple[dict, dict, dict | None]:
    """(scorers, summary rows, oracle block or None) of the reference models on ``data``:
    recomputed from the dataset, never stored with the results. The oracle
    (``references.oracle_row``) exists on datasets with hidden shape parameters only."""
    from benchmark.scoring import references

    _, scorers = references.reference_scores(data)
    return (
        scorers,
        {
            n: {**references.summary(sc), "per_class": per_class(sc.per_object(), sc.class_names)}
            for n, sc in scorers.items()
        },
        references.oracle_row(data, scorers),
    )


def per_class(po: dict, names: list[str]) -> dict:
    """The metric block (with intervals) of each class that has test objects."""
    from benchmark.scoring.metrics import metric_block

    out = {}
    for c, name in enumerate(names):
        sel = po["class_index"] == c
        if sel.any():
            out[name] = metric_block({k: v[sel] for k, v in po.items()}, po["class_index"][sel])
    return out


def dataset_info(data, directory) -> dict:
    """What a table says of its dataset: fingerprint, description and the registered version
    it was built as (by content, ``versions.identify``; None if it is none), not the preset's
    default version: ``--data`` may name another (the hidden track runs the cpu preset)."""
    from benchmark.scoring import versions

    try:
        version = versions.identify(directory).name
    except versions.VersionError:
        version = None
    return {"fingerprint": data.fingerprint, "description": data.describe(), "version": version}


def load_records(out: Path, preset_name: str, seeds: list[int], data) -> dict:
    """The (row, seed) records under ``out`` as ``benchmark reproduce`` keeps them in memory:
    every ``results/<row>/seed-<s>/results.json`` of the table's rows and ``seeds``, checked
    to be that row's and seed's, scored on ``data`` (its meshes and labels), with per-object
    errors; ``train_seconds`` from the checkpoint's config.json where it was kept (checked to
    be of the preset), else None."""
    from benchmark.scoring.protocol import load_results

    results_dir = out / "results"
    if not results_dir.is_dir():
        raise ReportError(
            f"{results_dir}: no such directory (expected the results/ folder "
            f"of a `benchmark reproduce --out`)"
        )
    records: dict[str, dict[int, dict]] = {}
    for embedding, regime in ROWS:
        name = f"{embedding}-{regime}"
        for seed in seeds:
            path = row_files(out, name, seed)[0]
            if not path.is_file():
                continue
            results = load_results(path)
            if (results["model"]["name"], results["seeds"].get("train")) != (name, seed):
                raise ReportError(
                    f"{path}: holds the results of {results['model']['name']} "
                    f"seed {results['seeds'].get('train')}, not {name} seed {seed}"
                )
            if (results["dataset_fingerprint"], results["label_fingerprint"]) != (
                data.fingerprint,
                data.label_fingerprint,
            ):
                raise ReportError(
                    f"{path}: scored on another dataset or other labels than "
                    f"{data.directory} (fingerprints differ)"
                )
            if "per_object" not in results:
                raise ReportError(f"{path}: no per_object errors (made by an older harness)")
            records.setdefault(name, {})[seed] = {
                "results": results,
                **_training(out, name, seed, preset_name),
            }
    if not records:
        raise ReportError(
            f"{results_dir}: no results.json of any row for seeds {','.join(map(str, seeds))}"
        )
    return records


def _training(out: Path, name: str, seed: int, preset_name: str) -> dict:
    """``train_seconds``, ``epochs_to_plateau``, ``capped`` and the validation curve
    (``val_curve``) of a run, from its checkpoint's config.json (Nones where not kept)."""
    path = checkpoint_dir(out, name, seed) / "config.json"
    none = {"train_seconds": None, "epochs_to_plateau": None, "capped": None, "val_curve": None}
    if not path.is_file():
        return none
    config = load_json(path, max_bytes=CONFIG_MAX_BYTES, error=ReportError)
    config = config if isinstance(config, dict) else {}
    trained = config.get("train") if isinstance(config.get("train"), dict) else {}
    wrong = [(k, v) for k, v in PRESETS[preset_name].train.items() if trained.get(k) != v]
    if wrong:  # results of another preset would be tabled (and decided) as this one's
        key, want = wrong[0]
        raise ReportError(
            f"{path}: trained with {key}={trained.get(key)!r}, not the "
            f"{preset_name} preset's {want!r}; is --preset right?"
        )
    value = config.get("train_seconds")
    if not number(value) or not value >= 0:
        raise ReportError(f"{path}: train_seconds must be a number >= 0, got {value!r}")
    return {"train_seconds": value, **plateau_record(config)}


def build_table(
    preset_name: str,
    seeds: list[int],
    records: dict,
    dataset: dict,
    ref_scorers: dict,
    ref_rows: dict,
    provenance: dict,
    oracle: dict | None = None,
) -> dict:
    """table.json: the rows of ``records``, the references (and the oracle of a dataset with
    hidden shape parameters, ``reference_rows``) and (presets large enough to decide them) the
    findings. ``dataset``: fingerprint and description; ``provenance``: command, hardware,
    python and timing of the invocation that trained the rows (hardware and timing None in a
    table rebuilt by ``benchmark report``)."""
    from benchmark.scoring import references

    preset = PRESETS[preset_name]
    rows = table_rows(records, ref_scorers, ref_rows)
    table = {
        "preset": preset_name,
        **provenance,
        "preset_config": asdict(preset),
        "dataset": dataset,
        "seeds": seeds,
        "references": ref_rows,
        "strongest_reference": references.strongest(ref_rows),
        "rows": rows,
        "findings": findings(rows) if preset.findings else [],
    }
    if oracle is not None:
        table["oracle"] = oracle
    if not preset.findings:
        table["no_findings"] = NO_FINDINGS
    return table


# --- table ------------------------------------------------------------------------------------
METRICS, OOD_METRICS, PEAK_METRICS = METRIC_NAMES, OOD_METRIC_NAMES, PEAK_METRIC_NAMES


def _mean_per_object(seed_results: list[dict]) -> dict:
    """Per-object errors averaged over seeds (NaN where an object lacks a metric); the OOD
    errors when every seed has them (results made before OOD scoring lack them)."""
    from benchmark.scoring.metrics import ood_keys

    first = seed_results[0]["per_object"]
    for r in seed_results[1:]:
        if r["per_object"]["object_id"] != first["object_id"]:
            raise ValueError("seeds of a row were scored on different test objects")
    out = {"object_id": np.array(first["object_id"]), "class_index": np.array(first["class_index"])}
    keys = METRICS + (
        ood_keys() if all("ood_complex_mse" in r["per_object"] for r in seed_results) else ()
    )
    if all("peak_simple_mse" in r["per_object"] for r in seed_results):
        keys += PEAK_METRICS
    for m in keys:
        arr = np.array(
            [[np.nan if x is None else x for x in r["per_object"][m]] for r in seed_results],
            np.float64,
        )
        out[m] = arr.mean(axis=0)
    return out


def table_rows(
    records: dict, ref_scorers: dict | None = None, ref_rows: dict | None = None
) -> list[dict]:
    """One row per (embedding, regime) with every finished seed: mean ± std across seeds,
    the interval of the seed-mean, per class and (OOD metrics) per remesher, no-skill votes
    and skill vs the references."""
    from benchmark.scoring import references
    from benchmark.scoring.metrics import metric_block, per_remesher

    rows = []
    for embedding, regime in ROWS:
        name = f"{embedding}-{regime}"
        seeds = sorted(records.get(name, {}))
        if not seeds:
            continue
        recs = [records[name][s] for s in seeds]
        res = [r["results"] for r in recs]
        po = _mean_per_object(res)
        block = metric_block(po, po["class_index"])
        cols = METRICS + OOD_METRICS + PEAK_METRICS
        row = {
            "name": name,
            "embedding": embedding,
            "regime": regime,
            "pretraining": PRETRAINING[regime],
            "training_meshes": "all" if regime == "ideal" else "simple",
            "seeds": seeds,
            **{k: block.get(k) for k in cols},
            **{k + "_ci": block.get(k + "_ci") for k in cols},
            **{k + "_std": _std([r["metrics"].get(k) for r in res]) for k in cols},
            "per_remesher": per_remesher(po, po["class_index"]),
            "per_seed": {
                str(s): {
                    **{k: r["metrics"].get(k) for k in cols},
                    "no_skill": r["metrics"]["no_skill"],
                }
                for s, r in zip(seeds, res)
            },
            "no_skill_seeds": sum(bool(r["metrics"]["no_skill"]) for r in res),
            "params": res[0]["model"]["params"],
            "ms_per_mesh": res[0]["speed"]["ms_per_mesh"],
            "speed": res[0]["speed"],
            "train_seconds": _mean([r.get("train_seconds") for r in recs]),
            # training to the plateau, per seed (None where the checkpoint was not kept)
            "epochs_to_plateau": [r.get("epochs_to_plateau") for r in recs],
            "capped": [r.get("capped") for r in recs],
            "val_curves": [r.get("val_curve") for r in recs],
            "per_class": per_class(po, list(res[0]["metrics"]["per_class"])),
            "per_object": {
                k: [None if np.isnan(x) else float(x) for x in v]
                if v.dtype.kind == "f"
                else v.tolist()
                for k, v in po.items()
            },
            # each seed's per-object errors: the findings' intervals count seed variance
            "per_seed_object": {m: [r["per_object"][m] for r in res] for m in METRICS},
        }
        row["no_skill"] = row["no_skill_seeds"] * 2 > len(seeds)
        if ref_scorers is not None:
            row["skill"] = references.skill(po, ref_scorers, ref_rows)
        rows.append(row)
    return rows


def _std(values: list) -> float | None:
    v = [x for x in values if x is not None]
    return float(np.std(v, ddof=1)) if len(v) > 1 else None


def _mean(values: list) -> float | None:
    v = [x for x in values if x is not None]
    return float(np.mean(v)) if v else None


def _per_seed(row: dict) -> dict:
    """(seeds, objects) errors per metric; rows made before per-seed errors were kept give
    their seed-averaged errors as one pseudo-seed."""
    per_seed = row.get("per_seed_object") or {m: [row["per_object"][m]] for m in METRICS}
    return {
        "class_index": np.array(row["per_object"]["class_index"]),
        **{
            m: np.array([[np.nan if x is None else x for x in s] for s in per_seed[m]], np.float64)
            for m in METRICS
        },
    }


def _decide(pairs: list[tuple], by: dict, metrics: tuple[str, ...]) -> dict:
    """Paired comparisons "a has lower error than b" on each metric, and the claim's verdict:
    reversed when any is reversed; otherwise, with every pair's rows present, holds when every
    comparison holds, else inconclusive; None (undecided) while rows are missing."""
    from benchmark.scoring.uncertainty import paired_seeds, verdict

    comps = []
    missing = 0
    for a, b in pairs:
        if a not in by or b not in by:
            missing += 1
            continue
        pa, pb = _per_seed(by[a]), _per_seed(by[b])
        for m in metrics:
            p = paired_seeds(pa[m], pb[m], pa["class_index"])
            if p is None:
                continue
            comps.append(
                {
                    "better": "-".join(a),
                    "than": "-".join(b),
                    "metric": m,
                    "diff": p["diff"],
                    "ci": p["ci"],
                    "half_width": p["half_width"],
                    "verdict": verdict(p["ci"]),
                    **({"seeds_for_3": p["seeds_for_3"]} if "seeds_for_3" in p else {}),
                }
            )
    counts = {
        v: sum(c["verdict"] == v for c in comps) for v in ("holds", "reversed", "inconclusive")
    }
    if counts["reversed"]:
        overall = "reversed"
    elif not comps or missing:
        overall = None
    elif counts["holds"] == len(comps):
        overall = "holds"
    else:
        overall = "inconclusive"
    return {
        "verdict": overall,
        **counts,
        "of": len(comps),
        "pairs_missing": missing,
        "comparisons": comps,
        "max_half_width": max((c["half_width"] for c in comps), default=None),
        "complex_seeds_for_3": _seeds_for_all(comps),
    }


def _seeds_for_all(comps: list[dict]) -> int | str | None:
    """Seeds per row for ±3 dB² on every Complex MSE comparison of a claim: the largest
    planning figure, "objects" when the test objects alone are wider, None without them."""
    need = [c["seeds_for_3"] for c in comps if c["metric"] == "complex_mse" and "seeds_for_3" in c]
    if not need:
        return None
    return "objects" if None in need else max(need)


def findings(rows: list[dict]) -> list[dict]:
    """The paper's claims, each decided by paired 95% intervals over the same test objects
    that count training-seed variance (``uncertainty.paired_seeds``); ``verdict`` None when
    rows are missing."""
    by = {(r["embedding"], r["regime"]): r for r in rows}
    pre = ("basic", "classification", "autoencoder")
    out = [
        {
            "claim": "graph and token embeddings beat direct (same pretraining, all three metrics)",
            **_decide(
                [((e, r), ("direct", r)) for e in ("graph", "token") for r in pre], by, METRICS
            ),
        },
        {
            "claim": "autoencoder pretraining beats classification pretraining and none "
            "(same embedding, all three metrics)",
            **_decide(
                [
                    ((e, "autoencoder"), (e, r))
                    for e in FACE_EMBEDDINGS
                    for r in ("classification", "basic")
                ],
                by,
                METRICS,
            ),
        },
        {
            "claim": "graph + autoencoder is best of the non-Ideal paper rows on all three metrics",
            **_decide(
                [
                    (("graph", "autoencoder"), (e, r))
                    for e in FACE_EMBEDDINGS
                    for r in pre
                    if (e, r) != ("graph", "autoencoder")
                ],
                by,
                METRICS,
            ),
        },
        {
            "claim": "every non-Ideal model falls short of its Ideal model on Variation MSE",
            **_decide(
                [((e, "ideal"), (e, r)) for e in FACE_EMBEDDINGS for r in pre],
                by,
                ("variation_mse",),
            ),
        },
    ]
    return out


def _num(x, digits: int = 1) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def _seconds(x) -> str:
    """Whole seconds, but a sub-second run (the tiny preset) is not shown as 0."""
    return _num(x, 0 if x is None or x >= 1 else 2)


def _cell(mean, std, ci, digits: int = 1) -> str:
    """mean ± std (across seeds) [95% interval of the seed-mean]."""
    if mean is None:
        return "-"
    text = _num(mean, digits) + (f" ± {_num(std, digits)}" if std is not None else "")
    return text + (f" [{_num(ci[0], digits)}, {_num(ci[1], digits)}]" if ci else "")


NO_FINDINGS = (
    "No findings: this preset is a smoke test (a few test objects, one seed, models "
    "too small to learn); its differences are noise and decide nothing."
)


def _digits(metric: str) -> int:
    return 2 if "variation" in metric else 1


def _metric_cells(r: dict, dagger: str, seeds: bool = True) -> str:
    """The five metric cells of a row (the no-skill dagger after Variation MSE); a record
    made before OOD scoring shows "-" for the OOD ones."""
    cells = [
        _cell(r.get(k), r.get(k + "_std") if seeds else None, r.get(k + "_ci"), _digits(k))
        for k in METRICS + OOD_METRICS
    ]
    cells[2] += dagger
    return " | ".join(cells)


def remesher_table(rows: list[dict], references: dict) -> list[str]:
    """Markdown lines: OOD Complex / OOD Variation per remesher for every reference and model
    row (none when no row has OOD meshes)."""
    from basic_shapes.shards import OOD_REMESHERS

    rows = [
        {**r, "embedding": f"reference: {n}", "pretraining": "-", "training_meshes": "-"}
        for n, r in references.items()
    ] + rows
    names = [n for n in OOD_REMESHERS if any(n in r.get("per_remesher", {}) for r in rows)]
    if not names:
        return []
    lines = [
        "",
        "### Out-of-distribution meshes per remesher",
        "",
        "OOD Complex / OOD Variation MSE (dB²) on each remesher's meshes, mean over seeds "
        "[95% interval of the seed-mean].",
        "",
        "| Embedding | Pretraining | Training meshes | "
        + " | ".join(f"{n} Complex | {n} Variation" for n in names)
        + " |",
        "|---|---|---|" + "---:|---:|" * len(names),
    ]
    for r in rows:
        pr = r.get("per_remesher", {})
        cells = [
            _cell(pr.get(n, {}).get(k), None, pr.get(n, {}).get(k + "_ci"), _digits(k))
            for n in names
            for k in OOD_METRICS
        ]
        lines.append(
            f"| {r['embedding']} | {r['pretraining']} | {r['training_meshes']} | "
            + " | ".join(cells)
            + " |"
        )
    return lines


def plateau_table(rows: list[dict]) -> list[str]:
    """Markdown lines: epochs to the validation plateau per row and seed, and how many runs
    the epoch cap ended while still improving (none when no checkpoint was kept)."""
    rows = [r for r in rows if any(e is not None for e in r.get("epochs_to_plateau", []))]
    if not rows:
        return []
    lines = [
        "",
        "### Training to the plateau",
        "",
        "The best validation epoch, per seed (the checkpoint holds that epoch; the plateau where "
        "the run was not capped); "
        "capped: runs the epoch cap ended while the validation error was still improving "
        "(a best epoch within the last `patience` epochs). Validation curves: "
        "`training_curves.png`.",
        "",
        "| Row | Best epoch (per seed) | Capped |",
        "|---|---|---:|",
    ]
    for r in rows:
        epochs = ", ".join("-" if e is None else str(e) for e in r["epochs_to_plateau"])
        capped = sum(bool(c) for c in r["capped"])
        lines.append(f"| {r['name']} | {epochs} | {capped} of {len(r['capped'])} |")
    return lines


def peak_table(rows: list[dict], references: dict) -> list[str]:
    """Markdown lines: the secondary, peak-relative metric for every reference and model row
    (none when no row has it: results made before it)."""
    rows = [{**r, "name": f"reference: {n}"} for n, r in references.items()] + rows
    if not any(r.get("peak_simple_mse") is not None for r in rows):
        return []
    lines = [
        "",
        "### Peak-relative MSE (secondary)",
        "",
        "MSE (dB²) over the bins within 40 dB of each label profile's peak, where the labels' "
        "physics is closest to Maxwell (docs/RESULTS.md, physics error budget); mean over "
        "seeds [95% interval of the seed-mean]. The paper's metric above stays the ranked one.",
        "",
        "| Row | Peak Simple | Peak Complex |",
        "|---|---:|---:|",
    ]
    for r in rows:
        cells = [_cell(r.get(k), None, r.get(k + "_ci"), 1) for k in PEAK_METRICS]
        lines.append(f"| {r['name']} | " + " | ".join(cells) + " |")
    return lines


def oracle_lines(oracle: dict | None) -> list[str]:
    """Markdown lines for a dataset with hidden shape parameters: the oracle's metrics and its
    paired difference to ``class-scale-nn`` (none on Basic Shapes)."""
    if oracle is None:
        return []
    from benchmark.scoring.references import K_NEAREST

    known = ", ".join(f"`{k}`" for k in oracle["hidden"])
    lines = [
        "",
        f"Oracle (not a model: told the hidden shape parameters {known}): the mean "
        f"target of the {K_NEAREST} training objects of the class nearest in (log scale, "
        f"{known}), each divided by its training spread. Its gap to `class-scale-nn` is what "
        f"a neighbour search gains from the hidden parameters; a model that reads the mesh "
        f"can gain more (it interpolates the scale better).",
        "",
        "| | Simple MSE | Complex MSE | Variation MSE | OOD Complex | OOD Variation |",
        "|---|---:|---:|---:|---:|---:|",
        "| oracle | " + _metric_cells(oracle, "", seeds=False) + " |",
    ]
    vs = oracle["vs_class_scale_nn"]
    for m, p in sorted(vs.items(), key=lambda kv: METRIC_NAMES.index(kv[0])):
        lines.append(
            f"| oracle - class-scale-nn, {m.replace('_', ' ')} | Δ {p['diff']:+.1f} "
            f"[{p['ci'][0]:+.1f}, {p['ci'][1]:+.1f}]: {p['verdict']} | | | | |"
        )
    return lines


def _provenance(table: dict) -> str:
    """Where the rows come from: the invocation that trained them, or ``benchmark report``."""
    t = table["timing"]
    if t is None:
        return (
            "Rebuilt by `benchmark report` from the per-seed results (nothing trained or "
            "predicted). ms / mesh: `predict` (first seed) as its results record it; each "
            "row's `speed.hardware` in table.json names the machine and whether, and on how "
            "many meshes, it was timed alone. Train s: from the checkpoints' config.json "
            "where they were kept."
        )
    evaluated = t.get("rows_evaluated", 0)  # from saved weights (benchmark weights --from)
    return (
        f"Hardware: {table['hardware']}; this invocation took "
        f"{t['total_s'] / 60:.1f} min, {t['rows_trained']} (row, seed) runs "
        f"trained{f', {evaluated} evaluated from saved weights,' if evaluated else ''} "
        f"and {t['rows_reused']} reused from an earlier run "
        f"(generate {_num(t.get('generate_s'))} s, label "
        f"{_num(t.get('label_s'))} s, rows + timing "
        f"{_num(t['rows_s'])} s, {t['jobs']} job(s) x "
        f"{t['threads_per_job']} thread(s)). ms / mesh: `predict` (first seed) timed with no "
        f"other job of this run on the CPU, on a sample of the test meshes stratified by "
        f"face count (its size, and the passes, in each row's `speed.hardware` in table.json)."
    )


def render_markdown(table: dict) -> str:
    """table.md from the table, the same text from memory or from table.json (whose keys are
    sorted): the references in their schema order."""
    refs = table["references"]
    table = {**table, "references": {n: refs[n] for n in REFERENCE_NAMES if n in refs}}
    lines = [
        f"# Basic Shapes reproduction: preset `{table['preset']}`",
        "",
        f"Command: `{table['command']}`",
        "",
        f"Dataset: version `{table['dataset'].get('version') or 'unregistered'}`, "
        f"{table['dataset']['description']}  ",
        f"fingerprint `{table['dataset']['fingerprint']}`  ",
        _provenance(table),
        "",
        f"MSE in dB² on T = 20 log10 max(|profile|, 1e-4), predictions clipped at the same "
        f"-80 dB floor. Model rows: mean ± std across {_seeds_text(table)} "
        f"[95% interval of the seed-mean: bootstrap over test objects, "
        f"stratified by class]. `†` marks no skill (not better than the training mean by a "
        f"paired 95% interval, in most seeds). Skill: 1 - Complex MSE / Complex MSE of the "
        f"strongest reference; Δ: the paired difference to it with its 95% interval.",
        "",
        "OOD Complex / OOD Variation: Complex / Variation MSE on the test objects' "
        "out-of-distribution meshes (remeshers no training mesh comes from; per remesher "
        "below).",
        "",
        "| Embedding | Pretraining | Training meshes | Simple MSE | Complex MSE | "
        "Variation MSE | OOD Complex | OOD Variation | Skill | Δ Complex vs ref | Params | "
        "ms / mesh | Train s |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, r in table["references"].items():
        lines.append(
            f"| reference: {name} | - | - | "
            + _metric_cells(r, " †" if r["no_skill"] else "", seeds=False)
            + " | - | - | 0 | - | - |"
        )
    for r in table["rows"]:
        sk = (r.get("skill") or {}).get("vs_reference", {})
        key = "complex_mse" if "complex_mse" in sk else "simple_mse"
        v = sk.get(key)
        skill = "-" if v is None or v["skill"] is None else f"{v['skill']:+.2f}"
        delta = "-" if v is None else f"{v['diff']:+.1f} [{v['ci'][0]:+.1f}, {v['ci'][1]:+.1f}]"
        lines.append(
            f"| {r['embedding']} | {r['pretraining']} | {r['training_meshes']} | "
            + _metric_cells(r, " †" if r["no_skill"] else "")
            + f" | {skill} | {delta} | {r['params']:,} | "
            f"{_num(r['ms_per_mesh'], 2)} | {_seconds(r['train_seconds'])} |"
        )
    strongest = table.get("strongest_reference")
    if strongest:
        lines += ["", f"Strongest reference: `{strongest}` (lowest Complex MSE)."]
    lines += oracle_lines(table.get("oracle"))
    lines += remesher_table(table["rows"], table["references"])
    lines += peak_table(table["rows"], table["references"])
    lines += plateau_table(table["rows"])
    lines += ["", "## The paper's findings on this table", ""]
    if not table["findings"]:
        lines.append(table.get("no_findings", NO_FINDINGS))
    n_seeds = {r["name"]: len(r["seeds"]) for r in table["rows"]}
    for f in table["findings"]:
        mark = f["verdict"] or ("not decided" if f["of"] else "not tested") + " (rows missing)"
        notes = (
            []
            if f["max_half_width"] is None
            else [f"largest paired 95% half-width {f['max_half_width']:.2f} dB²"]
        )
        need = f.get("complex_seeds_for_3")
        wide = any(c["metric"] == "complex_mse" and c["half_width"] > 3 for c in f["comparisons"])
        if need is not None and wide:  # the equal-seeds plan, while a Complex pair is wider
            notes.append(
                "±3 dB² on every Complex MSE pair needs more test objects, not seeds"
                if need == "objects"
                else f"±3 dB² on every Complex MSE pair would need {need} seeds per row"
            )
        if f.get("pairs_missing"):
            notes.append(f"{f['pairs_missing']} pair(s) of rows not yet run")
        lines.append(
            f"- {f['claim']}: **{mark}** ({f['holds']} hold, {f['reversed']} reversed, "
            f"{f['inconclusive']} inconclusive of {f['of']}{''.join('; ' + n for n in notes)})"
        )
        for c in f["comparisons"]:
            lines.append(
                f"  - {c['better']} < {c['than']} on {c['metric']}: Δ {c['diff']:+.2f} "
                f"[{c['ci'][0]:+.2f}, {c['ci'][1]:+.2f}] (±{c['half_width']:.2f}"
                f"{_unequal(c, n_seeds)}): {c['verdict']}{_seeds_note(c)}"
            )
    return "\n".join(lines) + "\n"


def _seeds_text(table: dict) -> str:
    """The training seeds the rows average: one list, or each row's where they differ
    (more seeds where a row's seeds spread most)."""
    lists = {tuple(r["seeds"]) for r in table["rows"]}
    if len(lists) <= 1:
        return f"the training seeds {table['seeds']}"
    each = "; ".join(f"{r['name']} {_span(r['seeds'])}" for r in table["rows"])
    return f"each row's training seeds ({each})"


def _span(seeds: list[int]) -> str:
    """'0-16' for a run of consecutive seeds, else the list."""
    if seeds == list(range(seeds[0], seeds[-1] + 1)) and len(seeds) > 2:
        return f"{seeds[0]}-{seeds[-1]}"
    return ",".join(map(str, seeds))


def _unequal(c: dict, n_seeds: dict) -> str:
    """', 17 vs 33 seeds' where the two rows have different seed counts."""
    a, b = n_seeds[c["better"]], n_seeds[c["than"]]
    return f", {a} vs {b} seeds" if a != b else ""


def _seeds_note(c: dict) -> str:
    if c["metric"] != "complex_mse" or c["half_width"] <= 3 or "seeds_for_3" not in c:
        return ""
    n = c["seeds_for_3"]
    return "; ±3 needs more test objects" if n is None else f"; ±3 at {n} seeds"


REGIME_KEY = {
    "basic": "basic (no pretraining)",
    "classification": "classification pretraining",
    "autoencoder": "autoencoder pretraining",
    "ideal": "ideal (trained on complex meshes too)",
}


def plot(rows: list[dict], path: Path, title: str, references: dict | None = None) -> None:
    """Speed against error (``scoring.plotting``): one point per row, coloured by embedding,
    shaped by regime, with its interval; the references as dashed lines."""
    from benchmark.scoring import plotting

    markers = {"basic": "o", "classification": "s", "autoencoder": "^", "ideal": "*"}
    points = [
        plotting.Point(
            r["ms_per_mesh"],
            r["complex_mse"],
            r["name"],
            ci=r.get("complex_mse_ci"),
            colour=REGISTRY[r["embedding"]].colour,
            marker=markers[r["regime"]],
            size=80 if r["regime"] == "ideal" else 45,
            hollow=r["no_skill"],
        )
        for r in rows
        if r["ms_per_mesh"] is not None and r["complex_mse"] is not None
    ]
    fig = plotting.speed_vs_error(
        points,
        {k: v.get("complex_mse") for k, v in (references or {}).items()},
        title=title,
        xlabel="ms per mesh (inference, including featurization; log scale)",
        marker_key={
            REGIME_KEY[k]: m for k, m in markers.items() if k in {r["regime"] for r in rows}
        },
    )
    with atomic_path(path) as tmp:
        tmp.write_bytes(plotting.png(fig))


def plot_curves(rows: list[dict], path: Path, title: str) -> bool:
    """``plotting.training_curves`` of the rows that kept a curve; False (nothing written)
    where none did."""
    from benchmark.scoring import plotting

    rows = [r for r in rows if any(c for c in r.get("val_curves", []))]
    if not rows:
        return False
    fig = plotting.training_curves(
        [(r["name"], r["seeds"], r["val_curves"], r["epochs_to_plateau"]) for r in rows], title
    )
    with atomic_path(path) as tmp:
        tmp.write_bytes(plotting.png(fig))
    return True


def plot_per_class(rows: list[dict], references: dict, path: Path, title: str) -> None:
    """Per class, each row's Simple and Complex MSE with intervals, references first."""
    from benchmark.scoring import plotting

    fig = plotting.per_class(
        [
            (f"ref: {n}", r.get("per_class", {}), plotting.REFERENCE_GREY)
            for n, r in references.items()
        ]
        + [(r["name"], r["per_class"], REGISTRY[r["embedding"]].colour) for r in rows],
        title,
    )
    with atomic_path(path) as tmp:
        tmp.write_bytes(plotting.png(fig))


def write_outputs(out: Path, table: dict, with_plot: bool = True) -> None:
    """table.json, table.md and (``with_plot``) the plots, each replaced atomically."""
    with atomic_path(out / "table.json") as tmp:
        tmp.write_text(json.dumps(table, indent=1, sort_keys=True, allow_nan=False) + "\n")
    with atomic_path(out / "table.md") as tmp:
        tmp.write_text(render_markdown(table))
    if with_plot:
        plot(
            table["rows"],
            out / "speed_vs_error.png",
            f"Basic Shapes, preset {table['preset']}: speed vs error",
            table["references"],
        )
        plot_curves(
            table["rows"],
            out / "training_curves.png",
            f"Basic Shapes, preset {table['preset']}: validation curves",
        )
        plot_per_class(
            table["rows"],
            table["references"],
            out / "per_class.png",
            f"Basic Shapes, preset {table['preset']}: per class",
        )
