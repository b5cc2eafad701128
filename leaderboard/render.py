"""`leaderboard render`: entry files -> a static site (HTML, CSS, JS, PNG) and LEADERBOARD.md.

Entries are grouped by dataset fingerprint, because numbers on different datasets are not
comparable; each dataset gets its table (sorted by Complex MSE; sortable in the browser) with
95% intervals, the harness's reference rows (marked "reference", unranked) and each model's
skill against the strongest of them, the OOD Complex and OOD Variation MSE (meshes from
remeshers no training mesh comes from), a no-skill flag, speeds and parameter counts the
harness did not measure marked self-reported (with a footnote), a per-class breakdown, a
speed-vs-error chart and an example figure. Every text from an entry is
escaped; the page loads nothing but its own files (a Content-Security-Policy says so), so it
works offline and from any static host. Everything is built in memory first, then the site
is published as a whole (a new directory swapped in), so a kill mid-render leaves the previous
site intact. Nothing is read or published through a symbolic link (entries, the package's
template and static files, files carried over from the previous site, the --out folder
itself): a link would publish whatever it points to.
"""

from __future__ import annotations

import ctypes
import fnmatch
import html
import math
import os
import re
import shutil
import stat
from importlib import resources
from pathlib import Path
from string import Template

from tqdm import tqdm

from basic_shapes.infra import fsync_dir
from benchmark.scoring.schema import OOD_METRIC_NAMES, PEAK_METRIC_NAMES
from leaderboard import figures
from leaderboard.store import (
    DEFAULT_ENTRIES,
    METRIC_NAMES,
    load_entries,
    params_self_reported,
    read_regular,
    speed_self_reported,
    track,
)

FIGURES = ("speed-vs-error-*.png", "per-class-*.png", "curves-*.png", "example-*.png")
METRIC_TITLES = {
    "simple_mse": "Simple MSE",
    "complex_mse": "Complex MSE",
    "variation_mse": "Variation MSE",
    "ood_complex_mse": "OOD Complex MSE",
    "ood_variation_mse": "OOD Variation MSE",
}
COLUMNS = METRIC_NAMES + OOD_METRIC_NAMES  # "—" in older entries
PACKAGE = resources.files("leaderboard")  # the template and static files
ASSET_MAX_BYTES = 1 << 20
SELF_REPORTED = " (self-reported)"  # the marker of a number the harness did not measure
CURVES_NOTE = (
    "Validation MSE after each epoch of every training seed, as the training run recorded it "
    "(results carry it as training.val_curves; for a submitted entry it is the submitter's "
    "record, not re-run by the board), the dot at the selected epoch. A curve still falling "
    "at its end is a model that stopped while learning. Entries without curves are left out; "
    f"at most the first {figures.CURVE_PANELS} in the table's order are drawn."
)
SELF_REPORTED_NOTE = (
    "(self-reported): given by the submitter, not measured by the harness. "
    "A submission is scored from its predictions file and no model is run, so "
    "the speed and the parameter count of a submitted entry are always "
    "self-reported; only the maintainers' own reproduce runs (leaderboard "
    "seed) and the timed physics simulator are measured."
)


def fmt_mse(x: float | None) -> str:
    return "—" if x is None else f"{x:.2f}"


def fmt_params(n: int | None) -> str:
    if n is None:
        return "—"
    for div, unit in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if n >= div:
            return f"{n / div:.3g} {unit}"
    return str(n)


def fmt_ms(x: float | None) -> str:
    """Three significant digits, trailing zeros kept (5.70 beside 5.08), never an exponent."""
    if x is None:
        return "—"
    if not x > 0:
        return f"{x:.3g}"
    return f"{x:.{max(0, 2 - math.floor(math.log10(x)))}f}"


def interval(block: dict, key: str) -> str:
    """``[70.10, 79.51]``, the metric's 95% interval, or "" where it has no width (one test
    object in a class) or no value."""
    ci = block.get(key + "_ci")
    return (
        f"[{ci[0]:.2f}, {ci[1]:.2f}]" if ci and block.get(key) is not None and ci[1] > ci[0] else ""
    )


def fmt_ci(block: dict, key: str) -> str:
    """A metric with its 95% interval when it has one: ``74.75 [70.10, 79.51]``."""
    ci = interval(block, key)
    return fmt_mse(block.get(key)) + (f" {ci}" if ci else "")


def no_skill(m: dict) -> bool:
    """The no-skill flag (``mode_collapse`` in entries made before it replaced that flag)."""
    return bool(m.get("no_skill", m.get("mode_collapse")))


def fmt_speed(e: dict) -> str:
    """ms per mesh, marked unless the harness measured it (``store.speed_self_reported``)."""
    ms = e["speed"].get("ms_per_mesh")
    return fmt_ms(ms) + (SELF_REPORTED if ms is not None and speed_self_reported(e) else "")


