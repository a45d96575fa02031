"""The ResNet-VAE: sizes, shapes, the latent, ImageNet weights from a local folder, BN folding."""

from __future__ import annotations

import copy
from dataclasses import replace
from pathlib import Path

import pytest
import torch
from transformers import ResNetModel

from weldpool_core.errors import InvalidInputError
from weldpool_core.student.model import (
    STUDENT_SIZES,
    StudentConfig,
    _resnet_config,
    build_student,
    fuse_batchnorm,
    kl_divergence,
    student_config,
)


@pytest.mark.parametrize("size", sorted(STUDENT_SIZES))
def test_every_size_maps_frames_to_two_maps_at_the_input_size(size: str) -> None:
    config = student_config(size, input_size=64, pretrained=False)
    model = build_student(config).model.eval()
    images = torch.rand(2, 3, 64, 64)
    output = model(images, sample=False)
    assert output.mask_logits.shape == output.heatmap_logits.shape == (2, 64, 64)
    assert output.mean.shape == output.logvar.shape == (2, config.latent_channels, 2, 2)


def test_resnet34_is_deeper_and_light_is_narrower_than_the_default() -> None:
    def parameters(config: StudentConfig) -> int:
        return sum(p.numel() for p in build_student(config).model.parameters())

    default = parameters(student_config("resnet18", pretrained=False))
    assert parameters(student_config("resnet34", pretrained=False)) > 1.5 * default
    assert parameters(student_config("light")) < default / 10
    assert STUDENT_SIZES["resnet18"].input_size == 256
    assert STUDENT_SIZES["light"] == StudentConfig()  # the default is the light layout


def test_samples_differ_and_the_mean_is_deterministic() -> None:
    model = build_student(student_config("light", input_size=64)).model.eval()
    images = torch.rand(1, 3, 64, 64)
    with torch.no_grad():
        model.to_latent.bias.fill_(0.5)  # a visible posterior spread
        first, again = model(images, sample=False), model(images, sample=False)
        drawn = model(images, sample=True, generator=torch.Generator().manual_seed(1))
    assert torch.equal(first.mask_logits, again.mask_logits)
    assert not torch.allclose(first.mask_logits, drawn.mask_logits)


def test_samples_have_the_posterior_mean_and_standard_deviation(monkeypatch) -> None:
    """latent = mean + ε·exp(½·logvar): over many draws the latent's mean and standard
    deviation are the posterior's (exp(logvar) instead would give σ² here, 4 instead of 2)."""
    model = build_student(student_config("light", input_size=64)).model.eval()
    mean = torch.full((4000, 2, 1, 1), 3.0)
    logvar = torch.full((4000, 2, 1, 1), float(2 * torch.log(torch.tensor(2.0))))  # σ = 2
    seen: list[torch.Tensor] = []
    monkeypatch.setattr(model, "encode", lambda images: (mean, logvar, ()))
    monkeypatch.setattr(
        model, "decode", lambda latent, skips: (seen.append(latent) or latent, latent)
    )
    model(torch.zeros(1), sample=True, generator=torch.Generator().manual_seed(0))
    latent = seen[0]
    assert float(latent.mean()) == pytest.approx(3.0, abs=0.1)
    assert float(latent.std()) == pytest.approx(2.0, rel=0.05)
    model(torch.zeros(1), sample=False)
    assert torch.equal(seen[1], mean)


def test_kl_is_zero_at_the_prior_and_positive_elsewhere() -> None:
    zeros = torch.zeros(2, 4, 3, 3)
    assert float(kl_divergence(zeros, zeros)) == 0.0
    assert float(kl_divergence(zeros + 1, zeros)) == pytest.approx(0.5)


