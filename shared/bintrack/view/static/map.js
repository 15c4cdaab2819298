// bintrack map page: draws the items the view server pushes over /ws (map_messages.py).
// Positions are in the deployment's units; Leaflet's L.CRS.Simple maps them 1:1 (lat = y, lng = x).
"use strict";

// Tracks only: no layer uses these hues (sensors grey, detecting yellow, motion green/red, the
// other layers grey or black), so a track never looks like a layer and never vanishes on one.
const PALETTE = ["#1e88e5", "#d81b60", "#00897b", "#8e24aa", "#e64a19", "#3949ab", "#6d4c41", "#0097a7"];
const MAX_COVER = 3.0;        // range circles drawn only where a point lies in at most this many on average
const LEGEND_TRACKS = 8;      // tracks listed one by one in the legend
const ARROW_S = 2.0;          // a velocity arrow is the displacement over this many seconds
const ESTIMATE_KEEP = 5.0;    // s of event time a peer estimate stays drawn
const ELLIPSE_K = 2.4477;     // sqrt(chi2_2(0.95)): a 95 % covariance ellipse
const MAX_PENDING = 5000;     // items waiting for a frame before the page asks for a fresh snapshot

const $ = (id) => document.getElementById(id);
const ll = (x, y) => L.latLng(y, x);
const colour = (id) => PALETTE[((id % PALETTE.length) + PALETTE.length) % PALETTE.length];
const fmt = (v, d = 2) => (v === null || v === undefined ? "–" : Number(v).toFixed(d));

const map = L.map("map", { crs: L.CRS.Simple, minZoom: -6, maxZoom: 8, zoomSnap: 0.25, preferCanvas: false });
map.attributionControl.setPrefix('<a href="https://leafletjs.com">Leaflet</a>');
const layers = {
  sensors: L.layerGroup().addTo(map),
  reports: L.layerGroup().addTo(map),
  estimates: L.layerGroup().addTo(map),
  tails: L.layerGroup().addTo(map),
  truth: L.layerGroup().addTo(map),
  objects: L.layerGroup().addTo(map),
  velocity: L.layerGroup().addTo(map),
  tracks: L.layerGroup().addTo(map),
  ranges: L.layerGroup(),     // no content: shows or hides the range circles (a class on the map)
};
layers.ranges.on("add", () => map.getContainer().classList.add("show-ranges"));
layers.ranges.on("remove", () => map.getContainer().classList.remove("show-ranges"));
// the layer box lists a layer once something of it is on the page
const LAYER_NAMES = {
  sensors: "Sensors", ranges: "Sensor ranges", reports: "Fused reports (95 % ellipses)", estimates: "Peer estimates",
  tracks: "Tracks", tails: "Track tails", truth: "Truth (dashed)", objects: "Laser objects", velocity: "Velocity",
};
const layerBox = L.control.layers(null, {}, { collapsed: false }).addTo(map);
const listed = new Set();
function listLayer(name) {
  if (listed.has(name)) return;
  listed.add(name);
  layerBox.addOverlay(layers[name], LAYER_NAMES[name]);
}

// a scale bar in the deployment's units (L.CRS.Simple: one unit is 2^zoom pixels)
const scaleBar = L.control({ position: "bottomleft" });
scaleBar.onAdd = () => L.DomUtil.create("div", "scale-bar");
scaleBar.addTo(map);
function drawScale() {
  const el = scaleBar.getContainer();
  if (!el || !S.deployment) return;
  const unitsPerPx = 1 / Math.pow(2, map.getZoom());
  const target = 120 * unitsPerPx;
  const step = Math.pow(10, Math.floor(Math.log10(target)));
  const length = [5, 2, 1].map((m) => m * step).find((v) => v <= target) || step;
  el.style.width = `${Math.round(length / unitsPerPx)}px`;
  el.textContent = `${Number(length.toPrecision(3))} ${S.deployment.units}`;
  el.dataset.length = String(length);
}
map.on("zoomend", drawScale);