def fmt_entry_params(e: dict) -> str:
    """The parameter count, marked unless the harness counted it."""
    n = e.get("params")
    return fmt_params(n) + (SELF_REPORTED if n is not None and params_self_reported(e) else "")


def self_reported_note(g: dict) -> str:
    """The footnote of the marker, when a row of the dataset carries it ('' if none does)."""
    marked = any(SELF_REPORTED in fmt_speed(e) + fmt_entry_params(e) for e in g["models"])
    sim = g["simulator"]
    return SELF_REPORTED_NOTE if marked or (sim and SELF_REPORTED in fmt_speed(sim)) else ""


def skill_of(e: dict) -> tuple[float | None, str]:
    """(1 - Complex MSE / that of the strongest reference, the cell's text)."""
    sk = e["metrics"].get("skill") or {}
    v = sk.get("vs_reference", {})
    v = v.get("complex_mse") or v.get("simple_mse")
    if not v or v.get("skill") is None:
        return None, "—"
    word = {"holds": "better", "reversed": "worse"}.get(v["verdict"], "not distinguishable")
    return v["skill"], f"{v['skill']:+.2f} ({word})"


def references(g: dict) -> dict:
    """The dataset's reference rows, as the harness computed them (from any model entry)."""
    for e in g["models"]:
        refs = e["metrics"].get("references")
        if refs:  # entry files sort their keys: show them in the harness's order
            order = [n for n in REFERENCE_NOTES if n in refs] + sorted(
                set(refs) - set(REFERENCE_NOTES)
            )
            return {n: refs[n] for n in order}
    return {}


def ranked(g: dict) -> list[tuple[int | None, dict | None, str | None, dict]]:
    """The board's rows in order: (rank, entry, None, metrics) for each entry in the board's
    order and (None, None, reference name, metrics) for each reference row, placed among the
    entries by Complex MSE (a reference is ranked where it scores, marked, never numbered)."""
    refs = sorted(
        references(g).items(),
        key=lambda kv: (kv[1].get("complex_mse") is None, kv[1].get("complex_mse") or 0.0),
    )
    rows: list = []
    for rank, e in enumerate(g["models"], 1):
        mse = e["metrics"]["complex_mse"]
        while (
            refs
            and mse is not None
            and refs[0][1].get("complex_mse") is not None
            and (refs[0][1]["complex_mse"] < mse)
        ):
            name, r = refs.pop(0)
            rows.append((None, None, name, r))
        rows.append((rank, e, None, e["metrics"]))
    return rows + [(None, None, name, r) for name, r in refs]


def beats_mean(m: dict) -> tuple[str, bool]:
    """The "Beats mean" cell: "yes", or "no" (flagged) for a row without skill."""
    return ("no", True) if no_skill(m) else ("yes", False)


def datasets(entries: list[dict]) -> list[dict]:
    """Group entries by dataset, its meshes and its labels (versions such as cpu-v2 and cpu-v3
    share meshes): models sorted by Complex MSE, and the simulator entry if any."""
    groups: dict[tuple[str, str], dict] = {}
    for e in entries:
        fp, labels = e["dataset"]["fingerprint"], e["dataset"].get("label_fingerprint") or ""
        g = groups.setdefault(
            (fp, labels),
            {
                "fingerprint": fp,
                "short": f"{fp[:12]}-{labels[:8]}" if labels else fp[:12],
                "dataset": e["dataset"],
                "models": [],
                "simulator": None,
                "track": "public",
            },
        )
        if track(e) == "heldout":
            g["track"] = "heldout"
        if e["kind"] == "simulator":
            g["simulator"] = e
        else:
            g["models"].append(e)
    for g in groups.values():
        g["models"].sort(
            key=lambda e: (
                e["metrics"]["complex_mse"] is None,
                e["metrics"]["complex_mse"] or 0.0,
                e["name"],
            )
        )
        with_sample = [e for e in g["models"] if e.get("sample")]
        g["example"] = [
            e
            for e in with_sample  # the best model's object, in case entries differ
            if e["sample"]["object_id"] == with_sample[0]["sample"]["object_id"]
        ]
    return sorted(
        groups.values(),
        key=lambda g: (g["track"] != "heldout", -len(g["models"]), g["fingerprint"]),
    )


BUDGET_NOTE = (
    "The labels' own physics error: each class's labels against the exact answer "
    "(docs/RESULTS.md, physics error budget), in this board's metric, over the sizes measured. "
    "Differences between models smaller than this are physics noise."
)


