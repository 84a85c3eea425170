// @ts-check
// Run page: each measurement series drawn from the summary the page carries
// (#measurements-data): the value against the position along the rail (its points, and the
// mean per metre), and the value over time with the robot's velocity.
(function () {
  "use strict";
  const data = document.getElementById("measurements-data");
  if (!data || typeof Chart === "undefined") return;
  /** @type {{name: string, unit: string, columns: Object<string, any>}[]} */
  const series = JSON.parse(data.textContent || "[]");

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

  for (const canvas of document.querySelectorAll("#measurements canvas[data-kind]")) {
    if (!(canvas instanceof HTMLCanvasElement)) continue;
    const one = series[Number(canvas.dataset.series)];
    const column = one && one.columns[canvas.dataset.column || ""];
    if (!column) continue;
    const unit = one.unit ? `${canvas.dataset.column} (${one.unit})` : canvas.dataset.column || "";
    if (canvas.dataset.kind === "position") positionChart(canvas, column, unit);
    else timeChart(canvas, column, unit);
  }
})();
