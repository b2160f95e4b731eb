"""Encoders: shapes, padding invariance, permutation behaviour, empty scenes, attention."""

from __future__ import annotations

import pytest
import torch

from crowdplan.nets.encoders import (
    ENCODER_NAMES,
    LSTM_ORDERS,
    RG_POOLINGS,
    EncoderConfig,
    make_encoder,
    unpacked_lstm,
)


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    """Library callers run torch on one thread; several threads are far slower for these nets."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


# (name, rg_pooling) for every encoder and every RG pooling
VARIANTS = [(n, "rob+lstm(obs)") for n in ENCODER_NAMES if n != "rg"] + [
    ("rg", p) for p in RG_POOLINGS
]
IDS = [n if n != "rg" else f"rg-{p}" for n, p in VARIANTS]
EXPECTED_OUT_DIM = {
    "raw": 56,
    "aw": 56,
    "sa": 56,
    "lsa": 56,
    "rg-rob+obs": 64,
    "rg-rob": 32,
    "rg-sum(rob+obs)": 32,
    "rg-rob+mlp(obs)": 64,
    "rg-mlp(rob+obs)": 64,
    "rg-lstm(rob+obs)": 32,
    "rg-rob+lstm(obs)": 64,
}


def build(name: str, pooling: str = "rob+lstm(obs)", order: str = "distance_desc", max_humans=5):
    torch.manual_seed(0)
    cfg = EncoderConfig(name=name, max_humans=max_humans, rg_pooling=pooling, lstm_order=order)
    return make_encoder(cfg)


def scene(batch: int, n: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Random robot/human features with distinct positive distances, every human real."""
    g = torch.Generator().manual_seed(seed)
    robot = torch.randn(batch, 6, generator=g)
    humans = torch.randn(batch, n, 7, generator=g)
    humans[..., 5] = torch.rand(batch, n, generator=g) * 8 + 0.1
    return robot, humans, torch.ones(batch, n, dtype=torch.bool)


def pad_with_garbage(humans, mask, extra: int, seed: int = 1):
    """Insert ``extra`` padding rows of large random garbage at random positions (the same in
    every batch row), keeping the relative order of the original rows."""
    g = torch.Generator().manual_seed(seed)
    batch, n, _ = humans.shape
    total = n + extra
    kept = torch.sort(torch.randperm(total, generator=g)[:n]).values
    out_humans = torch.randn(batch, total, 7, generator=g) * 100
    out_mask = torch.zeros(batch, total, dtype=torch.bool)
    out_humans[:, kept] = humans
    out_mask[:, kept] = mask
    return out_humans, out_mask


@pytest.mark.parametrize(("name", "pooling"), VARIANTS, ids=IDS)
def test_shapes(name, pooling):
    enc = build(name, pooling)
    robot, humans, mask = scene(4, 5)
    out, attention = enc(robot, humans, mask)
    key = name if name != "rg" else f"rg-{pooling}"
    assert enc.out_dim == EXPECTED_OUT_DIM[key]
    assert out.shape == (4, enc.out_dim)
    assert torch.isfinite(out).all()
    if name == "raw":
        assert attention is None
    else:
        assert attention.shape == (4, 5)


@pytest.mark.parametrize(("name", "pooling"), VARIANTS, ids=IDS)
@pytest.mark.parametrize("order", LSTM_ORDERS)
def test_padding_with_garbage_changes_nothing(name, pooling, order):
    if order != "distance_desc" and name in ("aw", "sa"):
        pytest.skip("order is unused by aw/sa")
    enc = build(name, pooling, order)
    robot, humans, mask = scene(6, 4)
    mask[1, 2:] = False  # rows with fewer real humans, one with none
    mask[3] = False
    ref, ref_att = enc(robot, humans, mask)
    padded_humans, padded_mask = pad_with_garbage(humans, mask, extra=3)
    out, att = enc(robot, padded_humans, padded_mask)
    torch.testing.assert_close(out, ref, atol=1e-5, rtol=1e-5)
    if ref_att is not None:
        # the attention of each real human is unchanged; padding gets exactly 0
        assert (att[~padded_mask] == 0).all()
        for b in range(6):
            torch.testing.assert_close(
                att[b][padded_mask[b]], ref_att[b][mask[b]], atol=1e-6, rtol=1e-5
            )


