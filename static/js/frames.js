// The frames page: sequences, the filtered frame list (the review queue by default), uploads
// of frames and videos with per-file progress, and teacher runs on a sequence or a selection.

import { api, ApiError, isReviewer, jobFromButton, query, ROLE, TEACHER_PROBLEM, upload, waitForJob } from "./api.js";
import { count, decimal, everyNth, mmPerPx, score } from "./format.js";
import { badge, formatBytes, h, progressBar, reviewBadge, setProgress, toast } from "./ui.js";
import { probeVideo } from "./video.js";

const PAGE_SIZE = 50;
const VIDEO = /\.(mp4|avi)$/i;
const FILTERS = ["sequence_id", "status", "split", "review", "assignee", "order"];

const filterForm = document.getElementById("filters");
const rows = document.getElementById("frame-rows");
const selected = new Set();
let sequences = [];
let offset = Number(new URLSearchParams(location.search).get("offset") ?? 0) || 0;
let lastPage = { items: [], total: 0 };
let filteredRun = null; // the Sequence filter the upload target last followed
// "Next" follows the server's cursor (a deep page then reads only its own rows); a reload or
// "previous" uses the offset in the URL.
let nextAfter = null;

// --- filters and the URL ----------------------------------------------------------------------

/** The filters as the form holds them (and the URL keeps them). */
function formValues() {
  const values = Object.fromEntries(new FormData(filterForm));
  values.order ||= "uncertainty";
  return values;
}

/** The filters as the API takes them: "my work" is the assignee filter `me` with no status
 * or review filter (the server's list: sent back to me first, then still to review). */
function filters() {
  const values = formValues();
  if (values.assignee === WORK) {
    values.assignee = "me";
    delete values.status;
    delete values.review;
  }
  return values;
}

const WORK = "work";

/** Status and review do not apply to "my work": the list is the person's work itself. */
function syncWorkFilter() {
  const work = filterForm.elements.assignee.value === WORK;
  for (const name of ["status", "review"]) {
    const field = filterForm.elements[name];
    if (field) { field.disabled = work; field.title = work ? "“Assigned: my work” lists what was sent back to you, then what is still to review" : ""; }
  }
}

/** The list's filters as the review page's queue context. */
function queueContext() {
  return query(filters());
}

function restoreFilters() {
  const params = new URLSearchParams(location.search);
  for (const name of FILTERS) {
    const field = filterForm.elements[name];
    if (params.has(name)) field.value = params.get(name);
  }
  filterForm.elements.unstable.checked = params.get("unstable") === "true"; // a checkbox: no value to set
  if (!filterForm.elements.order.value) filterForm.elements.order.value = "uncertainty";
}

function syncUrl() {
  history.replaceState(null, "", `/${query({ ...formValues(), offset: offset || "" })}`);
}

// --- sequences --------------------------------------------------------------------------------

async function loadSequences() {
  sequences = await api("/sequences");
  const list = document.getElementById("sequence-list");
  const select = document.getElementById("filter-sequence");
  const current = new URLSearchParams(location.search).get("sequence_id") ?? select.value;
  list.replaceChildren();
  select.replaceChildren(h("option", { value: "" }, "all"));
  if (!sequences.length) list.append(h("li", { class: "muted" }, "No sequences yet. Add one below, or upload frames without one."));
  for (const sequence of sequences) {
    select.append(h("option", { value: String(sequence.id) }, sequence.name));
    const active = String(sequence.id) === current;
    list.append(
      h("li", { class: active ? "active" : "", "data-sequence-id": String(sequence.id) },
        h("button", { type: "button", class: "link", onclick: () => pickSequence(sequence.id) }, sequence.name),
        h("span", { class: "muted count" }, count(sequence.frame_count, "frame")),
        processLine(sequence),
        h("div", { class: "seq-actions" },
        h("a", {
          class: "button small", href: `/sequences/${sequence.id}`, "data-testid": "sequence-timeline",
          title: "The run over time: pool geometry per frame, review status, propagation",
        }, "Timeline"),
        h("button", {
          type: "button", class: "secondary small", "data-testid": "edit-sequence",
          title: "Name, process parameters, scale and notes", onclick: () => editSequence(sequence),
        }, "Edit"),
        h("button", {
          type: "button", class: "secondary small", "data-testid": "teacher-sequence",
          title: TEACHER_PROBLEM || "Propose masks for every frame of this sequence",
          disabled: sequence.frame_count === 0 || Boolean(TEACHER_PROBLEM),
          onclick: () => runTeacher({ sequence_id: sequence.id }, sequence.name),
        }, "Run teacher"),
        isReviewer() ? h("button", {
          type: "button", class: "danger small", "data-testid": "delete-sequence",
          title: "Delete this weld run with its frames, videos and labels",
          onclick: () => deleteWork(`/sequences/${sequence.id}`, { method: "DELETE" },
            sequence.frame_count
              ? `Delete the weld run “${sequence.name}” with its ${count(sequence.frame_count, "frame")}, their proposals and labels? This cannot be undone.`
              : `Delete the empty weld run “${sequence.name}”?`,
            (r) => `Deleted the weld run “${sequence.name}”${r.deleted_frames ? ` with its ${count(r.deleted_frames, "frame")}` : ""}.`),
        }, "Delete") : ""),
      ),
    );
  }
  select.value = current ?? "";
  updateUploadTarget();
}

