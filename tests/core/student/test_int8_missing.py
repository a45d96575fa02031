"""Streaming int8 from a folder without its int8 student says where to make one: the models
page's "Make int8", or the command that quantizes."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.core.student.common import TINY_STUDENT
from weldpool_core.errors import InvalidInputError
from weldpool_core.student.runners import Int8Runner, RunnerOptions


def test_a_missing_int8_student_names_the_page_and_the_command(tmp_path: Path) -> None:
    with pytest.raises(InvalidInputError) as refused:
        Int8Runner(RunnerOptions(model_dir=tmp_path, config=TINY_STUDENT))
    message = str(refused.value)
    assert message.startswith(f"{tmp_path} has no model.int8.onnx; make the int8 student first")
    assert "“Make int8” on the models page" in message
    assert f"weldpool export-student {tmp_path} --format onnx-int8 --calibrate FRAMES" in message
