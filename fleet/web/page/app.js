// The operator's page: plant map, vehicles, orders, statistics, watch table, event log.
// Plain ES2020 with no build step; the server's Content-Security-Policy allows only files
// from this origin, so nothing here is inline, evaluated or fetched from elsewhere.
"use strict";

(() => {
  const API = "/api/v1";
  const TOKEN_KEY = "plc-runtime-token";
  const SVG_NS = "http://www.w3.org/2000/svg";
  const ORDER_PAGE = 500; // orders read at once (the API's page limit)
  const ORDER_ROWS = 200; // rows shown: more would only slow the page down
  const ORDER_PAGES = 20; // pages read back at most to find them (10,000 positions)
  const EVENT_ROWS = 100;
  const WATCH_PERIOD_MS = 500;
  const MAX_WATCH = 200; // the API's limit for one values request
  const TOWARDS_NEXT = 0.3; // how far a moving vehicle is drawn towards its next node
  const LARGE_PLANT = 400; // more nodes: no transit dots and no names (they would hide the lanes)
  const LABEL_EM = 0.25; // a node's name: font size per typical segment length, before scaling
  const LABELLED = new Set(["station", "entry", "exit", "charger"]);
  const RETRY_MS = 3000;
  const STATS_PERIOD_MS = 5000; // the percentiles and the cycle time are only in GET /stats
  const ANIMATE_UP_TO = 40; // vehicles: more, and they jump from snapshot to snapshot
  const FINAL = new Set(["FINISHED", "FAILED", "WITHDRAWN", "UNROUTABLE"]);
  const ORDER_STATES = ["RAW", "DISPATCHABLE", "BEING_PROCESSED", "FINISHED", "FAILED", "WITHDRAWN", "UNROUTABLE"];

  const $ = (selector) => document.querySelector(selector);

  // ----- small helpers ------------------------------------------------------------------
  function html(tag, className, text) {
    const e = document.createElement(tag);
    if (className) e.className = className;
    if (text !== undefined) e.textContent = text;
    return e;
  }

  function svg(tag, attrs, parent) {
    const e = document.createElementNS(SVG_NS, tag);
    for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, String(v));
    if (parent) parent.appendChild(e);
    return e;
  }

  function titled(e, text) {
    svg("title", {}, e).textContent = text;
    return e;
  }

  // Writes only what changed: a DOM write costs far more than a string compare, and
  // 100 vehicles at 10 snapshots a second would otherwise restyle the page constantly.
  function setText(e, text) {
    if (e._text !== text) {
      e._text = text;
      e.textContent = text;
    }
  }

  function setAttr(e, name, value) {
    const key = "_a_" + name;
    if (e[key] !== value) {
      e[key] = value;
      e.setAttribute(name, value);
    }
  }

  function setTitle(e, text) {
    if (e._title !== text) {
      e._title = text;
      e.title = text;
    }
  }

  const round3 = (x) => String(Math.round(x * 1000) / 1000);
  const dash = (x) => (x === null || x === undefined || x === "" ? "–" : String(x));

  function formatValue(v) {
    if (typeof v === "number" && !Number.isInteger(v)) return String(Number(v.toPrecision(7)));
    return String(v);
  }

  function message(text, ok = false) {
    const m = $("#message");
    m.textContent = text;
    m.classList.toggle("ok", ok);
    m.classList.toggle("error", !ok && text !== "");
  }

  // ----- the API -------------------------------------------------------------------------
  class ApiError extends Error {
    constructor(status, text, field) {
      super(text);
      this.status = status;
      this.field = field || null;
    }
  }

  const token = () => $("#token").value.trim();

  async function api(method, path, body) {
    const init = { method, headers: {}, cache: "no-store" };
    if (method !== "GET") {
      init.headers["Content-Type"] = "application/json";
      // no header at all without a token, so the server answers with its own 401 text
      if (token()) init.headers.Authorization = `Bearer ${token()}`;
      if (body !== undefined) init.body = JSON.stringify(body);
    }
    let response;
    try {
      response = await fetch(API + path, init);
    } catch (exc) {
      throw new ApiError(0, `no answer from the controller (${exc.message})`);
    }
    let data = null;
    try {
      data = await response.json();
    } catch (exc) {
      data = null; // an error page that is not JSON: the status says enough
    }
    if (!response.ok) {
      const text = data && typeof data.error === "string" && data.error
        ? data.error
        : `HTTP ${response.status} ${response.statusText}`.trim();
      throw new ApiError(response.status, text, data && data.field);
    }
    return data;
  }

  // ----- the plant -----------------------------------------------------------------------
  const plant = {
    nodes: new Map(), // id -> node (plant coordinates, metres, y up)
    unit: 1, // typical segment length: every glyph is sized from it
    stationOf: new Map(), // station or queue node -> its station
    queueCounts: new Map(), // station -> <text class="queue-count">
    segments: new Map(), // "a-b" (a < b) -> { hit: <line class="segment">, lane: <line class="lane"> }
    closed: new Set(),
    box: null, // the viewBox: x, y, width, height
  };
  const pairKey = (a, b) => (a < b ? `${a}-${b}` : `${b}-${a}`);

  function median(values) {
    if (!values.length) return 1;
    const s = [...values].sort((x, y) => x - y);
    return s[Math.floor(s.length / 2)];
  }

  // A return lane (non-routable) joins an exit to an entry far away; drawn straight it would
  // cross the plant, so it runs round the outside of the nodes' box, the shorter way.
  function detour(pa, pb, box, gap) {
    const [x0, x1, y0, y1] = box;
    const o = [x0 - gap, x1 + gap, y0 - gap, y1 + gap];
    const side = (p) => {
      const gaps = { left: p.x - x0, right: x1 - p.x, bottom: p.y - y0, top: y1 - p.y };
      return Object.keys(gaps).reduce((m, k) => (gaps[k] < gaps[m] ? k : m));
    };
    const onto = (p, s) => ({
      left: { x: o[0], y: p.y }, right: { x: o[1], y: p.y },
      bottom: { x: p.x, y: o[2] }, top: { x: p.x, y: o[3] },
    })[s];
    const corner = { // the corner after each side, going round clockwise (y up)
      top: { x: o[1], y: o[3] }, right: { x: o[1], y: o[2] },
      bottom: { x: o[0], y: o[2] }, left: { x: o[0], y: o[3] },
    };
    const order = ["top", "right", "bottom", "left"];
    const sa = side(pa), sb = side(pb);
    let best = null;
    for (const step of [1, -1]) {
      let s = sa;
      const via = [];
      while (s !== sb) {
        if (step === 1) via.push(corner[s]);
        const next = order[(order.indexOf(s) + step + 4) % 4];
        if (step === -1) via.push(corner[next]);
        s = next;
      }
      const way = [pa, onto(pa, sa), ...via, onto(pb, sb), pb];
      let length = 0;
      for (let i = 1; i < way.length; i++) length += Math.hypot(way[i].x - way[i - 1].x, way[i].y - way[i - 1].y);
      if (!best || length < best.length - 1e-9) best = { length, way };
    }
    return best.way;
  }

  const pointsOf = (way) => way.map((p) => `${round3(p.x)},${round3(-p.y)}`).join(" ");

  function drawPlant(p) {
    $("#plant-name").textContent = p.name || "plant";
    document.title = `${p.name || "plant"}: fleet controller`;
    for (const n of p.nodes) plant.nodes.set(n.id, n);
    for (const s of p.stations) plant.stationOf.set(s, s);
    for (const [s, queue] of Object.entries(p.queues || {})) {
      for (const q of queue) plant.stationOf.set(q, Number(s));
    }
    for (const n of p.nodes) { // a queue place the queues table missed still counts for its station
      if (n.queue_for !== null && n.queue_for !== undefined && !plant.stationOf.has(n.id)) plant.stationOf.set(n.id, n.queue_for);
    }

    // One drawn segment per unordered pair, whichever way (or ways) the edges run.
    const pairs = new Map();
    for (const e of p.edges) {
      if (!plant.nodes.has(e.a) || !plant.nodes.has(e.b) || e.a === e.b) continue;
      const key = pairKey(e.a, e.b);
      let pair = pairs.get(key);
      if (!pair) {
        pair = { a: Math.min(e.a, e.b), b: Math.max(e.a, e.b), routable: false, both: false, dirs: new Set(), returns: [] };
        pairs.set(key, pair);
      }
      if (e.routable) {
        pair.routable = true;
        if (e.bidirectional) pair.both = true;
        else pair.dirs.add(`${e.a}>${e.b}`);
      } else {
        pair.returns.push([e.a, e.b]);
      }
    }
    const dist = (a, b) => {
      const na = plant.nodes.get(a), nb = plant.nodes.get(b);
      return Math.hypot(na.x - nb.x, na.y - nb.y);
    };
    const unit = median([...pairs.values()].filter((q) => q.routable).map((q) => dist(q.a, q.b)).filter((d) => d > 0));
    plant.unit = unit;

    const xs = p.nodes.map((n) => n.x), ys = p.nodes.map((n) => n.y);
    const box = xs.length ? [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)] : [0, 1, 0, 1];
    const gap = 0.45 * unit;
    const returnWays = [];
    for (const pair of pairs.values()) {
      if (pair.routable || !pair.returns.length) continue;
      const [a, b] = pair.returns[0];
      returnWays.push(detour(plant.nodes.get(a), plant.nodes.get(b), box, gap));
    }
    let [x0, x1, y0, y1] = box;
    const large = p.nodes.length > LARGE_PLANT;
    if (!large) { // names under the nodes, roughly as wide as drawn: none is cut off at the edge
      for (const n of p.nodes) {
        if (!LABELLED.has(n.role)) continue;
        const half = 0.5 * (n.name || String(n.id)).length * 0.6 * LABEL_EM * unit;
        x0 = Math.min(x0, n.x - half); x1 = Math.max(x1, n.x + half);
        y0 = Math.min(y0, n.y - 0.4 * unit - 1.2 * LABEL_EM * unit);
      }
    }
    for (const way of returnWays) {
      for (const q of way) {
        x0 = Math.min(x0, q.x); x1 = Math.max(x1, q.x); y0 = Math.min(y0, q.y); y1 = Math.max(y1, q.y);
      }
    }
    const margin = 0.6 * unit;
    const map = $("#plant");
    // y grows upward in the plant and downward in SVG: every y is drawn as -y
    plant.box = [x0 - margin, -y1 - margin, Math.max(x1 - x0, unit) + 2 * margin, Math.max(y1 - y0, unit) + 2 * margin];
    map.setAttribute("viewBox", plant.box.map(round3).join(" "));

    const layers = {
      returns: $("#layer-return"), lanes: $("#layer-lanes"), arrows: $("#layer-arrows"),
      segments: $("#layer-segments"), nodes: $("#layer-nodes"), labels: $("#layer-labels"),
    };
    for (const layer of Object.values(layers)) layer.replaceChildren();
    for (const way of returnWays) svg("polyline", { class: "return-lane", points: pointsOf(way) }, layers.returns);

    const arrow = 0.12 * unit;
    for (const pair of pairs.values()) {
      if (!pair.routable) continue;
      const na = plant.nodes.get(pair.a), nb = plant.nodes.get(pair.b);
      const ends = { x1: round3(na.x), y1: round3(-na.y), x2: round3(nb.x), y2: round3(-nb.y) };
      // what is seen is thin; what is clicked is a wider, unpainted line over it, so a lane
      // of a dense plant can still be hit
      const lane = svg("line", { class: "lane", "data-a": pair.a, "data-b": pair.b, ...ends }, layers.lanes);
      // An axis-parallel line has a box of zero height or width, and some tools (WebDriver's
      // element click among them) refuse to click an element of zero size: the click target
      // is tilted by a hundredth of a segment, which nobody sees.
      const tilt = 0.01 * unit;
      const hitEnds = { ...ends };
      if (Math.abs(na.y - nb.y) < tilt) hitEnds.y2 = round3(-nb.y + tilt);
      if (Math.abs(na.x - nb.x) < tilt) hitEnds.x2 = round3(nb.x + tilt);
      const hit = svg("line", { class: "segment", "data-a": pair.a, "data-b": pair.b, ...hitEnds }, layers.segments);
      titled(hit, `${na.name || na.id} – ${nb.name || nb.id} (${pair.a}–${pair.b}): click to close or reopen`);
      plant.segments.set(pairKey(pair.a, pair.b), { hit, lane });
      if (!pair.both && pair.dirs.size === 1) { // one-way: an arrowhead half way, pointing along
        const [from, to] = [...pair.dirs][0].split(">").map(Number);
        const f = plant.nodes.get(from), t = plant.nodes.get(to);
        const d = Math.hypot(t.x - f.x, t.y - f.y) || 1;
        const ux = (t.x - f.x) / d, uy = -(t.y - f.y) / d; // SVG direction
        const mx = (f.x + t.x) / 2, my = -(f.y + t.y) / 2;
        const tip = [mx + ux * arrow, my + uy * arrow];
        const l = [mx - ux * arrow - uy * arrow * 0.8, my - uy * arrow + ux * arrow * 0.8];
        const r = [mx - ux * arrow + uy * arrow * 0.8, my - uy * arrow - ux * arrow * 0.8];
        svg("polygon", { class: "one-way", points: [tip, l, r].map((q) => q.map(round3).join(",")).join(" ") }, layers.arrows);
      }
    }

    layers.labels.setAttribute("font-size", round3(LABEL_EM * unit));
    for (const n of p.nodes) drawNode(n, layers, unit, large);
    for (const s of p.stations) {
      const n = plant.nodes.get(s);
      if (!n) continue;
      const t = svg("text", {
        class: "queue-count empty", "data-station": s,
        x: round3(n.x + 0.3 * unit), y: round3(-n.y - 0.3 * unit),
      }, layers.labels);
      t.textContent = "0";
      plant.queueCounts.set(s, t);
    }
    setBlockades(p.blockades || []);
    fillStationSelects(p);
  }

  function drawNode(n, layers, unit, large) {
    const x = n.x, y = -n.y;
    const name = n.name || String(n.id);
    const tip = `${name} (node ${n.id}, ${n.role}${n.queue_for !== null && n.queue_for !== undefined ? ` of station ${n.queue_for}` : ""})`;
    let shape = null;
    let label = false;
    switch (n.role) {
      case "station": {
        const h = 0.17 * unit;
        shape = svg("rect", { class: "node station", x: round3(x - h), y: round3(y - h), width: round3(2 * h), height: round3(2 * h) }, layers.nodes);
        label = true;
        break;
      }
      case "entry":
      case "exit": {
        const h = 0.17 * unit;
        shape = svg("polygon", {
          class: `node ${n.role}`,
          points: [[x - h, y - h], [x + h, y], [x - h, y + h]].map((q) => q.map(round3).join(",")).join(" "),
        }, layers.nodes);
        label = true;
        break;
      }
      case "charger": {
        const r = 0.17 * unit, k = r / 4;
        shape = svg("g", { class: "charger-mark" }, layers.nodes);
        svg("circle", { class: "node charger", cx: round3(x), cy: round3(y), r: round3(r) }, shape);
        const bolt = [[0.5, -3.5], [-2, 0.5], [-0.2, 0.5], [-0.7, 3.5], [2, -0.7], [0.2, -0.7]];
        svg("polygon", { class: "bolt", points: bolt.map(([bx, by]) => `${round3(x + bx * k)},${round3(y + by * k)}`).join(" ") }, shape);
        label = true;
        break;
      }
      case "parking": { // no name: parking places come in rows, their names would overlap
        const h = 0.15 * unit;
        shape = svg("g", { class: "parking-mark-group" }, layers.nodes);
        svg("rect", { class: "node parking", x: round3(x - h), y: round3(y - h), width: round3(2 * h), height: round3(2 * h), rx: round3(h / 3) }, shape);
        svg("text", { class: "parking-mark", x: round3(x), y: round3(y), "font-size": round3(1.5 * h) }, shape).textContent = "P";
        break;
      }
      case "queue": {
        const h = 0.1 * unit;
        shape = svg("polygon", {
          class: "node queue",
          points: [[x, y - h], [x + h, y], [x, y + h], [x - h, y]].map((q) => q.map(round3).join(",")).join(" "),
        }, layers.nodes);
        break;
      }
      default:
        if (large) return; // a transit dot per cell of a big grid only covers the lanes
        shape = svg("circle", { class: "node transit", cx: round3(x), cy: round3(y), r: round3(0.05 * unit) }, layers.nodes);
    }
    shape.setAttribute("data-node", n.id);
    titled(shape, tip);
    if (label && !large) {
      svg("text", { class: "node-label", x: round3(x), y: round3(y + 0.4 * unit) }, layers.labels).textContent = name;
    }
  }

  function setBlockades(list) {
    const now = new Set(list.map(([a, b]) => pairKey(a, b)));
    for (const key of plant.closed) {
      if (!now.has(key)) markClosed(key, false);
    }
    for (const key of now) {
      if (!plant.closed.has(key)) markClosed(key, true);
    }
    plant.closed = now;
  }

  function markClosed(key, closed) {
    const segment = plant.segments.get(key);
    if (!segment) return;
    segment.hit.classList.toggle("closed", closed);
    segment.lane.classList.toggle("closed", closed);
  }

  async function toggleSegment(line) {
    const a = Number(line.dataset.a), b = Number(line.dataset.b);
    if (!token()) {
      message("enter the token to close segments");
      return;
    }
    const closing = !line.classList.contains("closed");
    try {
      const answer = await api(closing ? "PUT" : "DELETE", `/blockades/${a}/${b}`);
      const next = new Set(plant.closed);
      if (answer.closed) next.add(pairKey(answer.a, answer.b));
      else next.delete(pairKey(answer.a, answer.b));
      setBlockades([...next].map((k) => k.split("-").map(Number)));
      message(`segment ${answer.a}–${answer.b} ${answer.closed ? "closed" : "reopened"}`, true);
    } catch (exc) {
      message(`segment ${a}–${b}: ${exc.message}`);
    }
  }

  // Lanes and click targets are sized in screen pixels (non-scaling strokes), vehicles in
  // metres but never smaller than a readable disc: the same page draws a 7 m workshop and a
  // 90 m hall, so both follow the map's drawn scale.
  let pixelsPerMetre = 0;

  function applyScale() {
    const map = $("#plant");
    if (!plant.box || !map.clientWidth) return;
    const scale = Math.min(map.clientWidth / plant.box[2], map.clientHeight / plant.box[3]);
    if (!(scale > 0) || Math.abs(scale - pixelsPerMetre) < 0.01 * scale) return;
    pixelsPerMetre = scale;
    const unitPx = plant.unit * scale;
    const clamp = (x, lo, hi) => Math.min(hi, Math.max(lo, x));
    map.style.setProperty("--lane-w", `${clamp(unitPx * 0.16, 2, 6).toFixed(1)}px`);
    map.style.setProperty("--hit-w", `${clamp(unitPx * 0.7, 6, 16).toFixed(1)}px`);
    for (const view of vehicles.values()) sizeVehicle(view);
    // names readable at any scale, but never larger than a third of a segment
    const font = Math.min(0.35 * plant.unit, Math.max(0.15 * plant.unit, 11 / scale));
    $("#layer-labels").setAttribute("font-size", round3(font));
  }

  function vehicleRadius() {
    const u = plant.unit;
    const readable = pixelsPerMetre > 0 ? 8 / pixelsPerMetre : 0.3 * u;
    return Math.min(0.45 * u, Math.max(0.22 * u, readable));
  }

  function sizeVehicle(view) {
    const r = vehicleRadius();
    const digits = String(view.id).length;
    setAttr(view.circle, "r", round3(r));
    setAttr(view.label, "font-size", round3(r * (digits < 2 ? 1.25 : digits < 3 ? 1.05 : 0.8)));
  }

  // ----- vehicles --------------------------------------------------------------------------
  const vehicles = new Map(); // id -> { g, circle, label, tip, released, planned, row, cells }
  let selected = null;

  function look(v) {
    if (v.suspect || v.fault || v.stale || ["suspect", "fault", "stale"].includes(v.state)) return "alert";
    if (!v.online || v.state === "offline" || v.state === "idle") return "idle";
    if (v.state === "driving" || v.state === "planning") return "moving";
    if (v.state === "waiting") return "waiting";
    if (v.state === "no_route") return "blocked";
    if (v.state === "arrived") return "arrived";
    return "idle";
  }

  function vehicleView(id) {
    let view = vehicles.get(id);
    if (view) return view;
    const routes = $("#layer-routes");
    const released = svg("polyline", { class: "route released", "data-vehicle": id, points: "" }, routes);
    const planned = svg("polyline", { class: "route planned", "data-vehicle": id, points: "" }, routes);
    const g = svg("g", { class: "vehicle hidden", "data-id": id }, $("#layer-vehicles"));
    const circle = svg("circle", {}, g);
    const label = svg("text", {}, g);
    label.textContent = String(id);
    const tip = svg("title", {}, g);
    g.addEventListener("click", () => select(id));

    const row = html("tr");
    row.dataset.id = String(id);
    const cells = {};
    for (const name of ["id", "state", "node", "target", "order", "battery", "flags"]) {
      cells[name] = row.appendChild(html("td", name));
    }
    setText(cells.id, String(id));
    setTitle(cells.id, `agv${id}`);
    row.addEventListener("click", () => select(id));
    insertSorted($("#vehicles tbody"), row, id);
    view = { id, g, circle, label, tip, released, planned, row, cells };
    sizeVehicle(view);
    vehicles.set(id, view);
    return view;
  }

  function insertSorted(tbody, row, id) {
    for (const other of tbody.children) {
      if (Number(other.dataset.id) > id) {
        tbody.insertBefore(row, other);
        return;
      }
    }
    tbody.appendChild(row);
  }

  function select(id) {
    selected = selected === id ? null : id;
    for (const view of vehicles.values()) paintSelection(view);
    $("#plant").classList.toggle("has-selection", selected !== null);
    if (selected !== null) vehicles.get(selected)?.row.scrollIntoView({ block: "nearest" });
  }

  function paintSelection(view) {
    const on = view.id === selected;
    view.row.classList.toggle("selected", on);
    view.g.classList.toggle("selected", on);
    view.released.classList.toggle("selected", on);
    view.planned.classList.toggle("selected", on);
  }

  const nodeName = (id) => (id === null || id === undefined ? "" : plant.nodes.get(id)?.name || "");

  // The newest state of every vehicle: a snapshot names only those that changed.
  const known = new Map();

  function updateVehicles(list) {
    const counts = new Map();
    for (const v of list) known.set(v.id, v);
    // a transition per vehicle repaints the whole map every frame: worth it for a few only
    $("#plant").classList.toggle("animated", known.size <= ANIMATE_UP_TO);
    for (const v of list) {
      const view = vehicleView(v.id);
      const at = v.node === null || v.node === undefined ? null : plant.nodes.get(v.node);
      const kind = look(v);
      let cls = `vehicle look-${kind}`;
      if (v.held) cls += " held";
      if (!at) cls += " hidden";
      if (v.id === selected) cls += " selected";
      setAttr(view.g, "class", cls);
      if (at) {
        let x = at.x, y = at.y;
        const next = v.next === null || v.next === v.node ? null : plant.nodes.get(v.next);
        if (next) {
          x += (next.x - x) * TOWARDS_NEXT;
          y += (next.y - y) * TOWARDS_NEXT;
        }
        setAttr(view.g, "transform", `translate(${round3(x)},${round3(-y)})`);
        setAttr(view.g, "data-x", round3(x));
        setAttr(view.g, "data-y", round3(y));
      }
      // routes: released from where it stands, planned on from the last released node
      const rel = at ? [v.node, ...v.released] : [];
      const relPoints = rel.length > 1 ? routePoints(rel) : "";
      const from = rel.length ? rel[rel.length - 1] : null;
      const plan = from !== null && v.planned.length ? [from, ...v.planned] : [];
      setAttr(view.released, "points", relPoints);
      setAttr(view.planned, "points", plan.length > 1 ? routePoints(plan) : "");
      setText(view.tip, `agv${v.id}: ${v.state}${v.battery !== null ? `, battery ${v.battery} %` : ""}${v.order ? `, order ${v.order}` : ""}`);
      updateVehicleRow(view, v, kind);
    }
    for (const v of known.values()) {
      const station = v.node === null || v.node === undefined ? undefined : plant.stationOf.get(v.node);
      if (station !== undefined) counts.set(station, (counts.get(station) || 0) + 1);
    }
    for (const [station, text] of plant.queueCounts) {
      const n = counts.get(station) || 0;
      setText(text, String(n));
      setAttr(text, "class", n ? "queue-count" : "queue-count empty");
    }
  }

  function routePoints(ids) {
    const out = [];
    for (const id of ids) {
      const n = plant.nodes.get(id);
      if (n) out.push(`${round3(n.x)},${round3(-n.y)}`);
    }
    return out.join(" ");
  }

  // what a vehicle without an order or recipe is doing, by its phase (docs/api.md, VehicleOut)
  const IDLE_JOBS = {
    to_charger: "to charger (must charge)",
    charging: "charging (must)",
    to_top_up: "to charger (topping up)",
    topping_up: "topping up",
    to_parking: "to parking",
    parked: "parked",
  };

  function updateVehicleRow(view, v, kind) {
    const c = view.cells;
    setText(c.state, v.state);
    setAttr(c.state, "class", `state look-${kind}`);
    setTitle(c.state, v.waiting_for !== null && v.waiting_for !== undefined ? `waits for agv${v.waiting_for}` : "");
    setText(c.node, dash(v.node));
    setTitle(c.node, nodeName(v.node));
    setText(c.target, dash(v.target));
    setTitle(c.target, nodeName(v.target));
    let job = v.order ? v.order : "";
    if (v.next_order) job += ` / ${v.next_order}`;
    if (!job && v.recipe) job = `recipe ${v.recipe}`;
    if (!job) job = IDLE_JOBS[v.phase] || "";
    setText(c.order, job || "–");
    setTitle(c.order, job);
    setText(c.battery, v.battery === null || v.battery === undefined ? "–" : `${v.battery} %`);
    setAttr(c.battery, "class", v.battery !== null && v.battery < 20 ? "battery low" : "battery");
    const flags = [];
    if (v.held) flags.push("held");
    if (v.suspect) flags.push("suspect");
    if (v.load && v.load !== v.order) flags.push(`load ${v.load} left on board`);
    if (v.stale) flags.push("stale");
    if (v.fault) flags.push("fault");
    if (!v.online) flags.push("offline");
    setText(c.flags, flags.join(" "));
    setTitle(c.flags, v.suspect_reason || "");
  }

  // ----- orders ------------------------------------------------------------------------------
  const orders = {
    rows: new Map(), // id -> { tr, cells, seq, state }; seq: the order's position in the book
    loading: false,
    again: false,
    pending: [], // changes that arrived while the list was being read
    available: null,
  };

  function setOrdersAvailable(yes) {
    if (orders.available === yes) return;
    orders.available = yes;
    $("#orders-off").hidden = yes;
    $("#layout").classList.toggle("no-orders", !yes);
  }

  function fillStationSelects(p) {
    for (const sel of [$("#order-get"), $("#order-put")]) {
      sel.replaceChildren();
      for (const s of p.stations) {
        const n = plant.nodes.get(s);
        const option = html("option", "", n && n.name ? n.name : String(s));
        option.value = String(s);
        sel.appendChild(option);
      }
    }
    if (p.stations.length > 1) $("#order-put").selectedIndex = 1;
  }

  function newOrderId() {
    $("#order-id").value = `web-${Date.now()}`;
  }

  async function reloadOrders() {
    if (orders.loading) {
      orders.again = true;
      return;
    }
    orders.loading = true;
    orders.pending = [];
    try {
      // the newest orders: those added from ORDER_PAGE positions before the next one on,
      // then the ORDER_PAGE positions before those, ... until ORDER_ROWS are found
      // (positions never change; orders that have left the book leave gaps), at most
      // ORDER_PAGES requests back
      const head = await api("GET", "/orders?offset=0&limit=1");
      let newest = [];
      let end = head.added;
      for (let n = 0; n < ORDER_PAGES && end > 0 && newest.length < ORDER_ROWS; n++) {
        const offset = Math.max(0, end - ORDER_PAGE);
        const page = await api("GET", `/orders?offset=${offset}&limit=${end - offset}`);
        newest = page.orders.filter((o) => o.position < end).concat(newest);
        end = offset;
      }
      const tbody = $("#orders tbody");
      orders.rows.clear();
      const fragment = document.createDocumentFragment();
      for (const o of newest.slice(-ORDER_ROWS).reverse()) {
        const row = orderRow(o, o.position);
        fragment.appendChild(row.tr);
      }
      tbody.replaceChildren(fragment);
      const pending = orders.pending;
      orders.pending = [];
      for (const o of pending) upsertOrder(o);
    } catch (exc) {
      message(`orders: ${exc.message}`);
    } finally {
      orders.loading = false;
      if (orders.again) {
        orders.again = false;
        reloadOrders();
      }
    }
  }

  function orderRow(o, seq) {
    const tr = html("tr");
    tr.dataset.id = o.id;
    const cells = {};
    for (const name of ["id", "get", "put", "priority", "state", "vehicle"]) cells[name] = tr.appendChild(html("td", name));
    const row = { tr, cells, seq, state: null };
    orders.rows.set(o.id, row);
    fillOrderRow(row, o);
    return row;
  }

  function fillOrderRow(row, o) {
    const c = row.cells;
    setText(c.id, o.id);
    setTitle(c.id, o.id);
    setText(c.get, String(o.get));
    setTitle(c.get, nodeName(o.get));
    setText(c.put, String(o.put));
    setTitle(c.put, nodeName(o.put));
    setText(c.priority, String(o.priority));
    setText(c.state, o.state);
    setAttr(c.state, "class", `state order-${o.state.toLowerCase()}`);
    setTitle(c.state, o.reason || "");
    const assigned = o.assigned !== null && o.assigned !== undefined;
    const only = o.vehicle !== null && o.vehicle !== undefined ? ` (only agv${o.vehicle} may take it)` : "";
    setText(c.vehicle, assigned ? String(o.assigned) : "");
    setTitle(c.vehicle, (assigned ? `agv${o.assigned}` : "not assigned") + only);
    row.state = o.state;
  }

  function upsertOrder(o) {
    const seq = o.position;
    let row = orders.rows.get(o.id);
    if (row && row.seq !== seq) { // an id used again once its old order had left the book
      row.tr.remove();
      orders.rows.delete(o.id);
      row = undefined;
    }
    if (row) {
      // a change that raced the list's reading must not undo a final state
      if (!(FINAL.has(row.state) && !FINAL.has(o.state))) fillOrderRow(row, o);
      return;
    }
    const tbody = $("#orders tbody");
    const last = tbody.lastElementChild;
    if (orders.rows.size >= ORDER_ROWS && last && orders.rows.get(last.dataset.id).seq > seq) return; // older than every row shown
    const fresh = orderRow(o, seq);
    let before = null;
    for (const tr of tbody.children) { // newest first; a new order goes on top at once
      if (orders.rows.get(tr.dataset.id).seq < seq) {
        before = tr;
        break;
      }
    }
    tbody.insertBefore(fresh.tr, before);
    while (orders.rows.size > ORDER_ROWS) {
      const old = tbody.lastElementChild;
      orders.rows.delete(old.dataset.id);
      old.remove();
    }
  }

  function updateOrderCounts(counts) {
    const box = $("#order-counts");
    const states = [...ORDER_STATES, ...Object.keys(counts).filter((s) => !ORDER_STATES.includes(s))];
    for (const state of states) {
      if (!(state in counts)) continue;
      let item = box._items?.[state];
      if (!item) {
        box._items = box._items || {};
        item = html("span", `count order-${state.toLowerCase()}`);
        item.dataset.state = state;
        item.appendChild(html("span", "count-name", state.replace("_", " ").toLowerCase()));
        item._value = item.appendChild(html("b", "count-value"));
        box.appendChild(item);
        box._items[state] = item;
      }
      setText(item._value, String(counts[state]));
    }
  }

  async function submitOrder(event) {
    event.preventDefault();
    const out = $("#order-message");
    const id = $("#order-id").value.trim();
    const get = Number($("#order-get").value), put = Number($("#order-put").value);
    const priority = Number($("#order-priority").value || "0");
    const say = (text, ok) => {
      out.textContent = text;
      out.classList.toggle("ok", ok);
      out.classList.toggle("error", !ok);
    };
    if (!id) return say("the order needs an id", false);
    if ($("#order-get").value === "" || $("#order-put").value === "") return say("the plant has no stations", false);
    if (!Number.isInteger(priority)) return say("the priority must be a whole number", false);
    const button = $("#order-submit");
    button.disabled = true;
    try {
      const added = await api("POST", "/orders", { id, get, put, priority });
      upsertOrder(added);
      say(`added ${added.id}`, true);
      newOrderId();
    } catch (exc) {
      say(exc.message, false);
      if (exc.status === 409 && /no vehicle/i.test(exc.message)) setOrdersAvailable(false);
      const field = { id: "#order-id", get: "#order-get", put: "#order-put", priority: "#order-priority" }[exc.field];
      if (field) $(field).focus();
    } finally {
      button.disabled = false;
    }
  }

  // ----- statistics --------------------------------------------------------------------------
  // Fixed items first, in this order; the fleet's counters follow as they appear.
  const STAT_ITEMS = [
    ["state", "run state"], ["cycles", "cycles"], ["sim_time", "sim time"], ["cycle_time", "cycle time"],
    ["exec_p50", "scan exec p50"], ["exec_p99", "scan exec p99"], ["exec_mean", "scan exec mean"],
    ["exec_max", "scan exec max"], ["lateness_p99", "lateness p99"], ["overruns", "overruns"],
  ];
  const statItems = new Map();

  function stat(key, label, value) {
    let dd = statItems.get(key);
    if (!dd) {
      const item = html("div", "kv-item");
      item.dataset.key = key;
      item.appendChild(html("dt", "", label));
      dd = item.appendChild(html("dd", "", "–"));
      $("#stats dl").appendChild(item);
      statItems.set(key, dd);
    }
    if (value !== undefined) setText(dd, value); // undefined: this source lacks it, keep the last
  }

  const num = (x) => (typeof x === "number" ? x : undefined);
  const inMs = (us) => (typeof us === "number" ? `${(us / 1000).toFixed(2)} ms` : undefined);

  // Both the GET answer and a stream snapshot. A snapshot may carry less (no percentiles,
  // no cycle time, its scan times at the top level rather than under "scan"), so whatever it
  // lacks keeps the value last read from GET /stats.
  function updateStats(s) {
    const scan = s.scan || {};
    const exec = scan.exec_us || s.exec_us || {};
    const late = scan.lateness_us || s.lateness_us || {};
    for (const [key, label] of STAT_ITEMS) stat(key, label, undefined);
    stat("state", "", s.state === undefined ? undefined : String(s.state));
    stat("cycles", "", num(s.cycles) === undefined ? undefined : String(s.cycles));
    stat("sim_time", "", num(s.sim_time_s) === undefined ? undefined : `${s.sim_time_s.toFixed(2)} s`);
    stat("cycle_time", "", num(s.cycle_time_s) === undefined ? undefined : `${(s.cycle_time_s * 1000).toFixed(0)} ms`);
    stat("exec_p50", "", inMs(exec.p50));
    stat("exec_p99", "", inMs(exec.p99));
    stat("exec_mean", "", inMs(exec.mean));
    stat("exec_max", "", inMs(exec.max));
    stat("lateness_p99", "", inMs(late.p99));
    const overruns = num(s.overruns) ?? num(scan.overruns);
    stat("overruns", "", overruns === undefined ? undefined : String(overruns));
    if (s.fault_reason) stat("fault_reason", "fault", String(s.fault_reason));
    for (const [key, value] of Object.entries(s.fleet || {})) {
      if (typeof value === "number") stat(`fleet.${key}`, key.replace(/_/g, " "), String(value));
    }
    updateHeader(s);
  }

  async function refreshStats() {
    try {
      updateStats(await api("GET", "/stats"));
    } catch (exc) {
      // the stream's own indicator shows a lost controller; no message every five seconds
    }
  }

  function updateHeader(s) {
    const state = $("#run-state");
    if (s.state !== undefined) {
      setText(state, String(s.state));
      setAttr(state, "class", `run-state run-${String(s.state).toLowerCase()}`);
    }
    if (typeof s.sim_time_s === "number") setText($("#sim-time"), `${s.sim_time_s.toFixed(1)} s`);
  }

  // ----- the event log -----------------------------------------------------------------------
  const events = { last: 0, wanted: 0, busy: false, pauseUntil: 0 };

  async function fetchEvents(upTo) {
    events.wanted = Math.max(events.wanted, upTo);
    if (events.busy || events.wanted <= events.last || Date.now() < events.pauseUntil) return;
    events.busy = true;
    let again = false;
    try {
      const after = Math.max(events.last, events.wanted - EVENT_ROWS);
      const page = await api("GET", `/events?after=${after}&limit=${EVENT_ROWS}`);
      const list = $("#events");
      for (const e of page.events) {
        if (e.seq <= events.last) continue;
        const li = html("li");
        li.dataset.seq = String(e.seq);
        li.append(
          html("span", "time", e.time_s.toFixed(2)), " ",
          html("span", "kind", e.kind), " ",
        );
        if (e.vehicle !== null && e.vehicle !== undefined) li.append(html("span", "who", `agv${e.vehicle}`), " ");
        li.append(html("span", "text", e.text));
        list.insertBefore(li, list.firstChild);
        events.last = e.seq;
      }
      // the log keeps only its newest events: what it dropped is not asked for again
      if (!page.events.length) events.last = Math.max(events.last, Math.min(page.last, events.wanted));
      events.wanted = Math.max(events.wanted, page.last);
      while (list.children.length > EVENT_ROWS) list.lastElementChild.remove();
      again = events.wanted > events.last;
    } catch (exc) {
      events.pauseUntil = Date.now() + RETRY_MS; // not ten failing requests a second
      message(`events: ${exc.message}`);
    } finally {
      events.busy = false;
      if (again) fetchEvents(0);
    }
  }

  // ----- the watch table ---------------------------------------------------------------------
  const watch = new Map(); // name -> { tr, cells, tag, input }
  let watchTimer = null;
  let tagNames = null; // every tag's name, once read: a typo is answered without a request

  async function addWatch(event) {
    event.preventDefault();
    const input = $("#watch-name");
    const name = input.value.trim();
    if (!name) return;
    if (watch.has(name)) {
      message(`${name} is watched already`);
      return;
    }
    if (watch.size >= MAX_WATCH) {
      message(`at most ${MAX_WATCH} tags can be watched at once`);
      return;
    }
    if (tagNames && !tagNames.has(name)) {
      message(`there is no tag '${name}'`);
      return;
    }
    try {
      const [tag] = await api("GET", `/tags/values?names=${encodeURIComponent(name)}`);
      if (!watch.has(tag.name)) watchRow(tag);
      fillWatchRow(tag);
      input.value = "";
      scheduleWatch();
    } catch (exc) {
      message(exc.message);
    }
  }

  function watchRow(tag) {
    const tr = html("tr");
    tr.dataset.name = tag.name;
    const cells = {};
    for (const name of ["name", "address", "value", "forced"]) cells[name] = tr.appendChild(html("td", name));
    setText(cells.name, tag.name);
    setTitle(cells.name, `${tag.comment || ""} (${tag.type})`.trim());
    setText(cells.address, tag.address);
    const controls = tr.appendChild(html("td", "controls"));
    const input = controls.appendChild(html("input", "force-value"));
    input.type = "text";
    input.size = 5;
    input.placeholder = tag.type === "BOOL" ? "1 / 0" : "value";
    input.setAttribute("aria-label", `value for ${tag.name}`);
    const buttons = {};
    for (const [cls, text] of [["write", "write"], ["force", "force"], ["unforce", "unforce"]]) {
      const b = controls.appendChild(html("button", cls, text));
      b.type = "button";
      buttons[cls] = b;
      if (!tag.writable) {
        b.disabled = true;
        b.title = `${tag.name} is read-only`;
      }
    }
    if (!tag.writable) {
      input.disabled = true;
      input.title = `${tag.name} is read-only`;
    }
    buttons.write.addEventListener("click", () => changeTag(tag.name, "write"));
    buttons.force.addEventListener("click", () => changeTag(tag.name, "force"));
    buttons.unforce.addEventListener("click", () => changeTag(tag.name, "unforce"));
    const remove = controls.appendChild(html("button", "remove", "×"));
    remove.type = "button";
    remove.title = `stop watching ${tag.name}`;
    remove.addEventListener("click", () => {
      watch.delete(tag.name);
      tr.remove();
    });
    input.addEventListener("keydown", (e) => {
      if (e.key === "Enter") changeTag(tag.name, "write");
    });
    $("#watch tbody").appendChild(tr);
    watch.set(tag.name, { tr, cells, tag, input });
  }

  function fillWatchRow(tag) {
    const row = watch.get(tag.name);
    if (!row) return;
    row.tag = tag;
    setText(row.cells.value, formatValue(tag.value));
    setText(row.cells.forced, tag.forced ? "forced" : "");
    setTitle(row.cells.forced, tag.forced ? `forced to ${formatValue(tag.forced_value)}` : "");
    row.tr.classList.toggle("is-forced", Boolean(tag.forced));
  }

  function parseValue(text, type) {
    const s = text.trim().toLowerCase();
    if (type === "BOOL") {
      if (s === "1" || s === "true") return true;
      if (s === "0" || s === "false") return false;
      throw new Error(`a BOOL takes 1, 0, true or false, not "${text}"`);
    }
    if (s === "") throw new Error("enter a value first");
    const n = Number(s);
    if (!Number.isFinite(n)) throw new Error(`"${text}" is not a number`);
    return n;
  }

  async function changeTag(name, action) {
    const row = watch.get(name);
    if (!row) return;
    const path = `/tags/${encodeURIComponent(name)}`;
    try {
      let tag;
      if (action === "unforce") {
        tag = await api("DELETE", `${path}/force`);
      } else {
        const value = parseValue(row.input.value, row.tag.type);
        tag = await api("PUT", action === "force" ? `${path}/force` : path, { value });
      }
      fillWatchRow(tag);
      const done = { write: `${name} written`, force: `${name} forced to ${formatValue(tag.forced_value)}`, unforce: `${name} unforced` };
      message(done[action], true);
    } catch (exc) {
      message(`${name}: ${exc.message}`);
    }
  }

  function scheduleWatch() {
    if (watchTimer === null && watch.size) watchTimer = setTimeout(pollWatch, WATCH_PERIOD_MS);
  }

  async function pollWatch() {
    try {
      if (!watch.size) return;
      const names = [...watch.keys()];
      const values = await api("GET", `/tags/values?names=${encodeURIComponent(names.join(","))}`);
      for (const tag of values) fillWatchRow(tag);
    } catch (exc) {
      message(`watch table: ${exc.message}`);
    } finally {
      watchTimer = null; // after the answer, so a slow controller is never asked twice at once
      scheduleWatch();
    }
  }

  async function loadTagNames() {
    try {
      const tags = await api("GET", "/tags");
      const fragment = document.createDocumentFragment();
      for (const t of tags) {
        const option = document.createElement("option");
        option.value = t.name;
        fragment.appendChild(option);
      }
      $("#tag-names").replaceChildren(fragment);
      tagNames = new Set(tags.map((t) => t.name));
    } catch (exc) {
      message(`tag names: ${exc.message}`);
    }
  }

  // ----- the live stream -----------------------------------------------------------------------
  // Snapshots may come faster than the screen repaints (a hidden tab repaints never): the
  // vehicles they name are gathered, newest state first, and drawn at the next frame. Orders
  // and events are taken as they arrive (each snapshot names only what changed since the one
  // before). A snapshot marked "full" names every vehicle (the first, or one after a miss).
  let latest = null;
  let streamed = false;
  let pendingVehicles = new Map();
  let frameAsked = false;
  let source = null;
  let opened = false;

  function onSnapshot(event) {
    let s;
    try {
      s = JSON.parse(event.data);
    } catch (exc) {
      return;
    }
    if (s.orders) {
      setOrdersAvailable(true);
      updateOrderCounts(s.orders.counts || {});
      if (s.orders.resync) reloadOrders();
      else if (orders.loading) orders.pending.push(...s.orders.changed);
      else for (const o of s.orders.changed) upsertOrder(o);
    } else {
      setOrdersAvailable(false);
    }
    if (typeof s.events === "number" && s.events > events.last) fetchEvents(s.events);
    for (const v of s.vehicles || []) pendingVehicles.set(v.id, v);
    streamed = true;
    latest = s;
    if (!frameAsked) {
      frameAsked = true;
      requestAnimationFrame(render);
    }
  }

  function render() {
    frameAsked = false;
    const s = latest;
    latest = null;
    if (!s) return;
    const changed = [...pendingVehicles.values()];
    pendingVehicles = new Map();
    updateVehicles(changed);
    setBlockades(s.blockades || []);
    updateStats(s);
  }

  function setConnection(live) {
    const c = $("#connection");
    setText(c, live ? "live" : "disconnected");
    setAttr(c, "class", live ? "connection up" : "connection down");
  }

  function connect() {
    source = new EventSource(`${API}/stream`);
    source.addEventListener("open", () => {
      setConnection(true);
      opened = true;
      // whatever changed while no snapshot arrived is only in the book itself
      reloadOrders();
    });
    source.addEventListener("snapshot", onSnapshot);
    source.addEventListener("error", () => {
      setConnection(source.readyState === EventSource.OPEN);
      // CLOSED: the browser gave up (the run ended, or every stream place is taken)
      if (source.readyState === EventSource.CLOSED) {
        source.close();
        setTimeout(connect, RETRY_MS);
      }
    });
  }

  // ----- start ---------------------------------------------------------------------------------
  async function loadPlant() {
    for (;;) {
      try {
        drawPlant(await api("GET", "/plant"));
        return;
      } catch (exc) {
        message(`plant: ${exc.message}; retrying`);
        await new Promise((resolve) => setTimeout(resolve, RETRY_MS));
      }
    }
  }

  async function start() {
    const tokenInput = $("#token");
    tokenInput.value = sessionStorage.getItem(TOKEN_KEY) || "";
    tokenInput.addEventListener("input", () => sessionStorage.setItem(TOKEN_KEY, tokenInput.value));
    // the field sits in a form only so the browser treats it as a password; Enter must not reload
    $("#token-form").addEventListener("submit", (e) => e.preventDefault());
    $("#order-form").addEventListener("submit", submitOrder);
    $("#watch-form").addEventListener("submit", addWatch);
    // one listener for every segment: thousands of lines need no handler each
    $("#layer-segments").addEventListener("click", (e) => {
      const line = e.target.closest("line.segment");
      if (line) toggleSegment(line);
    });
    newOrderId();
    setConnection(false);

    await loadPlant();
    message("");
    applyScale();
    new ResizeObserver(applyScale).observe($("#plant"));
    connect();
    loadTagNames();
    try {
      const [list, stats, log] = await Promise.all([api("GET", "/vehicles"), api("GET", "/stats"), api("GET", "/events?after=0&limit=1")]);
      if (!streamed) updateVehicles(list); // the stream's first snapshot has them all, and newer
      updateStats(stats);
      fetchEvents(log.last);
    } catch (exc) {
      message(exc.message);
    }
    setInterval(refreshStats, STATS_PERIOD_MS);
    // without a stream (every place taken) the list is still read once
    setTimeout(() => {
      if (!opened) reloadOrders();
    }, RETRY_MS);
  }

  start();
})();
