// Live view: start a student on a camera, stream or video on the server; watch the frame with
// its mask outline and keypoints (MJPEG), the pool's geometry as it scrolls, fps and latency.

import { api, isReviewer } from "./api.js";
import { leastSpan, lineChart } from "./chart.js";
import { count, decimal, gateLine } from "./format.js";
import { badge, h, toast } from "./ui.js";

const $ = (id) => document.getElementById(id);
const SHOWN_FRAMES = 300;
const ACTIVE = new Set(["starting", "running"]);
const histories = new Map(); // view id → records kept for the curves
const cards = new Map(); // view id → { card, image, stats, charts, keypoints, stop }

function statsLine(view) {
  const parts = [
    view.fps !== null ? `${decimal(view.fps, 1)} fps` : "",
    view.latency_p50_ms !== null ? `latency p50 ${decimal(view.latency_p50_ms, 1)} ms · p99 ${decimal(view.latency_p99_ms, 1)} ms` : "",
    count(view.frames, "frame"),
    view.dropped ? `${count(view.dropped, "stale frame")} dropped to keep up` : "none dropped",
  ].filter(Boolean);
  return parts.join(" · ") + (view.message ? ` — ${view.message}` : "");
}

function geometryCharts(view) {
  const rows = histories.get(view.id) ?? [];
  const mm = view.mm_per_px !== null;
  const series = (key, colour) => [{ name: key, colour, points: rows.map((r) => [r.frame, r[key] ?? NaN]) }];
  const chart = (title, key, unit, colour) => h("figure", { class: "chart-box" },
    lineChart({ title, unit, xLabel: "frame", width: 360, height: 150, series: series(key, colour),
      minSpan: leastSpan(rows.map((r) => r[key] ?? NaN), unit) }));
  return mm
    ? [chart("Pool area", "area_mm2", "mm²", "#1c7ed6"), chart("Length", "length_mm", "mm", "#2f9e44"), chart("Width", "width_mm", "mm", "#e8590c")]
    : [chart("Pool area", "area_px", "px²", "#1c7ed6"), chart("Length", "length_px", "px", "#2f9e44"), chart("Width", "width_px", "px", "#e8590c")];
}

function keypointTable(view) {
  const last = view.last;
  if (!last) return h("p", { class: "muted" }, "No frame yet.");
  const rows = (last.keypoints ?? []).map((p, i) => h("tr", {},
    h("th", {}, String(i + 1)),
    h("td", { class: "num" }, p ? decimal(p[0], 1) : "–"),
    h("td", { class: "num" }, p ? decimal(p[1], 1) : "–")));
  return h("table", { class: "metrics", "data-testid": "live-keypoints" },
    h("thead", {}, h("tr", {}, h("th", {}, "keypoint"), h("th", {}, "x px"), h("th", {}, "y px"))),
    h("tbody", {}, rows),
    h("tfoot", {}, h("tr", {}, h("th", {}, "ambiguity"), h("td", { class: "num", colspan: "2" }, decimal(last.ambiguity, 3))),
      h("tr", {}, h("th", { title: "The width's rolling coefficient of variation over 0.5 s; unstable over 8 %" }, "width CV"),
        h("td", { class: "num", colspan: "2", "data-testid": "live-stability" },
          last.stability_cv === null || last.stability_cv === undefined ? "–" : `${decimal(100 * last.stability_cv, 1)} %${last.unstable ? " · unstable" : ""}`))));
}

const OUTPUT_NAMES = { zeromq: "ZeroMQ", opcua: "OPC UA", mqtt: "MQTT" };

function outputsLine(view) {
  if (!view.outputs?.length) {
    return h("p", { class: "muted small-text", "data-testid": "live-outputs" },
      "Outputs: none (give ZeroMQ, OPC UA or MQTT addresses when starting a view).");
  }
  const listener = (o) => o.subscribers === null ? "" : ` · ${count(o.subscribers, o.kind === "opcua" ? "subscription" : "subscriber")}`;
  const item = (o) => h("li", { "data-testid": `live-output-${o.kind}` },
    h("strong", {}, OUTPUT_NAMES[o.kind] ?? o.kind), ` ${o.address} · ${o.state}${listener(o)} · ${count(o.sent, "frame")} sent`,
    o.skipped ? ` · ${count(o.skipped, "skipped")}` : "",
    o.added_p99_ms !== null ? ` · +${decimal(o.added_p99_ms, 2)} ms to the wire (p99)` : "");
  return h("ul", { class: "live-output-list small-text", "data-testid": "live-outputs" }, view.outputs.map(item));
}

