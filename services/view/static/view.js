// ovis live view: one WebSocket, plain DOM/SVG. Every object drawn on the map is a
// <g> with data-id, data-kind, data-x-cm, data-y-cm (and data-heading-deg for robots).
// How current each stream is comes from the server (state and seconds as of sending);
// the page adds the time since, every second, so the seconds grow with no message.
"use strict";

const SVGNS = "http://www.w3.org/2000/svg";
const TRAIL = 60; // positions kept per robot
const PICTURES_KEPT = 300; // headers of the last pictures, for scripts (view.pictureLog)
const $ = (id) => document.getElementById(id);

const view = {
  ws: null, arena: null, operator: false, fatal: false, pictures: 0, pictureUrl: null,
  footprint: [], bounds: null, trails: new Map(), selected: "", lastMessage: null,
  alive: new Set(), received: 0, health: null, connected: false, lastHealthAt: 0,
  healthPeriod: 0.5, fresh: {}, kind: "camera", gridStep: null, pictureLog: [],
  drive: null,
};
window.ovisView = view;

function fmt(v, digits = 1) {
  return v === null || v === undefined || !Number.isFinite(v) ? "–" : v.toFixed(digits);
}

function send(obj) {
  if (view.ws && view.ws.readyState === WebSocket.OPEN) view.ws.send(JSON.stringify(obj));
}

function showError(text) {
  const el = $("error");
  el.textContent = text; el.hidden = !text;
}

function setConnection(state, text) {
  const el = $("connection");
  el.dataset.state = state; el.textContent = text;
}

function connect() {
  const proto = location.protocol === "https:" ? "wss" : "ws";
  const ws = new WebSocket(`${proto}://${location.host}/ws`);
  ws.binaryType = "arraybuffer";
  view.ws = ws;
  setConnection("connecting", "connecting…");
  ws.onopen = () => {
    setConnection("open", "connected");
    // The operator's token first: checked at once, and it gets the operator in even
    // when every viewer's seat is taken.
    const token = operatorToken();
    if (token) ws.send(JSON.stringify({ type: "auth", token }));
  };
  ws.onclose = () => {
    if (view.ws !== ws) return;
    view.connected = false;
    setConnection("closed", view.fatal ? "disconnected" : "disconnected, reconnecting…");
    unknown(view.fatal ? $("notice").textContent
      : "lost the connection to the view server: nothing shown is current; reconnecting every 2 s…");
    if (!view.fatal) setTimeout(connect, 2000);
  };
  ws.onmessage = (ev) => {
    if (ev.data instanceof ArrayBuffer) onPicture(ev.data);
    else onText(ev.data);
  };
}

function onText(text) {
  let msg;
  try { msg = JSON.parse(text); } catch (e) { return; }
  switch (msg.type) {
    case "hello": onHello(msg); break;
    case "health": onHealth(msg); break;
    case "obstacles": onObstacles(msg); break;
    case "robots": onRobots(msg); break;
    case "recalibration": onRecalibration(msg); break;
    case "auth":
      if (!msg.ok) { sessionStorage.removeItem("ovis-token"); showError(`operator token: ${msg.message}`); }
      break;
    case "error":
      showError(msg.message);
      if (msg.fatal) { view.fatal = true; $("notice").textContent = msg.message; }
      break;
  }
}

function onHello(msg) {
  if (view.arena !== msg.arena) resetArena();
  view.arena = msg.arena; view.operator = msg.operator;
  view.healthPeriod = msg.health_period_s || 0.5;
  $("arena-name").textContent = `arena ${msg.arena}`;
  setArenas(msg.arenas || []);
  buildRecalibration(msg.operator);
  view.kind = $("show-binary").checked ? "binary" : "camera";
  send({ type: "show", kind: view.kind });
}

function resetArena() {
  view.footprint = []; view.bounds = null; view.trails.clear(); view.lastMessage = null;
  view.received = 0; view.fresh = {}; view.gridStep = null; view.pictureLog = []; view.drive = null;
  for (const id of ["grid-layer", "footprint-layer", "planner-layer", "trail-layer", "drive-layer", "object-layer", "scale-layer"]) $(id).replaceChildren();
  $("drive-info").replaceChildren();
  $("picture").hidden = true; $("picture-info").textContent = "no picture yet";
  showFreshness();
}

