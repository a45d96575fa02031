// Uploads: frames dropped or chosen are sent a few per request with per-file progress; a video
// waits for "Import" with its frame count and sampling step; the step is remembered.

import { upload, waitForJob } from "../api.js";
import { count, decimal, everyNth } from "../format.js";
import { formatBytes, h, progressBar, setProgress } from "../ui.js";
import { probeVideo } from "../video.js";
import { changed } from "./state.js";

const VIDEO = /\.(mp4|avi)$/i;

const uploadList = document.getElementById("upload-list");

function uploadItem(file) {
  const bar = progressBar(0, file.name);
  const result = h("span", { class: "result muted" }, "waiting");
  const item = h("li", { "data-testid": "upload-item", "data-name": file.name },
    h("span", { class: "name" }, file.name), h("span", { class: "muted size" }, formatBytes(file.size)), bar, result);
  uploadList.prepend(item);
  return {
    progress: (fraction) => { setProgress(bar, fraction); result.textContent = `${Math.round(fraction * 100)} %`; },
    offer: (node) => { result.replaceChildren(...(node ? [node] : [])); item.dataset.state = node ? "offered" : "sending"; },
    done: (text, kind) => {
      setProgress(bar, 1);
      item.classList.add(kind);
      item.dataset.state = kind;
      result.className = `result ${kind}`;
      result.textContent = text;
    },
  };
}

/** The run an upload goes to: the dropzone's own choice (set from the list's filter, shown). */
function targetSequence() {
  return document.getElementById("upload-sequence").value;
}

const BATCH_FILES = 8;
const BATCH_BYTES = 64 * 1024 * 1024;
const byName = (a, b) => a.name.localeCompare(b.name, undefined, { numeric: true });

/** Frames in one request, in order (so their ids follow the file order); each item its result. */
async function uploadFrames(batch) {
  const form = new FormData();
  for (const { file } of batch) form.append("files", file, file.name);
  const sequence = targetSequence();
  if (sequence) form.append("sequence_id", sequence);
  const { status, body } = await upload("/frames", form, (fraction) => batch.forEach(({ item }) => item.progress(fraction)));
  const stored = new Map((body?.stored ?? []).map((f) => [f.original_name, f]));
  const duplicates = new Map((body?.duplicates ?? []).map((d) => [d.name, d]));
  const rejected = new Map((body?.rejected ?? []).map((r) => [r.name, r]));
  const elsewhere = new Map((body?.also_in ?? []).map((a) => [a.frame_id, a]));
  const where = (a) => (a.sequence_name ? `run “${a.sequence_name}”` : "no run");
  for (const { file, item } of batch) {
    const frame = stored.get(file.name);
    const also = frame && elsewhere.get(frame.id);
    if (also) item.done(`stored as frame #${frame.id}; also in ${where(also)} as frame #${also.other_frame_id}`, "ok");
    else if (frame) item.done(`stored as frame #${frame.id}`, "ok");
    else if (duplicates.has(file.name)) item.done(`already stored as frame #${duplicates.get(file.name).frame_id}`, "duplicate");
    else if (rejected.has(file.name)) item.done(`refused: ${rejected.get(file.name).reason}`, "refused");
    else item.done(`refused: ${body?.detail ?? `the server answered ${status}`}`, "refused");
  }
}

/** A video waits for "Import": its frame count (read from its header) and the sampling step
 * show how many frames it will add before anything is uploaded. */
