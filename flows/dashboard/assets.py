# ruff: noqa: E501  (inline stylesheet and script: one rule per line reads better)
"""The page's inline stylesheet and script (no external resources)."""

CSS = """
:root { --fg:#1d2330; --muted:#5d6677; --line:#dde1e8; --bg:#f6f7f9; --card:#fff; --up:#1a7f37; --down:#c62828; }
* { box-sizing: border-box; }
body { margin:0; font:14px/1.45 system-ui, -apple-system, "Segoe UI", sans-serif; color:var(--fg); background:var(--bg); }
header { background:#1d2330; color:#fff; padding:14px 28px; }
header h1 { margin:0; font-size:20px; }
header .sub { color:#b8c0cc; font-size:12px; }
nav { position:sticky; top:0; z-index:2; background:#fff; border-bottom:1px solid var(--line); padding:6px 28px; }
nav a { margin-right:16px; color:#2b5fab; text-decoration:none; font-size:13px; }
main { padding:8px 28px 40px; max-width:1400px; }
section { background:var(--card); border:1px solid var(--line); border-radius:8px; padding:12px 18px 16px; margin:16px 0; }
h2 { margin:4px 0 10px; font-size:17px; }
h3 { margin:14px 0 6px; font-size:14px; color:var(--muted); }
table { border-collapse:collapse; margin:4px 0 10px; font-size:13px; }
th, td { padding:3px 9px; border-bottom:1px solid var(--line); white-space:nowrap; }
th { text-align:left; background:#f0f2f5; font-weight:600; position:relative; }
table.sortable th { cursor:pointer; }
table.num td { text-align:right; font-variant-numeric:tabular-nums; }
table.num td:first-child { text-align:left; }
tr.meta td { color:var(--muted); font-size:12px; }
td.up { color:var(--up); } td.down { color:var(--down); }
.cards { display:flex; gap:12px; flex-wrap:wrap; margin-bottom:10px; }
.card { background:#f0f4fa; border-radius:8px; padding:8px 16px; min-width:110px; text-align:center; color:var(--muted); }
.card .big { font-size:28px; font-weight:650; color:var(--fg); }
.swatch { display:inline-block; width:10px; height:10px; border-radius:2px; margin-right:5px; vertical-align:-1px; }
.row { display:flex; gap:24px; flex-wrap:wrap; }
figure { margin:6px 0; }
figcaption { font-size:12px; color:var(--muted); }
svg.chart { display:block; background:#fff; }
svg .grid { stroke:#e6e8ec; stroke-width:1; }
svg .axis { fill:#7a8394; }
svg .lbl { fill:#1d2330; }
svg .val { fill:#5d6677; font-size:10px; }
svg .area { fill:#cfd5de; opacity:.75; }
svg .pts { fill:#9aa3b2; }
svg .cursor { stroke:#1d2330; stroke-width:1; stroke-dasharray:3 3; }
.framebox { position:relative; }
.tip { position:absolute; top:4px; right:70px; background:rgba(29,35,48,.88); color:#fff; font-size:12px;
       padding:4px 8px; border-radius:4px; pointer-events:none; display:none; }
.gallery { display:flex; flex-wrap:wrap; gap:14px; }
.bev .pair { display:flex; gap:4px; }
.bev img { width:240px; height:240px; image-rendering:pixelated; border-radius:4px; }
.note { color:var(--muted); font-size:12px; margin:2px 0 6px; }
.warn { color:#b45309; font-weight:600; margin:4px 0; }
h4 { margin:12px 0 4px; font-size:13px; color:var(--muted); font-weight:600; }
.legend { display:flex; flex-wrap:wrap; gap:4px 14px; margin:4px 0 10px; font-size:12px; }
.legend .key { white-space:nowrap; }
.legend .swatch { width:12px; height:12px; border:1px solid #c4c9d2; }
.scroll { max-height:430px; overflow:auto; display:inline-block; border-bottom:1px solid var(--line); }
"""

JS = """
(function () {
  function sortTable(th) {
    var table = th.closest('table'), idx = Array.prototype.indexOf.call(th.parentNode.children, th);
    var body = table.tBodies[0], rows = Array.prototype.slice.call(body.rows);
    var dir = th.getAttribute('data-dir') === 'asc' ? -1 : 1;
    th.setAttribute('data-dir', dir === 1 ? 'asc' : 'desc');
    function key(row) {
      var c = row.cells[idx], v = c.getAttribute('data-v');
      var n = v === null || v === '' || v === 'None' ? NaN : parseFloat(v);
      return isNaN(n) ? c.textContent : n;
    }
    rows.sort(function (a, b) {
      var x = key(a), y = key(b);
      if (typeof x === 'number' && typeof y === 'number') { return dir * (x - y); }
      return dir * String(x).localeCompare(String(y));
    });
    rows.forEach(function (r) { body.appendChild(r); });
  }
  document.querySelectorAll('table.sortable th').forEach(function (th) {
    th.addEventListener('click', function () { sortTable(th); });
  });
  function pct(v) { return v === null ? '–' : (100 * v).toFixed(1); }
  document.querySelectorAll('.framebox').forEach(function (box) {
    var svg = box.querySelector('svg'), tip = box.querySelector('.tip'), cursor = svg.querySelector('.cursor');
    var data = JSON.parse(box.querySelector('script[type="application/json"]').textContent);
    var lo = +svg.dataset.lo, hi = +svg.dataset.hi, left = +svg.dataset.left, plot = +svg.dataset.plot;
    svg.addEventListener('mousemove', function (ev) {
      var r = svg.getBoundingClientRect(), x = (ev.clientX - r.left) * svg.viewBox.baseVal.width / r.width;
      var f = Math.round(lo + (x - left) / plot * Math.max(hi - lo, 1));
      var i = data.index.indexOf(f);
      if (i < 0) { tip.style.display = 'none'; return; }
      var cx = left + plot * (f - lo) / Math.max(hi - lo, 1);
      cursor.setAttribute('x1', cx); cursor.setAttribute('x2', cx);
      var lines = ['frame ' + data.frame_id[i] + ' · ' + data.points[i] + ' points'];
      data.runs.forEach(function (run) { lines.push(run.label + ': PQ ' + pct(run.pq[i])); });
      tip.textContent = lines.join('  |  ');
      tip.style.display = 'block';
    });
    svg.addEventListener('mouseleave', function () { tip.style.display = 'none'; });
  });
  document.body.setAttribute('data-ready', '1');
})();
"""
