// @ts-check
// The tokens page: a new token's Copy button (shown only where the browser can copy).
(function () {
  "use strict";
  const button = document.getElementById("copy-token");
  const input = /** @type {HTMLInputElement | null} */ (document.getElementById("new-token-value"));
  const status = document.getElementById("copy-token-status");
  if (!button || !input || !status || !navigator.clipboard) return;
  button.hidden = false;
  button.addEventListener("click", async () => {
    try {
      await navigator.clipboard.writeText(input.value);
      status.textContent = "Copied.";
    } catch (error) {
      input.select();
      status.textContent = "Copying was refused: the token is selected, copy it with Ctrl+C.";
    }
  });
})();
