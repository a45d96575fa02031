// The review page's constants: the frame shown, the queue it was opened from, the limits.

export const FRAME_ID = Number(document.getElementById("review").dataset.frameId);
export const K = 4;
export const HISTORY_LIMIT = 40; // each step may hold a full-frame mask (1 MB at 1280×800)
export const OUTLINE_TOLERANCE = 1; // pixels: a vertex where the boundary turns, not on every pixel
export const $ = (id) => document.getElementById(id);

/** The list's filters this frame was opened from: the queue that "next" walks. */
export const CONTEXT = new URLSearchParams(location.search);
if (!CONTEXT.has("order")) CONTEXT.set("order", "uncertainty");
if (!CONTEXT.has("status")) CONTEXT.set("status", "unreviewed"); // the queue: what is still to review