// The legend lists what is on the page: each entry once its first item is drawn, each
// current track in its own colour.
const legend = L.control({ position: "bottomright" });
legend.onAdd = () => L.DomUtil.create("div", "legend");
legend.addTo(map);
const LEGEND = {
  range: ['<circle cx="13" cy="7" r="6" class="sensor"/>', "sensor range"],
  node: ['<circle cx="13" cy="7" r="2" class="sensor-node"/>', "sensor"],
  detecting: ['<circle cx="13" cy="7" r="6" class="sensor lit"/>', "detecting (fades after)"],
  motion: ['<circle cx="7" cy="7" r="5" class="sensor closer"/><circle cx="19" cy="7" r="5" class="sensor farther"/>', "motion sensor: closer / farther"],
  beam: ['<path d="M1 11 L25 3" class="beam"/>', "laser beam"],
  sector: ['<path d="M13 7 L24 2 A12 12 0 0 1 24 12 Z" class="sector-lit"/>', "lit sector"],
  velocity: ['<path d="M1 11 L12 7 L25 3" class="velocity"/>', "velocity estimate (10 s)"],
  report: ['<ellipse cx="13" cy="7" rx="10" ry="5" class="report"/>', "fused report, 95 % ellipse"],
  estimate: ['<circle cx="13" cy="7" r="3.5" class="estimate"/>', "peer estimate"],
  truth: ['<path d="M1 7 L25 7" class="truth"/>', "truth"],
  object: ['<path d="M1 11 L25 3" class="object"/>', "laser object"],
};
const shown = new Set();    // legend entries with something on the page
let legendDirty = true;
function show(entry) { if (!shown.has(entry)) { shown.add(entry); legendDirty = true; } }
function renderLegend() {
  legendDirty = false;
  const rows = [];
  for (const [name, [svg, text]] of Object.entries(LEGEND)) {
    if (shown.has(name)) rows.push(`<div data-entry="${name}"><svg width="26" height="14">${svg}</svg>${text}</div>`);
  }
  const current = Object.values(S.tracks).filter((tr) => tr.current).map((tr) => tr.id).sort((a, b) => a - b);
  for (const id of current.slice(0, LEGEND_TRACKS)) {
    rows.push(`<div data-entry="track" data-track="${id}"><svg width="26" height="14"><path d="M1 10 L18 5" ` +
      `stroke="${colour(id)}" stroke-width="2.5"/><circle cx="20" cy="5" r="4" fill="${colour(id)}"/></svg>track ${id}</div>`);
  }
  if (current.length > LEGEND_TRACKS) rows.push(`<div data-entry="more">… ${current.length - LEGEND_TRACKS} more tracks</div>`);
  if (current.length) rows.push(`<div class="legend-note">track: id, tail, velocity (2 s)</div>`);
  legend.getContainer().innerHTML = rows.join("");
}

// ------------------------------------------------------------------------------ state

