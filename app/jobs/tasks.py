"""Built-in job kinds of the jobs domain."""

from __future__ import annotations

import os
import socket
import time
from typing import Any

from app.core.errors import InvalidInputError, WeldpoolError
from app.jobs.registry import JobContext, job_handler


@job_handler("diagnostic", lane="quick")
def diagnostic(ctx: JobContext) -> dict[str, Any]:
    """Prove that a worker runs jobs: wait ``seconds`` in steps with progress, optionally fail.

    Admins start it to check a deployment's workers (``POST /api/v1/jobs/diagnostic``).
    """
    seconds = float(ctx.params.get("seconds", 0.0))
    if not 0 <= seconds <= 3600:
        raise InvalidInputError("seconds must be between 0 and 3600.")
    steps = max(1, int(seconds * 4))
    for step in range(steps):
        time.sleep(seconds / steps)
        ctx.progress((step + 1) / steps, f"step {step + 1} of {steps}")
    if ctx.params.get("fail"):
        raise WeldpoolError(str(ctx.params["fail"]))
    ctx.summary = f"worker {ctx.worker_id} ran it for {seconds:g} s"
    return {
        "seconds": seconds,
        "worker": ctx.worker_id,
        "host": socket.gethostname(),
        "pid": os.getpid(),
    }
