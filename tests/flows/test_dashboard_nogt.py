"""The dashboard of a log without ground truth (the usual case for a team's own logs): the labelling
report's tables against the store's arrays, the page in a real headless Chromium (sections, numbers
= tables, pictures with a class legend, no errors, no network), and ``dsnet dashboard`` building
the report of a run that has none. DS-Net stages with refine, random-weight tiny checkpoint, k = 2,
sequence 00 of the synthetic vlp32 log with its labels removed."""

from __future__ import annotations

import math
import shutil
import subprocess

import numpy as np
import pyarrow.parquet as pq
import pytest

from dsnet_core.labels import load_label_map
from dsnet_core.viz.png import decode_png
from flows.publish import publish, report_is_current
from flows.report.tables import REPORT_TABLES
from storage.run import RunStore
from tasks.base import labels_contract
from tasks.infer import dequantise_probs
from tasks.methods import get_pipeline
from tests.flows.browser import Browser
from tests.flows.conftest import REPO, cli
from tests.helpers.plain_runner import run_stage_plain
from tests.model_helpers import make_checkpoint

P = get_pipeline("dsnet", refine=True)
LM = load_label_map("semantic-kitti")
LABELLED = ("s-labelled", "s-confidence", "s-tracks", "s-refine", "s-timings", "s-review")
SCORED = ("s-headline", "s-classes", "s-sequences", "s-frames", "s-worst")


