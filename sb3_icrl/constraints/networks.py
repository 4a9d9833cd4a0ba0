"""
Constraint models: a feasibility net ``phi(s, a) in (0, 1)`` and a Beta feasibility net for VICRL.

Both take numpy (or torch) batches of observations and actions as the env returns them, turn them into the net's
input (selected observation features, then the action, discrete spaces one-hot encoded), normalise that input
with statistics fitted on the expert data, and give the learned cost ``1 - phi`` as a batched numpy function that
``PPOLagrangian.set_cost_fn`` and ``LearnedCostVecEnvWrapper`` accept.
"""

import difflib
import inspect
from collections.abc import Sequence
from typing import Any, TypeVar

import numpy as np
import scipy.special
import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import create_mlp
from torch import nn

from sb3_icrl.common.utils import atomic_write

ArrayLike = np.ndarray | th.Tensor
SelfConstraintNet = TypeVar("SelfConstraintNet", bound="_ConstraintNet")

#: Cost modes of :class:`BetaFeasibilityNet`
BETA_COST_MODES = ("sample", "mean", "var", "cvar")
#: Largest batch that :meth:`_ConstraintNet.predict_feasibility` evaluates in NumPy (larger ones go through torch)
NUMPY_MAX_BATCH = 256


def _leaky_relu(x: np.ndarray) -> np.ndarray:
    return np.where(x >= 0, x, np.float32(0.01) * x)


def _elu(x: np.ndarray) -> np.ndarray:
    return np.where(x > 0, x, np.expm1(np.minimum(x, 0)))


#: The hidden activations (torch's defaults) the NumPy forward pass knows
NUMPY_ACTIVATIONS = {
    nn.ReLU: lambda x: np.maximum(x, np.float32(0)),
    nn.Tanh: np.tanh,
    nn.Sigmoid: scipy.special.expit,
    nn.LeakyReLU: _leaky_relu,
    nn.ELU: _elu,
}


class InputNormalizer(nn.Module):
    """
    Standardises the constraint net's input with the mean and standard deviation of the expert data, then clips:
    ``clip((x - mean) / sqrt(var + epsilon), -clip_range, clip_range)``.

    The statistics are buffers, so they travel with ``state_dict``. Until :meth:`fit` is called the normaliser
    refuses to run, so that a model cannot silently train on raw inputs.

    :param input_dim: Number of input features
    :param clip_range: Normalised inputs are clipped to ``[-clip_range, clip_range]`` (``None``: no clipping);
        nominal samples far outside the expert data then stay in a range the net has seen
    :param epsilon: Added to the variance, so constant expert features do not divide by zero
    """

    def __init__(self, input_dim: int, clip_range: float | None = 10.0, epsilon: float = 1e-8):
        super().__init__()
        if clip_range is not None and clip_range <= 0:
            raise ValueError(f"`clip_range` must be > 0 or None, got {clip_range}.")
        self.input_dim = input_dim
        self.clip_range = clip_range
        self.epsilon = epsilon
        self.mean: th.Tensor
        self.std: th.Tensor
        self.fitted: th.Tensor
        self.register_buffer("mean", th.zeros(input_dim))
        self.register_buffer("std", th.ones(input_dim))
        self.register_buffer("fitted", th.zeros((), dtype=th.bool))

    def fit(self, inputs: th.Tensor) -> None:
        """
        Set the statistics from a batch of (unnormalised) inputs, usually all expert pairs.

        :param inputs: Shape ``(n_samples, input_dim)``, ``n_samples >= 1``
        """
        if inputs.ndim != 2 or inputs.shape[1] != self.input_dim or inputs.shape[0] == 0:
            raise ValueError(
                f"The normaliser expects a non-empty batch of shape (n_samples, {self.input_dim}), got {tuple(inputs.shape)}."
            )
        with th.no_grad():
            inputs = inputs.to(dtype=self.mean.dtype, device=self.mean.device)
            self.mean.copy_(inputs.mean(dim=0))
            self.std.copy_(th.sqrt(inputs.var(dim=0, unbiased=False) + self.epsilon))
            self.fitted.fill_(True)

    def forward(self, inputs: th.Tensor) -> th.Tensor:
        if not bool(self.fitted):
            raise RuntimeError(
                "The input normaliser has not been fitted: call `fit_normalizer(expert_obs, expert_acts)` on the "
                "constraint net before using it, or build the net with `normalize_input=False`."
            )
        normalised = (inputs - self.mean) / self.std
        if self.clip_range is not None:
            normalised = th.clamp(normalised, -self.clip_range, self.clip_range)
        return normalised


