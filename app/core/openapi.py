"""The OpenAPI schema as the API really answers: every error's body and status documented.

FastAPI documents a 422 whose ``detail`` is a list; ours is one sentence plus the list under
``errors`` (``main._install_error_handlers``), and the typed errors (``app.core.errors``) answer
400/401/403/404/409/503 with ``{"detail": "<sentence>"}`` and sometimes more fields (a 409
on a label carries the current ``revision``). This module rewrites the generated schema to say
so, once, for every operation.
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi

from app.core.bounds import NO_NUL_PATTERN

ERROR_SCHEMA: dict[str, Any] = {
    "title": "Error",
    "type": "object",
    "properties": {
        "detail": {"type": "string", "description": "What went wrong, in one sentence."}
    },
    "required": ["detail"],
    "additionalProperties": True,
}
VALIDATION_SCHEMA: dict[str, Any] = {
    "title": "ValidationError",
    "type": "object",
    "properties": {
        "detail": {"type": "string", "description": "The first problem, in one sentence."},
        "errors": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "loc": {
                        "type": "array",
                        "items": {"anyOf": [{"type": "string"}, {"type": "integer"}]},
                    },
                    "msg": {"type": "string"},
                },
                "required": ["loc", "msg"],
            },
        },
    },
    "required": ["detail", "errors"],
}
ERRORS = {
    "400": "The input cannot be used as given.",
    "401": "No valid token or session.",
    "403": "The role does not allow this, or the CSRF token is missing.",
    "404": "The addressed object does not exist.",
    "409": "The request conflicts with the current state (a stale revision, a duplicate).",
    "413": "The request body is larger than WELDPOOL_MAX_REQUEST_MB.",
    "503": "A required part is missing (teacher weights, a migrated database, the queue).",
}
PUBLIC = {"/api/v1/health"}


def _error(description: str, ref: str) -> dict[str, Any]:
    return {
        "description": description,
        "content": {"application/json": {"schema": {"$ref": f"#/components/schemas/{ref}"}}},
    }


def _no_nul_strings(node: Any) -> None:
    """Every free-text string in the schema says it holds no NUL (``bounds.InputModel``)."""
    if isinstance(node, dict):
        if (
            node.get("type") == "string"
            and not {"pattern", "format", "enum", "const"} & node.keys()
        ):
            node["pattern"] = NO_NUL_PATTERN
        for value in node.values():
            _no_nul_strings(value)
    elif isinstance(node, list):
        for value in node:
            _no_nul_strings(value)


def openapi_schema(app: FastAPI) -> dict[str, Any]:
    """The app's schema with the real error bodies; built once, then cached on the app."""
    if app.openapi_schema:
        return app.openapi_schema
    schema = get_openapi(
        title=app.title, version=app.version, summary=app.summary, routes=app.routes
    )
    components = schema.setdefault("components", {}).setdefault("schemas", {})
    components["Error"] = ERROR_SCHEMA
    components["HTTPValidationError"] = VALIDATION_SCHEMA
    components.pop("ValidationError", None)
    for path, operations in schema.get("paths", {}).items():
        for operation in operations.values():
            responses = operation.setdefault("responses", {})
            responses["422"] = _error(
                "The request does not match the schema.", "HTTPValidationError"
            )
            for code, description in ERRORS.items():
                if path in PUBLIC and code != "503":
                    continue
                responses.setdefault(code, _error(description, "Error"))
    components_root = schema["components"]
    components_root["securitySchemes"] = {
        "bearer": {
            "type": "http",
            "scheme": "bearer",
            "description": "An API token (the account page, `weldpool token NAME`, or "
            "`POST /api/v1/tokens` with a name and password). A logged-in browser may instead "
            "send its session cookie and, on writes, its `X-CSRF-Token`: the API page does.",
        },
    }  # the session cookie is not a scheme here: Swagger UI cannot set one, the browser does
    schema["security"] = [{"bearer": []}]
    for path in PUBLIC:
        for operation in schema.get("paths", {}).get(path, {}).values():
            operation["security"] = []
    token = schema.get("paths", {}).get("/api/v1/tokens", {}).get("post")
    if token is not None:  # a script with no token yet sends a username and password instead
        token["security"] = [{"bearer": []}, {}]
    for locked in ("/api/v1/tokens", "/api/v1/users/me/password"):  # wrong passwords count
        operation = schema.get("paths", {}).get(locked, {}).get("post")  # towards the lockout
        if operation is not None:
            operation["responses"]["429"] = _error(
                "Too many wrong passwords; see Retry-After.", "Error"
            )
    _no_nul_strings(schema.get("paths", {}))
    for name, component in components.items():
        if name not in ("Error", "HTTPValidationError") and not name.endswith("Out"):
            _no_nul_strings(component)
    app.openapi_schema = schema
    return schema