@pytest.fixture(scope="module")
def nogt(synth_log, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("nogt")
    log = tmp / "log"
    shutil.copytree(synth_log, log)
    for labels in log.glob("sequences/*/labels"):
        shutil.rmtree(labels)
    ckpt = make_checkpoint(tmp / "ckpt", seed=0)
    store = RunStore(tmp / "run")
    run = {
        "data": str(log),
        **P.record(),
        "sequences": ["00"],
        "stages": {
            "align": {"scans": 2},
            "infer": {"checkpoint": str(ckpt)},
            "shift": {"clusterer": {"kind": "dynamic_shift", "n_seeds": 300, "bandwidths": [0.2, 1.8, 3.4]}},
        },
        "options": {"block_size": 3},
    }
    store.write_run_config("r1", run)
    for stage in P.names():
        run_stage_plain(store, P, "00", stage, run, "r1")
    published = publish(store.uri, "nogt", artifacts=False, pipeline=P)
    return store, published


def _table(store: RunStore, name: str) -> list[dict]:
    return store.read_all(REPORT_TABLES[name]).to_pylist()


def _decode(label: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return LM.lut(1 << 16, fill=0)[label & 0xFFFF].astype(np.int64), (label >> 16).astype(np.int64)


def test_publish_without_ground_truth_writes_the_labelling_report(nogt):
    store, published = nogt
    assert published["scored"] is False and published["dashboard"] == f"{store.uri}/dashboard.html"
    assert not any(store.has_table(REPORT_TABLES[n]) for n in ("score_run", "score_classes", "score_bev"))
    assert report_is_current(store)
    (seq,) = _table(store, "label_sequences")
    assert (seq["frames"], seq["labelled"], seq["truth_frames"], seq["scored"], seq["refined"]) == (
        6, 6, 0, False, True,
    )  # fmt: skip
    # per frame and per class: the final (refined) labels, decoded here
    refined = store.arrays("00", labels_contract("refine"))
    stitched = store.arrays("00", labels_contract("stitch"))
    frames = {f["index"]: f for f in _table(store, "label_frames")}
    after = np.zeros(LM.num_classes, np.int64)
    before = np.zeros(LM.num_classes, np.int64)
    ids: dict[int, set[int]] = {}
    for i in range(6):
        sem, inst = _decode(refined.read_item(i, ["label"])["label"])
        counts = np.bincount(sem, minlength=LM.num_classes)
        assert frames[i]["class_points"] == counts.tolist() and frames[i]["labelled"]
        assert frames[i]["instances"] == np.unique(inst[inst > 0]).size
        after += counts
        before += np.bincount(_decode(stitched.read_item(i, ["label"])["label"])[0], minlength=LM.num_classes)
        for t in np.unique(inst[inst > 0]):
            ids.setdefault(int(t), set()).add(i)
    assert seq["points"] == int(after.sum()) == sum(f["n_points"] for f in frames.values())
    classes = {c["class_id"]: c for c in _table(store, "label_classes")}
    for c in range(LM.num_classes):  # before refinement: from refine's transitions, = stitch's labels
        got = classes.get(c, {"points": 0, "points_before": 0})
        assert (got["points"], got["points_before"]) == (after[c], before[c]), c
    tracks = _table(store, "label_tracks")
    assert seq["tracks"] == len(tracks) == len(ids)
    assert {t["id"]: t["n_frames"] for t in tracks} == {k: len(v) for k, v in ids.items()}
    changes = store.read_table("00", P["refine"].table("refine_changes")).to_pydict()
    assert seq["changed"] == sum(changes["changed"]) and seq["class_changed"] == sum(changes["class_changed"])
    assert sum(t["points"] for t in _table(store, "refine_transitions")) == seq["class_changed"]
    plan = store.read_manifest("00", "refine").plan
    assert (seq["tracks_before"], seq["tracks_joined"], seq["tracks_dissolved"]) == (
        plan["tracks"], plan["joins"], plan["dissolved"],
    )  # fmt: skip


def test_confidence_per_class_review_queue_and_pictures(nogt):
    store, _ = nogt
    # per class: the winning probability of the points infer predicted as the class, each frame once
    align, infer = store.arrays("00", P["align"].contract), store.arrays("00", P["infer"].contract)
    n, s, owned = np.zeros(LM.num_classes), np.zeros(LM.num_classes), set()
    for v in range(align.n_items):
        src = align.read_item(v, ["source_frame"])["source_frame"]
        sel = ~np.isin(src, list(owned))
        owned |= set(np.unique(src).tolist())
        out = infer.read_item(v, ["sem", "probs"])
        p = dequantise_probs(out["probs"]).max(axis=1)
        n += np.bincount(out["sem"][sel], minlength=LM.num_classes)
        s += np.bincount(out["sem"][sel], weights=p[sel], minlength=LM.num_classes)
    for c in _table(store, "label_classes"):
        assert c["confidence_points"] == n[c["class_id"]]
        assert math.isclose(c["confidence_sum"], s[c["class_id"]], rel_tol=1e-9, abs_tol=1e-9)
    review = _table(store, "review_queue")
    assert review and min(r["points"] for r in review) >= 30  # no 1-point (or other tiny) instances
    assert [r["confidence"] for r in review] == sorted(r["confidence"] for r in review)
    conf = _table(store, "frame_confidence")
    bev = _table(store, "label_bev")
    assert [(b["sequence"], b["index"]) for b in bev] == [(c["sequence"], c["index"]) for c in conf[:6]]
    for b in bev:
        for key in ("png_class", "png_instance"):
            img = decode_png(b[key])
            assert img.shape == (240, 240, 3) and len(np.unique(img.reshape(-1, 3), axis=0)) >= 4
    legend = {r["class"]: r for r in _table(store, "class_legend")}
    assert {r["map"] for r in legend.values()} == {"model"}
    assert legend["car"]["colour"] == "#" + "".join(f"{v:02x}" for v in LM.color_map[10][::-1])


def test_the_review_queue_shows_stages_and_frame_numbers_and_the_scores_units(nogt):
    store, published = nogt
    volumes = {r["index"]: r["frames"] for r in store.read_table("00", P["align"].tables[0]).to_pylist()}
    review = _table(store, "review_queue")
    assert {r["source"].split("/")[0] for r in review} <= {"fuse", "stitch", "refine"}
    for r in review:
        if r["source"].startswith("fuse/"):  # a volume's instance: the volume's frames
            frames = volumes[r["item"]]
            assert r["frames"] == f"{min(frames)}–{max(frames)}" and len(frames) == 2
        else:  # a track: the frame it starts at
            assert r["frames"] == str(r["item"])
    assert any(r["source"].startswith("fuse/") for r in review)
    page = open(published["dashboard"], encoding="utf-8").read()
    section = page[page.index('<section id="s-review">') :]
    section = section[: section.index("</section>")]
    assert not any(r["source"] in section for r in review)  # no internal table names
    assert "<th>frames</th>" in section and "<th>confidence (0–1)</th>" in section
    first = review[0]
    assert f"<td>{first['frames']}</td>" in section
    assert "score: the frame score in %" in page and "</b> % · ±" in page  # the gallery's unit


def test_nogt_dashboard_in_headless_chromium(nogt, tmp_path):
    store, published = nogt
    with Browser(tmp_path / "profile") as browser:
        browser.open(f"file://{published['dashboard']}")
        assert browser.eval("document.body.dataset.ready") == "1"
        sections = browser.eval("Array.from(document.querySelectorAll('main > section')).map(s => s.id)")
        cells = browser.eval(
            "Array.from(document.querySelectorAll('[data-k]'))"
            ".map(e => [e.dataset.k, e.dataset.v, e.textContent])"
        )
        legend = browser.eval(
            "Array.from(document.querySelectorAll('#s-confidence .gallery ~ .legend .key[data-class]'))"
            ".map(e => e.textContent)"
        )
        rects = browser.eval(
            "Array.from(document.querySelectorAll('svg.chart, .bev img')).map(e => {"
            " const r = e.getBoundingClientRect();"
            " return [e.id || e.alt, r.left + scrollX, r.top + scrollY, r.width, r.height]; })"
        )
        browser.eval("window.scrollTo(0, 0)")
        png = browser.screenshot()
        errors, requests = browser.errors(), browser.requests()
    (tmp_path / "dashboard-nogt.png").write_bytes(png)  # the test's artifact: the whole page
    assert errors == []
    assert requests and all(u.startswith(("file:", "data:")) for u in requests), requests
    assert sections == list(LABELLED) and not set(SCORED) & set(sections)
    shown = {k: (v, t.replace("\u2009", "")) for k, v, t in cells}
    (seq,) = _table(store, "label_sequences")
    for key in ("frames", "labelled", "points", "tracks"):
        assert shown[f"lab:0:00:{key}"] == (repr(seq[key]), str(seq[key]))
    assert float(shown["lab:0:00:confidence"][1]) == pytest.approx(100 * seq["confidence"], abs=0.05)
    assert int(shown["ref:0:00:changed"][1]) == seq["changed"]
    total = seq["points"]
    for c in _table(store, "label_classes"):
        if c["points"]:
            share = float(shown[f"share:0:00:{c['class_id']}"][1])
            assert share == pytest.approx(100 * c["points"] / total, abs=0.05)
        if c["confidence_points"]:
            conf = float(shown[f"conf:0:{c['class_id']}"][1])
            assert conf == pytest.approx(100 * c["confidence_sum"] / c["confidence_points"], abs=0.05)
    for b in _table(store, "label_bev"):
        assert shown[f"lbev:0:{b['rank']}"][0] == repr(b["score"])
    names = {r["class"] for r in _table(store, "class_legend")}
    assert legend and set(legend) <= names and "car" in legend  # the pictures' class legend
    img = decode_png(png)[:, :, :3]
    assert len(rects) >= 6 + 2 * 6  # share, confidence, changed and bar charts; 6 picture pairs
    for name, x, y, w, h in rects:
        crop = img[int(y) : int(y + h), int(x) : int(x + w)]
        assert crop.size, name
        ink = (crop.astype(int).sum(axis=2) < 700).mean()
        assert ink > 0.01 and len(np.unique(crop.reshape(-1, 3), axis=0)) >= 3, (name, ink)


def test_dashboard_command_builds_the_report_and_refuses_a_file(nogt, tmp_path):
    store, _ = nogt
    root = tmp_path / "run"
    shutil.copytree(store.uri, root)
    for name in REPORT_TABLES:  # a run labelled before the report existed
        RunStore(root).remove_run_table(REPORT_TABLES[name])
    (root / "dashboard.html").unlink()
    env = {"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"}
    out = tmp_path / "d.html"
    res = subprocess.run(
        cli("dashboard", str(root), "--out", str(out)), cwd=REPO, env=env, capture_output=True, text=True
    )
    assert res.returncode == 0, res.stderr
    assert report_is_current(RunStore(root)) and 'id="s-labelled"' in out.read_text()
    assert pq.read_table(root / "tables" / "label_sequences" / "part-0.parquet").num_rows == 1
    for target, want in (
        (root / "run.json", f"error: {root / 'run.json'}: is a file, not a run folder"),
        (tmp_path, f"error: {tmp_path / 'run.json'}: no run config here"),
    ):
        res = subprocess.run(
            cli("dashboard", str(target), "--out", str(out)),
            cwd=REPO,
            env=env,
            capture_output=True,
            text=True,
        )
        assert res.returncode == 2 and want in res.stderr and len(res.stderr.splitlines()) == 1, res.stderr
    res = subprocess.run(
        cli("dashboard", str(root), "--out", str(tmp_path)), cwd=REPO, env=env, capture_output=True, text=True
    )
    assert res.returncode == 2 and "is a folder" in res.stderr and not list(tmp_path.glob(".*.tmp"))


@pytest.mark.slow
def test_label_flow_publishes_the_dashboard_of_an_unlabelled_log(prefect_api_url, nogt, tmp_path):
    from flows.label import label_dataset
    from tests.helpers.label_request import req

    store, _ = nogt
    run = store.read_run_config()
    root = tmp_path / "run"
    options = {"block_size": 3}
    label_dataset(req(run["data"], root, ["00"], run["stages"], options, method_options={"refine": True}))
    page = (root / "dashboard.html").read_text()
    assert 'id="s-labelled"' in page and 'id="s-refine"' in page and 'id="s-headline"' not in page
    seq = RunStore(root).read_all(REPORT_TABLES["label_sequences"]).to_pylist()[0]
    assert (seq["labelled"], seq["scored"], seq["refined"]) == (6, False, True)