def _constructor_arguments(net_class: type) -> set[str]:
    """The keyword arguments a constraint net class takes: its ``__init__``'s and, where that passes ``**kwargs`` on,
    its bases'."""
    names: set[str] = set()
    for klass in net_class.__mro__:
        if "__init__" not in vars(klass) or klass is nn.Module:
            continue
        parameters = inspect.signature(vars(klass)["__init__"]).parameters.values()
        names |= {p.name for p in parameters if p.name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}
        if not any(parameter.kind is parameter.VAR_KEYWORD for parameter in parameters):
            break
    return names


def reset_linear_layers(module: nn.Module) -> None:
    """
    Draw every linear layer of ``module`` afresh, with torch's default initialisation (from its global generator).

    :param module: The module, changed in place
    """
    for layer in module.modules():
        if isinstance(layer, nn.Linear):
            layer.reset_parameters()


class _ConstraintNet(nn.Module):
    """
    Shared input handling, normaliser and saving of the constraint nets. Subclasses set ``n_outputs`` and
    implement ``forward`` and ``predict_feasibility``.

    :param obs_dim: Observation features: the length of a flat Box observation, or ``n`` for ``Discrete(n)``
        (one-hot encoded)
    :param action_dim: Action features: the length of a flat Box action, or ``n`` for ``Discrete(n)``
    :param discrete_obs: Whether observations are integer indices of a ``Discrete`` space
    :param discrete_actions: Whether actions are integer indices of a ``Discrete`` space
    :param hidden_sizes: Units of each hidden layer
    :param activation_fn: Hidden activation, a class from ``torch.nn`` (saved by name)
    :param obs_select_dim: Indices of the observation features the net sees (``None``: all; ``()``: none); for a
        discrete observation they index the one-hot vector
    :param use_action: Whether the action is an input
    :param normalize_input: Whether to standardise the input with statistics fitted on expert data
    :param clip_input: Clip range of the normalised input (``None``: no clipping)
    """

    n_outputs: int = 1

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        discrete_obs: bool = False,
        discrete_actions: bool = False,
        hidden_sizes: Sequence[int] = (64, 64),
        activation_fn: type[nn.Module] = nn.ReLU,
        obs_select_dim: Sequence[int] | None = None,
        use_action: bool = True,
        normalize_input: bool = True,
        clip_input: float | None = 10.0,
    ):
        super().__init__()
        if obs_dim < 1 or action_dim < 1:
            raise ValueError(f"`obs_dim` and `action_dim` must be >= 1, got {obs_dim} and {action_dim}.")
        if getattr(nn, getattr(activation_fn, "__name__", ""), None) is not activation_fn:
            raise ValueError(f"`activation_fn` must be a class from torch.nn (e.g. nn.ReLU), got {activation_fn!r}.")
        self.obs_dim = int(obs_dim)
        self.action_dim = int(action_dim)
        self.discrete_obs = bool(discrete_obs)
        self.discrete_actions = bool(discrete_actions)
        sizes = list(hidden_sizes) if isinstance(hidden_sizes, (list, tuple)) else None
        if sizes is None or not all(
            isinstance(size, (int, np.integer)) and not isinstance(size, bool) and size >= 1 for size in sizes
        ):
            raise ValueError(f"`hidden_sizes` must be a list of layer widths (integers >= 1), got {hidden_sizes!r}.")
        self.hidden_sizes = [int(size) for size in sizes]
        self.activation_fn = activation_fn
        self.use_action = bool(use_action)
        self.normalize_input = bool(normalize_input)
        self.clip_input = clip_input
        self.obs_select_dim = self._check_obs_select_dim(obs_select_dim)
        # The NumPy path's index of the selected features: a list index is converted anew on every call, which costs
        # as much as the matmuls of a small net at batch 1; every feature in order needs no index at all
        self._numpy_obs_index: slice | np.ndarray = (
            slice(None) if self.obs_select_dim == list(range(self.obs_dim)) else np.asarray(self.obs_select_dim, dtype=np.intp)
        )
        self.input_dim = len(self.obs_select_dim) + (self.action_dim if self.use_action else 0)
        if self.input_dim == 0:
            raise ValueError("The constraint net has no input: `obs_select_dim` is empty and `use_action` is False.")
        self.normalizer = InputNormalizer(self.input_dim, clip_range=clip_input) if self.normalize_input else None
        self.network = nn.Sequential(*create_mlp(self.input_dim, self.n_outputs, self.hidden_sizes, activation_fn))
        # NumPy copies of the weights and the tensor versions they were made from (see _current_numpy_weights)
        self._numpy_weights: tuple[tuple[list[th.Tensor], list[int]], list[np.ndarray] | None] | None = None

    @classmethod
    def from_spaces(
        cls: type[SelfConstraintNet], observation_space: spaces.Space, action_space: spaces.Space, **kwargs: Any
    ) -> SelfConstraintNet:
        """
        Build the net for an env's spaces (flat ``Box`` or ``Discrete``).

        :param observation_space: The env's observation space
        :param action_space: The env's action space
        :param kwargs: The other constructor arguments
        :return: The net
        """
        # A misspelt argument (``constraint_net_kwargs: "dict(hiden_sizes=[64])"`` in a recipe) named with its fix
        accepted = _constructor_arguments(cls) - {"obs_dim", "action_dim", "discrete_obs", "discrete_actions"}
        for name in kwargs:
            if name not in accepted:
                close = difflib.get_close_matches(name, sorted(accepted), n=1, cutoff=0.6)
                raise TypeError(
                    f"{cls.__name__} takes no argument {name!r}{f' (did you mean {close[0]!r}?)' if close else ''}: its "
                    f"arguments are {', '.join(sorted(accepted))}."
                )
        obs_dim, discrete_obs = _space_features(observation_space, "observation")
        action_dim, discrete_actions = _space_features(action_space, "action")
        return cls(obs_dim, action_dim, discrete_obs=discrete_obs, discrete_actions=discrete_actions, **kwargs)

    def _check_obs_select_dim(self, obs_select_dim: Sequence[int] | None) -> list[int]:
        if obs_select_dim is None:
            return list(range(self.obs_dim))
        selected = [int(index) for index in obs_select_dim]
        bad = [index for index in selected if not 0 <= index < self.obs_dim]
        if bad:
            raise ValueError(
                f"`obs_select_dim` has indices {bad} outside the {self.obs_dim} observation features (valid: 0 to "
                f"{self.obs_dim - 1})."
            )
        if len(set(selected)) != len(selected):
            raise ValueError(f"`obs_select_dim` repeats indices: {selected}.")
        return selected

    @property
    def device(self) -> th.device:
        return next(self.parameters()).device

    @property
    def constructor_kwargs(self) -> dict[str, Any]:
        """The arguments that rebuild this net (plain values only; the activation is given by its name)."""
        return dict(
            obs_dim=self.obs_dim,
            action_dim=self.action_dim,
            discrete_obs=self.discrete_obs,
            discrete_actions=self.discrete_actions,
            hidden_sizes=list(self.hidden_sizes),
            activation_fn=self.activation_fn.__name__,
            obs_select_dim=list(self.obs_select_dim),
            use_action=self.use_action,
            normalize_input=self.normalize_input,
            clip_input=self.clip_input,
        )

    @classmethod
    def from_constructor_kwargs(cls: type[SelfConstraintNet], kwargs: dict[str, Any]) -> SelfConstraintNet:
        """
        Rebuild a net from :attr:`constructor_kwargs` (then load its ``state_dict``).

        :param kwargs: The saved constructor arguments
        :return: A freshly initialised net with that architecture
        """
        kwargs = dict(kwargs)
        activation = kwargs.get("activation_fn", "ReLU")
        if isinstance(activation, str):
            if not isinstance(getattr(nn, activation, None), type):
                raise ValueError(f"Unknown activation {activation!r}: expected the name of a class in torch.nn.")
            kwargs["activation_fn"] = getattr(nn, activation)
        return cls(**kwargs)

    def save(self, path: str) -> None:
        """
        Save the constructor arguments and the ``state_dict`` (weights and normaliser statistics) with ``torch.save``.

        :param path: Destination file
        """
        state_dict = {key: value.detach().cpu() for key, value in self.state_dict().items()}
        content = {"class": type(self).__name__, "kwargs": self.constructor_kwargs, "state_dict": state_dict}
        atomic_write(path, lambda file: th.save(content, file))  # a run killed while saving leaves no partial file

    @classmethod
    def load(cls: type[SelfConstraintNet], path: str, device: th.device | str = "cpu") -> SelfConstraintNet:
        """
        Load a net written by :meth:`save` (``weights_only``: nothing but tensors and plain values is unpickled).

        :param path: The saved file
        :param device: Where to put the net
        :return: The net, in eval mode
        """
        saved = th.load(path, map_location="cpu", weights_only=True)
        if saved.get("class") != cls.__name__:
            raise ValueError(f"{path!r} holds a {saved.get('class')!r}, not a {cls.__name__}: load it with that class.")
        net = cls.from_constructor_kwargs(saved["kwargs"])
        net.load_state_dict(saved["state_dict"])
        return net.to(device).eval()

    def _obs_features(self, obs: ArrayLike) -> th.Tensor:
        if self.discrete_obs:
            return self._one_hot(obs, self.obs_dim, "observation")
        tensor = th.as_tensor(np.asarray(obs) if not isinstance(obs, th.Tensor) else obs, dtype=th.float32)
        if tensor.ndim != 2 or tensor.shape[1] != self.obs_dim:
            raise ValueError(
                f"Observations must be a batch of shape (batch, {self.obs_dim}), got {tuple(tensor.shape)}. "
                + (
                    "Pass a single observation as obs[None]. "
                    if tensor.shape == (self.obs_dim,)
                    else f"The net was built for {self.obs_dim} observation features; build it for this env "
                    "(`from_spaces(env.observation_space, env.action_space)`). "
                )
            )
        return tensor.to(self.device)

    def _action_features(self, actions: ArrayLike) -> th.Tensor:
        if self.discrete_actions:
            return self._one_hot(actions, self.action_dim, "action")
        tensor = th.as_tensor(np.asarray(actions) if not isinstance(actions, th.Tensor) else actions, dtype=th.float32)
        if tensor.ndim == 1 and self.action_dim == 1:
            tensor = tensor.reshape(-1, 1)
        if tensor.ndim != 2 or tensor.shape[1] != self.action_dim:
            raise ValueError(
                f"Actions must be a batch of shape (batch, {self.action_dim}), got {tuple(tensor.shape)}. The net was "
                f"built for {self.action_dim} action features; build it for this env's action space."
            )
        return tensor.to(self.device)

    def _one_hot(self, indices: ArrayLike, n: int, what: str) -> th.Tensor:
        array = indices.detach().cpu().numpy() if isinstance(indices, th.Tensor) else np.asarray(indices)
        if array.ndim == 2 and array.shape[1] == 1:
            array = array[:, 0]
        if array.ndim != 1:
            raise ValueError(
                f"Discrete {what}s must be a batch of indices of shape (batch,) or (batch, 1), got {array.shape}."
            )
        if array.size and (not np.all(np.equal(np.mod(array, 1), 0)) or array.min() < 0 or array.max() >= n):
            raise ValueError(f"Discrete {what}s must be integers in [0, {n - 1}], got {array.tolist()}.")
        return nn.functional.one_hot(th.as_tensor(array.astype(np.int64), device=self.device), n).float()

    def _raw_inputs(self, obs: ArrayLike, actions: ArrayLike | None) -> th.Tensor:
        obs_features = self._obs_features(obs)
        parts = [obs_features[:, self.obs_select_dim]]
        if self.use_action:
            if actions is None:
                raise ValueError("This constraint net takes the action as input (`use_action=True`): pass the actions.")
            action_features = self._action_features(actions)
            if action_features.shape[0] != obs_features.shape[0]:
                raise ValueError(
                    f"Got {obs_features.shape[0]} observations but {action_features.shape[0]} actions: pass one action "
                    "per observation."
                )
            parts.append(action_features)
        return th.cat(parts, dim=1)

    def reinitialise(self) -> None:
        """
        Draw new initial weights, as a freshly built net of this class starts (from torch's global generator); the
        input normaliser is kept. Identification's untrained baseline reads a learned net against such copies.
        """
        reset_linear_layers(self)

    def fit_normalizer(self, expert_obs: ArrayLike, expert_actions: ArrayLike | None) -> None:
        """
        Fit the input normaliser on the expert data (observations as the env returns them).

        :param expert_obs: Expert observations, ``(n_samples, obs_dim)`` (or indices for a discrete space)
        :param expert_actions: Expert actions, ``(n_samples, action_dim)`` (or indices); may be ``None`` when
            ``use_action`` is False
        """
        if self.normalizer is None:
            raise RuntimeError("This net was built with `normalize_input=False`: there is no normaliser to fit.")
        self.normalizer.fit(self._raw_inputs(expert_obs, expert_actions))

    def preprocess(self, obs: ArrayLike, actions: ArrayLike | None) -> th.Tensor:
        """
        The net's input for a batch: selected observation features, then the action (one-hot where discrete),
        normalised.

        :param obs: Observations, ``(batch, obs_dim)`` (or ``(batch,)`` indices for a discrete space)
        :param actions: Actions, ``(batch, action_dim)`` (or indices); ignored when ``use_action`` is False
        :return: Float tensor of shape ``(batch, input_dim)`` on the net's device
        """
        inputs = self._raw_inputs(obs, actions)
        return self.normalizer(inputs) if self.normalizer is not None else inputs

    def predict_feasibility(self, obs: ArrayLike, actions: ArrayLike | None) -> np.ndarray:
        raise NotImplementedError

    def _numpy_forward(self, obs: ArrayLike, actions: ArrayLike | None) -> np.ndarray | None:
        """
        The network's output for a small batch of continuous NumPy inputs, computed in NumPy; ``None`` where this path
        does not apply (discrete spaces, a GPU, torch inputs, an activation it does not know, an unfitted normaliser,
        more than :data:`NUMPY_MAX_BATCH` pairs, or a malformed batch, which the torch path then reports).

        A learner calls the learned cost once per env step on ``n_envs`` pairs: there, torch's per-operation overhead
        (~100 us for a small MLP) dominates, and NumPy does the same float32 arithmetic in a fraction of the time.

        :param obs: Observations as the env returned them, ``(batch, obs_dim)``
        :param actions: Actions as sent to the env, ``(batch, action_dim)``
        :return: The network's output, ``(batch, n_outputs)``, or ``None``
        """
        if isinstance(obs, th.Tensor) or isinstance(actions, th.Tensor):
            return None
        weights = self._current_numpy_weights()
        if weights is None:
            return None
        obs = np.asarray(obs, dtype=np.float32)
        if obs.ndim != 2 or obs.shape[1] != self.obs_dim or not 0 < obs.shape[0] <= NUMPY_MAX_BATCH:
            return None
        parts = [obs[:, self._numpy_obs_index]]
        if self.use_action:
            if actions is None:
                return None
            acts = np.asarray(actions, dtype=np.float32)
            if acts.ndim == 1 and self.action_dim == 1:
                acts = acts.reshape(-1, 1)
            if acts.shape != (obs.shape[0], self.action_dim):
                return None
            parts.append(acts)
        inputs = np.concatenate(parts, axis=1)
        if self.normalizer is not None:
            inputs = (inputs - weights[0]) / weights[1]
            if self.normalizer.clip_range is not None:
                inputs = np.clip(inputs, -self.normalizer.clip_range, self.normalizer.clip_range)
            weights = weights[2:]
        activation = NUMPY_ACTIVATIONS[self.activation_fn]
        n_layers = len(weights) // 2
        for layer in range(n_layers):
            inputs = inputs @ weights[2 * layer] + weights[2 * layer + 1]
            if layer < n_layers - 1:
                inputs = activation(inputs)
        return inputs.astype(np.float32, copy=False)

    def _current_numpy_weights(self) -> list[np.ndarray] | None:
        """
        Normaliser mean and std (when normalising), then each linear layer's transposed weight and bias, as NumPy
        copies; ``None`` where the NumPy path does not apply. Copied again whenever a tensor has changed in place (an
        optimiser step, ``load_state_dict``: torch counts versions) or moved (``to``, see :meth:`_apply`).
        """
        cache = self._numpy_weights
        if cache is not None and all(tensor._version == version for tensor, version in zip(*cache[0], strict=True)):
            return cache[1]
        tensors = [*self.buffers(), *self.parameters()]
        usable = (
            not (self.discrete_obs or self.discrete_actions)
            and self.activation_fn in NUMPY_ACTIVATIONS
            and all(tensor.device.type == "cpu" and tensor.dtype in (th.float32, th.bool) for tensor in tensors)
            and (self.normalizer is None or bool(self.normalizer.fitted))
        )
        arrays: list[np.ndarray] | None = None
        if usable:
            arrays = []
            if self.normalizer is not None:
                arrays += [self.normalizer.mean.detach().numpy().copy(), self.normalizer.std.detach().numpy().copy()]
            for module in self.network:
                if isinstance(module, nn.Linear):
                    arrays += [module.weight.detach().numpy().T.copy(), module.bias.detach().numpy().copy()]
        self._numpy_weights = ((tensors, [tensor._version for tensor in tensors]), arrays)
        return arrays

    def _apply(self, fn: Any, recurse: bool = True) -> Any:
        # ``to``, ``cuda``, ``float``...: new tensors, so the NumPy copies must be made again
        self._numpy_weights = None
        return super()._apply(fn, recurse)

    def cost(self, obs: np.ndarray, actions: np.ndarray | None) -> np.ndarray:
        """
        The learned cost ``1 - phi`` for a batch (no gradient), usable as ``PPOLagrangian``'s ``cost_fn``.

        :param obs: Observations as the env returned them, ``(batch, obs_dim)``
        :param actions: Actions as sent to the env, ``(batch, action_dim)``
        :return: Costs in ``[0, 1]``, float32 of shape ``(batch,)``
        """
        return (1.0 - self.predict_feasibility(obs, actions)).astype(np.float32)


