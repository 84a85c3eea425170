// Run page: draw commanded vs measured velocity and refresh while the run is live.
(function () {
  "use strict";
  const status = document.getElementById("run-status");
  const canvas = document.getElementById("velocity-chart");
  if (!status) return;
  // The status keeps refreshing even if the chart library failed to load.
  const chart = canvas && typeof Chart !== "undefined" ? new Chart(canvas, {
    type: "line",
    data: { labels: [], datasets: [
      { label: "commanded (m/s, cw +)", data: [], borderWidth: 2, pointRadius: 0, stepped: true },
      { label: "measured (m/s, cw +)", data: [], borderWidth: 1.5, pointRadius: 0 },
    ] },
    options: {
      animation: false, maintainAspectRatio: false, parsing: false, normalized: true,
      scales: { x: { type: "linear", title: { display: true, text: "time since start (s)" } },
                y: { title: { display: true, text: "velocity (m/s)" } } },
    },
  }) : null;
  async function refresh() {
    let data;
    try {
      const response = await fetch(status.dataset.url, { headers: { Accept: "application/json" } });
      if (!response.ok) throw new Error(response.statusText);
      data = await response.json();
    } catch (error) {
      document.getElementById("run-progress").textContent = "(could not refresh: " + error.message + ")";
      setTimeout(refresh, 5000);
      return;
    }
    const s = data.series;
    if (chart) {
      chart.data.datasets[0].data = s.t.map((t, i) => ({ x: t, y: s.commanded_mps[i] }));
      chart.data.datasets[1].data = s.t.map((t, i) => ({ x: t, y: s.measured_mps[i] }));
      chart.update();
    }
    const state = document.getElementById("run-state");
    state.textContent = data.state_label;
    state.dataset.state = data.state;
    document.getElementById("sample-count").textContent = String(data.sample_count);
    const progress = document.getElementById("run-progress");
    progress.setAttribute("aria-busy", data.live ? "true" : "false");
    progress.textContent = data.live ? "updating…" : "";
    if (data.live) setTimeout(refresh, 2000);
  }
  refresh();
})();
