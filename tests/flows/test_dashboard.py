"""The dashboard in a real headless Chromium: no errors, no network, charts drawn, numbers = tables."""

from __future__ import annotations

import math
import subprocess

import numpy as np
import pyarrow.parquet as pq
import pytest

from dsnet_core.metrics.registry import columns
from dsnet_core.viz.png import decode_png
from flows.dashboard import build_dashboard
from tests.flows.browser import Browser
from tests.flows.conftest import REPO, cli
from tests.tasks.oracle_stitch import score_runs


@pytest.fixture(scope="module")
def runs(tmp_path_factory, synth_log):
    root = tmp_path_factory.mktemp("dash")
    uris = score_runs(root, synth_log, {"runA": 0.05, "runB": 0.15})
    page = build_dashboard(uris, root / "out" / "dashboard.html")
    return uris, page


def _table(uri: str, name: str) -> list[dict]:
    return pq.read_table(f"{uri}/tables/{name}/part-0.parquet").to_pylist()


def _headline(run: dict) -> list[str]:
    """The registered fractions a run has a value of (the dashboard's headline rows)."""
    return [c.key for c in columns("run") if c.kind == "score" and run.get(c.key) is not None]


def _expected(uris: list[str]) -> dict[str, object]:
    """Every value the page must show, keyed like the page's ``data-k``, straight from parquet."""
    out: dict[str, object] = {}
    base = _table(uris[0], "score_run")[0]
    for r, uri in enumerate(uris):
        run = _table(uri, "score_run")[0]
        for key in run:
            out[f"run:{r}:{key}"] = run[key]
        if r:
            for key in _headline(base):
                out[f"delta:{r}:{key}"] = run[key] - base[key]
        for c in _table(uri, "score_classes"):
            for key in ("pq", "sq", "rq", "iou"):
                out[f"class:{r}:{c['class']}:{key}"] = c[key]
        for s in _table(uri, "score_sequences"):
            for key in ("frames", "points", "pq", "miou", "lstq"):
                out[f"seq:{r}:{s['sequence']}:{key}"] = s[key]
        sums: dict[str, dict] = {}
        for t in _table(uri, "stage_timings"):
            acc = sums.setdefault(t["stage"], {"items": 0, "points": 0, "block_s": 0.0, "wall_s": 0.0})
            for key in acc:
                acc[key] += t[key]
        for stage, acc in sums.items():
            for key, v in acc.items():
                out[f"timing:{r}:{stage}:{key}"] = v
            out[f"timing:{r}:{stage}:items_per_s"] = acc["items"] / acc["block_s"]
        for q in _table(uri, "review_queue"):
            for key in ("instance", "points", "confidence"):
                out[f"review:{r}:{q['rank']}:{key}"] = q[key]
        for b in _table(uri, "score_bev"):
            out[f"bevpq:{r}:{b['rank']}"] = b["pq"]
    out["card:pq"] = base["pq"]
    return out


def _shown_matches(key: str, text: str, value: float) -> bool:
    """The text shown is the table's value as the page formats it (percent, 1 decimal, etc.)."""
    text = text.replace("\u2009", "")
    if key.split(":")[0] in ("run", "class", "seq", "card", "bevpq") and isinstance(value, float):
        return abs(float(text) - 100 * value) <= 0.05 + 1e-9
    if key.startswith("delta:"):
        return abs(float(text) - 100 * value) <= 0.05 + 1e-9 and text[0] in "+-"
    if key.endswith(":confidence"):
        return abs(float(text) - value) <= 5e-4
    if isinstance(value, int):
        return int(text) == value
    if key.split(":")[-1] in ("block_s", "wall_s"):
        return abs(float(text) - value) <= 0.005 + 1e-9
    if key.endswith("_per_s"):
        mult = {"k": 1e3, "M": 1e6}.get(text[-1], 1)
        return abs(float(text.rstrip("kM")) * mult - value) <= 0.005 * value
    return text == (str(value) or "–")


