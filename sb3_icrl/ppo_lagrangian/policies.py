from sb3_icrl.common.policies import CostActorCriticCnnPolicy, CostActorCriticPolicy

MlpPolicy = CostActorCriticPolicy
CnnPolicy = CostActorCriticCnnPolicy
