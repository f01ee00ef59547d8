// fw operator console: follows /api/stream, sends commands to /api/command.
// Plain browser JavaScript, no build step, nothing fetched from elsewhere.
"use strict";

const STALE_AFTER = 2.0;  // seconds without news before a section is marked stale
const $ = (id) => document.getElementById(id);
let takeable = [];
let idents = {};
let lastState = null;
let resetLog = true;  // a new stream starts with the whole log

function show(id, text, cls) {
  const el = $(id);
  el.textContent = text;
  const tile = el.closest(".tile");
  if (tile) tile.className = "tile " + (cls || "");
}

function fresh(section) {
  return section && section.age !== null && section.age < STALE_AFTER;
}

function render(state) {
  lastState = state;
  $("topology").textContent = state.topology;
  const s = state.status;
  show("operation", s.operation, s.operation === "stopped" ? "bad" : s.operation.startsWith("approaching") ? "ok" : "");
  show("area", s.area || "–", s.area === "critical" ? "warn" : s.area === "safe" ? "ok" : "");
  show("tracker", s.tracker, s.tracker === "No Sensor Available" ? "bad" : "ok");
  const distance = s.min_distance === null || s.min_distance === undefined ? "–" : (s.min_distance * 100).toFixed(0) + " cm";
  show("people", `${s.people_near ?? "–"} / ${distance}`, "");
  show("robot", s.robot || "–", (s.robot || "").startsWith("SAFETY STOP") ? "bad" : s.robot === "released" ? "ok" : "");
  $("people-tile").classList.toggle("stale", !fresh(state.people));
  $("tracker-tile").classList.toggle("stale", !fresh(state.supervisor));
  $("area-tile").classList.toggle("stale", !fresh(state.supervisor));

  takeable = (state.takeable && state.takeable.data) || [];
  for (const button of document.querySelectorAll("button[data-event]")) {
    button.disabled = !takeable.includes(button.dataset.event);
  }
  $("release").disabled = !takeable.includes("e_RELEASE");
  for (const form of document.querySelectorAll("#forms form")) {
    form.querySelector("button").disabled = !takeable.includes(form.dataset.event);
  }
  if ($("release").disabled) disarm();

  const health = (state.health && state.health.data) || {};
  $("health").classList.toggle("stale", !state.health || state.health.age === null || state.health.age > 3);
  $("health-rows").innerHTML = Object.entries(health).map(([name, h]) =>
    `<tr class="${h.alive ? "" : "dead"}"><td>${name}</td><td>${h.process}</td>` +
    `<td>${h.alive ? (h.state || "?") : "LOST"}</td></tr>`).join("");

  drawScene(state);
  drawPlots(state);
  drawLatencies(state);
  highlight(s.states || [], (state.chart && state.chart.data && state.chart.data.active) || []);
  if (s.setup_failed && !$("setup-failed").open) {
    $("setup-reason").textContent = s.failure || "a setup configuration failed";
    $("setup-failed").showModal();
  }
  if (resetLog && state.log) {
    $("log-lines").innerHTML = "";
    resetLog = false;
  }
  for (const line of state.log || []) addLog(line);
}

function addLog(line) {
  const li = document.createElement("li");
  li.className = line.severity;
  li.textContent = new Date(line.t * 1000).toLocaleTimeString() + "  " + line.text;
  $("log-lines").prepend(li);
  while ($("log-lines").children.length > 300) $("log-lines").lastChild.remove();
}

function highlight(_leaves, paths) {
  const active = new Set();
  for (const path of paths) {  // the active leaves and every ancestor
    const parts = path.split(".");
    for (let i = 1; i <= parts.length; i++) active.add(parts.slice(0, i).join("."));
  }
  for (const g of document.querySelectorAll("#chart-svg g.node, #chart-svg g.cluster")) {
    const title = g.querySelector("title");
    const ident = title ? title.textContent.replace(/^cluster_/, "") : "";
    g.classList.toggle("active", active.has(idents[ident]));
  }
}

async function send(event, payload) {
  $("answer").textContent = `${event}…`;
  $("answer").className = "";
  try {
    const reply = await fetch("/api/command", {
      method: "POST",
      headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ event, payload, origin: "console" }),
    });
    const answer = await reply.json();
    $("answer").textContent = answer.accepted ? `${event}: accepted` : `${event}: refused: ${answer.reason}`;
    $("answer").className = answer.accepted ? "accepted" : "refused";
  } catch (err) {
    $("answer").textContent = `${event}: no answer (${err})`;
    $("answer").className = "refused";
  }
}

