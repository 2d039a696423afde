// The experimenter's page, live: the link's token out of the address bar and the history (the cookie
// carries on), then the participants' table as the server sends it (server-sent events, each second);
// EventSource reconnects by itself when the server comes back.
"use strict";
history.replaceState(null, "", "/experimenter");
const live = document.getElementById("live");
const events = new EventSource("/experimenter/events");
events.onmessage = (event) => {
  const view = JSON.parse(event.data);
  live.innerHTML = view.table;             // made (and escaped) by the server
  live.dataset.running = String(view.running);
  delete live.dataset.error;
};
events.onerror = () => {
  live.dataset.error = "disconnected";   // the server gone: keep the last table, EventSource tries again
};