function pickSequence(id) {
  filterForm.elements.sequence_id.value = String(id);
  offset = 0;
  refresh();
}

function updateUploadTarget() {
  const id = filterForm.elements.sequence_id.value;
  const sequence = sequences.find((s) => String(s.id) === id);
  const target = document.getElementById("upload-sequence");
  const chosen = id !== filteredRun ? (sequence ? id : "") : target.value; // follows a new filter only
  filteredRun = id;
  target.replaceChildren(h("option", { value: "" }, "no sequence"),
    ...sequences.map((s) => h("option", { value: String(s.id) }, s.name)));
  target.value = sequences.some((s) => String(s.id) === chosen) ? chosen : "";
  for (const item of document.querySelectorAll("#sequence-list li")) item.classList.toggle("active", item.dataset.sequenceId === id);
}

document.getElementById("new-sequence").addEventListener("submit", async (event) => {
  event.preventDefault();
  const form = event.currentTarget;
  try {
    const sequence = await api("/sequences", { method: "POST", json: { name: form.elements.name.value.trim() } });
    form.reset();
    toast(`Sequence “${sequence.name}” added: fill in its process parameters.`, "ok");
    await loadSequences();
    pickSequence(sequence.id);
    editSequence(sequence); // the weld run's Table I parameters and scale, right away
  } catch (error) {
    toast(error.message, "error");
  }
});

// --- the frame list ---------------------------------------------------------------------------

function frameRow(frame) {
  const href = `/frames/${frame.id}${queueContext()}`;
  const box = h("input", {
    type: "checkbox", "aria-label": `select frame ${frame.id}`, checked: selected.has(frame.id),
    onchange: (event) => { event.target.checked ? selected.add(frame.id) : selected.delete(frame.id); updateSelection(); },
  });
  const uncertainty = score(frame.uncertainty);
  return h("tr", { "data-frame-id": String(frame.id), "data-testid": "frame-row" },
    h("td", {}, box),
    h("td", { class: "thumb" }, h("a", { href, tabindex: "-1" },
      h("img", { src: `/api/v1/frames/${frame.id}/image?variant=thumb`, alt: "", loading: "lazy", width: "96", height: String(Math.round(96 * frame.height / frame.width)) }))),
    h("td", {}, h("a", { href, class: "frame-link" }, `#${frame.id}`), " ",
      h("span", { class: "muted name" }, frame.original_name || (frame.frame_index !== null ? `frame ${frame.frame_index}` : ""))),
    h("td", { class: "muted" }, `${frame.width}×${frame.height}`, frame.bit_depth === 16 ? " · 16-bit" : "", h("br"), formatBytes(frame.size_bytes)),
    h("td", {}, badge(frame.status), frame.review ? [" ", reviewBadge(frame.review)] : null,
      frame.review === "returned" && frame.review_comment
        ? h("span", { class: "review-comment", "data-testid": "review-comment" }, `“${frame.review_comment}”`) : null),
    h("td", {}, frame.split),
    h("td", { "data-testid": "frame-assignee" }, frame.assignee ?? h("span", { class: "muted" }, "—")),
    h("td", { class: "num" }, uncertainty),
  );
}

