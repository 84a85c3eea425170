// @ts-check
// Live updates from the portal over Server-Sent Events (portal/web/live.py), polling while
// the stream is down, with a visible "reconnecting" state.
//
//   const follow = liveFollow(url, {
//     events: { state: (data) => …, samples: (data) => … },  // by event type
//     poll: () => …,       // read the page's data; called on every (re)connect, and every
//     pollMs: 3000,        //   pollMs while the stream is down,
//     safetyMs: 15000,     //   and every safetyMs while it is up (a push can be lost: a
//                          //   server restarting between a change and its push); optional
//     indicator: element,  // gets data-state="connecting|live|reconnecting|polling|off"
//   });
//   follow.stop();
(function () {
  "use strict";
  const WORDS = {
    connecting: "connecting…", live: "live", reconnecting: "reconnecting…",
    polling: "updating every few seconds", off: "",
  };

  // The streams are served by the ASGI server: on this page's own origin behind a proxy, or
  // on its own port of the same host (the page's meta tag names it).
  const streamPort = /** @type {HTMLMetaElement | null} */ (document.querySelector('meta[name="live-stream-port"]'));
  function streamUrl(path) {
    const url = new URL(path, window.location.href);
    if (streamPort) url.port = streamPort.content;
    return url.href;
  }

  window.liveFollow = function (url, options) {
    const indicator = options.indicator || null;
    let source = null;
    let timer = null;
    let safety = null;
    let retryMs = 1000;
    let stopped = false;

    function show(state) {
      if (!indicator) return;
      indicator.dataset.state = state;
      indicator.textContent = WORDS[state];
    }
    function startPolling() {
      if (timer === null && options.poll) timer = setInterval(options.poll, options.pollMs || 3000);
    }
    function stopPolling() {
      if (timer !== null) { clearInterval(timer); timer = null; }
    }
    function startSafety() {
      if (safety === null && options.poll && options.safetyMs) {
        safety = setInterval(options.poll, options.safetyMs);
      }
    }
    function stopSafety() {
      if (safety !== null) { clearInterval(safety); safety = null; }
    }
    function connect() {
      if (stopped) return;
      if (typeof EventSource === "undefined") { show("polling"); startPolling(); return; }
      source = new EventSource(streamUrl(url), { withCredentials: true });
      source.onopen = () => {
        retryMs = 1000;
        stopPolling();
        startSafety();
        show("live");
        // Whatever happened while the stream was down is read once, here.
        if (options.poll) options.poll();
      };
      for (const [type, handler] of Object.entries(options.events || {})) {
        source.addEventListener(type, (event) => {
          let data = {};
          try { data = JSON.parse(event.data); } catch (error) { return; }
          handler(data);
        });
      }
      source.onerror = () => {
        if (stopped) return;
        show("reconnecting");
        stopSafety();
        startPolling();
        // The browser retries a dropped connection by itself; a refused one (503, 403) it
        // gives up on: try again later, less and less often.
        if (source.readyState === EventSource.CLOSED) {
          source.close();
          setTimeout(connect, retryMs);
          retryMs = Math.min(retryMs * 2, 30000);
        }
      };
    }
    show("connecting");
    connect();
    return {
      stop() {
        stopped = true;
        stopPolling();
        stopSafety();
        if (source) source.close();
        show("off");
      },
    };
  };
})();
