"""The neural models: Table I parameter counts, receptive fields, shapes, causality."""
from __future__ import annotations

import pytest
import torch

from doabench.errors import ConfigError
from doabench_baselines.cnn1d import CausalCnn1d, gcc_cnn1d, max_cnn1d
from doabench_baselines.cnn2d import SpecCnn2d
from doabench_baselines.cross3d import Cross3D, branch_layers, cross3d_input
from doabench_baselines.layers import count_parameters, receptive_field_seconds, sphere_pad
from doabench_baselines.seldnet import Seldnet

# Paper Table I.
CROSS3D_PARAMETERS = {
    (4, 8): 526_372,
    (8, 16): 946_340,
    (16, 32): 1_693_988,
    (32, 64): 5_626_148,
    (64, 128): 21_354_788,
}



@pytest.mark.parametrize("resolution,expected", sorted(CROSS3D_PARAMETERS.items()))
def test_cross3d_parameter_count_matches_table_1(resolution, expected):
    with torch.device("meta"):  # counts without allocating 21 M floats
        model = Cross3D(*resolution)
    assert count_parameters(model) == expected


@pytest.mark.parametrize("factory,expected", [
    (gcc_cnn1d, 11_282_436), (max_cnn1d, 6_899_716), (SpecCnn2d, 1_882_372), (Seldnet, 104_643)])
def test_baseline_parameter_counts_match_table_1(factory, expected):
    with torch.device("meta"):
        model = factory()
    assert count_parameters(model) == expected


def test_gcc_cnn1d_input_is_nao_pairs_times_13_lags():
    import doabench

    nao = doabench.get_array("nao")
    n_lags = 2 * nao.max_lag(16000) + 1
    assert (len(nao.pairs), n_lags) == (66, 13)
    with torch.device("meta"):
        assert gcc_cnn1d(len(nao.pairs), n_lags).in_channels == 858


@pytest.mark.parametrize("resolution,frames,seconds", [((4, 8), 29, 5.63), ((8, 16), 33, 6.40), ((16, 32), 37, 7.17),
                                                        ((32, 64), 37, 7.17), ((64, 128), 37, 7.17)])
def test_cross3d_receptive_field_matches_table_1(resolution, frames, seconds):
    with torch.device("meta"):
        model = Cross3D(*resolution)
    assert model.receptive_field == frames
    assert round(receptive_field_seconds(frames), 2) == seconds


def test_branch_layers_follow_the_paper_rule():
    assert [branch_layers(n, 2 * n) for n in (4, 8, 16, 32, 64)] == [2, 3, 4, 4, 4]
    assert branch_layers(3, 40) == 1


def _first_changed_and_last_changed(model, x, t0):
    """Perturb frame t0 of x; return the output frames that changed."""
    with torch.no_grad():
        y = model(x)
        x2 = x.clone()
        x2[:, :, t0] += 3.0 * torch.randn_like(x2[:, :, t0])
        changed = (model(x2) - y).abs().amax(dim=(0, 2)) > 0
    return torch.nonzero(changed).flatten().tolist()


@pytest.mark.parametrize("make,shape", [
    (lambda: Cross3D(4, 8), (1, 3, 40, 4, 8)),
    (lambda: Cross3D(8, 16), (1, 3, 45, 8, 16)),
    (lambda: CausalCnn1d(5), (1, 5, 50, )),
    (lambda: SpecCnn2d(in_channels=2, n_freq=1024, channels=4), (1, 2, 50, 1024)),
])
def test_receptive_field_is_exact_and_causal(make, shape):
    """A change in frame t0 reaches outputs t0 .. t0 + RF - 1 and nothing else (no look-ahead)."""
    torch.manual_seed(0)
    model = make()
    t0 = 5
    changed = _first_changed_and_last_changed(model, torch.randn(shape), t0)
    assert changed[0] == t0 and changed[-1] == t0 + model.receptive_field - 1


def test_cross3d_output_shape_and_range():
    torch.manual_seed(0)
    model = Cross3D(8, 16)
    y = model(torch.randn(2, 3, 7, 8, 16))
    assert y.shape == (2, 7, 3)
    assert torch.all(y.abs() < 1)


def test_cross3d_rejects_wrong_input_shape():
    model = Cross3D(4, 8)
    with pytest.raises(ConfigError, match="4x8"):
        model(torch.zeros(1, 3, 5, 8, 16))
    with pytest.raises(ConfigError):
        Cross3D(2, 8)


def test_cross3d_input_broadcasts_the_maximum():
    srp = torch.randn(5, 4, 8)
    srp_max = torch.rand(5, 2)
    x = cross3d_input(srp, srp_max)
    assert x.shape == (5, 3, 4, 8)
    assert torch.equal(x[:, 0], srp)
    assert torch.equal(x[:, 1], srp_max[:, 0, None, None].expand(5, 4, 8))
    assert torch.equal(x[:, 2], srp_max[:, 1, None, None].expand(5, 4, 8))