def budget(dataset: dict) -> list[tuple[str, str, str, str]]:
    """(class, all bins, bins within 30 dB of the peak, exact reference) for a registered
    version's classes under its radar physics; [] where none is measured."""
    from benchmark.scoring import budget as physics_budget
    from benchmark.scoring.versions import VERSIONS

    v = VERSIONS.get(dataset.get("version") or "")
    if v is None:
        return []

    def value(x: float) -> str:
        return "<0.01" if x < 0.005 else f"{x:.3g}"

    def span(lo_hi) -> str:
        lo, hi = (value(x) for x in lo_hi)
        return lo if lo == hi else f"{lo}–{hi}"

    return [
        (r["class"], span(r["all_bins_db2"]), span(r["near_peak_db2"]), r["reference"])
        for r in physics_budget.rows(v.physics, list(dataset["classes"]))
    ]


PEAK_NOTE = (
    "Secondary, not ranked: MSE over the bins within 40 dB of each label profile's peak, "
    "where the labels' physics is closest to Maxwell (the physics error budget above). "
    "Entries scored before this metric existed show —."
)


def peak_rows(g: dict) -> list[tuple[str, str, str]]:
    """(name, Peak Simple, Peak Complex) per model and reference row; [] where no row of the
    dataset carries the peak-relative metric."""
    rows = [(e["name"], e["metrics"]) for e in g["models"]]
    rows += [(f"reference: {n}", r) for n, r in references(g).items()]
    if not any(m.get(PEAK_METRIC_NAMES[0]) is not None for _, m in rows):
        return []
    return [(name, *(fmt_ci(m, k) for k in PEAK_METRIC_NAMES)) for name, m in rows]


def html_peak(g: dict) -> str:
    rows = peak_rows(g)
    if not rows:
        return ""
    body = "\n".join(
        f"<tr><td>{_e(n)}</td><td>{_e(a)}</td><td>{_e(b)}</td></tr>" for n, a, b in rows
    )
    return (
        "<h3>Peak-relative MSE</h3>\n"
        f'<p class="note">{_e(PEAK_NOTE)}</p>\n'
        '<div class="scroll"><table class="peak"><thead><tr><th>Model</th>'
        "<th>Peak Simple MSE</th><th>Peak Complex MSE</th></tr></thead>\n"
        f"<tbody>\n{body}\n</tbody></table></div>"
    )


def html_budget(dataset: dict) -> str:
    rows = budget(dataset)
    if not rows:
        return ""
    body = "\n".join(
        f"<tr><td>{_e(c)}</td><td>{_e(a)}</td><td>{_e(n)}</td><td>{_e(ref)}</td></tr>"
        for c, a, n, ref in rows
    )
    return (
        "<h3>Physics error budget</h3>\n"
        f'<p class="note">{_e(BUDGET_NOTE)}</p>\n'
        '<div class="scroll"><table class="budget"><thead><tr><th>Class</th>'
        "<th>Labels vs exact, all bins (dB²)</th><th>Within 30 dB of the peak (dB²)</th>"
        f"<th>Exact reference</th></tr></thead>\n<tbody>\n{body}\n</tbody></table></div>"
    )


def describe(dataset: dict, heldout: bool = False) -> str:
    """The dataset's line: its registered version (grid, radar config, the command that builds
    it) or that it is none, then classes and test split; for the ranked track, the held-out
    build of which version (its recipe, a secret seed) and whether its fingerprints are the
    recorded ones."""
    from benchmark.scoring.versions import VERSIONS

    v = VERSIONS.get(dataset.get("version") or "")
    if heldout:
        return describe_heldout(dataset, v)
    head = (
        f"version {v.name}: {v.summary}; grid {v.grid()}, radar config "
        f"{v.radar_config().name}; built by: benchmark dataset {v.name} --data DIR. "
        if v
        else "not a registered dataset version. "
    )
    recorded = v.fingerprints if v else {}
    found = {"mesh": dataset.get("fingerprint"), "label": dataset.get("label_fingerprint")}
    if recorded.get("mesh") and found["mesh"] and found["mesh"] != recorded["mesh"]:
        head += (
            f"Scored on an earlier build of {v.name} (mesh {found['mesh'][:8]}..., "
            f"made before dataset bytes were machine-independent; the recorded build is "
            f"{recorded['mesh'][:8]}...): its numbers re-score only where that build comes back "
            f"(docs/RESULTS.md, Status). "
        )
    elif recorded.get("label") and found["label"] and found["label"] != recorded["label"]:
        head += (
            f"Scored on labels that are NOT {v.name}'s recorded ones (label "
            f"{found['label'][:8]}..., recorded {recorded['label'][:8]}...): relabelled or "
            f"edited; its numbers re-score only against those labels. "
        )
    return (
        head + f"Test split: {', '.join(dataset['classes'])}; {dataset['test_objects']} "
        f"test objects, {dataset['test_meshes']} simple and complex test meshes (and any "
        f"out-of-distribution ones)"
    )


