// @ts-check
// Compare runs: each run's measured velocity and position overlaid, from its first sample;
// each measurement series overlaid by position along the rail (its mean per metre).
(function () {
  "use strict";
  const source = document.getElementById("compare-series");
  if (!source) return;
  const runs = JSON.parse(source.textContent);
  // Colour-blind-safe (Okabe–Ito), one per run; the legend's swatches take the same.
  const COLOURS = ["#0072b2", "#d55e00", "#009e73", "#cc79a7", "#e69f00", "#56b4e9"];
  const colour = (i) => COLOURS[i % COLOURS.length];
  for (const swatch of /** @type {NodeListOf<HTMLElement>} */ (document.querySelectorAll(".swatch[data-index]"))) {
    swatch.style.background = colour(Number(swatch.dataset.index));
  }

  function points(series) {
    return series.t.map((t, i) => ({ x: t, y: series.y[i] }));
  }

  function chart(id, key, yTitle) {
    const canvas = document.getElementById(id);
    if (!canvas || typeof Chart === "undefined") return;
    new Chart(canvas, {
      type: "line",
      data: {
        datasets: runs.map((run, i) => ({
          label: run.label, data: points(run[key]), borderColor: colour(i), backgroundColor: colour(i),
          borderWidth: 1.5, pointRadius: 0,
        })),
      },
      options: {
        animation: false, maintainAspectRatio: false, parsing: false, normalized: true,
        interaction: { mode: "nearest", intersect: false },
        scales: { x: { type: "linear", title: { display: true, text: "time since the run's start (s)" } },
                  y: { title: { display: true, text: yTitle } } },
      },
    });
  }
  chart("compare-velocity", "velocity", "measured velocity (m/s, cw +)");
  chart("compare-position", "position", "from the start along the rail (m, cw +)");

  const measured = document.getElementById("compare-measurements-data");
  const measurements = measured ? JSON.parse(measured.textContent || "[]") : [];
  for (const canvas of document.querySelectorAll("canvas[data-measurement]")) {
    if (!(canvas instanceof HTMLCanvasElement) || typeof Chart === "undefined") continue;
    const m = measurements[Number(canvas.dataset.measurement)];
    if (!m) continue;
    new Chart(canvas, {
      type: "line",
      data: {
        datasets: m.runs.map((one, i) => ({
          label: runs[i] ? runs[i].label : "", borderColor: colour(i), backgroundColor: colour(i),
          borderWidth: 1.5, pointRadius: 0, spanGaps: false,
          data: one ? one.by_metre.map((row) => ({ x: row[0] + 0.5, y: row[1] })) : [],
        })),
      },
      options: {
        animation: false, maintainAspectRatio: false, parsing: false, normalized: true,
        interaction: { mode: "nearest", intersect: false },
        scales: { x: { type: "linear", title: { display: true, text: "position along the rail (m)" } },
                  y: { title: { display: true, text: m.unit ? `${m.column} (${m.unit})` : m.column } } },
      },
    });
  }
})();
