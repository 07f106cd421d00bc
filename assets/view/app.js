// swarm-explore viewer: one page for a live run (`swarm run --view`) and a replay
// (`swarm view RUN_DIR`). Everything comes from the viewer's server: /api/info, /api/truth.png,
// /api/frame/<step|latest>, /api/series, /api/robot/<id>[/grid.png], and in a live run the
// WebSocket /ws (one JSON frame per step; the server drops frames for a slow page, never steps),
// /api/robot/<id>/polygons (asked of the robot), POST /api/link/<name> (to netem) and
// POST /api/clock/<pause|resume|step> (to the world-server).
"use strict";

const $ = (id) => document.getElementById(id);
// The robots' colours: the palette of every picture, plot and MCAP file, from /api/info.
let COLOURS = ["#000000"];
const LINK_STYLE = {
  up: { colour: "rgba(30,150,60,0.85)", dash: [] },
  down: { colour: "rgba(140,140,140,0.5)", dash: [4, 4] },
  dead: { colour: "rgba(60,60,60,0.7)", dash: [1, 3] },
  range: { colour: "rgba(140,140,140,0.5)", dash: [4, 4] },
  fault: { colour: "rgba(210,30,30,0.9)", dash: [6, 3] },
  blackhole: { colour: "rgba(120,40,160,0.9)", dash: [2, 3] },
};
// An up link that may lose frames (netem's radio channel): long dashes, from green towards
// orange as its lower delivery probability falls to 0.5 and below (a square root: a few % of
// loss shows).
const LOSSY_DASH = [10, 4];
function lossyColour(delivery) {
  const t = Math.sqrt(Math.max(0, Math.min(1, (1 - delivery) / 0.5)));
  const mix = (a, b) => Math.round(a + (b - a) * t);
  return `rgba(${mix(30, 235)},${mix(150, 120)},${mix(60, 0)},0.9)`;
}
const TYPE_COLOURS = { ins: "#4363d8", rep: "#3cb44b", del: "#e6194b", em: "#f58231", chg: "#911eb4",
  rm: "#42d4f4", conn: "#808080", targ: "#000000", save: "#9a6324", scan: "#469990", cells: "#800000",
  mark: "#bbbbbb", bid: "#f032e6", task: "#808000", role: "#000075", move: "#aaffc3" };

// A live page draws at most this often (ms).
const DRAW_MS = 100;

const state = {
  paused: false, latest: null, drawing: null, detailAt: 0,
  info: null, truth: null, frame: null, trails: [], series: null,
  selected: null, // {robot: id} or {link: [a, b]}
  polygons: null, // live: what the selected robot holds (/api/robot/<id>/polygons)
  playing: null,
};

function colour(id) { return COLOURS[id % COLOURS.length]; }

function say(msg) { $("status").textContent = msg || ""; }

async function getJson(url) {
  const r = await fetch(url);
  if (!r.ok) throw new Error(`${url}: ${r.status} ${await r.text()}`);
  return r.json();
}

async function post(url, body) {
  const r = await fetch(url, { method: "POST", headers: { "Content-Type": "application/json" },
    body: JSON.stringify(body || {}) });
  const text = await r.text();
  if (!r.ok) { say(`${url}: ${r.status} ${text}`); return null; }
  say("");
  return text ? JSON.parse(text) : {};
}

// The map's frame on the canvas: metres to pixels, y up.
function view() {
  const c = $("map"), m = state.info.map;
  const w = m.width * m.resolution_m, h = m.height * m.resolution_m;
  const s = Math.min(c.width / w, c.height / h);
  return {
    s, w: w * s, h: h * s,
    px: (x) => (x - m.origin_x_m) * s,
    py: (y) => h * s - (y - m.origin_y_m) * s,
  };
}

