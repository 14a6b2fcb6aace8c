"""The trainer's kernels give the plain modules' numbers bit for bit and leave the state dict alone."""

import copy

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.learn.kernels import ConvReLU, fuse_conv_relu, keep_freed_memory, twin_forward
from swarmctl.policy.qnet import GlobalLocalQNetwork, QNetwork

LAYOUTS = [torch.contiguous_format, torch.channels_last]


def _pair(cls, window: int, layout, seed: int):
    """A network as the trainer holds it (channels-last filters; else the kernels step aside) and
    its fused copy."""
    torch.manual_seed(seed)
    plain = cls(window).to(memory_format=layout)
    return plain, fuse_conv_relu(copy.deepcopy(plain))


@pytest.mark.parametrize("cls", [QNetwork, GlobalLocalQNetwork])
def test_fusing_keeps_the_state_dict_and_every_convolution_becomes_a_conv_relu(cls):
    plain, fused = _pair(cls, 20, torch.channels_last, 0)
    assert {k: v.shape for k, v in plain.state_dict().items()} == {k: v.shape for k, v in fused.state_dict().items()}
    convs = [m for m in fused.modules() if isinstance(m, torch.nn.Conv2d)]
    assert convs and all(isinstance(m, ConvReLU) for m in convs)
    assert not any(isinstance(m, torch.nn.ReLU) and m is not fused.head[1] for m in fused.modules())
    fresh = cls(20)
    fresh.load_state_dict(fused.state_dict())  # a checkpoint of a fused network loads into a plain one


@settings(max_examples=12, deadline=None)
@given(
    st.sampled_from([QNetwork, GlobalLocalQNetwork]),
    st.sampled_from([8, 13, 20]),
    st.sampled_from(LAYOUTS),
    st.integers(1, 70),
    st.integers(0, 2**16),
)
def test_a_fused_network_gives_the_plain_outputs_and_gradients_bit_for_bit(cls, window, layout, rows, seed):
    plain, fused = _pair(cls, window, torch.channels_last if seed % 4 else torch.contiguous_format, seed)
    obs = torch.rand(rows, cls.in_channels, window, window, generator=torch.Generator().manual_seed(seed))
    obs = obs.round().to(memory_format=layout)  # the replay's batches are channels-last, acting's not
    with torch.inference_mode():
        assert torch.equal(plain(obs), fused(obs))
    for net in (plain, fused):
        net(obs).square().sum().backward()
    for (name, a), b in zip(plain.named_parameters(), fused.parameters()):
        assert torch.equal(a.grad, b.grad), name


@settings(max_examples=10, deadline=None)
@given(st.sampled_from(LAYOUTS), st.integers(1, 70), st.integers(0, 2**16), st.booleans())
def test_the_twin_forward_gives_each_network_its_own_q_values_bit_for_bit(layout, rows, seed, fused):
    torch.manual_seed(seed)
    online, target = (QNetwork(20).to(memory_format=torch.channels_last) for _ in range(2))
    if fused:
        fuse_conv_relu(online), fuse_conv_relu(target)
    obs = torch.rand(rows, 3, 20, 20).round().to(memory_format=layout)
    with torch.no_grad():
        q_online, q_target = twin_forward(online, target, obs)
        assert torch.equal(q_online, online(obs)) and torch.equal(q_target, target(obs))
        assert not torch.equal(q_online, q_target)


def test_the_twin_forward_of_other_networks_calls_them_one_after_the_other():
    online, target = GlobalLocalQNetwork(20), GlobalLocalQNetwork(20)
    obs = torch.rand(3, 7, 20, 20)
    with torch.no_grad():
        q_online, q_target = twin_forward(online, target, obs)
        assert torch.equal(q_online, online(obs)) and torch.equal(q_target, target(obs))


def test_keeping_freed_memory_applies_on_glibc_and_is_harmless_twice():
    import platform

    assert keep_freed_memory() == (platform.system() == "Linux" and platform.libc_ver()[0] == "glibc")
    assert keep_freed_memory() == keep_freed_memory()
