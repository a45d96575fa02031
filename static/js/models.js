// The models page: every student version with its metrics and training curves, the promote
// button, and (for reviewers) starting a training job.

import { api, ApiError, isReviewer, waitForJob } from "./api.js";
import { count, forced, gateLine, int8Line, metric, metricName, sequentialLine } from "./format.js";
import { lineChart } from "./chart.js";
import { classesTable } from "./model_classes.js";
import { badge, formatDate, h, progressBar, toast } from "./ui.js";

const list = document.getElementById("models");
const PALETTE = ["#d9480f", "#1971c2", "#2f9e44", "#9c36b5", "#e8590c"];


/** The curve's quantities grouped into small charts: losses, mIoU, mED, then anything else. */
export function curveCharts(curve) {
  const keys = [...new Set(curve.flatMap((row) => Object.keys(row)))].filter((k) => k !== "epoch");
  const groups = [
    { title: "Loss", keys: keys.filter((k) => /loss/i.test(k)) },
    { title: "Validation mIoU", keys: keys.filter((k) => /miou/i.test(k)), domain: [0, 1] },
    { title: "Validation mED", keys: keys.filter((k) => /med/i.test(k)), unit: "px" },
  ];
  const used = new Set(groups.flatMap((g) => g.keys));
  for (const key of keys.filter((k) => !used.has(k))) groups.push({ title: metricName(key), keys: [key] });
  return groups.filter((g) => g.keys.length).map((g) => lineChart({
    title: g.title,
    unit: g.unit,
    domain: g.domain,
    series: g.keys.map((key, i) => ({
      name: metricName(key),
      colour: PALETTE[i % PALETTE.length],
      points: curve.filter((row) => typeof row[key] === "number").map((row) => [row.epoch, row[key]]),
    })),
    xLabel: "round", // as the training job says it ("keeps round 3 of 5"): one pass over the labels
  }));
}

/** Start a job (``start`` resolves to its ``{ job_id }``), follow it in the state line under the
 * page's title, and say how it ended. */
async function followJob(what, start) {
  const stateLine = document.getElementById("train-state");
  const { job_id: jobId } = await start();
  const link = () => h("a", { href: `/jobs?job=${jobId}` }, `#${jobId}`);
  stateLine.replaceChildren(`${what} job `, link(), " started.");
  const job = await waitForJob(jobId, (j) => {
    stateLine.replaceChildren(`${what} job `, link(), `: ${j.status}, ${Math.round(j.progress * 100)} % ${j.message ?? ""}`);
  }, 1500);
  toast(`${what} job #${jobId} ${job.status}${job.error ? `: ${job.error}` : ""}.`, job.status === "succeeded" ? "ok" : "error");
}

async function trainSequential(model, button) {
  if (!confirm(`Train a sequential cell for ${model.name}? It learns from the reviewed frames of imported videos (a few minutes on a CPU) and is measured against the per-frame student on the validation frames.`)) return;
  button.disabled = true;
  try {
    await followJob("Sequential cell", () => api(`/models/${model.id}/sequential`, { method: "POST", json: {} }));
  } catch (error) {
    toast(error.message, "error");
  } finally {
    button.disabled = false;
  }
  load();
}

async function makeInt8(model, button) {
  if (!confirm(`Make an int8 student for ${model.name}? It is calibrated on up to 64 frames spread over the project and kept only if its masks agree with the float student's on others (seconds to a minute on a CPU).`)) return;
  button.disabled = true;
  try {
    await followJob("int8 student", () => api(`/models/${model.id}/int8`, { method: "POST" }));
  } catch (error) {
    toast(error.message, "error");
  } finally {
    button.disabled = false;
  }
  load();
}

