// OvertakeZoo episode viewer: plays one episode exported by
//   overtakezoo replay RUN.mcap --episode K --out episode.json
// (benchmark/archive/web.py writes the format; envs/faces/render.py's TopView is the drawing it follows).
// Plain JavaScript and one <canvas>, no network beyond the episode file: ?episode=URL (default
// episode.json beside this page), a file picked or dropped on the page. Tested by tests/benchmark/test_web_viewer.py.
"use strict";

(() => {
  const FORMAT = "overtakezoo-episode", VERSION = 1;
  const MODE_COLOURS = ["#1f77b4", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2"]; // follow, overtake, abort (tab:)
  const OUTCOME_COLOURS = { success: "#2ca02c", crash: "#d62728", timeout: "#ff7f0e", offroad: "#8c564b" };
  const $ = (id) => document.getElementById(id);
  const canvas = $("view"), ctx = canvas.getContext("2d");
  const ui = { play: $("play"), slider: $("slider"), step: $("step"), time: $("time"), speed: $("speed"),
    mode: $("mode"), egoSpeed: $("ego-speed"), outcome: $("outcome"), source: $("source"), status: $("status") };
  let ep = null, k = 0, playing = false, simT = 0, lastTick = 0;

  // ---------------------------------------------------------------- loading
  function check(doc) {
    if (!doc || doc.format !== FORMAT) throw new Error("not an OvertakeZoo episode file (no \"format\": \"" + FORMAT + "\")");
    if (doc.version !== VERSION) throw new Error(`episode file version ${doc.version}; this viewer reads version ${VERSION}`);
    const n = doc.steps + 1, tr = doc.track;
    for (const key of ["t", "ego_x", "ego_y", "ego_psi", "ego_v", "mode", "rollout", "blocked"]) {
      if (!Array.isArray(tr[key]) || tr[key].length !== n) throw new Error(`track.${key} does not have ${n} steps`);
    }
    return doc;
  }

  function load(doc, name) {
    ep = check(doc);
    const sc = ep.scenario, tr = ep.track;
    ep.reveal = sc.npc_reveal.map((r) => (r === null ? Infinity : r));
    ep.sensor = sc.sensor_range === null ? Infinity : sc.sensor_range;
    // The overview's x range: start to goal, every vehicle at every step (as replay's road_extent).
    const xs = [...tr.ego_x, sc.goal_s];
    tr.npc_s.forEach((s, j) => { if (sc.npc_present[j]) xs.push(...s); });
    const lo = Math.min(...xs), hi = Math.max(...xs), pad = 0.03 * (hi - lo) + 5;
    ep.extent = [lo - pad, hi + pad];
    const src = ep.source || {};
    ui.source.textContent = `episode ${ep.episode} \u00b7 ${src.suite || "?"} \u00b7 ${src.decider || "?"} \u00b7 ${name}`;
    ui.slider.max = String(ep.steps);
    ui.status.textContent = "";
    legend();
    pause();
    show(0);
  }

  function fail(what, err) {
    ep = null;
    ui.status.textContent = `cannot load ${what}: ${err.message}`;
    draw();
  }

  function fromUrl(url) {
    fetch(url).then((r) => {
      if (!r.ok) throw new Error(`HTTP ${r.status}`);
      return r.json();
    }).then((doc) => load(doc, url)).catch((err) => fail(url, location.protocol === "file:"
      ? new Error("pages opened from disk cannot fetch files: serve the folder (python -m http.server) or pick a file")
      : err));
  }

  function fromFile(file) {
    file.text().then((text) => load(JSON.parse(text), file.name)).catch((err) => fail(file.name, err));
  }

  function legend() {
    const list = $("legend");
    list.querySelectorAll(".mode").forEach((el) => el.remove());
    ep.mode_names.slice().reverse().forEach((name, i) => {
      const li = document.createElement("li"), sw = document.createElement("i");
      li.className = "mode";
      sw.className = "sw";
      sw.style.background = modeColour(ep.mode_names.length - 1 - i);
      li.append(sw, name);
      list.prepend(li);
    });
  }

  // ---------------------------------------------------------------- playback
  function show(step) {
    if (!ep) return;
    k = Math.max(0, Math.min(ep.steps, step));
    simT = ep.track.t[k];
    ui.slider.value = String(k);
    ui.step.textContent = `step ${k} / ${ep.steps}`;
    ui.time.textContent = `t = ${simT.toFixed(1)} s`;
    const v = ep.track.ego_v[k];
    ui.mode.textContent = modeName(ep.track.mode[k]);
    ui.mode.style.color = modeColour(ep.track.mode[k]);
    ui.egoSpeed.textContent = `${v.toFixed(2)} m/s (${(v * 3.6).toFixed(1)} km/h)`;
    ui.outcome.textContent = k === ep.steps ? outcomeText() : "running";
    ui.outcome.style.color = k === ep.steps ? OUTCOME_COLOURS[ep.outcome] || "#222" : "#222";
    draw();
  }

  function play() {
    if (!ep) return;
    if (k >= ep.steps) show(0);
    playing = true;
    ui.play.textContent = "Pause";
    lastTick = performance.now();
    requestAnimationFrame(tick);
  }

  function pause() {
    playing = false;
    ui.play.textContent = "Play";
  }

  function tick(now) {
    if (!playing || !ep) return;
    simT += ((now - lastTick) / 1000) * Number(ui.speed.value);
    lastTick = now;
    const t = ep.track.t;
    let next = k;
    while (next < ep.steps && t[next + 1] <= simT) next++;
    if (next !== k) {
      const keep = simT;
      show(next);
      simT = keep;
    }
    if (k >= ep.steps) pause();
    else requestAnimationFrame(tick);
  }

  const modeName = (m) => (ep.mode_names[m] || `mode ${m}`).toUpperCase();
  const modeColour = (m) => MODE_COLOURS[m % MODE_COLOURS.length];
  const outcomeText = () => ep.outcome.toUpperCase() + (ep.outcome === "crash" && ep.crash_npc >= 0 ? ` with NPC${ep.crash_npc + 1}` : "");

  // ---------------------------------------------------------------- drawing
  // A view maps road coordinates (s along the road, d across it, the ego lane at d = 0) to canvas pixels.
  function makeView(x, y, w, h, left, right, bottom, top, equal) {
    let sx = w / (right - left), sy = h / (top - bottom);
    if (equal) { // one scale: the lanes keep their width, the extra room shows more verge
      sx = sy = Math.min(sx, sy);
      right = left + w / sx;
      const mid = (top + bottom) / 2;
      bottom = mid - h / sy / 2;
      top = mid + h / sy / 2;
    }
    return { x, y, w, h, left, right, bottom, top, sx, sy, equal,
      px: (s) => x + (s - left) * sx, py: (d) => y + (top - d) * sy };
  }

  function draw() {
    const dpr = window.devicePixelRatio || 1, W = canvas.clientWidth || 1000, H = canvas.clientHeight || 340;
    if (canvas.width !== Math.round(W * dpr) || canvas.height !== Math.round(H * dpr)) {
      canvas.width = Math.round(W * dpr);
      canvas.height = Math.round(H * dpr);
    }
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.fillStyle = "#fafafa";
    ctx.fillRect(0, 0, W, H);
    if (!ep) {
      text("no episode loaded", W / 2, H / 2, { size: 16, colour: "#555", align: "center" });
      return;
    }
    const sc = ep.scenario, tr = ep.track, w = sc.lane_width, x0 = tr.ego_x[k];
    const bottom = -w / 2 - 1, top = 1.5 * w + 1;
    const ahead = Math.min(Math.max(Number.isFinite(ep.sensor) ? ep.sensor : 100, 30), 100) + 5;
    const over = makeView(8, 22, W - 16, 88, ep.extent[0], ep.extent[1], bottom, top, false);
    const follow = makeView(8, 156, W - 16, H - 164, x0 - 15, x0 + ahead, bottom, top, true);
    text(`episode ${ep.episode}    s (m): whole road, start to goal`, 8, 14, { size: 12, colour: "#333" });
    scene(over, true);
    ticks(over);
    // The follow view's window, outlined on the overview.
    ctx.strokeStyle = "rgba(255,255,255,0.8)";
    ctx.lineWidth = 1;
    ctx.strokeRect(over.px(follow.left), over.y + 1, (follow.right - follow.left) * over.sx, over.h - 2);
    title(8, 146);
    scene(follow, false);
  }

  function scene(view, overview) {
    const sc = ep.scenario, tr = ep.track, w = sc.lane_width, x0 = tr.ego_x[k], y0 = tr.ego_y[k];
    ctx.save();
    ctx.beginPath();
    ctx.rect(view.x, view.y, view.w, view.h);
    ctx.clip();
    ctx.fillStyle = "#6b8e4e"; // verge
    ctx.fillRect(view.x, view.y, view.w, view.h);
    ctx.fillStyle = "#555555"; // road
    ctx.fillRect(view.x, view.py(1.5 * w), view.w, 2 * w * view.sy);
    line(view, [[view.left, -w / 2], [view.right, -w / 2]], "white", 1.5);
    line(view, [[view.left, 1.5 * w], [view.right, 1.5 * w]], "white", 1.5);
    ctx.setLineDash([6, 6]);
    ctx.lineDashOffset = view.equal ? view.left * view.sx : 0; // the centre line's dashes move with the road
    line(view, [[view.left, w / 2], [view.right, w / 2]], "#f2c200", 1.5);
    ctx.setLineDash([]);
    line(view, [[sc.goal_s, -w / 2], [sc.goal_s, w / 2]], "white", 3);
    text("goal", view.px(sc.goal_s), view.py(-w / 2) + 1, { size: 10, colour: "white", align: "center", base: "top" });
    text("ego lane", view.x + 4, view.py(0), { colour: "white", base: "middle" });
    text("opposite lane", view.x + 4, view.py(w), { colour: "white", base: "middle" });
    // Sensor range: vehicles farther than this along the road are invisible to decider and planner.
    if (Number.isFinite(ep.sensor)) {
      ctx.setLineDash([2, 3]);
      for (const e of [x0 - ep.sensor, x0 + ep.sensor]) line(view, [[e, view.bottom], [e, view.top]], "cyan", 1.2);
      ctx.setLineDash([]);
      text("sensor range", Math.min(view.px(x0 + ep.sensor), view.x + view.w) - 3, view.y + 10,
        { colour: "cyan", align: "right" });
    }
    rollouts(view, x0, y0, w);
    const crash = k === ep.steps && ep.outcome === "crash";
    for (let j = 0; j < sc.npc_present.length; j++) {
      if (!sc.npc_present[j]) continue;
      const s = tr.npc_s[j][k], lane = sc.npc_lane[j];
      const seen = Math.abs(s - x0) <= Math.min(ep.sensor, ep.reveal[j]), hit = crash && ep.crash_npc === j;
      const label = `NPC${j + 1} ${lane === 1 ? "\u2190" : "\u2192"}`;
      vehicle(view, s, lane * w, lane === 1 ? Math.PI : 0, sc.npc_length[j], sc.npc_width[j],
        hit ? "#d62728" : "#bbbbbb", "black", seen || hit ? 1 : 0.35, label, "black", overview);
    }
    vehicle(view, x0, y0, tr.ego_psi[k], sc.ego_length, sc.ego_width, modeColour(tr.mode[k]), "yellow", 1, "ego",
      "white", overview);
    if (!overview && k === ep.steps) banner(view);
    ctx.restore();
  }

  // Rollouts ahead of the ego (planner.lateral_profile): the current offset held for the tip margin,
  // then a straight roll-in with the slope of a full lane change over roll_in metres, then the end offset.
  function rollouts(view, x0, y0, w) {
    const tr = ep.track, pl = ep.planner, chosen = tr.rollout[k];
    if (k === 0 || chosen < 0) return;
    const offsets = Array.isArray(tr.offsets[tr.offsets.length - 1]) ? tr.offsets[k] : tr.offsets;
    const v = tr.ego_v[k], rollIn = pl.roll_in_speed_factor * v + pl.roll_in_margin, tip = pl.car_tip_margin;
    const reach = Math.max(rollIn + tip + 10, v * pl.horizon_time);
    const order = offsets.map((_, i) => i).filter((i) => i !== chosen).concat([chosen]);
    for (const i of order) {
      const pts = [];
      for (let n = 0; n < 40; n++) {
        const a = (reach * n) / 39, lim = (w / rollIn) * Math.max(a - tip, 0);
        pts.push([x0 + a, y0 + Math.max(-lim, Math.min(lim, offsets[i] - y0))]);
      }
      const blocked = tr.blocked[k][i] === "1";
      ctx.globalAlpha = i === chosen ? 1 : 0.8;
      line(view, pts, i === chosen ? "black" : blocked ? "#e04040" : "#60d060", i === chosen ? 3 : 1);
    }
    ctx.globalAlpha = 1;
  }

  // A vehicle as a box centred at (s, d), heading psi; a dark band marks its front. The stretched
  // overview draws boxes unrotated and at least as long as their label.
  function vehicle(view, s, d, psi, length, width, fill, edge, alpha, label, labelColour, overview) {
    ctx.font = "11px system-ui, sans-serif";
    let lpx = length * view.sx;
    const wpx = width * view.sy, labelPx = ctx.measureText(label).width + 8;
    if (overview) { lpx = Math.max(lpx, labelPx); psi = psi === Math.PI ? Math.PI : 0; }
    ctx.save();
    ctx.globalAlpha = alpha;
    ctx.translate(view.px(s), view.py(d));
    ctx.rotate(-psi);
    ctx.fillStyle = fill;
    ctx.fillRect(-lpx / 2, -wpx / 2, lpx, wpx);
    if (!overview) { // windscreen: the front of the vehicle (the overview's labels carry an arrow instead)
      ctx.fillStyle = "rgba(0,0,0,0.35)";
      ctx.fillRect(lpx / 2 - Math.min(0.2 * lpx, 6), -wpx / 2 + 1, Math.min(0.1 * lpx, 3), wpx - 2);
    }
    ctx.strokeStyle = edge;
    ctx.lineWidth = 1.5;
    ctx.strokeRect(-lpx / 2, -wpx / 2, lpx, wpx);
    ctx.restore();
    ctx.globalAlpha = alpha < 1 ? 0.5 : 1;
    if (labelPx <= lpx + 2 || !overview) text(label, view.px(s), view.py(d), { colour: labelColour, align: "center", base: "middle" });
    ctx.globalAlpha = 1;
  }

  function banner(view) {
    const msg = outcomeText(), colour = OUTCOME_COLOURS[ep.outcome] || "#333";
    ctx.font = "bold 20px system-ui, sans-serif";
    const bw = ctx.measureText(msg).width + 24, x = view.x + view.w - bw - 10, y = view.y + 18;
    ctx.fillStyle = "rgba(255,255,255,0.9)";
    ctx.fillRect(x, y, bw, 32);
    ctx.strokeStyle = colour;
    ctx.lineWidth = 3;
    ctx.strokeRect(x, y, bw, 32);
    text(msg, x + bw / 2, y + 17, { size: 20, bold: true, colour, align: "center", base: "middle" });
  }

  function title(x, y) {
    const tr = ep.track, v = tr.ego_v[k], m = tr.mode[k];
    const parts = [[`t = ${tr.t[k].toFixed(1)} s`, "#222"], [`mode: ${modeName(m)}`, modeColour(m)],
      [`v = ${v.toFixed(2)} m/s`, "#222"], [k === ep.steps ? outcomeText() : "running",
        k === ep.steps ? OUTCOME_COLOURS[ep.outcome] || "#222" : "#777"]];
    for (const [msg, colour] of parts) x += text(msg, x, y, { size: 14, bold: true, colour }) + 28;
  }

  function ticks(view) {
    const span = view.right - view.left, raw = span / 8, mag = 10 ** Math.floor(Math.log10(raw));
    const step = [1, 2, 5, 10].map((f) => f * mag).find((f) => f >= raw);
    for (let s = Math.ceil(view.left / step) * step; s <= view.right; s += step) {
      line(view, [[s, view.bottom], [s, view.bottom + 0.6]], "#333", 1);
      text(String(Math.round(s)), view.px(s), view.y + view.h + 11, { colour: "#333", align: "center" });
    }
  }

  function line(view, pts, colour, width) {
    ctx.strokeStyle = colour;
    ctx.lineWidth = width;
    ctx.beginPath();
    pts.forEach(([s, d], i) => (i ? ctx.lineTo(view.px(s), view.py(d)) : ctx.moveTo(view.px(s), view.py(d))));
    ctx.stroke();
  }

  function text(msg, x, y, { size = 11, bold = false, colour = "#222", align = "left", base = "alphabetic" } = {}) {
    ctx.font = `${bold ? "bold " : ""}${size}px system-ui, sans-serif`;
    ctx.fillStyle = colour;
    ctx.textAlign = align;
    ctx.textBaseline = base;
    ctx.fillText(msg, x, y);
    return ctx.measureText(msg).width;
  }

  // ---------------------------------------------------------------- controls
  ui.play.addEventListener("click", () => (playing ? pause() : play()));
  $("restart").addEventListener("click", () => { pause(); show(0); });
  $("back").addEventListener("click", () => { pause(); show(k - 1); });
  $("fwd").addEventListener("click", () => { pause(); show(k + 1); });
  ui.slider.addEventListener("input", () => { pause(); show(Number(ui.slider.value)); });
  $("file").addEventListener("change", (e) => { if (e.target.files[0]) fromFile(e.target.files[0]); });
  document.addEventListener("keydown", (e) => {
    if (e.target.tagName === "INPUT" || e.target.tagName === "SELECT") return;
    const keys = { " ": () => (playing ? pause() : play()), ArrowLeft: () => { pause(); show(k - 1); },
      ArrowRight: () => { pause(); show(k + 1); }, Home: () => { pause(); show(0); },
      End: () => { pause(); if (ep) show(ep.steps); } };
    if (keys[e.key]) { e.preventDefault(); keys[e.key](); }
  });
  window.addEventListener("dragover", (e) => { e.preventDefault(); document.body.classList.add("dragging"); });
  window.addEventListener("dragleave", () => document.body.classList.remove("dragging"));
  window.addEventListener("drop", (e) => {
    e.preventDefault();
    document.body.classList.remove("dragging");
    if (e.dataTransfer.files[0]) fromFile(e.dataTransfer.files[0]);
  });
  window.addEventListener("resize", draw);

  fromUrl(new URLSearchParams(location.search).get("episode") || "episode.json");
})();
