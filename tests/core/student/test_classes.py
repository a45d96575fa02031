"""The label configuration's other classes as extra outputs of the student
(``weldpool_core.student.classes``): a pool-only student is the student as it was, each channel
is read as its class, the figures are the hand-computed ones, the loss reaches only labelled
frames, and the plumbing (checkpoint, predict, export, stream) carries the classes."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.core.student.common import TINY_FRAME, TINY_STUDENT, synthetic_frames, tiny_config
from weldpool_core import synth
from weldpool_core.errors import InvalidInputError
from weldpool_core.io import to_rgb8
from weldpool_core.student import checkpoint
from weldpool_core.student.classes import (
    ClassTruth,
    LearnedClass,
    class_figures,
    class_targets,
    classes_to_frame,
    prepare_classes,
)
from weldpool_core.student.data import FrameGeometry, TrainingFrame, collate, make_targets
from weldpool_core.student.data import prepare_frame as prepare
from weldpool_core.student.losses import class_loss
from weldpool_core.student.model import StudentConfig, build_student
from weldpool_core.student.predict import StudentPredictor
from weldpool_core.student.train import TrainResult, train_student

WIRE = LearnedClass("wire", "mask")
TIP = LearnedClass("wire tip", "points", ("tip",))
CLASSES = (WIRE, TIP)


def _labelled(seed: int) -> TrainingFrame:
    """A synthetic frame with its filler wire (a mask class) and the wire's tip (a point)."""
    width, height = TINY_FRAME.width, TINY_FRAME.height
    frame = synth.synth_frame(seed, TINY_FRAME)
    tip = synth._Pool.draw(np.random.default_rng(seed)).notch_tip(0.0, width, height)
    wire = synth._fill(synth._wire(tip, width, height), (height, width))
    truths = {
        "wire": ClassTruth(mask=wire),
        "wire tip": ClassTruth(points={"tip": (float(tip[0]), float(tip[1]))}),
    }
    return TrainingFrame(to_rgb8(frame.image), frame.mask, None, f"s{seed}", classes=truths)


def test_a_pool_only_student_is_the_student_as_it_was_and_classes_leave_the_pool_alone() -> None:
    plain = TINY_STUDENT
    assert "classes" not in plain.as_dict()  # the saved configuration as before classes
    assert StudentConfig.from_dict(plain.as_dict()) == plain
    torch.manual_seed(0)
    before = build_student(plain, load_pretrained=False).model.eval()
    torch.manual_seed(0)
    learning = build_student(replace(plain, classes=CLASSES), load_pretrained=False).model.eval()
    ours, theirs = before.state_dict(), learning.state_dict()
    assert before.decoder.class_head is None
    assert sorted(set(theirs) - set(ours)) == sorted(
        k for k in theirs if k.startswith("decoder.class_head.")
    )
    assert all(torch.equal(ours[key], theirs[key]) for key in ours)  # same start for the pool
    images = torch.rand(2, 3, 64, 64)
    with torch.no_grad():
        pool, both = before(images, sample=False), learning(images, sample=False)
    assert pool.class_logits is None
    assert both.class_logits is not None and both.class_logits.shape == (2, 2, 64, 64)
    assert torch.equal(pool.mask_logits, both.mask_logits)  # the pool's head is its own
    assert torch.equal(pool.heatmap_logits, both.heatmap_logits)


def test_the_learned_classes_are_saved_with_the_configuration(tmp_path: Path) -> None:
    config = replace(TINY_STUDENT, classes=CLASSES)
    saved = config.as_dict()
    assert saved["classes"] == [
        {"name": "wire", "kind": "mask", "points": []},
        {"name": "wire tip", "kind": "points", "points": ["tip"]},
    ]
    checkpoint.save_config(tmp_path, config, {})
    assert checkpoint.read_student_config(tmp_path).classes == CLASSES
    with pytest.raises(InvalidInputError, match="points class names 1"):
        LearnedClass("tip", "points")
    with pytest.raises(InvalidInputError, match="named once"):
        replace(TINY_STUDENT, classes=(WIRE, WIRE))


