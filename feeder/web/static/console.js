// The feeder operator's console (docs/console.md).  Talks to the daemon's /api with the token
// from the address' fragment (#token=...), which it then removes from the address bar.
"use strict";

const TOKEN_KEY = "feeder-console-token";
const UM = 1e6, DEG = 180 / Math.PI;
const $ = (id) => document.getElementById(id);

function takeToken() {
  const match = location.hash.match(/token=([^&]+)/);
  if (match) {
    sessionStorage.setItem(TOKEN_KEY, decodeURIComponent(match[1]));
    history.replaceState(null, "", location.pathname + location.search);
  }
  return sessionStorage.getItem(TOKEN_KEY) || "";
}
const token = takeToken();

// what the tests read: live view redraws, camera frames, new statuses received, pose overlay lag (ms)
window.consoleStats = { draws: 0, frames: 0, statuses: 0, lagsMs: [] };

let status = null;          // the newest status
let statusTime = 0;         // its snapshot's wall time (s)
let drawn = -1;             // statusTime of the last drawn status
let camera = null;          // {bitmap, width_px, height_px}: the newest frame, the camera's image size
let target = null;          // {x, y, angle} (m, m, rad) or null
let drag = null;
let trajectory = [];        // [t_s, x_m, y_m, psi_rad] of the current or last move
let lastState = null;
let cameraProgress = null;  // the camera calibration's step last shown
let cameraAnswered = false; // this page has its calibration's answer: statuses still moving are older

