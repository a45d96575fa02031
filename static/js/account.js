// One's own account: change the password (the current one, then the new one twice).

import { api } from "./api.js";
import { toast } from "./ui.js";

const form = document.getElementById("password-form");
const result = document.getElementById("password-result");

form.addEventListener("submit", async (event) => {
  event.preventDefault();
  const { current, new: next, repeat } = form.elements;
  result.hidden = true;
  if (next.value !== repeat.value) {
    toast("The two new passwords differ; type the same one twice.", "error");
    repeat.focus();
    return;
  }
  try {
    const changed = await api("/users/me/password", { method: "POST", json: { current: current.value, new: next.value } });
    const sessions = changed.sessions_ended;
    const tokens = changed.tokens_active;
    result.textContent = `Password changed. ${sessions ? `${sessions} other browser session${sessions > 1 ? "s were" : " was"} logged out. ` : ""}`
      + (tokens ? `${tokens} API token${tokens > 1 ? "s stay" : " stays"} valid: revoke below any you did not make.` : "");
    result.hidden = false;
    toast("Password changed.", "ok");
    form.reset();
  } catch (error) {
    toast(error.message, "error");
    if (error.status === 403) current.select();
  }
});
