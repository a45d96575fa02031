"""Signatures of the three real WAAM clips (../shared/data/waam: 0 mm, 2 mm and 4 mm wire
height), from their hand-drawn labels, in mm with the scale each run is given."""

from __future__ import annotations

import re
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.core.models import Frame, Role
from tests.helpers import SHARED_DATA, auth, real_label_masks

SCALES = {"compressed_0mm": 0.031, "compressed_2mm": 0.029, "compressed_mm": 0.033}
"""A scale for each clip's run (mm per pixel; the clips come without one)."""


def test_each_clip_gets_its_signature_in_mm_from_its_labels(
    client: TestClient, session_factory: Any, make_user: Any
) -> None:
    masks = real_label_masks()
    _, token = make_user("engineer", Role.reviewer)
    for clip, scale in SCALES.items():
        run = client.post(
            "/api/v1/sequences",
            json={"name": clip, "mm_per_px": scale, "voltage_v": 12.0, "current_a": 150.0,
                  "robot_speed_cm_min": 20.0},
            headers=auth(token),
        ).json()  # fmt: skip
        labelled = [m for m in masks if m.stem.startswith(clip + "_f")]
        assert len(labelled) == 5
        files = [
            (
                "files",
                (m.name, (SHARED_DATA / "waam" / "frames" / m.name).read_bytes(), "image/png"),
            )
            for m in labelled
        ]
        stored = client.post(
            "/api/v1/frames", files=files, data={"sequence_id": run["id"]}, headers=auth(token)
        ).json()["stored"]
        with session_factory() as session:  # the frames' place in their 15 fps video
            for frame, mask in zip(stored, labelled, strict=True):
                index = int(re.search(r"_f(\d+)$", mask.stem).group(1))  # type: ignore[union-attr]
                row = session.get(Frame, frame["id"])
                row.frame_index, row.timestamp_s = index, index / 15.0
            session.commit()
        for frame, mask in zip(stored, labelled, strict=True):
            import base64

            body = {"status": "corrected", "base_revision": 0, "keypoints": [],
                    "mask_png": base64.b64encode(mask.read_bytes()).decode()}  # fmt: skip
            saved = client.put(
                f"/api/v1/frames/{frame['id']}/label", json=body, headers=auth(token)
            )
            assert saved.status_code == 200, saved.text
        timeline = client.get(f"/api/v1/sequences/{run['id']}/geometry", headers=auth(token)).json()
        signature = client.get(f"/api/v1/sequences/{run['id']}/signature", headers=auth(token))
        found = signature.json()
        assert found["unit"] == "mm" and found["measured"] == 5
        widths = [r["width_px"] for r in timeline["frames"]]
        assert found["width"]["median"] == pytest.approx(float(np.median(widths)) * scale)
        lengths = [r["length_px"] for r in timeline["frames"]]
        assert found["length"]["median"] == pytest.approx(float(np.median(lengths)) * scale)
        assert 5 < found["width"]["median"] < 40  # a WAAM pool: millimetres, not pixels
    result = client.get(
        "/api/v1/process-map", params={"x": "heat_input_j_mm", "y": "width_mm"}, headers=auth(token)
    ).json()
    assert {p["name"] for p in result["points"]} == set(SCALES)
