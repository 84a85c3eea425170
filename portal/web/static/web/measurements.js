// @ts-check
// Run page: each measurement series drawn from the summary the page carries
// (#measurements-data): the value against the position along the rail (its points, and the
// mean per metre), and the value over time with the robot's velocity. The summaries are handed
// on ("measurements:data") to the roof's heatmap (roof.js). While the run is live, a series
// changed ("run:measurements", pushed: run.js) has the part read again and redrawn.
(function () {
  "use strict";
  if (!document.getElementById("measurement-series")) return;
  /** @type {any[]} */
  let charts = [];

  function positionChart(canvas, column, unit) {
    const scatter = column.scatter || { track_m: [], value: [] };
    return new Chart(canvas, {
      type: "scatter",
      data: {
        datasets: [
          { label: "points", data: scatter.track_m.map((x, i) => ({ x, y: scatter.value[i] })),
            pointRadius: 1.5, borderWidth: 0 },
          { label: "mean per metre", type: "line", pointRadius: 0, borderWidth: 2,
            data: (column.by_metre || []).map((row) => ({ x: row[0] + 0.5, y: row[2] })) },
        ],
      },
      options: {
        animation: false, maintainAspectRatio: false, parsing: false, normalized: true,
        scales: { x: { type: "linear", title: { display: true, text: "position along the rail (m)" } },
                  y: { title: { display: true, text: unit } } },
      },
    });
  }

  function timeChart(canvas, column, unit) {
    const line = column.line || { t_s: [], value: [], velocity_mps: [] };
    return new Chart(canvas, {
      type: "line",
      data: {
        datasets: [
          { label: unit || "value", data: line.t_s.map((x, i) => ({ x, y: line.value[i] })),
            pointRadius: 0, borderWidth: 1.5, yAxisID: "y" },
          { label: "robot's velocity (m/s)", data: line.t_s.map((x, i) => ({ x, y: line.velocity_mps[i] })),
            pointRadius: 0, borderWidth: 1, borderDash: [4, 3], yAxisID: "v", spanGaps: false },
        ],
      },
      options: {
        animation: false, maintainAspectRatio: false, parsing: false, normalized: true,
        interaction: { mode: "nearest", intersect: false },
        scales: { x: { type: "linear", title: { display: true, text: "time since the run's start (s)" } },
                  y: { title: { display: true, text: unit } },
                  v: { position: "right", grid: { drawOnChartArea: false }, title: { display: true, text: "m/s" } } },
      },
    });
  }

  function drawAll() {
    const data = document.getElementById("measurements-data");
    /** @type {{name: string, unit: string, columns: Object<string, any>}[]} */
    const series = data ? JSON.parse(data.textContent || "[]") : [];
    document.dispatchEvent(new CustomEvent("measurements:data", { detail: series }));
    for (const chart of charts) chart.destroy();
    charts = [];
    if (typeof Chart === "undefined") return;
    for (const canvas of document.querySelectorAll("#measurements canvas[data-kind]")) {
      if (!(canvas instanceof HTMLCanvasElement)) continue;
      const one = series[Number(canvas.dataset.series)];
      const column = one && one.columns[canvas.dataset.column || ""];
      if (!column) continue;
      const unit = one.unit ? `${canvas.dataset.column} (${one.unit})` : canvas.dataset.column || "";
      charts.push(canvas.dataset.kind === "position" ? positionChart(canvas, column, unit) : timeChart(canvas, column, unit));
    }
  }

  // One read at a time; pushes meanwhile cause one more after it. A part is not swapped
  // under someone typing in it (its offset form): it waits until they leave it.
  let loading = false;
  let again = false;
  let waiting = false;
  async function reload() {
    if (loading) { again = true; return; }
    const part = document.getElementById("measurement-series");
    if (!part) return;
    if (part.contains(document.activeElement)) {
      if (!waiting) {
        waiting = true;
        part.addEventListener("focusout", () => { waiting = false; setTimeout(reload, 0); }, { once: true });
      }
      return;
    }
    loading = true;
    try {
      const response = await fetch(part.dataset.url || "", { credentials: "same-origin", headers: { Accept: "text/html" } });
      if (!response.ok) throw new Error("HTTP " + response.status);
      const holder = document.createElement("template");
      holder.innerHTML = await response.text();
      const fresh = holder.content.getElementById("measurement-series");
      if (!fresh) throw new Error("not the series");
      part.replaceWith(fresh);
      drawAll();
    } catch (error) {
      // The next push, or the page's next load, reads it again.
      console.warn("measurements not refreshed:", error);
    } finally {
      loading = false;
      if (again) { again = false; reload(); }
    }
  }

  document.addEventListener("run:measurements", () => { reload(); });
  drawAll();
})();
