// The process map: one point per weld run (x a process parameter, y a signature figure, a third
// as colour), IQR bars, the power law through them, outliers ringed; a click opens the run's
// timeline at its first unstable frame. Drawn on a canvas, so the PNG is the canvas itself.

import { api, ApiError, query } from "./api.js";
import { ticks, format } from "./chart.js";
import { decimal } from "./format.js";
import { h } from "./ui.js";

const X = ["heat_input_j_mm", "voltage_v", "current_a", "wire_feed_m_min", "robot_speed_cm_min", "arc_length_correction_pct", "wire_per_travel"];
const Y = ["width_mm", "length_mm", "area_mm2", "width_iqr_mm", "length_iqr_mm", "area_iqr_mm2", "width_cv", "oscillation_hz", "oscillation_strength", "unstable_frames"];
const NAMES = {
  heat_input_j_mm: "heat input U·I/v (J/mm)", voltage_v: "voltage (V)", current_a: "current (A)", wire_feed_m_min: "wire feed (m/min)",
  robot_speed_cm_min: "travel speed (cm/min)", arc_length_correction_pct: "arc length correction (%)", wire_per_travel: "wire per travel (m/m)",
  width_mm: "width (mm)", length_mm: "length (mm)", area_mm2: "area (mm²)", width_iqr_mm: "width IQR (mm)", length_iqr_mm: "length IQR (mm)",
  area_iqr_mm2: "area IQR (mm²)", width_cv: "width CV", oscillation_hz: "oscillation (Hz)", oscillation_strength: "oscillation strength", unstable_frames: "unstable frames",
};
const $ = (id) => document.getElementById(id);
const state = { x: "heat_input_j_mm", y: "width_mm", color: "oscillation_hz", log: false, map: null, hits: [] };

function fillPickers() {
  const params = new URLSearchParams(location.search);
  for (const key of ["x", "y", "color"]) if (params.get(key)) state[key] = params.get(key);
  const options = (names, chosen, none = false) => [
    ...(none ? [h("option", { value: "" }, "none")] : []),
    ...names.map((n) => h("option", { value: n, ...(n === chosen ? { selected: "" } : {}) }, NAMES[n])),
  ];
  $("pick-x").replaceChildren(...options(X, state.x));
  $("pick-y").replaceChildren(...options(Y, state.y));
  $("pick-color").replaceChildren(...options([...Y, ...X], state.color, true));
}

/** A colour from blue (low) to red (high) for a value in [lo, hi]. */
function ramp(value, lo, hi) {
  if (value === null || !Number.isFinite(value)) return "#adb5bd";
  const t = hi > lo ? (value - lo) / (hi - lo) : 0.5;
  return `hsl(${Math.round(220 - 220 * t)} 70% 45%)`;
}

function scale(values, log) {
  let lo = Math.min(...values), hi = Math.max(...values);
  if (log) { lo = Math.log10(lo); hi = Math.log10(hi); }
  const pad = (hi - lo) * 0.08 || Math.abs(hi) * 0.1 || 1;
  return { lo: lo - pad, hi: hi + pad, f: log ? Math.log10 : (v) => v };
}