async function offerVideo(file) {
  const item = uploadItem(file);
  const probe = await probeVideo(file);
  const step = h("input", { type: "number", min: "1", value: String(nthValue()), class: "tiny", "data-testid": "video-every-nth", "aria-label": "keep one frame in" });
  const estimate = h("span", { "data-testid": "video-estimate" });
  const show = () => {
    const n = Math.max(1, Math.round(Number(step.value) || 1));
    estimate.textContent = probe
      ? `${count(probe.frames, "frame")} at ${decimal(probe.fps, 1)} fps (${decimal(probe.duration_s, 1)} s) → ${count(Math.ceil(probe.frames / n), "frame")} kept`
      : "frame count unknown until imported";
  };
  step.addEventListener("input", show);
  show();
  const importButton = h("button", { type: "button", class: "primary small", "data-testid": "video-import" }, "Import");
  const skip = h("button", { type: "button", class: "quiet small" }, "Skip");
  item.offer(h("span", { class: "video-offer" }, "keep one frame in ", step, estimate, importButton, skip));
  await new Promise((resolve) => {
    importButton.addEventListener("click", () => resolve(true), { once: true });
    skip.addEventListener("click", () => { item.done("skipped", "duplicate"); resolve(false); }, { once: true });
  }).then(async (go) => {
    if (!go) return;
    item.offer(null);
    try {
      await uploadVideo(file, item, Math.max(1, Math.round(Number(step.value) || 1)));
    } catch (error) {
      item.done(`failed: ${error.message}`, "refused");
    }
    await Promise.all([changed("sequences"), changed("frames")]);
  });
}

async function uploadVideo(file, item, everyNthFrame) {
  const form = new FormData();
  form.append("file", file, file.name);
  form.append("every_nth", String(everyNthFrame));
  const sequence = targetSequence();
  if (sequence) form.append("sequence_id", sequence);
  const { status, body } = await upload("/videos", form, item.progress);
  if (status !== 202) return item.done(`refused: ${body?.detail ?? `the server answered ${status}`}`, "refused");
  item.progress(0);
  const job = await waitForJob(body.job_id, (state) => item.progress(state.progress), 1000);
  if (job.status === "succeeded") {
    const extracted = job.result?.stored ?? job.result?.frames ?? "";
    item.done(`extracted ${extracted} frames (job #${job.id})`.replace("  ", " "), "ok");
  } else {
    item.done(`video job #${job.id} ${job.status}: ${job.error ?? ""}`, "refused");
  }
}

async function uploadAll(files) {
  const all = [...files];
  const images = all.filter((file) => !VIDEO.test(file.name)).sort(byName);
  all.filter((file) => VIDEO.test(file.name)).sort(byName).reverse().forEach(offerVideo);
  // Listed first file on top; sent in name order, a few per request.
  const queue = images.map((file) => ({ file }));
  for (const entry of [...queue].reverse()) entry.item = uploadItem(entry.file);
  let batch = [];
  let bytes = 0;
  const flush = async () => {
    if (!batch.length) return;
    try { await uploadFrames(batch); } catch (error) { batch.forEach(({ item }) => item.done(`failed: ${error.message}`, "refused")); }
    batch = [];
    bytes = 0;
  };
  for (const entry of queue) {
    if (batch.length && (batch.length >= BATCH_FILES || bytes + entry.file.size > BATCH_BYTES)) await flush();
    batch.push(entry);
    bytes += entry.file.size;
  }
  await flush();
  if (images.length) await Promise.all([changed("sequences"), changed("frames")]);
}

const dropzone = document.getElementById("dropzone");
const input = document.getElementById("upload-input");
input.addEventListener("change", () => { if (input.files.length) uploadAll(input.files).finally(() => { input.value = ""; }); });
for (const name of ["dragenter", "dragover"]) {
  dropzone.addEventListener(name, (event) => { event.preventDefault(); dropzone.classList.add("over"); });
}
for (const name of ["dragleave", "drop"]) dropzone.addEventListener(name, () => dropzone.classList.remove("over"));
dropzone.addEventListener("drop", (event) => {
  event.preventDefault();
  if (event.dataTransfer?.files?.length) uploadAll(event.dataTransfer.files);
});

// --- the video sampling step: remembered across uploads and visits --------------------------

const NTH_KEY = "weldpool.everyNth";
const nthInput = document.getElementById("every-nth");

function nthValue() {
  return Math.max(1, Math.round(Number(nthInput.value) || 1));
}

function showNth() {
  document.getElementById("every-nth-text").textContent = everyNth(nthValue());
}

nthInput.value = localStorage.getItem(NTH_KEY) ?? nthInput.value;
nthInput.addEventListener("input", () => {
  localStorage.setItem(NTH_KEY, String(nthValue()));
  showNth();
});
showNth();
