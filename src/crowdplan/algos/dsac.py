"""Discrete soft actor-critic (DSAC, SPEC section 5) with any encoder of ``crowdplan.nets``.

Christodoulou's discrete SAC: with 81 actions the expectations over the policy are computed exactly
as sums over actions, so neither the target nor the policy loss samples an action.

- target: ``y = r + gamma (1 - done) V(s')`` with the soft value
  ``V(s') = sum_a' pi(a'|s') (min(Q1', Q2')(s', a') - alpha log pi(a'|s'))``
- critic: ``MSE(Q1(s, a), y) + MSE(Q2(s, a), y)``
- policy: ``mean_s sum_a pi(a|s) (alpha log pi(a|s) - min(Q1, Q2)(s, a))`` (Q detached)
  (``average_q`` puts the mean of the twin critics where these two lines have their minimum)
- temperature: ``mean_s log_alpha (H(pi(.|s)) - H_target)``, ``H_target = scale * log(n_actions)``

``done`` is 1 only when the episode *terminated* (collision or goal). A time-limit truncation is
not a terminal state of the MDP, so its transition is stored with ``done = 0`` and the target
bootstraps through it. ``gamma`` is the discount per environment step, used as given.
"""

from __future__ import annotations

import math
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import dataclass
from typing import Any, ClassVar

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from crowdplan.algos.base import frozen_copy
from crowdplan.algos.cuda_graph import GraphedStep
from crowdplan.config import check_below, check_fields, spec
from crowdplan.nets.encoders import Encoder, EncoderConfig, make_encoder, unpacked_lstm
from crowdplan.nets.heads import PolicyHead, QHead

UPDATE_STATS = (
    "qf1_loss",
    "qf2_loss",
    "qf_loss",
    "actor_loss",
    "alpha_loss",
    "alpha",
    "entropy",
    "qf_mean",
)


