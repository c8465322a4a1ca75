// uavsearch view: draws the scene and the frames the server streams (see docs/view.md).
// Frames: {k: step, u: [[x, y, heading, task, silent, steered] | null per UAV], p: plans, l: cells looked at,
//          f: [[cell, uav]] first found this step, m: [found, eq. 30, lambda_2, min distance], t: MST edges}
"use strict";
(() => {
  const COLOURS = ["#2563eb", "#dc2626", "#059669", "#d97706", "#7c3aed",
    "#db2777", "#0891b2", "#65a30d", "#9333ea", "#ea580c"];
  const SILENT = "#9aa1ad";
  const ZONE = "#3f3f46";  // no-fly zones and their keep-out
  const TRACK_POINTS = 3000;
  const $ = (id) => document.getElementById(id);
  const colour = (i) => COLOURS[i % COLOURS.length];

  const params = new URLSearchParams(location.search);
  const runQuery = new URLSearchParams();
  for (const k of ["algorithm", "run"]) if (params.has(k)) runQuery.set(k, params.get(k));

  const st = {
    scene: null, frames: [], cur: -1, looks: null, looksAt: -1, live: false,
    playing: null, status: {}, cells: null, drawQueued: false,
  };

  // -- scene -------------------------------------------------------------------------------------
  function setupScene(scene) {
    st.scene = scene;
    st.live = scene.mode === "live";
    const g = scene.grid, n = scene.prior.length;
    const x = new Float64Array(n), y = new Float64Array(n), at = new Map();
    for (let p = 0; p < n; p++) {
      x[p] = g.x0 + g.cols[p] * g.cell;
      y[p] = g.y0 + g.rows[p] * g.cell;
      at.set(g.cols[p] + "," + g.rows[p], p);
    }
    let pmax = 0;
    for (const v of scene.prior) pmax = Math.max(pmax, v);
    const heat = scene.prior.map((v) => heatColour(pmax > 0 ? v / pmax : 0));
    const byLabel = new Map(), edges = [];
    if (scene.labels) {
      scene.labels.forEach((j, p) => { if (!byLabel.has(j)) byLabel.set(j, []); byLabel.get(j).push(p); });
      for (let p = 0; p < n; p++) {
        const right = at.get((g.cols[p] + 1) + "," + g.rows[p]);
        const up = at.get(g.cols[p] + "," + (g.rows[p] + 1));
        const h = g.cell / 2;
        if (right !== undefined && scene.labels[right] !== scene.labels[p])
          edges.push([x[p] + h, y[p] - h, x[p] + h, y[p] + h]);
        if (up !== undefined && scene.labels[up] !== scene.labels[p])
          edges.push([x[p] - h, y[p] + h, x[p] + h, y[p] + h]);
      }
    }
    st.cells = { n, x, y, heat, byLabel, edges };
    st.looks = new Int32Array(n);
    st.looksAt = -1;
    // the map shows the fence (UAVs may turn out there) and every zone's keep-out, even one outside it
    const outline = [...(scene.fence || scene.region), ...(scene.nofly || []).flatMap((z) => z.inflated[0])];
    const xs = outline.map((v) => v[0]), ys = outline.map((v) => v[1]);
    st.bounds = [Math.min(...xs), Math.min(...ys), Math.max(...xs), Math.max(...ys)];
    $("title").textContent = `${scene.mission} · ${scene.algorithm} · ${scene.n_uavs} UAVs`;
    $("mode").textContent = st.live ? "live" : "replay";
    $("mode").classList.toggle("replay", !st.live);
    $("target-total").textContent = scene.targets;
    $("follow-label").hidden = !st.live;
    document.title = `uavsearch view: ${scene.mission}`;
    if (!st.live && scene.runs.length > 1) {
      const sel = $("run-select");
      for (const [alg, run] of scene.runs) {
        const o = document.createElement("option");
        o.value = `${alg}/${run}`;
        o.textContent = `${alg} run ${run}`;
        o.selected = alg === scene.algorithm && run === scene.run;
        sel.appendChild(o);
      }
      sel.onchange = () => {
        const [alg, run] = sel.value.split("/");
        location.search = `?algorithm=${encodeURIComponent(alg)}&run=${run}`;
      };
      $("run-picker").hidden = false;
    }
    buildUavTable();
  }

  function heatColour(t) {  // 0 -> pale, 1 -> deep red
    const stops = [[255, 247, 214], [245, 158, 11], [185, 28, 28]];
    const s = Math.min(1, Math.max(0, t)) * 2, i = Math.min(1, Math.floor(s)), f = s - i;
    const c = stops[i].map((v, k) => Math.round(v + f * (stops[i + 1][k] - v)));
    return `rgb(${c[0]},${c[1]},${c[2]})`;
  }

  function buildUavTable() {
    const body = $("uavs").tBodies[0];
    body.innerHTML = "";
    for (let i = 0; i < st.scene.n_uavs; i++) {
      const tr = document.createElement("tr");
      tr.dataset.uav = i;
      tr.innerHTML = `<td><span class="dot" style="background:${colour(i)}"></span>U${i}</td>` +
        "<td>–</td><td>–</td><td>–</td><td>–</td><td>–</td>";
      body.appendChild(tr);
    }
  }

  // -- frames ------------------------------------------------------------------------------------
  function addFrames(frames) {
    const wasLast = st.cur === st.frames.length - 1;
    for (const f of frames) st.frames.push(f);
    const slider = $("slider");
    slider.max = Math.max(0, st.frames.length - 1);
    if (st.cur < 0 || (st.live && $("follow").checked) || (!st.live && wasLast && !st.playing))
      setCur(st.frames.length - 1);
    else queueDraw();
  }

  function setCur(i) {
    st.cur = Math.max(0, Math.min(i, st.frames.length - 1));
    $("slider").value = st.cur;
    queueDraw();
  }

  function looksUpTo(i) {
    if (i < st.looksAt) { st.looks.fill(0); st.looksAt = -1; }
    for (let j = st.looksAt + 1; j <= i; j++) for (const c of st.frames[j].l) st.looks[c]++;
    st.looksAt = i;
  }

  function foundUpTo(i) {
    const out = [];
    for (let j = 0; j <= i; j++) for (const [cell, uav] of st.frames[j].f) out.push({ cell, uav, k: st.frames[j].k });
    return out;
  }

  // -- drawing -----------------------------------------------------------------------------------
  function queueDraw() {
    if (st.drawQueued) return;
    st.drawQueued = true;
    requestAnimationFrame(() => { st.drawQueued = false; draw(); });
  }

  function draw() {
    if (!st.scene || st.cur < 0) return;
    const f = st.frames[st.cur];
    looksUpTo(st.cur);
    const found = foundUpTo(st.cur);
    drawMap(f, found);
    drawPanel(f, found);
    for (const c of document.querySelectorAll("canvas.chart")) drawChart(c);
    $("step-label").textContent = `step ${f.k} (${st.cur + 1}/${st.frames.length})`;
    document.body.dataset.step = f.k;
    document.body.dataset.frames = st.frames.length;
  }

  function fit(canvas) {
    const dpr = window.devicePixelRatio || 1, w = canvas.clientWidth, h = canvas.clientHeight;
    if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
      canvas.width = Math.round(w * dpr);
      canvas.height = Math.round(h * dpr);
    }
    const ctx = canvas.getContext("2d");
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, w, h);
    return [ctx, w, h];
  }

  function drawMap(f, found) {
    const sc = st.scene, cells = st.cells, canvas = $("map");
    const [ctx, w, h] = fit(canvas);
    const [x0, y0, x1, y1] = st.bounds, m = 36;
    const s = Math.min((w - 2 * m) / (x1 - x0), (h - 2 * m) / (y1 - y0));
    const ox = (w - s * (x1 - x0)) / 2 - s * x0, oy = (h + s * (y1 - y0)) / 2 + s * y0;
    const X = (x) => ox + s * x, Y = (y) => oy - s * y;
    Object.assign(canvas.dataset, { ox, oy, scale: s });  // world -> CSS pixels, for inspection
    const base = $("base").value, half = sc.grid.cell / 2, side = s * sc.grid.cell + 0.6;

    for (let p = 0; p < cells.n; p++) {  // prior and fused uncertainty
      const eta = Math.pow(sc.gamma, st.looks[p]);  // eta / eta0
      if (base === "uncertainty") {
        const v = Math.round(255 - 190 * eta);
        ctx.fillStyle = `rgb(${v},${v},${Math.min(255, v + 12)})`;
      } else ctx.fillStyle = cells.heat[p];
      ctx.fillRect(X(cells.x[p] - half), Y(cells.y[p] + half), side, side);
      if (base === "both" && st.looks[p] > 0) {
        ctx.fillStyle = `rgba(236,239,243,${0.82 * (1 - eta)})`;
        ctx.fillRect(X(cells.x[p] - half), Y(cells.y[p] + half), side, side);
      }
    }
    drawZones(ctx, sc.nofly || [], X, Y);
    ctx.beginPath();  // region
    sc.region.forEach(([x, y], i) => (i ? ctx.lineTo(X(x), Y(y)) : ctx.moveTo(X(x), Y(y))));
    ctx.closePath();
    ctx.strokeStyle = "#1d2330";
    ctx.lineWidth = 1.5;
    ctx.stroke();
    if (sc.fence) {  // the fence: the region and its operating margin
      ctx.beginPath();
      sc.fence.forEach(([x, y], i) => (i ? ctx.lineTo(X(x), Y(y)) : ctx.moveTo(X(x), Y(y))));
      ctx.closePath();
      ctx.setLineDash([4, 4]);
      ctx.strokeStyle = "#8a94a6";
      ctx.lineWidth = 1;
      ctx.stroke();
      ctx.setLineDash([]);
    }

    const uavs = f.u.map((u, i) => (u ? { i, x: u[0], y: u[1], h: u[2], task: u[3], silent: silent(i, u), adrift: adrift(u) } : null))
      .filter(Boolean);
    if ($("show-cvt").checked && sc.labels) {
      for (const u of uavs) {  // assigned regions
        if (u.task < 0 || u.silent) continue;
        ctx.fillStyle = colour(u.i) + "38";
        for (const p of cells.byLabel.get(u.task) || [])
          ctx.fillRect(X(cells.x[p] - half), Y(cells.y[p] + half), side, side);
      }
      ctx.beginPath();
      for (const [a, b, c, d] of cells.edges) { ctx.moveTo(X(a), Y(b)); ctx.lineTo(X(c), Y(d)); }
      ctx.strokeStyle = "rgba(55,65,81,0.35)";
      ctx.lineWidth = 1;
      ctx.stroke();
    }
    if ($("show-tracks").checked) {
      const from = Math.max(0, st.cur - TRACK_POINTS);
      for (let i = 0; i < sc.n_uavs; i++) {
        ctx.beginPath();
        let started = false;
        for (let j = from; j <= st.cur; j++) {
          const u = st.frames[j].u[i];
          if (!u) continue;
          if (started) ctx.lineTo(X(u[0]), Y(u[1])); else { ctx.moveTo(X(u[0]), Y(u[1])); started = true; }
        }
        ctx.strokeStyle = colour(i) + "99";
        ctx.lineWidth = 1.5;
        ctx.stroke();
      }
    }
    if ($("show-links").checked) {
      ctx.setLineDash([4, 4]);
      ctx.strokeStyle = "rgba(75,85,99,0.7)";
      ctx.lineWidth = 1;
      ctx.beginPath();
      for (let a = 0; a < uavs.length; a++) for (let b = a + 1; b < uavs.length; b++) {
        const ua = uavs[a], ub = uavs[b];
        if (Math.hypot(ua.x - ub.x, ua.y - ub.y) <= sc.comm_range) {
          ctx.moveTo(X(ua.x), Y(ua.y));
          ctx.lineTo(X(ub.x), Y(ub.y));
        }
      }
      ctx.stroke();
      ctx.setLineDash([]);
      ctx.strokeStyle = "#16a34a";
      ctx.lineWidth = 2.5;
      ctx.beginPath();
      for (const [a, b] of f.t) {
        const ua = f.u[a], ub = f.u[b];
        if (!ua || !ub) continue;
        ctx.moveTo(X(ua[0]), Y(ua[1]));
        ctx.lineTo(X(ub[0]), Y(ub[1]));
      }
      ctx.stroke();
    }
    if ($("show-plans").checked) {
      ctx.setLineDash([2, 3]);
      ctx.lineWidth = 2;
      for (const u of uavs) {
        const plan = f.p[u.i];
        if (!plan || !plan.length || u.silent) continue;
        ctx.strokeStyle = colour(u.i);
        ctx.beginPath();
        ctx.moveTo(X(u.x), Y(u.y));
        for (const [x, y] of plan) ctx.lineTo(X(x), Y(y));
        ctx.stroke();
      }
      ctx.setLineDash([]);
    }
    // targets: replay knows the truth (hollow until found); found ones are stars with their step
    const foundCells = new Set(found.map((t) => t.cell));
    for (const [cell, x, y] of sc.truth || []) {
      if (foundCells.has(cell)) continue;
      ctx.beginPath();
      ctx.arc(X(x), Y(y), 6, 0, 2 * Math.PI);
      ctx.strokeStyle = "#374151";
      ctx.lineWidth = 1.5;
      ctx.stroke();
    }
    ctx.font = "11px system-ui, sans-serif";
    for (const t of found) {
      const x = X(cells.x[t.cell]), y = Y(cells.y[t.cell]);
      star(ctx, x, y, 8, "#facc15", "#1d2330");
      ctx.fillStyle = "#1d2330";
      ctx.fillText(`k=${t.k}`, x + 9, y - 6);
    }
    for (const u of uavs) {  // UAVs last, on top
      const x = X(u.x), y = Y(u.y), c = u.silent ? SILENT : colour(u.i);
      if ($("show-fov").checked && !u.silent) {
        ctx.beginPath();
        ctx.arc(x, y, s * sc.fov_radius, 0, 2 * Math.PI);
        ctx.fillStyle = c + "22";
        ctx.fill();
        ctx.strokeStyle = c + "88";
        ctx.lineWidth = 1;
        ctx.stroke();
      }
      ctx.save();
      ctx.translate(x, y);
      ctx.rotate(-u.h);  // heading counter-clockwise from east; the screen's y points down
      ctx.beginPath();
      ctx.moveTo(11, 0);
      ctx.lineTo(-7, 6.5);
      ctx.lineTo(-3.5, 0);
      ctx.lineTo(-7, -6.5);
      ctx.closePath();
      ctx.fillStyle = c;
      ctx.fill();
      ctx.strokeStyle = "#fff";
      ctx.lineWidth = 1;
      if (u.silent) ctx.setLineDash([2, 2]);
      ctx.stroke();
      ctx.restore();
      ctx.font = "bold 11px system-ui, sans-serif";
      ctx.fillStyle = u.silent ? SILENT : "#1d2330";
      ctx.fillText(u.silent ? `U${u.i} silent` : u.adrift ? `U${u.i} not steered` : `U${u.i}`, x + 10, y + 14);
    }
    scaleBar(ctx, s, m, h);
    northArrow(ctx, w, m);
  }

  // no-fly zones: filled and labelled, and the keep-out (each zone grown by the operating margin) dashed
  function drawZones(ctx, zones, X, Y) {
    const path = (ring) => ring.forEach(([x, y], i) => (i ? ctx.lineTo(X(x), Y(y)) : ctx.moveTo(X(x), Y(y))));
    for (const z of zones) {
      ctx.beginPath();
      path(z.ring);
      ctx.closePath();
      ctx.fillStyle = ZONE;
      ctx.fill();
      ctx.beginPath();
      for (const ring of z.inflated) { path(ring); ctx.closePath(); }
      ctx.setLineDash([6, 4]);
      ctx.strokeStyle = ZONE;
      ctx.lineWidth = 2;
      ctx.stroke();
      ctx.setLineDash([]);
    }
    ctx.font = "bold 11px system-ui, sans-serif";
    ctx.textAlign = "center";
    ctx.textBaseline = "middle";
    ctx.lineWidth = 3;  // a halo in the zone's colour: readable where the label overhangs the zone
    ctx.strokeStyle = ZONE;
    ctx.fillStyle = "#fff";
    for (const z of zones) {
      ctx.strokeText(z.label, X(z.at[0]), Y(z.at[1]));
      ctx.fillText(z.label, X(z.at[0]), Y(z.at[1]));
    }
    ctx.textAlign = "start";
    ctx.textBaseline = "alphabetic";
  }

  // not steered: its companion says the vehicle does not fly the plan (a pilot, a failsafe, Hold)
  const adrift = (u) => u.length > 5 && !u[5];

  // silent: so marked in the frame, or (live, at the latest step) its liveliness token is gone
  function silent(i, u) {
    if (u[4]) return true;
    const s = st.status;
    return st.live && st.cur === st.frames.length - 1 && !!s.connected && !s.alive.includes(i);
  }

  function star(ctx, x, y, r, fill, stroke) {
    ctx.beginPath();
    for (let k = 0; k < 10; k++) {
      const a = -Math.PI / 2 + (k * Math.PI) / 5, rr = k % 2 ? r * 0.45 : r;
      ctx.lineTo(x + rr * Math.cos(a), y + rr * Math.sin(a));
    }
    ctx.closePath();
    ctx.fillStyle = fill;
    ctx.fill();
    ctx.strokeStyle = stroke;
    ctx.lineWidth = 1;
    ctx.stroke();
  }

  function scaleBar(ctx, s, m, h) {
    const want = 120 / s, e = Math.pow(10, Math.floor(Math.log10(want)));
    const len = [5, 2, 1].map((k) => k * e).find((v) => v <= want) || e;
    const x = m, y = h - 14, px = len * s;
    ctx.fillStyle = "#1d2330";
    ctx.fillRect(x, y - 3, px, 3);
    ctx.fillRect(x, y - 8, 1.5, 8);
    ctx.fillRect(x + px - 1.5, y - 8, 1.5, 8);
    ctx.font = "11px system-ui, sans-serif";
    ctx.fillText(len >= 1000 ? `${len / 1000} km` : `${len} m`, x + px + 6, y);
  }

  function northArrow(ctx, w, m) {
    const x = w - m, y = m;
    ctx.beginPath();
    ctx.moveTo(x, y - 16);
    ctx.lineTo(x + 7, y + 6);
    ctx.lineTo(x, y + 1);
    ctx.lineTo(x - 7, y + 6);
    ctx.closePath();
    ctx.fillStyle = "#1d2330";
    ctx.fill();
    ctx.font = "bold 12px system-ui, sans-serif";
    ctx.fillText("N", x - 4, y + 20);
  }

  // -- side panel --------------------------------------------------------------------------------
  const fmt = (v, d) => (v === null || v === undefined ? "–" : Number(v).toFixed(d));

  function drawPanel(f, found) {
    const [nFound, unc, lam, dist] = f.m;
    $("found-count").textContent = nFound;
    $("uncertainty").textContent = fmt(unc, 4);
    $("lambda2").textContent = fmt(lam, 4);
    $("min-distance").textContent = dist === null ? "–" : `${fmt(dist, 1)} m`;
    const rows = $("uavs").tBodies[0].rows;
    for (let i = 0; i < rows.length; i++) {
      const u = f.u[i], tr = rows[i], td = tr.cells;
      if (!u) { td[1].textContent = "not heard"; continue; }
      const quiet = silent(i, u);
      tr.classList.toggle("silent", quiet);
      td[1].textContent = quiet ? "silent" : adrift(u) ? "not steered" : "flying";
      td[2].textContent = fmt(u[0], 0);
      td[3].textContent = fmt(u[1], 0);
      td[4].textContent = `${(((Math.round(90 - (u[2] * 180) / Math.PI)) % 360) + 360) % 360}°`;  // from north, clockwise
      td[5].textContent = u[3] >= 0 ? u[3] : "–";
      Object.assign(tr.dataset, {
        step: f.k, x: u[0], y: u[1], heading: u[2], task: u[3], silent: quiet ? 1 : 0, steered: adrift(u) ? 0 : 1,
      });
    }
    const list = $("found-list");
    if (list.childElementCount !== found.length || list.dataset.step !== String(f.k)) {
      list.innerHTML = "";
      const cells = st.cells;
      for (const t of found) {
        const li = document.createElement("li");
        li.dataset.cell = t.cell;
        li.dataset.step = t.k;
        li.textContent = `step ${t.k}: cell ${t.cell} (${fmt(cells.x[t.cell], 0)}, ${fmt(cells.y[t.cell], 0)}) by U${t.uav}`;
        list.appendChild(li);
      }
      list.dataset.step = f.k;
    }
  }

  const SERIES = { "chart-found": 0, "chart-unc": 1, "chart-lam": 2, "chart-dist": 3 };

  function drawChart(canvas) {
    const [ctx, w, h] = fit(canvas), idx = SERIES[canvas.id], n = st.frames.length;
    let lo = Infinity, hi = -Infinity;
    for (const f of st.frames) { const v = f.m[idx]; if (v !== null) { lo = Math.min(lo, v); hi = Math.max(hi, v); } }
    if (idx === 0) { lo = 0; hi = Math.max(hi, st.scene.targets, 1); }
    if (idx === 2 || idx === 3) lo = 0;
    if (idx === 3) hi = Math.max(hi, st.scene.safety * 1.2);
    if (!(hi > lo)) { hi = lo + 1; }
    const pad = 14, X = (j) => (n > 1 ? (j / (n - 1)) * (w - 4) + 2 : w / 2);
    const Y = (v) => h - 3 - ((v - lo) / (hi - lo)) * (h - pad - 4);
    ctx.fillStyle = "#f4f5f7";
    ctx.fillRect(0, 0, w, h);
    if (idx === 3) {
      ctx.setLineDash([3, 3]);
      ctx.strokeStyle = "#dc2626";
      ctx.beginPath();
      ctx.moveTo(0, Y(st.scene.safety));
      ctx.lineTo(w, Y(st.scene.safety));
      ctx.stroke();
      ctx.setLineDash([]);
    }
    ctx.beginPath();
    let on = false;
    st.frames.forEach((f, j) => {
      const v = f.m[idx];
      if (v === null) { on = false; return; }
      if (on) ctx.lineTo(X(j), Y(v)); else { ctx.moveTo(X(j), Y(v)); on = true; }
    });
    ctx.strokeStyle = "#2563eb";
    ctx.lineWidth = 1.5;
    ctx.stroke();
    ctx.strokeStyle = "#1d2330";
    ctx.lineWidth = 1;
    ctx.beginPath();
    ctx.moveTo(X(st.cur), pad);
    ctx.lineTo(X(st.cur), h);
    ctx.stroke();
    const v = st.frames[st.cur].m[idx];
    ctx.fillStyle = "#1d2330";
    ctx.font = "11px system-ui, sans-serif";
    ctx.fillText(`${canvas.dataset.title}: ${v === null ? "–" : +Number(v).toFixed(4)}`, 4, 11);
  }

  function showStatus() {
    const s = st.status;
    let text;
    if (!st.live) text = `replay of ${s.replay || "a run"}: ${st.scene.algorithm} run ${st.scene.run}, ` +
      `${st.frames.length} steps`;
    else if (!s.connected) text = `joining the mesh… ${s.error || ""}`;
    else text = `mesh: ${s.alive.length} alive (${s.alive.map((u) => "U" + u).join(" ") || "none"})`;
    $("connection").textContent = text;
    if (st.live && s.connected !== undefined) {
      const refused = Object.entries(s.refused || {}).map(([kind, senders]) =>
        `${kind} ${Object.entries(senders).map(([who, n]) => `${n} from ${who}`).join(", ")}`);
      $("counters").textContent = `bundles received ${s.received}, malformed ${s.malformed}, `
        + `unauthenticated ${s.unauthenticated}, late ${s.late}${s.secured ? "" : " (INSECURE mesh)"}`
        + (refused.length ? `; REFUSED: ${refused.join("; ")}` : "");
    }
    document.body.dataset.malformed = s.malformed ?? "";
  }

  // -- controls ----------------------------------------------------------------------------------
  function play(on) {
    clearInterval(st.playing);
    st.playing = null;
    $("play").textContent = on ? "❚❚" : "▶";
    if (!on) return;
    if (st.cur >= st.frames.length - 1) setCur(0);
    st.playing = setInterval(() => {
      if (st.cur >= st.frames.length - 1) {
        play(false);
        if (st.live) $("follow").checked = true;
        return;
      }
      setCur(st.cur + 1);
    }, 1000 / Number($("speed").value));
  }

  $("play").onclick = () => play(!st.playing);
  $("speed").onchange = () => { if (st.playing) play(true); };
  $("slider").oninput = (e) => {
    if (st.live) $("follow").checked = Number(e.target.value) >= st.frames.length - 1;
    setCur(Number(e.target.value));
  };
  $("follow").onchange = (e) => { if (e.target.checked) setCur(st.frames.length - 1); };
  for (const id of ["base", "show-cvt", "show-links", "show-tracks", "show-plans", "show-fov"])
    $(id).onchange = queueDraw;
  window.addEventListener("resize", queueDraw);

  // -- server ------------------------------------------------------------------------------------
  function connect() {
    const proto = location.protocol === "https:" ? "wss://" : "ws://";
    const ws = new WebSocket(`${proto}${location.host}/ws?${runQuery}`);
    ws.onopen = () => {  // the server sends every frame again: start afresh
      st.frames = [];
      st.cur = -1;
      st.looks.fill(0);
      st.looksAt = -1;
    };
    ws.onmessage = (ev) => {
      const msg = JSON.parse(ev.data);
      if (msg.type === "frames") addFrames(msg.frames);
      else if (msg.type === "status") {
        const before = JSON.stringify(st.status.alive);
        st.status = msg;
        showStatus();
        if (JSON.stringify(msg.alive) !== before) queueDraw();
      }
      else if (msg.type === "error") $("connection").textContent = `error: ${msg.error}`;
    };
    ws.onclose = () => {
      if (!st.live) return;
      $("connection").textContent = "lost the view server; reconnecting…";
      setTimeout(connect, 1000);
    };
  }

  async function start() {
    const res = await fetch(`/api/scene?${runQuery}`);
    const body = await res.json();
    if (!res.ok) { $("connection").textContent = `error: ${body.error}`; return; }
    setupScene(body);
    document.body.dataset.ready = "1";
    connect();
  }

  window.uavView = st;  // for inspection from the browser's console
  start();
})();