async function promote(model) {
  if (!confirm(`Promote ${model.name}? It is measured against the promoted version and the teacher first.`)) return;
  try {
    await api(`/models/${model.id}/promote`, { method: "POST" });
    toast(`${model.name} is promoted: it scores the review queue; the review shows it where it beats the teacher.`, "ok");
  } catch (error) {
    if (error instanceof ApiError && error.status === 409) {
      const reason = error.body?.reason ?? error.message;
      if (confirm(`${model.name} did not pass the promotion gate: ${reason.replace(/\.$/, "")}.\n\n`
        + "Promote it anyway? It will then order the review queue and be the student the live view and "
        + "weldpool stream run by default (both say it did not pass); the review keeps showing the "
        + "teacher's proposals wherever they agree better with the reviewed labels.")) {
        try {
          await api(`/models/${model.id}/promote?force=true`, { method: "POST" });
          toast(`${model.name} is promoted by hand; the review keeps the teacher's proposals where they agree better.`, "info");
        } catch (again) { toast(again.message, "error"); }
      }
    } else {
      toast(error.message, "error");
    }
  }
  load();
}

export function modelCard(model) {
  const metrics = Object.entries(model.metrics ?? {}).filter(([name]) => name !== "classes"); // classesTable
  const charts = curveCharts(model.curve ?? []);
  return h("article", { class: `model-card${model.is_promoted ? " promoted" : ""}`, "data-testid": "model-card", "data-model-id": String(model.id) },
    h("header", {},
      h("h2", {}, model.name ?? `version ${model.id}`),
      model.is_promoted && !forced(model) ? badge("promoted") : "", // forced: the gate line says it
      h("span", { class: "spacer" }),
      isReviewer()
        ? h("button", { type: "button", class: "secondary", "data-testid": "train-sequential", title: "Train a recurrent cell on this version's latent from the reviewed frames of imported videos: steadier mask and keypoints in live views", onclick: (event) => trainSequential(model, event.currentTarget) }, model.sequential ? "Retrain sequential cell" : "Train sequential cell")
        : "",
      isReviewer()
        ? h("button", { type: "button", class: "secondary", "data-testid": "make-int8", title: "Quantize this version to int8 for ONNX Runtime: faster live inference on a CPU, checked against the float student", onclick: (event) => makeInt8(model, event.currentTarget) }, model.int8 ? "Remake int8" : "Make int8")
        : "",
      isReviewer()
        ? h("a", { class: "button secondary", href: `/live?model_id=${model.id}`, "data-testid": "live-view", title: "Run this version on a camera, stream or video and watch its mask and keypoints live" }, "Live view")
        : "",
      isReviewer() && !model.is_promoted
        ? h("button", { type: "button", class: "secondary", "data-testid": "promote", onclick: () => promote(model) }, "Promote")
        : ""),
    gateLine(model.gate, model.is_promoted),
    sequentialLine(model.sequential),
    int8Line(model.int8),
    h("p", { class: "muted" },
      `trained on ${count(model.train_label_count ?? 0, "label")} · ${formatDate(model.created_at)}`,
      model.job_id ? [" · ", h("a", { href: `/jobs?job=${model.job_id}` }, `job #${model.job_id}`)] : ""),
    h("div", { class: "model-body" },
      h("table", { class: "metrics" },
        h("tbody", {}, metrics.length
          ? metrics.map(([name, value]) => h("tr", {}, h("th", { title: name }, metricName(name)), h("td", { class: "num" }, metric(name, value))))
          : h("tr", {}, h("td", { class: "muted" }, "no metrics recorded")))),
      classesTable(model),
      h("div", { class: "charts" }, charts.length ? charts : h("p", { class: "muted" }, "no training curve recorded"))),
  );
}

function emptyState(note) {
  return h("div", { class: "empty-state", "data-testid": "models-empty" },
    h("h2", {}, "No models yet"),
    h("p", {}, "A student version appears here after its training job has run on the reviewed labels (accepted and corrected frames of the train split)."),
    h("p", { class: "muted" }, isReviewer() ? "Start one with “Train a new version”." : "A reviewer can start training."),
    note ? h("p", { class: "muted small-text" }, note) : "");
}