const S = {
  deployment: null, sensors: {}, tracks: {}, truth: {}, estimates: {}, t: null, tail: 30,
  status: {}, mode: null, pending: [], ended: null, received: 0, seeking: false, producing: new Set(),
};
// measurements for tests and benchmarks: rAF timestamps and arrival times of track scans
const frames = [];
const trackArrivals = [];
window.bintrack = {
  S, map,
  resetFrames() { frames.length = 0; },
  litSensors() {
    return Array.from(document.querySelectorAll("path.sensor.lit")).map((el) => ({
      sensor: el.dataset.sensor, value: Number(el.dataset.value), t: Number(el.dataset.t) }));
  },
  frameIntervals() { const out = []; for (let i = 1; i < frames.length; i++) out.push(frames[i] - frames[i - 1]); return out; },
  trackArrivals,
  sensorCount() { return document.querySelectorAll("path.sensor").length; },
  planCount() { return { obstacles: document.querySelectorAll("path.obstacle").length, doors: document.querySelectorAll("path.door").length }; },
  legendEntries() { return Array.from(document.querySelectorAll(".legend [data-entry]")).map((el) => el.dataset.entry); },
  // each legend track's colour and the colours its dot and label are drawn in, as the browser computes them
  trackColours() {
    return Array.from(document.querySelectorAll(".legend [data-entry=track]")).map((el) => {
      const id = el.dataset.track;
      const dot = document.querySelector(`path.track-dot.track-${id}`);
      const label = document.querySelector(`.track-label[data-track="${id}"]`);
      return { track: Number(id), legend: getComputedStyle(el.querySelector("circle")).fill,
               dot: dot ? getComputedStyle(dot).fill : null,
               label: label ? getComputedStyle(label).backgroundColor : null };
    });
  },
  detectingColour() {
    const el = document.querySelector("path.sensor.lit");
    return el ? getComputedStyle(el).fill : null;
  },
  rangesShown() { return map.getContainer().classList.contains("show-ranges"); },
  scaleBar() { const el = document.querySelector(".scale-bar"); return { text: el.textContent, px: el.offsetWidth }; },
  trackLabels() {
    return Array.from(document.querySelectorAll(".track-label")).map((el) => ({
      track: Number(el.dataset.track), x: Number(el.dataset.x), y: Number(el.dataset.y), t: Number(el.dataset.t) }));
  },
};

const fading = new Map();   // sensor entry -> when (performance.now(), ms) it stopped detecting
const FADE_MS = [700, 1500];
function fadeSensors(now) {
  for (const [entry, since] of fading) {
    const el = entry.layer.getElement();
    const age = now - since;
    if (!el || age >= FADE_MS[1]) { if (el) el.classList.remove("fade1", "fade2"); fading.delete(entry); }
    else if (age >= FADE_MS[0] && el.classList.contains("fade1")) { el.classList.replace("fade1", "fade2"); }
  }
}

function idleValue(kind) { return kind === "sector" ? -1 : 0; }

// ------------------------------------------------------------------------------ deployment

function setDeployment(dep) {
  S.deployment = dep;
  layers.sensors.clearLayers();
  S.sensors = {};
  const [xmin, ymin, xmax, ymax] = dep.region;
  // range circles: off by default where they overlap heavily (a grey mesh otherwise)
  const area = dep.sensors.filter((s) => (s.kind === "disk" || s.kind === "sector") && s.x !== null)
    .reduce((sum, s) => sum + Math.PI * s.r * s.r, 0);
  const cover = area / Math.max((xmax - xmin) * (ymax - ymin), 1e-12);
  listLayer("sensors");
  if (area > 0) {
    listLayer("ranges");
    if (cover <= MAX_COVER) { layers.ranges.addTo(map); show("range"); } else map.removeLayer(layers.ranges);
    show("node");
  }
  if (dep.sensors.some((s) => s.kind === "motion")) show("motion");
  if (dep.sensors.some((s) => s.kind === "line")) show("beam");
  map.fitBounds([ll(xmin, ymin), ll(xmax, ymax)], { padding: [10, 10] });   // before drawing: layers need a view
  drawScale();
  L.rectangle([ll(xmin, ymin), ll(xmax, ymax)], { color: "#b0bec5", weight: 1, fill: false, dashArray: "2 4",
                                                 interactive: false }).addTo(layers.sensors);
  const plan = dep.plan || { obstacles: [], doors: [] };   // the floor plan: where nobody stands, and the doors
  for (const outline of plan.obstacles) {
    L.polygon(outline.map(([x, y]) => ll(x, y)), { className: "obstacle", weight: 1, interactive: false }).addTo(layers.sensors);
  }
  for (const [x, y] of plan.doors) {
    L.circleMarker(ll(x, y), { radius: 5, className: "door", interactive: false }).addTo(layers.sensors);
  }
  for (const spec of dep.sensors) {
    const entry = { spec, value: idleValue(spec.kind), t: null, layer: null, lit: null };
    const tip = () => `${spec.id} · ${spec.kind} · value ${entry.value} · t ${fmt(entry.t, 3)} s`;
    if ((spec.kind === "disk" || spec.kind === "sector") && spec.x !== null) {
      entry.layer = L.circle(ll(spec.x, spec.y), { radius: spec.r, className: "sensor", weight: 1 });
      L.circleMarker(ll(spec.x, spec.y), { radius: 1.5, className: "sensor-node", interactive: false }).addTo(layers.sensors);
    } else if (spec.kind === "motion") {
      entry.layer = L.circleMarker(ll(spec.x, spec.y), { radius: 6, className: "sensor" });
    } else if (spec.kind === "line") {
      const beam = beamSegment(spec, dep.region);
      if (beam) entry.layer = L.polyline(beam, { className: "sensor beam" });
      else if (spec.x !== null) entry.layer = L.circleMarker(ll(spec.x, spec.y), { radius: 5, className: "sensor" });
    }
    if (entry.layer) {
      entry.layer.bindTooltip(tip, { sticky: true });
      entry.layer.addTo(layers.sensors);
      const el = entry.layer.getElement();
      if (el) el.dataset.sensor = spec.id;
    }
    S.sensors[spec.id] = entry;
  }
}

