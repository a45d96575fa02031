// The REST API as the pages use it: same-origin fetches with the session cookie, the CSRF
// header on state-changing calls, and errors as ApiError carrying the server's one sentence.

// The session's CSRF token: the page's, until a request finds it stale (a new login in another
// tab), when the session's own is fetched and the request sent once more.
let CSRF = document.querySelector('meta[name="csrf-token"]')?.content ?? "";
export const ROLE = document.querySelector('meta[name="user-role"]')?.content ?? "annotator";
/** Why the teacher cannot run here (missing weights), or "" when it can (set by the server). */
export const TEACHER_PROBLEM = document.querySelector('meta[name="teacher-problem"]')?.content ?? "";
/** Why SAM2 alone cannot run (clicks, boxes, embeddings, propagation), or "" when it can. */
export const SAM2_PROBLEM = document.querySelector('meta[name="sam2-problem"]')?.content ?? "";
/** Whether annotators' labels await a reviewer's approval (WELDPOOL_REVIEW_STAGE). */
export const REVIEW_STAGE = document.querySelector('meta[name="review-stage"]')?.content === "on";
/** What the logged-in user's role allows, as the server's one table says (`user-may`). */
const MAY = new Set((document.querySelector('meta[name="user-may"]')?.content ?? "").split(",").filter(Boolean));

/** Whether the logged-in user may do `action` (app/core/permissions.py names them). */
export const may = (action) => MAY.has(action);

/** Whether the logged-in user may review others' labels (reviewers and admins). */
export const isReviewer = () => may("review");

export class ApiError extends Error {
  constructor(status, detail, body) {
    super(detail);
    this.status = status;
    this.body = body;
  }
}

/** The login form in a new tab: this page keeps what is not saved yet. */
export const LOGIN_AGAIN = "Your session has ended: log in again in another tab (this page keeps what you have not saved), then try again.";

function describe(status, body) {
  if (status === 401) return LOGIN_AGAIN; // the API's sentence speaks to API clients
  if (body && typeof body.detail === "string") return body.detail;
  return `The server answered ${status}.`;
}

const staleCsrf = (status, body) => status === 403 && body?.reason === "csrf";

const USER = document.querySelector('meta[name="user-name"]')?.content ?? "";

/** The session's CSRF token now (after a login in another tab), when the session is still
 *  this page's user's; false when there is none. Throws when another user logged in since:
 *  the page's work must not be saved in their name. */
async function refreshCsrf() {
  let session;
  try {
    const response = await fetch("/api/v1/users/me/csrf", { headers: { Accept: "application/json" }, credentials: "same-origin" });
    session = response.ok ? await response.json() : null;
  } catch {
    return false;
  }
  if (!session?.csrf_token) return false;
  if (session.username !== USER) {
    throw new ApiError(403, `${session.username} has logged in in this browser since this page was opened for ${USER}; log in as ${USER} again in another tab to save this page's work, or reload it to work as ${session.username}.`, null);
  }
  CSRF = session.csrf_token;
  return true;
}

/**
 * Call `/api/v1${path}`; `json` is sent as the body. Returns the parsed JSON (or the
 * Response itself with `raw: true`); throws ApiError for any non-2xx answer.
 */
export async function api(path, { method = "GET", json, body, raw = false, signal } = {}, retried = false) {
  const headers = { Accept: "application/json" };
  if (method !== "GET" && method !== "HEAD") headers["X-CSRF-Token"] = CSRF;
  let sent = body;
  if (json !== undefined) {
    headers["Content-Type"] = "application/json";
    sent = JSON.stringify(json);
  }
  let response;
  try {
    response = await fetch(`/api/v1${path}`, { method, headers, body: sent, signal, credentials: "same-origin" });
  } catch (error) {
    if (error.name === "AbortError") throw error;
    throw new ApiError(0, "The server cannot be reached; check that weldpool is running.", null);
  }
  if (raw && response.ok) return response;
  const text = await response.text();
  let parsed = null;
  try { parsed = text ? JSON.parse(text) : null; } catch { parsed = null; }
  if (!retried && staleCsrf(response.status, parsed) && (await refreshCsrf())) {
    return api(path, { method, json, body, raw, signal }, true);
  }
  if (!response.ok) throw new ApiError(response.status, describe(response.status, parsed), parsed);
  return parsed;
}

/**
 * A multipart upload through XMLHttpRequest, for its upload progress events.
 * `onProgress(fraction)` is called while the body is sent. Resolves with
 * `{status, body}` for any HTTP answer (the caller reads refusals from the body).
 */
export async function upload(path, formData, onProgress) {
  let answer = await send(path, formData, onProgress);
  if (staleCsrf(answer.status, answer.body)) {
    try {
      if (await refreshCsrf()) answer = await send(path, formData, onProgress);
    } catch (error) {
      return { status: error.status, body: { detail: error.message } };
    }
  }
  return answer.status === 401 ? { status: 401, body: { detail: LOGIN_AGAIN } } : answer;
}

function send(path, formData, onProgress) {
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    xhr.open("POST", `/api/v1${path}`);
    xhr.setRequestHeader("X-CSRF-Token", CSRF);
    xhr.setRequestHeader("Accept", "application/json");
    xhr.upload.addEventListener("progress", (event) => {
      if (event.lengthComputable) onProgress(event.loaded / event.total);
    });
    xhr.addEventListener("load", () => {
      let body = null;
      try { body = JSON.parse(xhr.responseText); } catch { body = null; }
      resolve({ status: xhr.status, body });
    });
    xhr.addEventListener("error", () => reject(new ApiError(0, "The upload was interrupted; check the connection and try again.", null)));
    xhr.send(formData);
  });
}

/** Query string from an object, leaving out empty values. */
export function query(params) {
  const search = new URLSearchParams();
  for (const [key, value] of Object.entries(params)) {
    if (value !== undefined && value !== null && value !== "") search.set(key, value);
  }
  const text = search.toString();
  return text ? `?${text}` : "";
}

const FINISHED = new Set(["succeeded", "failed", "cancelled"]);

/** Poll a job until it has finished; `onUpdate(job)` sees each state. Resolves with the job. */
export async function waitForJob(jobId, onUpdate = () => {}, intervalMs = 500) {
  for (;;) {
    const job = await api(`/jobs/${jobId}`);
    onUpdate(job);
    if (FINISHED.has(job.status)) return job;
    await new Promise((resolve) => setTimeout(resolve, intervalMs));
  }
}

/**
 * Start a job from a button and follow it there: the button is disabled and shows
 * `${working} NN %` until the job ends, then gets its text back. Resolves with the finished job.
 */
export async function jobFromButton(button, start, working = "Working") {
  const text = button.textContent;
  button.disabled = true;
  try {
    const { job_id: jobId } = await start();
    return await waitForJob(jobId, (job) => { button.textContent = `${working} ${Math.round(job.progress * 100)} %`; }, 1000);
  } finally {
    button.textContent = text;
    button.disabled = false;
  }
}