async function load() {
  let models;
  try {
    models = await api("/models");
  } catch (error) {
    const missing = error instanceof ApiError && error.status === 404;
    list.replaceChildren(emptyState(missing ? "This server has no model registry yet." : error.message));
    document.body.dataset.ready = "1";
    return;
  }
  const items = Array.isArray(models) ? models : models?.items ?? [];
  list.replaceChildren(...(items.length ? items.map(modelCard) : [emptyState("")]));
  document.body.dataset.ready = "1";
}

const trainForm = document.getElementById("train-form");
const trainButton = trainForm?.querySelector("button[type=submit]");
const TRAIN_TITLE = trainButton?.title ?? "";
let followed = null; // the training job this page follows, wherever it was started

/** Who started a training job, in words. */
const starter = (job) => (job.params?.automatic ? "the automatic retrain" : job.created_by ?? "the system");

/** The running training in the state line, and the train button disabled while it runs (one
 * training at a time): started here, in another tab, by another person or by the retrain. */
function showTraining(job) {
  const stateLine = document.getElementById("train-state");
  const link = h("a", { href: `/jobs?job=${job.id}` }, `#${job.id}`);
  const percent = Math.round((job.progress ?? 0) * 100);
  stateLine.replaceChildren(`Training job `, link, ` (started by ${starter(job)}): ${job.status}, ${percent} %${job.message ? ` · ${job.message}` : ""}`,
    job.status === "running" || job.status === "queued" ? progressBar(job.progress ?? 0, `${percent} %`) : "");
  if (!trainButton) return;
  const busy = job.status === "running" || job.status === "queued";
  trainButton.disabled = busy;
  trainButton.title = busy ? `Training job #${job.id} is ${job.status}; one training runs at a time: wait for it to finish.` : TRAIN_TITLE;
}

/** Follow a training job to its end, then say how it ended and show the new version. */
async function followTraining(jobId) {
  if (followed === jobId) return;
  followed = jobId;
  try {
    const job = await waitForJob(jobId, showTraining, 1500);
    toast(`Training job #${jobId} ${job.status}${job.error ? `: ${job.error}` : ""}.`, job.status === "succeeded" ? "ok" : "error");
  } catch (error) {
    toast(error.message, "error");
  } finally {
    followed = null;
    if (trainButton) { trainButton.disabled = false; trainButton.title = TRAIN_TITLE; }
  }
  load();
}

/** A training queued or running now (at most one is), wherever it was started: followed here. */
async function findTraining() {
  if (followed !== null || document.hidden) return;
  try {
    const page = await api(`/jobs?kind=train_student&limit=1`);
    const job = page.items?.[0];
    if (job && (job.status === "queued" || job.status === "running")) followTraining(job.id);
  } catch { /* the next look tries again */ }
}

/** Ask before a training the promotion gate could not measure (too few labels). */
async function planAllows() {
  const plan = await api("/student/training-plan");
  if (!plan.warning || plan.labels + plan.held_out === 0) return true;
  return confirm(`${plan.warning}\n\nTrain on ${count(plan.labels, "label")} anyway?`);
}

trainForm?.addEventListener("submit", async (event) => {
  event.preventDefault();
  const epochs = Number(trainForm.elements.epochs.value);
  trainButton.disabled = true;
  let jobId = null;
  try {
    if (!(await planAllows())) return;
    const body = epochs > 0 ? { epochs } : {};
    if (trainForm.elements.pseudo_labels?.checked) body.pseudo_labels = true;
    ({ job_id: jobId } = await api("/student/train", { method: "POST", json: body }));
  } catch (error) {
    const missing = error instanceof ApiError && error.status === 404;
    toast(missing ? "This server cannot train students yet (no /api/v1/student/train)." : error.message, "error");
  } finally {
    if (jobId === null) trainButton.disabled = false;
  }
  if (jobId !== null) followTraining(jobId);
});

load();
findTraining();
setInterval(findTraining, 4000);
