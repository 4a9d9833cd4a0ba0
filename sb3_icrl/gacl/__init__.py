from sb3_icrl.gacl.gacl import GACL, GACLTrainer

__all__ = ["GACL", "GACLTrainer"]
