// The jobs page: recent background jobs with live progress (polled: every second while any job
// is queued or running, every five seconds otherwise), their errors, and cancellation.

import { api, query } from "./api.js";
import { count } from "./format.js";
import { badge, formatBytes, formatDate, h, progressBar, toast } from "./ui.js";

const ACTIVE = new Set(["queued", "running"]);
const form = document.getElementById("job-filters");
const rows = document.getElementById("job-rows");
const highlight = Number(new URLSearchParams(location.search).get("job") ?? 0);
let timer = null;
let runs = new Map(); // sequence id → name, for the scope column

/** The job's message: its progress while it runs, the sentence its handler summed up with once
 * it succeeded (every kind writes one), its error when it failed. */
function describe(job) {
  if (job.error) return h("span", { class: "error" }, job.error);
  const parts = [job.message || job.waiting];
  if (job.cancel_requested && ACTIVE.has(job.status)) parts.push("cancelling…");
  return parts.filter(Boolean).join(" — ");
}

async function cancel(job) {
  if (!confirm(`Cancel job #${job.id} (${job.kind}, ${scope(job)})? A running job stops at its next step; what it finished stays.`)) return;
  try {
    await api(`/jobs/${job.id}/cancel`, { method: "POST" });
    toast(`Job #${job.id}: cancel requested.`, "info");
  } catch (error) {
    toast(error.message, "error");
  }
  load();
}

/** A weld run by its name (its number when it is gone). */
const run = (id) => (runs.has(id) ? `run “${runs.get(id)}”` : `run #${id}`);

/** What a job works on, in words, from its parameters. */
function scope(job) {
  const p = job.params ?? {};
  if (job.kind === "export") return `${p.format ?? ""} export${p.sequence_id ? ` of ${run(p.sequence_id)}` : ""}${p.split ? `, ${p.split}` : ""}`;
  if (job.kind === "propagate") return `${run(p.sequence_id)} from ${count(p.from_frame_ids?.length ?? 0, "frame")}, ${p.direction ?? "both"}`;
  if (Array.isArray(p.frame_ids)) return `${p.sequence_id ? `${run(p.sequence_id)}, ` : ""}${count(p.frame_ids.length, "frame")}`;
  if (p.sequence_id && Number.isInteger(p.frames)) return `${run(p.sequence_id)}, ${count(p.frames, "frame")}`;
  if (p.scope === "unreviewed" && Number.isInteger(p.frames)) return `the ${count(p.frames, "frame")} still to review`;
  if (Number.isInteger(p.frames)) return count(p.frames, "frame");
  if (p.sequence_id) return run(p.sequence_id);
  if (p.video_id) return `video #${p.video_id}`;
  if (job.kind === "train_sequential") return `sequential cell of model #${p.model_version_id}`;
  if (job.kind === "quantize_student") return `int8 student of model #${p.model_version_id}`;
  if (job.kind === "train_student") return p.epochs ? count(p.epochs, "epoch") : "all reviewed labels";
  return "—";
}

/** How long the job ran (or has been running). */
function duration(job) {
  if (!job.started_at) return "";
  const when = (text) => new Date(text.endsWith("Z") || text.includes("+") ? text : `${text}Z`).getTime();
  const end = job.finished_at ? when(job.finished_at) : Date.now();
  const seconds = Math.max(0, Math.round((end - when(job.started_at)) / 1000));
  if (seconds < 60) return `${seconds} s`;
  if (seconds < 3600) return `${Math.floor(seconds / 60)} min ${seconds % 60} s`;
  return `${Math.floor(seconds / 3600)} h ${Math.floor((seconds % 3600) / 60)} min`;
}

