"""The board claims only what it checked, and publishing cannot be steered (reliability audit).

1. Speeds and parameter counts the harness did not measure are stored and shown as
   self-reported, whatever a results JSON says: always for ``leaderboard submit`` (a
   predictions file is scored, no model is run); ``seed`` keeps the harness's own numbers.
2. Two concurrent submissions of the same predictions: exactly one lands.
3. Nothing is read or published through a symbolic link (render --out, files carried over
   from the previous site, entries, the package's static files, serve).
4. A ``|`` in a link cannot break a Markdown table row; names and other entry texts refuse
   control and bidi/format characters (U+202E reverses what the board shows).

The dataset and the submissions are the ones of tests/test_leaderboard.py.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import threading
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from benchmark.scoring import references, schema
from leaderboard import render, store
from leaderboard.serve import make_server
from test_leaderboard import make_dataset, refused, run, write_predictions, write_results

ROOT = Path(__file__).resolve().parents[1]
SECRET = "SECRET-host-file-contents"
OLD_ENTRIES = Path(__file__).resolve().parent / "old_entries"


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("board") / "data")


@pytest.fixture(scope="module")
def submission(data, tmp_path_factory):
    d = tmp_path_factory.mktemp("board-sub")
    pred = write_predictions(d / "predictions.h5", data)
    return write_results(d / "results.json", data, pred), pred


def _edit(results: Path, out: Path, edit) -> Path:
    r = json.loads(results.read_text())
    edit(r)
    out.write_text(json.dumps(r))
    return out


def _rows(html: str) -> list[str]:
    body = re.search(r"<tbody>(.*?)</tbody>", html, re.S).group(1)
    return re.findall(r"<tr id=\"entry-[^>]*>(.*?)</tr>", body, re.S)


def _md_rows(md: str) -> list[str]:
    return [line for line in md.splitlines() if re.match(r"\| \d+ \|", line)]


# --- 1. the board claims only what it checked ----------------------------------------------


def test_submitted_speed_and_params_are_self_reported_whatever_the_json_says(
    data, submission, tmp_path
):
    results, pred = submission
    claim = _edit(
        Path(results),
        tmp_path / "fast.json",
        lambda r: (
            r["speed"].update(ms_per_mesh=0.0001, hardware="cpu: claimed", self_reported=False),
            r["model"].update(params=1),
        ),
    )
    entries, site = tmp_path / "entries", tmp_path / "site"
    run("submit", claim, "--predictions", pred, "--data", data, "--entries", entries)
    (entry,) = store.load_entries(entries)
    assert entry["origin"] == "submit"
    assert entry["speed"]["self_reported"] is True and entry["speed"]["ms_per_mesh"] == 0.0001
    assert entry["params_self_reported"] is True and entry["params"] == 1
    run("render", "--out", site, "--entries", entries)
    html, md = (site / "index.html").read_text(), (site / "LEADERBOARD.md").read_text()
    (row,) = _rows(html)
    assert "0.000100 (self-reported)" in row and ">1 (self-reported)<" in row
    assert re.search(
        r'<p class="note self-reported">\(self-reported\): given by the submitter, '
        r"not measured by the harness",
        html,
    )
    (md_row,) = _md_rows(md)
    assert "| 0.000100 (self-reported) |" in md_row and "| 1 (self-reported) |" in md_row
    assert "\n(self-reported): given by the submitter, not measured by the harness" in md


def test_seed_keeps_what_the_harness_measured_unmarked(data, tmp_path):
    rows = tmp_path / "reproduce"
    for row, self_reported in (("measured", False), ("given", True)):
        (rows / row).mkdir(parents=True)
        offsets = {
            "measured": None,
            "given": {"cube": (1.5, 3.0), "cylinder": (2.0, 5.0), "sphere": (0.5, 4.0)},
        }[row]
        pred = write_predictions(
            rows / row / "predictions.h5", data, **({"offsets": offsets} if offsets else {})
        )
        res = write_results(rows / row / "results.json", data, pred, name=row, ms_per_mesh=7.5)
        _edit(res, res, lambda r, s=self_reported: r["speed"].update(self_reported=s))
    entries, site = tmp_path / "entries", tmp_path / "site"
    run("seed", "--from", rows, "--data", data, "--entries", entries)
    by_name = {e["name"]: e for e in store.load_entries(entries)}
    measured, given = by_name["measured"], by_name["given"]
    assert measured["origin"] == given["origin"] == "seed"
    assert measured["speed"]["self_reported"] is False and not store.speed_self_reported(measured)
    assert measured["params_self_reported"] is False and not store.params_self_reported(measured)
    assert given["speed"]["self_reported"] is True and store.speed_self_reported(given)
    run("render", "--out", site, "--entries", entries)
    html = (site / "index.html").read_text()
    (measured_row,) = [r for r in _rows(html) if 'data-value="measured"' in r]
    (given_row,) = [r for r in _rows(html) if 'data-value="given"' in r]
    assert "self-reported" not in measured_row and "7.50 (self-reported)" in given_row


def test_old_entries_without_origin_read_as_submitted(tmp_path):
    """Entries made before ``origin`` existed (tests/old_entries: two that the board
    published until 2026-11-26) still validate and render; lacking ``origin`` they are read
    as ``leaderboard submit`` made them (their source says: not re-measured), so their speed
    and parameter count are marked even where the file says ``self_reported: false``."""
    store.load_entries(store.DEFAULT_ENTRIES)  # every committed entry still valid
    committed = store.load_entries(OLD_ENTRIES)
    model = next(e for e in committed if e["kind"] == "model" and "origin" not in e)
    physics = next(
        e
        for e in committed
        if e["kind"] == "simulator"
        and e["dataset"]["fingerprint"] == model["dataset"]["fingerprint"]
    )
    assert "origin" not in model and model["speed"]["self_reported"] is False
    entries, site = tmp_path / "entries", tmp_path / "site"
    entries.mkdir()
    for e in (model, physics):
        shutil.copy(OLD_ENTRIES / f"{e['id']}.json", entries)
    run("render", "--out", site, "--entries", entries)
    html, md = (site / "index.html").read_text(), (site / "LEADERBOARD.md").read_text()
    (row,) = _rows(html)
    assert f"{render.fmt_ms(model['speed']['ms_per_mesh'])} (self-reported)" in row
    assert f"{render.fmt_params(model['params'])} (self-reported)" in row
    assert "(self-reported)" in _md_rows(md)[0] and "\n(self-reported): given by" in md
    # the timed physics point stays unmarked
    assert f"{render.fmt_ms(physics['speed']['ms_per_mesh'])} ms per mesh" in md
    with pytest.raises(store.EntryError, match="origin"):  # a model cannot claim the timer
        store.validate_entry({**model, "origin": "simulator"})


def test_entries_are_checked_by_the_schemas_field_table():
    """One owner per record: an entry is the field table ``schema.ENTRY`` (with its dataset
    and sample blocks), checked by the same ``Field`` checks as a results JSON; a wrong value
    in any field is refused naming that field, and the committed entries use no other field."""
    committed = store.load_entries(store.DEFAULT_ENTRIES)
    entry = next(e for e in committed if e.get("sample"))
    for e in committed:
        assert set(e) <= set(schema.ENTRY) and set(e["dataset"]) <= set(schema.DATASET)
    for name in schema.ENTRY:
        with pytest.raises(store.EntryError, match=f"^{name} "):
            store.validate_entry({**entry, name: ["a", "list"]})
    for name in schema.DATASET:
        with pytest.raises(store.EntryError, match=rf"^dataset\.{name}"):
            store.validate_entry({**entry, "dataset": {**entry["dataset"], name: {}}})
    for name in schema.SAMPLE:
        with pytest.raises(store.EntryError, match=rf"^sample\.{name}"):
            store.validate_entry({**entry, "sample": {**entry["sample"], name: {}}})
    cases = {
        # one time format, the schema's ("submitted" once had a regex of its own)
        "submitted": ({"submitted": "2026-01-01"}, "submitted is not a UTC timestamp"),
        "sample field": (
            {"sample": {**entry["sample"], "note": 1}},
            "sample has unknown field(s) note",
        ),
        "image shape": (
            {"sample": {**entry["sample"], "range_m": entry["sample"]["range_m"][1:]}},
            "sample.physics_db must be a",
        ),
        "unknown": ({"junk": 1}, "the entry has unknown field(s) junk"),
        "bidi key": ({"ju\u202enk": 1}, "the entry key has the control or format character U+202E"),
    }
    for case, (edit, phrase) in cases.items():
        with pytest.raises(store.EntryError) as exc:
            store.validate_entry({**entry, **edit})
        assert str(exc.value).startswith(phrase), (case, str(exc.value))
    # the names are declared once and imported
    assert store.ENTRY_VERSION is schema.ENTRY_VERSION and store.METRIC_NAMES is schema.METRIC_NAMES
    assert references.REFERENCES is schema.REFERENCE_NAMES


# --- 2. submission is atomic -------------------------------------------------------------

# A child `leaderboard submit`: waits until both children are ready (a file each in GO), and
# with DELAY > 0 sleeps that long before writing its entry, so that without a lock both pass
# the duplicate check before either writes.
CHILD = """
import pathlib, sys, time
import leaderboard.submit as submit
from leaderboard.cli import main
go, delay, me = pathlib.Path(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
write = submit.write_entry
def slow_write(*args, **kwargs):
    time.sleep(delay)
    return write(*args, **kwargs)
submit.write_entry = slow_write
(go / me).touch()
while len(list(go.iterdir())) < 2:
    time.sleep(0.002)
main(sys.argv[4:])
"""


@pytest.mark.parametrize("delay", [0.4, 0.4, 0.4, 0.0, 0.0, 0.0])
def test_concurrent_submissions_of_the_same_predictions_land_once(
    data, submission, tmp_path, delay
):
    results, pred = submission
    entries, go = tmp_path / "entries", tmp_path / "go"
    go.mkdir()
    procs = [
        subprocess.Popen(
            [
                sys.executable,
                "-c",
                CHILD,
                str(go),
                str(delay),
                name,
                "submit",
                str(results),
                "--predictions",
                str(pred),
                "--data",
                str(data),
                "--entries",
                str(entries),
                "--name",
                name,
                "--unregistered",
            ],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for name in ("first", "second")
    ]
    outcomes = [(p.returncode, *out) for p in procs for out in [p.communicate(timeout=120)]]
    assert sorted(rc for rc, _, _ in outcomes) == [0, 1], outcomes
    (err,) = [e.strip() for rc, _, e in outcomes if rc == 1]
    assert (
        "\n" not in err
        and err.startswith("leaderboard submit: error: ")
        and "already on the board" in err
    ), err
    assert len(list(entries.glob("*.json"))) == 1
    assert sorted(p.name for p in entries.iterdir()) == [p.name for p in entries.glob("*.json")]


# --- 3. no symbolic link is followed -------------------------------------------------------


@pytest.fixture
def secret(tmp_path) -> Path:
    path = tmp_path / "host" / "hostname"
    path.parent.mkdir()
    path.write_text(SECRET)
    return path


def _tree(root: Path) -> dict[str, bytes | str]:
    """Every path under ``root`` (links as their target's name, not followed) with content."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for n in dirnames + filenames:
            p = Path(dirpath) / n
            out[str(p.relative_to(root))] = (
                f"-> {os.readlink(p)}" if p.is_symlink() else b"" if p.is_dir() else p.read_bytes()
            )
    return out


def test_render_refuses_an_out_that_is_a_symlink(tmp_path):
    entries, target, link = tmp_path / "entries", tmp_path / "real-site", tmp_path / "site"
    entries.mkdir()
    run("render", "--out", target, "--entries", entries)
    link.symlink_to(target, target_is_directory=True)
    before = _tree(tmp_path)
    msg = refused("render", "--out", link, "--entries", entries)
    assert (
        msg.startswith("leaderboard render: error: ")
        and str(link) in msg
        and "symbolic link" in msg
    ), msg
    assert link.is_symlink() and _tree(tmp_path) == before  # no .new link, target untouched


def test_render_never_carries_a_symlink_into_the_site(tmp_path, secret, capsys):
    entries, site = tmp_path / "entries", tmp_path / "site"
    entries.mkdir()
    (site / "notes").mkdir(parents=True)
    (site / "CNAME").write_text("board.example.org")
    (site / "notes" / "todo.txt").write_text("mine")
    (site / "leak.txt").symlink_to(secret)
    (site / "notes" / "inner-leak.txt").symlink_to(secret)
    (site / "hostdir").symlink_to(secret.parent, target_is_directory=True)
    os.mkfifo(site / "pipe")
    capsys.readouterr()
    run("render", "--out", site, "--entries", entries, "--quiet")  # warnings still print
    err = capsys.readouterr().err.strip().splitlines()
    tree = _tree(site)
    assert tree["CNAME"] == b"board.example.org" and tree["notes/todo.txt"] == b"mine"
    for name in ("leak.txt", "notes/inner-leak.txt", "hostdir", "pipe"):
        assert name not in tree, name
        assert sum(f"{site / name}: " in line for line in err) == 1, (name, err)
    assert len(err) == 4 and all(line.startswith("leaderboard render: warning: ") for line in err)
    assert not any(SECRET.encode() in v for v in tree.values() if isinstance(v, bytes))


def test_render_skips_an_entry_that_is_a_symlink(data, submission, tmp_path, capsys):
    results, pred = submission
    entries, site, outside = tmp_path / "entries", tmp_path / "site", tmp_path / "outside"
    run("submit", results, "--predictions", pred, "--data", data, "--entries", entries)
    (path,) = entries.glob("*.json")
    planted = {**json.loads(path.read_text()), "id": "planted-0123456789", "name": "planted"}
    outside.mkdir()
    (outside / "planted-0123456789.json").write_text(json.dumps(planted))
    link = entries / "planted-0123456789.json"
    link.symlink_to(outside / "planted-0123456789.json")
    with pytest.raises(store.EntryError, match="symbolic link"):
        store.load_entries(entries)
    capsys.readouterr()
    run("render", "--out", site, "--entries", entries, "--quiet")  # warnings still print
    (err,) = capsys.readouterr().err.strip().splitlines()
    assert str(link) in err and "symbolic link" in err and "entry skipped" in err, err
    assert ">planted<" not in (site / "index.html").read_text()


def test_static_files_are_never_read_through_a_symlink(tmp_path, secret, monkeypatch):
    package = tmp_path / "package"
    shutil.copytree(Path(render.__file__).parent / "templates", package / "templates")
    shutil.copytree(Path(render.__file__).parent / "static", package / "static")
    monkeypatch.setattr(render, "PACKAGE", package)
    assert render.build([])["sort.js"] == (package / "static" / "sort.js").read_bytes()
    (package / "static" / "sort.js").unlink()
    (package / "static" / "sort.js").symlink_to(secret)
    with pytest.raises(ValueError, match="sort.js: a symbolic link"):
        render.build([])
    shutil.rmtree(package / "static")
    (package / "static").symlink_to(secret.parent, target_is_directory=True)
    with pytest.raises(ValueError, match="static: a symbolic link"):
        render.build([])


def test_serve_never_follows_a_symlink(tmp_path, secret):
    site = tmp_path / "site"
    (site / "sub").mkdir(parents=True)
    (site / "index.html").write_text("<p>board</p>")
    (site / "sub" / "ok.txt").write_text("ok")
    (site / "leak.txt").symlink_to(secret)
    (site / "hostdir").symlink_to(secret.parent, target_is_directory=True)
    (site / "linked").mkdir()
    (site / "linked" / "index.html").symlink_to(secret)
    server = make_server(site, 0)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    base = f"http://127.0.0.1:{server.server_port}/"

    def get(path: str) -> tuple[int, bytes]:
        try:
            with urllib.request.urlopen(base + path, timeout=10) as r:
                return r.status, r.read()
        except urllib.error.HTTPError as exc:
            return exc.code, exc.read()

    try:
        assert get("index.html") == (200, b"<p>board</p>") and get("sub/ok.txt") == (200, b"ok")
        for path in ("leak.txt", "hostdir/hostname", "hostdir/", "linked/"):
            status, body = get(path)
            assert status == 404 and SECRET.encode() not in body, (path, status)
    finally:
        server.shutdown()
        server.server_close()
    link = tmp_path / "site-link"
    link.symlink_to(site, target_is_directory=True)
    with pytest.raises(ValueError, match="symbolic link"):
        make_server(link, 0)


# --- 4. links and texts cannot break or reorder the board --------------------------------


def test_a_pipe_in_a_link_keeps_the_markdown_row_whole(data, submission, tmp_path):
    results, pred = submission
    entries, site = tmp_path / "entries", tmp_path / "site"
    run(
        "submit",
        results,
        "--predictions",
        pred,
        "--data",
        data,
        "--entries",
        entries,
        "--link",
        "https://example.org/a|b?x=(1)",
    )
    run("render", "--out", site, "--entries", entries)
    md = (site / "LEADERBOARD.md").read_text()
    header = next(line for line in md.splitlines() if line.startswith("| # | Model |"))
    (row,) = _md_rows(md)

    def cells(line: str) -> int:
        return len(re.split(r"(?<!\\)\|", line))

    assert cells(row) == cells(header), row
    assert "(https://example.org/a%7Cb?x=%281%29)" in row
    assert 'href="https://example.org/a|b?x=(1)"' in (site / "index.html").read_text()


HIDDEN = [
    "\u202e",
    "\u202d",
    "\u2066",
    "\u200b",
    "\u200f",
    "\ufeff",
    "\u2028",
    "\u2029",
    "\x85",
    "\x7f",
    "\t",
]


@pytest.mark.parametrize("char", HIDDEN, ids=[f"U+{ord(c):04X}" for c in HIDDEN])
def test_entry_texts_refuse_control_and_bidi_characters(char):
    with pytest.raises(store.EntryError, match=f"U\\+{ord(char):04X}|printable"):
        store.check_text(f"graph{char}ea", "name")
    assert store.check_text("Graph AE (v2) – über ² 1.5×", "name")  # ordinary text is fine


def test_a_bidi_override_is_refused_in_names_and_any_entry_text(data, submission, tmp_path, capsys):
    results, pred = submission
    entries = tmp_path / "entries"
    msg = refused(
        "submit",
        results,
        "--predictions",
        pred,
        "--data",
        data,
        "--entries",
        entries,
        "--name",
        "evil\u202egnp.exe",
    )
    assert "U+202E" in msg and "name" in msg
    hidden = _edit(
        Path(results), tmp_path / "hidden.json", lambda r: r["model"].update(name="graph\u200bae")
    )
    msg = refused("submit", hidden, "--predictions", pred, "--data", data, "--entries", entries)
    assert "U+200B" in msg and str(hidden) in msg
    hw = _edit(
        Path(results), tmp_path / "hw.json", lambda r: r["speed"].update(hardware="cpu: \u202efast")
    )
    msg = refused("submit", hw, "--predictions", pred, "--data", data, "--entries", entries)
    assert "speed.hardware" in msg and "U+202E" in msg
    assert not entries.exists()
    run("submit", results, "--predictions", pred, "--data", data, "--entries", entries)
    (path,) = entries.glob("*.json")
    entry = json.loads(path.read_text())
    entry["metrics"]["per_class"]["cube\u2066"] = entry["metrics"]["per_class"].pop("cube")
    path.write_text(json.dumps(entry))
    capsys.readouterr()
    run("render", "--out", tmp_path / "site", "--entries", entries, "--quiet")
    (err,) = capsys.readouterr().err.strip().splitlines()
    assert path.name in err and "U+2066" in err and "skipped" in err
