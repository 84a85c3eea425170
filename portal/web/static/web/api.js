// @ts-check
// How the pages' scripts talk to the portal, every request of theirs: the session's CSRF
// token, JSON both ways, and the API's refusal ({detail, fields}) put into one sentence for the
// person reading it.
window.AmazingApi = (function () {
  "use strict";

  function csrf() {
    const input = /** @type {HTMLInputElement | null} */ (document.querySelector("[name=csrfmiddlewaretoken]"));
    return input ? input.value : "";
  }

  // Resolves to {ok, status, data}; data is null when the answer is not JSON, and status 0
  // when there was no answer at all (the connection dropped): never rejects, so every page
  // says what went wrong instead of leaving a button busy or a line empty.
  // A request without a body (a GET) is sent without one. options: `headers` to add, and
  // `keepalive`: the request outlives the page (a stop sent as the tab closes).
  async function api(method, url, body, options) {
    const { headers = {}, keepalive = false } = options || {};
    let response;
    try {
      response = await fetch(url, {
        method,
        // X-Amazing-Client: the door a booking's change came through, for its audit row.
        headers: Object.assign(
          body === undefined ? {} : { "Content-Type": "application/json" },
          { "X-CSRFToken": csrf(), Accept: "application/json", "X-Amazing-Client": "page" },
          headers,
        ),
        body: body === undefined ? undefined : JSON.stringify(body),
        credentials: "same-origin",
        keepalive,
      });
    } catch (error) {
      return { ok: false, status: 0, data: null };
    }
    let data = null;
    try { data = await response.json(); } catch (e) { data = null; }
    return { ok: response.ok, status: response.status, data };
  }

  // Why a request came to nothing, in a few words for a line of the page: no answer at all,
  // a refusal (its status), or an answer that is not JSON.
  function failure(result) {
    if (result.status === 0) return "no answer";
    if (!result.ok) return "HTTP " + result.status;
    return "an answer that is not JSON";
  }

  function explain(data) {
    if (!data) return "The server did not answer clearly; try again.";
    const parts = [data.detail || ""];
    if (data.fields) {
      for (const [field, messages] of Object.entries(data.fields)) {
        // The detail already says a field's message ("reason: Say why…") when there is one.
        for (const m of [].concat(messages)) if (m && !String(data.detail || "").includes(m)) parts.push(field === "quota" ? m : `${field}: ${m}`);
      }
    }
    return parts.filter(Boolean).join(" ");
  }

  return { api, explain, failure };
})();
