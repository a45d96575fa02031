"""Teacher weights and the offline teacher from the command line."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from app.cli.base import fail, friendly_errors, image_files, load_settings, main
from app.core.config import Settings
from app.core.errors import WeldpoolError
from app.teacher import runtime
from weldpool_core.teacher.prompt_names import DEFAULT_PROMPTS, PROMPT_NAMES, PromptName


@main.group()
def weights() -> None:
    """Download and check the teacher's model weights."""


def _weights_refs(settings: Settings) -> list[tuple[str, str]]:
    return [(settings.dino, "WELDPOOL_DINO"), (settings.sam2, "WELDPOOL_SAM2")]


@weights.command("status")
@friendly_errors
def weights_status_cmd() -> None:
    """Report where the teacher weights are; exit 2 when any is missing."""
    from weldpool_core.teacher.weights import weights_status

    statuses = [weights_status(ref, var) for ref, var in _weights_refs(load_settings())]
    click.echo(json.dumps([s.as_dict() for s in statuses], indent=2))
    missing = [s for s in statuses if not s.available]
    if missing:
        fail(missing[0].detail)


@weights.command("fetch")
@friendly_errors
def weights_fetch() -> None:
    """Download the teacher weights into the Hugging Face cache (needs internet)."""
    from weldpool_core.teacher.weights import fetch_weights

    for ref, var in _weights_refs(load_settings()):
        status = fetch_weights(ref, var)
        click.echo(f"{ref}: {status.detail} ({status.path})", err=True)


@weights.command("convert-dino")
@click.argument("checkpoint", type=click.Path(path_type=Path))
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path))
@friendly_errors
def weights_convert_dino(checkpoint: Path, out_dir: Path) -> None:
    """Convert Meta's DINO checkpoint (e.g. dino_deitsmall8_pretrain.pth) for WELDPOOL_DINO."""
    from weldpool_core.teacher.convert import convert_meta_dino

    if out_dir.exists() and any(out_dir.iterdir()):
        fail(f"{out_dir} is not empty; give a new folder for the converted model.")
    config = convert_meta_dino(checkpoint, out_dir)
    click.echo(
        f"wrote ViT ({config.num_hidden_layers} blocks, width {config.hidden_size}, patch "
        f"{config.patch_size}) to {out_dir}; set WELDPOOL_DINO={out_dir.resolve()}",
        err=True,
    )


PROMPT_CHOICE = click.Choice(PROMPT_NAMES)


@main.command("teacher")
@click.argument("images", nargs=-1, required=True)
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--prompts",
    type=PROMPT_CHOICE,
    default=DEFAULT_PROMPTS,
    show_default=True,
    help="Prompt configuration (the paper's ablation).",
)
@friendly_errors
def teacher_cmd(images: tuple[str, ...], out_dir: Path, prompts: PromptName) -> None:
    """Run the teacher offline on images (files or folders).

    Writes per image <stem>_mask.png (0 / 255), <stem>_heatmap.npy (H×W×2: heatmap, mask) and
    <stem>.json (keypoints, prompts, scores, timings). Weights: WELDPOOL_DINO, WELDPOOL_SAM2.
    """
    import hashlib

    import numpy as np

    from weldpool_core.io import encode_mask_png, read_image, to_rgb8

    settings = load_settings()
    files = image_files(images)
    teacher = runtime.teacher(settings, prompts)
    out_dir.mkdir(parents=True, exist_ok=True)
    with click.progressbar(files, label="teacher", file=sys.stderr) as bar:
        for path in bar:
            data = path.read_bytes()
            try:
                image = read_image(data, max_pixels=settings.max_image_pixels)
            except WeldpoolError as exc:
                fail(f"{path}: {exc.message}")
            result = teacher.run(to_rgb8(image), hashlib.sha256(data).hexdigest())
            (out_dir / f"{path.stem}_mask.png").write_bytes(encode_mask_png(result.mask))
            heatmap = result.heatmap
            if heatmap is None:  # no keypoints: an empty heatmap beside the mask
                heatmap = np.stack(
                    [np.zeros(result.mask.shape, np.float32), result.mask.astype(np.float32)],
                    axis=2,
                )
            np.save(out_dir / f"{path.stem}_heatmap.npy", heatmap)
            record = {
                "keypoints": result.keypoints,
                "keypoint_rules": result.keypoint_rules,
                "score": result.score,
                "object_score": result.object_score,
                "prompts": result.prompts.as_dict(),
                "prompt_config": prompts,
                "model_id": teacher.model_id,
                "timings": result.timings,
                "width": int(result.mask.shape[1]),
                "height": int(result.mask.shape[0]),
                "image": str(path),
                "warning": result.warning,
            }
            (out_dir / f"{path.stem}.json").write_text(json.dumps(record, indent=2) + "\n")
    click.echo(f"wrote teacher proposals for {len(files)} image(s) to {out_dir}", err=True)
