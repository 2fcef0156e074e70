// roadtruth report: leaderboard metric switch, colouring and sorting; plots drawn when scrolled into view.
(function () {
  "use strict";

  function fmt(v) {
    if (v === null || v === undefined || !isFinite(v)) return "—";
    var a = Math.abs(v);
    if (a !== 0 && (a < 1e-3 || a >= 1e5)) return v.toExponential(2);
    return String(Number(v.toPrecision(3)));
  }

  // Badness in [0, 1] of one value against its column (0 = best).
  function badness(v, col, sense) {
    if (v === null || !isFinite(v)) return 1;
    if (sense === "high") return Math.min(1, Math.max(0, (1 - v) / 0.3));
    if (sense === "one") return Math.min(1, Math.abs(Math.log10(Math.max(v, 1e-12))));
    var finite = col.filter(function (x) { return x !== null && isFinite(x); }).map(Math.abs);
    if (!finite.length) return 1;
    var best = Math.min.apply(null, finite), worst = Math.max.apply(null, finite);
    if (best > 0) return Math.min(1, Math.log10(Math.abs(v) / best));
    return worst > 0 ? Math.abs(v) / worst : 0;
  }

  function score(v, sense) {  // lower = better, for ranking
    if (v === null || !isFinite(v)) return Infinity;
    if (sense === "high") return -v;
    if (sense === "one") return Math.abs(Math.log(Math.max(v, 1e-12)));
    return Math.abs(v);
  }

  function paintTable(table, metric, sense) {
    var rows = Array.prototype.slice.call(table.tBodies[0].rows);
    if (!rows.length) return;
    var ncell = rows[0].querySelectorAll("td.cell").length;
    var ranks = rows.map(function () { return []; });
    for (var j = 0; j < ncell; j++) {
      var cells = rows.map(function (r) { return r.querySelectorAll("td.cell")[j]; });
      var vals = cells.map(function (c) {
        if (!c || c.dataset.status !== "ok" || !c.dataset.values) return null;
        var v = JSON.parse(c.dataset.values)[metric];
        return (v === null || v === undefined) ? null : v;
      });
      var present = cells.map(function (c) { return c && c.dataset.status !== "absent"; });
      var order = vals.map(function (v, i) { return [score(v, sense), i]; })
        .filter(function (p, i) { return present[i]; })
        .sort(function (a, b) { return a[0] - b[0]; });
      order.forEach(function (p, k) { ranks[p[1]].push(k + 1); });
      cells.forEach(function (c, i) {
        if (!c || c.dataset.status !== "ok") return;
        var v = vals[i];
        c.textContent = fmt(v);
        if (v === null) { c.style.background = "#f2f4f7"; return; }
        var b = badness(v, vals, sense);
        c.style.background = "hsl(" + Math.round(125 * (1 - b)) + ", 62%, " + (88 - 6 * (1 - Math.abs(0.5 - b))) + "%)";
      });
    }
    rows.forEach(function (r, i) {
      var rk = ranks[i];
      var cell = r.querySelector("td.rank");
      var m = rk.length ? rk.reduce(function (a, b) { return a + b; }, 0) / rk.length : null;
      cell.textContent = m === null ? "—" : m.toFixed(1);
      cell.dataset.sortValue = m === null ? "Infinity" : String(m);
    });
  }

  function paintAll() {
    var input = document.querySelector("input[name=lb-metric]:checked");
    if (!input) return;
    document.querySelectorAll("table.leaderboard").forEach(function (t) {
      paintTable(t, input.value, input.dataset.sense);
    });
  }

  function sortValue(cell, kind) {
    if (kind === "text") return cell.textContent.trim().toLowerCase();
    if (cell.dataset.sortValue !== undefined) return parseFloat(cell.dataset.sortValue);
    var v = parseFloat(cell.textContent);
    if (cell.classList.contains("failed") || cell.classList.contains("absent") || isNaN(v)) return Infinity;
    var input = document.querySelector("input[name=lb-metric]:checked");
    return input ? score(v, input.dataset.sense) : v;
  }

  function makeSortable(table) {
    var heads = table.tHead.rows[0].cells;
    Array.prototype.forEach.call(heads, function (th, col) {
      th.addEventListener("click", function () {
        var dir = th.dataset.dir === "asc" ? "desc" : "asc";
        Array.prototype.forEach.call(heads, function (h) { delete h.dataset.dir; });
        th.dataset.dir = dir;
        var body = table.tBodies[0];
        var rows = Array.prototype.slice.call(body.rows);
        var kind = th.dataset.sort || "num";
        rows.sort(function (a, b) {
          var x = sortValue(a.cells[col], kind), y = sortValue(b.cells[col], kind);
          var c = x < y ? -1 : x > y ? 1 : 0;
          return dir === "asc" ? c : -c;
        });
        rows.forEach(function (r) { body.appendChild(r); });
      });
    });
  }

  function drawPlot(div) {
    if (div.dataset.drawn) return;
    var node = document.getElementById(div.dataset.spec);
    if (!node || typeof Plotly === "undefined") return;
    var spec = JSON.parse(node.textContent);
    div.innerHTML = "";
    Plotly.newPlot(div, spec.data, spec.layout, { responsive: true, displaylogo: false });
    div.dataset.drawn = "1";
    document.body.dataset.plotsDrawn = String(document.querySelectorAll("div.plot[data-drawn]").length);
  }

  function setupPlots() {
    var plots = document.querySelectorAll("div.plot[data-spec]");
    if (!("IntersectionObserver" in window)) { plots.forEach(drawPlot); return; }
    var io = new IntersectionObserver(function (entries) {
      entries.forEach(function (e) {
        if (e.isIntersecting) { drawPlot(e.target); io.unobserve(e.target); }
      });
    }, { rootMargin: "600px 0px" });
    plots.forEach(function (p) { io.observe(p); });
  }

  function reportImages() {
    var imgs = document.querySelectorAll("img");
    var ok = 0, broken = 0;
    imgs.forEach(function (im) { if (im.complete && im.naturalWidth > 0) ok++; else broken++; });
    document.body.dataset.imagesOk = String(ok);
    document.body.dataset.imagesBroken = String(broken);
    document.body.dataset.plotsDrawn = String(document.querySelectorAll("div.plot[data-drawn]").length);
    document.body.dataset.jsErrors = String(window.__roadtruthErrors.length);
    if (window.__roadtruthErrors.length) document.body.dataset.jsErrorText = window.__roadtruthErrors.join(" | ");
  }

  document.querySelectorAll("input[name=lb-metric]").forEach(function (i) { i.addEventListener("change", paintAll); });
  document.querySelectorAll("table.leaderboard").forEach(makeSortable);
  paintAll();
  setupPlots();
  if (document.readyState === "complete") reportImages();
  else window.addEventListener("load", reportImages);
})();
