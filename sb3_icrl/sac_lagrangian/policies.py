"""SAC's policy with a cost critic beside its reward critics, for :class:`~sb3_icrl.sac_lagrangian.SACLagrangian`."""

from stable_baselines3.common.type_aliases import Schedule
from stable_baselines3.sac.policies import SACPolicy
from torch import random as th_random


class CostSACPolicy(SACPolicy):
    """
    SB3's ``SACPolicy`` plus a cost critic ``Q_c(s, a)`` (``n_critics`` heads, as the reward critic) and its target.

    The cost critic has a features extractor of its own, so its loss never changes the actor or the reward critics.
    It is built after them, under a forked random state, so that they get the same initial weights, and the run the
    same sampled actions, as SAC at the same seed. Its optimizer is ``cost_critic.optimizer``. Arguments: those of
    SB3's ``SACPolicy`` (``net_arch``'s ``"qf"`` sets both critics).
    """

    def _build(self, lr_schedule: Schedule) -> None:
        super()._build(lr_schedule)
        with th_random.fork_rng(devices=[]):
            self.cost_critic = self.make_critic(features_extractor=None)
            self.cost_critic_target = self.make_critic(features_extractor=None)
        self.cost_critic_target.load_state_dict(self.cost_critic.state_dict())
        self.cost_critic.optimizer = self.optimizer_class(  # type: ignore[call-arg]
            self.cost_critic.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs
        )
        self.cost_critic_target.set_training_mode(False)

    def set_training_mode(self, mode: bool) -> None:
        super().set_training_mode(mode)
        if hasattr(self, "cost_critic"):  # (SACPolicy calls it while building, before the cost critic exists)
            self.cost_critic.set_training_mode(mode)


MlpPolicy = CostSACPolicy