function draw() {
  const c = $("map"), g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  if (!state.info) return;
  const v = view();
  g.imageSmoothingEnabled = false;
  if ($("truth").checked && state.truth) g.drawImage(state.truth, 0, 0, v.w, v.h);
  else { g.strokeStyle = "#999"; g.strokeRect(0, 0, v.w, v.h); }
  const f = state.frame;
  if (!f) return;
  const at = new Map(f.robots.map((r) => [r.id, r]));
  const lost = []; // the middles of links that lost a frame in the step
  // Links under robots (unless hidden: a big team's links hide its robots).
  for (const l of $("links").checked ? f.links : []) {
    const a = at.get(l.a), b = at.get(l.b);
    if (!a || !b) continue;
    // Out of range: not drawn unless picked (most pairs of a team are).
    if ((l.state === "range" || l.state === "down") && !isSelectedLink(l)) continue;
    const st = LINK_STYLE[l.state] || LINK_STYLE.up;
    const lossy = l.state === "up" && l.air && l.air.delivery < 1;
    const perSecond = (l.bytes_a_to_b + l.bytes_b_to_a) / state.info.step_seconds;
    g.lineWidth = 1 + Math.log2(1 + perSecond) / 2 + (isSelectedLink(l) ? 2 : 0);
    g.strokeStyle = lossy ? lossyColour(l.air.delivery) : st.colour;
    g.setLineDash(lossy ? LOSSY_DASH : st.dash);
    g.beginPath(); g.moveTo(v.px(a.x), v.py(a.y)); g.lineTo(v.px(b.x), v.py(b.y)); g.stroke();
    if (l.air && l.air.lost > 0) lost.push([(v.px(a.x) + v.px(b.x)) / 2, (v.py(a.y) + v.py(b.y)) / 2]);
  }
  // A frame lost in the step (delivered a step late): a red cross at the link's middle, over
  // every link.
  g.setLineDash([]); g.strokeStyle = "#d01010"; g.lineWidth = 2;
  for (const [mx, my] of lost) {
    g.beginPath(); g.moveTo(mx - 4, my - 4); g.lineTo(mx + 4, my + 4);
    g.moveTo(mx - 4, my + 4); g.lineTo(mx + 4, my - 4); g.stroke();
  }
  drawPolygons(g, v);
  if ($("trails").checked) {
    state.trails.forEach((t, id) => {
      if (!t || t.length < 2) return;
      g.strokeStyle = colour(id); g.globalAlpha = 0.5; g.lineWidth = 1;
      g.beginPath(); g.moveTo(v.px(t[0][0]), v.py(t[0][1]));
      for (const p of t) g.lineTo(v.px(p[0]), v.py(p[1]));
      g.stroke(); g.globalAlpha = 1;
    });
  }
  for (const r of f.robots) {
    const x = v.px(r.x), y = v.py(r.y);
    if (r.target) {
      g.strokeStyle = colour(r.id); g.setLineDash([2, 3]); g.lineWidth = 1;
      g.beginPath(); g.moveTo(x, y); g.lineTo(v.px(r.target[0]), v.py(r.target[1])); g.stroke();
      g.setLineDash([]);
      g.strokeRect(v.px(r.target[0]) - 3, v.py(r.target[1]) - 3, 6, 6);
    }
    if ($("channel").checked) drawShare(g, r, x, y, f.channel_capacity);
    g.fillStyle = r.alive ? colour(r.id) : "#777";
    g.beginPath(); g.arc(x, y, 6, 0, 2 * Math.PI); g.fill();
    g.strokeStyle = "#000"; g.lineWidth = state.selected && state.selected.robot === r.id ? 3 : 1;
    g.stroke();
    g.beginPath(); g.moveTo(x, y);
    g.lineTo(x + 10 * Math.cos(r.theta), y - 10 * Math.sin(r.theta)); g.stroke();
    g.fillStyle = "#000"; g.fillText(String(r.id), x + 8, y - 8);
  }
}

// A robot's airtime share of a shared channel: a ring around it, filled clockwise from the top
// in proportion to share / the channel's bytes a step (a full ring: the whole channel).
function drawShare(g, r, x, y, capacity) {
  if (!r.air || !capacity) return;
  const part = Math.max(0, Math.min(1, r.air.share / capacity));
  g.setLineDash([]); g.lineWidth = 3;
  g.strokeStyle = "rgba(0,0,0,0.12)";
  g.beginPath(); g.arc(x, y, 10, 0, 2 * Math.PI); g.stroke();
  if (part > 0) {
    g.strokeStyle = "rgba(20,40,120,0.85)";
    g.beginPath(); g.arc(x, y, 10, -Math.PI / 2, -Math.PI / 2 + 2 * Math.PI * part); g.stroke();
  }
}

