// The weld runs beside the list: each with its frame count, process line and actions; adding
// one; its name, process parameters (the paper's Table I), scale and notes in a dialog; and
// the upload target, which follows the Sequence filter.

import { api, isReviewer, TEACHER_PROBLEM } from "../api.js";
import { count, mmPerPx } from "../format.js";
import { h, toast } from "../ui.js";
import { deleteWork, runTeacher } from "./actions.js";
import { changed, filterForm, S } from "./state.js";

let sequences = [];
let filteredRun = null; // the Sequence filter the upload target last followed

export async function loadSequences() {
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
  S.offset = 0;
  changed("filters");
}

/** The run an upload goes to follows a new Sequence filter (the dropzone keeps its own choice
 *  otherwise), and the run filtered on is marked in the list. */
export function updateUploadTarget() {
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
