"""Backbones: the shipped EfficientNet-Lite0 ImageNet weights really load and classify; ResNet weight rules."""

import numpy as np
import pytest
import torch
from skimage import data
from skimage.transform import resize

from ushape.encoder.backbones import efficientnet_lite0, resnet18, resnet50
from ushape.encoder.efficientnet_lite import EfficientNetLite0, SameConv2d, lite0_weights_file
from ushape.encoder.heads import IMAGENET_MEAN, IMAGENET_STD

EGYPTIAN_CAT, ESPRESSO = 285, 967


def _imagenet_input(image: np.ndarray, size: int = 224) -> torch.Tensor:
    x = torch.from_numpy(resize(image, (size, size), anti_aliasing=True)).permute(2, 0, 1).float()[None]
    return (x - torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1)) / torch.tensor(IMAGENET_STD).view(1, 3, 1, 1)


def test_lite0_weights_classify_known_images():
    """Every key loads (strictly) and the ImageNet classifier names skimage's cat and coffee photos."""
    backbone, dim = efficientnet_lite0(pretrained=True)
    assert dim == 1280
    fc_state = torch.load(lite0_weights_file(), weights_only=True)
    classifier = torch.nn.Linear(dim, 1000)
    classifier.load_state_dict({"weight": fc_state["_fc.weight"], "bias": fc_state["_fc.bias"]})
    backbone.eval()
    with torch.no_grad():
        logits = classifier(backbone(torch.cat([_imagenet_input(data.chelsea()), _imagenet_input(data.coffee())])))
    assert logits.argmax(-1).tolist() == [EGYPTIAN_CAT, ESPRESSO]
    assert logits.softmax(-1).max(-1).values.min() > 0.5


def test_lite0_random_init_differs_from_pretrained():
    pretrained, _ = efficientnet_lite0(pretrained=True)
    fresh, _ = efficientnet_lite0(pretrained=False)
    w = "_conv_stem.weight"
    assert not torch.equal(pretrained.state_dict()[w], fresh.state_dict()[w])
    assert torch.equal(pretrained.state_dict()[w], torch.load(lite0_weights_file(), weights_only=True)[w])


def test_lite0_features_at_small_sizes():
    backbone, dim = efficientnet_lite0(pretrained=False)
    for size in (32, 65):
        assert backbone(torch.rand(2, 3, size, size)).shape == (2, dim)


def test_same_padding_matches_tensorflow_output_size():
    conv = SameConv2d(1, 1, 3, stride=2)
    for size in (7, 8, 137):
        assert conv(torch.zeros(1, 1, size, size)).shape[-1] == -(-size // 2)


@pytest.mark.parametrize("builder", [resnet18, resnet50])
def test_resnet_pretrained_without_weights_explains_what_to_do(builder):
    with pytest.raises(ValueError, match="weights_path=.*pretrained=false"):
        builder(pretrained=True)


def test_resnet_loads_a_local_state_dict(tmp_path):
    import torchvision

    reference = torchvision.models.resnet18(weights=None)
    path = tmp_path / "resnet18.pth"
    torch.save(reference.state_dict(), path)
    model, dim = resnet18(weights_path=str(path))
    assert dim == 512
    assert torch.equal(model.conv1.weight, reference.conv1.weight)
    assert model.eval()(torch.rand(1, 3, 32, 32)).shape == (1, 512)


def test_resnet_rejects_a_foreign_state_dict(tmp_path):
    path = tmp_path / "wrong.pth"
    torch.save(EfficientNetLite0().state_dict(), path)
    with pytest.raises(RuntimeError, match="not a torchvision resnet18"):
        resnet18(weights_path=str(path))
    with pytest.raises(FileNotFoundError):
        resnet18(weights_path=str(tmp_path / "missing.pth"))


def test_lite0_stage_pooling_ends_with_the_head_features():
    from ushape.encoder.backbones import efficientnet_lite0

    stages, dim = efficientnet_lite0(pretrained=False, pooling="stages")
    head, head_dim = efficientnet_lite0(pretrained=False)
    head.load_state_dict(stages.state_dict())
    stages.eval(), head.eval()
    x = torch.rand(2, 3, 40, 40)
    with torch.no_grad():
        out = stages(x)
        assert out.shape == (2, dim) and dim == 784 + head_dim
        assert torch.allclose(out[:, -head_dim:], head(x), atol=1e-6)


def test_stage_maps_are_what_the_stages_pooling_averages():
    """Every stage's map and the head's, 7 + 1; stopped after a stage's last block, the same maps up to there."""
    torch.manual_seed(0)
    net = EfficientNetLite0("stages").eval()
    x = torch.randn(2, 3, 64, 64)
    with torch.no_grad():
        maps = net.stage_maps(x)
        first_five = net.stage_maps(x, blocks=11)  # blocks 0-10: stages 1-5
        pooled = net(x)
    assert [m.shape[1] for m in maps] == [16, 24, 40, 80, 112, 192, 320, 1280]
    assert len(first_five) == 5
    for a, b in zip(first_five, maps):  # the same blocks on the same batch: equal up to float rounding
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(pooled, torch.cat([m.mean(dim=(-2, -1)) for m in maps], dim=1))