// A robot's use of the radio channel in the frame's step, as rows of its panel.
function airRows(air, capacity) {
  if (!air) return "";
  const pct = (x) => `${(100 * x).toFixed(1)} %`;
  return `<tr><th>airtime share</th><td>${air.share} B${capacity ? ` (${pct(air.share / capacity)} of the channel)` : ""}</td></tr>
      <tr><th>airtime used</th><td>${air.airtime} B</td></tr>
      <tr><th>channel busy</th><td>${capacity ? pct(air.utilisation) : "–"}</td></tr>
      <tr><th>frames lost / bytes sent again</th><td>${air.frames_lost} / ${air.retransmitted} B</td></tr>`;
}

// A link's use of the radio channel in the frame's step, as rows of its panel.
function linkAirRows(x, a, b) {
  if (!x) return "";
  const share = (s) => (s == null ? "–" : `${s} B`);
  const lost = [x.lost_a_to_b && `${a}→${b}`, x.lost_b_to_a && `${b}→${a}`].filter(Boolean);
  return `<tr><th>delivery ${a}→${b} / ${b}→${a}</th><td>${x.delivery_a_to_b.toFixed(3)} / ${x.delivery_b_to_a.toFixed(3)}</td></tr>
      <tr><th>frame lost this step</th><td id="link-lost">${lost.length ? lost.join(", ") : "none"}</td></tr>
      <tr><th>airtime share ${a}→${b} / ${b}→${a}</th><td>${share(x.share_a_to_b)} / ${share(x.share_b_to_a)}</td></tr>
      <tr><th>airtime used ${a}→${b} / ${b}→${a}</th><td>${x.airtime_a_to_b} B / ${x.airtime_b_to_a} B</td></tr>`;
}

// f_occ of an edge: occupied edges solid, free ones dashed, unknown ones dotted and faint.
const EDGE_STYLE = { o: { dash: [], alpha: 1 }, f: { dash: [5, 3], alpha: 0.8 }, u: { dash: [1, 3], alpha: 0.5 } };

// The selected robot's polygons: its own (thick) and each owner's it holds, in the owner's colour.
function drawPolygons(g, v) {
  const p = state.polygons;
  if (!p || !$("polygons").checked || !state.selected || state.selected.robot !== p.robot) return;
  for (const o of p.owners) {
    g.strokeStyle = colour(o.robot);
    g.lineWidth = o.robot === p.robot ? 2.5 : 1.5;
    for (const poly of o.polygons) {
      const n = poly.points.length;
      for (let i = 0; i < n; i++) {
        const a = poly.points[i], b = poly.points[(i + 1) % n], st = EDGE_STYLE[poly.occ[i]] || EDGE_STYLE.u;
        g.setLineDash(st.dash); g.globalAlpha = st.alpha;
        g.beginPath(); g.moveTo(v.px(a[0]), v.py(a[1])); g.lineTo(v.px(b[0]), v.py(b[1])); g.stroke();
      }
    }
  }
  g.setLineDash([]); g.globalAlpha = 1;
}

// Live: asks the selected robot what it holds; the table lists it, the map draws it.
async function loadPolygons(id) {
  const el = $("held");
  try {
    const p = await getJson(`/api/robot/${id}/polygons`);
    if (!state.selected || state.selected.robot !== id) return;
    state.polygons = p;
    if (el) {
      const rows = p.owners.map((o) => `<tr><td style="color:${colour(o.robot)}">${o.robot}${o.life ? ` (life ${o.life})` : ""}</td>
        <td>${o.held}</td><td>${o.shown}</td><td>${o.polygons.length}</td>
        <td>${o.polygons.reduce((n, q) => n + q.points.length, 0)}</td></tr>`).join("");
      el.innerHTML = p.owners.length === 0 ? "<p>no polygons (this run does not exchange polygons)</p>" :
        `<p>polygons it holds at step ${p.step} (drawn on the map; edges: occupied solid, free dashed, unknown dotted):</p>
        <table id="held-table"><tr><th>owner</th><th>ops held</th><th>shown</th><th>polygons</th><th>vertices</th></tr>${rows}</table>`;
    }
    draw();
  } catch (e) { if (el) el.textContent = e.message; }
}

function isSelectedLink(l) {
  return state.selected && state.selected.link &&
    state.selected.link[0] === l.a && state.selected.link[1] === l.b;
}

