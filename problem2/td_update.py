"""A batch of joint transitions as tensors, and the TD gradient written out by hand.

:meth:`trainer.MultiAgentTrainer.td_loss` defines the loss with autograd, in a few
readable lines. An update of these small networks is dominated by per-operation overhead
(hundreds of tiny autograd operations), so for the plain network (not dueling) the
trainer computes the same gradient with :class:`FastTDGradient`: the same forward passes,
then the backward pass of the two-layer MLP written out by hand, into the flat gradient
of :class:`paired_networks.PairedQNetworks`. A test holds the two equal.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
import torch.nn.functional as F
from paired_networks import PairedQNetworks


@dataclass
class TransitionBatch:
    """B joint transitions, agent axis first (A, then B). Filled in place per update."""

    obs: torch.Tensor  # (2, B, D) observations
    next_obs: torch.Tensor  # (2, B, D) next observations, the TD target bootstraps from
    last_obs: torch.Tensor  # (2, B, D) observations one step before next_obs (= obs if n = 1)
    prev_obs: torch.Tensor  # (2, B, D) each agent's observation one step earlier (DIAL)
    has_prev: torch.Tensor  # (B,) 1.0 where prev_obs is stored, else 0.0
    actions: torch.Tensor  # (2, B) int64
    reward: torch.Tensor  # (B,) the team reward
    done: torch.Tensor  # (B,) 1.0 where both agents reached the target (terminal)
    discount: torch.Tensor  # (B,) γ^k of the k-step return, 0 where terminal: γ (1 − done) if k = 1
    weights: torch.Tensor  # (B,) importance weights (ones without prioritised replay)

    @classmethod
    def empty(cls, batch_size: int, obs_dim: int) -> TransitionBatch:
        def states() -> torch.Tensor:
            return torch.zeros(2, batch_size, obs_dim)

        return cls(
            obs=states(),
            next_obs=states(),
            last_obs=states(),
            prev_obs=states(),
            has_prev=torch.zeros(batch_size),
            actions=torch.zeros(2, batch_size, dtype=torch.int64),
            reward=torch.zeros(batch_size),
            done=torch.zeros(batch_size),
            discount=torch.zeros(batch_size),
            weights=torch.ones(batch_size),
        )

    @classmethod
    def of_rows(cls, rows: torch.Tensor, layout: dict[str, slice], obs_dim: int) -> TransitionBatch:
        """A batch whose fields are views of ``rows`` (B, row width), packed replay rows
        with the columns ``layout`` (``ReplayBuffer.sample_rows`` fills them in place).
        Fields the rows lack stay zeros, except ``last_obs``, which is then ``obs`` (one-step
        transitions). ``actions`` stays a copy (int64, to index with): see
        :meth:`read_actions`."""
        batch = cls.empty(rows.shape[0], obs_dim)

        def pair(name_a: str) -> torch.Tensor:  # columns of X_A then X_B -> (2, B, D)
            first = layout[name_a].start
            return rows[:, first : first + 2 * obs_dim].view(-1, 2, obs_dim).transpose(0, 1)

        pairs = {"obs": "state_A", "next_obs": "next_state_A", "prev_obs": "prev_state_A"}
        for attribute, name in (pairs | {"last_obs": "last_state_A"}).items():
            if name in layout:
                setattr(batch, attribute, pair(name))
        if "last_state_A" not in layout:
            batch.last_obs = batch.obs
        for name in ("has_prev", "reward", "done", "discount"):
            if name in layout:
                setattr(batch, name, rows[:, layout[name].start])
        return batch

    @staticmethod
    def stored_actions(rows: torch.Tensor, layout: dict[str, slice]) -> torch.Tensor:
        """The actions' columns of ``rows`` as a (2, B) float32 view (A's column then B's),
        to copy into ``actions`` after each gather."""
        first = layout["action_A"].start
        return rows[:, first : first + 2].T

    def clone(self) -> TransitionBatch:
        return TransitionBatch(**{f.name: getattr(self, f.name).clone() for f in fields(self)})


class FastTDGradient:
    """The gradient of ``MultiAgentTrainer.td_loss`` without autograd (plain network only).

    Notation per agent i (weights ``W1 b1`` hidden, ``W2 b2`` head: A Q-rows and a message
    row), masked inputs x, batch of B with importance weights w:

        h = relu(W1 x + b1),  q = W2[:A] h + b2[:A],  δ = q[a] − y,
        y = R + d · Q_target(s', argmax_a Q_online(s', a)),  R, d: the k-step reward and
        discount of the batch (k = 1: R = r, d = γ (1 − done)),
        L = Σ_i (1/B) Σ_b w_b huber(δ_ib),  ∂L/∂q[a] = clamp(δ, −1, 1) · w / B.

    Backward: the head gradient g (K, B) is zero except ∂L/∂q[a] in the taken action's
    row; ∂W2 = g hᵀ, ∂b2 = Σ_b g; the hidden gradient g_h = (W2ᵀ g) ⊙ [h > 0];
    ∂W1 = g_h xᵀ, ∂b1 = Σ_b g_h.
    DIAL: the receiver's input element m = w² (the message) is s = sigmoid(z) of the
    partner's message logit z on its previous observation, so ∂L/∂s = W1[:, m]ᵀ g_h and
    ∂L/∂z = ∂L/∂s · s(1 − s) (zero where no previous observation is stored); that flows
    back through the sender's message row and hidden layer exactly as above.
    The TD target y (Double DQN; the message in s' from the partner's target network on
    its observation one step before s') carries no gradient. Inputs and activations are
    held feature-major, (2, features, B): the small matrix products run several times
    faster that way on a CPU.
    Writes ``online.flat.grad`` and returns (loss, δ (2, B), mean Q(s, a)).
    """

    def __init__(
        self,
        online: PairedQNetworks,
        target: PairedQNetworks,
        mask: torch.Tensor,
        dial: bool,
        comm_noise: float,
        noise_rng: torch.Generator,
        weighted: bool = False,
    ) -> None:
        if online.dueling:
            raise ValueError("the hand-written gradient covers the plain network only")
        self.online, self.target, self.mask = online, target, mask.view(-1, 1)
        self.dial, self.comm_noise, self.noise_rng = dial, comm_noise, noise_rng
        self.weighted = weighted  # importance weights other than 1 (prioritised replay)
        self.num_actions = online.num_actions
        self.message = online.input_dim - 2  # input index of the received message
        self._views: tuple[int, int, int, LayerViews, LayerViews, LayerViews] | None = None
        self._buffers: dict[int, dict[str, torch.Tensor]] = {}
        self._batch: TransitionBatch | None = None  # the batch of the views below
        self._batch_views: tuple[torch.Tensor, ...] = ()

    def views(self) -> tuple[LayerViews, LayerViews, LayerViews]:
        """Views of the online and target weights and of the online gradient, made once
        (every view costs a tensor operation): (online, target, gradient)."""
        grad = self.online.flat.grad
        if self._views is not None and grad is not None:  # the usual case: storage unchanged
            key = (self.online.flat.data_ptr(), self.target.flat.data_ptr(), grad.data_ptr())
            if self._views[:3] == key:
                return self._views[3:]
        with torch.no_grad():
            online, target = self.online.weights(), self.target.weights()
            gradient = self.online.gradients()
        key = tuple(tensors[0].data_ptr() for tensors in (online, target, gradient))
        if self._views is None or self._views[:3] != key:
            m = self.message
            self._views = (
                *key,
                *(LayerViews.of(t, self.num_actions, m, False) for t in (online, target)),
                LayerViews.of(gradient, self.num_actions, m, True),
            )
        return self._views[3:]

    def buffers(self, batch_size: int) -> dict[str, torch.Tensor]:
        """Activations (2, features, B), reused between calls of the same batch size. With
        DIAL the online network sees the next and the previous observations side by side
        in one pass (2B). (Halves of a buffer are never written with ``out=``: a strided
        output makes a batched product copy, slower than two products.)"""
        if batch_size not in self._buffers:
            online, b = self.online, batch_size
            both = 2 * b if self.dial else b  # next (and previous) observations
            shapes = dict(
                x=(online.input_dim, b), next_prev_x=(online.input_dim, both),
                last_x=(online.input_dim, b),
                target_hidden=(online.hidden_dim, b), next_logit=(1, b),
                next_prev_hidden=(online.hidden_dim, both), next_prev_heads=(online.head_dim, both),
                next_target_hidden=(online.hidden_dim, b), next_target_q=(self.num_actions, b),
                hidden=(online.hidden_dim, b), q=(self.num_actions, b),
                grad_heads=(online.head_dim, b),
                grad_received=(1, b), best_next_q=(1, b),
                grad_w1_by_input=(online.input_dim, online.hidden_dim),
            )  # fmt: skip
            buf = {k: torch.empty(2, *shape) for k, shape in shapes.items()}
            buf["inverse_size"] = torch.tensor(1.0 / b)
            # The backward pass reuses the memory of the target network's hidden activations
            # (no longer needed by then): a smaller working set stays in the CPU's cache.
            buf["grad_hidden"] = buf["next_target_hidden"]
            buf["grad_prev_hidden"] = buf["target_hidden"]
            buf["best_next_action"] = torch.empty(2, 1, b, dtype=torch.int64)  # with best_next_q
            # Views used on every call, made once (each view costs about as much as an op).
            m, next_prev_x, next_prev_hidden = (
                self.message,
                buf["next_prev_x"],
                buf["next_prev_hidden"],
            )
            buf |= dict(
                next_x=next_prev_x[..., :b], prev_x=next_prev_x[..., b:],
                x_message=buf["x"][:, m], next_x_message=next_prev_x[:, m, :b],
                next_q=buf["next_prev_heads"][:, : self.num_actions, :b],
                logit=buf["next_prev_heads"][:, -1:, b:], prev_hidden=next_prev_hidden[..., b:],
                hidden_t=buf["hidden"].transpose(1, 2),
                grad_hidden_t=buf["grad_hidden"].transpose(1, 2),
                grad_prev_hidden_t=buf["grad_prev_hidden"].transpose(1, 2),
                grad_w1_by_input_t=buf["grad_w1_by_input"].transpose(1, 2),
                prev_hidden_t=next_prev_hidden[..., b:].transpose(1, 2),
            )  # fmt: skip
            self._buffers = {b: buf}
        return self._buffers[batch_size]

    def batch_views(self, batch: TransitionBatch) -> tuple[torch.Tensor, ...]:
        """Feature-major views (2, D, B) of the batch's observations (obs, next, previous,
        last) and its actions as (2, 1, B); made once for a batch that is refilled in place."""
        if batch is not self._batch:
            states = (batch.obs, batch.next_obs, batch.prev_obs, batch.last_obs)
            self._batch_views = (*(x.transpose(1, 2) for x in states), batch.actions.unsqueeze(1))
            self._batch = batch
        return self._batch_views

    def __call__(self, batch: TransitionBatch) -> tuple[float, torch.Tensor, float]:
        online, target, grad = self.views()  # plain views, made outside inference mode
        # Nothing here needs autograd (every tensor used is detached): inference mode skips
        # its bookkeeping on each operation. The activations it creates stay in this class.
        with torch.inference_mode():
            return self._loss_and_gradient(batch, online, target, grad)

    def _loss_and_gradient(
        self, batch: TransitionBatch, online: LayerViews, target: LayerViews, grad: LayerViews
    ) -> tuple[float, torch.Tensor, float]:
        size = batch.obs.shape[1]
        buf = self.buffers(size)
        obs_t, next_obs_t, prev_obs_t, last_obs_t, actions = self.batch_views(batch)
        # Masked inputs, feature-major (2, D, B); next and previous side by side (2, D, 2B).
        x = torch.mul(obs_t, self.mask, out=buf["x"])
        next_x = torch.mul(next_obs_t, self.mask, out=buf["next_x"])
        if self.dial:
            torch.mul(prev_obs_t, self.mask, out=buf["prev_x"])
            # Next message: the partner's target network on its observation before s'.
            last_x = torch.mul(last_obs_t, self.mask, out=buf["last_x"])
            target_hidden = target.hidden(last_x, buf["target_hidden"])
            next_logit = target.message(target_hidden, buf["next_logit"])  # (2, 1, B)
            torch.sigmoid(next_logit.flip(0).squeeze(1), out=buf["next_x_message"])
        # One online pass: Q on the next observations (for the Double DQN argmax) and, with
        # DIAL, the message logits on the previous ones.
        online.heads(
            online.hidden(buf["next_prev_x"], buf["next_prev_hidden"]), buf["next_prev_heads"]
        )
        best_next = torch.max(
            buf["next_q"], 1, keepdim=True, out=(buf["best_next_q"], buf["best_next_action"])
        ).indices  # (2, 1, B)
        if self.dial:
            # Received message: the partner's online network on its previous observation.
            logit = buf["logit"]
            if self.comm_noise > 0:
                noise = torch.randn(logit.shape, generator=self.noise_rng)
                logit.add_(noise, alpha=self.comm_noise)
            sent = logit.sigmoid_()  # (2, 1, B), indexed by the sender
            has_prev = batch.has_prev  # (B,) 1.0 / 0.0
            x_message = buf["x_message"]
            # Where has_prev is 1 the recomputed message, else the stored one (lerp is exact
            # at weights 0 and 1, and one operation instead of a comparison and a where).
            torch.lerp(x_message, sent.flip(0).squeeze(1), has_prev, out=x_message)
        # TD target: the target network's value of the online argmax, no gradient.
        next_target_q = target.q(
            target.hidden(next_x, buf["next_target_hidden"]), buf["next_target_q"]
        )
        next_value = next_target_q.gather(1, best_next).squeeze(1)  # (2, B)
        y = torch.addcmul(batch.reward, batch.discount, next_value)  # R + d Q'
        # Forward on the current observation, Huber loss.
        hidden = online.hidden(x, buf["hidden"])  # (2, H, B)
        q = online.q(hidden, buf["q"])  # (2, A, B)
        q_taken = q.gather(1, actions).squeeze(1)  # (2, B)
        delta = q_taken - y
        if self.weighted:
            scale = batch.weights / size
            loss = float(F.huber_loss(q_taken, y, reduction="none").mul_(scale).sum())
            grad_q = delta.clamp(-1.0, 1.0).mul_(scale)  # ∂L/∂q[a] (2, B)
        else:
            loss = float(huber_loss_sum(q_taken, y)) / size
            # clamp(δ, −1, 1) / B: what the Huber backward of a sum computes, bit for bit
            # (its kernel: clamp(q − y, −1, 1) · 1 · grad), cheaper as two plain operations.
            grad_q = delta.clamp(-1.0, 1.0).mul_(buf["inverse_size"])
        # Backward.
        grad_heads = buf["grad_heads"].zero_()  # (2, K, B)
        grad_heads.scatter_(1, actions, grad_q.unsqueeze(1))
        torch.bmm(grad_heads, buf["hidden_t"], out=grad.w2)
        torch.sum(grad_heads, dim=2, out=grad.b2)
        grad_hidden = torch.bmm(online.w2_t, grad_heads, out=buf["grad_hidden"])
        relu_backward_(grad_hidden, hidden)
        # ∂W1 is computed transposed, x g_hᵀ (2, D, H), and copied into place at the end:
        # a product whose result has D = 11 columns is 2-3x slower on a CPU.
        grad_w1_by_input = torch.bmm(x, buf["grad_hidden_t"], out=buf["grad_w1_by_input"])
        torch.sum(grad_hidden, dim=2, out=grad.b1)
        if self.dial:
            grad_received = torch.bmm(online.w1_message, grad_hidden, out=buf["grad_received"])
            grad_logit = sigmoid_backward(grad_received.mul_(has_prev).flip(0), sent)
            grad.wm.baddbmm_(grad_logit, buf["prev_hidden_t"])
            grad.bm.add_(grad_logit.sum(dim=2))
            grad_prev_hidden = torch.bmm(online.wm_t, grad_logit, out=buf["grad_prev_hidden"])
            relu_backward_(grad_prev_hidden, buf["prev_hidden"])
            grad_w1_by_input.baddbmm_(buf["prev_x"], buf["grad_prev_hidden_t"])
            grad.b1.add_(grad_prev_hidden.sum(dim=2))
        grad.w1.copy_(buf["grad_w1_by_input_t"])
        return loss, delta, float(q_taken.mean())


@dataclass
class LayerViews:
    """Views of the stacked weights (or gradients) of :class:`PairedQNetworks`, shaped for
    feature-major activations (2, features, B)."""

    w1: torch.Tensor  # (2, H, D)
    b1: torch.Tensor  # (2, H, 1); of a gradient (2, H)
    w2: torch.Tensor  # (2, K, H)
    b2: torch.Tensor  # (2, K, 1); of a gradient (2, K)
    wq: torch.Tensor  # (2, A, H) Q rows
    bq: torch.Tensor  # (2, A, 1)
    wm: torch.Tensor  # (2, 1, H) message row
    bm: torch.Tensor  # (2, 1, 1); of a gradient (2, 1)
    w2_t: torch.Tensor  # (2, H, K)
    wm_t: torch.Tensor  # (2, H, 1)
    w1_message: torch.Tensor  # (2, 1, H) the hidden weights of the message input

    @classmethod
    def of(
        cls, tensors: tuple[torch.Tensor, ...], num_actions: int, message: int, gradient: bool
    ) -> LayerViews:
        w1, b1, w2, b2 = tensors  # (2, H, D), (2, 1, H), (2, K, H), (2, 1, K)
        b1, b2 = (b1[:, 0], b2[:, 0]) if gradient else (b1.transpose(1, 2), b2.transpose(1, 2))
        wm = w2[:, -1:]
        return cls(
            w1=w1, b1=b1, w2=w2, b2=b2, wq=w2[:, :num_actions], bq=b2[:, :num_actions],
            wm=wm, bm=b2[:, -1:], w2_t=w2.transpose(1, 2), wm_t=wm.transpose(1, 2),
            w1_message=w1[..., message : message + 1].transpose(1, 2),
        )  # fmt: skip

    def hidden(self, x: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
        """relu(W1 x + b1): x (2, D, B) -> (2, H, B), written into ``out``."""
        return torch.baddbmm(self.b1, self.w1, x, out=out).relu_()

    def q(self, hidden: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
        """Q-values (2, A, B) of hidden activations (2, H, B)."""
        return torch.baddbmm(self.bq, self.wq, hidden, out=out)

    def heads(self, hidden: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
        """All K head outputs (2, K, B): the Q-values, then the message logit."""
        return torch.baddbmm(self.b2, self.w2, hidden, out=out)

    def message(self, hidden: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
        """Message logits (2, 1, B) of hidden activations (2, H, B)."""
        return torch.baddbmm(self.bm, self.wm, hidden, out=out)


def relu_backward_(grad: torch.Tensor, output: torch.Tensor) -> torch.Tensor:
    """In place: keep ``grad`` where the ReLU's ``output`` is positive, else 0."""
    return torch.ops.aten.threshold_backward.grad_input(grad, output, 0.0, grad_input=grad)


def huber_loss_sum(q: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Σ huber(q − y) (threshold 1): ``F.huber_loss(q, y, reduction="sum")`` without the
    Python checks of ``F`` (the same kernel)."""
    return torch.ops.aten.huber_loss(q, y, 2, 1.0)  # 2: sum


def sigmoid_backward(grad: torch.Tensor, output: torch.Tensor) -> torch.Tensor:
    """``grad · s (1 − s)`` for the sigmoid's ``output`` s (one fused operation)."""
    return torch.ops.aten.sigmoid_backward(grad, output)