def test_class_targets_move_with_the_augmentation_and_absent_labels_are_flagged() -> None:
    geometry = FrameGeometry.fit(40, 40, 32, "resize")
    wire = np.zeros((40, 40), bool)
    wire[0:10, 20:40] = True
    prepared = prepare_classes(CLASSES, {"wire": ClassTruth(mask=wire)}, geometry)
    targets, present = class_targets(prepared, 32, 2.0, None)
    assert targets.shape == (2, 32, 32) and present.tolist() == [1.0, 0.0]
    assert float(targets[1].abs().sum()) == 0.0  # no tip labelled: no target, no loss
    tip = prepare_classes(CLASSES, {"wire tip": ClassTruth(points={"tip": (10.0, 20.0)})}, geometry)
    shift = np.array([[1.0, 0.0, 5.0], [0.0, 1.0, -3.0]])
    moved, flags = class_targets(tip, 32, 2.0, shift)
    peak = np.unravel_index(int(moved[1].argmax()), (32, 32))
    x, y = geometry.to_input(np.array([[10.0, 20.0]]))[0]
    assert flags.tolist() == [0.0, 1.0]
    assert (peak[1], peak[0]) == (round(x + 5), round(y - 3))


def test_each_channel_is_read_as_its_own_class() -> None:
    """Channels follow the stored class order: reading them in another order breaks this."""
    geometry = FrameGeometry.fit(64, 64, 64, "resize")
    probabilities = np.zeros((2, 64, 64), np.float32)
    probabilities[0, 10:20, 30:50] = 0.9  # the wire
    probabilities[1, 40, 12] = 1.0  # the tip's peak
    found = classes_to_frame(probabilities, CLASSES, geometry)
    assert found["wire"].sum() == 10 * 20 and found["wire"][15, 40]
    assert found["wire tip"]["tip"] == pytest.approx([12.0, 40.0], abs=0.01)
    swapped = classes_to_frame(probabilities, (TIP, WIRE), geometry)
    assert swapped["wire"].sum() != 10 * 20


def test_class_figures_against_a_hand_computed_fixture() -> None:
    truth = np.zeros((10, 10), bool)
    truth[0:4, 0:4] = True  # 16 pixels
    drawn = np.zeros((10, 10), bool)
    drawn[2:6, 0:4] = True  # 8 shared of 24: IoU 1/3
    outputs = [
        {"wire": drawn, "wire tip": {"tip": [3.0, 4.0]}},
        {"wire": truth, "wire tip": {"tip": None}},
        {"wire": drawn, "wire tip": {"tip": [9.0, 9.0]}},
    ]
    truths = [
        {"wire": ClassTruth(mask=truth), "wire tip": ClassTruth(points={"tip": (0.0, 0.0)})},
        {"wire": ClassTruth(mask=truth), "wire tip": ClassTruth(points={"tip": (5.0, 5.0)})},
        {},  # nothing of either class labelled: not measured
    ]
    figures = class_figures(CLASSES, outputs, truths, [(10, 10), (6, 8), (10, 10)])
    assert figures["wire"] == {"kind": "mask", "frames": 2, "IoU": pytest.approx((1 / 3 + 1) / 2)}
    tip = figures["wire tip"]
    assert tip["frames"] == 2 and tip["missed"] == 1
    assert tip["distance_px"] == pytest.approx((5.0 + 10.0) / 2)  # 3-4-5, and a missed point
    assert tip["points"] == {"tip": pytest.approx(7.5)}  # counts as its frame's diagonal (10)


def test_the_class_loss_reaches_only_the_frames_that_label_the_class() -> None:
    logits = torch.zeros(2, 2, 8, 8, requires_grad=True)
    target = torch.ones(2, 2, 8, 8)
    present = torch.tensor([[1.0, 0.0], [0.0, 0.0]])
    loss = class_loss(logits, target, present, [True, False])
    loss.backward()  # type: ignore[no-untyped-call]
    assert logits.grad is not None
    assert float(logits.grad[0, 0].abs().sum()) > 0
    assert float(logits.grad[1].abs().sum()) == 0.0 and float(logits.grad[:, 1].abs().sum()) == 0.0
    assert float(class_loss(logits, target, torch.zeros(2, 2), [True, False])) == 0.0


