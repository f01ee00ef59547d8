// fw operator console: follows /api/stream, sends commands to /api/command.
// Plain browser JavaScript, no build step, nothing fetched from elsewhere. The page is
// generic: tiles, buttons, forms and plots come from /api/layout (the topology's
// `console:` section and the chart's operator events); a procedure's panels add their
// own scripts, each registering fwPanels[name] = {init(container), render(state)}.
"use strict";

const STALE_AFTER = 2.0;  // seconds without news before a section is marked stale
const COLORS = ["#f87171", "#4ade80", "#60a5fa", "#facc15", "#c084fc", "#fb923c"];
const $ = (id) => document.getElementById(id);
const fwPanels = {};
let layout = { buttons: [], forms: {}, plots: [], panels: [] };
let takeable = [];
let idents = {};
let lastState = null;
let resetLog = true;  // a new stream starts with the whole log
let alertShown = "";

function fresh(section) {
  return section && section.age !== null && section.age < STALE_AFTER;
}

function renderTiles(tiles) {
  const holder = $("status");
  for (const t of tiles) {
    let tile = $(`tile-${t.id}`);
    if (!tile) {
      tile = document.createElement("div");
      tile.id = `tile-${t.id}`;
      tile.innerHTML = `<label></label><b data-testid="${t.id}"></b>`;
      holder.appendChild(tile);
    }
    tile.querySelector("label").textContent = t.label;
    tile.querySelector("b").textContent = t.text;
    tile.className = ["tile", t.tone, t.stale ? "stale" : "", t.wide ? "wide" : ""].join(" ");
  }
}