function jobRow(job) {
  return h("tr", { "data-job-id": String(job.id), "data-status": job.status, "data-testid": "job-row", class: job.id === highlight ? "highlight" : "" },
    h("td", { class: "num" }, String(job.id)),
    h("td", {}, job.kind, h("div", { class: "muted small-text", "data-testid": "job-scope" }, scope(job))),
    h("td", { "data-testid": "job-owner" }, job.created_by ?? h("span", { class: "muted" }, "system")),
    h("td", {}, badge(job.status), job.attempts > 1 ? h("span", { class: "muted" }, ` try ${job.attempts}`) : ""),
    h("td", { class: "progress-col" }, progressBar(job.progress), h("span", { class: "muted small-text" }, `${Math.round(job.progress * 100)} %`)),
    h("td", { class: "message" }, describe(job)),
    h("td", { class: "muted" }, formatDate(job.created_at)),
    h("td", { class: "muted", "data-testid": "job-duration" }, duration(job)),
    h("td", {}, ACTIVE.has(job.status) && !job.cancel_requested
      ? h("button", { type: "button", class: "secondary small", "data-testid": "cancel-job", onclick: () => cancel(job) }, "Cancel")
      : ""),
  );
}

/** Update the table in place: a row stays the same element while its job is listed, and only
 *  its cells that changed are replaced, so a button under the pointer (Cancel) is not swapped
 *  out between two polls. */
function render(jobs) {
  const existing = new Map([...rows.querySelectorAll("tr[data-job-id]")].map((tr) => [tr.dataset.jobId, tr]));
  const wanted = jobs.map((job) => {
    const fresh = jobRow(job);
    const old = existing.get(String(job.id));
    if (!old) return fresh;
    for (const name of ["data-status", "class"]) {
      if (old.getAttribute(name) !== fresh.getAttribute(name)) old.setAttribute(name, fresh.getAttribute(name) ?? "");
    }
    [...fresh.children].forEach((cell, i) => {
      if (old.children[i].outerHTML !== cell.outerHTML) old.children[i].replaceWith(cell);
    });
    return old;
  });
  const same = wanted.length === rows.children.length && wanted.every((tr, i) => rows.children[i] === tr);
  if (!same) rows.replaceChildren(...wanted);
}

async function load() {
  clearTimeout(timer);
  let page;
  try {
    page = await api(`/jobs${query({ ...Object.fromEntries(new FormData(form)), limit: 100 })}`);
  } catch (error) {
    document.getElementById("poll-state").textContent = error.message;
    timer = setTimeout(load, 5000);
    return;
  }
  const named = page.items.map((j) => j.params?.sequence_id).filter((id) => id && !runs.has(id));
  if (named.length) {
    runs = new Map((await api("/sequences").catch(() => [])).map((s) => [s.id, s.name]));
  }
  if (page.items.length) render(page.items);
  else rows.replaceChildren(h("tr", {}, h("td", { colspan: "9", class: "empty" }, "No jobs yet. Teacher runs, video extraction and training appear here.")));
  const active = page.items.some((j) => ACTIVE.has(j.status));
  document.getElementById("poll-state").textContent =
    `${count(page.total, "job")} · updated ${new Date().toLocaleTimeString()} · ${active ? "live" : "idle"}`;
  document.body.dataset.ready = "1";
  timer = setTimeout(load, active ? 1000 : 5000);
}

form.addEventListener("change", load);
document.addEventListener("visibilitychange", () => { if (!document.hidden) load(); });
load();

// --- the embedding cache: its size, and (admins) a Clear button ----------------------------

async function showCache() {
  try {
    const cache = await api("/system/embedding-cache");
    document.getElementById("cache-size").textContent =
      `${count(cache.files, "frame")}, ${formatBytes(cache.bytes)} of ${formatBytes(cache.limit_bytes)} (WELDPOOL_EMBEDDING_CACHE_MB; least recently used out)`;
  } catch (error) {
    document.getElementById("cache-size").textContent = error.message;
  }
}

document.getElementById("cache-clear")?.addEventListener("click", async () => {
  if (!confirm("Clear the embedding cache? The next click on each frame computes its embedding again (seconds on a CPU).")) return;
  try {
    const cleared = await api("/system/embedding-cache", { method: "DELETE" });
    toast(`Cleared ${count(cleared.removed_files, "embedding")} (${formatBytes(cleared.removed_bytes)}).`, "ok");
  } catch (error) {
    toast(error.message, "error");
  }
  showCache();
});

showCache();