// What is under a click: a robot within 9 px, else the nearest link within 6 px.
function pick(ev) {
  const f = state.frame;
  if (!f) return null;
  const rect = $("map").getBoundingClientRect(), v = view();
  const mx = ev.clientX - rect.left, my = ev.clientY - rect.top;
  let best = null;
  for (const r of f.robots) {
    const d = Math.hypot(v.px(r.x) - mx, v.py(r.y) - my);
    if (d < 9 && (!best || d < best.d)) best = { d, robot: r.id };
  }
  if (best || !$("links").checked) return best;
  const at = new Map(f.robots.map((r) => [r.id, r]));
  for (const l of f.links) {
    const a = at.get(l.a), b = at.get(l.b);
    if (!a || !b) continue;
    const d = segmentDistance(mx, my, v.px(a.x), v.py(a.y), v.px(b.x), v.py(b.y));
    if (d < 6 && (!best || d < best.d)) best = { d, link: [l.a, l.b] };
  }
  return best;
}

function segmentDistance(px, py, ax, ay, bx, by) {
  const dx = bx - ax, dy = by - ay, len = dx * dx + dy * dy;
  const t = len === 0 ? 0 : Math.max(0, Math.min(1, ((px - ax) * dx + (py - ay) * dy) / len));
  return Math.hypot(px - (ax + t * dx), py - (ay + t * dy));
}

async function showDetail() {
  const d = $("detail"), sel = state.selected, f = state.frame;
  if (!sel || !f) { d.innerHTML = ""; return; }
  const stepQ = state.info.live ? "" : `?step=${f.step}`;
  if (sel.robot !== undefined) {
    let r;
    try { r = await getJson(`/api/robot/${sel.robot}${stepQ}`); } catch (e) { say(e.message); return; }
    const mine = f.robots.find((x) => x.id === r.robot);
    const views = (r.views || []).map((w) =>
      `<tr><td>${w.owner}</td><td>${w.held}</td><td>${w.shown}</td></tr>`).join("");
    d.innerHTML = `<h3 style="color:${colour(r.robot)}">robot ${r.robot}</h3>
      <table>
      <tr><th>step</th><td>${r.step}</td></tr><tr><th>life</th><td>${r.life}</td></tr>
      <tr><th>target</th><td>${r.target ? r.target.map((x) => x.toFixed(1)).join(", ") : "none"}</td></tr>
      <tr><th>idle</th><td>${r.idle}</td></tr><tr><th>known cells</th><td>${r.known_cells}</td></tr>
      <tr><th>frontier cells</th><td>${r.frontier_cells}</td></tr>
      <tr><th>splitting frequency</th><td>${r.splits_per_step == null ? "–" : r.splits_per_step.toFixed(2)}</td></tr>
      <tr><th>largest backlog</th><td>${r.backlog_bytes} B</td></tr>
      <tr><th>bytes sent / received</th><td>${r.bytes_sent} / ${r.bytes_received}</td></tr>
      ${airRows(mine && mine.air, f.channel_capacity)}
      </table>
      <p>planning grid (frontiers in red; believed free but not free in the world in magenta):</p>
      <img id="grid" alt="planning grid of robot ${r.robot}" src="/api/robot/${r.robot}/grid.png${stepQ}${stepQ ? "&" : "?"}t=${f.step}">
      <div id="held">${state.info.live ? "asking the robot for its polygons…" : ""}</div>
      ${views && !state.info.live ? `<p>what it shows of each owner's log (ops held, shown up to a save point; its polygons are asked of live robots only):</p>
      <table><tr><th>owner</th><th>held</th><th>shown</th></tr>${views}</table>` : ""}`;
    if (state.info.live) loadPolygons(r.robot);
  } else if (sel.link) {
    const [a, b] = sel.link;
    const l = f.links.find((x) => x.a === a && x.b === b);
    if (!l) { d.innerHTML = ""; return; }
    const controls = state.info.live ? `
      <p><button id="cut">cut</button> <button id="restore">restore</button></p>
      <p><label>bandwidth B/s <input id="bw" type="number" min="1" value="1000" size="7"></label>
      <button id="setbw">set</button></p>
      <p><label>latency ms <input id="lat" type="number" min="0" value="200" size="7"></label>
      <button id="setlat">set</button></p>` : "";
    d.innerHTML = `<h3>link r${a}-r${b}</h3><table>
      <tr><th>state</th><td id="link-state">${l.state}</td></tr>
      <tr><th>bytes ${a}→${b} this step</th><td>${l.bytes_a_to_b}</td></tr>
      <tr><th>bytes ${b}→${a} this step</th><td>${l.bytes_b_to_a}</td></tr>
      <tr><th>queued</th><td>${l.queued_bytes} B</td></tr>
      ${linkAirRows(l.air, a, b)}</table>${controls}`;
    if (state.info.live) {
      const name = `r${a}-r${b}`;
      $("cut").onclick = () => post(`/api/link/${name}`, { enabled: false });
      $("restore").onclick = () => post(`/api/link/${name}`, { enabled: true });
      $("setbw").onclick = () => post(`/api/link/${name}`, { bandwidth_bytes_per_s: Number($("bw").value) });
      $("setlat").onclick = () => post(`/api/link/${name}`, { latency_ms: Number($("lat").value) });
    }
  }
}

