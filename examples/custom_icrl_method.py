"""Your own ICRL method: a least-squares constraint update on PPO-Lagrangian (``python examples/custom_icrl_method.py``)."""

import torch as th

from sb3_icrl.constraints import FeasibilityNet
from sb3_icrl.icrl import ICRLTrainer, LagrangianICRL
from sb3_icrl.icrl.trainer import Minibatch


class LeastSquaresTrainer(ICRLTrainer):
    """Pulls the feasibility ``phi`` of expert pairs to 1 and of the learner's own pairs to 0, in least squares."""

    constraint_net_type = FeasibilityNet

    def loss(self, batch: Minibatch) -> tuple[th.Tensor, dict[str, float]]:
        assert isinstance(self.constraint_net, FeasibilityNet)
        expert_term = ((1.0 - self.constraint_net.feasibility(batch.expert_obs, batch.expert_acts)) ** 2).mean()
        nominal_term = (self.constraint_net.feasibility(batch.nominal_obs, batch.nominal_acts) ** 2).mean()
        return expert_term + nominal_term, {"loss_expert": expert_term.item(), "loss_nominal": nominal_term.item()}


class LSCL(LagrangianICRL):
    """Least-Squares Constraint Learning: PPO-Lagrangian on the learned cost ``1 - phi``."""

    constraint_net_class = FeasibilityNet
    default_trainer_class = LeastSquaresTrainer


if __name__ == "__main__":
    # Learn the grid world's wall from the shipped demonstrations (a minute or two on one core)
    model = LSCL("MlpPolicy", "sb3_icrl/GridWorldWall-v0", demonstrations="GridWorldWall-v0", n_steps=256, seed=0)
    model.learn(10_000)
    assert model.expert_obs is not None and model.expert_acts is not None
    expert_cost = model.constraint_cost(model.expert_obs, model.expert_acts).mean()
    print(f"{model.n_constraint_updates} constraint updates, mean learned cost of the expert's pairs {expert_cost:.3f}")