async function loadFrames() {
  const params = { ...filters(), limit: PAGE_SIZE, ...(nextAfter ? { after: nextAfter } : { offset }) };
  nextAfter = null;
  try {
    lastPage = await api(`/frames${query(params)}`);
  } catch (error) {
    rows.replaceChildren(h("tr", {}, h("td", { colspan: "8", class: "error" }, error.message)));
    return;
  }
  if (!lastPage.items.length && offset > 0) {
    offset = Math.max(0, offset - PAGE_SIZE);
    return loadFrames();
  }
  rows.replaceChildren(...(lastPage.items.length
    ? lastPage.items.map(frameRow)
    : [h("tr", {}, h("td", { colspan: "8", class: "empty", "data-testid": "frames-empty" },
        formValues().assignee === WORK
          ? "Nothing is waiting for you: nothing was sent back, and every frame handed to you is labelled."
        : filters().status === "unreviewed"
          ? "Nothing left to review here. Status “all” shows the frames already reviewed; drop frames above to add more."
          : "No frames match. Drop frames above, or import labels made elsewhere, to start."))]));
  const note = document.getElementById("order-note");
  note.textContent = lastPage.ordering ?? "";
  note.hidden = !lastPage.ordering || !lastPage.items.length;
  const last = Math.min(offset + PAGE_SIZE, lastPage.total);
  document.getElementById("page-info").textContent = lastPage.total ? `${offset + 1}–${last} of ${lastPage.total}` : "0 frames";
  document.getElementById("prev-page").disabled = offset === 0;
  document.getElementById("next-page").disabled = last >= lastPage.total;
  document.getElementById("select-all").checked = lastPage.items.length > 0 && lastPage.items.every((f) => selected.has(f.id));
  document.getElementById("review-queue").disabled = lastPage.total === 0;
}

function updateSelection() {
  document.getElementById("selection-count").textContent = `${selected.size} selected`;
  document.getElementById("assign-selection").disabled = selected.size === 0;
  document.getElementById("overlap-selection").disabled = selected.size === 0;
  document.getElementById("delete-selection").disabled = selected.size === 0;
  const teacherButton = document.getElementById("teacher-selection");
  teacherButton.disabled = selected.size === 0 || Boolean(TEACHER_PROBLEM);
  if (TEACHER_PROBLEM) teacherButton.title = TEACHER_PROBLEM;
}

async function refresh() {
  syncWorkFilter();
  syncUrl();
  updateUploadTarget();
  await loadFrames();
}

filterForm.addEventListener("change", () => { offset = 0; refresh(); });
document.getElementById("prev-page").addEventListener("click", () => { offset = Math.max(0, offset - PAGE_SIZE); refresh(); });
document.getElementById("next-page").addEventListener("click", () => {
  offset += PAGE_SIZE;
  nextAfter = lastPage.next_after ?? null;
  refresh();
});
document.getElementById("select-all").addEventListener("change", (event) => {
  for (const frame of lastPage.items) event.target.checked ? selected.add(frame.id) : selected.delete(frame.id);
  updateSelection();
  loadFrames();
});
document.getElementById("review-queue").addEventListener("click", () => {
  const first = lastPage.items[0];
  if (first) location.href = `/frames/${first.id}${queueContext()}`;
});
document.getElementById("teacher-selection").addEventListener("click", () => {
  runTeacher({ frame_ids: [...selected] }, `${selected.size} frames`);
});

// --- export -----------------------------------------------------------------------------------

document.getElementById("export").addEventListener("click", async (event) => {
  const { sequence_id: sequenceId, split } = filters();
  const body = { format: document.getElementById("export-format").value };
  if (sequenceId) body.sequence_id = Number(sequenceId);
  if (split) body.split = split;
  try {
    // A job with progress (big sets take a while); its zip is then downloaded from the server.
    const job = await jobFromButton(event.currentTarget, () => api("/exports", { method: "POST", json: body }), "Exporting");
    if (job.status !== "succeeded") throw new Error(`The export job ${job.status}: ${job.error ?? ""}`);
    const link = h("a", { href: `/api/v1/exports/${job.id}`, download: "", "data-testid": "export-link" });
    document.body.append(link);
    link.click();
    link.remove();
    toast(`Export ready (${job.message}).`, "ok");
  } catch (error) {
    toast(error.message, "error");
  }
});

document.addEventListener("labels-imported", async () => { await loadSequences(); await refresh(); }); // imports.js: new labels and runs

// --- a weld run's name, process parameters (the paper's Table I), scale and notes ---------------

const NUMBERS = ["wire_feed_m_min", "voltage_v", "current_a", "arc_length_correction_pct", "robot_speed_cm_min", "mm_per_px"];
const TEXTS = ["name", "synergic_law", "joint_type", "notes"];
const dialog = document.getElementById("sequence-dialog");
const sequenceForm = document.getElementById("sequence-form");
let editing = null;

