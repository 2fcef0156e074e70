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

  function score(v, sense) {  // lower = better, for sorting a scenario column
    if (v === null || !isFinite(v)) return Infinity;
    if (sense === "high") return -v;
    if (sense === "one") return Math.abs(Math.log(Math.max(v, 1e-12)));
    return Math.abs(v);
  }

  // Values and colours per cell; ranks are not computed here: they come from the report builder
  // (data-ranks on cells, data-mean-ranks on rows), the same numbers as the summary cards.
  function paintTable(table, metric, sense) {
    var rows = Array.prototype.slice.call(table.tBodies[0].rows);
    if (!rows.length) return;
    var ncell = rows[0].querySelectorAll("td.cell").length;
    for (var j = 0; j < ncell; j++) {
      var cells = rows.map(function (r) { return r.querySelectorAll("td.cell")[j]; });
      var vals = cells.map(function (c) {
        if (!c || c.dataset.status !== "ok" || !c.dataset.values) return null;
        var v = JSON.parse(c.dataset.values)[metric];
        return (v === null || v === undefined) ? null : v;
      });
      cells.forEach(function (c, i) {
        if (!c || c.dataset.status !== "ok") return;
        var v = vals[i];
        var rk = c.dataset.ranks ? JSON.parse(c.dataset.ranks)[metric] : null;
        c.textContent = fmt(v);
        if (rk) {
          var sup = document.createElement("sup");
          sup.className = "rk";
          sup.textContent = "#" + rk;
          c.appendChild(sup);
        }
        c.dataset.sortValue = v === null ? "Infinity" : String(score(v, sense));
        if (v === null) { c.style.background = "#f2f4f7"; return; }
        var b = badness(v, vals, sense);
        c.style.background = "hsl(" + Math.round(125 * (1 - b)) + ", 62%, " + (88 - 6 * (1 - Math.abs(0.5 - b))) + "%)";
      });
    }
    rows.forEach(function (r) {
      var all = r.dataset.meanRanks ? JSON.parse(r.dataset.meanRanks) : {};
      var mr = all[metric] || { mean: null, n: 0, of: 0 };
      var cell = r.querySelector("td.rank");
      cell.textContent = "";
      if (mr.mean === null || mr.mean === undefined) {
        cell.textContent = "—";
        cell.title = "not ranked in any scenario for this metric";
      } else {
        cell.appendChild(document.createTextNode(mr.mean.toFixed(1) + " "));
        var cov = document.createElement("span");
        cov.className = "cov";
        cov.textContent = "over " + mr.n + " of " + mr.of;
        cell.appendChild(cov);
        cell.title = "mean rank over the " + mr.n + " of " + mr.of + " scenarios where it was scored";
      }
      cell.dataset.sortValue = (mr.mean === null || mr.mean === undefined) ? "Infinity" : String(mr.mean);
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
    return Infinity;  // failed, not applicable and empty cells sort after every scored one
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

  // Compact figure arrays (harness/report/plot_data.py says the forms): integer steps on a decimal
  // or time grid, shared arrays, and an error drawn as estimate minus truth.
  var VARINT = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-_";

  function readVarints(text) {  // zigzag integers, 5 bits a character, 32 = more follows
    var out = [], value = 0, scale = 1, i, c;
    for (i = 0; i < text.length; i++) {
      c = VARINT.indexOf(text.charAt(i));
      value += (c & 31) * scale;  // arithmetic, not bit operations: values reach 2^51
      if (c & 32) { scale *= 32; continue; }
      out.push(value % 2 ? -(value + 1) / 2 : value / 2);
      value = 0; scale = 1;
    }
    return out;
  }

  function expandArray(a, arrays) {
    if (a && a.ref !== undefined) a = arrays[a.ref];
    if (!a || Array.isArray(a) || a.dk === undefined) return a;
    if (a._values) return a._values;  // a shared array is expanded once
    var steps = readVarints(a.dk), i, acc = 0;
    if (a.order === 2) for (i = 0; i < steps.length; i++) { acc += steps[i]; steps[i] = acc; }
    var dk = a.k0 === undefined ? [] : [0].concat(steps);
    var n = dk.length, out = new Array(n), k = a.k0 || 0;
    var p = Math.pow(10, Math.abs(a.exp || 0)), off = a.offset || 0;
    for (i = 0; i < n; i++) {
      k += dk[i];
      out[i] = a.step !== undefined ? off + k * a.step : (a.exp < 0 ? k / p : k * p);
    }
    (a.nan || []).forEach(function (g) { for (i = g[0]; i < g[0] + g[1]; i++) out[i] = null; });
    a._values = out;
    return out;
  }

  function expandFigure(spec) {
    var arrays = spec.arrays || [], grid = spec.grid;
    if (spec.note_defaults && spec.layout.annotations) {
      spec.layout.annotations = spec.layout.annotations.map(function (a) { return Object.assign({}, spec.note_defaults, a); });
    }
    spec.data.forEach(function (t) {
      if (grid && !("x" in t) && !("x0" in t)) { t.x0 = grid.x0; t.dx = grid.dx; }
      if ("x" in t) t.x = expandArray(t.x, arrays);
      if ("y" in t && !(t.y && (t.y.minus || t.y.around))) t.y = expandArray(t.y, arrays);
    });
    spec.data.forEach(function (t) {
      if (!(t.y && t.y.around)) return;
      var c = spec.data[t.y.around[0]].y, h = expandArray({ ref: t.y.around[1] }, arrays), s = t.y.side;
      t.y = c.map(function (v, i) { return v === null || h[i] === null ? null : v + s * h[i]; });
    });
    spec.data.forEach(function (t) {
      if (!(t.y && t.y.minus)) return;
      var a = spec.data[t.y.minus[0]].y, b = spec.data[t.y.minus[1]].y, w = t.y.wrap;
      t.y = a.map(function (v, i) {
        if (v === null || b[i] === null || b[i] === undefined) return null;
        var d = v - b[i];
        return w ? w / 2 - (((w / 2 - d) % w) + w) % w : d;
      });
    });
    return spec;
  }

  function drawPlot(div) {
    if (div.dataset.drawn) return;
    var node = document.getElementById(div.dataset.spec);
    if (!node || typeof Plotly === "undefined") return;
    var spec = expandFigure(JSON.parse(node.textContent));
    div.innerHTML = "";
    // On a narrow screen the horizontal legend wraps onto many rows: give the figure the height
    // those rows take, so the plot area itself keeps its size.
    var w = div.clientWidth || window.innerWidth;
    var layout = spec.layout;
    if (layout.legend && layout.legend.orientation === "h" && w < 700) {
      var n = spec.data.filter(function (t) { return t.showlegend !== false && t.name; }).length;
      var perRow = Math.max(1, Math.floor(w / 140));
      layout.height = (layout.height || 450) + 22 * Math.ceil(n / perRow);
      layout.margin = Object.assign({}, layout.margin || {}, { l: 44, r: 4 });
    }
    // The tool bar would cover the title on a narrow screen; zoom and pan still work by touch.
    Plotly.newPlot(div, spec.data, layout, { responsive: true, displaylogo: false, displayModeBar: w >= 700 ? "hover" : false });
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
