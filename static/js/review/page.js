// The review page's constants: the frame shown, the queue it was opened from, the limits.

export const FRAME_ID = Number(document.getElementById("review").dataset.frameId);
/** Algorithm 1's k, as the server says: the keypoints a validation set places. */
export const K = Number(document.getElementById("review").dataset.keypoints);
export const HISTORY_LIMIT = 40; // each step may hold a full-frame mask (1 MB at 1280×800)
export const OUTLINE_TOLERANCE = 1; // pixels: a vertex where the boundary turns, not on every pixel (the page's Tolerance)
/** Keys the page's own shortcuts take, as the server says (a new configuration's class hotkey
 * is none of them; one saved before the rule is shown struck through and does not pick). */
export const PAGE_KEYS = new Set(document.getElementById("review").dataset.pageKeys);
export const $ = (id) => document.getElementById(id);

/** The list's filters this frame was opened from: the queue that "next" walks. */
export const CONTEXT = new URLSearchParams(location.search);
if (!CONTEXT.has("order")) CONTEXT.set("order", "uncertainty");
// The queue: what is still to review; "my work" (assigned to me, no status or review filter)
// is the server's own list of what was sent back to me, then what is still to review.
const WORK = CONTEXT.get("assignee") === "me" && !CONTEXT.has("review");
if (!CONTEXT.has("status") && !WORK) CONTEXT.set("status", "unreviewed");