def describe_heldout(dataset: dict, v) -> str:
    from benchmark.scoring import heldout

    split = (
        f"Test split: {', '.join(dataset['classes'])}; {dataset['test_objects']} test objects, "
        f"{dataset['test_meshes']} simple and complex test meshes (and any out-of-distribution "
        f"ones)"
    )
    if v is None:
        return (
            "a private held-out dataset, no build of a registered version (evaluate-model "
            "--unregistered). " + split
        )
    rec = heldout.recorded(v)
    if rec is None:
        where = "no fingerprints recorded for it yet"
    elif rec.get("mesh") == dataset.get("fingerprint"):
        where = f"its fingerprints are the recorded ones (manifests/heldout/{v.name}.json)"
    else:
        where = "NOT the recorded held-out build (fingerprints differ)"
    return (
        f"The recipe of version {v.name} ({v.summary}; grid {v.grid()}, radar config "
        f"{v.radar_config().name}) generated from a secret seed; its labels are never "
        f"published; {where}. " + split
    )


TRACK_NOTES = {
    "heldout": (
        "Ranked track: every model here is an ONNX file run by the board itself (leaderboard "
        "evaluate-model) on the held-out build, one mesh per call, with onnxruntime on one "
        "thread under memory and time limits. ms / mesh was measured there (the board's "
        "hardware is the cell's tooltip) and the parameters were counted from the file's "
        "graph: neither is self-reported."
    ),
    "public": (
        "Self-scored track: scored from predictions files on the public test split, whose "
        "labels ship with the dataset (the labels themselves are refused, a perturbed copy "
        "would score near perfectly), so it is not "
        "ranked with the held-out track. The metrics are re-scored; speeds and parameter "
        "counts are the submitter's."
    ),
}
TRACK_TITLES = {"heldout": "Ranked track (held-out)", "public": "Self-scored track"}


def pareto_note(g: dict) -> str:
    """Plain-text sentence naming the Pareto front of the chart ('' where none is drawn)."""
    front = figures.pareto_front(g["models"], g["simulator"]) if g["track"] == "heldout" else []
    if not front:
        return ""
    return (
        "Pareto front of Complex MSE against board-measured ms per mesh (no other point is "
        "both faster and lower): " + ", ".join(name for name, _, _ in front) + "."
    )


def simulator_note(sim: dict | None) -> str:
    """One sentence about the physics point, plain text (escaped by the caller)."""
    if sim is None:
        return (
            "No physics simulator point for this dataset yet "
            "(run: leaderboard simulator --data DIR)."
        )
    how = sim.get("complex_mse_source", "")
    return (
        f"Physics simulator ({sim['name']}): {fmt_speed(sim)} ms per mesh "
        f"on {sim['speed']['hardware'] or 'unknown hardware'}; "
        f"Complex MSE {fmt_mse(sim['metrics']['complex_mse'])} dB² ({how})."
    )


def chart_note(g: dict) -> str:
    """Plain-text sentence naming the models missing from the chart ('' if none)."""
    missing = [e["name"] for e in g["models"] if e not in figures.plottable(g["models"])]
    return (
        f"Not on the chart (no speed or no Complex MSE reported): {', '.join(missing)}."
        if missing
        else ""
    )


# --- HTML ------------------------------------------------------------------------------------


def _e(text) -> str:
    return html.escape(str(text), quote=True)


def _th(title: str, kind: str, sort: str | None = None) -> str:
    aria = f' aria-sort="{sort}"' if sort else ""
    return f'<th data-type="{kind}"{aria}><button type="button">{_e(title)}</button></th>'


def _num(value, text: str) -> str:
    v = "" if value is None else repr(value)
    return f'<td class="num" data-value="{v}">{_e(text)}</td>'


def _metric(block: dict, key: str) -> str:
    """A metric cell: the value, and its 95% interval below it, small, where the interval has
    a width (one test object in a class gives none worth showing)."""
    value, ci = block.get(key), interval(block, key)
    v = "" if value is None else repr(value)
    below = f'<br><small class="ci">{ci}</small>' if ci else ""
    return f'<td class="num" data-value="{v}">{_e(fmt_mse(value))}{below}</td>'


def _speed(e: dict) -> str:
    """ms per mesh, with the hardware it was measured on as the cell's tooltip."""
    ms, hardware = e["speed"]["ms_per_mesh"], e["speed"].get("hardware") or "hardware not given"
    v = "" if ms is None else repr(ms)
    return f'<td class="num" data-value="{v}" title="{_e(hardware)}">{_e(fmt_speed(e))}</td>'


def _link(e: dict) -> str:
    if not e.get("link"):
        return '<td data-value="">—</td>'
    return (
        f'<td><a href="{_e(e["link"])}" rel="nofollow noopener noreferrer">'
        f"{_e(re.sub(r'^https?://', '', e['link'])[:40])}</a></td>"
    )