function setArenas(arenas) {
  const sel = $("arena-select");
  const names = [...new Set([...arenas, view.arena].filter(Boolean))].sort();
  $("arena-label").hidden = names.length < 2;
  if ([...sel.options].map((o) => o.value).join() !== names.join()) {
    sel.replaceChildren(...names.map((n) => new Option(n, n)));
  }
  sel.value = view.arena;
}

// --- pictures --------------------------------------------------------------------
function onPicture(buf) {
  const n = new DataView(buf).getUint32(0);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
  if (header.arena !== view.arena) return;
  const url = URL.createObjectURL(new Blob([new Uint8Array(buf, 4 + n)], { type: "image/jpeg" }));
  const img = $("picture");
  const old = view.pictureUrl;
  img.onload = () => { if (old) URL.revokeObjectURL(old); };
  img.src = url; img.hidden = false; view.pictureUrl = url;
  img.dataset.seq = header.seq; img.dataset.kind = header.kind;
  img.dataset.points = header.points || 0;
  img.dataset.robots = (header.robots || []).map((r) => r.label).join(",");
  view.pictures += 1;
  view.pictureLog.push({ seq: header.seq, kind: header.kind, points: header.points || 0,
    calibration_frame: header.calibration_frame, robots: header.robots || [], detected: header.detected,
    width: header.width, height: header.height, state: header.fresh ? header.fresh.state : null });
  if (view.pictureLog.length > PICTURES_KEPT) view.pictureLog.shift();
  if (header.fresh) setFresh(header.kind, header.fresh);
  setCount("count-pictures", view.pictures);
  const robots = (header.robots || []).map((r) => r.label);
  let info = `${header.kind} frame ${header.seq}, ${header.width}×${header.height}`;
  if (header.kind === "camera") {
    if (header.detected === false) info += ", its detections have not arrived (none drawn)";
    else info += `, ${header.objects} objects drawn` + (robots.length ? ` (robots ${robots.join(", ")})` : "");
    if (header.points) info += `; the ${header.points} control points of calibration v${header.calibration_version} (its own frame)`;
    else if (header.calibration_frame != null) info += `; control points only on frame ${header.calibration_frame}, the calibration's`;
  }
  $("picture-info").textContent = info;
  showFreshness();
}

function setCount(id, value) {
  const el = $(id); el.dataset.value = value; el.textContent = value;
}

// --- map -------------------------------------------------------------------------
function robotsOf(m) {
  // Marked robots when there are any, else the paper's one unmarked robot.
  if (Array.isArray(m.robots) && m.robots.length) return m.robots;
  return m.robot ? [m.robot] : [];
}

function grow(b, x, y, margin) {
  if (!b) return { x0: x - margin, x1: x + margin, y0: y - margin, y1: y + margin };
  return { x0: Math.min(b.x0, x - margin), x1: Math.max(b.x1, x + margin),
           y0: Math.min(b.y0, y - margin), y1: Math.max(b.y1, y + margin) };
}

function applyBounds() {
  const b = view.bounds; if (!b) return;
  // World y points up: the SVG draws (x, -y).
  $("map").setAttribute("viewBox", `${b.x0} ${-b.y1} ${b.x1 - b.x0} ${b.y1 - b.y0}`);
  drawGrid();
}

function gridLines(lo, hi, step) {
  const out = [];
  for (let k = Math.ceil(lo / step); k * step <= hi; k++) out.push(k * step);
  return out;
}

function cmText(v) {
  return Number.isInteger(v) ? `${v}` : `${+v.toFixed(3)}`;
}

