// The report page's behaviour: sortable tables, the plots, the query browser and the 3D view's selection.
// Plain JavaScript over the JSON in #report-data (written by semcityloc.benchmark.report_html).
"use strict";
(function () {
  const DATA = JSON.parse(document.getElementById("report-data").textContent);
  const ENTRIES = DATA.entries;
  const BY_KEY = new Map(ENTRIES.map((e) => [e.key, e]));
  const POSES = DATA.poses; // prior, estimate, truth
  const PLOT_CONFIG = { displaylogo: false, responsive: true };
  const NUMBER_LABELS = {
    err_xyz_m: "error: camera centre (m)", err_rot_deg: "error: rotation (°)", err_yaw_deg: "error: yaw (°)",
    prior_err_m: "prior error: camera centre (m)", prior_yaw_err_deg: "prior error: yaw (°)",
    score: "score", semantic: "semantic score", depth_cost: "depth cost", score_margin: "score margin",
    spread_m: "spread of good poses (m)", spread_deg: "spread of good poses (°)",
    sigma_xy_m: "1-sigma: horizontal (m)", sigma_z_m: "1-sigma: height (m)", sigma_yaw_deg: "1-sigma: yaw (°)",
    building_iou: "building IoU", probability: "acceptance probability (confidence)",
    query_miou: "query mask mIoU (%)", height_m: "height above ground (m)", t_total_s: "time (s)",
  };
  const state = { entry: null, shown: [], pose: 1, overlay: true, alpha: 0.35 };
  const $ = (id) => document.getElementById(id);
  const fmt = (v, d = 2) => (v === null || v === undefined ? "–" : Number(v).toFixed(d));

  // ------------------------------------------------------------------ sortable tables
  function cellValue(td) {
    const m = td.textContent.trim().match(/^[-+]?\d+(\.\d+)?/);
    return m ? parseFloat(m[0]) : td.textContent.trim().toLowerCase();
  }
  document.querySelectorAll("table.sortable").forEach((table) => {
    table.querySelectorAll("th").forEach((th, col) => {
      th.addEventListener("click", () => {
        const asc = !th.classList.contains("asc");
        table.querySelectorAll("th").forEach((h) => h.classList.remove("asc", "desc"));
        th.classList.add(asc ? "asc" : "desc");
        const body = table.tBodies[0];
        const rows = Array.from(body.rows);
        rows.sort((a, b) => {
          const x = cellValue(a.cells[col]), y = cellValue(b.cells[col]);
          const c = typeof x === typeof y ? (x < y ? -1 : x > y ? 1 : 0) : typeof x === "number" ? -1 : 1;
          return asc ? c : -c;
        });
        rows.forEach((r) => body.appendChild(r));
      });
    });
  });

  // ------------------------------------------------------------------ plots
  const figures = DATA.figures;
  function onPointClick(ev) {
    const p = ev.points && ev.points[0];
    if (p && typeof p.customdata === "string" && BY_KEY.has(p.customdata)) select(p.customdata, true);
  }
  for (const [id, fig] of Object.entries(figures)) {
    let div = $("plot-" + id);
    if (!div) {
      const box = document.createElement("div");
      box.innerHTML = "<h3></h3>";
      box.firstChild.textContent = fig.title;
      div = document.createElement("div");
      div.id = "plot-" + id;
      box.appendChild(div);
      $("curves-box").appendChild(box);
    }
    Plotly.newPlot(div, fig.figure.data, fig.figure.layout, PLOT_CONFIG);
    div.on("plotly_click", onPointClick);
  }
  if (!figures.city) $("plot-city").textContent = "No map could be loaded: no 3D view.";

  // ------------------------------------------------------------------ query browser
  function options(select, values, labels) {
    select.innerHTML = "";
    values.forEach((v, i) => {
      const o = document.createElement("option");
      o.value = v;
      o.textContent = labels ? labels[i] : v;
      select.appendChild(o);
    });
  }
  const uniq = (xs) => Array.from(new Set(xs));
  options($("f-run"), ["all", ...DATA.runs.map((_, i) => String(i))], ["all", ...DATA.runs.map((r) => r.label)]);
  options($("f-status"), ["all", ...uniq(ENTRIES.map((e) => e.status))]);
  options($("f-bin"), ["all", ...DATA.bins.filter((b) => ENTRIES.some((e) => e.bin === b))]);
  options($("f-view"), ["all", ...uniq(ENTRIES.map((e) => e.view)).sort()]);
  ["f-run", "f-status", "f-bin", "f-view"].forEach((id) => $(id).addEventListener("change", () => renderList()));

  function matches(e) {
    const run = $("f-run").value, st = $("f-status").value, bin = $("f-bin").value, view = $("f-view").value;
    return (run === "all" || String(e.run) === run) && (st === "all" || e.status === st)
      && (bin === "all" || e.bin === bin) && (view === "all" || e.view === view);
  }

  function renderList() {
    state.shown = ENTRIES.filter(matches);
    const body = $("q-list").tBodies[0];
    body.innerHTML = "";
    for (const e of state.shown) {
      const tr = document.createElement("tr");
      tr.dataset.key = e.key;
      const cells = [String(e.run + 1), e.qid, e.status, fmt(e.numbers.err_xyz_m), fmt(e.numbers.err_rot_deg)];
      cells.forEach((c, i) => {
        const td = document.createElement("td");
        td.textContent = c;
        if (i === 2) td.className = "st-" + e.status;
        tr.appendChild(td);
      });
      tr.title = DATA.runs[e.run].label;
      tr.addEventListener("click", () => select(e.key));
      body.appendChild(tr);
    }
    $("f-count").textContent = state.shown.length + " of " + ENTRIES.length + " queries";
    if (!state.shown.length) return;
    if (!state.entry || !state.shown.includes(state.entry)) select(state.shown[0].key);
    else markSelected();
  }

  function markSelected() {
    $("q-list").querySelectorAll("tbody tr").forEach((tr) => {
      const on = state.entry && tr.dataset.key === state.entry.key;
      tr.classList.toggle("selected", on);
      if (on) tr.scrollIntoView({ block: "nearest" });
    });
  }

  const images = new Map();
  function loadImage(uri) {
    if (!images.has(uri)) {
      images.set(uri, new Promise((resolve, reject) => {
        const img = new Image();
        img.onload = () => resolve(img);
        img.onerror = () => reject(new Error("image failed to decode"));
        img.src = uri;
      }));
    }
    return images.get(uri);
  }

  function imageBox(box, uri, missing) {
    box.innerHTML = "";
    if (uri) {
      const img = document.createElement("img");
      img.src = uri;
      box.appendChild(img);
    } else {
      box.textContent = missing;
    }
  }

  async function draw() {
    const e = state.entry;
    if (!e) return;
    const pose = POSES[state.pose];
    const layer = e.layers[pose];
    $("o-pose-name").textContent = pose;
    const canvas = $("q-canvas");
    const ctx = canvas.getContext("2d");
    // The background: the photo (or the run's overlay), else the query mask, else the map at the truth.
    const maskBase = e.background_kind === "query mask";
    const baseUri = e.background || (maskBase ? e.mask : null);
    const stand = !baseUri && e.layers.truth ? e.layers.truth.fill : null;
    const base = baseUri || stand ? await loadImage(baseUri || stand) : null;
    const fill = layer ? await loadImage(layer.fill) : null;
    const edges = layer ? await loadImage(layer.edges) : null;
    if (state.entry !== e || POSES[state.pose] !== pose) return; // a newer draw is under way
    const [w, h] = base ? [base.naturalWidth, base.naturalHeight] : e.size || [320, 240];
    canvas.width = w;
    canvas.height = h;
    ctx.fillStyle = "#777";
    ctx.fillRect(0, 0, w, h);
    if (base) {
      ctx.drawImage(base, 0, 0, w, h);
      if ((maskBase || stand) && state.overlay && layer) { // faded, so the model's edges stand out
        ctx.fillStyle = "rgba(255,255,255,0.45)";
        ctx.fillRect(0, 0, w, h);
      }
    } else {
      ctx.fillStyle = "#fff";
      ctx.font = "12px sans-serif";
      ctx.fillText("no image stored", 8, 18);
    }
    if (state.overlay && layer) {
      ctx.globalAlpha = state.alpha;
      ctx.drawImage(fill, 0, 0, w, h);
      ctx.globalAlpha = 1;
      ctx.drawImage(edges, 0, 0, w, h);
    }
    let cap = stand ? "the map at the true pose (this query's image was not kept: --keep-details)" : e.background_kind;
    // An estimate found on the map with eaves on its flat roofs is drawn on that map (found_map.py).
    const onMap = pose === "estimate" && e.estimate_map ? ", " + e.estimate_map : "";
    if (state.overlay && layer) cap += "; model at the " + pose + onMap + " (mask and edges)";
    else if (!layer) cap += "; no model drawn at the " + pose + (e.layers && Object.keys(e.layers).length ? " (no such pose)" : " (no camera stored)");
    $("q-canvas-cap").textContent = cap;
    imageBox($("q-render"), layer ? layer.fill : null, "no render at the " + pose);
    $("q-render-cap").textContent = "rendered mask at the " + pose + onMap;
    canvas.dataset.drawn = e.key + "|" + pose + "|" + (state.overlay && layer ? "on" : "off");
  }

  function numbersTable(e) {
    const t = $("q-numbers");
    t.innerHTML = "";
    for (const [k, label] of Object.entries(NUMBER_LABELS)) {
      const v = e.numbers[k];
      if (v === null || v === undefined) continue;
      const tr = t.insertRow();
      tr.insertCell().textContent = label;
      tr.insertCell().textContent = fmt(v, k.endsWith("_s") || k === "probability" ? 3 : 2);
    }
  }

  function costPlots(e) {
    const xy = $("q-cost-xy"), yaw = $("q-cost-yaw");
    if (!e.cost) {
      Plotly.purge(xy);
      Plotly.purge(yaw);
      xy.textContent = "no cost volume stored for this query (the run kept its details for the first queries only)";
      yaw.textContent = "";
      return;
    }
    xy.textContent = "";
    yaw.textContent = "";
    const c = e.cost;
    const colors = { prior: "rgb(60,120,255)", estimate: "rgb(255,0,255)", truth: "rgb(0,190,230)" };
    const marks = Object.entries(c.marks).map(([name, m]) => ({
      x: [m[0]], y: [m[1]], mode: "markers", name, type: "scatter",
      marker: { color: colors[name], size: 11, symbol: "circle-open", line: { width: 3 } },
    }));
    Plotly.react(xy, [{ type: "heatmap", x: c.x, y: c.y, z: c.xy, colorscale: "Viridis",
      colorbar: { thickness: 10 }, hovertemplate: "x %{x}, y %{y}: %{z:.3f}<extra></extra>" }, ...marks], {
      title: { text: "coarse cost, xy slice (z " + c.z + " m, yaw " + c.yaw_at + "°)", font: { size: 12 } },
      margin: { l: 50, r: 10, t: 30, b: 60 }, xaxis: { title: "x (local m)" },
      yaxis: { title: "y (local m)", scaleanchor: "x" }, showlegend: true,
      legend: { font: { size: 10 }, orientation: "h", y: -0.2 },
    }, PLOT_CONFIG);
    const shapes = Object.entries(c.marks).map(([name, m]) => ({
      type: "line", x0: m[2], x1: m[2], yref: "paper", y0: 0, y1: 1, line: { color: colors[name], dash: "dash" },
    }));
    Plotly.react(yaw, [{ x: c.yaw, y: c.yaw_scores, mode: "lines+markers", type: "scatter", name: "score" }], {
      title: { text: "yaw slice at x " + c.at[0] + ", y " + c.at[1] + ", z " + c.at[2], font: { size: 12 } },
      margin: { l: 50, r: 10, t: 30, b: 40 }, xaxis: { title: "yaw (°)" }, yaxis: { title: "score" }, shapes,
    }, PLOT_CONFIG);
  }

  function showInCity(e) {
    const div = $("plot-city");
    if (!figures.city || !div.data) return;
    const xyz = [[], [], []];
    for (const lines of Object.values(e.frusta)) for (let a = 0; a < 3; a++) xyz[a].push(...lines[a], null);
    Plotly.restyle(div, { x: [xyz[0]], y: [xyz[1]], z: [xyz[2]], name: "selected: " + e.qid }, [1]);
  }

  function select(key, scroll) {
    const e = BY_KEY.get(key);
    if (!e) return;
    state.entry = e;
    markSelected();
    $("q-title").textContent = e.qid + (e.name !== e.qid ? " (" + e.name + ")" : "") + " · " + DATA.runs[e.run].label;
    const st = $("q-status");
    st.innerHTML = "";
    const b = document.createElement("b");
    b.className = "st-" + e.status;
    b.textContent = e.status;
    st.appendChild(b);
    st.appendChild(document.createTextNode((e.reason ? " – " + e.reason : "") + " · error bin: " + e.bin + " · view: " + e.view));
    imageBox($("q-mask"), e.mask, "query mask not stored (kept for the first --keep-details queries)");
    numbersTable(e);
    costPlots(e);
    showInCity(e);
    draw();
    if (scroll) $("browser").scrollIntoView();
  }

  function step(d) {
    if (!state.shown.length) return;
    const i = Math.max(0, state.shown.indexOf(state.entry));
    select(state.shown[(i + d + state.shown.length) % state.shown.length].key);
  }
  $("q-prev").addEventListener("click", () => step(-1));
  $("q-next").addEventListener("click", () => step(1));
  $("o-on").addEventListener("change", (ev) => { state.overlay = ev.target.checked; draw(); });
  $("o-pose").addEventListener("input", (ev) => { state.pose = Number(ev.target.value); draw(); });
  $("o-alpha").addEventListener("input", (ev) => { state.alpha = Number(ev.target.value); draw(); });
  document.addEventListener("keydown", (ev) => {
    if (ev.target.tagName === "INPUT" || ev.target.tagName === "SELECT") return;
    if (ev.key === "n") step(1);
    else if (ev.key === "p") step(-1);
    else if (ev.key === "1" || ev.key === "2" || ev.key === "3") {
      state.pose = Number(ev.key) - 1;
      $("o-pose").value = String(state.pose);
      draw();
    }
  });
  renderList();
  document.body.dataset.ready = "1";
})();