def test_dashboard_in_headless_chromium(runs, tmp_path):
    uris, page = runs
    with Browser(tmp_path / "profile") as browser:
        browser.open(page.resolve().as_uri())
        assert browser.eval("document.body.dataset.ready") == "1"
        cells = browser.eval(
            "Array.from(document.querySelectorAll('[data-k]'))"
            ".map(e => [e.dataset.k, e.dataset.v, e.textContent])"
        )
        rects = browser.eval(
            "Array.from(document.querySelectorAll('#s-classes svg.chart, #s-frames svg.chart, "
            "#s-timings svg.chart, #s-worst .bev img')).map(e => {"
            " const r = e.getBoundingClientRect();"
            " return [e.id || e.alt, r.left + scrollX, r.top + scrollY, r.width, r.height]; })"
        )
        legend = browser.eval(
            "Array.from(document.querySelectorAll('#s-worst .legend .key[data-class]'))"
            ".map(e => e.textContent)"
        )
        browser_text = browser.eval("document.querySelector('#s-headline').textContent")
        browser.eval("window.scrollTo(0, 0)")
        png = browser.screenshot()
        errors, requests = browser.errors(), browser.requests()
    (tmp_path / "dashboard.png").write_bytes(png)
    assert "road" in legend and "vegetation" in legend and "car" not in legend  # stuff colours; things by id
    assert errors == []
    assert requests and all(u.startswith(("file:", "data:")) for u in requests), requests
    # the numbers shown are the tables' numbers
    expected = _expected(uris)
    shown = {k: (v, t) for k, v, t in cells}
    checked = 0
    for key, want in expected.items():
        if key not in shown:
            continue
        data_v, text = shown[key]
        if key.startswith(("delta:", "timing:")) and key.split(":")[-1] not in ("items", "points"):
            assert math.isclose(float(data_v), want, rel_tol=1e-12, abs_tol=1e-15), key
        elif key.startswith("delta:"):
            pass
        else:
            assert data_v == repr(want), (key, data_v, want)
        assert _shown_matches(key, text, want), (key, text, want)
        checked += 1
    for r in range(2):
        for key in _headline(expected_run := _table(uris[r], "score_run")[0]):
            assert f"run:{r}:{key}" in shown, key
        assert f"run:{r}:pat" not in shown and expected_run["pat"] is None  # nuScenes-only: no row
    assert "classes with ground-truth points" in browser_text
    assert sum(k.startswith("class:") for k in shown) == 2 * 19 * 4
    assert checked >= 2 * (10 + 19 * 4 + 2 * 5) + 10
    # the charts and pictures are drawn: non-blank, several colours
    img = decode_png(png)[:, :, :3]
    assert len(rects) == 2 + 2 + 1 + 2 + 2 * 2 * 3  # class bars, timing bars, frame charts, BEV pairs
    for name, x, y, w, h in rects:
        crop = img[int(y) : int(y + h), int(x) : int(x + w)]
        assert crop.size, name
        ink = (crop.astype(int).sum(axis=2) < 700).mean()  # not white
        colours = len(np.unique(crop.reshape(-1, 3), axis=0))
        assert ink > 0.02 and colours >= 4, (name, ink, colours)


def test_dashboard_command(runs, tmp_path):
    uris, _ = runs
    out = tmp_path / "d.html"
    env = {"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"}
    res = subprocess.run(
        cli("dashboard", *uris, "--out", str(out)), cwd=REPO, env=env, capture_output=True, text=True
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == f"wrote dashboard {out.resolve()}"
    html = out.read_text()
    assert "http://" not in html.replace("http://www.w3.org", "") and "https://" not in html
    assert html.count("data:image/png;base64,") == 2 * 2 * 3
    res = subprocess.run(
        cli("dashboard", str(tmp_path), "--out", str(out)), cwd=REPO, env=env, capture_output=True, text=True
    )
    assert res.returncode == 2 and "no run config here (not a run store" in res.stderr


def test_frame_axis_ticks_are_round_numbers():
    from flows.dashboard.svg import ticks

    assert ticks(0, 3999) == [0, 1000, 2000, 3000]
    assert ticks(0, 5) == [0, 1, 2, 3, 4, 5]
    assert ticks(3, 120) == [20, 40, 60, 80, 100, 120]
    assert ticks(7, 7) == [7]
