from sb3_icrl.mecl.mecl import MECL, MECLTrainer

__all__ = ["MECL", "MECLTrainer"]
