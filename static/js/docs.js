// The API page: Swagger UI from the vendored bundle (no CDN), reading this server's schema.
// "Try it out" works with the browser's session: writes carry the page's CSRF token (the API
// refuses a session write without it). A token given under Authorize is sent instead, as
// "Authorization: Bearer …", and is kept across reloads (persistAuthorization).
const root = document.getElementById("swagger-ui");
const CSRF = document.querySelector('meta[name="csrf-token"]')?.content ?? "";
window.ui = window.SwaggerUIBundle({
  url: root.dataset.openapiUrl,
  domNode: root,
  deepLinking: true,
  persistAuthorization: true,
  presets: [window.SwaggerUIBundle.presets.apis],
  layout: "BaseLayout",
  requestInterceptor: (request) => {
    const method = (request.method || "GET").toUpperCase();
    const bearer = Object.keys(request.headers || {}).some((name) => name.toLowerCase() === "authorization");
    if (CSRF && !bearer && method !== "GET" && method !== "HEAD") request.headers["X-CSRF-Token"] = CSRF;
    request.credentials = "same-origin";
    return request;
  },
});