function draw() {
  const canvas = $("plot");
  const ratio = window.devicePixelRatio || 1;
  const width = canvas.clientWidth, height = canvas.clientHeight;
  canvas.width = width * ratio; canvas.height = height * ratio;
  const g = canvas.getContext("2d");
  g.setTransform(ratio, 0, 0, ratio, 0, 0);
  g.fillStyle = "#fff"; g.fillRect(0, 0, width, height);
  g.font = "13px system-ui, sans-serif";
  const points = state.map?.points ?? [];
  state.hits = [];
  if (!points.length) { g.fillStyle = "#868e96"; g.fillText("No run to draw: runs need the parameter and a signature (mm figures need a scale).", 20, 40); return; }
  const log = state.log && points.every((p) => p.x > 0 && p.y > 0 && (p.y_q1 ?? 1) > 0);
  const pad = { left: 70, right: 24, top: 20, bottom: 52 };
  const sxv = scale(points.map((p) => p.x), log);
  const syv = scale(points.flatMap((p) => [p.y, p.y_q1 ?? p.y, p.y_q3 ?? p.y]), log);
  const sx = (v) => pad.left + ((sxv.f(v) - sxv.lo) / (sxv.hi - sxv.lo)) * (width - pad.left - pad.right);
  const sy = (v) => height - pad.bottom - ((syv.f(v) - syv.lo) / (syv.hi - syv.lo)) * (height - pad.top - pad.bottom);
  g.strokeStyle = "#e9ecef"; g.fillStyle = "#495057"; g.lineWidth = 1;
  const axisTicks = (s) => (log ? ticks(s.lo, s.hi, 5).map((t) => 10 ** t) : ticks(s.lo, s.hi, 6));
  for (const t of axisTicks(syv)) {
    g.beginPath(); g.moveTo(pad.left, sy(t)); g.lineTo(width - pad.right, sy(t)); g.stroke();
    g.textAlign = "right"; g.fillText(format(Number(t.toPrecision(3))), pad.left - 8, sy(t) + 4);
  }
  for (const t of axisTicks(sxv)) {
    g.beginPath(); g.moveTo(sx(t), pad.top); g.lineTo(sx(t), height - pad.bottom); g.stroke();
    g.textAlign = "center"; g.fillText(format(Number(t.toPrecision(3))), sx(t), height - pad.bottom + 18);
  }
  g.fillStyle = "#212529"; g.textAlign = "center";
  g.fillText(NAMES[state.x] + (log ? " · log" : ""), pad.left + (width - pad.left - pad.right) / 2, height - 12);
  g.save(); g.translate(16, pad.top + (height - pad.top - pad.bottom) / 2); g.rotate(-Math.PI / 2);
  g.fillText(NAMES[state.y] + (log ? " · log" : ""), 0, 0); g.restore();
  const fit = state.map.fit;
  if (fit) {
    const xs = points.map((p) => p.x).filter((v) => v > 0);
    const [a, b] = [Math.min(...xs), Math.max(...xs)];
    g.strokeStyle = "#212529"; g.setLineDash([6, 4]); g.beginPath();
    for (let i = 0; i <= 60; i += 1) {
      const x = log ? 10 ** (Math.log10(a) + (i / 60) * (Math.log10(b) - Math.log10(a))) : a + (i / 60) * (b - a);
      const y = fit.a * x ** fit.b;
      if (i === 0) g.moveTo(sx(x), sy(y)); else g.lineTo(sx(x), sy(y));
    }
    g.stroke(); g.setLineDash([]);
  }
  const colours = points.map((p) => p.color).filter((v) => v !== null && Number.isFinite(v));
  const [clo, chi] = colours.length ? [Math.min(...colours), Math.max(...colours)] : [0, 1];
  for (const p of points) {
    const [x, y] = [sx(p.x), sy(p.y)];
    if (p.y_q1 !== null && p.y_q3 !== null) {
      g.strokeStyle = "#868e96"; g.lineWidth = 2; g.beginPath();
      g.moveTo(x, sy(p.y_q1)); g.lineTo(x, sy(p.y_q3));
      g.moveTo(x - 5, sy(p.y_q1)); g.lineTo(x + 5, sy(p.y_q1)); g.moveTo(x - 5, sy(p.y_q3)); g.lineTo(x + 5, sy(p.y_q3));
      g.stroke();
    }
    g.fillStyle = state.color ? ramp(p.color, clo, chi) : "#1c7ed6";
    g.beginPath(); g.arc(x, y, 7, 0, 2 * Math.PI); g.fill();
    if (p.outlier) { g.strokeStyle = "#c2255c"; g.lineWidth = 3; g.beginPath(); g.arc(x, y, 12, 0, 2 * Math.PI); g.stroke(); }
    if (p.unstable_frames) { g.fillStyle = "#c2255c"; g.fillRect(x - 7, y + 10, 14, 3); }
    g.fillStyle = "#343a40"; g.font = "12px system-ui, sans-serif";
    const label = p.name.length > 28 ? `${p.name.slice(0, 27)}…` : p.name;
    // A label that would run past the plot's right edge is written to the point's left.
    const leftward = x + 14 + g.measureText(label).width > width - pad.right;
    g.textAlign = leftward ? "right" : "left";
    g.fillText(label, leftward ? x - 14 : x + 14, y - 8);
    state.hits.push({ x, y, p });
  }
  if (state.color && colours.length) {
    g.font = "12px system-ui, sans-serif"; g.textAlign = "right"; g.fillStyle = "#495057";
    g.fillText(`colour: ${NAMES[state.color]} ${format(Number(clo.toPrecision(3)))} (blue) – ${format(Number(chi.toPrecision(3)))} (red)`, width - pad.right, pad.top + 12);
  }
}

