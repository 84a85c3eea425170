// @ts-check
// How the pages' scripts talk to the REST API: the session's CSRF token, JSON both ways, and
// the API's refusal ({detail, fields}) put into one sentence for the person reading it.
window.AmazingApi = (function () {
  "use strict";

  function csrf() {
    const input = /** @type {HTMLInputElement | null} */ (document.querySelector("[name=csrfmiddlewaretoken]"));
    return input ? input.value : "";
  }

  // Resolves to {ok, status, data}; data is null when the answer is not JSON, and status 0
  // when there was no answer at all (the connection dropped): never rejects, so every page
  // says what went wrong instead of leaving a button busy or a line empty.
  async function api(method, url, body, extraHeaders) {
    let response;
    try {
      response = await fetch(url, {
        method,
        // X-Amazing-Client: the door a booking's change came through, for its audit row.
        headers: Object.assign({ "Content-Type": "application/json", "X-CSRFToken": csrf(), Accept: "application/json", "X-Amazing-Client": "page" }, extraHeaders || {}),
        body: body === undefined ? undefined : JSON.stringify(body),
        credentials: "same-origin",
      });
    } catch (error) {
      return { ok: false, status: 0, data: null };
    }
    let data = null;
    try { data = await response.json(); } catch (e) { data = null; }
    return { ok: response.ok, status: response.status, data };
  }

  function explain(data) {
    if (!data) return "The server did not answer clearly; try again.";
    const parts = [data.detail || ""];
    if (data.fields) {
      for (const [field, messages] of Object.entries(data.fields)) {
        for (const m of [].concat(messages)) if (m && m !== data.detail) parts.push(field === "quota" ? m : `${field}: ${m}`);
      }
    }
    return parts.filter(Boolean).join(" ");
  }

  return { api, explain };
})();