// A line chart of `lines` ([{values, colour}]) over `steps`, up to `upto`; horizontal marks.
function chart(canvas, steps, lines, upto, marks) {
  const g = canvas.getContext("2d"), W = canvas.width, H = canvas.height, pad = 28;
  g.clearRect(0, 0, W, H);
  const n = steps.findIndex((s) => s > upto);
  const end = n < 0 ? steps.length : n;
  let max = 1;
  for (const l of lines) for (let i = 0; i < end; i++) max = Math.max(max, l.values[i] || 0);
  for (const m of marks || []) max = Math.max(max, m);
  const last = Math.max(1, steps[steps.length - 1] || 1);
  const x = (s) => pad + (W - pad - 4) * s / last, y = (v) => H - 14 - (H - 20) * v / max;
  g.strokeStyle = "#ccc"; g.fillStyle = "#666"; g.font = "10px sans-serif";
  for (const m of marks || []) {
    g.beginPath(); g.moveTo(pad, y(m)); g.lineTo(W - 4, y(m)); g.stroke(); g.fillText(String(m), 2, y(m) + 3);
  }
  g.fillText(String(Math.round(max)), 2, 10); g.fillText(`step ${last}`, W - 60, H - 2);
  for (const l of lines) {
    g.strokeStyle = l.colour; g.lineWidth = 1.5; g.beginPath();
    for (let i = 0; i < end; i++) {
      const px = x(steps[i]), py = y(l.values[i] || 0);
      if (i === 0) g.moveTo(px, py); else g.lineTo(px, py);
    }
    g.stroke();
  }
}

function drawCharts() {
  const s = state.series, f = state.frame;
  if (!s || !f) return;
  chart($("chart-coverage"), s.steps, [{ values: s.coverage, colour: "#2b6cb0" }], f.step, [50, 90, 95, 100]);
  const types = Object.keys(s.bytes_by_type).filter((k) => s.bytes_by_type[k].some((v) => v > 0));
  chart($("chart-bytes"), s.steps,
    types.map((k) => ({ values: s.bytes_by_type[k], colour: TYPE_COLOURS[k] || "#000" })), f.step);
  chart($("chart-backlog"), s.steps, [{ values: s.backlog_max, colour: "#c05621" }], f.step);
}

function show(frame) {
  state.frame = frame;
  if (frame.trails) state.trails = frame.trails;
  $("step").textContent = `step ${frame.step}`;
  $("coverage").textContent = `coverage ${frame.coverage_pct.toFixed(1)} %`;
  // The channel's legend, once a frame says how the channel was used.
  if (frame.robots.some((r) => r.air) || frame.links.some((l) => l.air)) $("channel-legend").hidden = false;
  draw(); drawCharts();
}