// Lines every `gridStep` cm (the server chooses it from what the map shows), labelled
// along the bottom and left edges, and a scale bar one step long.
function drawGrid() {
  const b = view.bounds, step = view.gridStep;
  const grid = $("grid-layer"), scale = $("scale-layer");
  if (!b || !step) { grid.replaceChildren(); scale.replaceChildren(); return; }
  const w = b.x1 - b.x0, font = Math.max(w, b.y1 - b.y0) / 45, thin = w / 900;
  const style = `font-size:${font}px`;
  const items = [];
  for (const x of gridLines(b.x0, b.x1, step)) {
    items.push(el("line", { class: x === 0 ? "grid axis" : "grid", "data-x-cm": x,
      x1: x, x2: x, y1: -b.y1, y2: -b.y0, "stroke-width": thin }));
    if (x - b.x0 > font * 2) { // the corner is the y labels'
      items.push(el("text", { class: "grid-label", "data-x-cm": x, x: x + font * 0.2, y: -b.y0 - font * 0.3, style }, cmText(x)));
    }
  }
  for (const y of gridLines(b.y0, b.y1, step)) {
    items.push(el("line", { class: y === 0 ? "grid axis" : "grid", "data-y-cm": y,
      x1: b.x0, x2: b.x1, y1: -y, y2: -y, "stroke-width": thin }));
    items.push(el("text", { class: "grid-label", "data-y-cm": y, x: b.x0 + font * 0.2, y: -y - font * 0.3, style }, cmText(y)));
  }
  grid.dataset.stepCm = step;
  grid.replaceChildren(...items);
  // The scale bar: bottom right, one grid step long.
  const x1 = b.x1 - font, x0 = x1 - step, y = -b.y0 - font * 1.6, tick = font * 0.5;
  const bar = el("g", { id: "scale-bar", "data-cm": step });
  bar.append(el("title", {}, `scale: this bar is ${cmText(step)} cm on the floor; grid lines every ${cmText(step)} cm`));
  bar.append(el("rect", { class: "scale-back", x: x0 - font * 0.4, y: y - font * 1.6, width: step + font * 0.8, height: font * 2.2 }));
  bar.append(el("line", { class: "scale", x1: x0, x2: x1, y1: y, y2: y, "stroke-width": font / 5 }));
  for (const x of [x0, x1]) bar.append(el("line", { class: "scale", x1: x, x2: x, y1: y - tick, y2: y + tick, "stroke-width": font / 8 }));
  bar.append(el("text", { class: "scale-label", x: (x0 + x1) / 2, y: y - font * 0.5, "text-anchor": "middle", style }, `${cmText(step)} cm`));
  scale.replaceChildren(bar);
}

