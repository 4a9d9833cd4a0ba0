from sb3_icrl.bc2l.bc2l import BC2L, BC2LTrainer

__all__ = ["BC2L", "BC2LTrainer"]
