// The frames selected and what is done to them at once: teacher runs, deleting (with the
// weld runs' own Delete), handing frames to people, and giving them to several annotators.

import { api, ApiError, isReviewer, TEACHER_PROBLEM, waitForJob } from "../api.js";
import { count } from "../format.js";
import { h, toast } from "../ui.js";
import { filters } from "./filters.js";
import { changed, selected } from "./state.js";

export function updateSelection() {
  document.getElementById("selection-count").textContent = `${selected.size} selected`;
  document.getElementById("assign-selection").disabled = selected.size === 0;
  document.getElementById("overlap-selection").disabled = selected.size === 0;
  document.getElementById("delete-selection").disabled = selected.size === 0;
  const teacherButton = document.getElementById("teacher-selection");
  teacherButton.disabled = selected.size === 0 || Boolean(TEACHER_PROBLEM);
  if (TEACHER_PROBLEM) teacherButton.title = TEACHER_PROBLEM;
}

document.getElementById("teacher-selection").addEventListener("click", () => {
  runTeacher({ frame_ids: [...selected] }, `${selected.size} frames`);
});

// --- deleting ---------------------------------------------------------------------------------

/** Delete after asking; when reviewed work would be lost the server says how much, and the
 *  user is asked once more before it goes too (force). */
export async function deleteWork(path, options, question, done = (r) => `Deleted ${count(r.deleted_frames, "frame")}.`) {
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
    await changed("sequences", "frames");
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

export async function runTeacher(body, what) {
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
  changed("frames");
}

// --- assignments ------------------------------------------------------------------------------

const assignTo = document.getElementById("assign-to");
const NOBODY = "nobody";

/** Reviewers hand frames out: the people to pick, in the bar and as list filters. */
export async function loadAssignees() {
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
  changed("frames");
}

document.getElementById("assign-selection").addEventListener("click", () => assign({ frame_ids: [...selected] }));
document.getElementById("assign-next").addEventListener("click", () => {
  const next = Math.min(1000, Math.max(1, Math.round(Number(document.getElementById("assign-count").value) || 1)));
  const sequenceId = filters().sequence_id;
  assign({ next, ...(sequenceId ? { sequence_id: Number(sequenceId) } : {}) });
});

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
    changed("frames");
  } catch (error) {
    toast(error.message, "error");
  }
});
