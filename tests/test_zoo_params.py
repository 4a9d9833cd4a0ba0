"""``-params`` parsing: literals are evaluated, constructor-dict strings are kept as written for config.yml."""

import yaml

from sb3_icrl.zoo.hyperparams import preprocess_hyperparams
from sb3_icrl.zoo.train import get_parser


def test_params_keep_dict_strings_and_evaluate_literals():
    policy_kwargs = "dict(activation_fn=nn.ReLU, net_arch=[8])"
    args = get_parser().parse_args(
        [
            "--algo",
            "ppo",
            "--env",
            "ConstrainedCorridor-v0",
            "-params",
            "n_steps:64",
            "gamma:0.98",
            f"policy_kwargs:{policy_kwargs}",
        ]
    )
    assert args.hyperparams["n_steps"] == 64 and args.hyperparams["gamma"] == 0.98
    # Kept as the string: config.yml can record it (yaml.safe_dump fails on nn.ReLU) and it is evaluated later.
    assert args.hyperparams["policy_kwargs"] == policy_kwargs
    assert "policy_kwargs: dict(activation_fn=nn.ReLU" in yaml.safe_dump(args.hyperparams)
    params = preprocess_hyperparams({"n_timesteps": 10, **args.hyperparams})
    assert params["policy_kwargs"]["net_arch"] == [8]
    assert params["policy_kwargs"]["activation_fn"].__name__ == "ReLU"
