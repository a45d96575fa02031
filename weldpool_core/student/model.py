"""The student: a ResNet-VAE that maps a frame to the pool's mask and keypoint heatmap.

ResNet encoder (transformers' ``ResNetModel``, no torchvision) → a spatial latent at stride 32
(mean and log-variance per cell, ``latent_channels`` deep) → a sample (training) or the mean
(inference) → a convolutional decoder (four ×2 nearest-neighbour upsamplings, each followed by a
3×3 conv, BatchNorm and ReLU, to half the input size; a 1×1 head; a final ×2 bilinear
upsampling) → two channels at the input size: the mask logit and the heatmap logit. The last
step is bilinear rather than a fifth conv stage because the targets are smooth at that scale
(antialiased mask edges, Gaussians of σ ≥ 2 px) while a conv stage at full size costs more time
than any other part of training on a CPU (memory traffic, not arithmetic).

The latent is spatial rather than one vector so that the decoder keeps the pool's position
without learning it from scratch. With ``skips`` (default 2; 0–3) the encoder's stride-16 and 8
(and 4) maps of the frame are added (after a 1×1 projection) to the decoder's input at the same
scale, so fine detail (the pool's front at the wire) need not pass through the stride-32 grid:
on the real labels two skips lift the mask across clips from 0.825 to 0.87 mIoU and within a
clip from 0.938 to 0.959 (``bench/real_student.py``, docs/benchmarks). With 0 everything the decoder
draws passes through the latent.

The encoder takes RGB in [0, 1]; the ImageNet normalisation happens inside the model, so an
exported model needs nothing but the letterboxed (or resized) frame scaled to [0, 1].
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Literal, TypeVar, cast

import torch
import torch.nn.functional as F
from torch import nn
from transformers import ResNetConfig, ResNetModel

from weldpool_core.errors import InvalidInputError
from weldpool_core.student.classes import LearnedClass, initial_bias

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
STRIDE = 32
"""The encoder's output stride: the input size must be a multiple of it."""

CLASS_HEAD_CHANNELS = 16
"""Least width of the learned classes' head (``Decoder``)."""
Aspect = Literal["letterbox", "resize"]
KeypointSource = Literal["mask", "heatmap"]
ModuleT = TypeVar("ModuleT", bound=nn.Module)


@dataclass(frozen=True)
class EncoderSpec:
    """A ResNet family member: blocks per stage, and the hub id of its ImageNet weights."""

    depths: tuple[int, int, int, int]
    hub_id: str
    widths: tuple[int, int, int, int] = (64, 128, 256, 512)


ENCODERS: dict[str, EncoderSpec] = {
    "resnet18": EncoderSpec((2, 2, 2, 2), "microsoft/resnet-18"),
    "resnet34": EncoderSpec((3, 4, 6, 3), "microsoft/resnet-34"),
}
"""The encoders on offer, by name (a registry, so a new one is one line)."""


BEFORE_THE_KEY: dict[str, Any] = {"skips": 0, "keypoints": "heatmap"}
"""What a saved configuration without one of these keys was trained and used with."""