const ENDED = {
  stopped: "This view is stopped: it no longer runs.",
  ended: "The source ended: the view no longer runs.",
  failed: "This view failed and no longer runs",
};

/** What the frame's place says while no frame is shown: the student being prepared (a version's
 * first start exports it to ONNX, which takes a while), the source opening, or the view no
 * longer running (never a broken image). Null while frames come. */
export function framePlaceholder(view) {
  if (ACTIVE.has(view.state)) {
    if (view.frames > 0) return null;
    const seconds = Math.max(0, Math.round((Date.now() - Date.parse(view.started_at)) / 1000));
    const preparing = /onnx|export|preparing/i.test(view.message ?? "");
    const exporting = /export/i.test(view.message ?? "");
    return {
      title: exporting ? "Preparing the student (exporting it to ONNX)…" : preparing ? "Preparing the student…" : "Starting…",
      detail: preparing
        ? `The first start of a version exports it for ONNX Runtime once: ${seconds} s so far, up to a minute on a CPU.`
        : `${view.message ? `${view.message[0].toUpperCase()}${view.message.slice(1)}` : "Waiting for the first frame"} (${seconds} s so far).`,
      busy: true,
    };
  }
  const again = isReviewer() ? " Start it again above." : "";
  const detail = view.state === "failed" ? `${ENDED.failed}: ${view.message}` : `${ENDED[view.state] ?? `The view is ${view.state}.`}${again}`;
  return { title: view.state === "failed" ? "Failed" : view.state === "ended" ? "Ended" : "Stopped", detail, busy: false };
}

function showFrame(entry, view) {
  const shown = framePlaceholder(view);
  if (!ACTIVE.has(view.state) && entry.image.hasAttribute("src")) {
    entry.image.removeAttribute("src"); // the stream has ended: no broken image left behind
  }
  entry.image.hidden = shown !== null; // no frame yet, or none any more: the placeholder says why
  entry.placeholder.hidden = shown === null;
  if (shown) {
    entry.placeholder.dataset.state = view.state;
    entry.placeholder.replaceChildren(h("strong", {}, shown.title), h("span", {}, shown.detail),
      shown.busy ? h("div", { class: "progress indeterminate", role: "progressbar", "aria-label": shown.title }, h("div", { class: "fill" })) : "");
  }
}

async function stop(view, button) {
  button.disabled = true;
  try {
    await api(`/live/${view.id}/stop`, { method: "POST" });
    toast(`Live view ${view.id} stopped.`, "info");
  } catch (error) {
    toast(error.message, "error");
  }
  refresh();
}

function card(view) {
  let entry = cards.get(view.id);
  if (!entry) {
    const image = h("img", { class: "live-frame", alt: `Live frame of ${view.source}`, "data-testid": "live-frame" });
    if (ACTIVE.has(view.state)) image.src = `/api/v1/live/${view.id}/mjpeg`;
    entry = {
      image,
      placeholder: h("div", { class: "live-placeholder", "data-testid": "live-placeholder", hidden: "" }),
      state: h("span", {}),
      stats: h("p", { class: "muted", "data-testid": "live-stats" }),
      outputs: h("div", {}),
      charts: h("div", { class: "charts" }),
      keypoints: h("div", {}),
      stop: h("button", { type: "button", class: "secondary", "data-testid": "live-stop" }, "Stop"),
    };
    entry.stop.addEventListener("click", () => stop(view, entry.stop));
    entry.card = h("article", { class: "live-card", "data-testid": "live-card", "data-view-id": String(view.id) },
      h("header", {},
        h("h2", {}, `${view.model_name}${view.sequential ? " (sequential)" : ""}${view.int8 ? " (int8)" : ""} on ${view.source}`),
        entry.state,
        h("span", { class: "spacer" }),
        isReviewer() ? entry.stop : ""),
      gateLine(view.gate),
      entry.stats,
      entry.outputs,
      h("div", { class: "live-body" },
        h("div", { class: "live-frame-box" }, image, entry.placeholder),
        h("div", { class: "live-side" }, entry.keypoints)),
      entry.charts);
    cards.set(view.id, entry);
  }
  entry.state.replaceChildren(badge(view.state, `state-${view.state}`));
  entry.card.dataset.state = view.state;
  entry.stats.textContent = statsLine(view);
  entry.outputs.replaceChildren(outputsLine(view));
  entry.stop.hidden = !ACTIVE.has(view.state);
  showFrame(entry, view);
  entry.keypoints.replaceChildren(keypointTable(view));
  entry.charts.replaceChildren(...geometryCharts(view));
  return entry.card;
}

