// The experimenter's page, live: the link's token out of the address bar and the history (the cookie
// carries on), then the participants' table fetched again every second.
"use strict";
history.replaceState(null, "", "/experimenter");
const live = document.getElementById("live");
async function refresh() {
  try {
    const response = await fetch("/experimenter?format=table", { cache: "no-store", credentials: "same-origin" });
    if (response.ok) live.innerHTML = await response.text();
    else live.dataset.error = String(response.status);
  } catch (err) {
    live.dataset.error = String(err);   // the server gone: keep the last table, try again
  }
}
setInterval(refresh, 1000);
