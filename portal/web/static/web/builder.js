// @ts-check
// The experiment builder: the chosen robot's limits checked while typing, a preview of the
// velocity profile with the ramps the robot really drives, the distance, laps and end position
// on its rail; segments reordered (drag, or Alt+↑/↓ and the arrow buttons), cloned; the program
// imported and exported as the YAML/JSON files the `amazing` command reads.
// The form still posts its rows as before; the server checks everything again on save.
(function () {
  "use strict";
  const form = document.getElementById("experiment-form");
  const side = document.getElementById("builder");
  const body = /** @type {HTMLTableSectionElement | null} */ (document.querySelector("#segments tbody"));
  if (!form || !side || !body) return;
  const data = JSON.parse(document.getElementById("builder-data").textContent);
  const robots = new Map(data.robots.map((r) => [r.name, r]));
  const robotSelect = /** @type {HTMLSelectElement} */ (document.getElementById("builder-robot"));
  const railInput = /** @type {HTMLInputElement} */ (document.getElementById("builder-rail"));
  const problemsList = document.getElementById("builder-problems");
  const titleInput = /** @type {HTMLInputElement} */ (form.querySelector("[name=title]"));
  const STOPPED = 1e-9;
  side.hidden = false;

  // The fields a person has left (or that a file filled): only their errors are shown, so
  // that nothing is called wrong while it is still being typed.
  const touched = new WeakSet();
  const fmt = (x, digits) => (Math.round(x * 10 ** digits) / 10 ** digits).toFixed(digits);
  const robot = () => robots.get(robotSelect.value) || null;

  // --- Rows --------------------------------------------------------------------------------
  function rows() { return Array.from(body.rows); }
  function readRow(row) {
    const velocity = row.querySelector("[name=velocity_mps]").value.trim();
    const duration = row.querySelector("[name=duration_s]").value.trim();
    return {
      velocity: velocity === "" ? null : Number(velocity),
      direction: row.querySelector("[name=direction]").value,
      duration: duration === "" ? null : Number(duration),
      empty: velocity === "" && duration === "",
    };
  }
  function writeRow(row, segment) {
    row.querySelector("[name=velocity_mps]").value = segment.velocity_mps;
    row.querySelector("[name=direction]").value = segment.direction;
    row.querySelector("[name=duration_s]").value = segment.duration_s;
    // Filled from a file or a copy: checked at once, as if typed and left.
    row.querySelectorAll("input[name]").forEach((input) => touched.add(input));
  }
  function button(cls, label, text) {
    const b = document.createElement("button");
    b.type = "button";
    b.className = `outline secondary ${cls}`;
    b.setAttribute("aria-label", label);
    b.title = label;
    b.textContent = text;
    return b;
  }
  function decorate() {
    rows().forEach((row, i) => {
      row.querySelector(".index").textContent = String(i);
      row.draggable = true;
      const actions = row.querySelector(".row-actions");
      if (actions && !actions.querySelector(".move-up")) {
        actions.prepend(
          button("move-up", "move segment up", "↑"),
          button("move-down", "move segment down", "↓"),
          button("clone-row", "copy segment", "copy"),
        );
      }
      for (const input of row.querySelectorAll("input[name]")) {
        const cell = input.parentElement;
        if (!cell.querySelector(".field-error")) {
          const error = cell.appendChild(document.createElement("small"));
          error.className = "field-error error";
          error.dataset.for = input.getAttribute("name");
        }
      }
      let note = row.querySelector(".segment-note");
      if (!note) {
        note = document.createElement("small");
        note.className = "segment-note";
        row.querySelector("[name=duration_s]").parentElement.appendChild(note);
      }
    });
  }
  function move(row, by) {
    const list = rows();
    const to = list.indexOf(row) + by;
    if (to < 0 || to >= list.length) return;
    if (by < 0) body.insertBefore(row, list[to]);
    else body.insertBefore(row, list[to].nextSibling);
  }
  body.addEventListener("click", (/** @type {MouseEvent & {target: Element}} */ event) => {
    const row = event.target.closest("tr");
    if (!row) return;
    if (event.target.closest(".move-up")) { move(row, -1); event.target.closest("button").focus(); }
    else if (event.target.closest(".move-down")) { move(row, 1); event.target.closest("button").focus(); }
    else if (event.target.closest(".clone-row")) {
      const copy = /** @type {HTMLTableRowElement} */ (row.cloneNode(true));
      // cloneNode copies attributes, not what was typed or chosen since.
      writeRow(copy, {
        velocity_mps: /** @type {HTMLInputElement} */ (row.querySelector("[name=velocity_mps]")).value,
        direction: /** @type {HTMLSelectElement} */ (row.querySelector("[name=direction]")).value,
        duration_s: /** @type {HTMLInputElement} */ (row.querySelector("[name=duration_s]")).value,
      });
      row.after(copy);
      copy.querySelector("input").focus();
    }
  });
  body.addEventListener("keydown", (/** @type {KeyboardEvent & {target: Element}} */ event) => {
    if (!event.altKey || (event.key !== "ArrowUp" && event.key !== "ArrowDown")) return;
    const row = event.target.closest("tr");
    if (!row) return;
    event.preventDefault();
    const focused = /** @type {HTMLElement | null} */ (document.activeElement);
    move(row, event.key === "ArrowUp" ? -1 : 1);
    if (focused) focused.focus();
  });
  // Drag a row by any part of it that is not a field.
  let dragged = null;
  body.addEventListener("dragstart", (/** @type {DragEvent & {target: Element}} */ event) => {
    const row = event.target.closest && event.target.closest("tr");
    if (!row || event.target.matches("input, select")) return;
    dragged = row;
    row.classList.add("dragging");
    event.dataTransfer.effectAllowed = "move";
    event.dataTransfer.setData("text/plain", row.querySelector(".index").textContent);
  });
  body.addEventListener("dragover", (/** @type {DragEvent & {target: Element}} */ event) => {
    if (!dragged) return;
    event.preventDefault();
    const over = event.target.closest("tr");
    if (!over || over === dragged) return;
    const box = over.getBoundingClientRect();
    if (event.clientY < box.top + box.height / 2) body.insertBefore(dragged, over);
    else body.insertBefore(dragged, over.nextSibling);
  });
  body.addEventListener("drop", (event) => { if (dragged) event.preventDefault(); });
  body.addEventListener("dragend", () => {
    if (dragged) dragged.classList.remove("dragging");
    dragged = null;
    update();
  });

  // --- The profile the robot drives ----------------------------------------------------------
  // The base station slews the signed velocity (cw positive) towards each segment's at the
  // robot's acceleration, through zero when the direction changes, and to zero at the end.
  function profile(segments, accel) {
    const points = [{ t: 0, v: 0 }];
    const notes = [];
    let t = 0;
    let v = 0;
    const rampTo = (target, within) => {
      const need = Math.abs(target - v) / accel;
      if (need <= within) {
        if (need > 0) points.push({ t: t + need, v: target });
        t += within;
        v = target;
        points.push({ t, v });
        return { reached: true, need };
      }
      v += Math.sign(target - v) * accel * within;
      t += within;
      points.push({ t, v });
      return { reached: false, need };
    };
    segments.forEach((s) => {
      const from = v;
      const target = (s.direction === "ccw" ? -1 : 1) * s.velocity;
      const ramp = rampTo(target, s.duration);
      notes.push({ from, reached: ramp.reached, need: ramp.need, top: Math.abs(v) });
    });
    const stop = Math.abs(v) / accel;
    if (stop > STOPPED) rampTo(0, stop);
    return { points, notes, end: t };
  }
  function integrate(points) {
    let distance = 0;
    let displacement = 0;
    for (let i = 1; i < points.length; i++) {
      const a = points[i - 1];
      const b = points[i];
      const dt = b.t - a.t;
      displacement += ((a.v + b.v) / 2) * dt;
      if (a.v * b.v >= 0) distance += (Math.abs(a.v + b.v) / 2) * dt;
      else {
        // Through zero: two triangles.
        const tz = dt * Math.abs(a.v) / (Math.abs(a.v) + Math.abs(b.v));
        distance += (Math.abs(a.v) * tz + Math.abs(b.v) * (dt - tz)) / 2;
      }
    }
    return { distance, displacement };
  }

  // The colour of one's own bookings (app.css), which the chart's line is drawn in.
  const ownColour = () => getComputedStyle(document.documentElement).getPropertyValue("--amz-own").trim();
  let chart = null;
  function draw(points) {
    if (typeof Chart === "undefined") return;
    const series = points.map((p) => ({ x: p.t, y: p.v }));
    if (chart) {
      chart.data.datasets[0].data = series;
      chart.update("none");
      return;
    }
    chart = new Chart(document.getElementById("builder-chart"), {
      type: "line",
      data: { datasets: [{ label: "velocity (m/s, cw +)", data: series, borderColor: ownColour(), pointRadius: 0, tension: 0 }] },
      options: {
        animation: false,
        responsive: true,
        maintainAspectRatio: false,
        parsing: false,
        scales: { x: { type: "linear", title: { display: true, text: "s" } }, y: { title: { display: true, text: "m/s" } } },
        plugins: { legend: { display: false } },
      },
    });
  }

  // --- Checking while typing -----------------------------------------------------------------
  function update() {
    decorate();
    const chosen = robot();
    const limitV = chosen ? chosen.max_velocity_mps : null;
    const accel = chosen && chosen.max_accel_mps2 ? chosen.max_accel_mps2 : null;
    const limits = document.getElementById("builder-limits");
    limits.textContent = chosen
      ? `${chosen.name}: at most ${limitV === null ? "—" : fmt(limitV, 2) + " m/s"}, ` +
        `ramps at ${accel === null ? "—" : fmt(accel, 2) + " m/s²"}` +
        (chosen.rail_length_m ? `, rail ${fmt(chosen.rail_length_m, 2)} m.` : ".")
      : "No robot you may book.";
    const problems = [];
    const segments = [];
    const leftOut = [];
    rows().forEach((row, i) => {
      const s = readRow(row);
      const note = row.querySelector(".segment-note");
      note.textContent = "";
      note.className = "segment-note";
      const invalid = [];
      row.querySelectorAll("input").forEach((input) => input.removeAttribute("aria-invalid"));
      row.querySelectorAll(".field-error").forEach((error) => { error.textContent = ""; });
      if (s.empty) return;
      if (s.velocity === null || !(s.velocity >= 0)) invalid.push(["velocity_mps", "Give a velocity of 0 m/s or more."]);
      else if (limitV !== null && s.velocity > limitV) {
        invalid.push(["velocity_mps", `${fmt(s.velocity, 2)} m/s is above ${chosen.name}'s ${fmt(limitV, 2)} m/s.`]);
      }
      if (s.duration === null || !(s.duration > 0)) invalid.push(["duration_s", "Give a duration above 0 s."]);
      // Each error under its own field, once that field has been left.
      for (const [name, message] of invalid) {
        const input = row.querySelector(`[name=${name}]`);
        if (!touched.has(input)) continue;
        input.setAttribute("aria-invalid", "true");
        row.querySelector(`.field-error[data-for=${name}]`).textContent = message;
        problems.push(`Segment ${i}: ${message}`);
      }
      if (invalid.length) leftOut.push(i);
      else segments.push({ row, note, index: i, velocity: s.velocity, direction: s.direction, duration: s.duration });
    });
    if (segments.length > data.max_segments) problems.push(`At most ${data.max_segments} segments.`);
    const total = segments.reduce((sum, s) => sum + s.duration, 0);
    if (total > data.max_program_s) {
      problems.push(`The program lasts ${fmt(total, 1)} s; a booking lasts at most ${fmt(data.max_program_s / 3600, 2)} h.`);
    }
    // The preview is of the segments that can be read; it says which it leaves out.
    const without = leftOut.length
      ? ` (without segment${leftOut.length > 1 ? "s" : ""} ${leftOut.join(", ")}: not complete or not valid)`
      : "";
    document.getElementById("builder-duration").textContent = segments.length ? `${fmt(total, 1)} s${without}` : "—";
    const figures = ["builder-distance", "builder-laps", "builder-end"].map((id) => document.getElementById(id));
    if (!segments.length || accel === null || problems.length) {
      figures.forEach((f) => { f.textContent = "—"; });
      draw(segments.length && accel !== null ? profile(segments, accel).points : []);
    } else {
      const run = profile(segments, accel);
      run.notes.forEach((n, i) => {
        const s = segments[i];
        if (!n.reached) {
          s.note.textContent = `Reaches only ${fmt(n.top, 2)} m/s: ramping from ${fmt(Math.abs(n.from), 2)} m/s takes ${fmt(n.need, 2)} s.`;
          s.note.classList.add("warning");
          problems.push(`Segment ${s.index}: too short to reach ${fmt(s.velocity, 2)} m/s (needs ${fmt(n.need, 2)} s of ramp).`);
        } else if (n.need > 0) {
          s.note.textContent = `Ramps for ${fmt(n.need, 2)} s.`;
        }
      });
      const moved = integrate(run.points);
      figures[0].textContent = `${fmt(moved.distance, 2)} m`;
      const rail = Number(railInput.value);
      if (rail > 0) {
        figures[1].textContent = fmt(moved.distance / rail, 2);
        const at = ((moved.displacement % rail) + rail) % rail;
        figures[2].textContent = `${fmt(at, 2)} m clockwise from the start`;
      } else {
        figures[1].textContent = "— (give the rail's length)";
        figures[2].textContent = "—";
      }
      draw(run.points);
    }
    problemsList.replaceChildren(...problems.map((p) => Object.assign(document.createElement("li"), { textContent: p })));
    side.dataset.ok = String(!problems.length);
  }

  function chooseRobot() {
    const chosen = robot();
    // To the centimetre: the measured length carries digits no one typed.
    if (chosen && chosen.rail_length_m) railInput.value = fmt(chosen.rail_length_m, 2);
    update();
  }
  robotSelect.addEventListener("change", chooseRobot);
  railInput.addEventListener("input", update);
  body.addEventListener("focusout", (event) => {
    const target = /** @type {Element} */ (event.target);
    if (target.matches("input[name]")) { touched.add(target); update(); }
  });
  form.addEventListener("input", update);
  form.addEventListener("change", update);
  new MutationObserver(update).observe(body, { childList: true });

  // --- Files ---------------------------------------------------------------------------------
  function program() {
    return {
      title: titleInput.value,
      segments: rows().map(readRow).filter((s) => !s.empty).map((s) => ({
        velocity_mps: s.velocity, direction: s.direction, duration_s: s.duration,
      })),
    };
  }
  function download(text, type, ext) {
    const slug = (titleInput.value || "experiment").toLowerCase().replace(/[^a-z0-9]+/g, "-").replace(/^-|-$/g, "") || "experiment";
    const link = document.createElement("a");
    link.href = URL.createObjectURL(new Blob([text], { type }));
    link.download = `${slug}.${ext}`;
    document.body.appendChild(link);
    link.click();
    link.remove();
    setTimeout(() => URL.revokeObjectURL(link.href), 1000);
  }
  document.getElementById("builder-export-json").addEventListener("click", () => {
    download(JSON.stringify(program(), null, 2) + "\n", "application/json", "json");
  });
  document.getElementById("builder-export-yaml").addEventListener("click", () => {
    download(jsyaml.dump(program(), { flowLevel: 2 }), "application/yaml", "yaml");
  });

  // What `POST /api/v1/experiments/` takes; anything else is refused before a field changes.
  function parsed(text) {
    let doc;
    try { doc = jsyaml.load(text); } catch (e) { throw new Error(`not valid YAML or JSON: ${e.reason || e.message}`); }
    if (!doc || typeof doc !== "object" || Array.isArray(doc)) throw new Error("it holds no experiment (a title and segments)");
    const unknown = Object.keys(doc).filter((k) => k !== "title" && k !== "segments");
    if (unknown.length) throw new Error(`unknown field ${unknown[0]}`);
    if (typeof doc.title !== "string" || !doc.title.trim()) throw new Error("title: give a title");
    if (!Array.isArray(doc.segments) || !doc.segments.length) throw new Error("segments: give at least one segment");
    if (doc.segments.length > data.max_segments) throw new Error(`segments: at most ${data.max_segments}`);
    doc.segments.forEach((s, i) => {
      const at = `segments.${i}`;
      if (!s || typeof s !== "object") throw new Error(`${at}: not a segment`);
      if (typeof s.velocity_mps !== "number" || s.velocity_mps < 0) throw new Error(`${at}.velocity_mps: a number of 0 or more`);
      if (s.direction !== "cw" && s.direction !== "ccw") throw new Error(`${at}.direction: cw or ccw`);
      if (typeof s.duration_s !== "number" || s.duration_s <= 0) throw new Error(`${at}.duration_s: a number above 0`);
    });
    return doc;
  }
  document.getElementById("builder-import").addEventListener("change", async (/** @type {Event & {target: HTMLInputElement}} */ event) => {
    const status = document.getElementById("builder-import-status");
    const file = event.target.files[0];
    if (!file) return;
    try {
      const doc = parsed(await file.text());
      titleInput.value = doc.title;
      const template = rows()[0];
      const fresh = doc.segments.map((s) => {
        const row = template.cloneNode(true);
        writeRow(row, s);
        return row;
      });
      body.replaceChildren(...fresh);
      status.textContent = `Imported ${file.name}: ${doc.segments.length} segments. Save to keep them.`;
      status.className = "ok";
    } catch (e) {
      status.textContent = `${file.name} was not imported: ${e.message}.`;
      status.className = "error";
    }
    event.target.value = "";
    update();
  });

  chooseRobot();
})();