function processLine(sequence) {
  const parts = [
    sequence.wire_feed_m_min != null && `${sequence.wire_feed_m_min} m/min`,
    sequence.voltage_v != null && `${sequence.voltage_v} V`,
    sequence.current_a != null && `${sequence.current_a} A`,
    sequence.robot_speed_cm_min != null && `${sequence.robot_speed_cm_min} cm/min`,
    sequence.mm_per_px != null && `${mmPerPx(sequence.mm_per_px)} mm/px`,
  ].filter(Boolean);
  return parts.length ? h("span", { class: "muted small-text process", "data-testid": "process-line" }, parts.join(" · ")) : "";
}

function editSequence(sequence) {
  editing = sequence;
  for (const name of [...NUMBERS, ...TEXTS]) sequenceForm.elements[name].value = sequence[name] ?? "";
  document.getElementById("sequence-error").hidden = true;
  dialog.showModal();
}

document.getElementById("sequence-cancel").addEventListener("click", () => dialog.close());
// An error is about what was sent: it goes as soon as the user changes the form.
sequenceForm.addEventListener("input", () => { document.getElementById("sequence-error").hidden = true; });
// Two points a known distance apart: the scale is that distance over its length in pixels.
for (const id of ["scale-mm", "scale-px"]) {
  document.getElementById(id).addEventListener("input", () => {
    const mm = Number(document.getElementById("scale-mm").value);
    const px = Number(document.getElementById("scale-px").value);
    if (mm > 0 && px > 0) sequenceForm.elements.mm_per_px.value = String(Number((mm / px).toPrecision(6)));
  });
}
sequenceForm.addEventListener("submit", async (event) => {
  event.preventDefault();
  const body = {};
  for (const name of NUMBERS) {
    const text = sequenceForm.elements[name].value.trim();
    body[name] = text === "" ? null : Number(text);
  }
  for (const name of TEXTS) {
    const text = sequenceForm.elements[name].value.trim();
    body[name] = text === "" && name !== "notes" && name !== "name" ? null : text;
  }
  try {
    await api(`/sequences/${editing.id}`, { method: "PATCH", json: body });
    dialog.close();
    toast(`Saved “${body.name}”.`, "ok");
    await loadSequences();
  } catch (error) {
    const box = document.getElementById("sequence-error");
    box.textContent = error.message;
    box.hidden = false;
  }
});

// --- deleting ---------------------------------------------------------------------------------

/** Delete after asking; when reviewed work would be lost the server says how much, and the
 *  user is asked once more before it goes too (force). */
async function deleteWork(path, options, question, done = (r) => `Deleted ${count(r.deleted_frames, "frame")}.`) {
  if (!confirm(question)) return;
  const force = (url) => `${url}${url.includes("?") ? "&" : "?"}force=true`;
  try {
    let result;
    try {
      result = await api(path, options);
    } catch (error) {
      if (!(error instanceof ApiError && error.status === 409)) throw error;
      if (!confirm(`${error.message}\n\nDelete them anyway, with their reviewed labels?`)) return;
      result = options.json
        ? await api(path, { ...options, json: { ...options.json, force: true } })
        : await api(force(path), options);
    }
    toast(done(result), "ok");
    selected.clear();
    updateSelection();
    await loadSequences();
    await loadFrames();
  } catch (error) {
    toast(error.message, "error");
  }
}

const deleteButton = document.getElementById("delete-selection");
deleteButton.hidden = !isReviewer();
deleteButton.addEventListener("click", () => {
  const ids = [...selected];
  deleteWork("/frames/delete", { method: "POST", json: { frame_ids: ids } },
    `Delete ${count(ids.length, "selected frame")} with their proposals and labels? This cannot be undone.`);
});

// --- teacher runs -----------------------------------------------------------------------------

async function runTeacher(body, what) {
  let created;
  try {
    created = await api("/teacher/runs", { method: "POST", json: { ...body, force: document.getElementById("teacher-force").checked } });
  } catch (error) {
    toast(error.message, "error");
    return;
  }
  toast(`Teacher job #${created.job_id} started for ${what}; follow it on the Jobs page.`, "info");
  const job = await waitForJob(created.job_id, () => {}, 1000).catch((error) => ({ status: "failed", error: error.message }));
  if (job.status === "succeeded") {
    const result = job.result ?? {};
    toast(`Teacher job #${created.job_id} done: ${result.proposed ?? 0} proposed, ${result.skipped ?? 0} skipped.`, "ok");
    selected.clear();
    updateSelection();
  } else {
    toast(`Teacher job #${created.job_id} ${job.status}: ${job.error ?? ""}`, "error");
  }
  loadFrames();
}

// --- uploads ----------------------------------------------------------------------------------

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
    await Promise.all([loadSequences(), loadFrames()]);
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
  if (images.length) await Promise.all([loadSequences(), loadFrames()]);
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

// --- assignments ------------------------------------------------------------------------------

