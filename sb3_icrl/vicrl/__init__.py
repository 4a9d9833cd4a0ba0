from sb3_icrl.vicrl.vicrl import VICRL, VICRLTrainer

__all__ = ["VICRL", "VICRLTrainer"]
