"""Representation learners: turn (robot, humans, mask) tensors into one feature vector per state.

Every encoder takes the robot-centric features of SPEC section 3 as tensors

- ``robot``:  (B, 6)    ``[dist_to_goal, v_pref, theta', r, vx', vy']``
- ``humans``: (B, N, 7) ``[px', py', vx', vy', r_h, dist_robot_human, r + r_h]`` per human
- ``mask``:   (B, N)    bool, True for a real human, False for padding (N may be 0)

and returns ``(features (B, out_dim), attention (B, N) or None)``. Padding rows may hold arbitrary
values: they are zeroed on entry and excluded from every softmax, sum and LSTM, so they never change
an output. All encoders are trained end to end by the algorithm that owns them.

Encoders (SPEC section 4):

========  =========================================================================  =======
name      what it does                                                               out_dim
========  =========================================================================  =======
raw       robot + ``max_humans`` humans (distance-sorted, zero-padded) -> MLP          56
rg        relational graph (two message-passing layers) + configurable pooling      see RG
aw        attention-weighted sum of per-human features                               56
sa        as aw, with a skip connection of the 13-d pair into ``h_i``                56
lsa       as sa, pooled by an LSTM over the attention-weighted ``h_i`` (the method)  56
========  =========================================================================  =======

Permutation behaviour: aw, sa and rg with a non-LSTM pooling are invariant to the order of the
humans. raw, lsa and the rg LSTM poolings order humans by distance (the default ``lstm_order``),
so they are invariant up to ties in distance; with ``lstm_order="index"`` they follow the input
order.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass

import torch
from torch import Tensor, nn
from torch.nn.utils.rnn import pack_padded_sequence

from crowdplan.config import check_fields

ROBOT_DIM = 6
HUMAN_DIM = 7
PAIR_DIM = ROBOT_DIM + HUMAN_DIM
DIST_COL = 5  # column of ``humans`` holding the robot-human distance

ENCODER_NAMES = ("raw", "rg", "aw", "sa", "lsa")
RG_POOLINGS = (
    "rob+obs",
    "rob",
    "sum(rob+obs)",
    "rob+mlp(obs)",
    "mlp(rob+obs)",
    "lstm(rob+obs)",
    "rob+lstm(obs)",
)
LSTM_ORDERS = ("distance_desc", "distance_asc", "index")


def _check_choice(field: str, value: object, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ValueError(f"unknown {field} {value!r}; valid choices: {', '.join(choices)}")


@dataclass
class EncoderConfig:
    """Which encoder to build and its options.

    Attributes:
        name: one of ``raw``, ``rg``, ``aw``, ``sa``, ``lsa`` (SPEC section 4).
        max_humans: number of human slots of the ``raw`` encoder's fixed-size input (only raw).
        rg_pooling: how the RG encoder pools its node features; default ``rob+lstm(obs)``
            (the paper's RG-DSAC): ``[H[0], LSTM(H[1:])]``.
        lstm_order: order of the humans fed to an LSTM (lsa, rg LSTM poolings) and of the raw
            encoder's slots: ``distance_desc`` (default, closest last), ``distance_asc`` or
            ``index`` (input order).
        rg_width: width of the RG node embeddings X and H (32, as in relational graph learning).
        rg_layers: number of RG message-passing layers (SPEC: 2).
        rg_lstm_hidden: hidden size of the RG pooling LSTM.
    """

    name: str = "lsa"
    max_humans: int = 5
    rg_pooling: str = "rob+lstm(obs)"
    lstm_order: str = "distance_desc"
    rg_width: int = 32
    rg_layers: int = 2
    rg_lstm_hidden: int = 32

    def __post_init__(self) -> None:
        check_fields(self, "encoder")
        _check_choice("encoder name", self.name, ENCODER_NAMES)
        _check_choice("rg_pooling", self.rg_pooling, RG_POOLINGS)
        _check_choice("lstm_order", self.lstm_order, LSTM_ORDERS)
        if self.max_humans < 0:
            raise ValueError(f"max_humans must be >= 0, got {self.max_humans}")


# ---------------------------------------------------------------------------------------------
# helpers


def mlp(sizes: list[int], last_relu: bool = False) -> nn.Sequential:
    """Linear layers of the given sizes with ReLU between them (and after the last if asked)."""
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2 or last_relu:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def masked_softmax(logits: Tensor, mask: Tensor, dim: int = -1) -> Tensor:
    """Softmax over ``dim`` restricted to ``mask``; exactly 0 on masked entries.

    A row with no valid entry gives all zeros (not NaN), and so do its gradients.
    """
    # finfo.min instead of -inf: an all-masked row then gives a finite uniform softmax that the
    # final multiplication zeroes, instead of 0/0 = NaN.
    filled = logits.masked_fill(~mask, torch.finfo(logits.dtype).min)
    return torch.softmax(filled, dim=dim) * mask


def _zero_padding(humans: Tensor, mask: Tensor) -> Tensor:
    # masked_fill (not a multiplication) so that NaN/inf garbage in padding rows is removed too.
    return humans.masked_fill(~mask.unsqueeze(-1), 0.0)


def order_humans(humans: Tensor, mask: Tensor, order: str, padding_first: bool = False) -> Tensor:
    """Permutation index (B, N) that lists the real humans in ``order`` (see
    :class:`EncoderConfig`) and the padding after them (before them if ``padding_first``)."""
    if order == "index":
        # stable sort on "is padding" keeps the input order among the real humans
        is_last = mask if padding_first else ~mask
        return _stable_argsort(is_last.to(torch.int8), descending=False)
    descending = order == "distance_desc"
    pad_key = float("inf") if descending == padding_first else float("-inf")
    key = humans[..., DIST_COL].masked_fill(~mask, pad_key)
    return _stable_argsort(key, descending)


def _stable_argsort(key: Tensor, descending: bool) -> Tensor:
    """Stable argsort along dim 1."""
    if torch.compiler.is_exporting():
        # ONNX has no stable sort, but its TopK breaks ties by lower index first
        key = key.to(torch.float32)
        return torch.topk(key, key.shape[1], dim=1, largest=descending, sorted=True).indices
    return torch.sort(key, dim=1, descending=descending, stable=True).indices


def _gather_rows(x: Tensor, index: Tensor) -> Tensor:
    """``x[b, index[b, i]]`` for x of shape (B, N, D)."""
    # explicit expand + gather: take_along_dim adds a (slow) wrap-around of negative indices
    return x.gather(1, index.unsqueeze(-1).expand(-1, -1, x.shape[-1]))


def _in_lstm_order(humans: Tensor, mask: Tensor, order: str) -> tuple[Tensor, Tensor, Tensor]:
    """The humans and mask put in LSTM ``order`` up front, and the permutation index used."""
    index = order_humans(humans, mask, order)
    return _gather_rows(humans, index), mask.gather(1, index), index


def _in_input_order(weights: Tensor, index: Tensor) -> Tensor:
    """Per-human ``weights`` (B, N) computed in the order ``index`` put back in input order."""
    return torch.empty_like(weights).scatter_(1, index, weights)


def lstm_last_hidden(lstm: nn.LSTM, seq: Tensor, lengths: Tensor) -> Tensor:
    """Last hidden state of ``lstm`` over ``seq`` (B, T, D) whose first ``lengths[b]`` steps are
    valid. Rows of length 0 give zeros."""
    if torch.compiler.is_exporting() or _UNPACKED_LSTM.get():
        return _lstm_last_hidden_unpacked(lstm, seq, lengths)
    batch, steps = seq.shape[0], seq.shape[1]
    if steps == 0:
        return seq.new_zeros(batch, lstm.hidden_size)
    if bool((lengths == steps).all()):
        _, (h_n, _) = lstm(seq)
        return h_n[-1]
    # pack so that the LSTM stops at each row's last real element: padding never enters the state
    packed = pack_padded_sequence(
        seq, lengths.clamp(min=1).cpu(), batch_first=True, enforce_sorted=False
    )
    _, (h_n, _) = lstm(packed)
    return torch.where((lengths > 0).unsqueeze(-1), h_n[-1], 0.0)


_UNPACKED_LSTM: ContextVar[bool] = ContextVar("unpacked_lstm", default=False)


@contextmanager
def unpacked_lstm(on: bool = True) -> Iterator[None]:
    """Inside, :func:`lstm_last_hidden` never packs by length nor branches on the data (as in
    graph export): what a CUDA graph can capture. A run that captures its update uses this for
    every update, captured or not, so that all of them compute the same way."""
    token = _UNPACKED_LSTM.set(on)
    try:
        yield
    finally:
        _UNPACKED_LSTM.reset(token)


def _lstm_last_hidden_unpacked(lstm: nn.LSTM, seq: Tensor, lengths: Tensor) -> Tensor:
    """The same as :func:`lstm_last_hidden` without branching on the data or the sequence length
    (for graph export and CUDA-graph capture): the LSTM is causal, so its output at step
    ``lengths[b] - 1`` is the state after the last real element. One zero step is appended so
    that T = 0 still runs."""
    seq = torch.cat([seq, seq.new_zeros(seq.shape[0], 1, seq.shape[2])], dim=1)
    out, _ = lstm(seq)
    last = (lengths - 1).clamp(min=0).view(-1, 1, 1).expand(-1, 1, out.shape[2])
    return torch.where((lengths > 0).unsqueeze(-1), out.gather(1, last).squeeze(1), 0.0)


# ---------------------------------------------------------------------------------------------
# encoders


class Encoder(nn.Module):
    """Base class: ``forward(robot, humans, mask) -> (features (B, out_dim), attention)``.

    ``attention`` is (B, N) -- a softmax over the real humans, 0 on padding -- for encoders that
    have one, else None.
    """

    out_dim: int

    def forward(
        self, robot: Tensor, humans: Tensor, mask: Tensor
    ) -> tuple[Tensor, Tensor | None]:  # pragma: no cover - interface
        raise NotImplementedError(f"{type(self).__name__} must implement forward()")


class RawEncoder(Encoder):
    """Source-state ("raw") encoder: robot (6) + ``max_humans`` x human (7) -> MLP 150-100-56.

    Humans are ordered by ``lstm_order`` (default decreasing distance) and right-aligned in the
    ``max_humans`` slots, so with the default order the closest human always sits in the last slot;
    empty slots are zeros. With more than ``max_humans`` real humans, the ones that come first in
    that order (the farthest, by default) are dropped. Hidden layers use ReLU; the output is linear.
    """

    def __init__(self, cfg: EncoderConfig, hidden: tuple[int, ...] = (150, 100), out_dim: int = 56):
        super().__init__()
        self.max_humans = cfg.max_humans
        self.order = cfg.lstm_order
        self.out_dim = out_dim
        self.net = mlp([ROBOT_DIM + HUMAN_DIM * cfg.max_humans, *hidden, out_dim])

    def forward(self, robot: Tensor, humans: Tensor, mask: Tensor) -> tuple[Tensor, None]:
        batch, n = humans.shape[0], humans.shape[1]
        humans = _zero_padding(humans, mask)
        index = order_humans(humans, mask, self.order, padding_first=True)  # right-aligned
        ordered = _gather_rows(humans, index)
        # always pad, then keep the last max_humans slots: no branch on N (graph export)
        empty = ordered.new_zeros(batch, self.max_humans, HUMAN_DIM)
        slots = torch.cat([empty, ordered], dim=1)[:, n:]
        return self.net(torch.cat([robot, slots.reshape(batch, -1)], dim=1)), None


class AttentionEncoder(Encoder):
    """AW, SA and LSA (SPEC section 4).

    - ``e_i = f_e([s_r, o_i])``: MLP 13 -> 150 -> 100 (ReLU after both layers)
    - ``h_i = f_h(e_i)`` (AW, MLP 100 -> 100 -> 50) or ``f_h([e_i, s_r, o_i])`` (SA and LSA,
      113 -> 100 -> 50)
    - ``alpha_i = f_a(e_i)``: MLP 100 -> 100 -> 1; ``w = masked softmax(alpha)``
    - AW/SA: ``S_o = sum_i w_i h_i``; LSA: ``S_o`` = last hidden state of LSTM(50 -> 50) over
      ``w_i h_i`` in ``lstm_order`` (padding excluded by packing)
    - output ``[s_r, S_o]`` (56-d); with no real human ``S_o = 0``.
    """

    def __init__(self, cfg: EncoderConfig):
        super().__init__()
        self.kind = cfg.name
        self.order = cfg.lstm_order
        self.skip = cfg.name in ("sa", "lsa")
        self.f_e = mlp([PAIR_DIM, 150, 100], last_relu=True)
        self.f_h = mlp([100 + (PAIR_DIM if self.skip else 0), 100, 50])
        self.f_a = mlp([100, 100, 1])
        self.lstm = nn.LSTM(50, 50, batch_first=True) if cfg.name == "lsa" else None
        self.out_dim = ROBOT_DIM + 50

    def forward(self, robot: Tensor, humans: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
        humans = _zero_padding(humans, mask)
        index = None
        if self.lstm is not None:
            # a cheap gather of the inputs, not of the 50-d features
            humans, mask, index = _in_lstm_order(humans, mask, self.order)
        pair = torch.cat([robot.unsqueeze(1).expand(-1, humans.shape[1], -1), humans], dim=-1)
        e = self.f_e(pair)
        h = self.f_h(torch.cat([e, pair], dim=-1) if self.skip else e)
        attention = masked_softmax(self.f_a(e).squeeze(-1), mask)
        weighted = attention.unsqueeze(-1) * h
        if self.lstm is None:
            return torch.cat([robot, weighted.sum(dim=1)], dim=1), attention
        s_o = lstm_last_hidden(self.lstm, weighted, mask.sum(dim=1))
        attention = _in_input_order(attention, index)
        return torch.cat([robot, s_o], dim=1), attention


class RelationalGraphEncoder(Encoder):
    """Relational graph (RG) encoder (SPEC section 4, after relational graph learning, Chen 2020).

    ``X = [w_r(s_r); w_h(o_1..o_N)]`` (MLPs 6 -> 64 -> w and 7 -> 64 -> w, ReLU, w = ``rg_width``),
    ``A[i, j] = softmax_j MLP([X_i, X_j])`` (MLP 2w -> 2w -> 1, padding columns excluded), then
    ``rg_layers`` layers ``H_{l+1} = relu(A H_l W_l) + H_l`` with ``H_0 = X``.

    Poolings (w = ``rg_width``, k = ``rg_lstm_hidden``; "mean" is over real humans, 0 if none):

    ==============  ===============================================  =======
    rg_pooling      feature                                          out_dim
    ==============  ===============================================  =======
    rob+obs         ``[H_0, mean_i H_i]``                            2w
    rob             ``H_0``                                          w
    sum(rob+obs)    ``H_0 + sum_i H_i``                              w
    rob+mlp(obs)    ``[H_0, mean_i MLP(H_i)]`` (MLP w -> w -> w)     2w
    mlp(rob+obs)    ``MLP([H_0, mean_i H_i])`` (MLP 2w -> 2w -> 2w)  2w
    lstm(rob+obs)   LSTM over ``H_0, H_(1), ..., H_(n)``             k
    rob+lstm(obs)   ``[H_0, LSTM(H_(1), ..., H_(n))]`` (default)     w + k
    ==============  ===============================================  =======

    ``H_(i)`` are the human nodes in ``lstm_order``. With the defaults (w = k = 32) the default
    pooling gives 64 features. The attention output is the robot's row of the relation matrix,
    ``A[0, 1:]`` (it sums to ``1 - A[0, 0]`` over the real humans).
    """

    def __init__(self, cfg: EncoderConfig):
        super().__init__()
        w, k = cfg.rg_width, cfg.rg_lstm_hidden
        self.pooling = cfg.rg_pooling
        self.order = cfg.lstm_order
        self.w_r = mlp([ROBOT_DIM, 64, w], last_relu=True)
        self.w_h = mlp([HUMAN_DIM, 64, w], last_relu=True)
        # relation MLP on [X_i, X_j]: its first layer is split into the X_i and X_j halves so the
        # (M x M) pair tensor is only formed after the projection (same maths, M times cheaper).
        self.w_a_i = nn.Linear(w, 2 * w)
        self.w_a_j = nn.Linear(w, 2 * w, bias=False)
        self.w_a_out = nn.Linear(2 * w, 1)
        self.gcn = nn.ModuleList(nn.Linear(w, w, bias=False) for _ in range(cfg.rg_layers))
        self.pool_mlp: nn.Module | None = None
        self.lstm: nn.LSTM | None = None
        if self.pooling == "rob+mlp(obs)":
            self.pool_mlp = mlp([w, w, w])
        elif self.pooling == "mlp(rob+obs)":
            self.pool_mlp = mlp([2 * w, 2 * w, 2 * w])
        elif "lstm" in self.pooling:
            self.lstm = nn.LSTM(w, k, batch_first=True)
        self.out_dim = {
            "rob+obs": 2 * w,
            "rob": w,
            "sum(rob+obs)": w,
            "rob+mlp(obs)": 2 * w,
            "mlp(rob+obs)": 2 * w,
            "lstm(rob+obs)": k,
            "rob+lstm(obs)": w + k,
        }[self.pooling]

    def forward(self, robot: Tensor, humans: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
        humans = _zero_padding(humans, mask)
        index = None
        if self.lstm is not None:
            # the graph is permutation-equivariant: the order only matters to the LSTM
            humans, mask, index = _in_lstm_order(humans, mask, self.order)
        x = torch.cat([self.w_r(robot).unsqueeze(1), self.w_h(humans)], dim=1)  # (B, M, w)
        node_mask = torch.cat([mask.new_ones(mask.shape[0], 1), mask], dim=1)  # (B, M)
        pair_hidden = torch.relu(self.w_a_i(x).unsqueeze(2) + self.w_a_j(x).unsqueeze(1))
        a = masked_softmax(self.w_a_out(pair_hidden).squeeze(-1), node_mask.unsqueeze(1))
        h = x
        for w_l in self.gcn:
            h = torch.relu(a @ w_l(h)) + h
        attention = a[:, 0, 1:]
        if index is not None:
            attention = _in_input_order(attention, index)
        return self._pool(h[:, 0], h[:, 1:], mask), attention

    def _pool(self, h_rob: Tensor, h_obs: Tensor, mask: Tensor) -> Tensor:
        p = self.pooling
        if p == "rob":
            return h_rob
        if self.lstm is not None:  # h_obs is already in LSTM order, real humans first
            lengths = mask.sum(dim=1)
            if p == "lstm(rob+obs)":
                seq = torch.cat([h_rob.unsqueeze(1), h_obs], dim=1)
                return lstm_last_hidden(self.lstm, seq, lengths + 1)
            return torch.cat([h_rob, lstm_last_hidden(self.lstm, h_obs, lengths)], 1)
        maskf = mask.unsqueeze(-1).to(h_obs.dtype)
        if p == "sum(rob+obs)":
            return h_rob + (h_obs * maskf).sum(dim=1)
        count = maskf.sum(dim=1).clamp(min=1.0)
        if p == "rob+mlp(obs)":
            return torch.cat([h_rob, (self.pool_mlp(h_obs) * maskf).sum(dim=1) / count], dim=1)
        mean_obs = (h_obs * maskf).sum(dim=1) / count
        if p == "rob+obs":
            return torch.cat([h_rob, mean_obs], dim=1)
        return self.pool_mlp(torch.cat([h_rob, mean_obs], dim=1))  # mlp(rob+obs)


def make_encoder(cfg: EncoderConfig) -> Encoder:
    """Build the encoder named by ``cfg.name``; ValueError for an unknown name."""
    _check_choice("encoder name", cfg.name, ENCODER_NAMES)
    if cfg.name == "raw":
        return RawEncoder(cfg)
    if cfg.name == "rg":
        return RelationalGraphEncoder(cfg)
    return AttentionEncoder(cfg)
