// The SEEG panel of the operator console (components/supervisor/panel): the 3D view of
// robot and people (a perspective camera orbiting the table, capsules drawn as thick
// round-capped lines, depth-sorted, no library), the TCP's position and speed, and the
// reaction latencies measured live. Registers fwPanels.seeg = {init, render}.
"use strict";

const camera = { yaw: 0.4, pitch: 0.35, distance: 3.0, center: [0.6, 0.0, 0.5] };

function project(p, canvas) {
  const [cx, cy, cz] = camera.center;
  const x = p[0] - cx, y = p[1] - cy, z = p[2] - cz;
  const cyw = Math.cos(camera.yaw), syw = Math.sin(camera.yaw);
  const cp = Math.cos(camera.pitch), sp = Math.sin(camera.pitch);
  const xr = cyw * x - syw * y;           // turn about the vertical axis
  const yr = syw * x + cyw * y;
  const depth = camera.distance + cp * yr + sp * z;  // then tilt
  const up = cp * z - sp * yr;
  const f = canvas.height * 1.1 / Math.max(depth, 0.05);
  return { x: canvas.width / 2 + xr * f, y: canvas.height / 2 - up * f, depth, f };
}

function capsule(ctx, canvas, c, color) {
  const a = project(c.slice(0, 3), canvas), b = project(c.slice(3, 6), canvas);
  ctx.strokeStyle = color;
  ctx.lineCap = "round";
  ctx.lineWidth = Math.max(1, 2 * c[6] * (a.f + b.f) / 2);
  ctx.beginPath();
  ctx.moveTo(a.x, a.y);
  ctx.lineTo(b.x, b.y);
  ctx.stroke();
}

function marker(ctx, at, color, label) {
  // a tracked tool: a dot and its name
  ctx.fillStyle = color;
  ctx.beginPath(); ctx.arc(at.x, at.y, 4, 0, 2 * Math.PI); ctx.fill();
  ctx.font = "11px sans-serif";
  ctx.fillText(label, at.x + 7, at.y - 6);
}

function drawScene(state) {
  const canvas = document.getElementById("scene");
  const distance = state.min_distance ? state.min_distance.data : null;
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  ctx.strokeStyle = "#334155";  // the floor, 0.5 m grid
  ctx.lineWidth = 1;
  for (let i = -3; i <= 3; i++) {
    for (const [p, q] of [[[i / 2 + 0.6, -1.5, 0], [i / 2 + 0.6, 1.5, 0]], [[-0.9, i / 2, 0], [2.1, i / 2, 0]]]) {
      const a = project(p, canvas), b = project(q, canvas);
      ctx.beginPath(); ctx.moveTo(a.x, a.y); ctx.lineTo(b.x, b.y); ctx.stroke();
    }
  }
  const scene = (state.scene && state.scene.data) || { robot: [], people: [] };
  const supervisor = (state.supervisor && state.supervisor.data) || {};
  const items = [];
  for (const c of scene.robot) items.push([c, distance !== null && distance !== undefined && distance < 0.1 ? "#ef4444" : "#60a5fa"]);
  for (const person of scene.people) for (const c of person.capsules) items.push([c, "rgba(251,146,60,0.8)"]);
  items.sort((u, v) => (project(v[0].slice(0, 3), canvas).depth - project(u[0].slice(0, 3), canvas).depth));
  for (const [c, color] of items) capsule(ctx, canvas, c, color);
  const patient = state.patient && state.patient.data;
  if (patient) {  // the patient's head around its reference tool (a 9 cm sphere)
    const p = project(patient, canvas);
    ctx.fillStyle = "rgba(148,163,184,0.25)";
    ctx.beginPath(); ctx.arc(p.x, p.y, Math.max(4, 0.09 * p.f), 0, 2 * Math.PI); ctx.fill();
    marker(ctx, p, "#4ade80", "reference tool");
  }
  const trace = (state.trace && state.trace.data) || [];
  if (trace.length) marker(ctx, project(trace[trace.length - 1].slice(1, 4), canvas), "#22d3ee", "tool (TCP)");
  if (supervisor.target) {  // the target and its critical sphere
    const t = project(supervisor.target, canvas);
    ctx.strokeStyle = "#f87171";
    ctx.lineWidth = 1.5;
    ctx.beginPath(); ctx.arc(t.x, t.y, Math.max(2, supervisor.critical_radius * t.f), 0, 2 * Math.PI); ctx.stroke();
    ctx.fillStyle = "#f87171";
    ctx.beginPath(); ctx.arc(t.x, t.y, 3, 0, 2 * Math.PI); ctx.fill();
  }
  const stale = !state.scene || state.scene.age === null || state.scene.age > 2;
  ctx.fillStyle = stale ? "#f87171" : "#94a3b8";
  ctx.font = "12px sans-serif";
  const n = scene.people.length;
  const people = n === 0 ? "nobody in the room" : n === 1 ? "1 person in the room" : `${n} people in the room`;
  ctx.fillText(stale ? "no scene from the people detector (stale)" : people, 10, 18);
}