def html_table(g: dict) -> str:
    """The board: metrics with their 95% intervals below them, the hardware as the speed's
    tooltip and a link column only where some entry has a link, so it fits 1,400 px; a
    scroll box keeps a phone's page from scrolling sideways (tests/test_site_browser.py)."""
    links = any(e.get("link") for e in g["models"])
    head = (
        [_th("#", "num"), _th("Model", "text")]
        + [
            _th(METRIC_TITLES[k], "num", "ascending" if k == "complex_mse" else None)
            for k in COLUMNS
        ]
        + [
            _th("Skill", "num"),
            _th("Beats mean", "text"),
            _th("Params", "num"),
            _th("ms / mesh", "num"),
            _th("Date", "text"),
        ]
        + ([_th("Link", "text")] if links else [])
    )
    rows = []
    for rank, e, ref, m in ranked(g):
        beats, flagged = beats_mean(m)
        flag = f'<td class="flag">{beats}</td>' if flagged else f"<td>{beats}</td>"
        if e is None:
            cells = (
                [
                    _num(None, "ref"),
                    f'<td data-value="{_e(ref)}" title="{_e(REFERENCE_NOTES.get(ref, ""))}">'
                    f"reference: {_e(ref)}</td>",
                ]
                + [_metric(m, k) for k in COLUMNS]
                + [_num(None, "—"), flag, _num(0, "0"), _num(None, "—")]
                + ["<td>—</td>"] * (2 if links else 1)
            )
            rows.append('<tr class="reference">' + "".join(cells) + "</tr>")
            continue
        model = e.get("model", {})
        detail = " · ".join(str(model[k]) for k in ("embedding", "regime") if model.get(k))
        skill, skill_text = skill_of(e)
        cells = (
            [
                _num(rank, str(rank)),
                f'<td data-value="{_e(e["name"].lower())}">{_e(e["name"])}'
                + (f'<br><small class="note">{_e(detail)}</small>' if detail else "")
                + "</td>",
            ]
            + [_metric(m, k) for k in COLUMNS]
            + [
                _num(skill, skill_text),
                flag,
                _num(e.get("params"), fmt_entry_params(e)),
                _speed(e),
                f'<td class="date">{_e(e["submitted"][:10])}</td>',
            ]
            + ([_link(e)] if links else [])
        )
        cls = ' class="collapsed"' if flagged else ""
        rows.append(f'<tr id="entry-{_e(e["id"])}"{cls}>' + "".join(cells) + "</tr>")
    return (
        f'<div class="scroll"><table class="board sortable" id="board-{g["short"]}">\n'
        f"<thead><tr>{''.join(head)}"
        f"</tr></thead>\n<tbody>\n" + "\n".join(rows) + "\n</tbody>\n</table></div>"
    )


REFERENCE_NOTES = {
    "train-mean": "the training-set mean response, for every mesh",
    "class-mean": "the training mean of the object's class (class given)",
    "nearest-scale": "the 3 training objects nearest in log scale",
    "class-scale-nn": "class read from the mesh's normals, then the 3 nearest in scale",
}


def skill_note(g: dict) -> str:
    """Plain-text sentence naming the strongest reference that Skill is measured against."""
    names = {(e["metrics"].get("skill") or {}).get("reference") for e in g["models"]} - {None}
    if not names:
        return ""
    return (
        f"Skill: 1 − Complex MSE / Complex MSE of the strongest reference "
        f"({', '.join(sorted(names))}), and whether the model is better, worse or not "
        f"distinguishable from it by the paired 95% interval of the difference. Beats mean: "
        f"better than the training-set mean response by a paired 95% interval (rows that are "
        f"not are flagged and folded). Reference rows cost nothing to run; they stand where "
        f"they score, marked ref, without a rank: "
        + "; ".join(f"{k}, {v}" for k, v in REFERENCE_NOTES.items())
        + "."
    )


def html_per_class(g: dict) -> str:
    head = [_th("Model", "text"), _th("Class", "text")] + [
        _th(METRIC_TITLES[k], "num") for k in COLUMNS
    ]
    rows = []
    for e in g["models"]:
        for cls, m in sorted(e["metrics"]["per_class"].items()):
            rows.append(
                "<tr>"
                + f"<td>{_e(e['name'])}</td><td>{_e(cls)}</td>"
                + "".join(_metric(m, k) for k in COLUMNS)
                + "</tr>"
            )
    return (
        f'<div class="scroll"><table class="per-class sortable" id="per-class-{g["short"]}">\n'
        f"<thead><tr>{''.join(head)}</tr></thead>\n<tbody>\n"
        + "\n".join(rows)
        + "\n</tbody>\n</table></div>"
    )


def _img(name: str, size: tuple[int, int], alt: str) -> str:
    return (
        f'<figure><img src="{name}" width="{size[0]}" height="{size[1]}" alt="{_e(alt)}"></figure>'
    )


