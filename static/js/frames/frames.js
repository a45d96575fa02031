// The frames page's entry: sequences, the filtered frame list (the review queue by default),
// uploads of frames and videos with per-file progress, teacher runs and other actions on a
// sequence or a selection, and the export menu, one module each. It subscribes the views to
// the page's changes once (state.js) and starts the page; no module imports this one.

import { toast } from "../ui.js";
import { loadAssignees } from "./actions.js";
import { loadClassFilters } from "./classes.js";
import "./export.js";
import { landing, restoreFilters, syncUrl, syncWorkFilter } from "./filters.js";
import { loadFrames } from "./list.js";
import { loadSequences, updateUploadTarget } from "./sequences.js";
import { changed, subscribe } from "./state.js";
import "./upload.js";

/** The filters changed: the URL, the upload target and the list follow. */
async function refresh() {
  syncWorkFilter();
  syncUrl();
  updateUploadTarget();
  await loadFrames();
}

subscribe(async (parts) => {
  if (parts.has("sequences")) await loadSequences();
  if (parts.has("filters")) await refresh();
  else if (parts.has("frames")) await loadFrames();
});

document.addEventListener("labels-imported", () => changed("sequences", "filters")); // imports.js: new labels and runs

await loadAssignees().catch((error) => toast(error.message, "error"));
await loadClassFilters().catch((error) => toast(error.message, "error"));
restoreFilters();
await landing();
await loadSequences().catch((error) => toast(error.message, "error"));
restoreFilters();
await refresh();
document.body.dataset.ready = "1";