// the beam a·x + b·y = 1 clipped to the region (null if it misses it)
function beamSegment(spec, region) {
  if (spec.a === undefined || spec.a === null) return null;
  const [xmin, ymin, xmax, ymax] = region;
  const pts = [];
  if (Math.abs(spec.b) > 1e-12) for (const x of [xmin, xmax]) { const y = (1 - spec.a * x) / spec.b; if (y >= ymin && y <= ymax) pts.push([x, y]); }
  if (Math.abs(spec.a) > 1e-12) for (const y of [ymin, ymax]) { const x = (1 - spec.b * y) / spec.a; if (x >= xmin && x <= xmax) pts.push([x, y]); }
  return pts.length >= 2 ? [ll(...pts[0]), ll(...pts[pts.length - 1])] : null;
}

function setSensor(id, value, t, animate = true) {
  const entry = S.sensors[id];
  if (!entry) return;
  entry.value = value; entry.t = t;
  const el = entry.layer && entry.layer.getElement();
  const kind = entry.spec.kind;
  if (el) {
    const lit = kind === "sector" ? value >= 0 : kind === "motion" ? false : value !== 0;
    const was = el.classList.contains("lit");
    el.dataset.sensor = id;
    el.classList.toggle("lit", lit);
    if (lit) show(kind === "sector" ? "sector" : "detecting");
    el.dataset.value = String(value);
    el.dataset.t = t === null ? "" : String(t);
    el.classList.toggle("closer", kind === "motion" && value > 0);
    el.classList.toggle("farther", kind === "motion" && value < 0);
    el.classList.remove("fade1", "fade2");
    // fades after it stops detecting, in two steps (cheap to paint): see fadeSensors()
    if (was && !lit && animate) { el.classList.add("fade1"); fading.set(entry, performance.now()); }
    else fading.delete(entry);
    if (kind === "line" && lit) setTimeout(() => { if (entry.t === t) setSensor(id, 0, t); }, 600);
  }
  if (kind === "sector") {
    if (entry.lit) { layers.sensors.removeLayer(entry.lit); entry.lit = null; }
    if (value >= 0) entry.lit = L.polygon(sectorWedge(entry.spec, value), { className: "sector-lit", interactive: false })
      .addTo(layers.sensors);
  }
}

// sector k of s, numbered clockwise from the offset (paper 000)
function sectorWedge(spec, k) {
  const w = 2 * Math.PI / spec.s;
  const a0 = spec.o - k * w, a1 = spec.o - (k + 1) * w;
  const pts = [ll(spec.x, spec.y)];
  for (let i = 0; i <= 12; i++) {
    const a = a0 + (a1 - a0) * i / 12;
    pts.push(ll(spec.x + spec.r * Math.cos(a), spec.y + spec.r * Math.sin(a)));
  }
  return pts;
}

// ------------------------------------------------------------------------------ drawing helpers

