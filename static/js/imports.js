// The frames page's label import: a file and its format, uploaded with progress, read by a job
// whose result (labels, keypoint sets, new frames, and every skipped or refused item with its
// reason) is shown in the dialog; the frame list is refreshed after.

import { api, upload, waitForJob } from "./api.js";
import { count } from "./format.js";
import { h, progressBar, setProgress } from "./ui.js";

const dialog = document.getElementById("import-dialog");
const form = document.getElementById("import-form");
const result = document.getElementById("import-result");
const progressSlot = document.getElementById("import-progress");
const start = document.getElementById("import-start");
const sequenceSelect = document.getElementById("import-sequence");

document.getElementById("import-open").addEventListener("click", async () => {
  result.hidden = true;
  result.replaceChildren();
  progressSlot.replaceChildren();
  const sequences = await api("/sequences");
  const runs = sequences.map((s) => h("option", { value: String(s.id) }, s.name));
  sequenceSelect.replaceChildren(h("option", { value: "" }, "the runs the file names, else a new run"), ...runs);
  sequenceSelect.value = document.getElementById("filter-sequence").value; // the run shown here
  dialog.showModal();
});

document.getElementById("import-close").addEventListener("click", () => dialog.close());

form.addEventListener("submit", async (event) => {
  event.preventDefault();
  const data = new FormData(form);
  data.set("overwrite", form.elements.overwrite.checked ? "true" : "false");
  for (const name of ["sequence_id", "category"]) if (!data.get(name)) data.delete(name);
  const bar = progressBar(0, "import");
  const line = h("p", { class: "muted small-text" }, "Uploading…");
  progressSlot.replaceChildren(bar, line);
  result.hidden = true;
  start.disabled = true;
  try {
    // the upload is the first fifth of the bar, the job's reading the rest
    const { status, body } = await upload("/labels/import", data, (fraction) => setProgress(bar, 0.2 * fraction));
    if (status !== 202) throw new Error(body?.detail ?? `The import was refused (HTTP ${status}).`);
    const job = await waitForJob(body.job_id, (update) => {
      setProgress(bar, 0.2 + 0.8 * update.progress);
      line.textContent = update.message || "Reading…";
    });
    if (job.status !== "succeeded") throw new Error(`The import ${job.status}: ${job.error ?? ""}`);
    setProgress(bar, 1);
    line.textContent = job.message;
    showResult(job.result);
    document.dispatchEvent(new CustomEvent("labels-imported"));
  } catch (error) {
    result.replaceChildren(h("p", { class: "error-text", "data-testid": "import-error" }, error.message));
    result.hidden = false;
  } finally {
    start.disabled = false;
  }
});

function itemList(kind, items, total) {
  const rest = total - items.length;
  return h(
    "details",
    { class: kind, open: kind === "refused", "data-testid": `import-${kind}` },
    h("summary", {}, `${kind === "refused" ? "Refused" : "Skipped"}: ${total}`),
    h("ul", {}, items.map((item) => h("li", {}, h("code", {}, item.item), " — ", item.reason))),
    rest > 0 ? h("p", { class: "muted small-text" }, `and ${rest} more`) : null,
  );
}

function showResult(done) {
  const summary = h(
    "p",
    { "data-testid": "import-summary" },
    `${count(done.labels, "label")} and ${count(done.keypoints, "keypoint set")} imported, ${count(done.frames, "new frame")}.`,
  );
  const lists = ["refused", "skipped"]
    .filter((kind) => (done[`${kind}_count`] ?? done[kind].length) > 0)
    .map((kind) => itemList(kind, done[kind], done[`${kind}_count`] ?? done[kind].length));
  result.replaceChildren(summary, ...lists);
  result.hidden = false;
}