def test_prepared_frames_collate_with_their_class_targets() -> None:
    from weldpool_core.heatmap import HeatmapParams

    frames = [_labelled(0), replace(_labelled(1), classes={})]
    prepared = [prepare(f, 64, "letterbox", HeatmapParams(), CLASSES) for f in frames]
    batch = collate([make_targets(p, 3.0) for p in prepared])
    assert batch.classes is not None and batch.classes.shape == (2, 2, 64, 64)
    assert batch.present is not None and batch.present.tolist() == [[1.0, 1.0], [0.0, 0.0]]
    plain = [prepare(f, 64, "letterbox", HeatmapParams()) for f in frames]
    assert collate([make_targets(p, 3.0) for p in plain]).classes is None


@pytest.fixture(scope="module")
def class_student(tmp_path_factory: pytest.TempPathFactory) -> TrainResult:
    """A tiny student with the wire and its tip, trained two epochs (plumbing, not accuracy)."""
    out = tmp_path_factory.mktemp("class-student") / "model"
    frames = [_labelled(seed) for seed in range(6)]
    return train_student(frames, out, replace(TINY_STUDENT, classes=CLASSES), tiny_config())


def test_a_class_never_changes_what_the_pool_learns(
    class_student: TrainResult, tmp_path: Path
) -> None:
    """The class head reads the pool's features detached: with the same frames and seed the
    pool's weights and figures are exactly those of a student without classes."""
    from safetensors.torch import load_file

    frames = [replace(_labelled(seed), classes={}) for seed in range(6)]
    plain = train_student(frames, tmp_path / "plain", TINY_STUDENT, tiny_config())
    ours = load_file(str(plain.model_dir / "model.safetensors"))
    theirs = load_file(str(class_student.model_dir / "model.safetensors"))
    assert set(theirs) - set(ours) == {k for k in theirs if k.startswith("decoder.class_head.")}
    assert all(torch.equal(ours[key], theirs[key]) for key in ours)
    pool = {k: v for k, v in class_student.metrics.items() if k != "classes"}
    assert pool == plain.metrics and class_student.best_epoch == plain.best_epoch


def test_a_student_with_classes_trains_predicts_and_reports_them(
    class_student: TrainResult,
) -> None:
    figures = class_student.metrics["classes"]
    assert figures["wire"]["kind"] == "mask" and figures["wire"]["frames"] >= 1
    assert figures["wire tip"]["kind"] == "points" and "distance_px" in figures["wire tip"]
    saved = json.loads((class_student.model_dir / checkpoint.METRICS_FILE).read_text())
    assert set(saved["best"]["classes"]) == {"wire", "wire tip"}
    predictor = StudentPredictor.load(class_student.model_dir, "cpu")
    assert predictor.config.classes == CLASSES
    (found,) = predictor.predict([_labelled(50).image])
    assert found.classes["wire"].shape == (TINY_FRAME.height, TINY_FRAME.width)
    assert set(found.classes["wire tip"]) == {"tip"}
    pool_only = synthetic_frames(1)[0]
    assert StudentPredictor.load(class_student.model_dir, "cpu").predict([pool_only.image])