function arrowLatLngs(x, y, vx, vy, seconds = ARROW_S) {
  const tx = x + vx * seconds, ty = y + vy * seconds;
  const len = Math.hypot(tx - x, ty - y);
  if (!(len > 1e-9)) return null;
  const head = Math.min(len * 0.35, 1.5 + len * 0.1);
  const ang = Math.atan2(ty - y, tx - x);
  const h1 = ll(tx - head * Math.cos(ang - 0.45), ty - head * Math.sin(ang - 0.45));
  const h2 = ll(tx - head * Math.cos(ang + 0.45), ty - head * Math.sin(ang + 0.45));
  return [[ll(x, y), ll(tx, ty)], [h1, ll(tx, ty), h2]];
}

function ellipse(x, y, cxx, cxy, cyy) {
  // eigen-decomposition of the 2×2 covariance
  const tr = cxx + cyy, det = cxx * cyy - cxy * cxy;
  const disc = Math.sqrt(Math.max(0, tr * tr / 4 - det));
  const l1 = Math.max(0, tr / 2 + disc), l2 = Math.max(0, tr / 2 - disc);
  const ang = Math.abs(cxy) > 1e-12 ? Math.atan2(l1 - cxx, cxy) : (cxx >= cyy ? 0 : Math.PI / 2);
  const a = ELLIPSE_K * Math.sqrt(l1), b = ELLIPSE_K * Math.sqrt(l2);
  const pts = [];
  for (let i = 0; i < 36; i++) {
    const th = 2 * Math.PI * i / 36;
    const ex = a * Math.cos(th), ey = b * Math.sin(th);
    pts.push(ll(x + ex * Math.cos(ang) - ey * Math.sin(ang), y + ex * Math.sin(ang) + ey * Math.cos(ang)));
  }
  return pts;
}

// ------------------------------------------------------------------------------ tracks

function labelIcon(id, x, y, t) {
  return L.divIcon({ className: "label-icon", iconSize: null, iconAnchor: [-8, 20],
    html: `<span class="track-label" style="background:${colour(id)}" data-track="${id}" data-x="${x}" ` +
          `data-y="${y}" data-t="${t}">${id}</span>` });
}

function trackEntry(id) {
  let tr = S.tracks[id];
  if (!tr) {
    const c = colour(id);
    tr = S.tracks[id] = { id, points: [], current: false, x: 0, y: 0, vx: null, vy: null, t: null };
    tr.tail = L.polyline([], { className: "tail", color: c, interactive: false }).addTo(layers.tails);
    tr.dot = L.circleMarker(ll(0, 0), { radius: 6, className: `track-dot track-${id}`, fillColor: c, color: "#fff" });
    tr.dot.bindTooltip(() => `track ${id} · t ${fmt(tr.t, 2)} s · (${fmt(tr.x)}, ${fmt(tr.y)})` +
      (tr.vx === null ? "" : ` · v (${fmt(tr.vx)}, ${fmt(tr.vy)}) /s`), { sticky: true });
    tr.label = L.marker(ll(0, 0), { icon: labelIcon(id, 0, 0, 0), interactive: false, keyboard: false });
    tr.arrow = L.polyline([], { className: "arrow", color: c, interactive: false });
  }
  return tr;
}

function applyTracks(item, redraw = true) {
  const seen = new Set();
  legendDirty = true;
  if (item.tracks.length) { listLayer("tracks"); listLayer("tails"); }
  for (const [id, x, y, vx, vy] of item.tracks) {
    const tr = trackEntry(id);
    seen.add(id);
    Object.assign(tr, { x, y, vx, vy, t: item.t });
    tr.points.push([item.t, x, y]);
    if (!tr.current) { tr.dot.addTo(layers.tracks); tr.label.addTo(layers.tracks); tr.arrow.addTo(layers.tracks); tr.current = true; }
    if (redraw) drawTrack(tr);
  }
  for (const tr of Object.values(S.tracks)) {
    if (!seen.has(tr.id) && tr.current) {
      layers.tracks.removeLayer(tr.dot); layers.tracks.removeLayer(tr.label); layers.tracks.removeLayer(tr.arrow);
      tr.current = false;
    }
  }
}