async function pullRecords(view) {
  const kept = histories.get(view.id) ?? [];
  const after = kept.length ? kept[kept.length - 1].frame : -1;
  const { records } = await api(`/live/${view.id}/records?after=${after}&limit=300`);
  histories.set(view.id, kept.concat(records).slice(-SHOWN_FRAMES));
}

async function refresh() {
  let views;
  try {
    views = await api("/live");
  } catch (error) {
    $("views").replaceChildren(h("p", { class: "error" }, error.message));
    return;
  }
  await Promise.all(views.filter((v) => ACTIVE.has(v.state) || !histories.has(v.id)).map((v) => pullRecords(v).catch(() => {})));
  $("views").replaceChildren(...(views.length
    ? views.map(card)
    : [h("p", { class: "muted", "data-testid": "live-empty" }, "No live view yet. Give a source and start one: the promoted student runs on it here, on the server.")]));
  document.body.dataset.ready = "1";
}

async function fillModels() {
  const select = document.querySelector('#live-form select[name="model_id"]');
  if (!select) return;
  const wanted = new URLSearchParams(location.search).get("model_id");
  try {
    const models = await api("/models");
    const note = (m) => (m.is_promoted ? " (promoted)" : "") + (m.sequential ? ", sequential cell" : "") + (m.int8 ? ", int8" : "") + (m.gate?.usable === false ? " — not usable (promotion gate)" : "");
    select.append(...models.map((m) => h("option", { value: String(m.id) }, `${m.name}${note(m)}`)));
    if (wanted) select.value = wanted;
    const box = document.querySelector('#live-form input[name="sequential"]');
    const int8Box = document.querySelector('#live-form input[name="int8"]');
    const chosen = () => models.find((m) => (select.value ? String(m.id) === select.value : m.is_promoted));
    const follow = () => {
      const model = chosen();
      if (!model?.sequential) box.checked = false;
      if (!model?.int8) int8Box.checked = false;
      box.disabled = !model?.sequential || int8Box.checked;
      int8Box.disabled = !model?.int8 || box.checked;
      box.parentElement.title = model?.sequential
        ? `${model.name}'s sequential cell keeps a state from frame to frame: a steadier mask and keypoints (measured on the models page).`
        : `${model?.name ?? "This version"} has no sequential cell; train one on the models page.`;
      int8Box.parentElement.title = model?.int8
        ? `${model.name}'s int8 student: ${model.int8.int8_ms.toFixed(1)} ms a frame against ${model.int8.float_ms.toFixed(1)} ms, masks at IoU ${model.int8.mean_iou.toFixed(3)} with the float student's. Frame by frame: not with sequential.`
        : `${model?.name ?? "This version"} has no int8 student; make one on the models page.`;
    };
    select.addEventListener("change", follow);
    box.addEventListener("change", follow);
    int8Box.addEventListener("change", follow);
    follow();
  } catch (error) {
    toast(error.message, "error");
  }
}

$("live-form")?.addEventListener("submit", async (event) => {
  event.preventDefault();
  const form = event.target;
  const data = new FormData(form);
  const button = form.querySelector('button[type="submit"]');
  button.disabled = true;
  try {
    const view = await api("/live", {
      method: "POST",
      json: {
        source: data.get("source").trim(),
        model_id: data.get("model_id") ? Number(data.get("model_id")) : null,
        smooth: data.get("smooth") === "on",
        sequential: data.get("sequential") === "on",
        int8: data.get("int8") === "on",
        mm_per_px: data.get("mm_per_px") ? Number(data.get("mm_per_px")) : null,
        zeromq: data.get("zeromq")?.trim() || null,
        opcua: data.get("opcua")?.trim() || null,
        mqtt: data.get("mqtt")?.trim() || null,
      },
    });
    toast(`Live view ${view.id} started.`, "ok");
  } catch (error) {
    toast(error.message, "error");
  } finally {
    button.disabled = false;
  }
  refresh();
});

fillModels();
refresh();
setInterval(refresh, 1000);