@dataclass
class DSACConfig:
    """DSAC hyper-parameters (defaults: SPEC section 5 / the LSA-DSAC paper); YAML section ``dsac``.

    Attributes:
        gamma: discount per environment step.
        lr: Adam learning rate of the critic, and of the policy and the temperature unless
            ``policy_lr`` / ``alpha_lr`` give their own.
        batch_size: transitions per update.
        tau: Polyak coefficient of the target critic, ``target <- (1 - tau) target + tau critic``.
        target_entropy_scale: target entropy = scale * log(n_actions).
        target_entropy: an absolute target entropy instead of the scale (None: use the scale).
            ALN-DSAC's public code sets -162 (minus the action dimension), which no discrete
            policy can reach, so the temperature only ever decreases (docs/training.md).
        init_alpha: initial temperature.
        autotune_alpha: learn log(alpha) towards the target entropy; False keeps ``init_alpha``.
        n_actions: size of the discrete action set (SPEC: 81).
        updates_per_step: gradient updates per environment transition (UTD ratio).
        parallel_update: run the critic half and the policy half of every update on two threads
            (for two free cores); the results are bitwise the same as on one thread.
        cuda_graph: on a CUDA device, capture the whole update (both forward and backward
            passes, the Adam steps, the target update) in one CUDA graph after a few eager
            updates and replay it from then on (:mod:`crowdplan.algos.cuda_graph`): one launch
            instead of a few hundred. Every update of such a run, eager or replayed, runs the
            LSTM over the padded crowd (:func:`crowdplan.nets.encoders.unpacked_lstm`), so the
            run is not bitwise the one without the graph. Needs the serial update, a constant
            target entropy and no ``clip_q_targets`` (whose range is computed on the host).
        share_encoder: the policy reuses the critic's encoder (relation network / LSTM) instead of
            having its own; the shared encoder is then trained by the critic loss only and the
            policy sees its features detached (as in SAC-AE / DrQ). Default: separate encoders.
        q_hidden: hidden sizes of each of the twin Q heads.
        policy_hidden: hidden sizes of the policy head.
        random_steps: transitions collected with uniform random actions before the policy acts.
        learning_starts: transitions in the replay buffer before the first update.
        buffer_size: replay capacity in transitions.
        init_model: a DSAC model file (or shipped model name) whose policy initialises the
            actor (fine-tuning); it must have the same encoder and action frame as the run.
        init_networks: a DSAC training checkpoint (``checkpoint.pt``) or a networks file
            written from one (:func:`crowdplan.algos.dsac_networks.save_networks`) whose actor,
            critic, target critic and temperature start the run (continuing a run in another
            world); same encoder and action frame as the run. With ``init_model`` too, that
            model's policy replaces the networks' actor (e.g. the run's selected, averaged policy
            instead of its last one).
        actor_warmup_updates: updates during which only the critic learns (policy and
            temperature frozen), so that a fresh critic does not undo an initialised policy.
        demo_episodes: ORCA demonstration episodes (the robot executing the discrete action
            nearest to ORCA's command, safety space ``demo_safety_space``) stored in the replay
            buffer before the first environment step (0: none). Not in the paper; a warm start.
        demo_safety_space: ORCA's extra radius in the demonstrations (CrowdNav's 0.15).
        bc_epochs: epochs of behaviour cloning of the policy on the demonstrated actions
            (cross-entropy, Adam at ``bc_lr``) before the first step (0: none); pair it with
            ``actor_warmup_updates`` so that the critic learns the cloned policy's values before
            the policy follows the critic.
        bc_lr: learning rate of behaviour cloning.

    Stabilisation options (docs/training.md), all off by default:
        clip_q_targets: clip the soft target ``y`` to the reachable range
            ``[return_min, return_max + alpha log(n_actions) gamma / (1 - gamma)]``: the
            environment's return bounds, plus the most the entropy bonus can add (it is >= 0).
        return_min, return_max: bounds of the discounted return from any state (used by
            ``clip_q_targets``).
        alpha_min: temperature floor; ``log alpha`` is clamped to ``log(alpha_min)`` after each
            step (0: no floor).
        alpha_lr: Adam learning rate of the temperature (0: ``lr``).
        policy_lr: Adam learning rate of the policy (0: ``lr``); a smaller one lets a fine-tuned
            policy move no faster than its fresh critic learns the actions it starts taking.
        grad_clip_norm: clip the gradient norm of the critic and of the policy to this before
            their steps (0: no clipping).
        critic_layer_norm: layer norm before each hidden ReLU of the twin Q heads.
        target_entropy_start_scale: with ``target_entropy_anneal_updates`` > 0, the target
            entropy scale moves linearly from this value to ``target_entropy_scale`` over that
            many updates, then stays there.
        target_entropy_anneal_updates: length of that schedule in updates (0: constant target).
        average_q: the soft target and the policy loss use the mean of the twin critics instead
            of their minimum ("double average Q-learning" of Zhou et al., Revisiting Discrete
            Soft Actor-Critic): the minimum of two critics over 81 actions underestimates.
        q_clip: each critic's loss is the larger of its MSE and the MSE of its prediction
            clipped to within ``q_clip`` of the target critic's value of the same (s, a): once
            the predictions have moved towards their TD targets by more than that, the clipped
            loss is the larger and stops pulling them, a trust region around the target network
            (Zhou et al.'s Q-clip; 0: off). Costs a pass of the target critic over s as well.
        entropy_penalty: adds ``entropy_penalty * mean_s (H_behaviour(s) - H(pi(.|s)))^2`` to
            the policy loss, ``H_behaviour`` being the entropy of the policy that acted in s,
            stored with the transition (Zhou et al.'s entropy penalty: the policy's entropy may
            not move far from the one its data was collected with; 0: off).
        anchor_weight: adds ``anchor_weight * mean_s H(pi_0(.|s), pi(.|s))``, the cross-entropy
            of the policy against the frozen initial policy ``pi_0`` of ``init_model``, to the
            policy loss: a fine-tune is pulled back towards the actions its initial model takes,
            most where the critic tells the actions apart least (0: off; needs ``init_model``,
            which a resumed run reads again for it).
    """

    gamma: float = spec(0.95, low=0.0, high=1.0)
    lr: float = spec(3e-4, low=0.0, low_open=True)
    batch_size: int = spec(128, low=1)
    tau: float = spec(0.005, low=0.0, high=1.0)
    target_entropy_scale: float = 0.98
    target_entropy: float | None = None
    init_alpha: float = spec(0.2, low=0.0, low_open=True)
    autotune_alpha: bool = True
    n_actions: int = spec(81, low=2)
    updates_per_step: float = spec(1.0, low=0.0, low_open=True)
    parallel_update: bool = False
    cuda_graph: bool = False
    share_encoder: bool = False
    q_hidden: tuple[int, ...] = (128, 128)
    policy_hidden: tuple[int, ...] = (128, 128)
    random_steps: int = spec(2000, low=0)
    learning_starts: int = spec(1000, low=1)
    buffer_size: int = spec(200_000, low=1)
    init_model: str | None = None
    init_networks: str | None = None
    actor_warmup_updates: int = spec(0, low=0)
    demo_episodes: int = spec(0, low=0)
    demo_safety_space: float = spec(0.15, low=0.0)
    bc_epochs: int = spec(0, low=0)
    bc_lr: float = spec(1e-3, low=0.0, low_open=True)
    clip_q_targets: bool = False
    return_min: float = -2.5
    return_max: float = 1.5
    alpha_min: float = spec(0.0, low=0.0)
    alpha_lr: float = spec(0.0, low=0.0)
    policy_lr: float = spec(0.0, low=0.0)
    grad_clip_norm: float = spec(0.0, low=0.0)
    critic_layer_norm: bool = False
    target_entropy_start_scale: float = 0.98
    target_entropy_anneal_updates: int = spec(0, low=0)
    average_q: bool = False
    q_clip: float = spec(0.0, low=0.0)
    entropy_penalty: float = spec(0.0, low=0.0)
    anchor_weight: float = spec(0.0, low=0.0)

    # may change when a run resumes: bitwise the same training either way
    RESUME_MUTABLE: ClassVar[tuple[str, ...]] = ("parallel_update",)

    def __post_init__(self) -> None:
        check_fields(self, "dsac")
        if self.bc_epochs > 0 and self.demo_episodes == 0:
            raise ValueError(
                "dsac.bc_epochs clones the demonstrations' actions: set dsac.demo_episodes too"
            )
        if self.anchor_weight > 0 and self.init_model is None:
            raise ValueError(
                "dsac.anchor_weight pulls the policy towards the initial policy of "
                "dsac.init_model: set dsac.init_model too, or dsac.anchor_weight to 0"
            )
        if self.cuda_graph:
            conflicts = {
                "parallel_update": self.parallel_update,
                "target_entropy_anneal_updates": self.target_entropy_anneal_updates > 0,
                "clip_q_targets": self.clip_q_targets,
            }
            for name, on in conflicts.items():
                if on:
                    raise ValueError(
                        f"dsac.cuda_graph replays one fixed update: turn dsac.{name} off "
                        "or dsac.cuda_graph off"
                    )
        check_below("dsac.return_min", self.return_min, "dsac.return_max", self.return_max)