const timelineUrl = (p) => `/sequences/${p.sequence_id}` + (p.first_unstable_frame_id ? `?frame=${p.first_unstable_frame_id}` : "");

function renderText() {
  const { fit, points, skipped } = state.map;
  $("fit").textContent = fit
    ? `Fit: ${NAMES[state.y]} = ${Number(fit.a.toPrecision(4))} · x^${decimal(fit.b, 3)} (b from ${fit.b_low === null ? "–" : decimal(fit.b_low, 3)} to ${fit.b_high === null ? "–" : decimal(fit.b_high, 3)}, 95 %), R² ${decimal(fit.r2, 3)} on ${fit.n} runs`
      + (fit.excluded.length ? `; ${fit.excluded.length} outlier(s) left out of the fit.` : ".")
    : "No fit: it needs two runs at different x with positive values.";
  $("skipped").textContent = skipped.length ? `Not drawn: ${skipped.map((s) => `${s.name} (${s.reason})`).join("; ")}.` : "";
  const rows = points.map((p) => h("tr", { "data-testid": "process-run" },
    h("td", {}, h("a", { href: timelineUrl(p) }, p.name)),
    h("td", {}, format(Number(p.x.toPrecision(4)))),
    h("td", {}, format(Number(p.y.toPrecision(4)))),
    h("td", {}, p.y_q1 === null ? "–" : `${format(Number(p.y_q1.toPrecision(3)))}–${format(Number(p.y_q3.toPrecision(3)))}`),
    h("td", { class: p.outlier ? "outlier" : "" }, p.residual_pct === null ? "–" : `${p.residual_pct >= 0 ? "+" : ""}${decimal(p.residual_pct, 1)} %${p.outlier ? " · outlier" : ""}`),
    h("td", {}, p.unstable_frames ? `${p.unstable_frames} unstable frames` : "steady")));
  $("runs").replaceChildren(h("table", { class: "runs" },
    h("thead", {}, h("tr", {}, ...["run", NAMES[state.x], NAMES[state.y], "IQR", "off the law", "stability"].map((t) => h("th", {}, t)))),
    h("tbody", {}, ...rows)));
}

async function load() {
  const params = { x: state.x, y: state.y, ...(state.color ? { color: state.color } : {}) };
  history.replaceState(null, "", `/process${query(params)}`);
  $("map-csv").href = `/api/v1/process-map${query({ ...params, format: "csv" })}`;
  try {
    state.map = await api(`/process-map${query(params)}`);
  } catch (error) {
    $("fit").textContent = error instanceof ApiError ? error.message : String(error);
    document.body.dataset.ready = "1";
    return;
  }
  draw();
  renderText();
  document.body.dataset.ready = "1";
}

fillPickers();
for (const [id, key] of [["pick-x", "x"], ["pick-y", "y"], ["pick-color", "color"]]) {
  $(id).addEventListener("change", (event) => { state[key] = event.target.value; load(); });
}
$("log-axes").addEventListener("change", (event) => { state.log = event.target.checked; draw(); });
$("plot").addEventListener("click", (event) => {
  const box = $("plot").getBoundingClientRect();
  const [cx, cy] = [event.clientX - box.left, event.clientY - box.top];
  const hit = state.hits.find(({ x, y }) => Math.hypot(x - cx, y - cy) <= 12);
  if (hit) location.href = timelineUrl(hit.p);
});
$("map-png").addEventListener("click", () => {
  $("plot").toBlob((blob) => {
    const link = h("a", { href: URL.createObjectURL(blob), download: `process-map-${state.x}-${state.y}.png` });
    link.click();
    setTimeout(() => URL.revokeObjectURL(link.href), 1000);
  }, "image/png");
});
window.addEventListener("resize", draw);
load();