def html_section(g: dict, images: dict[str, tuple[int, int]]) -> str:
    short, heldout = g["short"], g["track"] == "heldout"
    parts = [
        f'<section id="dataset-{short}" class="track-{g["track"]}">',
        f"<h2>{_e(TRACK_TITLES[g['track']])}: "
        f"{'held-out build of ' if heldout else 'dataset '}"
        f"{_e(g['dataset'].get('version') or 'unregistered')} <code>{short}</code></h2>",
        f'<p class="note">{_e(describe(g["dataset"], heldout))}</p>',
        f'<p class="note track">{_e(TRACK_NOTES[g["track"]])}</p>',
    ]
    if g["models"]:
        parts += [html_table(g), f'<p class="note">{_e(skill_note(g))}</p>']
    if self_reported_note(g):
        parts.append(f'<p class="note self-reported">{_e(self_reported_note(g))}</p>')
    notes = " ".join(filter(None, [simulator_note(g["simulator"]), pareto_note(g), chart_note(g)]))
    parts += [
        "<h3>Speed against error</h3>",
        f"<p>{_e(notes)}</p>",
        _img(
            f"speed-vs-error-{short}.png",
            images[f"speed-vs-error-{short}.png"],
            "ms per mesh against Complex MSE for every model and the physics simulator",
        ),
    ]
    parts += [x for x in (html_budget(g["dataset"]), html_peak(g)) if x]
    if g["models"]:
        parts += [
            "<h3>Per class</h3>",
            _img(
                f"per-class-{short}.png",
                images[f"per-class-{short}.png"],
                "Simple and Complex MSE of every model, one panel per class",
            ),
            html_per_class(g),
        ]
    if f"curves-{short}.png" in images:
        parts += [
            "<h3>Training curves</h3>",
            f"<p>{_e(CURVES_NOTE)}</p>",
            _img(
                f"curves-{short}.png",
                images[f"curves-{short}.png"],
                "validation MSE per epoch of every training seed, the selected epoch marked",
            ),
        ]
    if g["example"]:
        s = g["example"][0]["sample"]
        parts += [
            "<h3>Example predictions</h3>",
            f"<p>Test object {s['object_id']} ({_e(s['class'])}): the physics response "
            f"(aspect against range, roll {s['roll_deg']:g}°) beside each model's prediction "
            f"for the simple mesh and for a complex mesh of exactly the same shape.</p>",
            _img(
                f"example-{short}.png",
                images[f"example-{short}.png"],
                "physics response beside predictions for a simple and a complex mesh",
            ),
        ]
    return "\n".join(parts + ["</section>"])


# --- Markdown --------------------------------------------------------------------------------


def _md(text) -> str:
    return re.sub(r"([\\`*_\[\]<>|#])", r"\\\1", str(text))


def md_url(url: str) -> str:
    """A link target for a Markdown table cell: parentheses would end the link and a ``|``
    the cell, so they are percent-encoded (the same URL to a browser)."""
    return url.replace("(", "%28").replace(")", "%29").replace("|", "%7C")


