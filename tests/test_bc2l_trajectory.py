"""BC2L's trajectory-level classifier (the reference code's grid-world update) and the tabular loop's nominal buffer."""

import math

import gymnasium as gym
import numpy as np
import pytest
import torch as th

from sb3_icrl.bc2l import BC2L, BC2LTrainer
from sb3_icrl.constraints import FeasibilityNet, bc2l_loss, bc2l_trajectory_loss
from sb3_icrl.data import load_demonstrations
from sb3_icrl.icrl.tabular import tabular_icrl

MAP = "GridWorldWall-v0"


def tensor(values: list[float], requires_grad: bool = False) -> th.Tensor:
    return th.tensor(values, dtype=th.float64, requires_grad=requires_grad)


def grid_net(seed: int = 0) -> tuple[gym.Env, FeasibilityNet]:
    th.manual_seed(seed)
    env = gym.make(f"sb3_icrl/{MAP}")
    net = FeasibilityNet.from_spaces(
        env.observation_space, env.action_space, hidden_sizes=[16], normalize_input=False, use_action=False
    )
    return env, net


def test_trajectory_loss_by_hand():
    # Expert trajectories (0.9, 0.8) and (0.5,); nominal trajectories (0.5, 0.4, 1.0) and (0.2,)
    loss = bc2l_trajectory_loss(tensor([0.9, 0.8, 0.5]), [2, 1], tensor([0.5, 0.4, 1.0, 0.2]), [3, 1], eps=0.0)
    expert = -(math.log(0.72) + math.log(0.5)) / 2
    nominal = -(math.log(1 - 0.2) + math.log(1 - 0.2)) / 2
    assert loss.expert.item() == pytest.approx(expert, rel=1e-12)
    assert loss.nominal.item() == pytest.approx(nominal, rel=1e-12)
    assert loss.regularizer.item() == 0.0 and loss.total.item() == pytest.approx(expert + nominal, rel=1e-12)
    # One-step trajectories: the per-pair loss
    pairs = bc2l_loss(tensor([0.9, 0.6]), tensor([0.2, 0.5, 0.7]), eps=0.0).total.item()
    assert bc2l_trajectory_loss(tensor([0.9, 0.6]), [1, 1], tensor([0.2, 0.5, 0.7]), [1, 1, 1], eps=0.0).total.item() == (
        pytest.approx(pairs, rel=1e-12)
    )


def test_a_pair_shared_with_the_expert_stays_feasible_per_trajectory_but_not_per_pair():
    """Expert trajectory: (shared,); nominal trajectory: (shared, detour). Fit the two feasibilities directly."""
    fitted = {}
    for name in ("trajectory", "pair"):
        logits = th.zeros(2, dtype=th.float64, requires_grad=True)
        optimizer = th.optim.Adam([logits], lr=0.05)
        for _ in range(2000):
            phi = th.sigmoid(logits)
            if name == "trajectory":
                loss = bc2l_trajectory_loss(phi[:1], [1], phi, [2]).total
            else:
                loss = bc2l_loss(phi[:1], phi).total
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        fitted[name] = th.sigmoid(logits).detach().numpy()
    shared, detour = fitted["trajectory"]
    assert shared > 0.95 and detour < 0.05  # the detour explains why the nominal trajectory is infeasible
    assert fitted["pair"][0] < 0.75  # per pair, the shared pair is labelled both ways: 2/3 here (1 vs 1/2 in counts)


def test_trajectory_loss_errors():
    with pytest.raises(ValueError, match="sum to 2 but there are 3 pairs"):
        bc2l_trajectory_loss(tensor([0.9, 0.8, 0.5]), [1, 1], tensor([0.5]), [1])
    with pytest.raises(ValueError, match="positive integers"):
        bc2l_trajectory_loss(tensor([0.9]), [1], tensor([0.5]), [0, 1])


def test_trainer_checks_the_expert_episode_lengths():
    _, net = grid_net()
    demonstrations = load_demonstrations(MAP)
    obs, acts = demonstrations.transitions.obs, demonstrations.transitions.acts
    optimizer = th.optim.Adam(net.parameters())
    with pytest.raises(ValueError, match="sum to the"):
        BC2LTrainer(net, optimizer, obs, acts, None, None, update_every=1, expert_episode_lengths=[len(obs) - 1])
    trainer = BC2LTrainer(
        net, optimizer, obs, acts, None, None, update_every=1, expert_episode_lengths=[len(t) for t in demonstrations]
    )
    assert trainer.expert_episode_lengths is not None and trainer.expert_episode_lengths.sum() == len(obs)


@pytest.mark.parametrize("batch_size", [None, 3])
def test_tabular_icrl_with_the_trajectory_classifier(batch_size):
    env, net = grid_net()
    demonstrations = load_demonstrations(MAP)
    result = tabular_icrl(
        BC2LTrainer,
        net,
        env,
        demonstrations,
        n_iterations=2,
        constraint_steps=2,
        n_nominal_trajectories=5,
        trainer_kwargs=dict(expert_episode_lengths=[len(t) for t in demonstrations], batch_size=batch_size),
    )
    stats = result.history[-1]
    assert {"loss", "loss_expert", "loss_nominal", "expert_feasibility", "nominal_feasibility"} <= set(stats)
    assert stats["n_nominal_trajectories"] == 5 and stats["n_updates"] == 2 and np.isfinite(stats["loss"])


def test_bc2l_class_accepts_the_trajectory_classifier():
    demonstrations = load_demonstrations(MAP)
    model = BC2L(
        "MlpPolicy",
        f"sb3_icrl/{MAP}",
        MAP,
        n_steps=128,
        batch_size=64,
        n_epochs=1,
        update_every=128,
        constraint_net_kwargs=dict(hidden_sizes=[16], normalize_input=False, use_action=False),
        trainer_kwargs=dict(expert_episode_lengths=[len(t) for t in demonstrations]),
        seed=0,
    )
    model.learn(256)
    assert model.icrl_trainer is not None and model.icrl_trainer.n_updates >= 1


def test_nominal_buffer():
    env, net = grid_net()
    sizes = []

    class RecordingTrainer(BC2LTrainer):
        def update(self, nominal):
            sizes.append(len(nominal.episode_lengths))
            return super().update(nominal)

    tabular_icrl(
        RecordingTrainer,
        net,
        env,
        load_demonstrations(MAP),
        n_iterations=3,
        constraint_steps=1,
        n_nominal_trajectories=4,
        nominal_buffer_size=6,
    )
    assert sizes == [4, 4, 4]  # drawn from the buffer: as many as the planner's rollouts
    with pytest.raises(ValueError, match="nominal_buffer_size"):
        tabular_icrl(BC2LTrainer, net, env, load_demonstrations(MAP), nominal_buffer_size=-1)