function disarm() {
  $("release").hidden = false;
  $("release-confirm").hidden = true;
  $("release-cancel").hidden = true;
}

for (const button of document.querySelectorAll("button[data-event]")) {
  button.addEventListener("click", () => {
    const payload = {};
    if (button.dataset.where) payload.where = button.dataset.where;
    if (button.dataset.reason) payload.reason = button.dataset.reason;
    send(button.dataset.event, Object.keys(payload).length ? payload : undefined);
  });
}
$("release").addEventListener("click", () => {  // two steps: arm, then confirm
  $("release").hidden = true;
  $("release-confirm").hidden = false;
  $("release-cancel").hidden = false;
});
$("release-cancel").addEventListener("click", disarm);
$("release-confirm").addEventListener("click", () => { disarm(); send("e_RELEASE"); });

const WITH_BUTTONS = ["e_GOTO", "e_STOP"];

function buildForms(commands) {
  // one form per operator command that carries values, from the chart's declaration
  const holder = $("forms");
  holder.innerHTML = "";
  for (const [event, spec] of Object.entries(commands)) {
    const fields = Object.entries(spec.payload || {});
    if (!fields.length || WITH_BUTTONS.includes(event)) continue;
    const form = document.createElement("form");
    form.dataset.event = event;
    form.id = `form-${event}`;
    form.noValidate = false;
    form.innerHTML = `<h3>${spec.doc || event}</h3>`;
    const row = document.createElement("div");
    row.style.display = "contents";
    for (const [name, f] of fields) {
      const label = document.createElement("label");
      label.textContent = `${name}${f.unit ? ` (${f.unit})` : ""}`;
      const input = document.createElement("input");
      input.name = name;
      input.required = true;
      input.type = f.type === "number" || f.type === "integer" ? "number" : "text";
      if (input.type === "number") input.step = f.type === "integer" ? "1" : "any";
      if (f.min !== undefined) input.min = f.min;
      if (f.max !== undefined) input.max = f.max;
      input.title = `${f.doc || name}${f.min !== undefined ? `, ${f.min} to ${f.max} ${f.unit || ""}` : ""}`;
      label.appendChild(input);
      row.appendChild(label);
    }
    form.appendChild(row);
    const button = document.createElement("button");
    button.type = "button";  // a submit button would stop at the browser's own check
    button.textContent = "Send";
    button.disabled = true;
    form.appendChild(button);
    const submit = (e) => {
      e.preventDefault();
      if (!form.checkValidity()) {
        form.reportValidity();  // refused in the page: the server checks again
        $("answer").textContent = `${event}: refused: a value is missing or out of range`;
        $("answer").className = "refused";
        return;
      }
      const payload = {};
      for (const input of form.querySelectorAll("input")) {
        payload[input.name] = input.type === "number" ? Number(input.value) : input.value;
      }
      send(event, payload);
    };
    button.addEventListener("click", submit);
    form.addEventListener("submit", submit);
    holder.appendChild(form);
  }
}

async function loadChart() {
  try {
    const chart = await (await fetch("/api/chart")).json();
    idents = chart.idents || {};
    buildForms(chart.commands || {});
    $("chart-svg").innerHTML = chart.svg || `<p>${chart.error || "no chart"}</p>`;
    if (lastState) render({ ...lastState, log: undefined });
  } catch (err) {
    $("chart-svg").textContent = `cannot load the chart: ${err}`;
  }
}

function connect() {
  const stream = new EventSource("/api/stream");
  stream.addEventListener("state", (e) => {
    $("link").textContent = "live";
    $("link").className = "badge";
    document.body.classList.remove("stale");
    render(JSON.parse(e.data));
  });
  stream.addEventListener("log", (e) => addLog(JSON.parse(e.data)));
  stream.onerror = () => {
    $("link").textContent = "connection lost: data is stale";
    $("link").className = "badge stale";
    document.querySelector("main").classList.add("stale");
  };
  stream.onopen = () => {
    resetLog = true;
    document.querySelector("main").classList.remove("stale");
  };
}

$("details").addEventListener("change", (e) => $("log").classList.toggle("details", e.target.checked));

loadChart();
connect();
