// The export menu: the labelled frames of the list's sequence and split, in the chosen format,
// made by a job and then downloaded as a zip.

import { api, jobFromButton } from "../api.js";
import { h, toast } from "../ui.js";
import { filters } from "./filters.js";

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