def test_the_stream_adds_the_learned_classes_geometry(class_student: TrainResult) -> None:
    from weldpool_core.cell.stream import StreamStudent, record_fields
    from weldpool_core.cell.stream import run_stream as stream

    student = StreamStudent(class_student.model_dir, backend="torch", device="cpu")
    frame = synth.synth_frame(60, TINY_FRAME)
    bgr = np.repeat(to_rgb8(frame.image)[:, :, :1], 3, axis=2)

    class _Source:
        def __iter__(self):  # type: ignore[no-untyped-def]
            from weldpool_core.cell.stream import CapturedFrame

            yield CapturedFrame(index=0, wall_time=0.0, captured=0.0, bgr=bgr)

    (result,) = list(stream(_Source(), student))  # type: ignore[arg-type]
    assert set(result.record) == set(record_fields())
    classes = result.record["classes"]
    assert set(classes) == {"wire", "wire tip"}
    assert set(classes["wire"]) == {"area_px", "centroid"} and set(classes["wire tip"]) == {"tip"}
    (only,) = list(stream(_Source(), student, classes=("wire tip",)))  # type: ignore[arg-type]
    assert set(only.record["classes"]) == {"wire tip"}
    with pytest.raises(InvalidInputError, match="did not learn the class 'spatter'"):
        list(stream(_Source(), student, classes=("spatter",)))  # type: ignore[arg-type]


def test_the_cell_outputs_are_told_the_classes_chosen_with_classes(tmp_path: Path) -> None:
    """`weldpool stream --classes`: the outputs (the OPC UA server's variables) get the classes
    the records carry, before the first frame."""
    from app.cli.stream import _cell_outputs, stream_cmd

    checkpoint.save_config(tmp_path, replace(TINY_STUDENT, classes=CLASSES), {})
    cell = {option.name: option.default for option in stream_cmd.params}

    def chosen(names: tuple[str, ...] | None) -> object:
        return _cell_outputs(None, cell, tmp_path, True, None, names)[1].classes

    assert chosen(None) == CLASSES and chosen(("wire tip",)) == (TIP,) and chosen(()) == ()
    with pytest.raises(InvalidInputError, match="did not learn the class 'spatter'"):
        chosen(("spatter",))


@pytest.mark.slow
def test_the_extra_channels_learn_the_wire_and_its_tip(tmp_path: Path) -> None:
    """On synthetic frames the wire (a thin band, ~1.5 % of the frame) and its tip are learned
    to figures that an empty or a full channel, or a tip at the frame's centre, do not reach."""
    frames = [_labelled(seed) for seed in range(8)]
    unseen = [_labelled(seed) for seed in range(100, 106)]
    config = tiny_config(epochs=None, steps=400, rounds=4)
    train_student(frames, tmp_path / "m", replace(TINY_STUDENT, classes=CLASSES), config)
    predictions = StudentPredictor.load(tmp_path / "m", "cpu").predict([f.image for f in unseen])
    truths = [f.classes for f in unseen]
    sizes = [f.mask.shape for f in unseen]
    learned = class_figures(CLASSES, [p.classes for p in predictions], truths, sizes)
    shape = (TINY_FRAME.height, TINY_FRAME.width)
    centre = [TINY_FRAME.width / 2, TINY_FRAME.height / 2]
    for fill in (False, True):
        constant = [{"wire": np.full(shape, fill), "wire tip": {"tip": centre}} for _ in unseen]
        baseline = class_figures(CLASSES, constant, truths, sizes)
        assert baseline["wire"]["IoU"] < 0.05
        assert learned["wire"]["IoU"] > 0.1
        assert learned["wire tip"]["distance_px"] < 0.5 * baseline["wire tip"]["distance_px"]


def test_the_onnx_export_carries_the_classes_in_their_order(class_student: TrainResult) -> None:
    from weldpool_core.cell.stream import StreamStudent
    from weldpool_core.student.checkpoint import EXPORT_FILE
    from weldpool_core.student.export import export_student

    exported = export_student(class_student.model_dir, ["onnx"])
    assert exported.differences["onnx"] < 1e-4  # every output, the classes' included
    described = json.loads((class_student.model_dir / EXPORT_FILE).read_text())
    assert described["classes"] == [c.as_dict() for c in CLASSES]
    assert described["outputs"]["classes"].endswith("channels: wire, wire tip:tip")
    student = StreamStudent(class_student.model_dir, backend="onnx")
    batch, geometry = student.prepare(np.ascontiguousarray(_labelled(7).image[:, :, ::-1]))
    student(batch, geometry)
    assert student.extra is not None and student.extra.shape == (2, 64, 64)