function drawTrack(tr) {
  const p = ll(tr.x, tr.y);
  tr.dot.setLatLng(p);
  tr.label.setLatLng(p);
  tr.label.setIcon(labelIcon(tr.id, tr.x, tr.y, tr.t));
  const arrow = tr.vx === null ? null : arrowLatLngs(tr.x, tr.y, tr.vx, tr.vy);
  tr.arrow.setLatLngs(arrow || []);
  tr.tail.setLatLngs(tr.points.map(([, x, y]) => ll(x, y)));
}

function trimTails() {
  if (S.t === null) return;
  const horizon = S.t - S.tail;
  for (const [id, tr] of Object.entries(S.tracks)) {
    let cut = 0;
    while (cut < tr.points.length && tr.points[cut][0] < horizon) cut++;
    if (cut) { tr.points.splice(0, cut); tr.tail.setLatLngs(tr.points.map(([, x, y]) => ll(x, y))); }
    if (!tr.points.length && !tr.current) { layers.tails.removeLayer(tr.tail); delete S.tracks[id]; }
  }
  for (const [id, tg] of Object.entries(S.truth)) {
    let cut = 0;
    while (cut < tg.points.length - 1 && tg.points[cut][0] < horizon) cut++;
    if (cut) tg.points.splice(0, cut);
    if (tg.points.length && tg.points[tg.points.length - 1][0] < horizon) {
      layers.truth.removeLayer(tg.line); layers.truth.removeLayer(tg.dot); delete S.truth[id];
    } else tg.line.setLatLngs(tg.points.map(([, x, y]) => ll(x, y)));
  }
  for (const [node, est] of Object.entries(S.estimates)) {
    if (est.t < S.t - ESTIMATE_KEEP) { layers.estimates.removeLayer(est.layer); delete S.estimates[node]; }
  }
}

// ------------------------------------------------------------------------------ other items

function applyReports(item) {
  layers.reports.clearLayers();
  if (item.reports.length) { show("report"); listLayer("reports"); }
  for (const [x, y, cxx, cxy, cyy, shared] of item.reports) {
    L.polygon(ellipse(x, y, cxx, cxy, cyy), { className: shared ? "report shared" : "report" })
      .bindTooltip(`fused report · t ${fmt(item.t, 2)} s · (${fmt(x)}, ${fmt(y)})${shared ? " · shared" : ""}`, { sticky: true })
      .addTo(layers.reports);
  }
}

function applyEstimate(item) {
  show("estimate"); listLayer("estimates");
  const old = S.estimates[item.node];
  if (old) layers.estimates.removeLayer(old.layer);
  const layer = L.circleMarker(ll(item.x, item.y), { radius: 3.5, className: "estimate" })
    .bindTooltip(`estimate of ${item.node} (${item.tracker}) · t ${fmt(item.t, 2)} s · (${fmt(item.x)}, ${fmt(item.y)})`)
    .addTo(layers.estimates);
  S.estimates[item.node] = { t: item.t, layer };
}

function applyObject(item) {
  show("object"); listLayer("objects");
  const rev = item.rev || 0;
  const old = layers.objects.getLayers().find((l) => l.objectNumber === item.n);
  if (old && old.objectRevision > rev) return;  // a later revision is already drawn
  if (old) layers.objects.removeLayer(old);
  const [ex, ey] = item.entry, [xx, xy] = item.exit;
  const arrow = arrowLatLngs(ex, ey, xx - ex, xy - ey, 1) || [[ll(ex, ey), ll(xx, xy)]];
  const line = L.polyline(arrow, { className: "object" })
    .bindTooltip(`laser object ${item.n}${rev ? ` (revision ${rev})` : ""} · ${fmt(item.t0, 2)}–${fmt(item.t, 2)} s · v (${fmt(item.v[0])}, ${fmt(item.v[1])}) /s`, { sticky: true })
    .addTo(layers.objects);
  line.objectNumber = item.n;
  line.objectRevision = rev;
  while (layers.objects.getLayers().length > 100) layers.objects.removeLayer(layers.objects.getLayers()[0]);
}