def test_imagenet_weights_load_from_a_local_folder(tmp_path: Path) -> None:
    config = student_config("resnet18", input_size=64)
    reference = ResNetModel(_resnet_config(config))
    reference.save_pretrained(tmp_path / "resnet")
    built = build_student(replace(config, encoder_weights=str(tmp_path / "resnet")))
    assert built.pretrained and not built.notes
    stem = built.model.stem.embedder.convolution.weight
    assert torch.equal(stem, reference.embedder.embedder.convolution.weight)
    missing = build_student(replace(config, encoder_weights=str(tmp_path / "none")))
    assert not missing.pretrained and "random" in missing.notes[0]
    narrow = build_student(StudentConfig(input_size=64, encoder_weights=str(tmp_path / "resnet")))
    assert not narrow.pretrained and not narrow.notes  # the default width has no such weights


def test_folding_batchnorm_keeps_the_outputs() -> None:
    model = build_student(student_config("light", input_size=64)).model
    model.train()
    with torch.no_grad():  # give BatchNorm statistics that are not the identity
        for _ in range(3):
            model(torch.rand(4, 3, 64, 64))
    model.eval()
    images = torch.rand(2, 3, 64, 64)
    with torch.no_grad():
        expected = model(images, sample=False).mask_logits
        fused = fuse_batchnorm(copy.deepcopy(model))
        found = fused(images, sample=False).mask_logits  # type: ignore[operator]
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in fused.modules())
    assert torch.allclose(found, expected, atol=1e-4)


def test_configurations_round_trip_and_bad_ones_are_refused() -> None:
    config = student_config("light", aspect="resize")
    assert StudentConfig.from_dict(config.as_dict()) == config
    with pytest.raises(InvalidInputError, match="multiple of 32"):
        StudentConfig(input_size=100)
    with pytest.raises(InvalidInputError, match="encoder must be one of"):
        StudentConfig(encoder="resnet50")
    with pytest.raises(InvalidInputError, match="Unknown model size"):
        student_config("huge")
    with pytest.raises(InvalidInputError, match="Unknown student configuration keys"):
        StudentConfig.from_dict({"layers": 3})
    with pytest.raises(InvalidInputError, match="skips must be 0 to 3"):
        StudentConfig(skips=4)
    with pytest.raises(InvalidInputError, match="keypoints must be mask or heatmap"):
        StudentConfig(keypoints="corners")  # type: ignore[arg-type]
    # A folder saved before a key existed loads as it was trained and used, whatever the
    # default is now.
    changed = replace(config, skips=2, keypoints="mask")
    for key, before in (("skips", 0), ("keypoints", "heatmap")):
        saved_before = {k: v for k, v in changed.as_dict().items() if k != key}
        assert getattr(StudentConfig.from_dict(saved_before), key) == before
    assert StudentConfig.from_dict(changed.as_dict()) == changed


def test_skips_carry_the_frames_own_detail_past_the_latent() -> None:
    """With ``skips`` the decoder adds the encoder's stride-16, 8 and 4 maps of the frame itself:
    the same latent decodes differently with another frame's maps. Without, nothing passes by
    the latent."""
    a, b = torch.rand(2, 1, 3, 64, 64, generator=torch.Generator().manual_seed(0))
    for skips in (0, 1, 3):
        torch.manual_seed(0)
        model = build_student(student_config("light", input_size=64, skips=skips)).model.eval()
        with torch.no_grad():
            mean, _, maps_a = model.encode(a)
            _, _, maps_b = model.encode(b)
            own = model.decode(mean, maps_a)[0]
            other = model.decode(mean, maps_b)[0]
            whole = model(a, sample=False).mask_logits
        assert [m.shape[-1] for m in maps_a] == [4, 8, 16][:skips]  # strides 16, 8, 4
        if skips == 3:  # the stride-4 map is the first stage's output, not the stem's
            with torch.no_grad():
                stem = model.stem((a - model.pixel_mean) / model.pixel_std)
                torch.testing.assert_close(maps_a[2], model.stages.stages[0](stem))
        torch.testing.assert_close(own, whole)
        assert (own - other).abs().max() > 1e-3 if skips else torch.equal(own, other)
        if skips:
            with pytest.raises(ValueError, match=f"takes {skips} skip map"):
                model.decode(mean)
