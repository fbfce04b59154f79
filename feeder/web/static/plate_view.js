// The console's plate view (docs/console.md): the model the page draws (parts with poses, the
// travel), the plate (m) ↔ canvas (px) frame, and the drawing of parts, target and camera image.
// Loaded before console.js, whose state (status, camera, target, trajectory) and helpers ($, UM,
// DEG, selectedPart) it uses when called, never at load.
"use strict";

// -- the model the page draws: parts with poses, travel -------------------------------------
function partSize(label) {  // "300x300x50" (µm) → [L, W] (m)
  const dims = String(label || "300x300").split("x").map(Number);
  return [dims[0] / UM, (dims[1] || dims[0]) / UM];
}

function parts() {
  if (!status) return [];
  if (hasPoses()) return (status.parts || []).filter((p) => p.pose);
  const x = status.position_m ?? status.last_known_position_m;
  if (x === null || x === undefined) return [];
  const info = (status.parts && status.parts[0]) || {};
  return [{ shape: "rectangle", size_m: partSize(status.part), ...info, id: 1, pose: [x, 0, 0] }];
}

// a plane (more than one axis): poses, pose moves; else one axis: position_m, target_m
const hasPoses = () => Boolean(status && status.axes && Object.keys(status.axes).length > 1);

function travel() {
  if (status && status.travel_m) return { x: status.travel_m.x, y: status.travel_m.y };
  const [lo, hi] = (status && status.travel_limits_m) || [-5e-3, 5e-3];
  return { x: [lo, hi], y: [-(hi - lo) / 2, (hi - lo) / 2] };
}

function frame(canvas) {  // plate (m) ↔ canvas (px): square, the travel plus a margin
  const t = travel();
  const span = 1.1 * Math.max(t.x[1] - t.x[0], t.y[1] - t.y[0]);
  const cx = (t.x[0] + t.x[1]) / 2, cy = (t.y[0] + t.y[1]) / 2;
  const scale = canvas.width / span;
  return {
    scale,
    toPx: (x, y) => [(x - cx) * scale + canvas.width / 2, canvas.height / 2 - (y - cy) * scale],
    toPlate: (px, py) => [cx + (px - canvas.width / 2) / scale, cy + (canvas.height / 2 - py) / scale],
  };
}

// -- the plate view ------------------------------------------------------------------------------
function drawView() {
  const canvas = $("view"), ctx = canvas.getContext("2d");
  const f = frame(canvas);
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  ctx.fillStyle = "#37474f";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  drawCamera(ctx, f);
  const t = travel();
  const [ax, ay] = f.toPx(t.x[0], t.y[1]), [bx, by] = f.toPx(t.x[1], t.y[0]);
  ctx.strokeStyle = "#90a4ae";
  ctx.setLineDash([6, 4]);
  ctx.strokeRect(ax, ay, bx - ax, by - ay);
  ctx.setLineDash([]);
  const [ox, oy] = f.toPx(0, 0);
  ctx.strokeStyle = "#b0bec5";
  ctx.beginPath();
  ctx.moveTo(ox - 8, oy); ctx.lineTo(ox + 8, oy); ctx.moveTo(ox, oy - 8); ctx.lineTo(ox, oy + 8);
  ctx.stroke();
  if (trajectory.length > 1) {
    ctx.strokeStyle = "#ffca28";
    ctx.beginPath();
    trajectory.forEach(([, x, y], i) => { const [px, py] = f.toPx(x, y); i ? ctx.lineTo(px, py) : ctx.moveTo(px, py); });
    ctx.stroke();
  }
  for (const part of parts()) drawPart(ctx, f, part, "#4fc3f7", "rgba(79,195,247,0.35)", String(part.id));
  if (target) {
    const part = parts().find((p) => p.id === selectedPart()) || parts()[0];
    const ghost = { ...(part || { shape: "rectangle", size_m: partSize() }), pose: [target.x, target.y, target.angle] };
    drawPart(ctx, f, ghost, "#ff7043", "rgba(255,112,67,0.15)", "target");
  }
}

function drawPart(ctx, f, part, stroke, fill, label) {
  const [x, y, psi] = part.pose;
  const [px, py] = f.toPx(x, y);
  const [length, width] = (part.size_m || partSize()).map((s) => Math.max(4, s * f.scale));
  ctx.save();
  ctx.translate(px, py);
  ctx.rotate(-psi);
  ctx.fillStyle = fill;
  ctx.strokeStyle = stroke;
  ctx.lineWidth = 2;
  ctx.beginPath();
  if (part.shape === "disc") ctx.arc(0, 0, length / 2, 0, 2 * Math.PI);
  else ctx.rect(-length / 2, -width / 2, length, width);
  ctx.fill();
  ctx.stroke();
  ctx.beginPath();  // heading mark: the part's +x
  ctx.moveTo(0, 0);
  ctx.lineTo(Math.max(length / 2, 10), 0);
  ctx.stroke();
  ctx.restore();
  ctx.fillStyle = stroke;
  ctx.font = "12px system-ui";
  ctx.fillText(`${label} (${(x * UM).toFixed(1)}, ${(y * UM).toFixed(1)}) µm ${(psi * DEG).toFixed(2)}°`, px + 10, py - 10);
}

function drawCamera(ctx, f) {
  // with a stored camera calibration the image is drawn in plate coordinates; without, beside
  const cal = status && status.camera_calibration;
  const note = $("camera-note"), side = $("camera");
  if (!camera || !camera.bitmap) { note.textContent = ""; side.hidden = true; return; }
  const b = camera.bitmap;
  if (!cal || !cal.pixel_size_m) {
    side.hidden = false;
    if (!camera.fresh) return;
    camera.fresh = false;
    const height = Math.round(side.width * b.height / b.width);
    if (side.height !== height) side.height = height;
    side.getContext("2d").drawImage(b, 0, 0, side.width, side.height);
    note.textContent = "camera (not registered to the plate: no camera calibration; run feeder vision calibrate)";
    return;
  }
  side.hidden = true;
  note.textContent = "";
  // image px (full resolution) → plate: inverse of CameraCalibration.to_image
  const shrink = (camera.width_px || b.width) / b.width;
  const c = Math.cos(cal.rotation_rad || 0), s = Math.sin(cal.rotation_rad || 0);
  const flip = cal.mirrored ? -1 : 1, p = cal.pixel_size_m;
  // plate = R^-1 (u - u0) p with R = [[c, -s flip], [s, c flip]]: R^-1 = [[c, s], [-s flip, c flip]]
  const a11 = c * p, a12 = s * p, a21 = -s * flip * p, a22 = c * flip * p;
  const u0 = cal.origin_x_px || 0, v0 = cal.origin_y_px || 0;
  const [tx, ty] = f.toPx(0, 0);
  const k = f.scale * shrink;
  ctx.save();
  // canvas = toPx(plate) = (x k' + tx, -y k' + ty), plate = A (u shrink - u0)
  ctx.setTransform(a11 * k, -a21 * k, a12 * k, -a22 * k,
    tx - f.scale * (a11 * u0 + a12 * v0), ty + f.scale * (a21 * u0 + a22 * v0));
  ctx.drawImage(b, 0, 0);
  ctx.restore();
}