function applyVelocity(item) {
  show("velocity"); listLayer("velocity");
  layers.velocity.clearLayers();
  let [x, y] = item.p || [null, null];
  if (x === null && S.deployment) { const r = S.deployment.region; x = (r[0] + r[2]) / 2; y = (r[1] + r[3]) / 2; }
  if (x === null) return;
  const arrow = arrowLatLngs(x, y, item.v[0], item.v[1], 10);
  if (arrow) L.polyline(arrow, { className: "velocity" })
    .bindTooltip(`${item.method} · t ${fmt(item.t, 2)} s · v (${fmt(item.v[0])}, ${fmt(item.v[1])}) /s (arrow: 10 s)`, { sticky: true })
    .addTo(layers.velocity);
}

function applyTruth(item, redraw = true) {
  show("truth"); listLayer("truth");
  let tg = S.truth[item.id];
  if (!tg) {
    tg = S.truth[item.id] = { points: [] };
    tg.line = L.polyline([], { className: "truth", interactive: false }).addTo(layers.truth);
    tg.dot = L.circleMarker(ll(item.x, item.y), { radius: 4, className: "truth-dot" })
      .bindTooltip(() => `truth: target ${item.id} · t ${fmt(tg.points[tg.points.length - 1][0], 2)} s`).addTo(layers.truth);
  }
  tg.points.push([item.t, item.x, item.y]);
  if (redraw) { tg.line.addLatLng(ll(item.x, item.y)); tg.dot.setLatLng(ll(item.x, item.y)); }
}

function clearDynamic() {
  for (const name of ["reports", "estimates", "tails", "truth", "objects", "velocity", "tracks"]) layers[name].clearLayers();
  S.tracks = {}; S.truth = {}; S.estimates = {};
  for (const [id, entry] of Object.entries(S.sensors)) setSensor(id, idleValue(entry.spec.kind), null, false);
}

function applySnapshot(snap) {
  if (snap.deployment && (!S.deployment || JSON.stringify(snap.deployment) !== JSON.stringify(S.deployment))) setDeployment(snap.deployment);
  clearDynamic();
  S.tail = snap.tail; S.t = snap.t; S.ended = snap.ended;
  for (const [id, [v, t]] of Object.entries(snap.sensors)) setSensor(id, v, t, false);
  for (const scan of snap.scans) applyTracks(scan, false);
  for (const tr of Object.values(S.tracks)) drawTrack(tr);
  if (snap.reports) applyReports(snap.reports);
  for (const e of snap.estimates) applyEstimate(e);
  for (const o of snap.objects) applyObject(o);
  if (snap.velocity) applyVelocity(snap.velocity);
  for (const p of snap.truth) applyTruth(p, false);
  for (const tg of Object.values(S.truth)) {
    tg.line.setLatLngs(tg.points.map(([, x, y]) => ll(x, y)));
    const [, x, y] = tg.points[tg.points.length - 1]; tg.dot.setLatLng(ll(x, y));
  }
  if (snap.status) applyStatus(snap.status);
  trimTails();
}

function apply(item) {
  if (item.t !== undefined && item.t !== null && (S.t === null || item.t > S.t)) S.t = item.t;
  switch (item.k) {
    case "snapshot": applySnapshot(item); break;
    case "deployment": setDeployment(item); break;
    case "sensor": setSensor(item.id, item.v, item.t); break;
    case "tracks": applyTracks(item); break;
    case "reports": applyReports(item); break;
    case "estimate": applyEstimate(item); break;
    case "object": applyObject(item); break;
    case "velocity": applyVelocity(item); break;
    case "truth": applyTruth(item); break;
    case "eos": S.ended = item.t; break;
    case "status": applyStatus(item); break;
  }
}

// ------------------------------------------------------------------------------ status line

