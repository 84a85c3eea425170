// @ts-check
// A campaign's page: every completed run's measured velocity overlaid from its first sample,
// one colour per combination of values (the results table's swatches take the same).
(function () {
  "use strict";
  const source = document.getElementById("campaign-chart");
  if (!source) return;
  /** @type {{run: number, group: number, label: string, velocity: {t: number[], y: number[]}}[]} */
  const runs = JSON.parse(source.textContent || "[]");
  // Colour-blind-safe (Okabe–Ito), one per combination.
  const COLOURS = ["#0072b2", "#d55e00", "#009e73", "#cc79a7", "#e69f00", "#56b4e9", "#000000", "#f0e442"];
  const colour = (/** @type {number} */ i) => COLOURS[i % COLOURS.length];
  for (const swatch of /** @type {NodeListOf<HTMLElement>} */ (document.querySelectorAll(".swatch[data-index]"))) {
    swatch.style.background = colour(Number(swatch.dataset.index));
  }
  const canvas = document.getElementById("campaign-velocity");
  if (!(canvas instanceof HTMLCanvasElement) || typeof Chart === "undefined") return;
  new Chart(canvas, {
    type: "line",
    data: {
      datasets: runs.map((run) => ({
        label: run.label, borderColor: colour(run.group), backgroundColor: colour(run.group),
        borderWidth: 1.5, pointRadius: 0,
        data: run.velocity.t.map((t, i) => ({ x: t, y: run.velocity.y[i] })),
      })),
    },
    options: {
      animation: false, maintainAspectRatio: false, parsing: false, normalized: true,
      interaction: { mode: "nearest", intersect: false },
      plugins: { legend: { display: runs.length <= 12 } },
      scales: { x: { type: "linear", title: { display: true, text: "time since the run's start (s)" } },
                y: { title: { display: true, text: "measured velocity (m/s, cw +)" } } },
    },
  });
})();
