// @ts-check
// The roof, live: the robot's rail drawn in SVG from its agent's geometry (/rails/<name>.json),
// the thesis grid cells along it, the fixed nodes' places, and the robot placed by track_m.
//
// Where the robot is comes from the page: the run page's data ("run:data" events from run.js:
// the last point of its series), the robot console's status ("robot:status" from robot.js).
// Every position is also written out in words (#roof-text), the map's text alternative.
//
// On the run page the grid cells are coloured by a measurement's mean in each (the summaries
// measurements.js hands on as "measurements:data"): a heatmap whose numbers are the table of
// that column per grid cell in the measurements section.
(function () {
  "use strict";
  const root = document.getElementById("roof");
  if (!root) return;
  const svg = document.getElementById("roof-map");
  const text = document.getElementById("roof-text");
  const NS = "http://www.w3.org/2000/svg";

  let rail = null; // {length_m, xyAt(track_m) -> [x, y], tangentAt(track_m) -> [dx, dy], cellAt(track_m)}
  let pending = null; // a position that came before the map
  let robot = null; // the SVG group of the robot
  let cells = []; // the drawing's grid cells: {id, from_m, to_m}
  let unit = 1; // a stroke's width on this roof
  let heatLayer = null; // the SVG group the heatmap is drawn in, under the rail
  /** @type {{key: string, label: string, unit: string, byCell: any[]}[]} */
  let heatChoices = [];

  function el(name, attrs, parent) {
    const node = document.createElementNS(NS, name);
    for (const [key, value] of Object.entries(attrs || {})) node.setAttribute(key, String(value));
    if (parent) parent.appendChild(node);
    return node;
  }
  const wrap = (t, length) => ((t % length) + length) % length;

  // A closed polyline, walked clockwise; track_m counts from the origin.
  function polylineRail(drawing) {
    const pts = drawing.points.map((p) => [p.x_m, -p.y_m]); // SVG's y grows downwards
    const length = drawing.length_m;
    const first = drawing.points[0].track_m;
    const starts = [0];
    const edges = [];
    for (let k = 0; k < pts.length; k++) {
      const a = pts[k], b = pts[(k + 1) % pts.length];
      edges.push(Math.hypot(b[0] - a[0], b[1] - a[1]));
      if (k + 1 < pts.length) starts.push(starts[k] + edges[k]);
    }
    function edgeAt(track) {
      const raw = wrap(track - first, length);
      let k = 0;
      while (k + 1 < starts.length && starts[k + 1] <= raw) k++;
      return [k, Math.min(1, (raw - starts[k]) / (edges[k] || 1))];
    }
    return {
      length_m: length,
      outline: pts,
      xyAt(track) {
        const [k, f] = edgeAt(track);
        const a = pts[k], b = pts[(k + 1) % pts.length];
        return [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])];
      },
      tangentAt(track) {
        const [k] = edgeAt(track);
        const a = pts[k], b = pts[(k + 1) % pts.length];
        const n = Math.hypot(b[0] - a[0], b[1] - a[1]) || 1;
        return [(b[0] - a[0]) / n, (b[1] - a[1]) / n];
      },
    };
  }

  // Without a geometry (the kinematic model): a circle of the rail's length, origin at north.
  function circleRail(length) {
    const r = length / (2 * Math.PI);
    const angle = (track) => (wrap(track, length) / length) * 2 * Math.PI;
    const outline = [];
    for (let k = 0; k < 72; k++) outline.push([r * Math.sin((k / 72) * 2 * Math.PI), -r * Math.cos((k / 72) * 2 * Math.PI)]);
    return {
      length_m: length,
      outline,
      xyAt: (track) => [r * Math.sin(angle(track)), -r * Math.cos(angle(track))],
      tangentAt: (track) => [Math.cos(angle(track)), Math.sin(angle(track))],
    };
  }

  function cellFinder(cells) {
    return (track) => {
      for (const cell of cells) if (track >= cell.from_m && track < cell.to_m) return cell.id;
      return null;
    };
  }

  function draw(drawing) {
    rail = drawing.geometry ? polylineRail(drawing) : circleRail(drawing.length_m);
    cells = drawing.geometry ? drawing.cells : [];
    rail.cellAt = cellFinder(cells);
    const nodes = drawing.geometry ? drawing.nodes : [];
    const all = rail.outline.concat(nodes.map((n) => [n.x_m, -n.y_m]), [[0, 0]]);
    const xs = all.map((p) => p[0]), ys = all.map((p) => p[1]);
    const span = Math.max(Math.max(...xs) - Math.min(...xs), Math.max(...ys) - Math.min(...ys), 1);
    const margin = span * 0.14;
    const minX = Math.min(...xs) - margin, minY = Math.min(...ys) - margin;
    const width = Math.max(...xs) - Math.min(...xs) + 2 * margin;
    const height = Math.max(...ys) - Math.min(...ys) + 2 * margin;
    svg.setAttribute("viewBox", `${minX} ${minY} ${width} ${height}`);
    unit = span / 100; // strokes and labels scale with the roof
    // Keep <title> and <desc>; redraw the rest.
    for (const child of Array.from(svg.children)) if (child.tagName !== "title" && child.tagName !== "desc") child.remove();

    heatLayer = el("g", { class: "roof-heat", "aria-hidden": "true" }, svg);
    const map = el("g", { class: "roof-drawing", "aria-hidden": "true" }, svg);
    el("polygon", { class: "roof-rail", points: rail.outline.map((p) => p.join(",")).join(" "), "stroke-width": 1.6 * unit }, map);
    // Grid cells: a tick across the rail where each starts, its name outside the rail.
    for (const cell of cells) {
      const [x, y] = rail.xyAt(cell.from_m);
      const r = Math.hypot(x, y) || 1;
      el("line", { class: "roof-cell-tick", x1: x * (1 - 3 * unit / r), y1: y * (1 - 3 * unit / r), x2: x * (1 + 3 * unit / r), y2: y * (1 + 3 * unit / r), "stroke-width": 0.5 * unit }, map);
      const [mx, my] = rail.xyAt((cell.from_m + cell.to_m) / 2);
      const mr = Math.hypot(mx, my) || 1;
      const label = el("text", { class: "roof-cell", x: mx * (1 + 7 * unit / mr), y: my * (1 + 7 * unit / mr), "font-size": 4 * unit, "text-anchor": "middle", "dominant-baseline": "middle" }, map);
      label.textContent = cell.id;
    }
    const [ox, oy] = rail.xyAt(0);
    el("circle", { class: "roof-origin", cx: ox, cy: oy, r: 1.2 * unit }, map);
    const originLabel = el("text", { class: "roof-label", x: ox + 2 * unit, y: oy + 5 * unit, "font-size": 3.2 * unit }, map);
    originLabel.textContent = "0 m";
    for (const node of nodes) {
      const size = 3 * unit;
      el("rect", { class: "roof-node", x: node.x_m - size / 2, y: -node.y_m - size / 2, width: size, height: size }, map);
      const name = el("text", { class: "roof-label", x: node.x_m + size, y: -node.y_m + size / 3, "font-size": 3 * unit }, map);
      name.textContent = node.name;
    }
    const north = el("text", { class: "roof-north", x: minX + 3 * unit, y: minY + 6 * unit, "font-size": 5 * unit }, map);
    north.textContent = "N ↑";

    robot = el("g", { id: "roof-robot", class: "roof-robot", visibility: "hidden" }, svg);
    el("title", {}, robot);
    el("circle", { r: 2.6 * unit, "stroke-width": 0.6 * unit }, robot);
    el("path", { class: "roof-heading", d: `M ${6.5 * unit} 0 L ${2.6 * unit} ${-2.4 * unit} L ${2.6 * unit} ${2.4 * unit} Z` }, robot);
    root.dataset.ready = "1";
    text.textContent = drawing.geometry
      ? `The rail “${drawing.name}”, ${drawing.length_m.toFixed(1)} m around, ${cells.length ? new Set(cells.map((c) => c.id)).size + " grid cells" : "no grid"}${nodes.length ? ", " + nodes.length + " fixed node" + (nodes.length === 1 ? "" : "s") : ""}. Where the robot is appears here.`
      : `A rail ${drawing.length_m.toFixed(1)} m around (its base station has no geometry; drawn as a circle). Where the robot is appears here.`;
    if (pending) { const p = pending; pending = null; place(p); }
    heatDraw();
  }

  // Viridis (perceptually even, colour-blind safe): low values dark blue, high yellow.
  const VIRIDIS = [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]];
  function colourAt(f) {
    const x = Math.max(0, Math.min(1, f)) * (VIRIDIS.length - 1);
    const k = Math.min(VIRIDIS.length - 2, Math.floor(x));
    const a = VIRIDIS[k], b = VIRIDIS[k + 1], t = x - k;
    return `rgb(${a.map((v, i) => Math.round(v + t * (b[i] - v))).join(",")})`;
  }
  const heatSelect = /** @type {HTMLSelectElement | null} */ (document.getElementById("roof-heat-choice"));
  const heatBox = document.getElementById("roof-heat");
  const heatLegend = document.getElementById("roof-heat-legend");

  // The cells coloured by the chosen column's mean; each cell's stretch of rail is a thick
  // line under the rail's own.
  function heatDraw() {
    if (!heatLayer || !heatSelect || !heatLegend) return;
    heatLayer.textContent = "";
    const choice = heatChoices.find((c) => c.key === heatSelect.value);
    root.dataset.heat = "";
    if (!choice || !rail || !cells.length) { heatLegend.textContent = ""; return; }
    const means = new Map(choice.byCell.filter((row) => row.mean !== null).map((row) => [row.cell, row]));
    const values = Array.from(means.values(), (row) => row.mean);
    if (!values.length) { heatLegend.textContent = "No point of it fell in a grid cell."; return; }
    const low = Math.min(...values), high = Math.max(...values);
    const shown = [];
    for (const cell of cells) {
      const row = means.get(cell.id);
      if (!row) continue;
      const steps = 12, points = [];
      for (let k = 0; k <= steps; k++) points.push(rail.xyAt(cell.from_m + ((cell.to_m - cell.from_m) * k) / steps).join(","));
      const line = el("polyline", { class: "roof-heat-cell", "data-cell": cell.id, points: points.join(" "), stroke: colourAt(high > low ? (row.mean - low) / (high - low) : 0.5), "stroke-width": 5 * unit }, heatLayer);
      el("title", {}, line).textContent = `${cell.id}: mean ${row.mean.toFixed(2)} ${choice.unit} (${row.count} points)`;
      shown.push(cell.id);
    }
    root.dataset.heat = shown.join(" ");
    const gradient = VIRIDIS.map((c, i) => `rgb(${c.join(",")}) ${(i / (VIRIDIS.length - 1)) * 100}%`).join(", ");
    heatLegend.innerHTML = "";
    const lowText = document.createElement("span");
    lowText.textContent = `${low.toFixed(1)} ${choice.unit}`;
    const bar = document.createElement("span");
    bar.className = "roof-heat-bar";
    bar.setAttribute("aria-hidden", "true");
    bar.style.background = `linear-gradient(to right, ${gradient})`;
    const highText = document.createElement("span");
    highText.textContent = `${high.toFixed(1)} ${choice.unit}`;
    const note = document.createElement("span");
    note.textContent = ` · mean of ${choice.label} per grid cell (${shown.length} cells); the numbers are in its table below.`;
    heatLegend.append(lowText, bar, highText, note);
  }

  // The run page's measurements (measurements.js): one choice per series and value column
  // that has points in grid cells; the choice made is kept when the data is read again.
  document.addEventListener("measurements:data", (event) => {
    if (!heatSelect || !heatBox) return;
    const series = /** @type {any[]} */ ((/** @type {CustomEvent} */ (event)).detail || []);
    heatChoices = [];
    for (const one of series) {
      for (const [column, summary] of Object.entries(one.columns || {})) {
        if (!summary.by_cell || !summary.by_cell.length) continue;
        const label = Object.keys(one.columns).length > 1 ? `${one.name} · ${column}` : one.name;
        heatChoices.push({ key: `${one.name}/${column}`, label, unit: one.unit || "", byCell: summary.by_cell });
      }
    }
    const kept = heatSelect.value;
    heatSelect.textContent = "";
    for (const choice of heatChoices) {
      const option = document.createElement("option");
      option.value = choice.key;
      option.textContent = choice.label + (choice.unit ? ` (${choice.unit})` : "");
      heatSelect.appendChild(option);
    }
    if (heatChoices.some((c) => c.key === kept)) heatSelect.value = kept;
    heatBox.hidden = heatChoices.length === 0;
    heatDraw();
  });
  if (heatSelect) heatSelect.addEventListener("change", heatDraw);

  // position: {track_m, velocity_mps (signed, cw +) or speed with direction, direction, at}
  function place(position) {
    if (!rail) { pending = position; return; }
    if (position.track_m === null || position.track_m === undefined || !isFinite(position.track_m)) return;
    const track = wrap(Number(position.track_m), rail.length_m);
    const [x, y] = rail.xyAt(track);
    const speed = Math.abs(Number(position.velocity_mps) || 0);
    const ccw = position.direction ? position.direction === "ccw" : Number(position.velocity_mps) < 0;
    let [dx, dy] = rail.tangentAt(track);
    if (ccw) { dx = -dx; dy = -dy; }
    const angle = (Math.atan2(dy, dx) * 180) / Math.PI;
    robot.setAttribute("transform", `translate(${x} ${y}) rotate(${angle})`);
    robot.setAttribute("visibility", "visible");
    robot.classList.toggle("moving", speed > 0.005);
    const cell = rail.cellAt(track);
    const moving = speed > 0.005 ? `moving ${ccw ? "counter-clockwise" : "clockwise"} at ${speed.toFixed(2)} m/s` : "standing still";
    const words = `${position.label || "Robot"} at ${track.toFixed(1)} m along the rail${cell ? ", cell " + cell : ""}, ${moving}.`;
    robot.querySelector("title").textContent = words;
    root.dataset.trackM = track.toFixed(2);
    root.dataset.cell = cell || "";
    text.textContent = words;
  }

  // The run page: the newest point of the run's series (run.js dispatches each answer).
  document.addEventListener("run:data", (event) => {
    const series = (event.detail && event.detail.series) || {};
    const track = series.track_m, velocity = series.measured_mps;
    if (!track || !Array.isArray(track.y) || !track.y.length) return;
    const last = track.y.length - 1;
    const v = velocity && velocity.y && velocity.y.length ? velocity.y[velocity.y.length - 1] : 0;
    place({ track_m: track.y[last], velocity_mps: v, label: event.detail.live ? "Robot" : "At the run's last sample, the robot" });
  });
  // The robot console: the agent's status (robot.js dispatches each reading).
  document.addEventListener("robot:status", (event) => {
    const r = (event.detail && event.detail.robot) || {};
    place({ track_m: r.track_m, velocity_mps: r.velocity_mps, direction: r.direction });
  });

  const { api, failure } = window.AmazingApi;
  api("GET", root.dataset.railUrl)
    .then((result) => {
      if (!result.ok || result.data === null) throw new Error(failure(result));
      const data = result.data;
      if (!data.available) throw new Error(data.detail || "not available");
      draw(data);
    })
    .catch((error) => {
      root.dataset.ready = "0";
      text.textContent = "The map of the roof is not available: " + error.message;
    });
})();