function applyStatus(st) {
  S.status = st;
  S.mode = st.mode;
  const parts = [st.mode === "recording" ? `recording ${st.file || ""}` : `live${st.net ? " · " + st.net : ""}`];
  if (S.deployment) parts.push(`${S.deployment.sensors.length} sensors (${S.deployment.units})`);
  if (st.rates) {
    const names = { raw: "events", transition: "transitions", estimate: "estimates", fusion_reports: "reports", tracks: "tracks" };
    // only what the running stack produces: a figure appears once its rate was above 0
    for (const [k, r] of Object.entries(st.rates)) if (r > 0) S.producing.add(k);
    parts.push(Object.entries(st.rates).filter(([k]) => S.producing.has(k))
      .map(([k, r]) => `${names[k] || k} ${r}/s`).join(" · "));
  }
  if (st.services && st.services.length) parts.push(`services: ${st.services.join(", ")}`);
  if (st.dropped) parts.push(`dropped ${st.dropped}`);
  $("status").textContent = parts.filter(Boolean).join("  |  ");
  showBanner(st.message || "");
  if (st.mode === "recording") {
    $("controls").hidden = false;
    const slider = $("slider");
    slider.min = st.range[0]; slider.max = st.range[1];
    if (!S.seeking) slider.value = st.position;
    $("play").textContent = st.playing ? "❚❚" : "▶";
    $("speed").value = String(st.speed);
  }
}

function showBanner(text) {
  const banner = $("banner");
  banner.textContent = text;
  banner.hidden = !text;
}

function showTime() {
  const el = $("event-time");
  const t = S.mode === "recording" && S.status.position !== undefined ? S.status.position : S.t;
  const text = t === null || t === undefined ? "t = – s" : `t = ${t.toFixed(2)} s${S.ended !== null && S.ended !== undefined ? " (end)" : ""}`;
  if (el.textContent !== text) { el.textContent = text; el.dataset.t = t === null || t === undefined ? "" : String(t); }
  if (S.mode === "recording") $("time").textContent = `${Number($("slider").value).toFixed(2)} / ${Number(S.status.range[1]).toFixed(2)} s`;
}

// ------------------------------------------------------------------------------ the socket

let socket = null;
function connect() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  socket = new WebSocket(`${proto}//${location.host}/ws`);
  socket.onopen = () => { if ($("banner").dataset.server === "gone") { showBanner(""); $("banner").dataset.server = ""; } };
  socket.onmessage = (ev) => {
    const arrived = performance.timeOrigin + performance.now();
    const batch = JSON.parse(ev.data);
    S.received += batch.length;
    for (const item of batch) if (item.k === "tracks") trackArrivals.push([item.t, arrived]);
    if (trackArrivals.length > 2000) trackArrivals.splice(0, 1000);
    if (batch.length && batch[0].k === "snapshot") S.pending = [];
    for (const item of batch) S.pending.push(item);
    if (S.pending.length > MAX_PENDING) { S.pending = []; send({ cmd: "snapshot" }); }
  };
  socket.onclose = () => {
    showBanner("view server gone: the page lost its connection; reconnecting…");
    $("banner").dataset.server = "gone";
    setTimeout(connect, 1000);
  };
}
function send(obj) { if (socket && socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(obj)); }

$("play").onclick = () => send({ cmd: S.status.playing ? "pause" : "play" });
$("speed").onchange = (ev) => send({ cmd: "speed", x: Number(ev.target.value) });
$("slider").addEventListener("input", () => { S.seeking = true; showTime(); });
$("slider").addEventListener("change", (ev) => { S.seeking = false; send({ cmd: "seek", t: Number(ev.target.value) }); });

let lastTrim = 0;
function frame(now) {
  frames.push(now);
  if (frames.length > 2000) frames.splice(0, 1000);
  if (S.pending.length) {
    const batch = S.pending; S.pending = [];
    for (const item of batch) apply(item);
  }
  if (now - lastTrim > 250) { trimTails(); fadeSensors(now); lastTrim = now; }
  showTime();
  if (legendDirty) renderLegend();
  requestAnimationFrame(frame);
}
requestAnimationFrame(frame);
connect();
