"""Heads that map an encoder's feature vector to Q-values, action logits or a state value."""

from __future__ import annotations

from torch import Tensor, nn

from crowdplan.nets.encoders import mlp


class QHead(nn.Module):
    """Twin Q heads (clipped double Q): two independent MLPs in_dim -> 128 -> 128 -> n_actions.

    ``layer_norm`` puts a LayerNorm before each hidden ReLU, which bounds the features the last
    layer sees (a common remedy for diverging critics).
    """

    def __init__(
        self,
        in_dim: int,
        n_actions: int = 81,
        hidden: tuple[int, ...] = (128, 128),
        layer_norm: bool = False,
    ):
        super().__init__()
        make = _layer_norm_mlp if layer_norm else mlp
        self.q1 = make([in_dim, *hidden, n_actions])
        self.q2 = make([in_dim, *hidden, n_actions])

    def forward(self, features: Tensor) -> tuple[Tensor, Tensor]:
        """Return ``(q1, q2)``, each (B, n_actions)."""
        return self.q1(features), self.q2(features)


def _layer_norm_mlp(sizes: list[int]) -> nn.Sequential:
    """Linear layers with LayerNorm + ReLU after each hidden one."""
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers += [nn.LayerNorm(sizes[i + 1]), nn.ReLU()]
    return nn.Sequential(*layers)


class PolicyHead(nn.Module):
    """Categorical policy head: MLP ``in_dim -> 128 -> 128 -> n_actions`` giving logits."""

    def __init__(self, in_dim: int, n_actions: int = 81, hidden: tuple[int, ...] = (128, 128)):
        super().__init__()
        self.net = mlp([in_dim, *hidden, n_actions])

    def forward(self, features: Tensor) -> Tensor:
        """Return unnormalised action logits (B, n_actions)."""
        return self.net(features)


class ValueHead(nn.Module):
    """State-value head: MLP ``in_dim -> 150 -> 100 -> 100 -> 1`` (CrowdNav value networks)."""

    def __init__(self, in_dim: int, hidden: tuple[int, ...] = (150, 100, 100)):
        super().__init__()
        self.net = mlp([in_dim, *hidden, 1])

    def forward(self, features: Tensor) -> Tensor:
        """Return the value, shape (B, 1)."""
        return self.net(features)