@pytest.mark.parametrize(("name", "pooling"), VARIANTS, ids=IDS)
def test_mixed_batch_equals_each_scene_alone(name, pooling):
    """A padded batch gives, row by row, what each scene gives alone without any padding."""
    enc = build(name, pooling)
    robot, humans, mask = scene(5, 5, seed=3)
    counts = [5, 3, 1, 0, 4]
    for b, c in enumerate(counts):
        mask[b, c:] = False
    out, _ = enc(robot, humans, mask)
    for b, c in enumerate(counts):
        alone, _ = enc(robot[b : b + 1], humans[b : b + 1, :c], mask[b : b + 1, :c])
        torch.testing.assert_close(out[b : b + 1], alone, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize(("name", "pooling"), VARIANTS, ids=IDS)
def test_permutation_behaviour(name, pooling):
    """Documented behaviour: with the default distance ordering every encoder is invariant to
    the order in which humans are listed (distances are distinct here)."""
    enc = build(name, pooling)
    robot, humans, mask = scene(3, 5, seed=4)
    perm = torch.tensor([3, 0, 4, 1, 2])
    out, att = enc(robot, humans, mask)
    out_p, att_p = enc(robot, humans[:, perm], mask[:, perm])
    torch.testing.assert_close(out_p, out, atol=1e-5, rtol=1e-5)
    if att is not None:
        torch.testing.assert_close(att_p, att[:, perm], atol=1e-6, rtol=1e-5)


def test_index_order_follows_the_input_order():
    enc = build("lsa", order="index")
    robot, humans, mask = scene(3, 5, seed=4)
    perm = torch.tensor([3, 0, 4, 1, 2])
    out, _ = enc(robot, humans, mask)
    out_p, _ = enc(robot, humans[:, perm], mask[:, perm])
    assert not torch.allclose(out, out_p, atol=1e-6)
    # ...while aw/sa pooling is a plain weighted sum: always invariant
    enc = build("sa")
    torch.testing.assert_close(
        enc(robot, humans[:, perm], mask[:, perm])[0], enc(robot, humans, mask)[0]
    )


@pytest.mark.parametrize(("name", "pooling"), VARIANTS, ids=IDS)
def test_the_unpacked_lstm_gives_the_packed_features_and_gradients(name, pooling):
    """What a CUDA graph captures: the LSTM over the padded crowd, read at each row's last real
    human, instead of packed by length (rows of 0 to 4 real humans)."""
    enc = build(name, pooling)
    robot, humans, _ = scene(6, 4)
    mask = torch.arange(4) < torch.tensor([0, 1, 2, 3, 4, 2]).unsqueeze(1)
    results = []
    for unpacked in (False, True):
        enc.zero_grad(set_to_none=True)
        with unpacked_lstm(unpacked):
            out, _ = enc(robot, humans, mask)
        out.square().sum().backward()
        results.append((out.detach(), [p.grad for p in enc.parameters()]))
    (packed, packed_grads), (padded, padded_grads) = results
    torch.testing.assert_close(padded, packed, atol=1e-6, rtol=1e-5)
    for a, b in zip(padded_grads, packed_grads, strict=True):
        if a is None or b is None:
            assert a is None and b is None
        else:
            torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-4)


@pytest.mark.parametrize(("name", "pooling"), VARIANTS, ids=IDS)
def test_no_humans_is_finite_with_finite_gradients(name, pooling):
    enc = build(name, pooling)
    robot = torch.randn(3, 6, requires_grad=True)
    for humans, mask in [
        (torch.zeros(3, 0, 7), torch.zeros(3, 0, dtype=torch.bool)),
        (torch.randn(3, 4, 7) * 50, torch.zeros(3, 4, dtype=torch.bool)),  # all masked
    ]:
        enc.zero_grad(set_to_none=True)
        robot.grad = None
        out, att = enc(robot, humans, mask)
        assert torch.isfinite(out).all()
        if att is not None:
            assert (att == 0).all()
        out.square().sum().backward()
        assert torch.isfinite(robot.grad).all()
        for p in enc.parameters():
            assert p.grad is None or torch.isfinite(p.grad).all()
    # all-masked rows equal an empty scene
    empty, _ = enc(robot, torch.zeros(3, 0, 7), torch.zeros(3, 0, dtype=torch.bool))
    masked, _ = enc(robot, torch.randn(3, 4, 7), torch.zeros(3, 4, dtype=torch.bool))
    torch.testing.assert_close(masked, empty, atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("name", ["aw", "sa", "lsa"])
def test_attention_is_a_softmax_over_real_humans(name):
    enc = build(name)
    robot, humans, mask = scene(4, 6, seed=5)
    mask[0, 3:] = False
    mask[2, 1:] = False
    _, att = enc(robot, humans, mask)
    torch.testing.assert_close(att.sum(dim=1), torch.ones(4))
    assert (att[~mask] == 0).all()
    assert (att[mask] > 0).all()
    assert att[2, 0].item() == pytest.approx(1.0)


def test_rg_attention_is_the_robot_row_of_the_relation_matrix():
    enc = build("rg")
    robot, humans, mask = scene(4, 6, seed=5)
    mask[0, 3:] = False
    _, att = enc(robot, humans, mask)
    assert (att[~mask] == 0).all()
    assert ((att.sum(dim=1) > 0) & (att.sum(dim=1) < 1)).all()  # 1 - A[0, 0]


def test_raw_keeps_the_closest_humans():
    enc = build("raw", max_humans=3)
    robot, humans, mask = scene(2, 5, seed=6)
    out, _ = enc(robot, humans, mask)
    closest = torch.argsort(humans[..., 5], dim=1)[:, :3]
    kept = torch.take_along_dim(humans, closest.unsqueeze(-1), dim=1)
    out_kept, _ = enc(robot, kept, mask[:, :3])
    torch.testing.assert_close(out, out_kept)


def test_backward_reaches_every_parameter():
    for name, pooling in VARIANTS:
        enc = build(name, pooling)
        robot, humans, mask = scene(4, 3)
        out, _ = enc(robot, humans, mask)
        out.square().sum().backward()
        missing = [n for n, p in enc.named_parameters() if p.grad is None]
        assert not missing, (name, pooling, missing)


@pytest.mark.parametrize(
    ("kwargs", "bad"),
    [
        ({"name": "transformer"}, "transformer"),
        ({"rg_pooling": "max"}, "max"),
        ({"lstm_order": "random"}, "random"),
    ],
)
def test_bad_config_values_are_named(kwargs, bad):
    with pytest.raises(ValueError, match=bad) as info:
        EncoderConfig(**kwargs)
    assert "valid choices" in str(info.value)


def test_make_encoder_rejects_unknown_name():
    cfg = EncoderConfig()
    cfg.name = "sarl2"
    with pytest.raises(ValueError, match="sarl2.*raw, rg, aw, sa, lsa"):
        make_encoder(cfg)