const assignTo = document.getElementById("assign-to");

/** Reviewers hand frames out: the people to pick, in the bar and as list filters. */
async function loadAssignees() {
  if (!isReviewer()) return;
  const users = await api("/users/assignable");
  assignTo.replaceChildren(
    h("option", { value: "", disabled: true, selected: true }, "choose a person…"),
    ...users.map((user) => h("option", { value: String(user.id) }, `${user.username} (${user.role})`)),
    h("option", { value: NOBODY }, "nobody (take them back)"));
  const filter = document.getElementById("filter-assignee");
  for (const user of users) filter.append(h("option", { value: String(user.id) }, `to ${user.username}`));
  document.getElementById("overlap-people").replaceChildren(...users.map((user) =>
    h("label", { class: "check" }, h("input", { type: "checkbox", name: "user", value: String(user.id), checked: user.role === "annotator" }), ` ${user.username} (${user.role})`)));
  document.getElementById("assign-controls").hidden = false;
}

const NOBODY = "nobody";

async function assign(body) {
  if (!assignTo.value) {
    toast("Choose who to hand the frames to (“Hand to”).", "error");
    assignTo.focus();
    return;
  }
  const assigneeId = assignTo.value === NOBODY ? null : Number(assignTo.value);
  try {
    const result = await api("/frames/assign", { method: "POST", json: { ...body, assignee_id: assigneeId } });
    if (!result.assigned) toast("Nobody's frames are left in this queue to hand out.", "info");
    else toast(`${count(result.assigned, "frame")} ${result.assignee ? `assigned to ${result.assignee}` : "taken back: nobody's now"}.`, "ok");
    selected.clear();
    updateSelection();
  } catch (error) {
    toast(error.message, "error");
  }
  loadFrames();
}

document.getElementById("assign-selection").addEventListener("click", () => assign({ frame_ids: [...selected] }));

// --- agreement: frames given to several annotators -------------------------------------------

const overlapDialog = document.getElementById("overlap-dialog");
document.getElementById("overlap-selection").addEventListener("click", () => overlapDialog.showModal());
document.getElementById("overlap-cancel").addEventListener("click", () => overlapDialog.close());
document.getElementById("overlap-form").addEventListener("submit", async (event) => {
  event.preventDefault();
  const people = [...event.target.querySelectorAll("input[name=user]:checked")].map((box) => Number(box.value));
  try {
    const result = await api("/frames/overlap", { method: "POST", json: { frame_ids: [...selected], user_ids: people } });
    overlapDialog.close();
    toast(`${count(selected.size, "frame")} given to ${people.length} people (${count(result.given, "new label")} to make).`, "ok");
    selected.clear();
    updateSelection();
    loadFrames();
  } catch (error) {
    toast(error.message, "error");
  }
});
document.getElementById("assign-next").addEventListener("click", () => {
  const next = Math.min(1000, Math.max(1, Math.round(Number(document.getElementById("assign-count").value) || 1)));
  const sequenceId = filters().sequence_id;
  assign({ next, ...(sequenceId ? { sequence_id: Number(sequenceId) } : {}) });
});

/** Where a person lands (unless the URL names filters): an annotator on her work (what was
 * sent back to her, then what is handed to her); a reviewer on what awaits his approval, else
 * on the frames handed to him. */
async function landing() {
  if (FILTERS.some((name) => new URLSearchParams(location.search).has(name))) return;
  const work = await api("/users/me/work").catch(() => null);
  if (!work) return;
  if (isReviewer() && work.awaiting_review && filterForm.elements.review) {
    filterForm.elements.review.value = "awaiting";
    filterForm.elements.status.value = "all";
    filterForm.elements.order.value = "id";
    toast(`${count(work.awaiting_review, "label")} await${work.awaiting_review > 1 ? "" : "s"} your approval: shown first. “Review: any” shows every frame.`, "info", 6000);
  } else if (work.sent_back || work.assigned) {
    filterForm.elements.assignee.value = WORK;
    const parts = [work.sent_back ? `${count(work.sent_back, "label")} sent back to you` : "", work.assigned ? `${count(work.assigned, "frame")} handed to you` : ""];
    toast(`Your work first: ${parts.filter(Boolean).join(", then ")}. “Assigned: to anyone” shows all.`, "info", 6000);
  }
}

// --- start ------------------------------------------------------------------------------------

await loadAssignees().catch((error) => toast(error.message, "error"));
restoreFilters();
await landing();
await loadSequences().catch((error) => toast(error.message, "error"));
restoreFilters();
await refresh();
document.body.dataset.ready = "1";

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