class FeasibilityNet(_ConstraintNet):
    """
    Feasibility ``phi(s, a) = sigmoid(MLP(x)) in (0, 1)``: 1 means allowed, 0 forbidden; the cost is ``1 - phi``.
    Used by BC2L and MECL as the constraint model and by GACL as the discriminator ``D(s, a)``.
    See :class:`_ConstraintNet` for the arguments.
    """

    def forward(self, inputs: th.Tensor) -> th.Tensor:
        """
        :param inputs: Preprocessed inputs, ``(batch, input_dim)``
        :return: ``phi``, shape ``(batch,)``
        """
        return th.sigmoid(self.network(inputs)).reshape(-1)

    def feasibility(self, obs: ArrayLike, actions: ArrayLike | None) -> th.Tensor:
        """
        ``phi`` for a batch, with gradient (for the losses).

        :param obs: Observations
        :param actions: Actions
        :return: ``phi``, shape ``(batch,)``
        """
        return self(self.preprocess(obs, actions))

    def predict_feasibility(self, obs: ArrayLike, actions: ArrayLike | None) -> np.ndarray:
        """
        ``phi`` for a batch as numpy, without gradient.

        :param obs: Observations
        :param actions: Actions
        :return: ``phi``, float32 of shape ``(batch,)``
        """
        outputs = self._numpy_forward(obs, actions)
        if outputs is not None:
            return scipy.special.expit(outputs[:, 0]).astype(np.float32)
        with th.no_grad():
            return self.feasibility(obs, actions).cpu().numpy().astype(np.float32)