def markdown(groups: list[dict]) -> str:
    out = [
        "# Basic Shapes leaderboard",
        "",
        "The ranked track (first, where the board has one): ONNX models the board ran itself "
        "on a held-out build (labels never published), with speed measured and parameters "
        "counted by the board. The self-scored track: predictions on a public test split, each "
        "verified by re-scoring it against the dataset. MSE in dB² "
        "with 95% intervals (bootstrap over test objects), lower is better. Reference rows are "
        "computed by the harness and stand where they score, marked ref, without a rank. A "
        "model that does not beat the training-set mean by a paired 95% interval is flagged "
        "(Beats mean: **no**): its low Variation MSE is not an achievement. OOD Complex / "
        "OOD Variation: Complex / Variation MSE on test meshes from remeshers no training mesh "
        "comes from. Speeds and parameter counts "
        "marked (self-reported) were not measured by the harness.",
        "",
    ]
    if not groups:
        out += ["No entries yet: see docs/SUBMITTING.md.", ""]
    for g in groups:
        short, heldout = g["short"], g["track"] == "heldout"
        out += [
            f"## {TRACK_TITLES[g['track']]}: {'held-out build of' if heldout else 'dataset'} "
            f"{g['dataset'].get('version') or 'unregistered'} `{short}`",
            "",
            _md(describe(g["dataset"], heldout)),
            "",
            _md(TRACK_NOTES[g["track"]]),
            "",
        ]
        if g["models"]:
            out += [
                "| # | Model | Simple MSE | Complex MSE | Variation MSE | OOD Complex MSE "
                "| OOD Variation MSE | Skill | Beats mean | Params | ms / mesh | Hardware "
                "| Date |",
                "|---:|---|---:|---:|---:|---:|---:|---:|---|---:|---:|---|---|",
            ]
            for rank, e, ref, m in ranked(g):
                beats, flagged = beats_mean(m)
                beats = f"**{beats}**" if flagged else beats
                cells = " | ".join(fmt_ci(m, k) for k in COLUMNS)
                if e is None:
                    out.append(
                        f"| ref | reference: {_md(ref)} | {cells} | — | {beats} | 0 | — | — | — |"
                    )
                    continue
                name = _md(e["name"])
                if e.get("link"):
                    name = f"[{name}]({md_url(e['link'])})"
                out.append(
                    f"| {rank} | {name} | {cells} | {skill_of(e)[1]} | {beats} | "
                    f"{fmt_entry_params(e)} | {fmt_speed(e)} | "
                    f"{_md(e['speed']['hardware'] or '—')} | {e['submitted'][:10]} |"
                )
            out += ["", _md(skill_note(g)), ""]
        if self_reported_note(g):
            out += [_md(self_reported_note(g)), ""]
        notes = " ".join(
            filter(None, [simulator_note(g["simulator"]), pareto_note(g), chart_note(g)])
        )
        out += [_md(notes), "", f"![Speed against error](speed-vs-error-{short}.png)", ""]
        if budget(g["dataset"]):
            out += [
                "### Physics error budget",
                "",
                _md(BUDGET_NOTE),
                "",
                "| Class | Labels vs exact, all bins (dB²) | Within 30 dB of the peak (dB²) "
                "| Exact reference |",
                "|---|---:|---:|---|",
            ]
            out += [
                f"| {_md(c)} | {a} | {n} | {_md(ref)} |" for c, a, n, ref in budget(g["dataset"])
            ]
            out += [""]
        if peak_rows(g):
            out += ["### Peak-relative MSE", "", _md(PEAK_NOTE), ""]
            out += ["| Model | Peak Simple MSE | Peak Complex MSE |", "|---|---:|---:|"]
            out += [f"| {_md(n)} | {a} | {b} |" for n, a, b in peak_rows(g)]
            out += [""]
        if g["models"]:
            out += [
                "### Per class",
                "",
                f"![Simple and Complex MSE per class](per-class-{short}.png)",
                "",
                "| Model | Class | " + " | ".join(METRIC_TITLES[k] for k in COLUMNS) + " |",
                "|---|---|" + "---:|" * len(COLUMNS),
            ]
            out += [
                f"| {_md(e['name'])} | {_md(c)} | "
                + " | ".join(fmt_ci(m, k) for k in COLUMNS)
                + " |"
                for e in g["models"]
                for c, m in sorted(e["metrics"]["per_class"].items())
            ]
            out += [""]
        if g["example"]:
            out += [f"![Example predictions](example-{short}.png)", ""]
    return "\n".join(out)


# --- the site --------------------------------------------------------------------------------


def _png_size(data: bytes) -> tuple[int, int]:
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def build(entries: list[dict], progress: bool = False) -> dict[str, bytes]:
    """Every file of the site, by name. The figures are most of the time (a bar with
    ``progress``)."""
    groups = datasets(entries)
    drawings = {}
    for g in groups:
        drawings[f"speed-vs-error-{g['short']}.png"] = lambda g=g: figures.speed_vs_error(
            g["models"], g["simulator"], references(g), front=g["track"] == "heldout"
        )
        if g["models"]:
            drawings[f"per-class-{g['short']}.png"] = lambda g=g: figures.per_class(
                g["models"], f"{g['dataset'].get('version') or g['short']}: per class"
            )
        if figures.with_curves(g["models"]):
            drawings[f"curves-{g['short']}.png"] = lambda g=g: figures.training_curves(
                g["models"],
                f"{g['dataset'].get('version') or g['short']}: validation curves, as each "
                "entry's training run recorded them (not re-run by the board)",
            )
        if g["example"]:
            drawings[f"example-{g['short']}.png"] = lambda g=g: figures.example(g["example"])
    bar = tqdm(drawings.items(), desc="render", unit="figure", disable=not progress)
    files: dict[str, bytes] = {name: draw() for name, draw in bar}
    sizes = {name: _png_size(data) for name, data in files.items()}
    body = (
        "\n".join(html_section(g, sizes) for g in groups)
        if groups
        else "<p>No entries yet: see docs/SUBMITTING.md.</p>"
    )
    page = Template(asset("templates", "page.html").decode("utf-8"))
    files["index.html"] = page.substitute(body=body, n_entries=len(entries)).encode()
    files["LEADERBOARD.md"] = markdown(groups).encode()
    for name in ("sort.js", "style.css"):
        files[name] = asset("static", name)
    return files


def asset(folder: str, name: str) -> bytes:
    """A template or static file of the package, refused if it or its folder is a symbolic
    link (a link committed in their place would publish its target)."""
    base = PACKAGE.joinpath(folder)
    if not isinstance(base, Path):  # a zipped package holds no links
        return base.joinpath(name).read_bytes()
    if base.is_symlink():
        raise ValueError(f"{base}: a symbolic link (never followed: it would publish its target)")
    data = read_regular(base / name, ASSET_MAX_BYTES, error=ValueError)
    if len(data) > ASSET_MAX_BYTES:
        raise ValueError(f"{base / name}: larger than the {ASSET_MAX_BYTES} bytes allowed")
    return data