function drawPlots(state) {
  const trace = (state.trace && state.trace.data) || [];
  const t = trace.map((r) => r[0]);
  const first = trace[0] || [0, 0, 0, 0];  // positions relative to the window's start
  plotOn(document.getElementById("plot-position"), { t, values: [0, 1, 2].map((i) => trace.map((r) => (r[1 + i] - first[1 + i]) * 1000)) },
    ["Δx mm", "Δy mm", "Δz mm"], ["#f87171", "#4ade80", "#60a5fa"], "mm");
  const speed = trace.map((r, i) => i === 0 ? 0 : Math.hypot(r[1] - trace[i - 1][1], r[2] - trace[i - 1][2], r[3] - trace[i - 1][3]) / Math.max(r[0] - trace[i - 1][0], 1e-3) * 100);
  plotOn(document.getElementById("plot-speed"), { t, values: [speed] }, ["TCP speed cm/s"], ["#facc15"], "cm/s");
}

function drawLatencies(state) {
  // reaction latencies measured live (STOP sent -> braking, sensor swap), newest right
  const canvas = document.getElementById("plot-latency");
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const items = (state.latencies && state.latencies.data) || [];
  ctx.fillStyle = "#94a3b8"; ctx.font = "11px sans-serif";
  if (!items.length) { ctx.fillText("reaction latencies: none yet (a STOP or a tracker swap)", 10, 16); return; }
  const hi = Math.max(...items.map((i) => i.ms), 1);
  const colors = { "STOP sent -> braking": "#f87171", "sensor swap": "#4ade80" };
  ctx.fillText(`${hi.toFixed(1)} ms`, 2, 12);
  ctx.fillText("0 ms", 2, canvas.height - 5);
  items.forEach((item, i) => {
    const x = 45 + i * (canvas.width - 55) / Math.max(items.length - 1, 1);
    const y = canvas.height - 10 - item.ms / hi * (canvas.height - 25);
    ctx.fillStyle = colors[item.kind] || "#facc15";
    ctx.beginPath(); ctx.arc(x, y, 4, 0, 2 * Math.PI); ctx.fill();
  });
  Object.entries(colors).forEach(([kind, color], k) => {
    const last = items.filter((i) => i.kind === kind).pop();
    ctx.fillStyle = color;
    ctx.fillText(`${kind}${last ? `: ${last.ms.toFixed(2)} ms` : ""}`, 80 + 200 * k, 12);
  });
}

function orbit() {
  const canvas = document.getElementById("scene");
  let drag = null;
  canvas.addEventListener("mousedown", (e) => { drag = [e.clientX, e.clientY]; });
  window.addEventListener("mouseup", () => { drag = null; });
  window.addEventListener("mousemove", (e) => {
    if (!drag) return;
    camera.yaw += (e.clientX - drag[0]) * 0.01;
    camera.pitch = Math.min(1.5, Math.max(-0.2, camera.pitch + (e.clientY - drag[1]) * 0.01));
    drag = [e.clientX, e.clientY];
    if (lastState) drawScene(lastState);
  });
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    camera.distance = Math.min(10, Math.max(1, camera.distance * (e.deltaY > 0 ? 1.1 : 0.9)));
    if (lastState) drawScene(lastState);
  });
}

fwPanels.seeg = {
  init(container) {
    container.insertAdjacentHTML("beforeend", `
      <section id="view" aria-label="3D view">
        <canvas id="scene" width="640" height="420" data-testid="scene"></canvas>
        <p class="hint">drag to turn · wheel to zoom · blue: robot · orange: people · grey: the patient's head, green its reference tool · cyan: the tool at the TCP · red: target and its critical sphere</p>
      </section>
      <section id="seeg-plots" aria-label="SEEG plots">
        <canvas id="plot-position" width="640" height="200"></canvas>
        <canvas id="plot-speed" width="640" height="150"></canvas>
        <canvas id="plot-latency" width="640" height="150" data-testid="latency"></canvas>
      </section>`);
    orbit();
  },
  render(state) {
    drawScene(state);
    drawPlots(state);
    drawLatencies(state);
  },
};