class BetaFeasibilityNet(_ConstraintNet):
    """
    VICRL's feasibility distribution ``phi(s, a) ~ Beta(alpha, beta)`` with
    ``[alpha, beta] = softplus(MLP(x)) + min_concentration`` (the paper's ``log(1 + exp(f))``; the floor keeps both
    parameters strictly positive when softplus underflows).

    The cost ``1 - phi`` takes ``phi`` from ``cost_mode``:

    - ``"sample"``: a draw from the Beta (the reference's default)
    - ``"mean"``: ``alpha / (alpha + beta)``
    - ``"var"``: the value at risk, the ``(1 - confidence)``-quantile of the feasibility, i.e. the low-feasibility
      (high-cost) tail: ``P(phi <= phi_VaR) = 1 - confidence``. Higher confidence, larger (more risk-averse) cost.
    - ``"cvar"``: the conditional value at risk, ``E[phi | phi <= phi_VaR]``, the mean of that same tail (in closed
      form: ``mean * I(phi_VaR; alpha + 1, beta) / (1 - confidence)``, ``I`` the regularised incomplete beta function)

    The reference code used the same tail (``scipy.stats.beta.ppf(1 - confidence)``) and estimated the CVaR by
    sampling. Other arguments: see :class:`_ConstraintNet`.

    :param cost_mode: One of ``"sample"``, ``"mean"``, ``"var"``, ``"cvar"``
    :param confidence: Confidence level in ``(0, 1)`` for ``"var"`` and ``"cvar"``
    :param min_concentration: Added to the softplus outputs
    :param kwargs: The arguments of :class:`_ConstraintNet` (``discrete_obs``, ``hidden_sizes``, ``obs_select_dim``, ...)
    """

    n_outputs = 2

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        cost_mode: str = "sample",
        confidence: float = 0.5,
        min_concentration: float = 1e-4,
        **kwargs: Any,
    ):
        super().__init__(obs_dim, action_dim, **kwargs)
        if min_concentration <= 0:
            raise ValueError(f"`min_concentration` must be > 0, got {min_concentration}.")
        self.min_concentration = float(min_concentration)
        self.cost_mode = _check_cost_mode(cost_mode)
        self.confidence = _check_confidence(confidence)

    @property
    def constructor_kwargs(self) -> dict[str, Any]:
        return {
            **super().constructor_kwargs,
            "cost_mode": self.cost_mode,
            "confidence": self.confidence,
            "min_concentration": self.min_concentration,
        }

    def forward(self, inputs: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """
        :param inputs: Preprocessed inputs, ``(batch, input_dim)``
        :return: ``alpha`` and ``beta``, each of shape ``(batch,)``, both ``>= min_concentration``
        """
        concentrations = nn.functional.softplus(self.network(inputs)) + self.min_concentration
        return concentrations[:, 0], concentrations[:, 1]

    def alpha_beta(self, obs: ArrayLike, actions: ArrayLike | None) -> tuple[th.Tensor, th.Tensor]:
        """
        ``alpha`` and ``beta`` for a batch, with gradient.

        :param obs: Observations
        :param actions: Actions
        :return: ``(alpha, beta)``, each ``(batch,)``
        """
        return self(self.preprocess(obs, actions))

    def distribution(self, obs: ArrayLike, actions: ArrayLike | None) -> th.distributions.Beta:
        """
        :param obs: Observations
        :param actions: Actions
        :return: ``Beta(alpha, beta)`` for each pair of the batch
        """
        return th.distributions.Beta(*self.alpha_beta(obs, actions))

    def predict_feasibility(
        self, obs: ArrayLike, actions: ArrayLike | None, cost_mode: str | None = None, confidence: float | None = None
    ) -> np.ndarray:
        """
        The feasibility used for the cost, without gradient.

        :param obs: Observations
        :param actions: Actions
        :param cost_mode: Overrides ``self.cost_mode`` for this call
        :param confidence: Overrides ``self.confidence`` for this call
        :return: Feasibility in ``[0, 1]``, float32 of shape ``(batch,)``
        """
        mode = self.cost_mode if cost_mode is None else _check_cost_mode(cost_mode)
        level = self.confidence if confidence is None else _check_confidence(confidence)
        outputs = self._numpy_forward(obs, actions)
        if outputs is not None:
            # torch's softplus: log(1 + exp(x)), and x itself above 20
            concentrations = np.where(outputs > 20, outputs, np.logaddexp(np.float32(0), outputs)) + self.min_concentration
            alpha_np, beta_np = concentrations[:, 0].astype(np.float32), concentrations[:, 1].astype(np.float32)
            if mode == "mean":
                return (alpha_np / (alpha_np + beta_np)).astype(np.float32)
            alpha, beta = th.from_numpy(alpha_np), th.from_numpy(beta_np)
        else:
            with th.no_grad():
                alpha, beta = self.alpha_beta(obs, actions)
        with th.no_grad():
            if mode == "sample":
                return th.distributions.Beta(alpha, beta).sample().cpu().numpy().astype(np.float32)
            if mode == "mean":
                return (alpha / (alpha + beta)).cpu().numpy().astype(np.float32)
        return beta_tail_feasibility(
            alpha.cpu().numpy().astype(np.float64), beta.cpu().numpy().astype(np.float64), level, mode
        ).astype(np.float32)


def beta_tail_feasibility(alpha: np.ndarray, beta: np.ndarray, confidence: float, mode: str) -> np.ndarray:
    """
    The value at risk (``mode="var"``) or conditional value at risk (``mode="cvar"``) of ``phi ~ Beta(alpha, beta)``
    on its low-feasibility tail at level ``confidence``: ``VaR = F^-1(1 - confidence)`` and
    ``CVaR = E[phi | phi <= VaR] = alpha / (alpha + beta) * I(VaR; alpha + 1, beta) / (1 - confidence)``.

    :param alpha: ``alpha > 0``
    :param beta: ``beta > 0``, same shape
    :param confidence: Level in ``(0, 1)``
    :param mode: ``"var"`` or ``"cvar"``
    :return: The feasibility, same shape
    """
    tail_probability = 1.0 - _check_confidence(confidence)
    value_at_risk = scipy.special.betaincinv(alpha, beta, tail_probability)
    if mode == "var":
        return value_at_risk
    if mode == "cvar":
        mean = alpha / (alpha + beta)
        return np.clip(mean * scipy.special.betainc(alpha + 1.0, beta, value_at_risk) / tail_probability, 0.0, value_at_risk)
    raise ValueError(f"`mode` must be 'var' or 'cvar', got {mode!r}.")


def _check_cost_mode(cost_mode: str) -> str:
    mode = str(cost_mode).lower()
    if mode not in BETA_COST_MODES:
        raise ValueError(f"Unknown cost mode {cost_mode!r}: expected one of {BETA_COST_MODES} (case-insensitive).")
    return mode


def _check_confidence(confidence: float) -> float:
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"`confidence` must be in (0, 1), got {confidence}.")
    return float(confidence)