def render(
    out_dir: str | os.PathLike,
    entries_dir: str | os.PathLike = DEFAULT_ENTRIES,
    warn=None,
    progress: bool = False,
) -> dict[str, bytes]:
    """Validate every entry, build the site in memory, then publish it as a whole.

    A bad entry file is skipped, reported through ``warn(message)`` (one broken file must not
    take the board down). The site is written into a new sibling directory and swapped in
    (``publish``), so a reader or a kill never sees a mix of old and new files. An ``out_dir``
    that is a symbolic link is refused before anything is built or written.
    """
    warn = warn or (lambda msg: None)
    check_out(Path(out_dir))
    entries = load_entries(entries_dir, on_error=lambda msg: warn(f"{msg}; entry skipped"))
    files = build(entries, progress)
    publish(Path(out_dir), files, warn)
    return files


def check_out(out: Path) -> None:
    """Refuse an output folder that is a symbolic link: the swap would replace the link by a
    directory and leave its target stale (and a stray link beside it)."""
    if out.is_symlink():
        raise ValueError(
            f"{out}: a symbolic link; render publishes into a real directory, "
            f"never through a link (pass its target as --out)"
        )
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: not a directory")


def publish(out: Path, files: dict[str, bytes], warn=None) -> None:
    """Write ``files`` into a fresh directory beside ``out`` and swap it with ``out``.

    Files in ``out`` that the site does not produce (a CNAME, notes) are carried over, except
    figures of datasets no longer on the board, and except symbolic links and special files
    (at any depth), left out with a ``warn(message)``: copying a link copies its target's
    contents. ``out`` itself must not be a link (``check_out``). The swap is one atomic
    renameat2 exchange where the kernel has it; otherwise two renames (the old site stays
    whole as ``.old`` until the new one is in place).
    """
    warn = warn or (lambda msg: None)
    check_out(out)
    out = out.absolute()
    out.parent.mkdir(parents=True, exist_ok=True)
    new = out.with_name(f".{out.name}.new-{os.getpid()}")
    old = out.with_name(f".{out.name}.old-{os.getpid()}")
    if new.is_symlink():
        new.unlink()
    shutil.rmtree(new, ignore_errors=True)
    new.mkdir()
    try:
        if out.is_dir():
            keep = [
                n
                for n in sorted(os.listdir(out))
                if n not in files and not any(fnmatch.fnmatch(n, pat) for pat in FIGURES)
            ]
            _carry(out, new, keep, warn)
        for name, data in files.items():
            (new / name).write_bytes(data)
            with open(new / name, "rb") as fh:
                os.fsync(fh.fileno())
        fsync_dir(new)
        if out.is_dir() and _exchange(new, out):
            shutil.rmtree(new)  # now holds the old site
        else:
            if out.exists():
                os.replace(out, old)
            os.replace(new, out)
            shutil.rmtree(old, ignore_errors=True)
        fsync_dir(out.parent)
    finally:
        shutil.rmtree(new, ignore_errors=True)


def _carry(src: Path, dst: Path, names: list[str], warn) -> None:
    """Copy ``names`` of ``src`` into ``dst``: folders recursively, regular files with their
    mode and times; never through a symbolic link (opened with O_NOFOLLOW, so a file swapped
    for a link meanwhile is left out too), and no FIFO or device."""
    for name in names:
        path, target = src / name, dst / name
        try:
            st = os.lstat(path)
        except FileNotFoundError:  # removed meanwhile
            continue
        if stat.S_ISDIR(st.st_mode):
            target.mkdir()
            _carry(path, target, sorted(os.listdir(path)), warn)
            shutil.copystat(path, target)
            continue
        if stat.S_ISLNK(st.st_mode) or not stat.S_ISREG(st.st_mode):
            what = "a symbolic link" if stat.S_ISLNK(st.st_mode) else "not a regular file"
            warn(f"{path}: {what}; not carried over into the new site")
            continue
        try:
            fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError as exc:
            warn(f"{path}: cannot read ({exc.strerror or exc}); not carried over into the new site")
            continue
        with os.fdopen(fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):  # swapped meanwhile
                warn(f"{path}: not a regular file; not carried over into the new site")
                continue
            with open(target, "xb") as out:
                shutil.copyfileobj(fh, out)
        os.chmod(target, stat.S_IMODE(st.st_mode))
        os.utime(target, ns=(st.st_atime_ns, st.st_mtime_ns))


def _exchange(a: Path, b: Path) -> bool:
    """Atomically swap two directories (Linux renameat2 RENAME_EXCHANGE); False if unsupported."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    return renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0