function el(tag, attrs = {}, text) {
  const e = document.createElementNS(SVGNS, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}

function label(obj) {
  if ((obj.kind || "obstacle") !== "robot") return `O${obj.id}`;
  return obj.name ? `R${obj.id} ${obj.name}` : `R${obj.id}`;
}

function objectKey(obj) { return `${obj.kind || "obstacle"}-${obj.id}`; }

function drawMap(m) {
  const robots = robotsOf(m).map((r) => ({ kind: "robot", ...r }));
  const obstacles = (m.obstacles || []).map((o) => ({ kind: "obstacle", ...o }));
  const objects = [...robots, ...obstacles].filter((o) => Number.isFinite(o.x_cm) && Number.isFinite(o.y_cm));
  for (const o of objects) view.bounds = grow(view.bounds, o.x_cm, o.y_cm, (o.radius_cm || 0) + 10);
  applyBounds();
  const map = $("map");
  map.dataset.seq = m.seq; map.dataset.calibrationVersion = m.calibration_version;
  // trails
  for (const r of robots) {
    const key = objectKey(r);
    const t = view.trails.get(key) || [];
    t.push([r.x_cm, r.y_cm]); if (t.length > TRAIL) t.shift();
    view.trails.set(key, t);
  }
  const trails = [];
  for (const [key, pts] of view.trails) {
    const line = el("polyline", { class: "trail ovis", "data-robot": key, "data-source": "ovis",
      "data-points": pts.length, points: pts.map(([x, y]) => `${x},${-y}`).join(" ") });
    line.append(el("title", {}, `trail of ${key}: its positions as measured by ovis (the pose stage)`));
    trails.push(line);
  }
  $("trail-layer").replaceChildren(...trails);
  // objects
  const groups = objects.map((o) => {
    const g = el("g", { class: `obj ${o.kind}`, "data-id": o.id, "data-kind": o.kind,
      "data-x-cm": o.x_cm.toFixed(3), "data-y-cm": o.y_cm.toFixed(3),
      "data-radius-cm": fmt(o.radius_cm || 0, 3), tabindex: 0 });
    if (o.kind === "robot") {
      g.dataset.headingDeg = Number.isFinite(o.heading_deg) ? o.heading_deg.toFixed(1) : "";
      if (objectKey(o) === view.selected) g.classList.add("selected");
      g.addEventListener("click", () => selectRobot(objectKey(o)));
    }
    g.append(el("title", {}, `${label(o)} ${o.kind} at (${fmt(o.x_cm)}, ${fmt(o.y_cm)}) cm, radius ${fmt(o.radius_cm)} cm` +
      (o.kind === "robot" && Number.isFinite(o.heading_deg) ? `, heading ${fmt(o.heading_deg)}°` : "")));
    g.append(el("circle", { cx: o.x_cm, cy: -o.y_cm, r: Math.max(o.radius_cm || 0, 1) }));
    if (o.kind === "robot" && Number.isFinite(o.heading_deg)) {
      const h = (o.heading_deg * Math.PI) / 180, L = Math.max(o.radius_cm || 0, 4) * 1.6;
      g.append(el("line", { class: "heading", x1: o.x_cm, y1: -o.y_cm,
        x2: o.x_cm + L * Math.cos(h), y2: -(o.y_cm + L * Math.sin(h)) }));
    }
    g.append(el("text", { x: o.x_cm + (o.radius_cm || 1) + 1, y: -o.y_cm }, label(o)));
    return g;
  });
  $("object-layer").replaceChildren(...groups);
  drawPlanner(m, robots, obstacles);
  fillRobotSelect(robots);
  fillObjectTable(objects);
  setCount("count-objects", objects.length);
  $("map-info").textContent = `frame ${m.seq}, calibration v${m.calibration_version}`;
}

function drawPlanner(m, robots, obstacles) {
  const robot = robots.find((r) => objectKey(r) === view.selected);
  const layer = $("planner-layer");
  if (!robot) { layer.replaceChildren(); return; }
  const byId = new Map(obstacles.map((o) => [o.id, o]));
  // Marked robots: their own plans (to obstacles and to the other robots, which are
  // obstacles to them); the unmarked robot: the message's planner list.
  const plan = (m.robot_plans || []).find((p) => p.robot_id === robot.id);
  let entries = m.planner || [];
  if (plan) {
    for (const r of robots) if (r.id !== robot.id) byId.set(`robot-${r.id}`, r);
    entries = plan.entries.map((e) => ({ ...e,
      obstacle_id: e.target_kind === "robot" ? `robot-${e.target_id}` : e.target_id }));
  }
  layer.replaceChildren(...entries.filter((e) => byId.has(e.obstacle_id)).map((e) => {
    const o = byId.get(e.obstacle_id);
    const g = el("g", { class: "planner", "data-obstacle-id": e.obstacle_id,
      "data-distance-cm": fmt(e.distance_cm, 2), "data-angle-deg": fmt(e.angle_deg, 1) });
    g.append(el("line", { x1: robot.x_cm, y1: -robot.y_cm, x2: o.x_cm, y2: -o.y_cm }));
    g.append(el("text", { x: (robot.x_cm + o.x_cm) / 2, y: -(robot.y_cm + o.y_cm) / 2 },
      `${fmt(e.distance_cm)} cm ${e.angle_deg >= 0 ? "+" : ""}${fmt(e.angle_deg)}°`));
    return g;
  }));
}

function selectRobot(key) {
  view.selected = key;
  $("robot-select").value = key;
  if (view.lastMessage) drawMap(view.lastMessage);
}

function fillRobotSelect(robots) {
  const sel = $("robot-select");
  const keys = robots.map(objectKey);
  if (!view.selected && keys.length) view.selected = keys[0];
  const want = ["", ...keys].join();
  if ([...sel.options].map((o) => o.value).join() !== want) {
    sel.replaceChildren(new Option("no robot", ""), ...robots.map((r) => new Option(label(r), objectKey(r))));
  }
  sel.value = view.selected;
}

function fillObjectTable(objects) {
  const rows = objects.map((o) => {
    const tr = document.createElement("tr");
    for (const v of [`${label(o)} (${o.kind})`, fmt(o.x_cm, 2), fmt(o.y_cm, 2), fmt(o.radius_cm, 2),
      o.kind === "robot" ? fmt(o.heading_deg) : ""]) {
      const td = document.createElement("td"); td.textContent = v; tr.append(td);
    }
    return tr;
  });
  document.querySelector("#objects tbody").replaceChildren(...rows);
}

function drawFootprint(points) {
  view.footprint = points;
  for (const [x, y] of points) view.bounds = grow(view.bounds, x, y, 5);
  applyBounds();
  const layer = $("footprint-layer");
  if (points.length < 3) { layer.replaceChildren(); return; }
  const poly = el("polygon", { class: "footprint", "data-kind": "footprint",
    points: points.map(([x, y]) => `${x},${-y}`).join(" ") });
  poly.append(el("title", {}, "what the camera sees of the floor (its footprint)"));
  layer.replaceChildren(poly);
}

function onObstacles(msg) {
  if (msg.arena !== view.arena || !msg.message) return;
  view.received = msg.received;
  setCount("count-messages", msg.received);
  view.lastMessage = msg.message;
  drawMap(msg.message);
}

// --- driven robots: goal, command, the world's trail -----------------------------
function onRobots(msg) {
  if (msg.arena !== view.arena) return;
  view.drive = { robots: msg.robots, at: performance.now() };
  for (const r of msg.robots) {
    if (r.goal_cm) view.bounds = grow(view.bounds, r.goal_cm[0], r.goal_cm[1], 10);
    for (const [x, y] of r.trail_cm) view.bounds = grow(view.bounds, x, y, 5);
  }
  applyBounds();
  drawDrive();
}

// A command as it is now: the server's judgement, its seconds grown by the time since;
// past either of the robots' limits it is stale here too (the server may be silent).
function commandNow(c, dt) {
  const since = c.since_s + dt, age = c.age_s + dt;
  let state = c.state, reason = c.reason;
  if (state !== "stale" && since > c.command_timeout_s) {
    state = "stale"; reason = `no newer command for ${since.toFixed(2)} s: over the robots' watchdog of ${c.command_timeout_s} s`;
  } else if (state !== "stale" && age > c.max_frame_age_s) {
    state = "stale"; reason = `made from a frame ${age.toFixed(2)} s old: over the robots' limit of ${c.max_frame_age_s} s`;
  }
  return { ...c, since_s: since, age_s: age, state, reason };
}

// Where the command would take the robot in one second (a differential drive: forwards
// v, turning at ω), from the pose it was drawn at.
function commandPath(c) {
  let [x, y, h] = c.at; h = (h * Math.PI) / 180;
  const pts = [[x, y]], n = 12, dt = 1 / n, w = (c.omega_deg_s * Math.PI) / 180;
  for (let i = 0; i < n; i++) {
    x += c.v_cm_s * dt * Math.cos(h); y += c.v_cm_s * dt * Math.sin(h); h += w * dt;
    pts.push([x, y]);
  }
  return pts;
}

function commandText(c) {
  const sign = (v) => (v >= 0 ? "+" : "");
  const frame = c.frame_seq != null ? `frame ${c.frame_seq}` : `the frame captured at ${utc(c.frame_stamp_ns)}`;
  const what = `v ${fmt(c.v_cm_s)} cm/s, ω ${sign(c.omega_deg_s)}${fmt(c.omega_deg_s)} °/s (floor frame, ω counter-clockwise) from ${frame}, ${ageText(c.age_s)} old`;
  if (c.state === "stale") return `STALE command ${c.seq}: ${what}; ${c.reason}`;
  if (c.state === "stop") return `command ${c.seq}: STOP (${c.reason}); ${what}`;
  return `command ${c.seq}: ${what}` + (c.replay ? ` (replay of ${c.replay})` : "");
}

function drawDrive() {
  const layer = $("drive-layer"), info = $("drive-info");
  if (!view.drive) { layer.replaceChildren(); info.replaceChildren(); return; }
  const dt = (performance.now() - view.drive.at) / 1000;
  const items = [], lines = [];
  for (const r of view.drive.robots) {
    const line = document.createElement("li");
    line.dataset.robotId = r.id;
    const parts = [];
    if (r.trail_cm.length) {
      const t = el("polyline", { class: "trail world", "data-robot-id": r.id, "data-source": "world",
        "data-points": r.trail_cm.length, points: r.trail_cm.map(([x, y]) => `${x},${-y}`).join(" ") });
      t.append(el("title", {}, `R${r.id} trail: ${r.trail_from}`));
      items.push(t);
      parts.push(`trail (dashed): ${r.trail_from}` + (r.goal_reached ? "; goal reached" : "") +
        (r.collisions ? `; ${r.collisions} collision${r.collisions === 1 ? "" : "s"}` : ""));
    }
    if (r.goal_cm) {
      const [gx, gy] = r.goal_cm;
      const g = el("g", { class: "goal", "data-robot-id": r.id, "data-x-cm": gx.toFixed(2), "data-y-cm": gy.toFixed(2) });
      g.append(el("title", {}, `goal of R${r.id} at (${fmt(gx)}, ${fmt(gy)}) cm: ${r.goal_from}`));
      g.append(el("circle", { cx: gx, cy: -gy, r: 4 }));
      g.append(el("line", { x1: gx - 5, x2: gx + 5, y1: -gy, y2: -gy }));
      g.append(el("line", { x1: gx, x2: gx, y1: -gy - 5, y2: -gy + 5 }));
      g.append(el("text", { x: gx + 5, y: -gy - 2 }, `goal R${r.id}`));
      items.push(g);
      parts.push(`goal (${fmt(gx)}, ${fmt(gy)}) cm, ${r.goal_from}`);
    }
    if (r.command) {
      const c = commandNow(r.command, dt);
      const text = commandText(c);
      line.dataset.commandState = c.state;
      if (c.at) {
        const g = el("g", { class: "command", "data-robot-id": r.id, "data-state": c.state, "data-seq": c.seq,
          "data-v-cm-s": c.v_cm_s.toFixed(3), "data-omega-deg-s": c.omega_deg_s.toFixed(3),
          "data-frame-seq": c.frame_seq ?? "", "data-age-s": c.age_s.toFixed(3) });
        g.append(el("title", {}, `${text}; drawn from ${c.at_from}; the line: where it would drive the robot in 1 s`));
        const path = el("polyline", { points: commandPath(c).map(([x, y]) => `${x},${-y}`).join(" ") });
        if (c.state !== "stale") path.setAttribute("marker-end", "url(#command-arrow)");
        g.append(path);
        const label = c.state === "stale" ? "stale command"
          : c.state === "stop" ? "stop" : `${fmt(c.v_cm_s)} cm/s ${c.omega_deg_s >= 0 ? "+" : ""}${fmt(c.omega_deg_s, 0)} °/s`;
        g.append(el("text", { x: c.at[0] + 4, y: -c.at[1] + 5 }, label));
        items.push(g);
      }
      parts.push(text + (c.at ? ` (arrow: the next 1 s of it, from ${c.at_from})` : ""));
    }
    line.textContent = `R${r.id}: ${parts.join(" · ")}`;
    lines.push(line);
  }
  layer.replaceChildren(...items);
  info.replaceChildren(...lines);
}

// --- health ----------------------------------------------------------------------
function onHealth(msg) {
  if (msg.arena !== view.arena) return;
  view.health = msg;
  setArenas(msg.arenas || []);
  const s = msg.summary;
  const rows = s.stages.map((st) => {
    const tr = document.createElement("tr");
    tr.dataset.stage = st.name; tr.dataset.alive = st.alive;
    tr.className = st.alive ? "alive" : "dead";
    const errors = st.errors ? `${st.errors} (${Object.entries(st.errors_by_kind).map(([k, v]) => `${k} ${v}`).join(", ")})` : "0";
    const cells = [st.name, st.alive ? "yes" : "NO", st.state, fmt(st.fps), st.frames_in ?? "–",
      st.frames_out ?? "–", st.dropped ?? "–", errors, st.where || "–"];
    cells.forEach((v, i) => {
      const td = document.createElement("td"); td.textContent = v;
      if (i === 7 && st.last_error) td.title = st.last_error;
      tr.append(td);
    });
    return tr;
  });
  document.querySelector("#stages tbody").replaceChildren(...rows);
  const noLatency = s.replay ? "– (a replay: not live)" : "–";
  $("latency-p50").textContent = s.latency_p50_ms == null ? noLatency : `${fmt(s.latency_p50_ms, 2)} ms`;
  $("latency-p99").textContent = s.latency_p99_ms == null ? "–" : `${fmt(s.latency_p99_ms, 2)} ms`;
  $("stream").textContent = s.stream; $("stream").dataset.state = s.stream;
  $("stream-reason").textContent = s.stream_reason ? `: ${s.stream_reason}` : "";
  $("viewers").textContent = msg.viewers;
  view.connected = true; view.lastHealthAt = performance.now();
  for (const [kind, f] of Object.entries(s.fresh || {})) setFresh(kind, f);
  if (msg.grid_step_cm !== view.gridStep) { view.gridStep = msg.grid_step_cm; drawGrid(); }
  const c = s.calibration, cal = $("calibration");
  cal.dataset.version = c ? c.version : 0;
  cal.textContent = c
    ? `v${c.version}: DIPE ${fmt(c.dipe_px, 3)} px = ${fmt(c.dipe_mm, 4)} mm (max ${fmt(c.dipe_max_px, 3)} px)` +
      (c.held_out_px != null ? `; held-out (${c.held_out_method}) ${fmt(c.held_out_px, 3)} px` +
        (c.held_out_cm != null ? ` = ${fmt(c.held_out_cm, 3)} cm` : "") : "; no held-out error") +
      (c.age_s != null ? `; made ${ago(c.age_s)} ago` : "") + (c.source ? ` on ${c.source}` : "")
    : "no calibration yet (the calibrator has not published one)";
  if (msg.footprint && msg.footprint.length !== view.footprint.length) drawFootprint(msg.footprint);
  else if (msg.footprint && msg.footprint.length && view.footprint[0] && msg.footprint[0][0] !== view.footprint[0][0]) drawFootprint(msg.footprint);
  if (msg.recalibration && view.operator) onRecalibration({ arena: msg.arena, ...msg.recalibration }, true);
  $("notice").textContent = notice(s, msg);
  showFreshness();
}

function ago(s) {
  if (s < 120) return `${Math.round(s)} s`;
  if (s < 7200) return `${Math.round(s / 60)} min`;
  if (s < 172800) return `${Math.round(s / 3600)} h`;
  return `${Math.round(s / 86400)} days`;
}

function notice(s, msg) {
  const alive = s.stages.filter((st) => st.alive).map((st) => st.name);
  const dead = s.stages.filter((st) => !st.alive).map((st) => st.name);
  const down = dead.length ? ` (not running: ${dead.join(", ")})` : "";
  const why = s.stream_reason ? `: ${s.stream_reason}` : "";
  if (s.stream === "source lost") return `arena ${msg.arena}: SOURCE LOST${why}` + down;
  if (s.replay) return `arena ${msg.arena}: a REPLAY of ${s.replay}, not a live camera` + down;
  if (!alive.length) return `arena ${msg.arena}: no stage is running (waiting for ovis up / ovis run)`;
  if (!view.received) return `arena ${msg.arena}: waiting for the first obstacle message` + down;
  if (s.stream === "stalled") return `arena ${msg.arena}: NO DATA, frames have stopped` + down;
  if (!["ok", "waiting"].includes(s.stream)) return `arena ${msg.arena}: stream ${s.stream}${why}` + down;
  if (dead.length) return `arena ${msg.arena}: not running: ${dead.join(", ")}`;
  return `arena ${msg.arena}: all stages running`;
}

// --- how current it is -------------------------------------------------------------
function setFresh(kind, f) {
  view.fresh[kind] = { f, at: performance.now() };
}

// The freshness of `kind` now: the server's, its seconds grown by the time since.
function freshNow(kind) {
  const e = view.fresh[kind];
  if (!e) return null;
  const dt = (performance.now() - e.at) / 1000;
  const plus = (v) => (v == null ? null : v + dt);
  return { ...e.f, age_s: plus(e.f.age_s), since_s: plus(e.f.since_s) };
}

function secs(s) { return s < 10 ? s.toFixed(1) : `${Math.round(s)}`; }
function ageText(s) { return Math.abs(s) < 1 ? `${Math.round(s * 1000)} ms` : `${secs(s)} s`; }
function utc(ns) {
  return new Date(ns / 1e6).toISOString().replace("T", " ").replace(/\.(\d)\d*Z$/, ".$1 UTC");
}

function describe(f, what) {
  if (!f) return `no ${what} yet`;
  switch (f.state) {
    case "waiting": return `waiting for the first ${what}` + (f.since_s != null ? ` (${secs(f.since_s)} s)` : "");
    case "live": return `live · ${what} ${f.seq} · age ${ageText(f.age_s)}`;
    case "late": return `late · ${what} ${f.seq} captured ${secs(f.age_s)} s ago, not live ` +
      "(replayed without saying so, or the camera's clock is off)";
    case "replay": return `replay of ${f.recording} · recorded ${utc(f.recorded_ns)} · ${secs(f.into_s)} s into the recording`;
    case "stalled": return `stalled · no ${what} for ${secs(f.since_s)} s · ` + (f.recording
      ? `replay of ${f.recording}, last recorded ${utc(f.recorded_ns)}`
      : `last ${what} ${f.seq}, captured ${secs(f.age_s)} s ago`);
    default: return f.state;
  }
}

function staleText(f) {
  if (!view.connected) return "DISCONNECTED";
  if (!f) return "";
  if (f.state === "stalled") return `STALE ${Math.round(f.since_s)} s`;
  if (f.state === "late") return `LATE ${Math.round(f.age_s)} s`;
  return "";
}

function showFresh(id, f, what) {
  const el = $(id);
  el.dataset.state = view.connected ? (f ? f.state : "waiting") : "unknown";
  el.dataset.sinceS = f && f.since_s != null ? f.since_s.toFixed(1) : "";
  el.textContent = view.connected ? describe(f, what) : "unknown (not connected to the view server)";
}

function showFreshness() {
  const kind = $("picture").dataset.kind || view.kind;
  const pic = freshNow(kind), obs = freshNow("obstacles");
  showFresh("picture-fresh", pic, kind === "binary" ? "binarised frame" : "frame");
  showFresh("map-fresh", obs, "obstacle message");
  const stale = $("picture").hidden ? "" : staleText(pic);
  $("picture-box").dataset.stale = stale ? "true" : "false";
  $("picture-stale").hidden = !stale; $("picture-stale").textContent = stale;
  const mapStale = !view.connected || (obs && (obs.state === "stalled" || obs.state === "late"));
  $("map").dataset.stale = mapStale ? "true" : "false";
}

// Not connected (or the server stopped talking): nothing on the page is current.
function unknown(text) {
  view.connected = false;
  $("stream").textContent = "unknown"; $("stream").dataset.state = "unknown";
  $("stream-reason").textContent = "";
  for (const id of ["latency-p50", "latency-p99", "viewers"]) $(id).textContent = "–";
  for (const tr of document.querySelectorAll("#stages tbody tr")) {
    tr.dataset.alive = "unknown"; tr.className = "unknown";
    tr.cells[1].textContent = "?"; tr.cells[2].textContent = "unknown";
  }
  $("notice").textContent = text;
  showFreshness();
}

function everySecond() {
  const quiet = (performance.now() - view.lastHealthAt) / 1000;
  if (view.connected && quiet > Math.max(5, 10 * view.healthPeriod)) {
    unknown(`the view server has sent nothing for ${Math.round(quiet)} s: nothing shown is current`);
  }
  showFreshness();
  if (view.drive) drawDrive();
}

// --- recalibration ---------------------------------------------------------------
function operatorToken() {
  return new URLSearchParams(location.hash.slice(1)).get("token") || sessionStorage.getItem("ovis-token") || "";
}

function buildRecalibration(operator) {
  const panel = $("recalibration-panel");
  if (!operator) { panel.replaceChildren(); return; }
  if ($("recalibrate")) return;
  const fromUrl = operatorToken();
  panel.innerHTML = `<form id="recal-form" onsubmit="return false">
    <label>operator token <input type="password" id="token" autocomplete="off"></label>
    <label>population <input type="number" id="population" min="2" max="10000" placeholder="configured"></label>
    <label>generations <input type="number" id="generations" min="1" max="10000" placeholder="configured"></label>
    <label>seed <input type="number" id="seed" min="0" placeholder="configured"></label>
    <button id="recalibrate" type="button">Recalibrate</button>
    <output id="recal-status" data-state="idle" aria-live="polite"></output></form>`;
  $("token").value = fromUrl;
  $("recalibrate").addEventListener("click", () => {
    const token = $("token").value;
    sessionStorage.setItem("ovis-token", token);
    const req = { type: "recalibrate", token };
    for (const k of ["population", "generations", "seed"]) {
      const v = parseInt($(k).value, 10);
      if (Number.isFinite(v)) req[k] = v;
    }
    $("recal-status").dataset.state = "sent"; $("recal-status").textContent = "sent…";
    send(req);
  });
}

let recalTimer = null;
function onRecalibration(msg, fromHealth = false) {
  if (msg.arena !== view.arena) return;
  const out = $("recal-status"), btn = $("recalibrate");
  if (!out) return;
  if (fromHealth && msg.state !== "running" && out.dataset.state !== "running") return;
  out.dataset.state = msg.state;
  clearInterval(recalTimer);
  if (msg.state === "running") {
    btn.disabled = true;
    const t0 = msg.started_ns / 1e6;
    const tick = () => { out.textContent = `running… ${Math.max(0, (Date.now() - t0) / 1000).toFixed(0)} s (${msg.message})`; };
    tick(); recalTimer = setInterval(tick, 1000);
  } else {
    btn.disabled = false;
    out.textContent = msg.message;
    if (msg.reply) out.dataset.version = msg.reply.version;
  }
}

$("show-binary").addEventListener("change", (e) => {
  view.kind = e.target.checked ? "binary" : "camera";
  send({ type: "show", kind: view.kind });
});
$("arena-select").addEventListener("change", (e) => send({ type: "select", arena: e.target.value }));
$("robot-select").addEventListener("change", (e) => selectRobot(e.target.value));
setInterval(everySecond, 1000);
setInterval(() => { if (view.drive) drawDrive(); }, 250); // a command turns stale on time
connect();