// Live: a frame appends to trails and series.
function onLiveFrame(frame) {
  for (const r of frame.robots) {
    (state.trails[r.id] = state.trails[r.id] || []).push([r.x, r.y]);
  }
  const s = state.series;
  if (s && (s.steps.length === 0 || frame.step > s.steps[s.steps.length - 1])) {
    s.steps.push(frame.step); s.coverage.push(frame.coverage_pct); s.backlog_max.push(frame.backlog_max);
    for (const k of Object.keys(frame.bytes_by_type)) {
      (s.bytes_by_type[k] = s.bytes_by_type[k] || new Array(s.steps.length - 1).fill(0)).push(frame.bytes_by_type[k]);
    }
  }
  state.latest = frame;
  if (state.drawing) return;
  // Draws at most every DRAW_MS: frames that come faster update the data only (a page that
  // redrew map and charts for each of 30 frames a second took a core of a 2-core machine).
  state.drawing = setTimeout(() => {
    state.drawing = null;
    show(state.latest);
    const now = Date.now();
    if (state.selected && state.selected.robot !== undefined && now - state.detailAt > 1000) {
      state.detailAt = now;
      showDetail();
    }
  }, DRAW_MS);
}

// Live: pause / resume / one step of the run's clock (the world-server holds the next step).
async function clockOrder(order) {
  const r = await post(`/api/clock/${order}`);
  if (r) showPaused(r.paused);
}

function showPaused(paused) {
  state.paused = paused;
  $("pause").textContent = paused ? "resume" : "pause";
  $("stepone").disabled = !paused;
  $("mode").textContent = paused ? "live (paused)" : "live";
}

function connectLive() {
  const ws = new WebSocket(`ws://${location.host}/ws`);
  ws.onmessage = (m) => onLiveFrame(JSON.parse(m.data));
  ws.onclose = () => { $("mode").textContent = "live (run ended)"; $("clock").hidden = true; };
}

async function seek(step) {
  try { show(await getJson(`/api/frame/${step}`)); } catch (e) { say(e.message); }
  if (state.selected) showDetail();
}

async function main() {
  state.info = await getJson("/api/info");
  if (state.info.palette && state.info.palette.length) COLOURS = state.info.palette;
  const c = $("map"), m = state.info.map;
  // Fit the canvas to the map's aspect.
  const aspect = (m.width) / (m.height);
  if (aspect > c.width / c.height) c.height = Math.round(c.width / aspect); else c.width = Math.round(c.height * aspect);
  state.truth = new Image();
  state.truth.onload = draw;
  state.truth.src = "/api/truth.png";
  state.series = await getJson("/api/series");
  $("mode").textContent = state.info.live ? "live" : "replay";
  $("seek").hidden = state.info.live;
  for (const id of ["truth", "trails", "links", "polygons", "channel"]) $(id).onchange = draw;
  $("map").onclick = (ev) => {
    const p = pick(ev);
    state.selected = p ? (p.robot !== undefined ? { robot: p.robot } : { link: p.link }) : null;
    state.polygons = null;
    draw(); showDetail();
  };
  $("map").onmousemove = (ev) => {
    const p = pick(ev);
    if (p && p.link) {
      const l = state.frame.links.find((x) => x.a === p.link[0] && x.b === p.link[1]);
      const air = l && l.air ? `, delivery ${l.air.delivery.toFixed(2)}${l.air.lost ? `, ${l.air.lost} frame(s) lost` : ""}` : "";
      $("map").title = l ? `r${l.a}-r${l.b}: ${l.state}, queued ${l.queued_bytes} B${air}` : "";
    } else $("map").title = p ? `robot ${p.robot}` : "";
  };
  if (state.info.live) {
    $("clock").hidden = false;
    showPaused(!!state.info.paused);
    $("pause").onclick = () => clockOrder(state.paused ? "resume" : "pause");
    $("stepone").onclick = () => clockOrder("step");
    try { show(await getJson("/api/frame/latest")); } catch (e) { /* no step yet */ }
    connectLive();
  } else {
    const sl = $("slider");
    sl.min = state.info.first_step; sl.max = state.info.last_step; sl.value = state.info.first_step;
    sl.oninput = () => seek(Number(sl.value));
    $("play").onclick = () => {
      if (state.playing) { clearInterval(state.playing); state.playing = null; $("play").textContent = "play"; return; }
      $("play").textContent = "stop";
      state.playing = setInterval(() => {
        if (Number(sl.value) >= Number(sl.max)) { $("play").click(); return; }
        sl.value = Number(sl.value) + 1; seek(Number(sl.value));
      }, 100);
    };
    await seek(state.info.first_step);
  }
}

main().catch((e) => say(e.message));