function render(state) {
  lastState = state;
  $("topology").textContent = state.topology;
  renderTiles(state.tiles || []);

  takeable = (state.takeable && state.takeable.data) || [];
  for (const button of document.querySelectorAll("#buttons button[data-event]")) {
    button.disabled = !takeable.includes(button.dataset.event);
    if (button.disabled && button.dataset.confirm) disarm(button);
  }
  for (const form of document.querySelectorAll("#forms form")) {
    form.querySelector("button").disabled = !takeable.includes(form.dataset.event);
  }

  const health = (state.health && state.health.data) || {};
  $("health").classList.toggle("stale", !state.health || state.health.age === null || state.health.age > 3);
  $("health-rows").innerHTML = Object.entries(health).map(([name, h]) =>
    `<tr class="${h.alive ? "" : "dead"}"><td>${name}</td><td>${h.process}</td>` +
    `<td>${h.alive ? (h.state || "?") : "LOST"}</td></tr>`).join("");

  for (const spec of layout.plots) {
    const series = (state.plots || {})[spec.id] || { t: [], values: [] };
    const n = series.values.length;  // a 2- or 3-vector's lines are x, y, z
    const labels = series.values.map((_, k) => n === 1 ? spec.label : n <= 3 ? `${spec.label} ${"xyz"[k]}` : `${spec.label} [${k}]`);
    plotOn($(`plot-${spec.id}`), series, labels, COLORS, spec.unit);
  }
  for (const panel of layout.panels) {
    const code = fwPanels[panel.name];
    if (code && code.render) code.render(state);
  }
  highlight((state.chart && state.chart.data && state.chart.data.active) || []);
  const alert = state.alert;
  if (alert && alert.text !== alertShown && !$("alert").open) {
    $("alert-title").textContent = alert.title;
    $("alert-text").textContent = alert.text;
    $("alert").showModal();
  }
  alertShown = alert ? alert.text : "";
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

function highlight(paths) {
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
  // the chart at its own size (readable), scrolled so the active leaf stays in view
  const key = paths.join(" ");
  // the deepest active state (the procedure's task, not a small side region); of equally
  // deep ones the last (regions come in their chart's order: the main task last here)
  const depth = (p) => p.split(".").length;
  const deepest = paths.reduce((best, p) => (depth(p) >= depth(best) ? p : best), paths[0] || "");
  const first = Object.keys(idents).find((ident) => idents[ident] === deepest);
  const leaf = [...document.querySelectorAll("#chart-svg g.node.active")].find(
    (g) => (g.querySelector("title") || {}).textContent === first) || document.querySelector("#chart-svg g.node.active");
  if (leaf && key !== lastFocus) {
    lastFocus = key;
    const pane = $("chart"), box = leaf.getBoundingClientRect(), at = pane.getBoundingClientRect();
    pane.scrollLeft += box.left + box.width / 2 - (at.left + pane.clientWidth / 2);
    pane.scrollTop += box.top + box.height / 2 - (at.top + pane.clientHeight / 2);
  }
}
let lastFocus = "";

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

function disarm(button) {
  button.hidden = false;
  $(`${button.id}-confirm`).hidden = true;
  $(`${button.id}-cancel`).hidden = true;
}

function buildButtons(buttons) {
  // one button per operator command; a button with `confirm` is armed, then confirmed
  const holder = $("buttons");
  holder.innerHTML = "";
  for (const spec of buttons) {
    const button = document.createElement("button");
    button.id = spec.id;
    button.dataset.event = spec.event;
    button.textContent = spec.confirm ? `${spec.label}…` : spec.label;
    button.title = spec.doc || spec.event;
    button.className = spec.style === "normal" ? "" : spec.style;
    button.disabled = true;
    const payload = Object.keys(spec.payload || {}).length ? spec.payload : undefined;
    holder.appendChild(button);
    if (!spec.confirm) {
      button.addEventListener("click", () => send(spec.event, payload));
      continue;
    }
    button.dataset.confirm = "1";
    const confirm = document.createElement("button");
    confirm.id = `${spec.id}-confirm`;
    confirm.className = button.className;
    confirm.textContent = `Confirm ${spec.label}`;
    confirm.hidden = true;
    const cancel = document.createElement("button");
    cancel.id = `${spec.id}-cancel`;
    cancel.textContent = "Cancel";
    cancel.hidden = true;
    holder.append(confirm, cancel);
    button.addEventListener("click", () => {  // two steps: arm, then confirm
      button.hidden = true;
      confirm.hidden = false;
      cancel.hidden = false;
    });
    cancel.addEventListener("click", () => disarm(button));
    confirm.addEventListener("click", () => { disarm(button); send(spec.event, payload); });
  }
}

function buildForms(commands) {
  // one form per operator command that carries values, from the chart's declaration
  const holder = $("forms");
  holder.innerHTML = "";
  holder.hidden = !Object.keys(commands).length;
  for (const [event, spec] of Object.entries(commands)) {
    const fields = Object.entries(spec.payload || {});
    const form = document.createElement("form");
    form.dataset.event = event;
    form.id = `form-${event}`;
    form.innerHTML = `<h3></h3>`;
    form.querySelector("h3").textContent = spec.doc || event;
    const row = document.createElement("div");
    row.style.display = "contents";
    for (const [name, f] of fields) {
      const label = document.createElement("label");
      label.textContent = `${name}${f.unit ? ` (${f.unit})` : ""}`;
      let input;
      if (f.values) {  // allowed values: a choice, not free text
        input = document.createElement("select");
        for (const value of f.values) {
          const option = document.createElement("option");
          option.value = option.textContent = String(value);
          input.appendChild(option);
        }
        input.dataset.type = f.type;
      } else {
        input = document.createElement("input");
        input.type = f.type === "number" || f.type === "integer" ? "number" : "text";
        if (input.type === "number") input.step = f.type === "integer" ? "1" : "any";
      }
      input.name = name;
      input.required = true;
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
      form.classList.add("tried");  // fields turn red only once a Send found them wrong
      if (!form.checkValidity()) {
        form.reportValidity();  // refused in the page: the server checks again
        $("answer").textContent = `${event}: refused: a value is missing or out of range`;
        $("answer").className = "refused";
        return;
      }
      const payload = {};
      for (const input of form.querySelectorAll("input, select")) {
        const number = input.type === "number" || ["number", "integer"].includes(input.dataset.type);
        payload[input.name] = number ? Number(input.value) : input.value;
      }
      send(event, payload);
    };
    button.addEventListener("click", submit);
    form.addEventListener("submit", submit);
    holder.appendChild(form);
  }
}

function buildPlots(plots) {
  const holder = $("plots");
  holder.hidden = !plots.length;
  holder.innerHTML = plots.map((p) => `<canvas id="plot-${p.id}" width="640" height="160"></canvas>`).join("");
}

function loadScript(url) {
  return new Promise((resolve, reject) => {
    const script = document.createElement("script");
    script.src = url;
    script.onload = resolve;
    script.onerror = () => reject(new Error(`cannot load ${url}`));
    document.body.appendChild(script);
  });
}

async function loadLayout() {
  try {
    layout = await (await fetch("/api/layout")).json();
  } catch (err) {
    $("answer").textContent = `cannot load the page's layout: ${err}`;
    return;
  }
  buildButtons(layout.buttons);
  buildForms(layout.forms);
  buildPlots(layout.plots);
  for (const panel of layout.panels) {
    try {
      for (const url of panel.scripts) await loadScript(url);
      if (fwPanels[panel.name] && fwPanels[panel.name].init) fwPanels[panel.name].init($("panels"));
    } catch (err) {
      $("panels").insertAdjacentHTML("beforeend", `<section class="bad">panel ${panel.name}: ${err}</section>`);
    }
  }
  if (lastState) render({ ...lastState, log: undefined });
}

async function loadChart() {
  try {
    const chart = await (await fetch("/api/chart")).json();
    idents = chart.idents || {};
    $("chart-svg").innerHTML = chart.svg || `<p>${chart.error || "no chart"}</p>`;
    if (lastState) highlight((lastState.chart && lastState.chart.data && lastState.chart.data.active) || []);
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

function plotOn(canvas, series, labels, colors, unit) {
  // a rolling line plot: series.t (s) against series.values (one list per line)
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const t = series.t;
  if (t.length < 2) return;
  const values = series.values.flat().filter(Number.isFinite);
  let lo = Math.min(...values), hi = Math.max(...values);
  if (hi - lo < 1e-6) { lo -= 1; hi += 1; }
  const x = (v) => 40 + (v - t[0]) / (t[t.length - 1] - t[0] || 1) * (canvas.width - 50);
  const y = (v) => canvas.height - 20 - (v - lo) / (hi - lo) * (canvas.height - 35);
  ctx.fillStyle = "#94a3b8"; ctx.font = "11px sans-serif";
  ctx.fillText(`${hi.toFixed(1)} ${unit}`, 2, 12);
  ctx.fillText(`${lo.toFixed(1)} ${unit}`, 2, canvas.height - 22);
  ctx.fillText(`last ${(t[t.length - 1] - t[0]).toFixed(0)} s`, canvas.width - 60, canvas.height - 5);
  let labelX = 45;
  series.values.forEach((column, k) => {
    ctx.strokeStyle = colors[k]; ctx.lineWidth = 1.5; ctx.beginPath();
    column.forEach((v, i) => (i ? ctx.lineTo(x(t[i]), y(v)) : ctx.moveTo(x(t[i]), y(v))));
    ctx.stroke();
    ctx.fillStyle = colors[k]; ctx.fillText(labels[k], labelX, 12);
    labelX += ctx.measureText(labels[k]).width + 14;
  });
}


$("details").addEventListener("change", (e) => $("log").classList.toggle("details", e.target.checked));

// `?snapshot`: the state once, no stream, so the page finishes loading and a headless
// browser (chromium --headless --screenshot) can take a picture of it for a bug report
const snapshot = new URLSearchParams(location.search).has("snapshot");

async function once() {
  try {
    render(await (await fetch("/api/state")).json());
    $("link").textContent = `snapshot of ${new Date().toLocaleTimeString()} (not live)`;
    $("link").className = "badge";
  } catch (err) {
    $("link").textContent = `cannot load the state: ${err}`;
  }
  document.body.dataset.snapshot = "ready";
}

loadLayout().then(async () => {
  if (snapshot) { await loadChart(); await once(); } else { loadChart(); connect(); }
});
