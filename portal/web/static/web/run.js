// Run page: charts of velocity, position and battery; refresh charts and tables while live.
(function () {
  "use strict";
  const status = document.getElementById("run-status");
  if (!status) return;

  function lineChart(id, datasets, yTitle) {
    const canvas = document.getElementById(id);
    // The status keeps refreshing even if the chart library failed to load.
    if (!canvas || typeof Chart === "undefined") return null;
    return new Chart(canvas, {
      type: "line",
      data: { datasets: datasets.map((d) => Object.assign({ data: [], pointRadius: 0 }, d)) },
      options: {
        animation: false, maintainAspectRatio: false, parsing: false, normalized: true,
        interaction: { mode: "nearest", intersect: false },
        scales: { x: { type: "linear", title: { display: true, text: "time since start (s)" } },
                  y: { title: { display: true, text: yTitle } } },
      },
    });
  }
  const charts = {
    velocity: lineChart("velocity-chart", [
      { key: "commanded_mps", label: "commanded (m/s, cw +)", borderWidth: 2, stepped: true },
      { key: "measured_mps", label: "measured (m/s, cw +)", borderWidth: 1.5 },
    ], "velocity (m/s)"),
    position: lineChart("position-chart", [
      { key: "track_m", label: "position along the rail, unwrapped (m, cw +)", borderWidth: 1.5 },
    ], "m from the rail's origin"),
    battery: lineChart("battery-chart", [
      { key: "battery_v", label: "battery (V, filtered)", borderWidth: 1.5 },
    ], "V"),
  };

  function draw(series) {
    for (const chart of Object.values(charts)) {
      if (!chart) continue;
      for (const dataset of chart.data.datasets) {
        const s = series[dataset.key] || { t: [], y: [] };
        dataset.data = s.t.map((t, i) => ({ x: t, y: s.y[i] }));
      }
      chart.update();
    }
  }

  let firstLoad = true;
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
    draw(data.series);
    const state = document.getElementById("run-state");
    state.textContent = data.state_label;
    state.dataset.state = data.state;
    document.getElementById("sample-count").textContent = String(data.sample_count);
    // The server rendered the tables with the page; while samples arrive they are redrawn.
    if (!firstLoad || data.live) document.getElementById("run-analysis").innerHTML = data.analysis_html;
    firstLoad = false;
    // The rail length arrives with the first samples; the form's hint follows it.
    const form = document.getElementById("pass-form");
    if (form && data.rail_length_m && form.dataset.railLengthM !== String(data.rail_length_m)) {
      form.dataset.railLengthM = String(data.rail_length_m);
      document.getElementById("rail-hint").textContent =
        "(0 – " + data.rail_length_m.toFixed(1) + "; 0 is the rail's origin)";
    }
    const progress = document.getElementById("run-progress");
    progress.setAttribute("aria-busy", data.live ? "true" : "false");
    progress.textContent = data.live ? "updating…" : "";
    if (data.live) setTimeout(refresh, 2000);
  }
  refresh();
})();
