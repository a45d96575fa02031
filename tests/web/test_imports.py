"""The frames page's Import labels dialog in a real browser: a COCO zip with one bad
annotation is imported, the refusal is listed with its reason, and the new run appears."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.factories import synthetic_png
from tests.imports.common import zipped
from tests.pages import login, shoot
from tests.web.server import LiveServer
from weldpool_core.outline import coco_mask
from weldpool_core.synth import SynthParams, synth_frame

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def test_import_labels_from_the_frames_page_lists_what_it_refused(
    page: Any, server: LiveServer, tmp_path: Path
) -> None:
    truth = synth_frame(seed=77, params=SynthParams(640, 400)).mask
    rle = coco_mask(truth).rle
    coco = {
        "images": [
            {"id": 1, "file_name": "weld-a.png", "width": 640, "height": 400},
            {"id": 2, "file_name": "weld-b.png", "width": 640, "height": 400},
        ],
        "annotations": [
            {"id": 1, "image_id": 1, "category_id": 1, "segmentation": rle, "iscrowd": 1},
            {"id": 2, "image_id": 2, "category_id": 2, "segmentation": rle},
            {"id": 3, "image_id": 9, "category_id": 1, "segmentation": rle},
        ],
        "categories": [{"id": 1, "name": "weld_pool"}, {"id": 2, "name": "wire"}],
    }
    archive = tmp_path / "cvat-coco-export.zip"
    archive.write_bytes(
        zipped(
            {
                "annotations/instances_default.json": json.dumps(coco).encode(),
                "images/weld-a.png": synthetic_png(77, 640, 400),
                "images/weld-b.png": synthetic_png(78, 640, 400),
            }
        )
    )
    login(page, server, "anna")
    page.goto(f"{server.url}/?status=all")
    page.wait_for_selector("body[data-ready]")
    shoot(page, "frames-import-button")  # Import labels beside Export
    page.click("[data-testid=import-open]")
    page.set_input_files("[data-testid=import-file]", str(archive))
    page.select_option("[data-testid=import-format]", "coco")
    page.click("[data-testid=import-start]")
    page.wait_for_selector("[data-testid=import-summary]", timeout=60_000)
    assert page.inner_text("[data-testid=import-summary]") == (
        "1 label and 0 keypoint sets imported, 1 new frame."
    )
    refused = page.inner_text("[data-testid=import-refused]")
    assert "Refused: 1" in refused
    assert "It names image 9, which the file does not list." in refused
    shoot(page, "import-dialog")
    page.click("[data-testid=import-close]")
    page.wait_for_selector("text=cvat-coco-export")  # the new run, in the sequence list
    run = next(s for s in server.api("GET", "/sequences").json() if s["name"] == "cvat-coco-export")
    frames = server.api("GET", "/frames", params={"sequence_id": run["id"]}).json()["items"]
    assert [f["status"] for f in frames] == ["corrected"]
    label = server.api("GET", f"/frames/{frames[0]['id']}/label").json()
    import base64

    from weldpool_core.io import decode_mask_png

    assert np.array_equal(decode_mask_png(base64.b64decode(label["mask_png"])), truth)