class SoftQNetwork(nn.Module):
    """Critic: encoder + twin Q heads. ``forward(robot, humans, mask) -> (q1, q2)``, (B, A) each."""

    def __init__(
        self, encoder: Encoder, n_actions: int, hidden: tuple[int, ...], layer_norm: bool = False
    ):
        super().__init__()
        self.encoder = encoder
        self.head = QHead(encoder.out_dim, n_actions, hidden, layer_norm)

    def forward(self, robot: Tensor, humans: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
        features, _ = self.encoder(robot, humans, mask)
        return self.head(features)


class Actor(nn.Module):
    """Policy: encoder + logits head. ``forward(...) -> (logits (B, A), attention (B, N) | None)``.

    With ``detach_encoder`` the encoder (owned and trained by the critic) runs without gradient.
    """

    def __init__(
        self, encoder: Encoder, n_actions: int, hidden: tuple[int, ...], detach_encoder: bool
    ):
        super().__init__()
        self.encoder = encoder
        self.head = PolicyHead(encoder.out_dim, n_actions, hidden)
        self.detach_encoder = detach_encoder

    def forward(self, robot: Tensor, humans: Tensor, mask: Tensor) -> tuple[Tensor, Tensor | None]:
        with torch.set_grad_enabled(torch.is_grad_enabled() and not self.detach_encoder):
            features, attention = self.encoder(robot, humans, mask)
        return self.head(features), attention


class DSAC:
    """Discrete SAC agent: critic, target critic, policy, temperature and their optimisers.

    Args:
        config: hyper-parameters.
        encoder_config: which encoder the critic and the policy use (each gets its own instance
            unless ``config.share_encoder``).
        seed: parameters are initialised from this seed without touching torch's global RNG.
        device: where the networks live; batches passed to :meth:`update` must be there too.
    """

    def __init__(
        self,
        config: DSACConfig,
        encoder_config: EncoderConfig,
        seed: int = 0,
        device: torch.device | str = "cpu",
    ):
        self.config = config
        self.encoder_config = encoder_config
        self.device = torch.device(device)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            self.critic = SoftQNetwork(
                make_encoder(encoder_config),
                config.n_actions,
                config.q_hidden,
                config.critic_layer_norm,
            )
            actor_encoder = (
                self.critic.encoder if config.share_encoder else make_encoder(encoder_config)
            )
            self.actor = Actor(
                actor_encoder, config.n_actions, config.policy_hidden, config.share_encoder
            )
        if config.cuda_graph and self.device.type != "cuda":
            raise ValueError(
                f"dsac.cuda_graph needs a CUDA device, not {str(self.device)!r}: set device: cuda "
                "or turn dsac.cuda_graph off"
            )
        self.critic.to(self.device)
        self.actor.to(self.device)
        self.critic_target = frozen_copy(self.critic)
        self.log_alpha = torch.tensor(
            math.log(config.init_alpha), device=self.device, requires_grad=True
        )

        actor_params = self.actor.head if config.share_encoder else self.actor
        # One Adam per half of the update, so that each half can take its step on its own thread.
        self.critic_optimizer = torch.optim.Adam(
            [{"params": list(self.critic.parameters()), "name": "critic"}],
            lr=config.lr,
            fused=True,
            capturable=config.cuda_graph,
        )
        self.actor_optimizer = torch.optim.Adam(
            [
                {
                    "params": list(actor_params.parameters()),
                    "name": "actor",
                    "lr": config.policy_lr or config.lr,
                },
                {"params": [self.log_alpha], "name": "alpha", "lr": config.alpha_lr or config.lr},
            ],
            lr=config.lr,
            fused=True,
            capturable=config.cuda_graph,
        )
        self._critic_params = list(self.critic.parameters())
        self._actor_params = list(actor_params.parameters())
        self._log_alpha_min = math.log(config.alpha_min) if config.alpha_min > 0 else None
        self._target_params = list(self.critic_target.parameters())
        self._worker = ThreadPoolExecutor(1) if config.parallel_update else None
        self._graphed = GraphedStep(self._update_tensors) if config.cuda_graph else None
        self.anchor: Actor | None = None
        self.n_updates = 0

    def anchor_to_actor(self) -> None:
        """Freeze a copy of the policy as it is now as the ``anchor_weight`` term's ``pi_0``."""
        self.anchor = frozen_copy(self.actor)

    @property
    def alpha(self) -> float:
        """Current temperature."""
        return float(self.log_alpha.detach().exp())

    @property
    def target_entropy(self) -> float:
        """Target entropy of the next update: ``target_entropy`` when set, else
        ``scale * log(n_actions)``, the scale following the schedule of
        ``target_entropy_anneal_updates``."""
        config = self.config
        if config.target_entropy is not None:
            return config.target_entropy
        scale = config.target_entropy_scale
        if self.n_updates < config.target_entropy_anneal_updates:
            progress = self.n_updates / config.target_entropy_anneal_updates
            start = config.target_entropy_start_scale
            scale = start + (scale - start) * progress
        return scale * math.log(config.n_actions)

    @torch.no_grad()
    def act(
        self,
        robot: Tensor,
        humans: Tensor,
        mask: Tensor,
        deterministic: bool = False,
        generator: torch.Generator | None = None,
    ) -> tuple[Tensor, Tensor | None]:
        """Choose one action per state.

        Returns ``(actions (B,) int64, attention (B, N) or None)``: the argmax of the policy when
        ``deterministic``, else a sample from it drawn with ``generator`` (reproducible).
        """
        logits, attention = self.actor(robot, humans, mask)
        if deterministic:
            return logits.argmax(dim=1), attention
        return _draw(logits, generator)[0], attention

    @torch.no_grad()
    def sample(
        self, robot: Tensor, humans: Tensor, mask: Tensor, generator: torch.Generator | None = None
    ) -> tuple[Tensor, Tensor]:
        """``(actions (B,), entropy (B,))``: the actions :meth:`act` would sample with the same
        ``generator``, and the policy's entropy in each state (the behaviour entropy that
        ``entropy_penalty`` compares with)."""
        return _draw(self.actor(robot, humans, mask)[0], generator)

    def update(self, batch: dict[str, Tensor]) -> dict[str, float]:
        """One gradient step on critic, policy and temperature from a replay batch.

        ``batch`` holds the keys of :meth:`crowdplan.algos.buffer.ReplayBuffer.sample`. Returns
        floats: ``qf1_loss, qf2_loss, qf_loss, actor_loss, alpha_loss, alpha, entropy, qf_mean``.
        """
        # the policy stays frozen for the first actor_warmup_updates: a different update, so the
        # graph is captured after them
        with unpacked_lstm(self.config.cuda_graph):
            if self._graphed is not None and self.n_updates >= self.config.actor_warmup_updates:
                stats = self._graphed(batch)
            else:
                stats = self._update_tensors(batch)
        self.n_updates += 1
        return dict(zip(UPDATE_STATS, stats.tolist(), strict=True))

    def _update_tensors(self, batch: dict[str, Tensor]) -> Tensor:
        """The update of :meth:`update` without reading anything back to the host: returns its
        statistics as one tensor in the order of :data:`UPDATE_STATS`."""
        obs = (batch["robot"], batch["humans"], batch["mask"])
        next_obs = (batch["next_robot"], batch["next_humans"], batch["next_mask"])
        alpha = self.log_alpha.detach().exp()
        behaviour_entropy = batch["behaviour_entropy"] if self.config.entropy_penalty else None

        # The critic loss and the policy + temperature losses act on disjoint parameters and
        # every cross term (Q in the policy loss, alpha in both, the entropy in the temperature
        # loss) is detached, so each half can take its own optimiser step as soon as its backward
        # is done. With ``parallel_update`` the policy's work (pi(s'), pi(s), its backward and
        # step) and the critic's (Q'(s'), Q(s), its backward, step and target update) run on two
        # threads, exchanging pi(.|s') and min Q(s, .) through futures; torch releases the GIL
        # inside its kernels, and the results are bitwise the same as on one thread.
        next_policy: Future[tuple[Tensor, Tensor]] = Future()
        min_qf_values: Future[Tensor] = Future()
        critic_args = (obs, next_obs, batch["action"], batch["reward"], batch["done"], alpha)
        if self._worker is None:
            self._next_policy(next_obs, next_policy)
            critic_stats = self._critic_step(*critic_args, next_policy, min_qf_values)
            actor_stats = self._actor_step(obs, alpha, min_qf_values, behaviour_entropy)
        else:
            critic_job = self._worker.submit(
                self._critic_step, *critic_args, next_policy, min_qf_values
            )
            try:
                self._next_policy(next_obs, next_policy)
                actor_stats = self._actor_step(obs, alpha, min_qf_values, behaviour_entropy)
            except BaseException:
                wait([critic_job])  # it fails too (its inputs are failed futures); let it finish
                raise
            critic_stats = critic_job.result()
        if self.config.share_encoder:
            self._step_critic()
        qf1_loss, qf2_loss, qf_loss, qf_mean = critic_stats
        actor_loss, alpha_loss, entropy = actor_stats
        return torch.stack(
            [qf1_loss, qf2_loss, qf_loss, actor_loss, alpha_loss, alpha, entropy, qf_mean]
        )

    def _critic_step(
        self,
        obs: tuple[Tensor, Tensor, Tensor],
        next_obs: tuple[Tensor, Tensor, Tensor],
        actions: Tensor,
        rewards: Tensor,
        dones: Tensor,
        alpha: Tensor,
        next_policy: Future[tuple[Tensor, Tensor]],
        min_qf_values: Future[Tensor],
    ) -> tuple[Tensor, ...]:
        """Soft target, twin-critic loss, backward and step; hands the twin estimate of Q(s, .)
        (:meth:`twin_q`) to the policy step through ``min_qf_values`` as soon as the critic's
        forward pass has it."""
        self.critic_optimizer.zero_grad(set_to_none=True)
        try:
            with torch.no_grad():
                if self.config.q_clip > 0:  # Q'(s) too, in the same pass as Q'(s')
                    both = [torch.cat(pair) for pair in zip(next_obs, obs, strict=True)]
                    split = len(actions)
                    qf1_target, qf2_target = self.critic_target(*both)
                    qf1_next_target, qf1_old = qf1_target[:split], qf1_target[split:]
                    qf2_next_target, qf2_old = qf2_target[:split], qf2_target[split:]
                else:
                    qf1_next_target, qf2_next_target = self.critic_target(*next_obs)
            qf1_values, qf2_values = self.critic(*obs)
            min_qf_values.set_result(self.twin_q(qf1_values, qf2_values).detach())
            with torch.no_grad():
                next_pi, next_log_pi = next_policy.result()
                # soft state value: exact expectation over the actions (a sum, not a mean)
                min_qf_next_target = (
                    next_pi * (self.twin_q(qf1_next_target, qf2_next_target) - alpha * next_log_pi)
                ).sum(dim=1)
                # dones are terminations only; truncated (timeout) transitions bootstrap
                next_q_value = rewards + self.config.gamma * (1.0 - dones) * min_qf_next_target
                if self.config.clip_q_targets:
                    next_q_value = next_q_value.clamp(*self._target_range(alpha))
            index = actions.unsqueeze(1)
            qf1_a_values = qf1_values.gather(1, index).squeeze(1)
            qf2_a_values = qf2_values.gather(1, index).squeeze(1)
            qf1_loss = F.mse_loss(qf1_a_values, next_q_value)
            qf2_loss = F.mse_loss(qf2_a_values, next_q_value)
            if self.config.q_clip > 0:
                qf1_loss = self._clipped_loss(qf1_loss, qf1_a_values, qf1_old, index, next_q_value)
                qf2_loss = self._clipped_loss(qf2_loss, qf2_a_values, qf2_old, index, next_q_value)
            qf_loss = qf1_loss + qf2_loss
            qf_loss.backward()
        except BaseException as error:
            if not min_qf_values.done():  # never leave the policy step waiting
                min_qf_values.set_exception(error)
            raise
        if not self.config.share_encoder:
            # a shared encoder is still being read by the policy half: `update` steps it later
            self._step_critic()
        return qf1_loss.detach(), qf2_loss.detach(), qf_loss.detach(), qf1_a_values.mean().detach()

    def twin_q(self, q1: Tensor, q2: Tensor) -> Tensor:
        """The twin critics' joint estimate: their minimum, or their mean with ``average_q``."""
        return (q1 + q2) * 0.5 if self.config.average_q else torch.min(q1, q2)

    def _clipped_loss(
        self, loss: Tensor, q_a: Tensor, q_old: Tensor, index: Tensor, target: Tensor
    ) -> Tensor:
        """Q-clip: the larger of ``loss`` and the MSE of ``q_a`` held within ``q_clip`` of the
        target critic's ``q_old`` (s, .) at the batch's actions ``index``."""
        old = q_old.gather(1, index).squeeze(1)
        clip = self.config.q_clip
        return torch.maximum(loss, F.mse_loss(old + (q_a - old).clamp(-clip, clip), target))

    def _target_range(self, alpha: Tensor) -> tuple[float, float]:
        """Reachable soft targets: the return bounds, plus the entropy bonus's largest sum."""
        config = self.config
        if config.gamma >= 1.0:
            return config.return_min, math.inf
        bonus = float(alpha) * math.log(config.n_actions) * config.gamma / (1.0 - config.gamma)
        return config.return_min, config.return_max + bonus

    def _step_critic(self) -> None:
        """Adam step of the critic, then ``target <- target + tau (critic - target)``."""
        if self.config.grad_clip_norm > 0:
            nn.utils.clip_grad_norm_(self._critic_params, self.config.grad_clip_norm)
        self.critic_optimizer.step()
        with torch.no_grad():
            torch._foreach_lerp_(self._target_params, self._critic_params, self.config.tau)

    @torch.no_grad()
    def _next_policy(
        self, next_obs: tuple[Tensor, Tensor, Tensor], out: Future[tuple[Tensor, Tensor]]
    ) -> None:
        """pi(.|s') and log pi(.|s') for the soft target, delivered through ``out``."""
        try:
            next_log_pi = F.log_softmax(self.actor(*next_obs)[0], dim=1)
            out.set_result((next_log_pi.exp(), next_log_pi))
        except BaseException as error:
            out.set_exception(error)  # never leave the critic step waiting
            raise

    def _actor_step(
        self,
        obs: tuple[Tensor, Tensor, Tensor],
        alpha: Tensor,
        min_qf_values: Future[Tensor],
        behaviour_entropy: Tensor | None,
    ) -> tuple[Tensor, ...]:
        """Policy loss against this batch's (detached) critic values (plus the entropy penalty
        when ``behaviour_entropy`` is given), temperature loss, backward and the Adam step of the
        policy and the temperature."""
        self.actor_optimizer.zero_grad(set_to_none=True)
        log_pi = F.log_softmax(self.actor(*obs)[0], dim=1)
        action_probs = log_pi.exp()
        actor_loss = (action_probs * (alpha * log_pi - min_qf_values.result())).sum(dim=1).mean()
        entropy = -(action_probs * log_pi).sum(dim=1)
        if behaviour_entropy is not None:
            penalty = F.mse_loss(entropy, behaviour_entropy)
            actor_loss = actor_loss + self.config.entropy_penalty * penalty
        if self.config.anchor_weight > 0:
            if self.anchor is None:
                raise RuntimeError(
                    "dsac.anchor_weight needs the initial policy: call anchor_to_actor() after "
                    "loading it into the actor"
                )
            with torch.no_grad():
                anchor_probs = torch.softmax(self.anchor(*obs)[0], dim=1)
            cross_entropy = -(anchor_probs * log_pi).sum(dim=1).mean()
            actor_loss = actor_loss + self.config.anchor_weight * cross_entropy
        entropy = entropy.detach()
        alpha_loss = (self.log_alpha * (entropy - self.target_entropy)).mean()
        if self.n_updates < self.config.actor_warmup_updates:
            return actor_loss.detach(), alpha_loss.detach(), entropy.mean()
        (actor_loss + (alpha_loss if self.config.autotune_alpha else 0.0)).backward()
        if self.config.grad_clip_norm > 0:
            nn.utils.clip_grad_norm_(self._actor_params, self.config.grad_clip_norm)
        self.actor_optimizer.step()
        if self._log_alpha_min is not None:
            with torch.no_grad():
                self.log_alpha.clamp_(min=self._log_alpha_min)
        return actor_loss.detach(), alpha_loss.detach(), entropy.mean()

    def state_dict(self) -> dict[str, Any]:
        """Everything needed to resume: networks, target, temperature and optimiser states."""
        return {
            "critic": self.critic.state_dict(),
            "critic_target": self.critic_target.state_dict(),
            "actor": self.actor.state_dict(),
            "log_alpha": self.log_alpha.detach().clone(),
            "critic_optimizer": self.critic_optimizer.state_dict(),
            "actor_optimizer": self.actor_optimizer.state_dict(),
            "n_updates": self.n_updates,
        }

    def load_networks(self, networks: dict[str, Any]) -> None:
        """Start from another run's actor, critic, target critic and log temperature (the
        optimisers start afresh)."""
        self.critic.load_state_dict(networks["critic"])
        self.critic_target.load_state_dict(networks["critic_target"])
        self.actor.load_state_dict(networks["actor"])
        with torch.no_grad():
            self.log_alpha.copy_(networks["log_alpha"])

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`state_dict` returned (same configs)."""
        self.critic.load_state_dict(state["critic"])
        self.critic_target.load_state_dict(state["critic_target"])
        self.actor.load_state_dict(state["actor"])
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        if "optimizer" in state:  # checkpoints of versions with one Adam over all three groups
            critic_state, actor_state = _split_joint_optimizer_state(state["optimizer"])
        else:
            critic_state, actor_state = state["critic_optimizer"], state["actor_optimizer"]
        for optimizer, saved in (
            (self.critic_optimizer, critic_state),
            (self.actor_optimizer, actor_state),
        ):
            optimizer.load_state_dict(saved)
            for group in optimizer.param_groups:  # the saved flag is the saving run's
                group["capturable"] = self.config.cuda_graph
        self.n_updates = int(state["n_updates"])


def _draw(logits: Tensor, generator: torch.Generator | None) -> tuple[Tensor, Tensor]:
    """One action per row sampled from ``softmax(logits)`` with ``generator``, and the
    distribution's entropy per row."""
    probs = torch.softmax(logits, dim=1)
    entropy = -(probs * F.log_softmax(logits, dim=1)).sum(dim=1)
    return torch.multinomial(probs, 1, generator=generator).squeeze(1), entropy


def _split_joint_optimizer_state(state: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Split the state of one Adam with groups (critic, actor, alpha) into the states of the
    critic's Adam and of the actor's (actor, alpha). Parameter ids may stay as saved: Adam maps
    them onto its parameters by their position in the groups."""
    critic_groups, actor_groups = state["param_groups"][:1], state["param_groups"][1:]

    def part(groups: list[dict[str, Any]]) -> dict[str, Any]:
        ids = {i for group in groups for i in group["params"]}
        return {
            "state": {i: s for i, s in state["state"].items() if i in ids},
            "param_groups": groups,
        }

    return part(critic_groups), part(actor_groups)