def test_sphere_pad_is_circular_in_azimuth_and_reflecting_in_elevation():
    x = torch.arange(12.0).reshape(3, 4)  # rows: elevation, columns: azimuth
    p = sphere_pad(x, 1, 2)
    assert p.shape == (5, 8)
    assert torch.equal(p[1:-1, 2:-2], x)
    assert torch.equal(p[1:-1, :2], x[:, -2:]) and torch.equal(p[1:-1, -2:], x[:, :2])
    assert torch.equal(p[0, 2:-2], x[1]) and torch.equal(p[-1, 2:-2], x[-2])
    # The same as torch's own modes.
    ref = torch.nn.functional.pad(torch.nn.functional.pad(x[None, None], (2, 2, 0, 0), mode="circular"),
                                  (0, 0, 1, 1), mode="reflect")[0, 0]
    assert torch.equal(p, ref)


def test_sphere_pad_matches_torch_padding_modes_in_values_and_gradients():
    """On (batch, channels, frames, theta, phi) tensors, channels-last 3D too: the slices and
    concatenations give F.pad's reflect/circular values and the same gradients."""
    F = torch.nn.functional
    torch.manual_seed(1)
    for memory_format in (torch.contiguous_format, torch.channels_last_3d):
        x = torch.randn(2, 3, 5, 6, 8).contiguous(memory_format=memory_format).requires_grad_()
        y = x.detach().clone().requires_grad_()
        for pt, pp in ((1, 1), (2, 2), (0, 3), (2, 0)):
            ours = sphere_pad(x, pt, pp)
            folded = y.reshape(-1, 1, 6, 8)
            if pt:
                folded = F.pad(folded, (0, 0, pt, pt), mode="reflect")
            if pp:
                folded = F.pad(folded, (pp, pp, 0, 0), mode="circular")
            ref = folded.reshape(2, 3, 5, 6 + 2 * pt, 8 + 2 * pp)
            assert torch.equal(ours, ref)
            w = torch.randn_like(ref)
            (gx,) = torch.autograd.grad((ours * w).sum(), x)
            (gy,) = torch.autograd.grad((ref * w).sum(), y)
            assert torch.allclose(gx, gy, rtol=0, atol=1e-6)


def test_cross3d_is_equivariant_to_azimuth_rotation_before_pooling():
    """Circular azimuth padding: rotating the maps by 2^L cells rotates the first layer's output."""
    torch.manual_seed(0)
    model = Cross3D(4, 8)
    x = torch.randn(1, 3, 6, 4, 8)
    with torch.no_grad():
        h = model.input(x)
        h_rot = model.input(torch.roll(x, 3, dims=-1))
    assert torch.allclose(torch.roll(h, 3, dims=-1), h_rot, rtol=1e-5, atol=1e-6)


def test_seldnet_shapes_and_non_causality():
    torch.manual_seed(0)
    model = Seldnet().eval()
    x = torch.randn(1, 24, 12, 256)
    with torch.no_grad():
        y = model(x)
        x2 = x.clone()
        x2[:, :, -1] += 1.0
        y2 = model(x2)
    assert y.shape == (1, 12, 3)
    assert not torch.equal(y[:, 0], y2[:, 0])  # the last frame changes the first output: offline model


def test_widened_cross3d_feeds_its_1d_layer_what_the_coarse_network_did():
    """A warm start of 32x64 from 16x32 weights: the 3D convolutions are copied, and on maps whose
    2x2 finer cells repeat the coarse cells the widened 1D layer's pre-activation equals the coarse
    one's where the 3D features repeat too (no map padding effect: a constant map)."""
    from doabench_baselines.cross3d import widen_state

    torch.manual_seed(0)
    coarse, fine = Cross3D(16, 32), Cross3D(32, 64)
    fine.load_state_dict(widen_state(coarse.state_dict(), (16, 32), (32, 64)))
    for name, value in coarse.state_dict().items():
        if not name.startswith("hidden."):
            assert torch.equal(fine.state_dict()[name], value), name
    assert torch.equal(fine.state_dict()["hidden.conv.bias"], coarse.state_dict()["hidden.conv.bias"])
    x = torch.rand(1, 3, 12, 1, 1)  # a map constant over directions, changing in time
    yc, yf = coarse(x.expand(1, 3, 12, 16, 32)), fine(x.expand(1, 3, 12, 32, 64))
    assert torch.allclose(yc, yf, atol=1e-5)
    with pytest.raises(ConfigError, match="whole multiple"):
        widen_state(coarse.state_dict(), (16, 32), (24, 48))
    with pytest.raises(ConfigError, match="pooling blocks"):
        widen_state(Cross3D(8, 16).state_dict(), (8, 16), (16, 32))  # 3 blocks against 4


def test_spec_cnn2d_starts_with_an_output_that_moves():
    """He initialisation for the PReLUs keeps the signal's spread through the five convolutions:
    with PyTorch's default the output's standard deviation at initialisation is about 0.007 (0.6x
    per layer), and the network fits a fixed batch slower."""
    torch.manual_seed(0)
    net = SpecCnn2d(n_freq=1024)
    x = torch.rand(1, 24, 40, 1024) * 2 - 1
    with torch.no_grad():
        out = net(x)
    assert float(out.std()) > 0.1
    assert all(float(m.bias.detach().abs().max()) == 0.0 for m in net.modules() if isinstance(m, torch.nn.Conv2d))