def _space_features(space: spaces.Space, what: str) -> tuple[int, bool]:
    if isinstance(space, spaces.Discrete):
        if space.start != 0:
            raise ValueError(f"Discrete {what} spaces must start at 0, got start={space.start}.")
        return int(space.n), True
    if isinstance(space, spaces.Box) and len(space.shape) == 1:
        return int(space.shape[0]), False
    raise ValueError(
        f"The constraint nets take a flat Box or a Discrete {what} space, got {space}. Flatten the {what}s first "
        "(e.g. gymnasium.wrappers.FlattenObservation)."
    )


class CostNet(_ConstraintNet):
    """
    A learned cost ``c(s, a) = LeakyReLU(MLP(x))``, unbounded above and (but for LeakyReLU's small negative slope)
    non-negative: the cost model of :class:`~sb3_icrl.irlplus.IRLPlus`, which learns a cost as a negative reward
    instead of a feasibility in ``(0, 1)``. Its output layer starts at zero, so every pair starts at cost 0 and the
    learner first follows the reward alone. ``predict_feasibility`` returns ``exp(-c)`` (1 at zero cost), used only
    for logging and for the trainer's ``feasibility_gap``; :meth:`cost` returns ``c`` itself.
    See :class:`_ConstraintNet` for the arguments.
    """

    #: Slope of the output LeakyReLU below 0 (torch's default)
    negative_slope: float = 0.01

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self._zero_output_layer()

    def _zero_output_layer(self) -> None:
        output_layer = self.network[-1]
        assert isinstance(output_layer, nn.Linear)
        with th.no_grad():
            output_layer.weight.zero_()
            output_layer.bias.zero_()

    def reinitialise(self) -> None:
        """New hidden weights and an output layer at zero, as a fresh :class:`CostNet`: cost 0 everywhere."""
        super().reinitialise()
        self._zero_output_layer()

    def forward(self, inputs: th.Tensor) -> th.Tensor:
        """
        :param inputs: Preprocessed inputs, ``(batch, input_dim)``
        :return: ``c``, shape ``(batch,)``
        """
        return nn.functional.leaky_relu(self.network(inputs), self.negative_slope).reshape(-1)

    def cost_tensor(self, obs: ArrayLike, actions: ArrayLike | None) -> th.Tensor:
        """
        ``c`` for a batch, with gradient (for the losses).

        :param obs: Observations
        :param actions: Actions
        :return: ``c``, shape ``(batch,)``
        """
        return self(self.preprocess(obs, actions))

    def cost(self, obs: np.ndarray, actions: np.ndarray | None) -> np.ndarray:
        """
        The learned cost ``c`` for a batch (no gradient).

        :param obs: Observations as the env returned them, ``(batch, obs_dim)``
        :param actions: Actions as sent to the env, ``(batch, action_dim)``
        :return: Costs, float32 of shape ``(batch,)``
        """
        outputs = self._numpy_forward(obs, actions)
        if outputs is not None:
            return _leaky_relu(outputs[:, 0]).astype(np.float32)
        with th.no_grad():
            return self.cost_tensor(obs, actions).cpu().numpy().astype(np.float32)

    def paid_cost(self, obs: np.ndarray, actions: np.ndarray | None) -> np.ndarray:
        """
        The cost the grid's planner is charged: :meth:`cost` floored at 0. A planner paid a little for every step in a
        cell below 0 would rather wander there than end its episode at the goal; the cost update itself still sees (and
        gets gradients from) the dip. The learners (IRL-Plus on SAC or PPO) are charged :meth:`cost` itself, as in the
        reference: floored, every difference the update makes below 0 would be lost to them.

        :param obs: Observations as the env returned them, ``(batch, obs_dim)``
        :param actions: Actions as sent to the env, ``(batch, action_dim)``
        :return: Costs >= 0, float32 of shape ``(batch,)``
        """
        return np.maximum(self.cost(obs, actions), np.float32(0))

    def predict_feasibility(self, obs: ArrayLike, actions: ArrayLike | None) -> np.ndarray:
        """
        ``exp(-c)`` for a batch: 1 at zero cost, towards 0 as the cost grows (for logging).

        :param obs: Observations
        :param actions: Actions
        :return: Float32 of shape ``(batch,)``
        """
        return np.exp(-self.cost(obs, actions)).astype(np.float32)  # type: ignore[arg-type]