// -- API ---------------------------------------------------------------------------------
async function api(method, path, body) {
  const init = { method, headers: { Authorization: "Bearer " + token } };
  if (body !== undefined) {
    init.headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  let response;
  try {
    response = await fetch(path, init);
  } catch (err) {
    say("daemon unreachable: " + err.message, true);
    return null;
  }
  const answer = await response.json().catch(() => ({ ok: false, error: response.statusText }));
  if (response.status === 401) refused(answer.error);
  else if (!answer.ok) say(answer.error || response.statusText, true);
  return answer;
}

function say(text, bad) {
  $("message").textContent = text;
  $("message").className = bad ? "fault" : "hint";
}

function refused(text) {
  $("auth").style.display = "block";
  if (text) $("auth-text").textContent = text;
  $("state").textContent = "not authorised";
  $("state").className = "offline";
}

// -- live state ------------------------------------------------------------------------------
function connect() {
  const scheme = location.protocol === "https:" ? "wss://" : "ws://";
  const ws = new WebSocket(scheme + location.host + "/api/live");
  ws.binaryType = "blob";
  ws.onopen = () => ws.send(JSON.stringify({ token }));
  ws.onmessage = async (event) => {
    if (typeof event.data !== "string") {
      const bitmap = await createImageBitmap(event.data);
      if (camera && camera.bitmap) camera.bitmap.close();
      camera = { ...camera, bitmap, fresh: true };
      window.consoleStats.frames += 1;
      schedule();
      return;
    }
    const message = JSON.parse(event.data);
    if (message.type === "error") refused(message.error);
    else if (message.type === "frame") camera = { ...camera, width_px: message.width_px, height_px: message.height_px };
    else if (message.type === "status") {
      status = message.status;
      if (message.time_s !== statusTime) window.consoleStats.statuses += 1;
      statusTime = message.time_s;
      onStatus();
      schedule();
    }
  };
  ws.onclose = (event) => {
    if (event.code === 4401) { refused("The daemon refused the token."); return; }
    $("state").textContent = "offline";
    $("state").className = "offline";
    setTimeout(connect, 1000);
  };
}

let scheduled = false;
function schedule() {
  if (scheduled) return;
  scheduled = true;
  requestAnimationFrame(() => {
    scheduled = false;
    drawView();
    if (status && statusTime !== drawn) {
      drawn = statusTime;
      const stats = window.consoleStats;
      stats.draws += 1;
      stats.lagsMs.push(Date.now() - statusTime * 1000);
      if (stats.lagsMs.length > 500) stats.lagsMs.shift();
    }
  });
}

// -- click to set the target position, drag to set its angle ----------------------------------
function canvasPoint(event) {
  const canvas = $("view"), box = canvas.getBoundingClientRect();
  return [(event.clientX - box.left) * canvas.width / box.width, (event.clientY - box.top) * canvas.height / box.height];
}

$("view").addEventListener("pointerdown", (event) => {
  const f = frame($("view"));
  const [px, py] = canvasPoint(event);
  const [x, y] = f.toPlate(px, py);
  const part = parts().find((p) => p.id === selectedPart());
  target = { x, y: hasPoses() ? y : 0, angle: part ? part.pose[2] : 0 };
  drag = [px, py];
  $("view").setPointerCapture(event.pointerId);
  showTarget();
});
$("view").addEventListener("pointermove", (event) => {
  if (!drag || !hasPoses()) return;
  const [px, py] = canvasPoint(event);
  if (Math.hypot(px - drag[0], py - drag[1]) < 6) return;
  target.angle = Math.atan2(-(py - drag[1]), px - drag[0]);
  showTarget();
});
$("view").addEventListener("pointerup", () => { drag = null; });

function showTarget() {
  $("target-x").value = (target.x * UM).toFixed(1);
  $("target-y").value = (target.y * UM).toFixed(1);
  $("target-angle").value = (target.angle * DEG).toFixed(2);
  schedule();
}
for (const id of ["target-x", "target-y", "target-angle"]) {
  $(id).addEventListener("input", () => {
    target = { x: Number($("target-x").value) / UM, y: Number($("target-y").value) / UM, angle: Number($("target-angle").value) / DEG };
    schedule();
  });
}

const selectedPart = () => Number($("part").value) || 1;

$("move").addEventListener("click", async () => {
  if (!target) { say("click the plate to set a target first", true); return; }
  const request = hasPoses()
    ? { x_m: target.x, y_m: target.y, angle_rad: target.angle, part: selectedPart(), wait: false }
    : { target_m: target.x, wait: false };
  const answer = await api("POST", "/api/move", request);
  if (answer && answer.ok) say(`moving to ${(target.x * UM).toFixed(1)} µm`);
});

async function stop() {
  const answer = await api("POST", "/api/stop");
  if (answer && answer.ok) say(answer.stopped ? "stopped" : "nothing to stop");
}
$("stop").addEventListener("click", stop);
document.addEventListener("keydown", (event) => { if (event.key === "Escape") stop(); });

$("release").addEventListener("click", async () => {
  const answer = await api("POST", "/api/release", { part: Number($("part").value) });
  if (answer && answer.ok) say(answer.released.length ? `released part ${answer.released.join(", ")}` : "that part was not held");
});

$("calibrate").addEventListener("click", async () => {
  const answer = await api("POST", "/api/calibrate", { steps: Number($("cal-steps").value), wait: false });
  if (answer && answer.ok) say("calibrating");
});

$("calibrate-camera").addEventListener("click", async () => {
  const request = { save: $("cam-save").checked };  // an empty field: the daemon's default
  for (const [id, key] of [["cam-volts", "volts"], ["cam-increment", "increment_v"], ["cam-frames", "frames"]]) {
    if ($(id).value !== "") request[key] = key === "frames" ? Math.round(Number($(id).value)) : Number($(id).value);
  }
  if ($("cam-gain").value !== "") {
    const gain = Number($("cam-gain").value);
    if (!(gain > 0)) return say("stack gain must be a positive number of nm/V (the plate's move per volt)", true);
    request.stack_gain_m_per_v = gain * 1e-9;
  }
  say("calibrating the camera: the plate moves by offsets along x, y and θ (STOP ends it)");
  $("camera-result").textContent = "";
  $("calibrate-camera").disabled = true;
  try {
    showCameraAnswer(await api("POST", "/api/calibrate_camera", request));
  } finally {
    $("calibrate-camera").disabled = false;
  }
});

function showCameraAnswer(answer) {  // this page's calibration ended: its report, or api's error
  cameraAnswered = true;
  if (answer && answer.ok) {
    say("camera calibrated");
    $("camera-result").innerHTML = cameraReport(answer.calibration).map((l) => `<div>${escapeHtml(l)}</div>`).join("");
  }
}

function showCameraProgress() {
  // each new step once; its end clears a step still shown (another page's calibration). The
  // answer comes over HTTP, the statuses over the WebSocket: one taken before the answer may
  // arrive after it, and must not bring a step (and then "ended") back over the answer.
  const progress = (status.camera_moves && status.camera_moves_progress) || null;
  if (!status.camera_moves) cameraAnswered = false;
  if (progress === cameraProgress || cameraAnswered) { cameraProgress = progress; return; }
  if (progress) say(`calibrating the camera: ${progress} (STOP ends it)`);
  else if ($("message").textContent.startsWith("calibrating the camera:")) say("the camera calibration ended");
  cameraProgress = progress;
}

function cameraReport(c) {  // the daemon's calibrate_camera report, as lines
  const px = (v) => (v === null || v === undefined ? "–" : v.toFixed(1));
  const origin = c.origin_x_px === null || c.origin_x_px === undefined
    ? "O not measured (no θ axis moved)"
    : `O at (${px(c.origin_x_px)}, ${px(c.origin_y_px)}) px ± ${px(c.origin_uncertainty_px)} px`;
  const lines = [
    `${(c.pixel_size_m * UM).toFixed(4)} µm/px, turned ${deg(c.rotation_rad)}${c.mirrored ? ", mirrored" : ""}`,
    `${origin}; the parts came back within ${c.returned_px.toFixed(3)} px`,
    c.saved ? "stored: parts are located with it from the next move on" : "not stored" + (c.slipped ? ": the parts slipped" : c.travel_outside ? ": " + c.travel_outside : ""),
  ];
  return lines.concat(c.warnings || []);
}

function jog(axis, sign) {
  const steps = sign * Math.max(1, Math.round(Number($("jog-steps").value)));
  api("POST", "/api/jog", { axis, steps, part: selectedPart() }).then((answer) => {
    if (answer && answer.ok) say(`jog ${axis} ${steps > 0 ? "+" : ""}${steps} steps`);
  });
}

// -- panels ------------------------------------------------------------------------------------
const um = (m) => (m === null || m === undefined ? "–" : (m * UM).toFixed(2) + " µm");
const deg = (rad) => (rad === null || rad === undefined ? "–" : (rad * DEG).toFixed(3) + "°");

function axisNames() { return hasPoses() && status.axes ? Object.keys(status.axes) : ["x"]; }

function onStatus() {
  const state = status.camera_moves ? "calibrating" : status.state;  // the camera's: the plate moves, no job
  showCameraProgress();
  $("state").textContent = (status.camera_moves ? "calibrating camera" : state) + (status.position_state === "uncertain" ? " (position uncertain)" : "");
  $("state").className = state;
  const part = parts().find((p) => p.id === selectedPart()) || parts()[0];
  $("position").textContent = part ? `part ${part.id}: x ${um(part.pose[0])}` + (hasPoses() ? `, y ${um(part.pose[1])}, ${deg(part.pose[2])}` : "") : "position unknown";
  for (const el of document.querySelectorAll(".pose-only")) el.hidden = !hasPoses();
  for (const el of document.querySelectorAll(".line-only")) el.hidden = hasPoses();  // calibrate: a line job
  for (const el of document.querySelectorAll(".camera-only")) el.hidden = !(hasPoses() && status.camera_calibration);
  updatePartChoice();
  updateAxes(part);
  updateCalibration();
  updateFaults();
  updateResult();
  if (state === "moving" || state === "calibrating") {
    if (lastState !== state) trajectory = [];
    if (part) trajectory.push([statusTime, ...part.pose]);
  } else if (lastState === "moving" || lastState === "calibrating") {
    loadHistory(true);
    drawTrajectory();
  }
  if (trajectory.length % 5 === 1) drawTrajectory();
  lastState = state;
}

function updatePartChoice() {
  // a held part (a move brought it to its target; later moves keep it there) says so
  const held = new Set((status.held || []).map((h) => h.part));
  const labels = parts().map((p) => [String(p.id), held.has(p.id) ? `${p.id} (held)` : String(p.id)]);
  const select = $("part");
  if ([...select.options].map((o) => o.value + "=" + o.text).join() === labels.map((l) => l.join("=")).join()) return;
  const chosen = select.value;
  select.replaceChildren(...labels.map(([id, label]) => new Option(label, id)));
  if (labels.some(([id]) => id === chosen)) select.value = chosen;
}

function updateAxes(part) {
  const rows = [];
  const names = axisNames();
  if (jogAxes !== names.join()) buildJog(names);
  for (const axis of names) {
    let position = "–", goal = "–", forward = "–", backward = "–";
    if (hasPoses()) {
      const a = status.axes[axis] || {};
      const index = { x: 0, y: 1, theta: 2 }[axis];
      const show = axis === "theta" ? deg : um;
      if (part && index !== undefined) position = show(part.pose[index]);
      const t = part && status.target_part === part.id ? status.target_pose : null;  // the running pose move's
      if (t && index !== undefined) goal = show(t[index]);
      const own = axis === "theta" && part ? part : a;  // θ's step is the part's own (where it turns)
      forward = a.step_m !== undefined ? um(a.step_m) : own.step_rad !== undefined ? deg(own.step_rad) : summary(a);
      backward = a.step_back_m !== undefined ? um(a.step_back_m) : own.step_back_rad !== undefined ? deg(own.step_back_rad) : "–";
    } else {
      position = um(status.position_m);
      goal = um(status.target_m);
      const e = status.estimates || {};
      forward = e["coarse/forward"] ? um(e["coarse/forward"].step_m) : "–";
      backward = e["coarse/backward"] ? um(e["coarse/backward"].step_m) : "–";
    }
    rows.push(`<tr><td>${axis}</td><td>${position}</td><td>${goal}</td><td>${forward}</td><td>${backward}</td></tr>`);
  }
  $("axes").tBodies[0].innerHTML = rows.join("");
}

function summary(obj) {
  return escapeHtml(Object.entries(obj).filter(([, v]) => typeof v !== "object").map(([k, v]) => `${k} ${typeof v === "number" ? v.toPrecision(3) : v}`).join(", ")) || "–";
}

let jogAxes = "";
function buildJog(names) {
  jogAxes = names.join();
  $("jog").replaceChildren(...names.map((axis) => {
    const row = document.createElement("div");
    row.className = "row";
    const minus = document.createElement("button"), plus = document.createElement("button");
    minus.textContent = `${axis} −N`;
    plus.textContent = `${axis} +N`;
    minus.dataset.jog = `${axis}-`;
    plus.dataset.jog = `${axis}+`;
    minus.onclick = () => jog(axis, -1);
    plus.onclick = () => jog(axis, 1);
    row.append(minus, plus);
    return row;
  }));
}

function updateCalibration() {
  const lines = [];
  const estimates = status.estimates || {};
  if (estimates.gains) {  // the plane: the planar plant's predicted steps times learned gains
    for (const [name, g] of Object.entries(estimates.gains)) {
      if (!g.bursts) continue;
      const low = Math.min(...g.gain), high = Math.max(...g.gain);
      const gain = low === high ? `×${low.toFixed(3)}` : `×${low.toFixed(3)}…${high.toFixed(3)} over ${g.radii_m.length} radii`;
      lines.push(`${name}: the model's step ${gain}, learned from ${g.bursts} bursts`);
    }
    const station = estimates.station_radius_m;  // where θ turns a part: at O, or on a circle about it
    if (station !== undefined) lines.push(station > 0 ? `θ turns parts ${um(station)} from O` : "θ turns parts in place at O");
  } else {
    for (const [name, e] of Object.entries(estimates)) {
      lines.push(`${name}: ${um(e.step_m)} ± ${um(e.std_m)} per step, learned from ${e.steps} steps`);
    }
  }
  const cal = status.camera_calibration;
  lines.push(cal ? `camera: ${(cal.pixel_size_m * UM).toFixed(3)} µm/px, rotation ${deg(cal.rotation_rad || 0)}` + (cal.source === "configuration" ? ` (from the configuration; ${hasPoses() ? "Calibrate camera" : "feeder vision calibrate"} measures it)` : "") : "camera: not calibrated (feeder vision calibrate)");
  $("calibration").innerHTML = lines.map((l) => `<div>${escapeHtml(l)}</div>`).join("");
}

const ADVICE = [
  [/embedded simulator .* died/i, "The simulated amplifier and camera (firmware_sim) stopped; the daemon starts a new one by itself. No move resumes: send it again."],
  [/not calibrated|measured no plate moves/i, "Moves wait for the camera's calibration: Calibrate camera (with your stacks' gain; store checked), or feeder vision calibrate-moves --daemon --save-state (docs/vision.md); or set [camera] aligned = true if the image's axes are the plate's."],
  [/amplifier/i, "Output grounded. Check the amplifier's cable and power; the daemon reconnects by itself. No move resumes: send it again."],
  [/sensor|camera/i, "The position sensor stopped sending. Check the camera's cable or stream; the daemon reconnects by itself."],
  [/unwritable|disk/i, "The state database cannot be written (disk full or read-only?). Free space; moves are refused until then."],
];
const RESULT_ADVICE = {
  stalled: "The part did not move: check it lies on the plate and nothing blocks it; then move again (one axis: calibrate).",
  limit: "The target is beyond the travel: choose one inside the dashed box.",
  oscillating: "The part overshoots back and forth: move again (the steps learned so far help; one axis: calibrate), or ask for a larger tolerance.",
  unreachable: "The daemon cannot reach it within its bursts: calibrate, or choose a target the part can reach.",
  fault: "The move ended on a fault: a lost link (see Faults), or a command the amplifier refused (the reason above).",
  stopped: "Stopped on request.",
};

function updateFaults() {
  const items = [];
  const current = status.fault ? [status.fault] : [];
  if (status.store_unwritable) current.push("state store unwritable: " + status.store_unwritable);
  if (status.moves_refused) current.push("moves refused: " + status.moves_refused);
  if (status.sensor_noise_warning) current.push(status.sensor_noise_warning);
  if (status.stack_warning) current.push(status.stack_warning);
  for (const text of current) items.push([text, true]);
  for (const f of (status.faults || []).slice(-5).reverse()) {
    const back = f.reconnected_after_attempts ? ` (back after ${f.reconnected_after_attempts} attempts)` : f.last_error ? ` (retrying: ${f.last_error})` : "";
    items.push([`${new Date(f.time_s * 1000).toLocaleTimeString()} ${f.link}: ${f.message}${back}`, false]);
  }
  if (status.position_state === "uncertain") items.push(["position uncertain: waiting for the sensor to confirm it", true]);
  $("faults").innerHTML = items.length ? items.map(([text, now]) => {
    const advice = (ADVICE.find(([re]) => re.test(text)) || [null, ""])[1];
    return `<div class="${now ? "fault" : ""}">${escapeHtml(text)}</div>` + (now && advice ? `<div class="advice">${escapeHtml(advice)}</div>` : "");
  }).join("") : "none";
}

function updateResult() {
  const r = status.last_result;
  if (!r) return;
  const error = r.error_m !== undefined && r.error_m !== null ? ` error ${um(r.error_m)}` : "";
  const angle = r.error_rad !== undefined && r.error_rad !== null ? `, ${deg(r.error_rad)}` : "";
  const text = `${r.kind} ${r.status}: ${r.reason}.${error}${angle}, ${r.steps} steps in ${r.bursts} bursts, ${(r.duration_s || 0).toFixed(2)} s`;
  const advice = r.status === "done" ? "" : RESULT_ADVICE[r.status] || "";
  $("result").innerHTML = `<div class="result-status" data-status="${escapeHtml(r.status)}">${escapeHtml(text)}</div>` + (advice ? `<div class="advice">${escapeHtml(advice)}</div>` : "");
}

function escapeHtml(text) {
  return String(text).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" }[c]));
}

// -- plots ----------------------------------------------------------------------------------------
function plot(canvas, series, xLabel) {
  // series: [{points: [[x, y]...], color, dots}]
  const ctx = canvas.getContext("2d"), w = canvas.width, h = canvas.height, m = 40;
  ctx.clearRect(0, 0, w, h);
  const all = series.flatMap((s) => s.points);
  ctx.fillStyle = "#666";
  ctx.font = "11px system-ui";
  if (all.length === 0) { ctx.fillText("no data yet", w / 2 - 30, h / 2); return; }
  let [x0, x1] = [Math.min(...all.map((p) => p[0])), Math.max(...all.map((p) => p[0]))];
  let [y0, y1] = [Math.min(...all.map((p) => p[1])), Math.max(...all.map((p) => p[1]))];
  if (x1 === x0) x1 = x0 + 1;
  if (y1 === y0) { y0 -= 1; y1 += 1; }
  const X = (x) => m + (x - x0) / (x1 - x0) * (w - m - 10), Y = (y) => h - 20 - (y - y0) / (y1 - y0) * (h - 30);
  ctx.strokeStyle = "#ccc";
  ctx.strokeRect(m, 10, w - m - 10, h - 30);
  ctx.fillText(y1.toPrecision(3), 2, 14);
  ctx.fillText(y0.toPrecision(3), 2, h - 20);
  ctx.fillText(xLabel, w / 2 - 20, h - 4);
  for (const s of series) {
    ctx.strokeStyle = ctx.fillStyle = s.color;
    ctx.beginPath();
    s.points.forEach(([x, y], i) => {
      if (s.dots) ctx.fillRect(X(x) - 2, Y(y) - 2, 4, 4);
      else i ? ctx.lineTo(X(x), Y(y)) : ctx.moveTo(X(x), Y(y));
    });
    if (!s.dots) ctx.stroke();
  }
}

async function loadHistory(aMoveEnded = false) {
  // a move that just ended: its record is finished by the daemon's writer thread, which a loaded
  // machine may leave behind the status saying idle; ask again (10 × 0.5 s) while the newest
  // record still reads "running"
  for (let tries = 0; tries < (aMoveEnded ? 10 : 1); tries += 1) {
    if (tries) await new Promise((done) => setTimeout(done, 500));
    const answer = await api("GET", "/api/history?limit=50");
    if (!answer || !answer.ok) return;
    // the recorded error: along x on one axis (signed), the centre's distance from the target in the plane
    const moves = answer.moves.filter((m) => m.error_m !== null && m.error_m !== undefined);
    const points = moves.map((m) => [m.id, m.error_m * UM]);
    window.consoleStats.history = points;
    plot($("history"), [{ points, color: "#1565c0", dots: true }], "move id");
    if (!answer.moves.length || answer.moves[0].status !== "running") return;
  }
}

function drawTrajectory() {
  const t0 = trajectory.length ? trajectory[0][0] : 0;
  const series = [{ points: trajectory.map((p) => [p[0] - t0, p[1] * UM]), color: "#1565c0" }];
  if (hasPoses()) series.push({ points: trajectory.map((p) => [p[0] - t0, p[2] * UM]), color: "#2e7d32" });
  plot($("trajectory"), series, "time (s)" + (hasPoses() ? ": x blue, y green" : ""));
}

connect();
loadHistory();
drawTrajectory();