@dataclass(frozen=True)
class StudentConfig:
    """The student's architecture and input geometry (stored in every checkpoint).

    Attributes:
        encoder: a name in ``ENCODERS`` (``resnet18`` default, ``resnet34``).
        width: channel multiplier of the encoder and decoder (default 0.25: the ``light``
            layout). 1.0 is the standard ResNet, whose ImageNet weights can load (the
            ``resnet18`` and ``resnet34`` sizes); narrower encoders start from random weights.
            The default is narrow because, from a random start on a CPU, the quarter-width
            network trained for 800 steps learns the real pool better in the same minutes
            than the full-width one can be trained (``bench/real_student.py``).
        input_size: side of the square model input, a multiple of 32 (default 256).
        aspect: ``letterbox`` (default: scale the frame to fit, pad the rest with black, so
            shapes keep their proportions) or ``resize`` (stretch to the square). Either way the
            outputs are mapped back to full-resolution pixels (see ``student.data.FrameGeometry``).
        latent_channels: depth of the latent per stride-32 cell (default 32).
        decoder_channels: channels after each of the four decoder upsamplings (before
            ``width``).
        k: keypoints per frame.
        keypoints: where they are read (``student.predict.frame_keypoints``): ``mask``
            (default) Algorithm 1 on the predicted mask, the rule a label's keypoints follow;
            ``heatmap`` the predicted heatmap's modes. A model folder saved before this choice
            existed reads its keypoints from the heatmap, as it did.
        pretrained: start the encoder from ImageNet weights when they are on this machine
            (``encoder_weights``: a local ``save_pretrained`` directory or a hub id in the local
            cache; default the encoder's ``hub_id``); random weights otherwise.
        encoder_weights: where the ImageNet weights are, overriding the encoder's hub id.
        skips: how many of the encoder's finer maps (strides 16, 8, 4, in that order) feed the
            decoder beside the latent (default 2; see the module doc).
        classes: the label configuration's other classes learned beside the pool, as extra
            output channels of their own head (``student.classes``; default none: the pool
            alone, the same network and saved configuration as before classes existed).
    """

    encoder: str = "resnet18"
    width: float = 0.25
    input_size: int = 256
    aspect: Aspect = "letterbox"
    latent_channels: int = 32
    decoder_channels: tuple[int, int, int, int] = (256, 128, 64, 32)
    k: int = 4
    pretrained: bool = True
    encoder_weights: str | None = None
    skips: int = 2
    keypoints: KeypointSource = "mask"
    classes: tuple[LearnedClass, ...] = ()

    def __post_init__(self) -> None:
        problems = []
        if self.encoder not in ENCODERS:
            problems.append(f"encoder must be one of {', '.join(ENCODERS)}, not {self.encoder!r}")
        if self.input_size < STRIDE or self.input_size % STRIDE:
            problems.append(f"input_size must be a positive multiple of 32, not {self.input_size}")
        if self.aspect not in ("letterbox", "resize"):
            problems.append(f"aspect must be letterbox or resize, not {self.aspect!r}")
        if not 0 < self.width <= 4 or self.latent_channels < 1 or self.k < 1:
            problems.append("width must lie in (0, 4], latent_channels and k be positive")
        if not 0 <= self.skips <= 3:
            problems.append(f"skips must be 0 to 3, not {self.skips}")
        if self.keypoints not in ("mask", "heatmap"):
            problems.append(f"keypoints must be mask or heatmap, not {self.keypoints!r}")
        if len(self.decoder_channels) != 4 or min(self.decoder_channels) < 1:
            problems.append("decoder_channels must be four positive numbers")
        if len({c.name for c in self.classes}) != len(self.classes):
            problems.append("each learned class must be named once")
        if problems:
            raise InvalidInputError(f"Bad student configuration: {'; '.join(problems)}.")

    @property
    def extra_channels(self) -> int:
        """Output channels of the learned classes (0 without classes)."""
        return sum(c.channels for c in self.classes)

    @property
    def spec(self) -> EncoderSpec:
        """The encoder's registry entry."""
        return ENCODERS[self.encoder]

    def channels(self, base: int) -> int:
        """``base`` channels scaled by ``width`` (at least 8)."""
        return max(8, round(base * self.width))

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (``from_dict`` reads it back); ``classes`` only when there are some,
        so that a pool-only student saves what it saved before classes existed."""
        data = asdict(self)
        data.pop("classes")
        if self.classes:
            data["classes"] = [c.as_dict() for c in self.classes]
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> StudentConfig:
        """The configuration saved by ``as_dict``; unknown keys are refused, and a key saved
        before it existed takes the value that folder was trained and used with."""
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(data) - known)
        if unknown:
            raise InvalidInputError(f"Unknown student configuration keys: {', '.join(unknown)}.")
        values = BEFORE_THE_KEY | dict(data)
        if "decoder_channels" in values:
            values["decoder_channels"] = tuple(values["decoder_channels"])
        values["classes"] = tuple(LearnedClass.from_dict(c) for c in values.get("classes") or ())
        return cls(**values)


STUDENT_SIZES: dict[str, StudentConfig] = {
    "resnet18": StudentConfig(width=1.0, latent_channels=64),
    "resnet34": StudentConfig(encoder="resnet34", width=1.0, latent_channels=64),
    "light": StudentConfig(),
}
"""Named model sizes: the full ResNet18 at 256² (ImageNet weights when present), ResNet34, and
``light``, the default (``StudentConfig()``): the ResNet18 layout at a quarter of the channels,
still at 256² so that keypoints keep the pixel precision (about 1/14 of ResNet18's FLOPs;
random start, as no ImageNet weights exist at that width). Light is what learns the real pool
best from a few labels in minutes on a CPU; ResNet18 is for a GPU, with ImageNet weights."""


def student_config(size: str, **changes: Any) -> StudentConfig:
    """The configuration of a named size (``STUDENT_SIZES``), with ``changes`` applied."""
    if size not in STUDENT_SIZES:
        raise InvalidInputError(
            f"Unknown model size {size!r}; use one of {', '.join(STUDENT_SIZES)}."
        )
    return replace(STUDENT_SIZES[size], **changes)


@dataclass
class StudentOutput:
    """What the ResNet-VAE returns for a batch (N×… tensors at the input size).

    Attributes:
        mask_logits: N×H×W logits of the pool mask.
        heatmap_logits: N×H×W logits of the keypoint heatmap (``sigmoid`` gives [0, 1]).
        mean: N×C×h×w latent mean (h = H / 32).
        logvar: N×C×h×w latent log-variance.
        class_logits: N×E×H×W logits of the learned classes' channels (``student.classes``),
            None for a pool-only student.
    """

    mask_logits: torch.Tensor
    heatmap_logits: torch.Tensor
    mean: torch.Tensor
    logvar: torch.Tensor
    class_logits: torch.Tensor | None = None


def _conv_bn_relu(in_channels: int, out_channels: int, kernel: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(in_channels, out_channels, kernel, padding=kernel // 2, bias=False),
        nn.BatchNorm2d(out_channels),
        nn.ReLU(inplace=True),
    )


class Decoder(nn.Module):
    """Latent (stride 32) → two logit channels at the input size (see the module doc), and
    ``extra`` more for the learned classes from a head of their own (two 3×3 conv stages and a
    1×1 conv) on the same features, detached: the classes' loss never reaches the encoder and
    decoder the pool uses, so a class cannot lower what the pool learns (with the same seed
    the pool's weights train exactly as without classes)."""

    def __init__(
        self,
        latent_channels: int,
        channels: tuple[int, ...],
        skip_channels: tuple[int, ...] = (),
        extra: int = 0,
    ) -> None:
        super().__init__()
        self.entry = _conv_bn_relu(latent_channels, channels[0], 1)
        stages = []
        previous = channels[0]
        inputs = []
        for out_channels in channels:
            inputs.append(previous)
            stages.append(_conv_bn_relu(previous, out_channels, 3))
            previous = out_channels
        self.stages = nn.ModuleList(stages)
        # skip_channels[i]: the encoder map at stage i's scale (stride 16, 8, 4), added after
        # a 1×1 projection before the stage's conv
        self.skips = nn.ModuleList(nn.Conv2d(c, inputs[i], 1) for i, c in enumerate(skip_channels))
        self.head = nn.Conv2d(previous, 2, 1)
        # made last, so a student with classes starts its pool with a pool-only one's weights
        wide = max(previous, CLASS_HEAD_CHANNELS)
        self.class_head = (
            nn.Sequential(
                _conv_bn_relu(previous, wide, 3),
                _conv_bn_relu(wide, wide, 3),
                nn.Conv2d(wide, extra, 1),
            )
            if extra
            else None
        )

    def forward(self, latent: torch.Tensor, skips: tuple[torch.Tensor, ...] = ()) -> torch.Tensor:
        """Decode an N×C×h×w latent into N×(2 + extra)×32h×32w logits (mask, heatmap, then
        the learned classes' channels)."""
        if len(skips) != len(self.skips):
            plural = "" if len(self.skips) == 1 else "s"
            raise ValueError(
                f"This decoder takes {len(self.skips)} skip map{plural}, not {len(skips)}."
            )
        features = self.entry(latent)
        for index, stage in enumerate(self.stages):
            features = F.interpolate(features, scale_factor=2.0, mode="nearest")
            if index < len(self.skips):
                features = features + self.skips[index](skips[index])
            features = stage(features)
        logits = _upsample(self.head(features))
        if self.class_head is None:
            return logits
        # upsampled apart, so the pool's logits are computed exactly as without classes
        return torch.cat([logits, _upsample(self.class_head(features.detach()))], dim=1)


def _upsample(logits: torch.Tensor) -> torch.Tensor:
    """The decoder's last ×2 step (bilinear; see the module doc)."""
    return F.interpolate(logits, scale_factor=2.0, mode="bilinear", align_corners=False)


def _resnet_config(config: StudentConfig) -> ResNetConfig:
    spec = config.spec
    return ResNetConfig(
        num_channels=3,
        embedding_size=config.channels(spec.widths[0]),
        hidden_sizes=[config.channels(w) for w in spec.widths],
        depths=list(spec.depths),
        layer_type="basic",
        hidden_act="relu",
        downsample_in_first_stage=False,
    )


class ResNetVAE(nn.Module):
    """The student network (see the module doc); ``forward`` takes RGB in [0, 1], N×3×S×S."""

    pixel_mean: torch.Tensor
    pixel_std: torch.Tensor

    def __init__(self, config: StudentConfig, encoder: ResNetModel | None = None) -> None:
        super().__init__()
        self.config = config
        resnet = encoder if encoder is not None else ResNetModel(_resnet_config(config))
        self.stem = resnet.embedder
        self.stages = resnet.encoder
        features = config.channels(config.spec.widths[-1])
        self.to_latent = nn.Conv2d(features, 2 * config.latent_channels, 1)
        widths = [config.channels(w) for w in config.spec.widths]
        self.decoder = Decoder(
            config.latent_channels,
            tuple(config.channels(c) for c in config.decoder_channels),
            tuple(widths[2::-1][: config.skips]),
            config.extra_channels,
        )
        self.register_buffer("pixel_mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1))
        self.register_buffer("pixel_std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1))
        with torch.no_grad():
            self.to_latent.weight.zero_()  # start at mean 0, log-variance 0: the prior
            cast(torch.Tensor, self.to_latent.bias).zero_()
            # the heatmap is mostly 0: start it low (as CenterNet does)
            cast(torch.Tensor, self.decoder.head.bias).copy_(torch.tensor([0.0, -4.0]))
            if self.decoder.class_head is not None:
                last = cast(nn.Conv2d, self.decoder.class_head[-1])
                cast(torch.Tensor, last.bias).copy_(initial_bias(config.classes))

    def encoder_maps(self, images: torch.Tensor) -> tuple[torch.Tensor, tuple[torch.Tensor, ...]]:
        """The encoder's last feature map (N×F×S/32×S/32) of RGB images in [0, 1], and the
        maps its decoder takes as skips (strides 16, 8, 4; ``config.skips`` of them)."""
        pixels = (images - self.pixel_mean) / self.pixel_std
        if not self.config.skips:
            return self.stages(self.stem(pixels), return_dict=False)[0], ()
        last, hidden = self.stages(self.stem(pixels), output_hidden_states=True, return_dict=False)
        return last, tuple(hidden[3:0:-1][: self.config.skips])

    def features(self, images: torch.Tensor) -> torch.Tensor:
        """The encoder's last feature map (N×F×S/32×S/32) of RGB images in [0, 1]."""
        return self.encoder_maps(images)[0]

    def posterior(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Latent mean and log-variance of encoder features."""
        mean, logvar = self.to_latent(features).chunk(2, dim=1)
        return mean, logvar.clamp(-12.0, 6.0)

    def encode(
        self, images: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, tuple[torch.Tensor, ...]]:
        """Latent mean and log-variance (N×C×S/32×S/32) of RGB images in [0, 1], and the
        encoder maps ``decode`` takes with them (none unless ``config.skips``)."""
        last, skips = self.encoder_maps(images)
        mean, logvar = self.posterior(last)
        return mean, logvar, skips

    def decode(
        self, latent: torch.Tensor, skips: tuple[torch.Tensor, ...] = ()
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Mask logits and heatmap logits (N×S×S each) of a latent (and the frame's skip maps)."""
        mask_logits, heatmap_logits, _ = self.decode_all(latent, skips)
        return mask_logits, heatmap_logits

    def decode_all(
        self, latent: torch.Tensor, skips: tuple[torch.Tensor, ...] = ()
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """``decode`` and the learned classes' logits (N×E×S×S; None without classes)."""
        logits = self.decoder(latent, skips)
        extra = logits[:, 2:] if self.decoder.class_head is not None else None
        return logits[:, 0], logits[:, 1], extra

    def forward(
        self, images: torch.Tensor, sample: bool = True, generator: torch.Generator | None = None
    ) -> StudentOutput:
        """Encode, sample the latent (or take its mean when ``sample`` is False), decode."""
        mean, logvar, skips = self.encode(images)
        latent = mean
        if sample:
            noise = torch.randn(
                mean.shape, generator=generator, device=mean.device, dtype=mean.dtype
            )
            latent = mean + noise * torch.exp(0.5 * logvar)
        if self.decoder.class_head is None:  # the pool alone, as before classes existed
            mask_logits, heatmap_logits = self.decode(latent, skips)
            return StudentOutput(mask_logits, heatmap_logits, mean, logvar)
        mask_logits, heatmap_logits, class_logits = self.decode_all(latent, skips)
        return StudentOutput(mask_logits, heatmap_logits, mean, logvar, class_logits)


def kl_divergence(mean: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    """KL(q(z|x) ‖ N(0, I)), averaged over latent elements and the batch."""
    return 0.5 * torch.mean(mean.pow(2) + logvar.exp() - 1.0 - logvar)


def _pretrained_encoder(config: StudentConfig) -> ResNetModel | None:
    """ImageNet ResNet weights when they are on this machine (never downloads), else None."""
    if not config.pretrained or not math.isclose(config.width, 1.0):
        return None
    from weldpool_core.teacher.weights import weights_status

    ref = config.encoder_weights or config.spec.hub_id
    status = weights_status(ref, "encoder_weights")
    if not status.available or status.path is None:
        return None
    return ResNetModel.from_pretrained(status.path)


@dataclass(frozen=True)
class BuiltStudent:
    """A fresh student and whether its encoder starts from ImageNet weights."""

    model: ResNetVAE
    pretrained: bool
    notes: list[str] = field(default_factory=list)


def build_student(config: StudentConfig, *, load_pretrained: bool = True) -> BuiltStudent:
    """A new ResNet-VAE; its encoder from ImageNet weights when asked for and present."""
    encoder = _pretrained_encoder(config) if load_pretrained else None
    notes = []
    weights_fit = math.isclose(config.width, 1.0)  # narrower encoders have no ImageNet weights
    if load_pretrained and config.pretrained and weights_fit and encoder is None:
        notes.append("ImageNet encoder weights not found on this machine; random start")
    return BuiltStudent(ResNetVAE(config, encoder), encoder is not None, notes)


def channels_last(model: ModuleT) -> ModuleT:
    """``model`` with its weights in channels-last memory (faster convolutions on CPUs)."""
    moved: ModuleT = model.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
    return moved


def fuse_batchnorm(model: ModuleT) -> ModuleT:
    """Fold every eval-mode BatchNorm into the convolution before it (in place; inference only).

    Saves one pass over each feature map; the outputs are unchanged up to rounding.
    """
    from torch.nn.utils.fusion import fuse_conv_bn_eval

    for module in model.modules():
        conv, norm = getattr(module, "convolution", None), getattr(module, "normalization", None)
        if isinstance(conv, nn.Conv2d) and isinstance(norm, nn.BatchNorm2d):
            module.convolution = fuse_conv_bn_eval(conv, norm)
            module.normalization = nn.Identity()
        if isinstance(module, nn.Sequential):
            children = list(module)
            for index in range(len(children) - 1):
                first, second = children[index], children[index + 1]
                if isinstance(first, nn.Conv2d) and isinstance(second, nn.BatchNorm2d):
                    module[index] = fuse_conv_bn_eval(first, second)
                    module[index + 1] = nn.Identity()
    return model
