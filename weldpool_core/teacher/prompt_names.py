"""The teacher's prompt configurations by name (the paper's ablation), in a module light enough
for the service's settings, schemas and command line to import without loading a model."""

from __future__ import annotations

from typing import Literal, get_args

PromptName = Literal["none", "center", "heuristic"]
"""``none``: SAM2 alone (its automatic mode); ``center``: a point at the frame's centre;
``heuristic``: the paper's prompts from DINO's attention (``prompts.heuristic_prompts``)."""
PROMPT_NAMES: tuple[PromptName, ...] = get_args(PromptName)
DEFAULT_PROMPTS: PromptName = "heuristic"
